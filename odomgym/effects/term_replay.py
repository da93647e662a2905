"""The grammar's terms applied to a replayed run (:mod:`odomgym.effects.discovered`), compiled.

Why compiled: the diagnose fits replay every logged run hundreds of times with different
coefficients (a finite-difference derivative per term and iteration), and the terms' numpy
expressions — one array per term and modulator, a gradient for the acceleration — were most of
a replay's time. Why bit-identical: every expression below is the numpy one it replaces
(``discovered.wheel_modulator``, ``discovered.body_modulator``, ``numpy.gradient``), element
by element with the same operations in the same order, and numba compiles them without
fast-math (:func:`odomgym._jit.kernel`), so a fit's numbers do not depend on which ran
(``tests/test_diagnose_speed.py``). Transcendental functions stay numpy's: the angle
modulators come in precomputed.

Modulator codes are the positions in ``WHEEL_MODULATORS`` and ``BODY_MODULATORS``. The kernels
call each other, so they live in one module (numba's cache notices edits to a kernel's own
module only).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel

__all__ = ["replay_body_terms", "replay_wheel_terms"]

FloatArray = NDArray[np.float64]


@kernel
def _sign(x: float) -> float:
    """``numpy.sign`` of one float: ±1, 0 for ±0 and NaN for NaN."""
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0 if x == 0.0 else x


@kernel
def _abs_speed_rate(speed: FloatArray, dt: FloatArray) -> FloatArray:
    """d|v|/dt (n, 2) [m/s²] of wheel speeds (n, 2) [m/s] over intervals ``dt`` (n,) [s]:
    ``numpy.gradient`` of |v| over the intervals' middles (second-order inside, one-sided at
    the ends), its operations in its order; 0·v if those middles do not increase."""
    n = speed.shape[0]
    out = np.zeros((n, 2))
    if n < 2:
        return out
    mid = np.empty(n)
    total = 0.0
    for i in range(n):
        total += dt[i]
        mid[i] = total - 0.5 * dt[i]
    step = np.empty(n - 1)
    uniform = True
    for i in range(n - 1):
        step[i] = mid[i + 1] - mid[i]
        if not step[i] > 0.0:
            for j in range(n):
                for w in range(2):
                    out[j, w] = 0.0 * speed[j, w]
            return out
        uniform = uniform and step[i] == step[0]
    for w in range(2):
        for i in range(1, n - 1):
            f0 = abs(speed[i - 1, w])
            f1 = abs(speed[i, w])
            f2 = abs(speed[i + 1, w])
            if uniform:
                out[i, w] = (f2 - f0) / (2.0 * step[0])
            else:
                dx1 = step[i - 1]
                dx2 = step[i]
                a = -dx2 / (dx1 * (dx1 + dx2))
                b = (dx2 - dx1) / (dx1 * dx2)
                c = dx1 / (dx2 * (dx1 + dx2))
                out[i, w] = a * f0 + b * f1 + c * f2
        out[0, w] = (abs(speed[1, w]) - abs(speed[0, w])) / step[0]
        out[n - 1, w] = (abs(speed[n - 1, w]) - abs(speed[n - 2, w])) / step[n - 2]
    return out


@kernel
def replay_wheel_terms(
    wheel: FloatArray,
    radius: FloatArray,
    dt: FloatArray,
    sin1: FloatArray,
    cos1: FloatArray,
    sin2: FloatArray,
    cos2: FloatArray,
    time: FloatArray,
    columns: NDArray[np.int64],
    codes: NDArray[np.int64],
    coefficients: FloatArray,
    bounds: NDArray[np.int64],
) -> FloatArray:
    """The wheel terms on the wheel rotations (n, 2) [rad] of the runs whose rows start at
    ``bounds`` (R + 1,; ``[0, n]`` for one run): each wheel's rotation × (1 + Σ c·m) over the
    terms in order (wheel ``columns``, modulator ``codes`` in ``WHEEL_MODULATORS`` order), the
    speed [m/s] the travel through ``radius`` [m] over ``dt`` [s], the angle modulators
    precomputed; the acceleration is each run's own gradient. Bit-identical to the numpy
    expressions of ``wheel_modulator`` on each run: the same operations in the same order."""
    n = wheel.shape[0]
    speed = np.empty((n, 2))
    for i in range(n):
        safe = dt[i] if dt[i] > 0.0 else np.inf
        for w in range(2):
            speed[i, w] = wheel[i, w] * radius[w] / safe
    accel = speed
    if np.any(codes == 4):
        accel = np.empty((n, 2))
        for r in range(bounds.shape[0] - 1):
            a, b = bounds[r], bounds[r + 1]
            accel[a:b] = _abs_speed_rate(speed[a:b], dt[a:b])
    factor = np.ones((n, 2))
    for t in range(codes.size):
        w = columns[t]
        code = codes[t]
        c = coefficients[t]
        for i in range(n):
            v = speed[i, w]
            if code == 0:
                m = 1.0
            elif code == 1:
                m = abs(v)
            elif code == 2:
                m = v * v
            elif code == 3:
                m = _sign(v)
            elif code == 4:
                m = accel[i, w]
            elif code == 5:
                m = sin1[i, w]
            elif code == 6:
                m = cos1[i, w]
            elif code == 7:
                m = sin2[i, w]
            elif code == 8:
                m = cos2[i, w]
            else:
                m = time[i]
            factor[i, w] += c * m
    out = np.empty((n, 2))
    for i in range(n):
        for w in range(2):
            out[i, w] = wheel[i, w] * factor[i, w]
    return out


@kernel
def replay_body_terms(
    ds: FloatArray,
    dtheta: FloatArray,
    crab: FloatArray,
    dt: FloatArray,
    time: FloatArray,
    spin: FloatArray,
    yaw: NDArray[np.bool_],
    codes: NDArray[np.int64],
    coefficients: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """The body terms on one run's intervals: (crab + Σ c·m [rad], dθ × (1 + Σ c·m)) over the
    crab and the ``yaw`` terms in order (modulator ``codes`` in ``BODY_MODULATORS`` order,
    v = ``ds``/``dt`` [m/s], ω = ``dtheta``/``dt`` [rad/s]; ``spin`` (n,) the ``spin``
    modulator precomputed from the wheel travels, empty when no term has it). Bit-identical to
    the numpy expressions of ``body_modulator``: the same operations in the same order."""
    n = ds.shape[0]
    v = np.empty(n)
    omega = np.empty(n)
    for i in range(n):
        safe = dt[i] if dt[i] > 0.0 else np.inf
        v[i] = ds[i] / safe
        omega[i] = dtheta[i] / safe
    extra = np.zeros(n)
    scale = np.ones(n)
    for t in range(codes.size):  # term by term: each sample still sums its terms in order
        code = codes[t]
        c = coefficients[t]
        acc = scale if yaw[t] else extra
        for i in range(n):
            if code == 0:
                m = 1.0
            elif code == 1:
                m = abs(v[i])
            elif code == 2:
                m = v[i] * v[i]
            elif code == 3:
                m = abs(omega[i])
            elif code == 4:
                m = abs(v[i] * omega[i])
            elif code == 5:
                m = v[i] * omega[i]
            elif code == 6:
                m = _sign(v[i])
            elif code == 7:
                m = time[i]
            else:
                m = spin[i]
            acc[i] += c * m
    out_crab = np.empty(n)
    out_dtheta = np.empty(n)
    for i in range(n):
        out_crab[i] = crab[i] + extra[i]
        out_dtheta[i] = dtheta[i] * scale[i]
    return out_crab, out_dtheta

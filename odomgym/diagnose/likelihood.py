"""The likelihood of a logged run under a model: a Kalman filter on the disagreement.

State: δ = (true − predicted) axle pose (x, y [m], θ [rad]) in the world frame. The prediction
is the replay (:mod:`odomgym.diagnose.replay`); the disagreement grows through

* **wheel noise** — each wheel's travel d carries variance k²·|d| per sample (Chong & Kleeman
  1997, Eq. 4) and whatever noise effects add; linearised through the midpoint odometry
  equations, δ ← F·δ + G·w with F the displacement coupling (a heading error δθ moves later
  positions by δθ × displacement) and G = ∂(x, y, θ)/∂(d_L, d_R), exactly the propagation of
  Chong & Kleeman's Eq. 23 applied sample by sample;
* **wheel jumps** (``floor_bumps``): a Poisson number of sudden losses of e metres of one
  wheel's travel between two measurements (a bump: the pose moves −e/2 along the track and
  turns ±e/b); the innovation is a Gaussian mixture over the jump count (0–3), each jump's
  effect propagated to the measurement like the wheel noise, collapsed to one Gaussian after
  each update (a first-order generalised pseudo-Bayesian filter). With ``gaussian_jumps`` the
  jumps enter as their variance instead (for least-squares fits);
* **the sensor** — every measured pose component has white noise (σ_xy, σ_xy, σ_θ); the first
  measured pose starts the replay, so its noise is the initial covariance.

The log-likelihood (prediction-error decomposition) is a proper scoring rule for a held-out run;
the whitened innovations turn a fit of the mean model into generalised least squares.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import inlined_kernel, kernel
from odomgym.diagnose.replay import Replay
from odomgym.effects import EFFECTS
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = ["RunLikelihood", "SensorNoise", "measurement_mask", "run_likelihood", "run_scores"]

FloatArray = NDArray[np.float64]
_MAX_JUMPS = 3


@dataclass(frozen=True)
class SensorNoise:
    """White noise of the ground-truth sensor: position σ [m] (each axis), heading σ [rad]."""

    position: float
    heading: float


@dataclass(frozen=True)
class RunLikelihood:
    """Log-likelihood of one run, its whitened innovations and how many values entered."""

    loglik: float
    whitened: FloatArray
    count: int


def measurement_mask(run: Run, min_interval: float) -> NDArray[np.bool_]:
    """Which pose components (T, 3) enter the filter: measured ones, at most one sample every
    ``min_interval`` seconds (the last measured sample always), never the first (it starts the
    replay)."""
    measured = np.isfinite(run.true_pose)
    rows = np.flatnonzero(measured[:, :2].all(axis=1) | measured[:, 2])
    keep = np.zeros(len(run.time), dtype=bool)
    last = -math.inf
    for k in rows[1:]:
        if run.time[k] - last >= min_interval - 1e-9:
            keep[k] = True
            last = run.time[k]
    if len(rows) > 1:
        keep[rows[-1]] = True
    return measured & keep[:, None]


def process_noise(spec: RobotSpec, travel: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """Per-sample wheel variance (n, 2) [m²], expected wheel jumps (n, 2) and the travel each
    jump loses [m], from the spec's noise effects."""
    variance = np.zeros_like(travel)
    jumps = np.zeros_like(travel)
    size = 0.0
    for name, values in spec.effect_dict().items():
        effect = EFFECTS.get(name)
        if effect is None or not effect.noise:
            continue
        extra = effect.wheel_variance(values, travel)
        if extra is not None:
            variance += extra
        jumping = effect.wheel_jumps(values, travel, float(spec.true_wheelbase))
        if jumping is not None:
            rate, jump = jumping
            if size and jump != size:
                raise ValueError("only one wheel-jump effect is supported at a time")
            jumps += rate
            size = jump
    return variance, jumps, size


def run_likelihood(
    run: Run,
    replay: Replay,
    spec: RobotSpec,
    sensor: SensorNoise,
    mask: NDArray[np.bool_],
    *,
    gaussian_jumps: bool = False,
) -> RunLikelihood:
    """Filter ``run``'s disagreement with ``replay`` under ``spec``'s noise and ``sensor``."""
    loglik, whitened, count = _filter(
        *_model_arrays(replay, spec, sensor),
        _residual(run, replay, mask),
        mask,
        gaussian_jumps,
        True,
        np.zeros((0, 2)),
    )
    return RunLikelihood(float(loglik), whitened, int(count))


def run_scores(
    run: Run,
    replay: Replay,
    spec: RobotSpec,
    sensor: SensorNoise,
    mask: NDArray[np.bool_],
    *,
    whitened: bool,
) -> tuple[float, FloatArray | None]:
    """``run``'s log-likelihood with the jump mixture and, if ``whitened``, its whitened
    innovations with the jumps as their variance: :func:`run_likelihood`'s ``loglik`` without
    and ``whitened`` with ``gaussian_jumps``, which is what a fit needs of every run.

    Why one function: the two filters differ only at samples where a wheel jump is expected
    (``gaussian_jumps`` is read nowhere else), so without any — every model but one carrying
    ``floor_bumps`` — one pass gives both, bit-identical to two; the process noise and the
    residual are computed once either way."""
    arrays = _model_arrays(replay, spec, sensor)
    residual = _residual(run, replay, mask)
    no_expected = np.zeros((0, 2))
    loglik, white, _ = _filter(*arrays, residual, mask, False, True, no_expected)
    if not whitened:
        return float(loglik), None
    jumps = arrays[6]
    if np.any(jumps > 0.0):
        _, white, _ = _filter(*arrays, residual, mask, True, True, no_expected)
    return float(loglik), white


def _residual(run: Run, replay: Replay, mask: NDArray[np.bool_]) -> FloatArray:
    """Measured minus predicted tracked pose (T, 3) where ``mask`` holds, else 0; the heading
    difference wrapped to [−π, π) [rad]."""
    residual = np.where(mask, run.true_pose - replay.tracked, 0.0)
    residual[:, 2] = np.mod(residual[:, 2] + math.pi, 2.0 * math.pi) - math.pi
    return residual


def _model_arrays(
    replay: Replay, spec: RobotSpec, sensor: SensorNoise
) -> tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, float, FloatArray, FloatArray, float, FloatArray
]:
    """The replay's motion, ``spec``'s process noise and ``sensor``'s sigmas in the order the
    compiled ``_filter`` takes them (it accepts arrays and scalars only)."""
    variance, jumps, size = process_noise(spec, replay.travel)
    return (
        replay.pose,
        replay.tracked,
        replay.ds,
        replay.dtheta,
        replay.wheelbase,
        variance,
        jumps,
        size,
        np.array([sensor.position, sensor.position, sensor.heading]),
    )


def expected_square_gap(
    run: Run, replay: Replay, spec: RobotSpec, sensor: SensorNoise, mask: NDArray[np.bool_]
) -> FloatArray:
    """E|measured − predicted position|² [m²] and E(heading disagreement)² [rad²] at every
    sample (T, 2) (NaN where not in ``mask``) if the model were right: what noise alone leaves
    (the sensor, wheel noise, heading jumps as their variance), propagated open loop from the
    start."""
    expected = np.full((len(run.time), 2), np.nan)
    _filter(
        *_model_arrays(replay, spec, sensor),
        np.zeros((len(run.time), 3)),
        mask,
        True,
        False,
        expected,
    )
    return expected


@kernel
def _propagate(mat: FloatArray, ux: float, uy: float) -> None:
    """mat ← F·mat·Fᵀ in place for F = I + u·e_θᵀ, u = (ux, uy, 0): a heading error moves later
    positions by δθ × displacement. Scalar code: this runs once per logged sample."""
    p20 = mat[2, 0]
    p21 = mat[2, 1]
    p22 = mat[2, 2]
    mat[0, 0] += 2.0 * ux * p20 + ux * ux * p22
    mat[1, 1] += 2.0 * uy * p21 + uy * uy * p22
    mat[0, 1] += ux * p21 + uy * p20 + ux * uy * p22
    mat[1, 0] = mat[0, 1]
    mat[0, 2] += ux * p22
    mat[2, 0] = mat[0, 2]
    mat[1, 2] += uy * p22
    mat[2, 1] = mat[1, 2]


@kernel
def _add_outer(mat: FloatArray, weight: float, gx: float, gy: float, gt: float) -> None:
    """mat += weight·g·gᵀ in place, g = (gx, gy, gt)."""
    mat[0, 0] += weight * gx * gx
    mat[1, 1] += weight * gy * gy
    mat[2, 2] += weight * gt * gt
    mat[0, 1] += weight * gx * gy
    mat[1, 0] = mat[0, 1]
    mat[0, 2] += weight * gx * gt
    mat[2, 0] = mat[0, 2]
    mat[1, 2] += weight * gy * gt
    mat[2, 1] = mat[1, 2]


@inlined_kernel
def _gauss_update(
    prior: FloatArray,
    mean: FloatArray,
    h: FloatArray,
    nu: FloatArray,
    rdiag: FloatArray,
    dim: int,
    work: FloatArray,
    sol: FloatArray,
    s_nu: FloatArray,
    out_mean: FloatArray,
    out_cov: FloatArray,
) -> float:
    """One Kalman update with the first ``dim`` rows of ``h`` (measurement noise ``rdiag``,
    innovation ``nu``), written out for at most three rows without temporaries; returns the
    innovation's log density, leaves the whitened innovation L⁻¹ν in ``sol`` and the posterior
    in ``out_mean``, ``out_cov``. ``work`` (4, 3, 3) and ``s_nu`` (3,) are scratch space."""
    hp = work[0]  # H·P (dim × 3)
    s_mat = work[1]  # H·P·Hᵀ + R
    chol = work[2]  # its Cholesky factor
    x = work[3]  # S⁻¹·H·P
    for a in range(dim):
        for b in range(3):
            hp[a, b] = h[a, 0] * prior[0, b] + h[a, 1] * prior[1, b] + h[a, 2] * prior[2, b]
    for a in range(dim):
        for b in range(dim):
            s_mat[a, b] = hp[a, 0] * h[b, 0] + hp[a, 1] * h[b, 1] + hp[a, 2] * h[b, 2]
        s_mat[a, a] += rdiag[a]
    logdet = 0.0
    for a in range(dim):
        for b in range(a + 1):
            acc = s_mat[a, b]
            for c in range(b):
                acc -= chol[a, c] * chol[b, c]
            if a == b:
                chol[a, a] = math.sqrt(max(acc, 1e-300))
            else:
                chol[a, b] = acc / chol[b, b]
        logdet += 2.0 * math.log(chol[a, a])
    quad = 0.0
    for a in range(dim):  # forward substitution: L·sol = ν
        acc = nu[a]
        for c in range(a):
            acc -= chol[a, c] * sol[c]
        sol[a] = acc / chol[a, a]
        quad += sol[a] * sol[a]
    for b in range(3):  # X = S⁻¹·(H·P), column by column: L·y = hp, Lᵀ·x = y
        for a in range(dim):
            acc = hp[a, b]
            for c in range(a):
                acc -= chol[a, c] * x[c, b]
            x[a, b] = acc / chol[a, a]
        for a in range(dim - 1, -1, -1):
            acc = x[a, b]
            for c in range(a + 1, dim):
                acc -= chol[c, a] * x[c, b]
            x[a, b] = acc / chol[a, a]
    # Gain K = (H·P)ᵀ·S⁻¹: posterior mean + (H·P)ᵀ·S⁻¹ν, covariance P − (H·P)ᵀ·S⁻¹·(H·P).
    for a in range(dim - 1, -1, -1):  # S⁻¹ν: back substitution Lᵀ·s_nu = sol
        acc = sol[a]
        for c in range(a + 1, dim):
            acc -= chol[c, a] * s_nu[c]
        s_nu[a] = acc / chol[a, a]
    for a in range(3):
        out_mean[a] = mean[a]
        for c in range(dim):
            out_mean[a] += hp[c, a] * s_nu[c]
        for b in range(3):
            acc = prior[a, b]
            for c in range(dim):
                acc -= hp[c, a] * x[c, b]
            out_cov[a, b] = acc
    return -0.5 * (dim * math.log(2.0 * math.pi) + logdet + quad)


@kernel
def _filter(
    pose: FloatArray,
    tracked: FloatArray,
    ds: FloatArray,
    dtheta: FloatArray,
    wheelbase: float,
    variance: FloatArray,
    jumps: FloatArray,
    size: float,
    sigma: FloatArray,
    residual: FloatArray,
    mask: NDArray[np.bool_],
    gaussian_jumps: bool,
    update: bool,
    expected: FloatArray,
) -> tuple[float, FloatArray, int]:
    n_samples = pose.shape[0]
    whitened = np.zeros(3 * n_samples)
    count = 0
    loglik = 0.0
    # Initial covariance: the first measured pose's noise, mapped from the tracked point to the
    # axle (δ_axle = H⁻¹·δ_tracked with H the offset coupling below).
    ox = tracked[0, 0] - pose[0, 0]
    oy = tracked[0, 1] - pose[0, 1]
    hinv = np.eye(3)
    hinv[0, 2] = oy
    hinv[1, 2] = -ox
    r0 = np.diag(sigma**2)
    cov = hinv @ r0 @ hinv.T
    mean = np.zeros(3)
    a0 = 0.0  # expected jumps since the last update
    vacc = np.zeros((3, 3))  # Σ μ·(Φg)(Φg)ᵀ of those jumps, propagated to the current sample
    rows = np.zeros(3, dtype=np.int64)
    h = np.zeros((3, 3))
    nu = np.zeros(3)
    rdiag = np.zeros(3)
    v1 = np.zeros((3, 3))
    prior = np.zeros((3, 3))
    work = np.zeros((4, 3, 3))
    sol = np.zeros(3)
    s_nu = np.zeros(3)
    weights = np.zeros(_MAX_JUMPS + 1)
    logs = np.zeros(_MAX_JUMPS + 1)
    means = np.zeros((_MAX_JUMPS + 1, 3))
    covs = np.zeros((_MAX_JUMPS + 1, 3, 3))
    for k in range(1, n_samples):
        m = k - 1
        # δ ← F·δ, P ← F·P·Fᵀ + G·Q·Gᵀ with F = I + u·e_θᵀ, u = (−Δy, Δx, 0): scalar code, no
        # temporaries (this loop runs once per logged sample).
        ux = -(pose[k, 1] - pose[m, 1])
        uy = pose[k, 0] - pose[m, 0]
        mean[0] += ux * mean[2]
        mean[1] += uy * mean[2]
        _propagate(cov, ux, uy)
        if a0 > 0.0:
            _propagate(vacc, ux, uy)
        mid = pose[m, 2] + 0.5 * dtheta[m]
        c = math.cos(mid)
        s = math.sin(mid)
        half = ds[m] / (2.0 * wheelbase)
        for w in range(2):
            var = variance[m, w]
            mu = jumps[m, w]
            if mu > 0.0 and gaussian_jumps:
                var += mu * size * size
            if var == 0.0 and mu == 0.0:
                continue
            sign = 1.0 if w == 0 else -1.0
            gx = 0.5 * c + sign * half * s
            gy = 0.5 * s - sign * half * c
            gt = -sign / wheelbase
            if var > 0.0:
                _add_outer(cov, var, gx, gy, gt)
            if mu > 0.0 and not gaussian_jumps:
                a0 += mu
                _add_outer(vacc, mu * size * size, gx, gy, gt)
        if not (mask[k, 0] or mask[k, 1] or mask[k, 2]):
            continue
        if not update:
            # Open loop: the expected squared position disagreement (tracked point) from
            # noise alone, E|z_xy|² = tr(H P Hᵀ)_xy + 2σ², jumps as their variance.
            ox = tracked[k, 0] - pose[k, 0]
            oy = tracked[k, 1] - pose[k, 1]
            vx = cov[0, 0] - 2.0 * oy * cov[0, 2] + oy * oy * cov[2, 2]
            vy = cov[1, 1] + 2.0 * ox * cov[1, 2] + ox * ox * cov[2, 2]
            expected[k, 0] = vx + vy + sigma[0] ** 2 + sigma[1] ** 2
            expected[k, 1] = cov[2, 2] + sigma[2] ** 2
            continue
        # Measurement: tracked point = axle + R(θ)·o, linearised in δθ. Work arrays are
        # preallocated (this runs once per measured sample).
        ox = tracked[k, 0] - pose[k, 0]
        oy = tracked[k, 1] - pose[k, 1]
        dim = 0
        for j in range(3):
            if mask[k, j]:
                rows[dim] = j
                dim += 1
        for a in range(dim):
            j = rows[a]
            for b in range(3):
                h[a, b] = 0.0
            h[a, j] = 1.0
            if j == 0:
                h[a, 2] = -oy
            elif j == 1:
                h[a, 2] = ox
            nu[a] = residual[k, j] - (h[a, 0] * mean[0] + h[a, 1] * mean[1] + h[a, 2] * mean[2])
            rdiag[a] = sigma[j] ** 2
        n_comp = 1
        weights[0] = 1.0
        if a0 > 0.0 and not gaussian_jumps:
            # Jump mixture: v1 = the covariance one jump since the last update adds.
            n_comp = _MAX_JUMPS + 1
            total = 0.0
            term = math.exp(-a0)
            for j in range(n_comp):
                weights[j] = term
                total += term
                term = term * a0 / (j + 1)
            for j in range(n_comp):
                weights[j] /= total
            for a in range(3):
                for b in range(3):
                    v1[a, b] = vacc[a, b] / a0
            a0 = 0.0
            vacc[:, :] = 0.0
        top = -math.inf
        for j in range(n_comp):
            for a in range(3):
                for b in range(3):
                    prior[a, b] = cov[a, b] + j * v1[a, b]
            # All three components measured (the usual case): the update compiled for three
            # rows, its loops unrolled (~25 % less filter time, the same operations).
            post_mean, post_cov = means[j], covs[j]
            if dim == 3:
                fit = _gauss_update(
                    prior, mean, h, nu, rdiag, 3, work, sol, s_nu, post_mean, post_cov
                )
            else:
                fit = _gauss_update(
                    prior, mean, h, nu, rdiag, dim, work, sol, s_nu, post_mean, post_cov
                )
            logs[j] = math.log(weights[j]) + fit
            if j == 0:
                for a in range(dim):
                    whitened[3 * k + rows[a]] = sol[a]
            top = max(top, logs[j])
        total = 0.0
        for j in range(n_comp):
            total += math.exp(logs[j] - top)
        loglik += top + math.log(total)
        for a in range(3):
            mean[a] = 0.0
            for b in range(3):
                cov[a, b] = 0.0
        for j in range(n_comp):
            weight = math.exp(logs[j] - top) / total
            for a in range(3):
                mean[a] += weight * means[j, a]
        for j in range(n_comp):
            weight = math.exp(logs[j] - top) / total
            for a in range(3):
                da = means[j, a] - mean[a]
                for b in range(3):
                    cov[a, b] += weight * (covs[j, a, b] + da * (means[j, b] - mean[b]))
        for a in range(3):
            for b in range(a + 1, 3):
                sym = 0.5 * (cov[a, b] + cov[b, a])
                cov[a, b] = sym
                cov[b, a] = sym
        count += dim
    return loglik, whitened, count

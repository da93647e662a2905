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

from odomgym._jit import kernel
from odomgym.diagnose.replay import Replay
from odomgym.effects import EFFECTS
from odomgym.robot import RobotSpec
from odomgym.runs import Run

__all__ = ["RunLikelihood", "SensorNoise", "measurement_mask", "run_likelihood"]

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
    variance, jumps, size = process_noise(spec, replay.travel)
    residual = np.where(mask, run.true_pose - replay.tracked, 0.0)
    residual[:, 2] = np.mod(residual[:, 2] + math.pi, 2.0 * math.pi) - math.pi
    loglik, whitened, count = _filter(
        replay.pose,
        replay.tracked,
        replay.ds,
        replay.dtheta,
        replay.wheelbase,
        variance,
        jumps,
        size,
        residual,
        mask,
        np.array([sensor.position, sensor.position, sensor.heading]),
        gaussian_jumps,
        True,
        np.zeros((0, 2)),
    )
    return RunLikelihood(float(loglik), whitened, int(count))


def expected_square_gap(
    run: Run, replay: Replay, spec: RobotSpec, sensor: SensorNoise, mask: NDArray[np.bool_]
) -> FloatArray:
    """E|measured − predicted position|² [m²] and E(heading disagreement)² [rad²] at every
    sample (T, 2) (NaN where not in ``mask``) if the model were right: what noise alone leaves
    (the sensor, wheel noise, heading jumps as their variance), propagated open loop from the
    start."""
    variance, jumps, size = process_noise(spec, replay.travel)
    expected = np.full((len(run.time), 2), np.nan)
    _filter(
        replay.pose,
        replay.tracked,
        replay.ds,
        replay.dtheta,
        replay.wheelbase,
        variance,
        jumps,
        size,
        np.zeros((len(run.time), 3)),
        mask,
        np.array([sensor.position, sensor.position, sensor.heading]),
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
    residual: FloatArray,
    mask: NDArray[np.bool_],
    sigma: FloatArray,
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
        # Measurement: tracked point = axle + R(θ)·o, linearised in δθ.
        ox = tracked[k, 0] - pose[k, 0]
        oy = tracked[k, 1] - pose[k, 1]
        rows = np.empty(3, dtype=np.int64)
        dim = 0
        for j in range(3):
            if mask[k, j]:
                rows[dim] = j
                dim += 1
        h = np.zeros((dim, 3))
        z = np.empty(dim)
        r = np.zeros((dim, dim))
        for a in range(dim):
            j = rows[a]
            h[a, j] = 1.0
            if j == 0:
                h[a, 2] = -oy
            elif j == 1:
                h[a, 2] = ox
            z[a] = residual[k, j]
            r[a, a] = sigma[j] ** 2
        nu = z - h @ mean
        # Jump mixture: V1 = a²·E[g gᵀ] of one jump since the last update.
        n_comp = 1
        v1 = np.zeros((3, 3))
        weights = np.ones(_MAX_JUMPS + 1)
        if a0 > 0.0 and not gaussian_jumps:
            n_comp = _MAX_JUMPS + 1
            v1 = vacc / a0  # the covariance one jump adds
            total = 0.0
            term = math.exp(-a0)
            for j in range(_MAX_JUMPS + 1):
                weights[j] = term
                total += term
                term = term * a0 / (j + 1)
            for j in range(_MAX_JUMPS + 1):
                weights[j] /= total
            a0 = 0.0
            vacc[:, :] = 0.0
        new_mean = np.zeros(3)
        new_cov = np.zeros((3, 3))
        means = np.zeros((n_comp, 3))
        covs = np.zeros((n_comp, 3, 3))
        logs = np.zeros(n_comp)
        for j in range(n_comp):
            prior = cov + j * v1
            s_mat = h @ prior @ h.T + r
            chol = np.linalg.cholesky(s_mat)
            sol = np.linalg.solve(chol, nu)
            logdet = 0.0
            for a in range(dim):
                logdet += 2.0 * math.log(chol[a, a])
            logs[j] = math.log(weights[j]) - 0.5 * (
                dim * math.log(2.0 * math.pi) + logdet + sol @ sol
            )
            if j == 0:
                for a in range(dim):
                    whitened[3 * k + rows[a]] = sol[a]
            gain = prior @ h.T @ np.linalg.inv(s_mat)
            means[j] = mean + gain @ nu
            covs[j] = (np.eye(3) - gain @ h) @ prior
        top = logs.max()
        total = 0.0
        for j in range(n_comp):
            total += float(math.exp(logs[j] - top))
        loglik += top + math.log(total)
        for j in range(n_comp):
            weight = math.exp(logs[j] - top) / total
            new_mean += weight * means[j]
        for j in range(n_comp):
            weight = math.exp(logs[j] - top) / total
            d = means[j] - new_mean
            new_cov += weight * (covs[j] + np.outer(d, d))
        mean = new_mean
        cov = 0.5 * (new_cov + new_cov.T)
        count += dim
    return loglik, whitened, count

"""Monte Carlo check of the closed forms of Chong & Kleeman 1997 (§6.1) and its report.

Why a module of its own: :mod:`odomgym.noise.covariance` holds the theory (Eqs. 14, 23, 25–28) that
the envs and the noise fit use; this module *simulates* the same wheel-noise model (Eq. 4) run by
run to check that theory, and formats theory and simulation side by side in the layout of the
paper's Tables 1–7. Conventions (frames, units, unwrapped headings) are those of
:mod:`odomgym.noise.covariance`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from odomgym.noise.covariance import (
    _CORR_PAIRS,
    _check_motion,
    _covariance,
    _nonnegative,
    origin,
    propagate_segment,
)

__all__ = [
    "MonteCarloResult",
    "covariance_report",
    "format_report",
    "monte_carlo",
    "monte_carlo_loop",
]

FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------- Monte Carlo
@dataclass(frozen=True)
class MonteCarloResult:
    """Sample statistics of simulated end poses, with their standard errors.

    ``mean`` and ``std`` are (x [m], y [m], θ [rad], θ unwrapped); ``corr`` is (xθ, yθ, xy) as
    fractions. Standard errors use the sample fourth moments, so they stay honest for the
    non-Gaussian end poses of Table 7: SE(s) = √((m₄ − s⁴)/n)/(2s) (→ s/√(2n), the normal
    approximation of the χ² interval, for Gaussian data) and, for r, the spread of its influence
    function uv − r(u² + v²)/2 (→ (1 − r²)/√n), carried to Fisher's z = atanh r.
    """

    n_runs: int
    n_partitions: int
    end_poses: FloatArray
    mean: FloatArray
    std: FloatArray
    corr: FloatArray
    mean_se: FloatArray
    std_se: FloatArray
    corr_z_se: FloatArray

    def intervals(
        self, confidence: float = 0.95, *, versus_independent_run: bool = False
    ) -> dict[str, FloatArray]:
        """Two-sided intervals, arrays (3, 2), keyed "mean", "std", "corr".

        With ``versus_independent_run`` the half-widths grow by √2: the range within which
        *another* Monte Carlo estimate of the same size (e.g. the paper's) should fall.
        """
        if not 0.0 < confidence < 1.0:
            raise ValueError(f"confidence must lie in (0, 1), got {confidence!r}")
        z = NormalDist().inv_cdf(0.5 + 0.5 * confidence) * (
            math.sqrt(2.0) if versus_independent_run else 1.0
        )
        fisher = np.arctanh(np.clip(self.corr, -1.0, 1.0))
        return {
            "mean": np.stack([self.mean - z * self.mean_se, self.mean + z * self.mean_se], 1),
            "std": np.stack([self.std - z * self.std_se, self.std + z * self.std_se], 1),
            "corr": np.tanh(
                np.stack([fisher - z * self.corr_z_se, fisher + z * self.corr_z_se], 1)
            ),
        }


def _summarise(poses: FloatArray, n_partitions: int) -> MonteCarloResult:
    n = poses.shape[0]
    mean = poses.mean(axis=0)
    dev = poses - mean
    m2 = (dev**2).mean(axis=0)
    var = m2 * n / (n - 1)
    std = np.sqrt(var)
    with np.errstate(divide="ignore", invalid="ignore"):
        std_se = np.sqrt(np.maximum((dev**4).mean(axis=0) - var**2, 0.0) / n) / (2.0 * std)
        u = dev / np.sqrt(m2)
        corr, corr_z_se = np.empty(3), np.empty(3)
        for k, (i, j) in enumerate(_CORR_PAIRS):
            corr[k] = float(np.mean(u[:, i] * u[:, j]))
            influence = u[:, i] * u[:, j] - 0.5 * corr[k] * (u[:, i] ** 2 + u[:, j] ** 2)
            corr_z_se[k] = float(np.std(influence)) / math.sqrt(n) / (1.0 - corr[k] ** 2)
    return MonteCarloResult(
        n, n_partitions, poses, mean, std, corr, std / math.sqrt(n), std_se, corr_z_se
    )


def _mc_setup(
    left: float, right: float, wheelbase: float, kl: float, kr: float,
    init_cov: ArrayLike | None, n_runs: int, n_partitions: int,
) -> tuple[FloatArray, float, float, float, float]:  # fmt: skip
    """Validate; return the initial-pose factor S (S·Sᵀ = init_cov), steps [m] and noise σ [m]."""
    _check_motion(left, right, wheelbase, kl, kr)
    if isinstance(n_runs, bool) or not isinstance(n_runs, int) or n_runs < 2:
        raise ValueError(f"n_runs must be an integer >= 2, got {n_runs!r}")
    if isinstance(n_partitions, bool) or not isinstance(n_partitions, int) or n_partitions < 1:
        raise ValueError(f"n_partitions must be an integer >= 1, got {n_partitions!r}")
    eigval, eigvec = np.linalg.eigh(_covariance("init_cov", init_cov))
    factor = eigvec * np.sqrt(np.maximum(eigval, 0.0))
    step_l, step_r = left / n_partitions, right / n_partitions
    sd_l, sd_r = kl * math.sqrt(abs(step_l)), kr * math.sqrt(abs(step_r))  # Eq. 4 per partition
    return factor, step_l, step_r, sd_l, sd_r


def monte_carlo(
    left: float,
    right: float,
    wheelbase: float,
    kl: float,
    kr: float,
    init_cov: ArrayLike | None = None,
    n_runs: int = 10_000,
    n_partitions: int = 1000,
    *,
    rng: np.random.Generator,
    chunk_elements: int = 1 << 15,
) -> MonteCarloResult:
    """Simulate the paper's §6.1 experiment, many runs per numpy call.

    Each run draws its start pose from N(0, init_cov) and, per partition of the path, wheel noise
    N(0, k²·|d|/n_partitions) (Eq. 4); each partition is integrated exactly as an arc: with
    h = Δθ/2 its displacement is ds·sinc(h)·e^{i(θ_prev + h)}. Headings are accumulated as unit
    complex numbers (a cumulative product of e^{2ih}), so no trig of large angles is needed.
    Runs go through in chunks of ~``chunk_elements`` partitions (cache-sized buffers, bounded
    memory). Run i consumes 3 + 2·n_partitions standard normals in a row, so the result does not
    depend on the chunking and matches :func:`monte_carlo_loop` for the same generator state.
    """
    factor, step_l, step_r, sd_l, sd_r = _mc_setup(
        left, right, wheelbase, kl, kr, init_cov, n_runs, n_partitions
    )
    p, b = n_partitions, wheelbase
    chunk = max(1, min(n_runs, chunk_elements // p))
    z = np.empty((chunk, 3 + 2 * p))
    ds, work, half = np.empty((chunk, p)), np.empty((chunk, p)), np.empty((chunk, p))
    nonzero = np.empty((chunk, p), dtype=bool)
    rot, phase = np.empty((chunk, p), dtype=complex), np.empty((chunk, p), dtype=complex)
    poses = np.empty((n_runs, 3))
    for first in range(0, n_runs, chunk):
        m = min(chunk, n_runs - first)
        zm, dm, wm, hm, rm, pm = (a[:m] for a in (z, ds, work, half, rot, phase))
        nz = nonzero[:m]
        rng.standard_normal(out=zm)
        np.multiply(zm[:, 3 : 3 + p], sd_l / (2 * b), out=dm)  # left noise / 2B
        np.multiply(zm[:, 3 + p :], sd_r / (2 * b), out=wm)  # right noise / 2B
        np.subtract(wm, dm, out=hm)
        hm += (step_r - step_l) / (2 * b)  # h = Δθ/2 = (d_R − d_L)/2B
        np.add(dm, wm, out=dm)
        dm *= b
        dm += 0.5 * (step_l + step_r)  # ds = (d_L + d_R)/2
        np.sin(hm, out=rm.imag)
        if -1.5 < hm.min() and hm.max() < 1.5:  # cos h = √(1 − sin²h), cheaper than cos
            np.multiply(rm.imag, rm.imag, out=wm)
            np.subtract(1.0, wm, out=wm)
            np.sqrt(wm, out=rm.real)
        else:
            np.cos(hm, out=rm.real)
        np.not_equal(hm, 0.0, out=nz)
        np.divide(rm.imag, hm, out=wm, where=nz)
        if not nz.all():
            np.copyto(wm, 1.0, where=~nz)  # sinc(0) = 1
        dm *= wm  # chord length ds·sinc(h)
        pm[:, 0] = 1.0
        np.multiply(rm[:, :-1], rm[:, :-1], out=pm[:, 1:])  # e^{2ih} = e^{iΔθ}
        np.cumprod(pm[:, 1:], axis=1, out=pm[:, 1:])  # e^{iθ_prev}, relative to the start
        pm *= rm  # e^{i(θ_prev + h)}
        x0, y0, th0 = (zm[:, :3] @ factor.T).T
        dx, dy = np.einsum("ij,ij->i", dm, pm.real), np.einsum("ij,ij->i", dm, pm.imag)
        cos0, sin0 = np.cos(th0), np.sin(th0)
        poses[first : first + m, 0] = x0 + cos0 * dx - sin0 * dy
        poses[first : first + m, 1] = y0 + sin0 * dx + cos0 * dy
        poses[first : first + m, 2] = th0 + 2.0 * hm.sum(axis=1)
    return _summarise(poses, p)


def monte_carlo_loop(
    left: float,
    right: float,
    wheelbase: float,
    kl: float,
    kr: float,
    init_cov: ArrayLike | None = None,
    n_runs: int = 10_000,
    n_partitions: int = 1000,
    *,
    rng: np.random.Generator,
) -> MonteCarloResult:
    """The same simulation as :func:`monte_carlo`, one run and one partition at a time.

    Plain Python, the straightforward way; kept only as the baseline of the speed benchmark and
    as an independent check of the vectorised integration.
    """
    factor, step_l, step_r, sd_l, sd_r = _mc_setup(
        left, right, wheelbase, kl, kr, init_cov, n_runs, n_partitions
    )
    p = n_partitions
    poses = np.empty((n_runs, 3))
    for run in range(n_runs):
        z = rng.standard_normal(3 + 2 * p)
        x, y, th = (float(v) for v in factor @ z[:3])
        noise = z.tolist()
        for i in range(p):
            d_l = noise[3 + i] * sd_l + step_l
            d_r = noise[3 + p + i] * sd_r + step_r
            half = (d_r - d_l) / (2.0 * wheelbase)
            ds = 0.5 * (d_l + d_r) * (math.sin(half) / half if half != 0.0 else 1.0)
            x += ds * math.cos(th + half)
            y += ds * math.sin(th + half)
            th += 2.0 * half
        poses[run] = (x, y, th)
    return _summarise(poses, p)


# ----------------------------------------------------------------------------- reports
def _num(value: float) -> float | None:
    """A JSON-safe float: None for NaN/inf (e.g. a correlation with a zero σ)."""
    return float(value) if math.isfinite(value) else None


def _stats_dict(mean: FloatArray, std: FloatArray, corr: FloatArray) -> dict[str, Any]:
    return {
        "mean": {"x_m": _num(mean[0]), "y_m": _num(mean[1]),
                 "theta_rad": _num(mean[2] % (2 * math.pi)), "heading_change_rad": _num(mean[2])},
        "std": {"x_m": _num(std[0]), "y_m": _num(std[1]), "theta_rad": _num(std[2])},
        "corr": {"x_theta": _num(corr[0]), "y_theta": _num(corr[1]), "x_y": _num(corr[2])},
    }  # fmt: skip


def covariance_report(
    left: float,
    right: float,
    wheelbase: float,
    kl: float,
    kr: float,
    init_std: Sequence[float] = (0.0, 0.0, 0.0),
    montecarlo_runs: int = 0,
    partitions: int = 1000,
    rng: np.random.Generator | int | None = None,
    confidence: float = 0.95,
) -> dict[str, Any]:
    """Theory (and optionally Monte Carlo) for one arc from the origin, as a JSON-ready dict.

    ``init_std`` = (σ_x [m], σ_y [m], σ_θ [rad]) of the start pose (independent). The mean
    heading ``theta_rad`` is wrapped into [0, 2π) as in the paper's tables; the unwrapped value
    is ``heading_change_rad``. Correlations are fractions; undefined values are ``None``.
    ``rng`` may be a Generator or a seed; ``None`` seeds from the OS.
    """
    _check_motion(left, right, wheelbase, kl, kr)
    if len(init_std) != 3:
        raise ValueError(f"init_std must have 3 entries (x, y, theta), got {init_std!r}")
    sigma = [_nonnegative(f"init_std[{i}]", v) for i, v in enumerate(init_std)]
    if isinstance(montecarlo_runs, bool) or not isinstance(montecarlo_runs, int):
        raise ValueError(f"montecarlo_runs must be an integer, got {montecarlo_runs!r}")
    if montecarlo_runs != 0 and montecarlo_runs < 2:
        raise ValueError(f"montecarlo_runs must be 0 or >= 2, got {montecarlo_runs!r}")
    init_cov = np.diag(np.square(sigma))
    theory = propagate_segment(origin(init_cov), left, right, wheelbase, kl, kr)
    report: dict[str, Any] = {
        "model": "Chong & Kleeman 1997, Eqs. 14, 23, 25-28",
        "inputs": {"left_m": float(left), "right_m": float(right),
                   "wheelbase_m": float(wheelbase), "kl_sqrt_m": float(kl), "kr_sqrt_m": float(kr),
                   "init_std": sigma},
        "theory": _stats_dict(theory.mean, theory.std, theory.corr)
        | {"covariance": theory.cov.tolist()},
        "simulation": None,
    }  # fmt: skip
    if montecarlo_runs:
        generator = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        mc = monte_carlo(left, right, wheelbase, kl, kr, init_cov, montecarlo_runs, partitions,
                         rng=generator)  # fmt: skip
        ci = mc.intervals(confidence)
        ci["mean"][2] = ci["mean"][2] - (mc.mean[2] - mc.mean[2] % (2 * math.pi))
        report["simulation"] = _stats_dict(mc.mean, mc.std, mc.corr) | {
            "runs": montecarlo_runs, "partitions": partitions, "confidence": confidence,
            "interval": {key: [[_num(v) for v in row] for row in value]
                         for key, value in ci.items()},
        }  # fmt: skip
    return report


_ROWS = (
    ("mean x (m)", "mean", "x_m", 1.0),
    ("mean y (m)", "mean", "y_m", 1.0),
    ("mean θ (rad)", "mean", "theta_rad", 1.0),
    ("stddev x (m)", "std", "x_m", 1.0),
    ("stddev y (m)", "std", "y_m", 1.0),
    ("stddev θ (rad)", "std", "theta_rad", 1.0),
    ("corr xθ (%)", "corr", "x_theta", 100.0),
    ("corr yθ (%)", "corr", "y_theta", 100.0),
    ("corr xy (%)", "corr", "x_y", 100.0),
)


def format_report(report: dict[str, Any]) -> str:
    """Text in the layout of the paper's Tables 1–7: theory and simulation columns."""

    def cell(value: float | None, scale: float) -> str:
        return "—" if value is None else f"{value * scale:.6g}"

    inp, sim = report["inputs"], report["simulation"]
    lines = [
        f"L={inp['left_m']:g} m, R={inp['right_m']:g} m, B={inp['wheelbase_m']:g} m, "
        f"k_L={inp['kl_sqrt_m']:g} m^1/2, k_R={inp['kr_sqrt_m']:g} m^1/2, "
        "[σx σy σθ]₀=[{:g} m {:g} m {:g} rad]".format(*inp["init_std"]),
        f"{'':16}{'Theory':>14}"
        + (f"{'Simul':>14}  {sim['confidence']:.0%} interval" if sim else ""),
    ]
    for k, (label, group, key, scale) in enumerate(_ROWS):
        row = f"{label:16}{cell(report['theory'][group][key], scale):>14}"
        if sim:
            low, high = sim["interval"][group][k % 3]
            row += f"{cell(sim[group][key], scale):>14}  [{cell(low, scale)}, {cell(high, scale)}]"
        lines.append(row)
    if sim:
        lines.append(f"Monte Carlo: {sim['runs']} runs, {sim['partitions']} partitions per path")
    return "\n".join(lines)

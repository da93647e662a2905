"""Estimating wheel-noise constants k_L, k_R [m^½] from repeated runs (Chong & Kleeman 1997, §6.3).

Why: Chong & Kleeman's model gives each wheel's travel d white noise of variance k²·|d| (Eq. 4).
They chose k_L, k_R "by trial and error" from 60 runs of 10 m forward and 10 m back and found no
pair that reproduced all six elements of the measured covariance, the off-track y fitting worst
(Fig. 4). Here that fit is a maximum-likelihood estimate with intervals and a per-component
goodness of fit, so such statements can be checked on any set of runs.

**Model.** A run's end-pose error ε = true − odometry (x [m], y [m], θ [rad] in the run's start
frame, as :func:`odomgym.odometry.runs.return_error`) is zero-mean Gaussian with covariance

    Σ = k_L²·A + k_R²·B      (Eq. 23 over the whole run; A, B = Σ at (k_L, k_R) = (1, 0), (0, 1)),

since every segment's Cov(U_k) (Eqs. 25–28), and so their composition, is linear in k_L², k_R².
A and B come from the run's *own* odometry path: each sample's wheel travels (encoder counts ×
metres per tick, calibrated) form one constant-curvature segment (:func:`run_noise_basis`).

**Systematic errors.** Eq. 4 has zero mean; a real robot's residual calibration error does not.
With ``systematic="group-mean"`` (default) runs are grouped — same session, path and turning
direction, hence the same systematic error — and only within-group contrasts enter the
likelihood (restricted maximum likelihood, REML): an error common to a group cancels exactly,
whatever its size. Consequences: a group of n runs yields 3(n − 1) observations, not 3n, and a
systematic error that changes *from run to run* (drift, battery, slightly different paths) is
not removed but charged to k. ``systematic="none"`` takes the odometry as calibrated.

**Intervals.** Profile likelihood by default (deterministic; asymptotically exact *if the model
is right*), or a percentile bootstrap over runs resampled within their groups
(``interval="bootstrap"``, explicit generator), which stays honest when the component fit shows
the model is wrong.

**Validity.** Eq. 23 is first order. On 10 m out and back at k = 0.002 m^½ (σ_θ ≈ 2° at the end)
the along-track error gains the second-order shortening −½∫δθ² ds, which Σ lacks: measured over
12 seeds of 60 simulated runs, the x variance then exceeds the fitted prediction 1.4-fold and k
comes out 10–17 % high (interval coverage 50–75 %). At the paper's k ≈ 0.0005 m^½ the estimates
are unbiased to 1–5 % with ~90 % coverage of the 95 % intervals. With unequal k the quieter
wheel's estimate, which rests on the x–θ covariance, absorbs the excess first: +5 % at
k_L, k_R = 0.0002, 0.0006 m^½, +12 % at 0.0003, 0.0009 (``tests/test_noise_fit.py``).

Simulated experiments, recorded sessions, the report and the Fig. 4 plot are in
:mod:`odomgym.noise.experiment`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy import optimize, stats

from odomgym.noise.covariance import propagate_path
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run, require_differential, return_error, wheel_travels
from odomgym.robot import RobotSpec

__all__ = [
    "MIN_RUNS",
    "ComponentFit",
    "NoiseFit",
    "NoiseSamples",
    "check_noise_run",
    "fit_noise",
    "noise_samples",
    "run_noise_basis",
]

FloatArray = NDArray[np.float64]
Systematic = Literal["group-mean", "none"]
IntervalMethod = Literal["profile", "bootstrap"]

MIN_RUNS = 5
"""Fewest runs (after removing group means: contrasts + 1) a fit accepts; below this the
covariance of three components cannot even be estimated."""

ROUND_OFF = 1e-9
"""Residuals (errors less their group means) no larger than this fraction of the largest error
are round-off: the runs did not differ (a floor without noise), so the fit's checks against
the model are undefined (:class:`ComponentFit`)."""

COMPONENTS = (("x", "m"), ("y", "m"), ("theta", "rad"))
_QUAD_NODES = 16  # exact to round-off for |Δθ| ≲ 1 rad per sample (covariance.py)
_MAX_SAMPLE_TURN = 1.0  # [rad]; samples turning more go through propagate_path instead


# ----------------------------------------------------------------------------- per-run inputs
def check_noise_run(run: Run, travels: FloatArray) -> None:
    """Refuse a run a noise fit or simulation cannot use (ValueError naming its source):
    non-finite time or poses, non-finite wheel ``travels`` (T − 1, 2) [m], or no motion."""
    for name, values in (("time", run.time), ("true_pose", run.true_pose)):
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{run.source}: run has non-finite (NaN/inf) values in {name}")
    if not np.all(np.isfinite(travels)):
        raise ValueError(f"{run.source}: wheel travels are not finite (robot or calibration?)")
    if not np.abs(travels).sum() > 0.0:
        raise ValueError(f"{run.source}: run has zero length (no encoder counts changed)")


def _path_basis(travels: FloatArray, wheelbase: float) -> tuple[FloatArray, FloatArray]:
    """A, B of one path: Σ_k F_k·Cov(U_k)·F_kᵀ for k = (1, 0) and (0, 1), vectorised.

    Same quantities as :func:`odomgym.noise.covariance.propagate_path`: the product of the Eq. 21
    start Jacobians from the end of segment k to the end of the path is the shear
    [[1, 0, −(y_N − y_k)], [0, 1, x_N − x_k], [0, 0, 1]], and each segment's Cov(U_k) is the
    Gauss–Legendre form of Eqs. 23–24
    (:func:`odomgym.noise.covariance.quadrature_motion_covariance`, exact to round-off for
    per-sample turns below 1 rad).
    """
    left, right = travels[:, 0], travels[:, 1]
    dtheta = (right - left) / wheelbase
    heading0 = np.concatenate([[0.0], np.cumsum(dtheta)[:-1]])
    chord = 0.5 * (left + right) * np.sinc(0.5 * dtheta / math.pi)
    mid = heading0 + 0.5 * dtheta
    x_end, y_end = np.cumsum(chord * np.cos(mid)), np.cumsum(chord * np.sin(mid))
    u, w = np.polynomial.legendre.leggauss(_QUAD_NODES)
    s, w = 0.5 * (u + 1.0), 0.5 * w
    theta = heading0[:, None] + s * dtheta[:, None]  # (K, nodes)
    rest = 0.5 * dtheta[:, None] * (1.0 - s)
    arm = 0.5 * (left + right)[:, None] / wheelbase * (1.0 - s) * np.sinc(rest / math.pi)
    a = np.stack([0.5 * np.cos(theta), 0.5 * np.sin(theta), np.zeros_like(theta)], axis=-1)
    q = np.stack(
        [arm * np.sin(theta + rest), -arm * np.cos(theta + rest), np.full_like(theta, -1.0)],
        axis=-1,
    )
    q[..., 2] /= wheelbase
    shear = np.zeros((len(left), 3, 3))
    shear[:, 0, 0] = shear[:, 1, 1] = shear[:, 2, 2] = 1.0
    shear[:, 0, 2] = -(y_end[-1] - y_end)
    shear[:, 1, 2] = x_end[-1] - x_end
    out = []
    for jac, travel in ((a + q, left), (a - q, right)):  # J_L = a + q, J_R = a − q (Eq. 24)
        moved = np.einsum("kij,knj->kni", shear, jac)  # F_k · J(s)
        out.append(np.einsum("k,n,kni,knj->ij", np.abs(travel), w, moved, moved))
    return out[0], out[1]


def run_noise_basis(
    run: Run,
    robot: RobotSpec,
    calibration: Calibration | None = None,
    *,
    method: Literal["vectorised", "propagate_path"] = "vectorised",
) -> tuple[FloatArray, FloatArray]:
    """A, B (3×3 each; Σ's units [m², m·rad, rad²] per metre of k²) with Σ = k_L²·A + k_R²·B.

    The odometry path is the run's encoder counts under ``robot``'s nominal parameters and
    ``calibration``, one segment per sample. ``method="propagate_path"`` runs
    :func:`odomgym.noise.covariance.propagate_path` with (k_L, k_R) = (1, 0) and (0, 1) (the
    reference, ~50 µs per sample); the default computes the same sums in numpy (see
    :func:`_path_basis`), ~50× faster, and falls back to the reference for samples that turn
    more than 1 rad.
    """
    require_differential(calibration, "Chong & Kleeman's covariance")
    cal = calibration if calibration is not None else Calibration()
    travels, wheelbase = wheel_travels(run, robot, cal)
    check_noise_run(run, travels)
    if method == "vectorised" and np.abs(np.diff(travels, axis=1)).max() / wheelbase < (
        _MAX_SAMPLE_TURN
    ):
        return _path_basis(travels, wheelbase)
    segments = [(float(left), float(right)) for left, right in travels]
    return (
        propagate_path(segments, wheelbase, 1.0, 0.0).cov,
        propagate_path(segments, wheelbase, 0.0, 1.0).cov,
    )


@dataclass(frozen=True)
class NoiseSamples:
    """What the fit needs from n runs.

    Attributes:
        errors: (n, 3) end-pose errors true − odometry in each run's start frame [m, m, rad].
        basis_left, basis_right: (n, 3, 3) A and B of each run (Σ = k_L²·A + k_R²·B).
        groups: a label per run; runs sharing a label share one systematic error.
        sources: where each run came from, for messages.
    """

    errors: FloatArray
    basis_left: FloatArray
    basis_right: FloatArray
    groups: tuple[str, ...]
    sources: tuple[str, ...]

    def __post_init__(self) -> None:
        n = len(self.errors)
        shapes = (self.errors.shape, self.basis_left.shape, self.basis_right.shape)
        if shapes != ((n, 3), (n, 3, 3), (n, 3, 3)) or len(self.groups) != n:
            raise ValueError(f"inconsistent sample arrays: {shapes}, {len(self.groups)} groups")
        finite = np.asarray(np.isfinite(self.errors).all(axis=1), dtype=bool).tolist()
        if not all(finite):
            bad = ", ".join(s for s, ok in zip(self.sources, finite, strict=True) if not ok)
            raise ValueError(f"non-finite (NaN/inf) errors in runs {bad}")

    @property
    def n_runs(self) -> int:
        """Number of runs n."""
        return len(self.errors)

    def select(self, keep: Sequence[bool]) -> NoiseSamples:
        """The runs where ``keep`` is true."""
        mask = np.asarray(keep, dtype=bool)
        return NoiseSamples(
            self.errors[mask],
            self.basis_left[mask],
            self.basis_right[mask],
            tuple(g for g, k in zip(self.groups, mask, strict=True) if k),
            tuple(s for s, k in zip(self.sources, mask, strict=True) if k),
        )

    def __add__(self, other: NoiseSamples) -> NoiseSamples:
        """Pool two sets of runs (e.g. several sessions); groups keep their labels."""
        return NoiseSamples(
            np.concatenate([self.errors, other.errors]),
            np.concatenate([self.basis_left, other.basis_left]),
            np.concatenate([self.basis_right, other.basis_right]),
            self.groups + other.groups,
            self.sources + other.sources,
        )


def noise_samples(
    runs: Sequence[Run],
    robot: RobotSpec,
    calibration: Calibration | None = None,
    *,
    group: str | Sequence[str] | Callable[[Run], str] = "all",
) -> NoiseSamples:
    """Errors and bases of ``runs`` under ``robot``'s nominal parameters and ``calibration``.

    ``group`` labels runs that share a systematic error: one label for all, one per run, or a
    function of the run (e.g. by direction). Raises ValueError for an empty list, non-finite
    values or a run of zero length, naming the run.
    """
    if not runs:
        raise ValueError("no runs given")
    labels = (
        [group] * len(runs)
        if isinstance(group, str)
        else [group(r) for r in runs]
        if callable(group)
        else list(group)
    )
    if len(labels) != len(runs):
        raise ValueError(f"{len(labels)} group labels for {len(runs)} runs")
    errors, lefts, rights = [], [], []
    for run in runs:
        basis_left, basis_right = run_noise_basis(run, robot, calibration)  # checks the run
        errors.append(return_error(run, robot, calibration, frame="start"))
        lefts.append(basis_left)
        rights.append(basis_right)
    return NoiseSamples(
        np.array(errors),
        np.array(lefts),
        np.array(rights),
        tuple(labels),
        tuple(r.source for r in runs),
    )


# ----------------------------------------------------------------------------- likelihood
@dataclass(frozen=True)
class _Design:
    """The runs of one fit: errors, bases, and (for REML) which group each run is in."""

    errors: FloatArray  # (n, 3)
    basis_left: FloatArray  # (n, 3, 3)
    basis_right: FloatArray
    membership: FloatArray | None  # (G, n) one-hot, or None for systematic="none"
    n_obs: int  # 3·(n − G), or 3·n
    constant: float  # Σ_g 3·log n_g (REML's log det XᵀX), or 0


def _design(samples: NoiseSamples, index: NDArray[np.intp], systematic: Systematic) -> _Design:
    errors = samples.errors[index]
    if systematic == "none":
        return _Design(errors, samples.basis_left[index], samples.basis_right[index], None,
                       3 * len(index), 0.0)  # fmt: skip
    labels = [samples.groups[i] for i in index]
    names = list(dict.fromkeys(labels))
    membership = np.array([[lab == name for lab in labels] for name in names], dtype=float)
    sizes = membership.sum(axis=1)
    return _Design(errors, samples.basis_left[index], samples.basis_right[index], membership,
                   3 * (len(index) - len(names)), 3.0 * float(np.log(sizes).sum()))  # fmt: skip


def _terms(design: _Design, k2_left: float, k2_right: float) -> tuple[float, float]:
    """(log det, quadratic form) of the (restricted) Gaussian likelihood; (inf, inf) where a
    run's Σ is singular.

    With group means removed this is REML: for contrasts z = K·ε with K·X = 0 (X stacks one
    3×3 identity per run of a group), log det(KΣKᵀ) = Σ log det Σ_i + Σ_g log det(Σ_i∈g Σ_i⁻¹)
    − Σ_g 3·log n_g, and zᵀ(KΣKᵀ)⁻¹z = Σ εᵢᵀΣᵢ⁻¹εᵢ − Σ_g t_gᵀ(Σ_i∈g Σ_i⁻¹)⁻¹t_g with
    t_g = Σ_i∈g Σᵢ⁻¹εᵢ: the residuals about the generalised-least-squares group mean. Only 3×3
    matrices are ever factorised, however many runs a group holds.
    """
    sigma = k2_left * design.basis_left + k2_right * design.basis_right
    try:
        chol = np.linalg.cholesky(sigma)
    except np.linalg.LinAlgError:
        return math.inf, math.inf
    logdet = 2.0 * float(np.log(np.diagonal(chol, axis1=1, axis2=2)).sum())
    precision = np.linalg.inv(sigma)
    weighted = np.einsum("nij,nj->ni", precision, design.errors)
    quad = float(np.einsum("ni,ni->", weighted, design.errors))
    if design.membership is not None:
        info = np.einsum("gn,nij->gij", design.membership, precision)
        total = design.membership @ weighted
        sign, group_logdet = np.linalg.slogdet(info)
        if not np.all(sign > 0):
            return math.inf, math.inf
        logdet += float(group_logdet.sum()) - design.constant
        quad -= float(np.einsum("gi,gi->", total, np.linalg.solve(info, total[..., None])[..., 0]))
    return logdet, quad


def _log_likelihood(design: _Design, k2_left: float, k2_right: float) -> float:
    """Gaussian log-likelihood of the contrasts (REML when they are within-group contrasts);
    −inf where the covariance is singular (e.g. k_L = 0 on straight runs)."""
    n_obs = design.n_obs
    logdet, quad = _terms(design, k2_left, k2_right)
    if not math.isfinite(logdet):
        return -math.inf
    return -0.5 * (logdet + quad + n_obs * math.log(2.0 * math.pi))


def _mle(design: _Design) -> tuple[float, float, float]:
    """(k_L², k_R², log-likelihood) maximised over k² ≥ 0.

    Parametrised as k_L² = λ·u, k_R² = λ·(1 − u): for fixed u, ℓ = −½(N·log λ + log det S_u +
    Q_u/λ + N·log 2π) is maximal at λ = Q_u/N (N observations), which leaves a bounded search
    over u ∈ [0, 1] — no starting values or scales to guess.
    """
    n_obs = design.n_obs

    def profile(u: float) -> tuple[float, float]:
        logdet, quad = _terms(design, u, 1.0 - u)
        if not (math.isfinite(logdet) and quad > 0.0):
            return -math.inf, 0.0
        lam = quad / n_obs
        return -0.5 * (n_obs * math.log(lam) + logdet + n_obs * (1.0 + math.log(2 * math.pi))), lam

    grid = np.linspace(0.0, 1.0, 41)
    values = [profile(float(u))[0] for u in grid]
    best = int(np.argmax(values))
    if not math.isfinite(values[best]):
        raise ValueError("the errors are degenerate under every k_L/k_R split (all zero?)")
    low, high = float(grid[max(best - 1, 0)]), float(grid[min(best + 1, len(grid) - 1)])
    # Where the likelihood is degenerate beside the best split (errors at round-off, as with
    # no noise at all) the objective is +inf there, and Brent's parabolic step computes inf −
    # inf: it then takes a golden-section step, as wanted, but numpy warned on the terminal.
    with np.errstate(invalid="ignore", over="ignore"):
        res = optimize.minimize_scalar(
            lambda u: -profile(u)[0],
            bounds=(low, high),
            method="bounded",
            options={"xatol": 1e-10},
        )
    u = float(res.x) if -float(res.fun) >= values[best] else float(grid[best])
    ell, lam = profile(u)
    return lam * u, lam * (1.0 - u), ell


def _profile_interval(
    design: _Design, estimate: tuple[float, float, float], which: int, confidence: float
) -> tuple[float, float]:
    """Profile-likelihood interval of k_L² (``which`` = 0) or k_R² (1): where
    2·(ℓ̂ − max over the other k² of ℓ) stays below the χ²₁ quantile."""
    best = estimate[2]
    limit = 0.5 * float(stats.chi2.ppf(confidence, 1))
    scale = estimate[0] + estimate[1]

    def deficit(value: float) -> float:
        def neg(other: float) -> float:
            pair = (value, other) if which == 0 else (other, value)
            ell = _log_likelihood(design, *pair)
            return -ell if math.isfinite(ell) else 1e300

        hi = 4.0 * scale + value
        res = optimize.minimize_scalar(neg, bounds=(0.0, hi), method="bounded",
                                       options={"xatol": 1e-9 * scale})  # fmt: skip
        ell = min(float(res.fun), neg(0.0))
        return best - (-ell) - limit

    centre = estimate[which]
    floor = 1e-9 * scale
    lower = floor if deficit(floor) <= 0.0 else optimize.brentq(
        deficit, floor, max(centre, floor * 2), xtol=1e-12 * scale
    )  # fmt: skip
    step, upper = max(centre, 0.1 * scale), centre
    for _ in range(60):
        upper = centre + step
        if deficit(upper) > 0.0:
            break
        step *= 2.0
    upper = optimize.brentq(deficit, max(centre, floor), upper, xtol=1e-12 * scale)
    return (0.0 if lower <= floor else float(lower)), float(upper)


# ----------------------------------------------------------------------------- the fit
@dataclass(frozen=True)
class ComponentFit:
    """How well the fitted model predicts one error component.

    Attributes:
        name, unit: ``"x"``/``"y"`` [m] or ``"theta"`` [rad].
        measured_var: pooled variance of the residuals (errors less group means) [unit²].
        predicted_var: what the fitted Σ predicts for that pooled variance [unit²].
        ratio: measured_var / predicted_var (1 = perfect; > 1: the model under-predicts).
        chi2, dof: Σ zᵀC⁻¹z over this component's contrasts, χ²-distributed with ``dof``
            degrees of freedom if the model is right (ignoring that k was fitted).
        p_value: two-sided p of ``chi2``: 2·min(P(χ²_dof ≥ chi2), P(χ²_dof ≤ chi2)); small
            values flag a component the model over- (ratio < 1) or under-predicts (> 1).

    ``ratio``, ``chi2`` and ``p_value`` are NaN (``null`` in JSON, n/a in the table) when the
    runs did not differ (:data:`ROUND_OFF`): with no noise the fitted k is round-off, and
    they compared round-off with round-off — negative χ² and p = 0, a false misfit.
    """

    name: str
    unit: str
    measured_var: float
    predicted_var: float
    ratio: float
    chi2: float
    dof: int
    p_value: float


@dataclass(frozen=True)
class NoiseFit:
    """k_L, k_R [m^½] with intervals, and the fit's diagnostics.

    ``measured_cov`` and ``predicted_cov`` (3×3, [m², m·rad, rad²]) are pooled over the runs in
    the same way (residual outer products over the residual degrees of freedom, and the
    model's expectation of that average); ``residuals`` (n, 3) are the errors less their group
    means (or the errors, with ``systematic="none"``).
    """

    k_left: float
    k_right: float
    k_left_interval: tuple[float, float]
    k_right_interval: tuple[float, float]
    confidence: float
    interval_method: IntervalMethod
    systematic: Systematic
    n_runs: int
    n_groups: int
    dof: int
    log_likelihood: float
    chi2_total: float
    components: tuple[ComponentFit, ...]
    measured_cov: FloatArray
    predicted_cov: FloatArray
    residuals: FloatArray

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe summary (no per-run arrays)."""
        return {
            "k_left_sqrt_m": self.k_left,
            "k_right_sqrt_m": self.k_right,
            "k_left_interval": list(self.k_left_interval),
            "k_right_interval": list(self.k_right_interval),
            "confidence": self.confidence,
            "interval_method": self.interval_method,
            "systematic": self.systematic,
            "runs": self.n_runs,
            "groups": self.n_groups,
            "dof": self.dof,
            "log_likelihood": self.log_likelihood,
            "chi2_total": self.chi2_total,
            "components": [vars(c) for c in self.components],
            "measured_cov": self.measured_cov.tolist(),
            "predicted_cov": self.predicted_cov.tolist(),
            "measured_corr": _corr(self.measured_cov),
            "predicted_corr": _corr(self.predicted_cov),
        }


def _corr(cov: FloatArray) -> dict[str, float | None]:
    std = np.sqrt(np.diag(cov))
    out: dict[str, float | None] = {}
    for key, (i, j) in (("x_y", (0, 1)), ("x_theta", (0, 2)), ("y_theta", (1, 2))):
        value = cov[i, j] / (std[i] * std[j]) if std[i] * std[j] > 0 else math.nan
        out[key] = float(value) if math.isfinite(value) else None
    return out


def _group_index(samples: NoiseSamples, systematic: Systematic) -> list[NDArray[np.intp]]:
    groups: dict[str, list[int]] = {}
    for i, label in enumerate(samples.groups):
        groups.setdefault(label, []).append(i)
    index = [np.array(v, dtype=np.intp) for v in groups.values()]
    if systematic == "group-mean":
        lonely = [label for label, v in groups.items() if len(v) < 2]
        if lonely:
            raise ValueError(
                f"groups with a single run carry no information once their mean is removed: "
                f"{', '.join(lonely)} (pool them with others, or use systematic='none')"
            )
    dof = samples.n_runs - (len(index) if systematic == "group-mean" else 0)
    if dof < MIN_RUNS - 1 or samples.n_runs < MIN_RUNS:
        raise ValueError(
            f"too few runs: {samples.n_runs} runs in {len(index)} groups leave {dof} independent "
            f"errors; the fit needs at least {MIN_RUNS} runs and {MIN_RUNS - 1} independent "
            "errors (runs minus groups when group means are removed)"
        )
    return index


def _diagnostics(
    samples: NoiseSamples, index: list[NDArray[np.intp]], systematic: Systematic,
    k2_left: float, k2_right: float,
) -> tuple[tuple[ComponentFit, ...], FloatArray, FloatArray, FloatArray, int]:  # fmt: skip
    """Per-component fit, pooled measured and predicted covariances, residuals, dof.

    Residuals about the plain group mean have E[Σ rrᵀ] = Σ_i (1 − 1/n_g)·Σ_i, which is the
    prediction; χ² per component uses the scalar form of :func:`_terms` (GLS group mean).
    """
    sigma = k2_left * samples.basis_left + k2_right * samples.basis_right  # (n, 3, 3)
    residuals = samples.errors.copy()
    predicted, chi2, dof = np.zeros((3, 3)), np.zeros(3), 0
    for members in index:
        var = np.diagonal(sigma[members], axis1=1, axis2=2)  # (m, 3)
        err = samples.errors[members]
        chi2 += (err**2 / var).sum(axis=0)
        if systematic == "group-mean":
            residuals[members] -= err.mean(axis=0)
            chi2 -= (err / var).sum(axis=0) ** 2 / (1.0 / var).sum(axis=0)
            predicted += (1.0 - 1.0 / len(members)) * sigma[members].sum(axis=0)
            dof += len(members) - 1
        else:
            predicted += sigma[members].sum(axis=0)
            dof += len(members)
    measured = residuals.T @ residuals / dof
    predicted /= dof
    silent = not np.abs(residuals).max() > ROUND_OFF * np.abs(samples.errors).max()
    components = []
    for j, (name, unit) in enumerate(COMPONENTS):
        if silent:  # no spread to test: the checks are undefined (ComponentFit)
            ratio = chi2_j = p_value = math.nan
        else:
            upper = float(stats.chi2.sf(chi2[j], dof))
            ratio, chi2_j = float(measured[j, j] / predicted[j, j]), float(chi2[j])
            p_value = min(1.0, 2.0 * min(upper, 1.0 - upper))
        components.append(
            ComponentFit(name, unit, float(measured[j, j]), float(predicted[j, j]), ratio,
                         chi2_j, dof, p_value)
        )  # fmt: skip
    return tuple(components), measured, predicted, residuals, dof


def _bootstrap_interval(
    samples: NoiseSamples, residuals: FloatArray, index: list[NDArray[np.intp]],
    systematic: Systematic, confidence: float, rng: np.random.Generator, n_bootstrap: int,
) -> list[tuple[float, float]]:  # fmt: skip
    """Percentile intervals of k_L², k_R² over refits on runs resampled within their groups.

    With group means removed, a run is resampled as its residual (error less group mean) ×
    √(n_g/(n_g − 1)), with its own A, B: resampling n_g residuals with replacement and removing
    their mean again shrinks the spread by (n_g − 1)/n_g on average, which would bias the
    intervals low for the small groups of recorded sessions (3 runs: by a third).
    """
    errors = samples.errors
    if systematic == "group-mean":
        errors = residuals.copy()
        for members in index:
            errors[members] *= math.sqrt(len(members) / (len(members) - 1))
    draws = []
    for _ in range(n_bootstrap):
        pick = np.concatenate([rng.choice(m, size=len(m)) for m in index])
        resampled = NoiseSamples(errors[pick], samples.basis_left[pick],
                                 samples.basis_right[pick], tuple(samples.groups[i] for i in pick),
                                 tuple(samples.sources[i] for i in pick))  # fmt: skip
        try:
            draws.append(_mle(_design(resampled, np.arange(len(pick)), systematic))[:2])
        except ValueError:  # every group drew copies of one run: no spread to fit
            continue
    if len(draws) < n_bootstrap // 2:
        raise ValueError(f"only {len(draws)} of {n_bootstrap} bootstrap refits succeeded")
    tail = 50.0 * (1.0 - confidence)
    qs = np.percentile(draws, [tail, 100.0 - tail], axis=0)
    return [(float(qs[0, w]), float(qs[1, w])) for w in (0, 1)]


def fit_noise(
    samples: NoiseSamples,
    *,
    systematic: Systematic = "group-mean",
    confidence: float = 0.95,
    interval: IntervalMethod = "profile",
    rng: np.random.Generator | None = None,
    n_bootstrap: int = 200,
) -> NoiseFit:
    """Maximum-likelihood k_L, k_R [m^½] (Chong & Kleeman 1997, Eq. 4) from the runs in ``samples``.

    See the module docstring for the model and the two ways of treating systematic errors.
    ``interval="profile"``: the set of k² whose profile log-likelihood lies within
    χ²₁(confidence)/2 of the maximum (reported as k = √k²; clipped at 0). ``"bootstrap"``:
    percentile interval of ``n_bootstrap`` refits on runs resampled with replacement within
    each group, drawn from ``rng`` (required).

    Raises:
        ValueError: fewer than :data:`MIN_RUNS` runs (or independent errors), a group of one
            run under ``"group-mean"``, a bad option, or degenerate (all-zero) errors.
    """
    if systematic not in ("group-mean", "none"):
        raise ValueError(f"systematic must be 'group-mean' or 'none', got {systematic!r}")
    if interval not in ("profile", "bootstrap"):
        raise ValueError(f"interval must be 'profile' or 'bootstrap', got {interval!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence!r}")
    index = _group_index(samples, systematic)
    design = _design(samples, np.arange(samples.n_runs), systematic)
    estimate = _mle(design)
    components, measured, predicted, residuals, dof = _diagnostics(
        samples, index, systematic, estimate[0], estimate[1]
    )
    if interval == "profile":
        bounds = [_profile_interval(design, estimate, w, confidence) for w in (0, 1)]
    else:
        if rng is None:
            raise ValueError("interval='bootstrap' needs rng=np.random.Generator")
        if n_bootstrap < 20:
            raise ValueError(f"n_bootstrap must be >= 20, got {n_bootstrap!r}")
        bounds = _bootstrap_interval(samples, residuals, index, systematic, confidence,
                                     rng, n_bootstrap)  # fmt: skip
    return NoiseFit(
        k_left=math.sqrt(estimate[0]),
        k_right=math.sqrt(estimate[1]),
        k_left_interval=(math.sqrt(bounds[0][0]), math.sqrt(bounds[0][1])),
        k_right_interval=(math.sqrt(bounds[1][0]), math.sqrt(bounds[1][1])),
        confidence=confidence,
        interval_method=interval,
        systematic=systematic,
        n_runs=samples.n_runs,
        n_groups=len(index),
        dof=dof,
        log_likelihood=estimate[2],
        chi2_total=_terms(design, estimate[0], estimate[1])[1],
        components=components,
        measured_cov=measured,
        predicted_cov=predicted,
        residuals=residuals,
    )

"""Closed-form odometry covariance of Chong & Kleeman 1997 and the classic model.

Why: an EKF needs the covariance of the odometry pose. The classic incremental model (Eqs. 1–3)
depends on how a path is cut into steps; Chong & Kleeman instead give each wheel's travel d
zero-mean white noise of variance k²·|d| (Eq. 4, k in m^½) and sum it over the whole segment,
which yields closed forms for an arc (Eq. 25), a straight line (Eqs. 26–27) and an in-place
turn (Eq. 28) that compose exactly, segment by segment (Eq. 23). The Monte Carlo check of these
forms (the paper's §6.1) and the table-style report live in :mod:`odomgym.noise.montecarlo`.

Conventions (SI throughout): pose (x [m], y [m], θ [rad]); x forward, y left, θ counter-clockwise;
the left wheel sits at +B/2, so θ changes by (R − L)/B. This *is* the frame of the paper's Eq. 14,
so the paper's tables are reproduced without any remapping: L = 3 m, R = 1 m, B = 0.4 m turns
the robot by −5 rad to (−0.38357, −0.28654). Headings are kept unwrapped; only reports wrap the
mean heading into [0, 2π), as the tables print it (−5 rad ≡ 1.28319).

Paper errata found while reproducing Tables 1–7 (the code follows the corrected forms):
  * Eq. 17 lacks the 1/B of the r·cos θ_k terms (Eq. 22 has it);
  * Eq. 26, element (2,2): the D²/(3B²) term carries cos²θ_k, not sin²θ_k (see Eq. 27);
  * §5.2 substitutes L → B/2·Δθ, R → −B/2·Δθ; Eq. 14 needs the opposite signs — Eq. 28 itself
    is right for L = −B/2·Δθ, R = +B/2·Δθ;
  * the initial heading variances of Tables 3–6 are (2°)² and (5°)² rounded to 0.0012 and
    0.0076 rad² — only these reproduce the printed theory columns.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from odomgym.errors import SpecError, require_finite, require_positive

__all__ = [
    "ClassicInconsistency",
    "PoseEstimate",
    "arc_motion_covariance",
    "classic_inconsistency",
    "classic_step",
    "end_pose",
    "motion_covariance",
    "origin",
    "propagate_path",
    "propagate_segment",
    "quadrature_motion_covariance",
    "start_jacobian",
    "straight_motion_covariance",
    "turn_motion_covariance",
]

FloatArray = NDArray[np.float64]

NEAR_STRAIGHT_RAD = 0.1
"""Below this |Δθ| [rad] Eq. 25 loses ~ε/Δθ³ to cancellation (7e-14 relative at 0.1 rad, 7e-8 at
1e-3), so :func:`motion_covariance` evaluates the same integral by quadrature instead."""

_CORR_PAIRS = ((0, 2), (1, 2), (0, 1))  # xθ, yθ, xy: the order of the paper's tables


# ----------------------------------------------------------------------------- validation
def _nonnegative(name: str, value: object) -> float:
    number = require_finite(name, value)
    if number < 0.0:
        raise ValueError(f"{name} must be >= 0, got {number!r}")
    return number


def _check_motion(
    left: float, right: float, wheelbase: float, kl: float, kr: float, names: str = "left right"
) -> None:
    """Finite travels (named by ``names``), wheelbase > 0 [m], k ≥ 0 [m^½]; else ValueError."""
    for name, value in zip(names.split(), (left, right), strict=False):
        require_finite(name, value)
    require_positive("wheelbase", wheelbase)
    _nonnegative("kl", kl)
    _nonnegative("kr", kr)


def _pose(name: str, value: ArrayLike) -> tuple[float, float, float]:
    """A finite pose (x [m], y [m], θ [rad]); else ValueError naming ``name``."""
    try:
        pose = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pose (x, y, theta), got {value!r}") from None
    if pose.shape != (3,) or not np.all(np.isfinite(pose)):
        raise ValueError(f"{name} must be a finite pose (x, y, theta), got {value!r}")
    x, y, theta = pose.tolist()
    return x, y, theta


def _covariance(name: str, value: ArrayLike | None) -> FloatArray:
    """A finite, symmetric, positive semi-definite 3×3 matrix (zeros for None)."""
    cov = np.zeros((3, 3)) if value is None else np.array(value, dtype=float)
    if cov.shape != (3, 3) or not np.all(np.isfinite(cov)):
        raise ValueError(f"{name} must be a finite 3x3 matrix, got {cov!r}")
    if not np.allclose(cov, cov.T) or np.linalg.eigvalsh(cov).min() < -1e-12 * max(
        1.0, float(np.abs(cov).max())
    ):
        raise ValueError(f"{name} must be symmetric positive semi-definite, got {cov!r}")
    return cov


# ----------------------------------------------------------------------------- pose estimate
@dataclass(frozen=True)
class PoseEstimate:
    """Mean pose (x [m], y [m], θ [rad], θ unwrapped) and its 3×3 covariance [SI units²]."""

    mean: FloatArray
    cov: FloatArray

    @property
    def std(self) -> FloatArray:
        """Standard deviations (σ_x [m], σ_y [m], σ_θ [rad])."""
        return np.sqrt(np.diag(self.cov))

    @property
    def corr(self) -> FloatArray:
        """Correlation coefficients (xθ, yθ, xy) as fractions; NaN where a σ is zero."""
        std = self.std
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.array([self.cov[i, j] / (std[i] * std[j]) for i, j in _CORR_PAIRS])


def origin(cov: ArrayLike | None = None) -> PoseEstimate:
    """The paper's start: origin, heading +x, with initial covariance ``cov`` (default 0)."""
    return PoseEstimate(np.zeros(3), _covariance("init_cov", cov))


# ----------------------------------------------------------------------------- one segment
def end_pose(start: ArrayLike, left: float, right: float, wheelbase: float) -> FloatArray:
    """End pose after wheel travels ``left``, ``right`` [m] on a constant-curvature arc (Eq. 14).

    Written as chord length D·sinc(Δθ/2) along the mid heading θ₀ + Δθ/2, which equals Eq. 14's
    r·[sin θ₀ − sin θ_k, cos θ_k − cos θ₀] but stays exact for straight lines (r → ∞).
    """
    x0, y0, th0 = _pose("start", start)
    for name, value in (("left", left), ("right", right)):
        require_finite(name, value)
    require_positive("wheelbase", wheelbase)
    dtheta = (right - left) / wheelbase
    if not math.isfinite(dtheta):
        # A finite difference over a tiny wheelbase (1e300 m over 1e-10 m) overflows to inf,
        # whose sine was Python's bare "math domain error".
        raise SpecError(
            f"the turn (right − left)/wheelbase = ({right:g} − {left:g})/{wheelbase:g} "
            "overflows a float: too large for the closed forms (travels and wheelbase are "
            "metres)",
            field="wheelbase",
        )
    half = 0.5 * dtheta
    chord = 0.5 * (left + right) * (math.sin(half) / half if half != 0.0 else 1.0)
    mid = th0 + half
    return np.array([x0 + chord * math.cos(mid), y0 + chord * math.sin(mid), th0 + dtheta])


def start_jacobian(start: ArrayLike, end: ArrayLike) -> FloatArray:
    """∂(end pose)/∂(start pose) of one segment: Eq. 21, the product of the Eq. 16 Jacobians.

    Its entries r(cos θ₀ − cos θ_k) and r(sin θ₀ − sin θ_k) are −(y_k − y₀) and x_k − x₀: a
    start-heading error swings the whole segment about its start point.
    """
    delta = np.asarray(end, dtype=float) - np.asarray(start, dtype=float)
    return np.array([[1.0, 0.0, -delta[1]], [0.0, 1.0, delta[0]], [0.0, 0.0, 1.0]])


def _symmetric(
    c11: float, c22: float, c33: float, c12: float, c13: float, c23: float
) -> FloatArray:
    return np.array([[c11, c12, c13], [c12, c22, c23], [c13, c23, c33]])


def arc_motion_covariance(
    left: float, right: float, wheelbase: float, kl: float, kr: float, heading: float = 0.0
) -> FloatArray:
    """Cov(U_k) [m², m·rad, rad²] of a circular arc, Eq. 25 as printed (needs left ≠ right).

    ``heading`` is θ₀ [rad] at the start of the arc; θ_k = θ₀ + (R − L)/B, r = B/2·(L+R)/(L−R)
    (Eq. 15). Loses about ε/Δθ³ relative accuracy as the arc straightens; prefer
    :func:`motion_covariance`, which switches method there.
    """
    _check_motion(left, right, wheelbase, kl, kr)
    if left == right:
        raise ValueError("left and right must differ for an arc (use straight_motion_covariance)")
    b, t0 = wheelbase, heading
    tk = t0 + (right - left) / b
    d = left - right
    r = 0.5 * b * (left + right) / d
    s = kr**2 * abs(right) + kl**2 * abs(left)  # Σ wheel variances [m²]
    a = kr**2 * abs(right) * left + kl**2 * right * abs(left)
    q = kr**2 * left**2 * abs(right) + kl**2 * right**2 * abs(left)
    g = -b / (4.0 * d**3) * q
    sin0, sink, cos0, cosk = math.sin(t0), math.sin(tk), math.cos(t0), math.cos(tk)
    c11 = (
        -2.0 * r / d**2 * a * (sin0 - sink) * cosk
        + (r / b * cosk) ** 2 * s
        + g * (2.0 * (tk - t0) - math.sin(2 * t0) + math.sin(2 * tk))
    )
    c22 = (
        -2.0 * r / d**2 * a * (cosk - cos0) * sink
        + (r / b * sink) ** 2 * s
        + g * (2.0 * (tk - t0) + math.sin(2 * t0) - math.sin(2 * tk))
    )
    c12 = (
        -r / d**2 * a * (math.cos(2 * tk) - math.cos(t0 + tk))
        + 0.5 * (r / b) ** 2 * math.sin(2 * tk) * s
        + g * (math.cos(2 * t0) - math.cos(2 * tk))
    )
    c13 = a / d**2 * (sin0 - sink) - r / b**2 * cosk * s
    c23 = a / d**2 * (cosk - cos0) - r / b**2 * sink * s
    return _symmetric(c11, c22, s / b**2, c12, c13, c23)


def straight_motion_covariance(
    distance: float, wheelbase: float, kl: float, kr: float, heading: float = 0.0
) -> FloatArray:
    """Cov(U_k) of a straight run of ``distance`` [m] (negative: reverse) at ``heading``, Eq. 26.

    At heading 0 this is Eq. 27: σ_x² ∝ D, σ_y² ∝ D³ and corr(y, θ) = √3/2. Element (2,2) uses
    cos²θ (the paper prints sin²θ, contradicting its Eq. 27).
    """
    _check_motion(distance, distance, wheelbase, kl, kr, "distance")
    b, dd, ad = wheelbase, distance, abs(distance)
    ksum, kdiff = kl**2 + kr**2, kr**2 - kl**2
    sn, cs = math.sin(heading), math.cos(heading)
    c11 = ad * (
        cs**2 / 4 * ksum - dd / (2 * b) * sn * cs * kdiff + dd**2 / (3 * b**2) * sn**2 * ksum
    )
    c22 = ad * (
        sn**2 / 4 * ksum + dd / (2 * b) * sn * cs * kdiff + dd**2 / (3 * b**2) * cs**2 * ksum
    )
    c12 = ad * (
        (1 / 8 - dd**2 / (6 * b**2)) * math.sin(2 * heading) * ksum
        + dd / (4 * b) * math.cos(2 * heading) * kdiff
    )
    c13 = ad * (cs / (2 * b) * kdiff - dd / (2 * b**2) * sn * ksum)
    c23 = ad * (sn / (2 * b) * kdiff + dd / (2 * b**2) * cs * ksum)
    return _symmetric(c11, c22, ad / b**2 * ksum, c12, c13, c23)


def turn_motion_covariance(
    angle: float, wheelbase: float, kl: float, kr: float, heading: float = 0.0
) -> FloatArray:
    """Cov(U_k) of a turn on the spot by ``angle`` [rad], Eq. 28 (L = −B·angle/2, R = B·angle/2)."""
    _check_motion(angle, angle, wheelbase, kl, kr, "angle")
    b, t0, tk = wheelbase, heading, heading + angle
    ksum, kdiff, sgn = kl**2 + kr**2, kr**2 - kl**2, float(np.sign(angle))
    c11 = b / 32 * (2 * angle - math.sin(2 * t0) + math.sin(2 * tk)) * ksum * sgn
    c22 = b / 32 * (2 * angle + math.sin(2 * t0) - math.sin(2 * tk)) * ksum * sgn
    c12 = b / 32 * (math.cos(2 * t0) - math.cos(2 * tk)) * ksum * sgn
    c13 = 0.25 * kdiff * (math.sin(tk) - math.sin(t0)) * sgn
    c23 = 0.25 * kdiff * (math.cos(t0) - math.cos(tk)) * sgn
    return _symmetric(c11, c22, abs(angle) / (2 * b) * ksum, c12, c13, c23)


@functools.cache
def _gauss_legendre(nodes: int) -> tuple[tuple[float, float], ...]:
    """(node, weight) pairs on [0, 1]; cached, as computing them costs more than the quadrature."""
    u, w = np.polynomial.legendre.leggauss(nodes)
    return tuple(zip((0.5 * (u + 1.0)).tolist(), (0.5 * w).tolist(), strict=True))


def quadrature_motion_covariance(
    left: float,
    right: float,
    wheelbase: float,
    kl: float,
    kr: float,
    heading: float = 0.0,
    nodes: int = 16,
) -> FloatArray:
    """Cov(U_k) as the integral that Eq. 25 solves, by Gauss–Legendre quadrature on ``nodes``
    (a whole number ≥ 1).

    Eq. 23's sum tends to ∫₀¹ J(s) diag(k_L²|L|, k_R²|R|) J(s)ᵀ ds with J from Eq. 24: wheel noise
    at arc fraction s moves the pose by half its length along θ(s) (``a``) and turns the rest of
    the arc by ∓1/B about that point (``q``): J_L = a + q, J_R = a − q. The integrand is entire
    in s, so 8 nodes are exact to round-off for |Δθ| < 0.1 rad (near-straight arcs, where Eq. 25
    cancels) and 16 for |Δθ| ≲ 1 rad; the tests use many nodes as a reference for Eqs. 25–28.
    """
    _check_motion(left, right, wheelbase, kl, kr)
    if isinstance(nodes, bool) or not isinstance(nodes, int) or nodes < 1:
        raise ValueError(f"nodes must be a whole number >= 1, got {nodes!r}")
    dtheta, reach, qt = (right - left) / wheelbase, 0.5 * (left + right) / wheelbase, -1 / wheelbase
    # ∫aaᵀ + qqᵀ ("e") and ∫aqᵀ + qaᵀ ("o"), element by element; plain floats are 3× faster here
    e11 = e22 = e12 = e13 = e23 = o11 = o22 = o12 = o13 = o23 = 0.0
    for s, w in _gauss_legendre(nodes):
        theta, half_rest = heading + s * dtheta, 0.5 * dtheta * (1.0 - s)
        chord = reach * (1.0 - s) * (math.sin(half_rest) / half_rest if half_rest else 1.0)
        ax, ay = 0.5 * math.cos(theta), 0.5 * math.sin(theta)
        qx, qy = chord * math.sin(theta + half_rest), -chord * math.cos(theta + half_rest)
        e11, e22 = e11 + w * (ax * ax + qx * qx), e22 + w * (ay * ay + qy * qy)
        e12, e13, e23 = e12 + w * (ax * ay + qx * qy), e13 + w * qx * qt, e23 + w * qy * qt
        o11, o22, o12 = o11 + 2 * w * ax * qx, o22 + 2 * w * ay * qy, o12 + w * (ax * qy + ay * qx)
        o13, o23 = o13 + w * ax * qt, o23 + w * ay * qt
    var_l, var_r = kl**2 * abs(left), kr**2 * abs(right)
    t, d = var_l + var_r, var_l - var_r  # J_L = a + q, J_R = a − q
    return _symmetric(t * e11 + d * o11, t * e22 + d * o22, t * qt * qt,
                      t * e12 + d * o12, t * e13 + d * o13, t * e23 + d * o23)  # fmt: skip


def motion_covariance(
    left: float, right: float, wheelbase: float, kl: float, kr: float, heading: float = 0.0
) -> FloatArray:
    """Cov(U_k) of one constant-curvature segment: Eq. 26, 28, 25 or (near straight) quadrature."""
    _check_motion(left, right, wheelbase, kl, kr)
    try:
        dtheta = (right - left) / wheelbase
        if left == right:
            cov = straight_motion_covariance(left, wheelbase, kl, kr, heading)
        elif left == -right:
            cov = turn_motion_covariance(dtheta, wheelbase, kl, kr, heading)
        elif abs(dtheta) < NEAR_STRAIGHT_RAD:
            cov = quadrature_motion_covariance(left, right, wheelbase, kl, kr, heading, nodes=8)
        else:
            cov = arc_motion_covariance(left, right, wheelbase, kl, kr, heading)
    except OverflowError:
        cov = np.full((3, 3), np.inf)
    if not math.isfinite(float(cov.sum())):
        # Why a check here: Python's float powers raise OverflowError and numpy's give inf or
        # NaN, far from the argument that caused it (a travel of 1e200 m, k of 1e160 m^½).
        # One sum is the cheapest test of nine entries (NaN and inf carry through it).
        raise SpecError(
            f"a segment with left = {left:g} m, right = {right:g} m, wheelbase = "
            f"{wheelbase:g} m, kl = {kl:g} and kr = {kr:g} m^½ is too large for the closed "
            "forms (a power in its covariance overflows a float): travels are metres and k "
            "is m^½ (Chong & Kleeman 1997's k_L, k_R, about 1e-3)",
            field="covariance",
        )
    return cov


def propagate_segment(
    start: PoseEstimate, left: float, right: float, wheelbase: float, kl: float, kr: float
) -> PoseEstimate:
    """Mean and covariance after one segment: Eq. 14, and Eq. 23 = F·Cov(S₀)·Fᵀ + Cov(U_k)."""
    mean = end_pose(start.mean, left, right, wheelbase)
    jac = start_jacobian(start.mean, mean)
    motion = motion_covariance(left, right, wheelbase, kl, kr, float(start.mean[2]))
    return PoseEstimate(mean, jac @ start.cov @ jac.T + motion)


def propagate_path(
    segments: Sequence[tuple[float, float]],
    wheelbase: float,
    kl: float,
    kr: float,
    start: PoseEstimate | None = None,
) -> PoseEstimate:
    """Compose segments (left [m], right [m]) from ``start`` (default: origin, zero covariance).

    Because Eq. 25 is the k → ∞ limit of incremental propagation, cutting an arc into pieces
    leaves the result unchanged — the consistency the classic model lacks.
    """
    estimate = origin() if start is None else start
    for index, segment in enumerate(segments):
        try:
            left, right = segment
        except (TypeError, ValueError):
            raise ValueError(
                f"segments[{index}] must be a pair (left, right) of wheel travels [m], got "
                f"{segment!r}"
            ) from None
        estimate = propagate_segment(estimate, left, right, wheelbase, kl, kr)
    return estimate


# ----------------------------------------------------------------------------- classic model
def classic_step(
    start: PoseEstimate,
    distance: float,
    rotation: float,
    var_distance: float,
    var_rotation: float,
) -> PoseEstimate:
    """Classic model, Eqs. 1–3: rotate by α [rad], then translate D [m], with independent errors.

    ``var_distance`` σ_D² [m²] and ``var_rotation`` σ_α² [rad²] are per step, which is the flaw:
    nothing ties them to the distance, so results depend on how the path is cut.
    """
    require_finite("distance", distance)
    require_finite("rotation", rotation)
    _nonnegative("var_distance", var_distance)
    _nonnegative("var_rotation", var_rotation)
    x, y, th = (float(v) for v in start.mean)
    heading = th + rotation
    c, s = math.cos(heading), math.sin(heading)
    mean = np.array([x + distance * c, y + distance * s, heading])
    grad_s = np.array([[1.0, 0.0, -distance * s], [0.0, 1.0, distance * c], [0.0, 0.0, 1.0]])
    grad_u = np.array([[c, -distance * s], [s, distance * c], [0.0, 1.0]])
    cov_u = np.diag([var_distance, var_rotation])
    return PoseEstimate(mean, grad_s @ start.cov @ grad_s.T + grad_u @ cov_u @ grad_u.T)


@dataclass(frozen=True)
class ClassicInconsistency:
    """Covariances of one straight run of 2D versus two runs of D, under both models (§1)."""

    classic_one: FloatArray
    classic_two: FloatArray
    new_one: FloatArray
    new_two: FloatArray


def classic_inconsistency(
    distance: float, wheelbase: float, kl: float, kr: float
) -> ClassicInconsistency:
    """The paper's §1 example: one step of 2D or two steps of D [m] from an exact start.

    The classic step variances follow the wheel noise of one step of D (σ_D² = (k_L²+k_R²)D/4,
    σ_α² = (k_L²+k_R²)D/B²) and are doubled for the step of 2D, as the paper sets
    Cov(u_k0) = 2·Cov(u_k1). The classic model then gives σ_y² = 8D²σ_α² versus 5D²σ_α²; the new
    model gives the same matrix both ways.
    """
    _check_motion(distance, distance, wheelbase, kl, kr, "distance")
    ksum = kl**2 + kr**2
    var_d, var_a = ksum * abs(distance) / 4, ksum * abs(distance) / wheelbase**2
    one = classic_step(origin(), 2 * distance, 0.0, 2 * var_d, 2 * var_a)
    two = classic_step(
        classic_step(origin(), distance, 0.0, var_d, var_a), distance, 0.0, var_d, var_a
    )
    new_one = propagate_path([(2 * distance, 2 * distance)], wheelbase, kl, kr)
    new_two = propagate_path([(distance, distance)] * 2, wheelbase, kl, kr)
    return ClassicInconsistency(one.cov, two.cov, new_one.cov, new_two.cov)

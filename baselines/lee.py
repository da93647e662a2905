"""Lee et al.: UMBmark without the assumption that unequal wheels leave the 90° turns alone.

K. Lee, C. Jung, W. Chung, *Accurate calibration of kinematic parameters for two wheel
differential mobile robots*, J. Mech. Sci. Technol. 25(6):1603–1611, 2011. UMBmark (Borenstein &
Feng 1994, §6) attributes the whole Type A error α (every corner turned by 90° − α) to the
wheelbase. Lee et al. note that unequal wheels also change an on-the-spot turn: if the diameter
error sits in the right wheel (D_L as believed, D_R = E_d·D_L), each wheel's nominal
quarter-turn arc π·b/4 makes the robot turn (1 + E_d)·π/4 instead of π/2, an *over*-turn of

    α_d = (E_d − 1)·π/4 = π·b / (4·(R − b/2))        (E_d = (R + b/2)/(R − b/2))

per corner. With the centres of gravity x_cw, x_ccw, y_cw, y_ccw of the return errors
(``odomgym.odometry.runs.return_error``, true − odometry, start frame):

    R̂_x = −4L²/(x_cw − x_ccw)             (= L/β_x,  β_x = (x_cw − x_ccw)/(−4L), Eq. 6.22a)
    α_x = (x_cw + x_ccw)/(−4L) + π·b/(4·(R̂_x − b/2))
    R̂_y = −4L²/(y_cw + y_ccw)             (= L/β_y,  β_y = (y_cw + y_ccw)/(−4L), Eq. 6.22b)
    α_y = (y_cw − y_ccw)/(−4L) + π·b/(4·(R̂_y − b/2))

and, as UMBmark, E_d = (R̂ + b/2)/(R̂ − b/2) and E_b = (π/2)/(π/2 − α) (Borenstein & Feng
1994, Eqs. 6.24, 6.29) from x and from y, averaged (footnote 2 of §6.3). b is the wheelbase the
odometry used while driving [m], L the square side [m]; angles in radians.

**Sign conventions, checked against the simulator.** odomgym's square starts at the origin
heading +x, cw squares turn toward −y, and return errors are true − odometry in the start frame
— the frame of Borenstein & Feng 1994, Eqs. 6.19–6.20, in which α > 0 means under-turning
(E_b > 1) and β > 0 means the legs curve left (E_d = D_R/D_L > 1, R̂ > 0). A larger right
wheel over-turns every corner, cw and ccw alike, so the observed α is α_b − α_d and the
wheelbase's share is α_b = α + α_d: the "+" of the formulas above. No sign had to change.
Simulated on the LabMate with b_true = 1.02·b and only the right wheel 0.4 % larger (D_L
nominal), Lee et al. recover E_b = 1.0208 where UMBmark's α gives 1.0187 — UMBmark's value is b
relative to the *mean* diameter, 1.02/1.002.

**Which wheel carries E_d (``diameter_error``).** α_d ≠ 0 is a statement about the mean
diameter. Wheels split as UMBmark's correction factors and
:meth:`odomgym.robot.RobotSpec.with_errors` split them (D_L = 2D_a/(E_d + 1),
D_R = 2D_a/(1/E_d + 1), mean D_a kept) turn in place exactly as far as two wheels of diameter
D_a, so for them α_d = 0. Squares measure only D_R/D_L and b/D_a; Lee et al.'s assumption fixes
D_L and so moves (E_d − 1)/2 of relative error from the mean diameter into the wheelbase.
The default, ``"right_wheel"``, is the paper: α_d as above, and the correction applied
*consistently with that model* — the left wheel's travel per count unchanged, the right wheel's
multiplied by E_d, b by E_b (``Calibration.from_errors(E_d, E_b, E_s=(1 + E_d)/2)``, see
:func:`lee_correction`). ``"split"`` uses UMBmark's split instead (α_d = 0: the method is then
UMBmark with R̂ = L/β). Both give the odometry the same b/D_a, so the same headings; they
differ in how they name it. The paper's E_b with UMBmark's mean-preserving factors would mix
the two models and mis-scale every turn by (E_d − 1)/2 (measured on the LabMate with E_d =
1.004, E_b = 1.02, E_s = 0.995: E_max,syst 50 mm instead of 16 mm). On such a robot — odomgym's
default split — Lee et al.'s E_b (1.0279) and E_s (1.0020) are not the true 1.02 and 0.995;
their ratio, 1.0259, is the true 1.0251 plus the +0.0007 second-order bias that UMBmark's
first-order equations share at these error sizes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike

from odomgym.baselines.base import (
    CalibrationResult,
    SquareCalibrator,
    SquareOptions,
    require_choice,
)
from odomgym.baselines.umbmark import e_b_from_alpha, perform_squares
from odomgym.errors import SpecError
from odomgym.lab.experiment import Lab
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import require_differential, return_error
from odomgym.odometry.umbmark_measures import centre_of_gravity, summarize_umbmark

__all__ = [
    "DiameterError",
    "Lee",
    "LeeEstimates",
    "LeeOptions",
    "lee_alpha_d",
    "lee_correction",
    "lee_estimates",
]

DiameterError = Literal["right_wheel", "split"]


def lee_alpha_d(beta: float, side: float, wheelbase: float) -> float:
    """α_d = π·b/(4·(R̂ − b/2)) with R̂ = L/β [rad]: a corner's over-turn caused by a right
    wheel E_d = (R̂ + b/2)/(R̂ − b/2) times the left one.

    Written as π·b·β/(4·(L − b·β/2)), which is the same and finite for β = 0. ``side`` L and
    ``wheelbase`` b in metres, β in radians.
    """
    return math.pi * wheelbase * beta / (4.0 * (side - 0.5 * wheelbase * beta))


def _e_d_from_radius(beta: float, side: float, wheelbase: float) -> float:
    """E_d = (R̂ + b/2)/(R̂ − b/2) with R̂ = L/β, as (L + b·β/2)/(L − b·β/2) (finite at β = 0)."""
    half = 0.5 * wheelbase * beta
    if not abs(half) < side:
        raise ValueError(
            f"Type B error β = {beta} rad bends a {side} m leg tighter than the wheelbase "
            f"({wheelbase} m) allows; the return errors are far outside the model"
        )
    return (side + half) / (side - half)


@dataclass(frozen=True)
class LeeEstimates:
    """Lee et al.'s quantities from one bi-directional experiment (x- and y-based, averaged).

    Attributes:
        alpha: α_b, the wheelbase's share of the Type A error per corner, mean of x and y [rad].
        beta: Type B error per leg, mean of x and y [rad].
        alpha_d: the corner over-turn attributed to E_d, mean of x and y [rad].
        radius: R̂ = L/β of the mean β [m] (``inf`` for β = 0).
        e_d: E_d = D_R/D_L, mean of the x- and y-based values [-].
        e_b: E_b = b_actual/b, mean of the x- and y-based values [-].
        alpha_x, beta_x, radius_x, alpha_y, beta_y, radius_y: per-component values.
    """

    alpha: float
    beta: float
    alpha_d: float
    radius: float
    e_d: float
    e_b: float
    alpha_x: float
    beta_x: float
    radius_x: float
    alpha_y: float
    beta_y: float
    radius_y: float

    def as_dict(self) -> dict[str, float]:
        """Named as in the paper (``alpha``, ``beta``, ``alpha_d``, ``R``, ``E_d``, ``E_b``, …)."""
        return {
            "alpha": self.alpha,
            "beta": self.beta,
            "alpha_d": self.alpha_d,
            "R": self.radius,
            "E_d": self.e_d,
            "E_b": self.e_b,
            "alpha_x": self.alpha_x,
            "beta_x": self.beta_x,
            "R_x": self.radius_x,
            "alpha_y": self.alpha_y,
            "beta_y": self.beta_y,
            "R_y": self.radius_y,
        }


def lee_estimates(
    cw_errors: ArrayLike,
    ccw_errors: ArrayLike,
    side: float,
    wheelbase: float,
    *,
    diameter_error: DiameterError = "right_wheel",
) -> LeeEstimates:
    """Lee et al.'s E_d and E_b from cw and ccw return errors (see the module docstring).

    Args:
        cw_errors, ccw_errors: return errors (n, ≥2) [m], true − odometry in the start frame;
            further columns are ignored.
        side: square side L [m].
        wheelbase: the wheelbase b the odometry used while driving [m].
        diameter_error: ``"right_wheel"`` (the paper's α_d) or ``"split"`` (α_d = 0).
    """
    if not side > 0.0 or not wheelbase > 0.0:
        raise ValueError(f"side and wheelbase must be > 0, got {side}, {wheelbase}")
    if diameter_error not in ("right_wheel", "split"):
        raise ValueError(f"diameter_error must be 'right_wheel' or 'split', got {diameter_error!r}")
    x_cw, y_cw = (float(v) for v in centre_of_gravity(cw_errors))
    x_ccw, y_ccw = (float(v) for v in centre_of_gravity(ccw_errors))
    denom = -4.0 * side
    components = {
        "x": ((x_cw - x_ccw) / denom, (x_cw + x_ccw) / denom),  # β, α_obs (6.22a, 6.26a)
        "y": ((y_cw + y_ccw) / denom, (y_cw - y_ccw) / denom),  # β, α_obs (6.22b, 6.26b)
    }
    values: dict[str, tuple[float, float, float, float, float]] = {}
    for axis, (beta, alpha_observed) in components.items():
        alpha_d = lee_alpha_d(beta, side, wheelbase) if diameter_error == "right_wheel" else 0.0
        alpha = alpha_observed + alpha_d
        radius = math.inf if beta == 0.0 else side / beta
        values[axis] = (
            alpha,
            beta,
            alpha_d,
            radius,
            _e_d_from_radius(beta, side, wheelbase),
        )
    ax, bx, dx, rx, edx = values["x"]
    ay, by, dy, ry, edy = values["y"]
    beta = 0.5 * (bx + by)
    return LeeEstimates(
        alpha=0.5 * (ax + ay),
        beta=beta,
        alpha_d=0.5 * (dx + dy),
        radius=math.inf if beta == 0.0 else side / beta,
        e_d=0.5 * (edx + edy),
        e_b=0.5 * (e_b_from_alpha(ax) + e_b_from_alpha(ay)),
        alpha_x=ax,
        beta_x=bx,
        radius_x=rx,
        alpha_y=ay,
        beta_y=by,
        radius_y=ry,
    )


def lee_correction(e_d: float, e_b: float, diameter_error: DiameterError) -> Calibration:
    """The correction (relative to the odometry that drove) that Lee et al.'s E_d, E_b mean.

    ``"right_wheel"``: left travel per count unchanged, right × E_d, b × E_b (so the mean
    diameter grows by (1 + E_d)/2). ``"split"``: UMBmark's c_L = 2/(E_d + 1), c_R = 2/(1/E_d
    + 1), b × E_b (Borenstein & Feng 1994, Eqs. 6.28, 6.33–6.34).
    """
    e_s = 0.5 * (1.0 + e_d) if diameter_error == "right_wheel" else 1.0
    return Calibration.from_errors(e_d, e_b, e_s)


@dataclass(frozen=True)
class LeeOptions(SquareOptions):
    """The settings of :class:`Lee`: ``side`` [m], ``runs_per_direction`` and
    ``diameter_error`` (``"right_wheel"`` or ``"split"``)."""

    diameter_error: DiameterError = "right_wheel"

    def __post_init__(self) -> None:
        super().__post_init__()
        require_choice("diameter_error", self.diameter_error, ("right_wheel", "split"))


class Lee(SquareCalibrator):
    """Lee et al.'s calibration from ``runs_per_direction`` cw and ccw squares (see the module).

    Args:
        side: square side L [m] (the paper, as UMBmark: 4 m).
        runs_per_direction: squares per direction (5 as UMBmark).
        diameter_error: ``"right_wheel"`` (the paper) or ``"split"`` (UMBmark's split of E_d,
            for which α_d = 0).
    """

    name: ClassVar[str] = "lee"
    reference: ClassVar[str] = (
        "K. Lee, C. Jung, W. Chung, Accurate calibration of kinematic parameters for two wheel "
        "differential mobile robots, J. Mech. Sci. Technol. 25(6):1603-1611, 2011"
    )
    options_type: ClassVar[type[LeeOptions]] = LeeOptions

    def __init__(
        self,
        side: float = 4.0,
        runs_per_direction: int = 5,
        *,
        diameter_error: DiameterError = "right_wheel",
    ) -> None:
        options = LeeOptions(side, runs_per_direction, diameter_error=diameter_error)
        self._set_squares(options)
        self.options: LeeOptions = options
        self.diameter_error: DiameterError = options.diameter_error

    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        """Drive the squares with ``initial`` active and correct E_d and E_b."""
        require_differential(initial, self.name)
        robot = lab.robot
        runs0, dist0 = lab.runs_used, lab.distance_used
        calibration = initial if initial is not None else Calibration()
        try:
            cw, ccw = perform_squares(lab, calibration, self.side, self.runs_per_direction)
        except LookupError as exc:
            raise LookupError(
                f"Lee et al.'s calibration needs {self.runs_per_direction} cw and as many ccw "
                f"squares of side {self.side:g} m that this lab cannot provide: {exc}"
            ) from exc
        cw_err = np.array([return_error(r, robot, calibration) for r in cw])
        ccw_err = np.array([return_error(r, robot, calibration) for r in ccw])
        try:
            found = lee_estimates(
                cw_err,
                ccw_err,
                self.side,
                calibration.wheelbase_scale * robot.wheelbase,
                diameter_error=self.diameter_error,
            )
        except ValueError as exc:
            # The only way measured return errors break the model: a leg bent tighter than
            # the wheelbase allows, which squares far too small for the robot's errors (the
            # user's side) produce. An option's error, so a SpecError naming it, not a bug.
            raise SpecError(
                f"side {self.side:g} m is too short for Lee et al.'s model on this robot: {exc}; "
                "drive larger squares (the paper's are 4 m)",
                field="side",
            ) from None
        summary = summarize_umbmark(cw_err, ccw_err)
        estimates = found.as_dict()
        estimates.update(
            x_cg_cw=summary.cg_cw[0],
            y_cg_cw=summary.cg_cw[1],
            x_cg_ccw=summary.cg_ccw[0],
            y_cg_ccw=summary.cg_ccw[1],
            E_max_syst=summary.e_max_syst,
        )
        correction = lee_correction(found.e_d, found.e_b, self.diameter_error)
        estimates["E_s"] = correction.distance_scale  # what the wheel model implies
        return CalibrationResult(
            calibration=calibration.then(correction),
            estimates=estimates,
            runs_used=lab.runs_used - runs0,
            distance_used=lab.distance_used - dist0,
            notes=[],
        )

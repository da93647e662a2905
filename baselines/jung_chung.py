"""Jung & Chung calibration of E_d and E_b from the *heading* errors of bi-directional squares.

C. Jung, W. Chung, *Calibration of kinematic parameters for two wheel differential mobile
robots by using experimental heading errors*, Int. J. Adv. Robot. Syst. 8(6):134–142, 2011,
doi:10.5772/50906. Where UMBmark (Borenstein & Feng 1994, §6) infers the Type A and Type B
angles from return *positions*, Jung & Chung read them from the return *heading* errors, which
the first-order model (:func:`odomgym.baselines.umbmark.first_order_return_errors`) predicts as
θ_cw = 4(α + β) and θ_ccw = 4(β − α) for errors true − odometry [rad]:

    α_b = (θ_cw − θ_ccw)/8,    β = (θ_cw + θ_ccw)/8,    α_d = π·b·β/(4L)

α_d is the extra turn per corner that a right wheel E_d times larger than the (nominal) left
one causes during the on-the-spot turns: (E_d − 1)·π/4 with E_d − 1 ≈ b·β/L. Part of the
Type A error the wheelbase causes is thus hidden: the observed α_b is the wheelbase's share
minus α_d, and E_b adds α_d back. Then

    E_b = (π/2)/(π/2 − (α_b + α_d)),   R = (L/2)/sin(β/2),   E_d = (R + E_b·b/2)/(R − E_b·b/2)

with θ_cw, θ_ccw the centres of the cw and ccw return heading errors (their circular mean).
Heading errors do not depend on the frame the positions are expressed in.

**OptiOdom conventions** (``conventions="optiodom"``) reproduce the authors' MATLAB
``src/diff/jung-and-chung/main.m`` with its ``computeEvaluationMeasures.m``
(github.com/sousarbarb/optiodom), including a bug in the heading centre: it sums the unit
vectors of the n final heading errors, takes ``atan2`` — already the circular mean — and then
divides by n a second time (``wrapToPi(atan2(Σsin, Σcos)/n)``). Their α_b and β, and so E_b − 1
and E_d − 1, come out about n times too small (3× on their six-run sessions). The parameter
update is theirs too (:func:`odomgym.baselines.umbmark.optiodom_update`). The default
(``conventions="jung_chung"``) uses the circular mean and composes the correction with the
calibration in place (solderspot 2014).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike

from odomgym.baselines.base import (
    CalibrationResult,
    SquareCalibrator,
    SquareOptions,
)
from odomgym.baselines.umbmark import (
    e_b_from_alpha,
    e_d_from_beta,
    optiodom_update,
    perform_squares,
)
from odomgym.lab.experiment import Lab, parse_choice
from odomgym.odometry.calibration import Calibration, wrap_angle
from odomgym.odometry.runs import require_differential, return_error

__all__ = [
    "HeadingMean",
    "JungChung",
    "JungChungConventions",
    "JungChungEstimates",
    "JungChungOptions",
    "heading_centre",
    "jung_chung_estimates",
    "jung_chung_from_headings",
]

HeadingMean = Literal["circular", "optiodom"]


class JungChungConventions(StrEnum):
    """Whose reading of Jung & Chung :class:`JungChung` follows (see the module docstring)."""

    JUNG_CHUNG = "jung_chung"  # circular-mean heading centres, correction composed
    OPTIODOM = "optiodom"  # the OptiOdom authors' code, its double division included


@dataclass(frozen=True)
class JungChungOptions(SquareOptions):
    """The settings of :class:`JungChung`: ``side`` [m], ``runs_per_direction`` and
    ``conventions`` (a :class:`JungChungConventions` or its spelling)."""

    conventions: JungChungConventions = JungChungConventions.JUNG_CHUNG

    def __post_init__(self) -> None:
        super().__post_init__()
        conventions = parse_choice(JungChungConventions, self.conventions, field="conventions")
        object.__setattr__(self, "conventions", conventions)


def heading_centre(errors: ArrayLike, *, mean: HeadingMean = "circular") -> float:
    """Centre of the return heading errors (column 2 of ``errors`` (n, 3)) [rad].

    ``"circular"``: atan2(Σ sin θ_i, Σ cos θ_i), the circular mean. ``"optiodom"``: the
    authors' ``computeEvaluationMeasures.m``, which divides that angle by n once more and wraps
    it to [−π, π) — reproduced only to match their published numbers.
    """
    array = np.asarray(errors, dtype=float)
    if array.ndim != 2 or array.shape[0] == 0 or array.shape[1] < 3:
        raise ValueError(f"need return errors of shape (n>=1, 3), got {array.shape}")
    theta = array[:, 2]
    centre = math.atan2(float(np.sum(np.sin(theta))), float(np.sum(np.cos(theta))))
    if mean == "optiodom":
        return float(wrap_angle(centre / len(theta)))
    if mean != "circular":
        raise ValueError(f"mean must be 'circular' or 'optiodom', got {mean!r}")
    return centre


@dataclass(frozen=True)
class JungChungEstimates:
    """Jung & Chung's intermediate quantities and results.

    Attributes:
        theta_cw, theta_ccw: centres of the cw and ccw return heading errors [rad].
        alpha_b: Type A error per corner attributed to the wheelbase [rad].
        beta: Type B error per leg [rad].
        alpha_d: turn error per corner attributed to unequal wheels, π·b·β/(4L) [rad].
        radius: R = (L/2)/sin(β/2) [m] (``inf`` for β = 0).
        e_b: E_b = (π/2)/(π/2 − (α_b + α_d)) [-].
        e_d: E_d = (R + E_b·b/2)/(R − E_b·b/2) [-].
    """

    theta_cw: float
    theta_ccw: float
    alpha_b: float
    beta: float
    alpha_d: float
    radius: float
    e_b: float
    e_d: float

    def as_dict(self) -> dict[str, float]:
        """Named as in the paper (``alpha_b``, ``beta``, ``alpha_d``, ``R``, ``E_b``, ``E_d``)."""
        return {
            "theta_cw": self.theta_cw,
            "theta_ccw": self.theta_ccw,
            "alpha_b": self.alpha_b,
            "beta": self.beta,
            "alpha_d": self.alpha_d,
            "R": self.radius,
            "E_b": self.e_b,
            "E_d": self.e_d,
        }


def jung_chung_from_headings(
    theta_cw: float, theta_ccw: float, side: float, wheelbase: float
) -> JungChungEstimates:
    """Jung & Chung's estimates from the two heading centres [rad], side L and wheelbase b [m]."""
    if not side > 0.0 or not wheelbase > 0.0:
        raise ValueError(f"side and wheelbase must be > 0, got {side}, {wheelbase}")
    alpha_b = (theta_cw - theta_ccw) / 8.0
    beta = (theta_cw + theta_ccw) / 8.0
    alpha_d = math.pi * wheelbase * beta / (4.0 * side)
    e_b = e_b_from_alpha(alpha_b + alpha_d)
    e_d = e_d_from_beta(beta, side, e_b * wheelbase)
    radius = math.inf if beta == 0.0 else 0.5 * side / math.sin(0.5 * beta)
    return JungChungEstimates(theta_cw, theta_ccw, alpha_b, beta, alpha_d, radius, e_b, e_d)


def jung_chung_estimates(
    cw_errors: ArrayLike,
    ccw_errors: ArrayLike,
    side: float,
    wheelbase: float,
    *,
    heading_mean: HeadingMean = "circular",
) -> JungChungEstimates:
    """Jung & Chung's estimates from cw and ccw return errors (n, 3): x, y [m], θ [rad].

    Only the heading column is used. ``wheelbase`` is the b the odometry used while driving.
    """
    return jung_chung_from_headings(
        heading_centre(cw_errors, mean=heading_mean),
        heading_centre(ccw_errors, mean=heading_mean),
        side,
        wheelbase,
    )


# mypy cannot follow the setuptools package-dir mapping odomgym.baselines → baselines/, so
# to it Calibrator is Any; drop the ignore once that mapping is visible to mypy.
class JungChung(SquareCalibrator):
    """Jung & Chung's heading-error calibration on ``runs_per_direction`` cw + ccw squares.

    Args:
        side: square side L [m].
        runs_per_direction: squares per direction.
        conventions: ``"jung_chung"`` (circular-mean heading centres; correction multiplied onto
            the calibration in place) or ``"optiodom"`` (a :class:`JungChungConventions` or its
            spelling) (the authors' code, bug included; see
            the module docstring).
    """

    name: ClassVar[str] = "jung_chung"
    reference: ClassVar[str] = (
        "C. Jung, W. Chung, Calibration of kinematic parameters for two wheel differential "
        "mobile robots by using experimental heading errors, Int. J. Adv. Robot. Syst. "
        "8(6):134-142, 2011, doi:10.5772/50906"
    )
    options_type: ClassVar[type[JungChungOptions]] = JungChungOptions

    def __init__(
        self,
        side: float = 4.0,
        runs_per_direction: int = 5,
        *,
        conventions: JungChungConventions | str = JungChungConventions.JUNG_CHUNG,
    ) -> None:
        options = JungChungOptions(
            side=side,
            runs_per_direction=runs_per_direction,
            conventions=parse_choice(JungChungConventions, conventions, field="conventions"),
        )
        self._set_squares(options)
        self.options: JungChungOptions = options
        self.conventions = options.conventions

    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        """Drive the squares in ``lab`` with ``initial`` and correct E_b and E_d."""
        require_differential(initial, self.name)
        robot = lab.robot
        runs0, dist0 = lab.runs_used, lab.distance_used
        calibration = initial if initial is not None else Calibration()
        cw, ccw = perform_squares(lab, calibration, self.side, self.runs_per_direction)
        cw_err = np.array([return_error(r, robot, calibration) for r in cw])
        ccw_err = np.array([return_error(r, robot, calibration) for r in ccw])
        compat = self.conventions is JungChungConventions.OPTIODOM
        found = jung_chung_estimates(
            cw_err,
            ccw_err,
            self.side,
            calibration.wheelbase_scale * robot.wheelbase,
            heading_mean="optiodom" if compat else "circular",
        )
        if compat:
            updated = optiodom_update(robot, calibration, found.e_d, found.e_b)
            notes = [
                "OptiOdom conventions: heading centres divided by the number of runs twice, "
                "as the authors' computeEvaluationMeasures.m"
            ]
        else:
            updated = calibration.then(Calibration.from_errors(found.e_d, found.e_b))
            notes = []
        return CalibrationResult(
            calibration=updated,
            estimates=found.as_dict(),
            runs_used=lab.runs_used - runs0,
            distance_used=lab.distance_used - dist0,
            notes=notes,
        )

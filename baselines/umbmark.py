"""UMBmark calibration of E_d and E_b from bi-directional square runs (Borenstein & Feng).

J. Borenstein, L. Feng, *UMBmark — A Method for Measuring, Comparing, and Correcting
Dead-reckoning Errors in Mobile Robots*, Univ. of Michigan TR UM-MEAM-94-22, 1994, §6,
with the E_s phase and multiplicative iteration of solderspot 2014.

**Frame.** Return errors ε = true − odometry at the end of each square, in the *start frame*:
origin at the first true pose, +x along the starting heading, +y to its left (Borenstein & Feng
1994, §6.1: the first leg runs along +x and a ccw square goes to +y). In that frame the
first-order model of Borenstein & Feng 1994, Eqs. 6.3–6.20 (implemented by
:func:`first_order_return_errors`) gives the centres of gravity

    x_cw = −2L(α + β),   x_ccw = −2L(α − β)        (Eqs. 6.19, 6.20)
    y_cw = −2L(α + β),   y_ccw = +2Lα − 2Lβ        (Eqs. 6.6b, 6.10b, 6.14b, 6.18b)

where α [rad] is the Type A error (each 90° corner turned by 90° − α: the robot *under-turns*
for α > 0, a wheelbase larger than believed) and β [rad] the Type B error (each leg bends left
by β: the right wheel larger than believed). Inverting:

    β = (x_cw − x_ccw)/(−4L)  (6.22a)      β = (y_cw + y_ccw)/(−4L)  (6.22b)
    α = (x_cw + x_ccw)/(−4L)  (6.26a)      α = (y_cw − y_ccw)/(−4L)  (6.26b)
    R = (L/2)/sin(β/2)  (6.23),   E_d = (R + b/2)/(R − b/2)  (6.24),   E_b = (π/2)/(π/2 − α) (6.29)

and the corrections c_L = 2/(E_d + 1), c_R = 2/(1/E_d + 1) (6.33–6.34), b_new = E_b·b (6.28).
By default E_d and E_b are computed from x and from y and averaged (footnote 2 of §6.3).

**OptiOdom conventions** (``conventions="optiodom"``) reproduce the authors' MATLAB
``src/diff/umbmark/main.m`` (github.com/sousarbarb/optiodom): errors ground truth − odometry in
the motion-capture frame (``return_error(frame="world")``; their synchronisation already put the
first pose at the origin with zero heading, so on their data the two frames coincide); α and β
from the x centres of gravity only; E_d = (R + E_b·b/2)/(R − E_b·b/2), i.e. with the *corrected*
wheelbase; b_new = E_b·b; the mean of the current wheel diameters kept and split by E_d (which
replaces, rather than multiplies, any previous diameter ratio); no E_s phase and no second
compensation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from odomgym.baselines.base import (
    CalibrationResult,
    SquareOptions,
    SquaresSizing,
    require_choice,
    square_experiments,
)
from odomgym.errors import SpecError, require_count, require_positive
from odomgym.lab.experiment import Experiment, ExperimentKind, Lab, parse_choice
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run, replay_odometry, require_differential, return_error
from odomgym.odometry.umbmark_measures import centre_of_gravity, summarize_umbmark
from odomgym.robot import RobotSpec

__all__ = [
    "Components",
    "UMBmark",
    "UMBmarkConventions",
    "UMBmarkEstimates",
    "UMBmarkOptions",
    "alpha_from_e_b",
    "beta_from_e_d",
    "e_b_from_alpha",
    "e_d_from_beta",
    "first_order_return_errors",
    "optiodom_update",
    "perform_squares",
    "umbmark_estimates",
]

FloatArray = NDArray[np.float64]
Components = Literal["xy", "x", "y"]
EdWheelbase = Literal["nominal", "corrected"]


# ------------------------------------------------------------------------ the first-order model
def e_b_from_alpha(alpha: float) -> float:
    """E_b = (π/2)/(π/2 − α), α [rad] — Borenstein & Feng 1994, Eq. 6.29, in radians."""
    if not abs(alpha) < 0.5 * math.pi:
        raise ValueError(f"Type A error α = {alpha} rad is outside the model's range (|α| < π/2)")
    return 0.5 * math.pi / (0.5 * math.pi - alpha)


def alpha_from_e_b(e_b: float) -> float:
    """The Type A error α [rad] that E_b causes per 90° corner — inverse of Eq. 6.29."""
    return 0.5 * math.pi * (1.0 - 1.0 / e_b)


def e_d_from_beta(beta: float, side: float, wheelbase: float) -> float:
    """E_d = (R + b/2)/(R − b/2) with R = (L/2)/sin(β/2) — Borenstein & Feng 1994, Eqs. 6.23–6.24.

    Written as (1 + k)/(1 − k) with k = b·sin(β/2)/L, which is the same and stays finite for
    β = 0 (R = ∞, E_d = 1). ``side`` L and ``wheelbase`` b in metres, β in radians.
    """
    k = wheelbase * math.sin(0.5 * beta) / side
    if not abs(k) < 1.0:
        raise ValueError(
            f"Type B error β = {beta} rad bends a {side} m leg tighter than the wheelbase "
            f"({wheelbase} m) allows; the return errors are far outside the first-order model"
        )
    return (1.0 + k) / (1.0 - k)


def beta_from_e_d(e_d: float, side: float, wheelbase: float) -> float:
    """The Type B error β [rad] per leg of ``side`` [m] caused by E_d — inverse of 6.23–6.24."""
    k = (e_d - 1.0) / (e_d + 1.0)
    return 2.0 * math.asin(k * side / wheelbase)


def first_order_return_errors(
    alpha: float, beta: float, side: float
) -> tuple[FloatArray, FloatArray]:
    """Return errors (x, y [m], θ [rad]) of one cw and one ccw square, first-order model.

    Superposes Borenstein & Feng 1994, Eqs. 6.3–6.18 (Type A: 6.6, 6.10; Type B: 6.14, 6.18) as
    in Eqs. 6.19–6.20, in the start frame. The heading errors follow from the same model: each of
    the four corners turns α too little and each leg bends β to the left, so θ_cw = 4α + 4β and
    θ_ccw = −4α + 4β.

    Returns:
        (cw, ccw), each of shape (3,).
    """
    two_l = 2.0 * side
    cw = np.array([-two_l * (alpha + beta), -two_l * (alpha + beta), 4.0 * (alpha + beta)])
    ccw = np.array([-two_l * (alpha - beta), two_l * alpha - two_l * beta, 4.0 * (beta - alpha)])
    return cw, ccw


@dataclass(frozen=True)
class UMBmarkEstimates:
    """What the UMBmark equations give for one bi-directional experiment.

    Attributes:
        alpha: Type A error α per corner [rad] (mean of the components used).
        beta: Type B error β per leg [rad] (mean of the components used).
        radius: R = (L/2)/sin(β/2) of the mean β [m] (``inf`` for β = 0), Eq. 6.23.
        e_d: E_d = D_R/D_L relative to the odometry that drove (mean of E_d,x and E_d,y when
            both are used, footnote 2 of Borenstein & Feng 1994, §6.3) [-].
        e_b: E_b = b_actual/b relative to the odometry that drove (likewise averaged) [-].
        alpha_x, beta_x, alpha_y, beta_y: the per-component angles [rad] (``nan`` if unused).
    """

    alpha: float
    beta: float
    radius: float
    e_d: float
    e_b: float
    alpha_x: float = math.nan
    beta_x: float = math.nan
    alpha_y: float = math.nan
    beta_y: float = math.nan

    def as_dict(self) -> dict[str, float]:
        """Named as in Borenstein & Feng 1994 (``alpha``, ``beta``, ``R``, ``E_d``, ``E_b``, …)."""
        out = {
            "alpha": self.alpha,
            "beta": self.beta,
            "R": self.radius,
            "E_d": self.e_d,
            "E_b": self.e_b,
        }
        for name in ("alpha_x", "beta_x", "alpha_y", "beta_y"):
            value = float(getattr(self, name))
            if not math.isnan(value):
                out[name] = value
        return out


def umbmark_estimates(
    cw_errors: ArrayLike,
    ccw_errors: ArrayLike,
    side: float,
    wheelbase: float,
    *,
    use: Components = "xy",
    ed_wheelbase: EdWheelbase = "nominal",
) -> UMBmarkEstimates:
    """α, β, R, E_d and E_b from cw and ccw return errors — Borenstein & Feng 1994, Eqs. 6.22–6.29.

    Args:
        cw_errors, ccw_errors: return errors (n, ≥2) [m], start frame (see the module
            docstring); a third (heading) column is ignored.
        side: square side L [m].
        wheelbase: the wheelbase b the odometry used while driving [m] (Eq. 6.24).
        use: ``"xy"`` (compute E_d and E_b from x and from y and average them, footnote 2 of
            §6.3), ``"x"`` (Eqs. 6.22a, 6.26a only, as the OptiOdom authors) or ``"y"``.
        ed_wheelbase: ``"nominal"``: b in Eq. 6.24 as written; ``"corrected"``: E_b·b, as the
            OptiOdom authors' ``main.m``.
    """
    if not side > 0.0 or not wheelbase > 0.0:
        raise ValueError(f"side and wheelbase must be > 0, got {side}, {wheelbase}")
    cg_cw = centre_of_gravity(cw_errors)
    cg_ccw = centre_of_gravity(ccw_errors)
    denom = -4.0 * side
    angles: dict[str, tuple[float, float]] = {}
    if use in ("xy", "x"):
        angles["x"] = (
            float(cg_cw[0] + cg_ccw[0]) / denom,  # α, Eq. 6.26a
            float(cg_cw[0] - cg_ccw[0]) / denom,  # β, Eq. 6.22a
        )
    if use in ("xy", "y"):
        angles["y"] = (
            float(cg_cw[1] - cg_ccw[1]) / denom,  # α, Eq. 6.26b
            float(cg_cw[1] + cg_ccw[1]) / denom,  # β, Eq. 6.22b
        )
    if not angles:
        raise ValueError(f"use must be 'xy', 'x' or 'y', got {use!r}")
    e_bs, e_ds = [], []
    for alpha, beta in angles.values():
        e_b = e_b_from_alpha(alpha)
        b = e_b * wheelbase if ed_wheelbase == "corrected" else wheelbase
        e_bs.append(e_b)
        e_ds.append(e_d_from_beta(beta, side, b))
    alpha = float(np.mean([a for a, _ in angles.values()]))
    beta = float(np.mean([b for _, b in angles.values()]))
    radius = math.inf if beta == 0.0 else 0.5 * side / math.sin(0.5 * beta)
    ax, bx = angles.get("x", (math.nan, math.nan))
    ay, by = angles.get("y", (math.nan, math.nan))
    return UMBmarkEstimates(
        alpha=alpha,
        beta=beta,
        radius=radius,
        e_d=float(np.mean(e_ds)),
        e_b=float(np.mean(e_bs)),
        alpha_x=ax,
        beta_x=bx,
        alpha_y=ay,
        beta_y=by,
    )


# ------------------------------------------------------------------------ shared procedure steps
def perform_squares(
    lab: Lab, calibration: Calibration, side: float, runs: int
) -> tuple[list[Run], list[Run]]:
    """Drive ``runs`` cw squares, then ``runs`` ccw squares of side ``side`` [m]."""
    cw_experiment, ccw_experiment = square_experiments(side, runs)
    cw = lab.perform(cw_experiment, calibration)
    ccw = lab.perform(ccw_experiment, calibration)
    return cw, ccw


def optiodom_update(robot: RobotSpec, current: Calibration, e_d: float, e_b: float) -> Calibration:
    """The OptiOdom authors' parameter update (``main.m``): b ← E_b·b and the mean D_a of the
    current diameters split as D_R = 2·D_a/(1 + 1/E_d), D_L = 2·D_a/(1 + E_d) [m].

    Unlike :meth:`Calibration.then`, E_d *replaces* the current diameter ratio; the two agree
    when the current D_R = D_L (all the published square sessions).
    """
    params = current.parameters(robot)
    mean = 0.5 * (params["right_diameter"] + params["left_diameter"])
    return Calibration.from_parameters(
        robot,
        wheelbase=e_b * params["wheelbase"],
        right_diameter=2.0 * mean / (1.0 + 1.0 / e_d),
        left_diameter=2.0 * mean / (1.0 + e_d),
    )


def _return_errors(
    runs: list[Run], robot: RobotSpec, calibration: Calibration, conventions: UMBmarkConventions
) -> FloatArray:
    optiodom = conventions is UMBmarkConventions.OPTIODOM
    frame: Literal["start", "world"] = "world" if optiodom else "start"
    return np.array([return_error(r, robot, calibration, frame=frame) for r in runs])


# ------------------------------------------------------------------------ the calibrator
class UMBmarkConventions(StrEnum):
    """Whose equations and frames :class:`UMBmark` follows (see the module docstring)."""

    UMBMARK = "umbmark"  # Borenstein & Feng 1994, §6, with solderspot 2014's E_s phase
    OPTIODOM = "optiodom"  # the OptiOdom authors' src/diff/umbmark/main.m


@dataclass(frozen=True)
class UMBmarkOptions(SquareOptions):
    """The settings of :class:`UMBmark` (see its Args); ``side`` [m] and
    ``runs_per_direction`` from :class:`~odomgym.baselines.base.SquareOptions`.

    ``use = None`` and ``scale_phases = None`` mean "the conventions' default" (``"xy"`` and 2
    for umbmark, ``"x"`` and 0 for optiodom), resolved by :class:`UMBmark`.
    """

    use: Components | None = None
    conventions: UMBmarkConventions = UMBmarkConventions.UMBMARK
    scale_phases: int | None = None
    straight_runs: int = 3
    straight_distance: float = 2.0
    second_compensation: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        conventions = parse_choice(UMBmarkConventions, self.conventions, field="conventions")
        object.__setattr__(self, "conventions", conventions)
        if self.use is not None:
            require_choice("use", self.use, ("xy", "x", "y"))
        if self.scale_phases is not None:
            require_count("scale_phases", self.scale_phases, 0)
        require_count("straight_runs", self.straight_runs, 1)
        require_positive("straight_distance", self.straight_distance)
        if not isinstance(self.second_compensation, bool):
            raise SpecError(
                f"second_compensation must be true or false, got {self.second_compensation!r}",
                field="second_compensation",
            )
        if conventions is UMBmarkConventions.OPTIODOM and (
            self.scale_phases or self.second_compensation
        ):
            raise SpecError(
                "the OptiOdom authors' UMBmark has no E_s phase and no second compensation",
                field="scale_phases" if self.scale_phases else "second_compensation",
            )


# mypy cannot follow the setuptools package-dir mapping odomgym.baselines → baselines/, so
# to it Calibrator is Any; drop the ignore once that mapping is visible to mypy.
class UMBmark(SquaresSizing):
    """UMBmark (Borenstein & Feng 1994, §6) with the E_s phase and iteration of solderspot 2014.

    Procedure (default ``conventions="umbmark"``):

    1. **E_s phase** (solderspot 2014), ``scale_phases`` times: drive ``straight_runs`` straight
       runs of ``straight_distance`` [m]; E_s = mean(true distance / odometric distance)
       (start-to-end displacements); the odometry's distance scale is multiplied by E_s. Skipped,
       with a note, if the lab has no straight runs (it raises ``LookupError``).
    2. **Squares**: ``runs_per_direction`` cw then as many ccw squares of side ``side`` [m];
       return errors in the start frame; E_d and E_b by :func:`umbmark_estimates`; the odometry
       is corrected by c_L, c_R (Eqs. 6.33–6.34) and b ← E_b·b (Eq. 6.28), multiplying any
       correction already in place (solderspot 2014).
    3. **Second compensation** (optional, Borenstein & Feng 1994, §6.3): repeat the squares with
       the new calibration; if E_max,syst > 3·SEM
       (:func:`odomgym.odometry.umbmark_measures.summarize_umbmark`), correct again on top of the
       first correction.

    Args:
        side: square side L [m] (Borenstein & Feng 1994: 4 m).
        runs_per_direction: squares per direction (Borenstein & Feng 1994: 5).
        use: ``"xy"`` (default; footnote 2), ``"x"`` or ``"y"``; see :func:`umbmark_estimates`.
        conventions: a :class:`UMBmarkConventions` or its spelling, ``"umbmark"`` or
            ``"optiodom"`` (see the module docstring); the latter defaults ``use`` to ``"x"``
            and refuses an E_s phase or a second compensation.
        scale_phases: E_s phases (default 2 as solderspot 2014; 0 with optiodom conventions).
        straight_runs: straight runs per E_s phase (solderspot 2014: 3).
        straight_distance: straight-run length [m] (solderspot 2014: 2 m).
        second_compensation: whether to verify and, if the 3×SEM rule advises, correct again.
    """

    name: ClassVar[str] = "umbmark"
    reference: ClassVar[str] = (
        "J. Borenstein, L. Feng, UMBmark — A Method for Measuring, Comparing, and Correcting "
        "Dead-reckoning Errors in Mobile Robots, Univ. of Michigan TR UM-MEAM-94-22, 1994, §6"
    )
    options_type: ClassVar[type[UMBmarkOptions]] = UMBmarkOptions

    @classmethod
    def budget_options(cls, runs: int) -> dict[str, Any]:
        """The procedure of solderspot 2014 when the budget allows (2 E_s phases of 3 straight
        runs + 5 + 5 squares)."""
        if runs >= 16:
            return {"scale_phases": 2, "straight_runs": 3, "runs_per_direction": (runs - 6) // 2}
        if runs >= 6:
            return {"scale_phases": 1, "straight_runs": 2, "runs_per_direction": (runs - 2) // 2}
        return {"scale_phases": 0, "runs_per_direction": max(1, runs // 2)}

    def __init__(
        self,
        side: float = 4.0,
        runs_per_direction: int = 5,
        *,
        use: Components | None = None,
        conventions: UMBmarkConventions | str = UMBmarkConventions.UMBMARK,
        scale_phases: int | None = None,
        straight_runs: int = 3,
        straight_distance: float = 2.0,
        second_compensation: bool = False,
    ) -> None:
        options = UMBmarkOptions(
            side=side,
            runs_per_direction=runs_per_direction,
            use=use,
            conventions=parse_choice(UMBmarkConventions, conventions, field="conventions"),
            scale_phases=scale_phases,
            straight_runs=straight_runs,
            straight_distance=straight_distance,
            second_compensation=second_compensation,
        )
        compat = options.conventions is UMBmarkConventions.OPTIODOM
        self.options = options
        self.side = options.side
        self.runs_per_direction = options.runs_per_direction
        self.conventions = options.conventions
        self.use: Components = options.use if options.use is not None else ("x" if compat else "xy")
        self.scale_phases = (
            options.scale_phases if options.scale_phases is not None else (0 if compat else 2)
        )
        self.straight_runs = options.straight_runs
        self.straight_distance = options.straight_distance
        self.second_compensation = options.second_compensation

    def experiments(self) -> list[Experiment]:
        """E_s phases (straight runs), the cw and ccw squares, and the verification squares."""
        straight = Experiment(
            ExperimentKind.STRAIGHT, None, self.straight_runs, self.straight_distance
        )
        squares: list[Experiment] = square_experiments(self.side, self.runs_per_direction)
        verify = squares if self.second_compensation else []
        return [straight] * self.scale_phases + squares + verify

    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        """Run the procedure in ``lab`` from ``initial`` (default: uncalibrated)."""
        require_differential(initial, self.name)
        robot = lab.robot
        runs0, dist0 = lab.runs_used, lab.distance_used
        calibration = initial if initial is not None else Calibration()
        estimates: dict[str, float] = {}
        notes: list[str] = []

        if self.scale_phases:
            calibration = self._scale_phases(lab, calibration, estimates, notes)

        cw, ccw = perform_squares(lab, calibration, self.side, self.runs_per_direction)
        calibration, found = self._compensate(robot, calibration, cw, ccw, "")
        estimates.update(found)

        if self.second_compensation:
            cw, ccw = perform_squares(lab, calibration, self.side, self.runs_per_direction)
            cw_err = _return_errors(cw, robot, calibration, self.conventions)
            ccw_err = _return_errors(ccw, robot, calibration, self.conventions)
            summary = summarize_umbmark(cw_err, ccw_err)
            estimates["E_max_syst_after_1"] = summary.e_max_syst
            estimates["SEM_after_1"] = summary.sem
            if not math.isfinite(summary.sem):
                notes.append(
                    "second compensation not decided: the 3·SEM rule needs at least two runs "
                    "per direction"
                )
            elif summary.second_compensation_advised:
                calibration, found = self._compensate(robot, calibration, cw, ccw, "_2")
                estimates.update(found)
                notes.append(
                    f"second compensation applied: E_max,syst = {summary.e_max_syst * 1e3:.1f} mm"
                    f" > 3·SEM = {3 * summary.sem * 1e3:.1f} mm after the first"
                )
            else:
                notes.append(
                    f"second compensation not advised: E_max,syst = "
                    f"{summary.e_max_syst * 1e3:.1f} mm ≤ 3·SEM = {3 * summary.sem * 1e3:.1f} mm"
                )
        return CalibrationResult(
            calibration=calibration,
            estimates=estimates,
            runs_used=lab.runs_used - runs0,
            distance_used=lab.distance_used - dist0,
            notes=notes,
        )

    def _scale_phases(
        self,
        lab: Lab,
        calibration: Calibration,
        estimates: dict[str, float],
        notes: list[str],
    ) -> Calibration:
        """The E_s phases of solderspot 2014: E_s = mean(true / odometric straight-run distance)."""
        experiment = Experiment(
            ExperimentKind.STRAIGHT, None, self.straight_runs, self.straight_distance
        )
        e_s_total, done = 1.0, 0
        for phase in range(1, self.scale_phases + 1):
            try:
                runs = lab.perform(experiment, calibration)
            except LookupError as exc:
                notes.append(f"E_s phase {phase} skipped: the lab has no straight runs ({exc})")
                break
            ratios = []
            for run in runs:
                odom = replay_odometry(run, lab.robot, calibration)
                true = float(np.hypot(*(run.true_pose[-1, :2] - run.true_pose[0, :2])))
                reported = float(np.hypot(*(odom[-1, :2] - odom[0, :2])))
                if not reported > 0.0:
                    raise ValueError(f"{run.source}: the odometry reports no straight travel")
                ratios.append(true / reported)
            e_s = float(np.mean(ratios))
            estimates[f"E_s_{phase}"] = e_s
            e_s_total *= e_s
            done += 1
            calibration = calibration.then(Calibration(distance_scale=e_s))
        if done:
            estimates["E_s"] = e_s_total
        return calibration

    def _compensate(
        self,
        robot: RobotSpec,
        calibration: Calibration,
        cw: list[Run],
        ccw: list[Run],
        suffix: str,
    ) -> tuple[Calibration, dict[str, float]]:
        """One UMBmark correction from the squares driven with ``calibration``."""
        cw_err = _return_errors(cw, robot, calibration, self.conventions)
        ccw_err = _return_errors(ccw, robot, calibration, self.conventions)
        compat = self.conventions is UMBmarkConventions.OPTIODOM
        found = umbmark_estimates(
            cw_err,
            ccw_err,
            self.side,
            calibration.wheelbase_scale * robot.wheelbase,
            use=self.use,
            ed_wheelbase="corrected" if compat else "nominal",
        )
        summary = summarize_umbmark(cw_err, ccw_err)
        values = found.as_dict()
        values.update(
            x_cg_cw=summary.cg_cw[0],
            y_cg_cw=summary.cg_cw[1],
            x_cg_ccw=summary.cg_ccw[0],
            y_cg_ccw=summary.cg_ccw[1],
            E_max_syst=summary.e_max_syst,
            SEM=summary.sem,
        )
        if compat:
            updated = optiodom_update(robot, calibration, found.e_d, found.e_b)
        else:
            updated = calibration.then(Calibration.from_errors(found.e_d, found.e_b))
        return updated, {f"{k}{suffix}": v for k, v in values.items()}

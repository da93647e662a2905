"""Trajectory optimisation: fit (b, D_R, D_L) to whole ground-truth trajectories (OptiOdom).

R. B. Sousa, M. R. Petry, A. P. Moreira, P. Costa, *OptiOdom: a Generic Approach for Odometry
Calibration of Wheeled Mobile Robots*, J. Intell. Robot. Syst. 105:39, 2022
(github.com/sousarbarb/optiodom). Where UMBmark and its successors read a few numbers off the
*end* of prescribed manoeuvres, OptiOdom replays the encoder counts of runs of *any* shape with
candidate parameters and minimises the position error against the ground truth along the whole
trajectory:

    min over (b, D_R, D_L) of  Σ_runs Σ_k ‖p_odo,k(b, D_R, D_L) − p_gt,k‖²

with p_odo the odometry of :mod:`odomgym.odometry.calibration` (midpoint integration, started at the
first ground-truth pose, as the authors' ``simulateRobot_diff.m``) and k over the samples of each
run (every sample by default; the authors sample every ``sampleDist`` = 0.5 m of travel, available
as ``sample_distance``). The authors minimise it with iRprop−; here it is
:func:`scipy.optimize.least_squares` (trust-region reflective) with the analytic Jacobian of
:func:`odomgym.odometry.runs.replay_with_jacobian`, which converges in a handful of evaluations.

**Parameters and units.** The fit works on the logarithms of the three effective parameters the
odometry uses, x = (ln D_L/D_L0, ln D_R/D_R0, ln b/b0), starting at the calibration in place
(x = 0); D_L, D_R are wheel diameters [m] and b the wheelbase [m]. The result is expressed as an
absolute :class:`~odomgym.odometry.calibration.Calibration` (:meth:`Calibration.from_parameters`).

**Frames.** Residuals are odometry − ground truth positions [m] in the ground-truth frame; the
odometry starts at the first ground-truth pose, so the first sample's residual is zero and is
left out. Headings enter only through the positions (the paper's cost) unless
``heading_weight`` > 0 adds heading residuals [rad] times that length [m/rad].

**What it needs.** Turning *while* the position is observed: squares, circles and free paths
determine all three parameters (Jacobian condition numbers 18–24 on the OptiOdom square and
circular sessions, 56 on simulated 4 m squares), but an in-place spin moves no position, so on
straight-and-spin runs the position-only cost leaves b free (condition numbers 140–3600; b
drifts to 0.05–0.19 m on the OptiOdom Ivanjko sessions, as the authors' own OptiOdom row for
session 250620201655 shows with b = 0.1935 m). ``heading_weight`` = 0.2 m/rad restores it.
On the four OptiOdom square sessions the fit reaches largest position errors over all samples
of 14–22 mm, no larger than the authors' iRprop− results (15–23 mm).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from odomgym.baselines.base import (
    CalibrationResult,
    Holdings,
    SquaresSizing,
    perform,
    require_choice,
    square_experiments,
)
from odomgym.errors import SpecError, require_count, require_finite, require_positive
from odomgym.lab.experiment import Experiment, ExperimentKind, Lab, parse_choice
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run, replay_with_jacobian, require_differential
from odomgym.robot import RobotSpec

__all__ = [
    "POOR_CONDITION",
    "TRAJECTORY_PATHS",
    "Trajectory",
    "TrajectoryBaseline",
    "TrajectoryFit",
    "TrajectoryOptions",
    "fit_trajectories",
    "sample_indices",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]


def sample_indices(run: Run, sample_distance: float | None = None) -> IntArray:
    """The measured samples of ``run`` whose errors enter the cost (never the first, always the
    last measured one). Samples without ground truth (gaps: NaN poses) are never picked.

    ``None``: every measured sample. Otherwise the first measured sample after each further
    ``sample_distance`` metres of ground-truth travel (the authors' ``sampleDist``; across a
    gap, the straight line between the measured positions on either side), and the last one; a
    run that turns in place and never travels that far contributes its last sample only.
    """
    if sample_distance is not None and not sample_distance > 0.0:
        raise ValueError(f"sample_distance must be > 0 [m], got {sample_distance}")
    pose = run.true_pose
    known: NDArray[np.bool_] = np.asarray(np.isfinite(pose).any(axis=1))
    measured = np.flatnonzero(known[1:]) + 1
    if sample_distance is None or not len(measured):
        return measured.astype(np.intp)
    placed = np.flatnonzero(np.isfinite(pose[:, :2]).all(axis=1))
    if not len(placed):
        return measured[-1:].astype(np.intp)
    steps = np.hypot(*np.diff(pose[placed, :2], axis=0).T)
    travelled = np.interp(measured, placed, np.concatenate([[0.0], np.cumsum(steps)]))
    marks = np.floor(np.concatenate([[0.0], travelled]) / sample_distance)
    picked = measured[np.diff(marks) > 0]
    return np.unique(np.concatenate([picked, measured[-1:]])).astype(np.intp)


@dataclass(frozen=True)
class TrajectoryFit:
    """The result of :func:`fit_trajectories`.

    Attributes:
        calibration: the fitted calibration (absolute).
        parameters: the fitted b, D_R, D_L [m] (keys ``wheelbase``, ``right_diameter``,
            ``left_diameter``).
        rms_before, rms_after: RMS position error ‖p_odo − p_gt‖ over the samples used [m],
            with the starting and with the fitted calibration.
        relative_std: standard errors of the relative changes of (D_L, D_R, b) [-] from the
            Gauss–Newton covariance s²·(JᵀJ)⁻¹, s² the residual variance: how well the runs
            pin each parameter down (it ignores the correlation of successive samples' errors,
            so it is optimistic).
        condition: condition number of the Jacobian at the solution [-]; large values
            (hundreds and more) mean the runs hardly tell the parameters apart.
        residuals: number of scalar residuals.
        evaluations: cost-function evaluations.
    """

    calibration: Calibration
    parameters: dict[str, float]
    rms_before: float
    rms_after: float
    relative_std: tuple[float, float, float]
    condition: float
    residuals: int
    evaluations: int


#: Jacobian condition number above which :class:`Trajectory` warns in its notes [-]. Measured:
#: 18–24 on the OptiOdom square and circular sessions, 56 on 4 m simulated squares, 140–3600 on
#: the straight-run-and-spin sessions, where b is not identifiable from positions.
POOR_CONDITION = 100.0


def fit_trajectories(
    runs: Sequence[Run],
    robot: RobotSpec,
    initial: Calibration | None = None,
    *,
    sample_distance: float | None = None,
    heading_weight: float = 0.0,
    loss: str = "linear",
) -> TrajectoryFit:
    """Fit D_L, D_R and b to the ground-truth trajectories of ``runs`` (Sousa et al. 2022).

    Args:
        runs: runs of any shape (squares, circles, straight runs, free paths).
        robot: the nominal robot (its ``metres_per_tick`` and ``wheelbase``).
        initial: the starting calibration (default: uncalibrated).
        sample_distance: use samples every so many metres of travel [m] (the authors: 0.5);
            ``None`` (default): every sample.
        heading_weight: also fit the heading errors, weighted by this length [m/rad] (0, the
            default, is the paper's position-only cost). Needed for runs that turn without
            translating: an in-place spin moves no position, so a position-only cost cannot
            see b in it (on the OptiOdom straight-and-spin sessions it drives b to 0.05–0.19 m
            instead of 0.2 m).
        loss: :func:`scipy.optimize.least_squares` loss (``"linear"``; ``"soft_l1"`` or
            ``"huber"`` to down-weight outliers such as slip), with scale 5 mm.

    Ground-truth gaps (NaN pose components) are left out of the cost component by component:
    a residual exists where its measured value does. Heading errors are wrapped to [−π, π), so
    a heading unwrapped the wrong way round across a gap (``odomgym.data.native``) costs
    nothing.

    Raises:
        SpecError: runs that do not determine the parameters at all (a singular Jacobian, e.g.
            only straight runs), a run whose first sample has no full pose (the odometry
            starts there), or runs without a measured pose after their first sample.
        ValueError: no runs, or a negative ``heading_weight``.
    """
    if not runs:
        raise ValueError("trajectory optimisation needs at least one run")
    if not heading_weight >= 0.0:
        raise ValueError(f"heading_weight must be >= 0 [m/rad], got {heading_weight}")
    for run in runs:
        if not np.isfinite(run.true_pose[0]).all():
            raise SpecError(
                "trajectory optimisation replays each run from its first ground-truth pose, "
                "but this run's first sample has no full pose (x, y and theta)",
                field="x",
                source=run.source,
            )
    start = initial if initial is not None else Calibration()
    base = start.parameters(robot)
    rows = [0, 1, 2] if heading_weight > 0.0 else [0, 1]
    weights = np.array([1.0, 1.0, heading_weight])[rows]
    chosen = [sample_indices(run, sample_distance) for run in runs]
    truth = np.concatenate(
        [run.true_pose[idx][:, rows] for run, idx in zip(runs, chosen, strict=True)]
    )
    measured = np.isfinite(truth)  # the residuals there are; gaps are left out
    placed = measured[:, 0] & measured[:, 1]
    if not measured.any():
        raise SpecError(
            "trajectory optimisation needs measured poses after the runs' first samples, and "
            "these runs have none",
            field="x",
        )

    def calibration_at(x: FloatArray) -> Calibration:
        return Calibration.from_parameters(
            robot,
            wheelbase=base["wheelbase"] * math.exp(x[2]),
            right_diameter=base["right_diameter"] * math.exp(x[1]),
            left_diameter=base["left_diameter"] * math.exp(x[0]),
        )

    cache: dict[bytes, tuple[FloatArray, FloatArray]] = {}

    def evaluate(x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Errors (samples, rows) [m, rad], NaN in gaps, heading wrapped, and the weighted
        Jacobian of the measured ones (measured components, 3)."""
        key = np.asarray(x, dtype=float).tobytes()
        if key not in cache:
            cache.clear()
            cal = calibration_at(x)
            poses, jacs = [], []
            for run, idx in zip(runs, chosen, strict=True):
                pose, jac = replay_with_jacobian(run, robot, cal)
                poses.append(pose[idx][:, rows])
                jacs.append(jac[idx][:, rows, :])
            errors = np.concatenate(poses) - truth
            if len(rows) == 3:
                errors[:, 2] = np.mod(errors[:, 2] + math.pi, 2.0 * math.pi) - math.pi
            jacobian = (np.concatenate(jacs) * weights[None, :, None])[measured]
            cache[key] = (errors, jacobian)
        return cache[key]

    def residual(x: FloatArray) -> FloatArray:
        weighted: FloatArray = (evaluate(x)[0] * weights)[measured]
        return weighted

    def rms_position(errors: FloatArray) -> float:
        if not placed.any():
            return math.nan
        return float(np.sqrt(np.mean(errors[placed, 0] ** 2 + errors[placed, 1] ** 2)))

    x0 = np.zeros(3)
    errors0, jacobian0 = evaluate(x0)
    if np.linalg.matrix_rank(jacobian0) < 3:
        raise SpecError(
            "the runs do not tell D_L, D_R and b apart (singular Jacobian): they need both "
            "straight travel and turning",
            field="runs",
        )
    solution = least_squares(
        residual,
        x0,
        jac=lambda x: evaluate(x)[1],
        method="trf",
        loss=loss,
        f_scale=0.005,
        x_scale=1e-3,
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
    )
    x = np.asarray(solution.x, dtype=float)
    errors, jacobian = evaluate(x)
    final = residual(x)
    variance = float(final @ final) / max(final.size - 3, 1)
    std = np.sqrt(np.clip(np.diag(variance * np.linalg.pinv(jacobian.T @ jacobian)), 0.0, None))
    calibration = calibration_at(x)
    return TrajectoryFit(
        calibration=calibration,
        parameters=calibration.parameters(robot),
        rms_before=rms_position(errors0),
        rms_after=rms_position(errors),
        relative_std=(float(std[0]), float(std[1]), float(std[2])),
        condition=float(np.linalg.cond(jacobian)),
        residuals=int(final.size),
        evaluations=int(solution.nfev),
    )


@dataclass(frozen=True)
class TrajectoryBaseline:
    """The baseline of ``odomgym diagnose`` (:class:`odomgym.diagnose.heldout.Baseline`): the
    3-parameter calibration a user already trusts, (b, D_R, D_L) by :func:`fit_trajectories` on
    the diagnosis's fit runs (their measurement nuisances removed), as the robot with that true
    geometry.

    ``heading_weight`` (0.2 m/rad, as :class:`TrajectoryOptions` recommends for in-place spins)
    makes it determine b on runs of any kind, straight-and-spin sessions included; the paper's
    position-only cost would leave b free there.
    """

    heading_weight: float = 0.2
    name: str = "trajectory optimisation (Sousa et al. 2022), heading weight 0.2 m/rad"

    def __call__(self, runs: Sequence[Run], robot: RobotSpec) -> RobotSpec:
        """The robot with the geometry fitted to ``runs``.

        Raises:
            SpecError: the runs cannot determine it (:func:`fit_trajectories`), or determine
                it so poorly that the fit leaves the range a robot may have (runs that all
                drive straight, or all turn in place, nearly singular), saying that
                ``odomgym diagnose --no-baseline`` leaves the baseline out.
        """
        try:
            fit = fit_trajectories(runs, robot, heading_weight=self.heading_weight)
            b = fit.parameters["wheelbase"]
            right, left = fit.parameters["right_diameter"], fit.parameters["left_diameter"]
            return robot.with_errors(
                e_d=right / left,
                e_b=b / robot.wheelbase,
                e_s=0.5 * (right + left) / robot.wheel_diameter,
            )
        except SpecError as exc:
            # A geometry a factor of two or more from the robot file is seldom the robot's: the
            # usual causes are the logs' units and wiring (a user's logs with theta in degrees,
            # mm, swapped wheels or a flipped encoder all ended here).
            hint = (
                "; a factor of 2 or more from the robot file: check the logs' units (x, y in "
                "m, theta in rad, t in s), the wiring (left and right columns, each encoder's "
                "sign) and the robot file"
                if "must lie within" in str(exc)
                else ""
            )
            raise SpecError(
                f"the baseline calibration cannot be fitted to these runs: {exc}{hint} "
                "(--no-baseline leaves it out)",
                field=exc.field,
            ) from None


#: The runs :class:`Trajectory` can ask a lab for: each turns while it moves, so positions
#: alone determine D_L, D_R and b (a spin does not move; straight runs do not turn).
TRAJECTORY_PATHS: tuple[ExperimentKind, ...] = (
    ExperimentKind.SQUARE,
    ExperimentKind.CIRCULAR,
    ExperimentKind.FREE,
)

#: Losses of :func:`scipy.optimize.least_squares`.
LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")


@dataclass(frozen=True)
class TrajectoryOptions:
    """The settings of :class:`Trajectory` (see its Args for meaning and units)."""

    side: float = 4.0
    runs_per_direction: int = 3
    path: ExperimentKind = ExperimentKind.SQUARE
    radius: float = 1.0
    laps: float = 1.0
    free_runs: int = 3
    free_length: float = 10.0
    straight_runs: int = 0
    straight_distance: float = 3.0
    sample_distance: float | None = None
    heading_weight: float = 0.0
    loss: str = "linear"

    def __post_init__(self) -> None:
        path = parse_choice(ExperimentKind, self.path, field="path")
        if path not in TRAJECTORY_PATHS:
            raise SpecError(
                f"path must be one of {', '.join(repr(k.value) for k in TRAJECTORY_PATHS)} "
                f"(runs that turn while they move), got {path.value!r}",
                field="path",
            )
        object.__setattr__(self, "path", path)
        require_positive("side", self.side)
        require_count("runs_per_direction", self.runs_per_direction, 1)
        require_positive("radius", self.radius)
        require_positive("laps", self.laps)
        require_count("free_runs", self.free_runs, 1)
        require_positive("free_length", self.free_length)
        require_count("straight_runs", self.straight_runs, 0)
        require_positive("straight_distance", self.straight_distance)
        if self.sample_distance is not None:
            require_positive("sample_distance", self.sample_distance)
        if require_finite("heading_weight", self.heading_weight) < 0.0:
            raise SpecError(
                f"heading_weight must be >= 0 [m/rad], got {self.heading_weight}",
                field="heading_weight",
            )
        require_choice("loss", self.loss, LOSSES)


class Trajectory(SquaresSizing):
    """OptiOdom-style trajectory optimisation (Sousa et al. 2022) over the runs it performs.

    The runs (``path``): ``"square"`` (default) — ``runs_per_direction`` cw and as many ccw
    UMBmark squares of side ``side`` [m]; ``"circular"`` — ``runs_per_direction`` cw and as
    many ccw circles of radius ``radius`` [m], ``laps`` laps each; ``"free"`` — ``free_runs``
    free paths of ``free_length`` [m] (recorded, or the simulator's random arcs,
    :func:`odomgym.sim.arc_runs.free_plan`). Squares suffice: the legs' lateral drift fixes
    D_R/D_L, the corners fix b relative to the mean diameter, and the positions *along* the legs fix
    the mean diameter — which return errors alone cannot see. Circles need both directions: one
    circle fixes the mean diameter and one combination of D_R/D_L and b (its curvature); the
    circle turning the other way fixes the other. ``straight_runs`` adds straight runs of
    ``straight_distance`` [m] (more scale information; the default 0 keeps the budget of a
    UMBmark run).

    Args:
        side: square side L [m].
        runs_per_direction: squares or circles per direction.
        path: which runs to ask for: an :class:`~odomgym.lab.experiment.ExperimentKind` among
            :data:`TRAJECTORY_PATHS`, or its spelling.
        radius: circle radius [m].
        laps: laps per circular run [-].
        free_runs: free runs.
        free_length: length of a simulated free run [m] (recorded ones are served whatever
            their length).
        straight_runs: additional straight runs (0: none).
        straight_distance: their length [m].
        sample_distance: see :func:`fit_trajectories` [m].
        heading_weight: see :func:`fit_trajectories` [m/rad] (0: the paper's cost).
        loss: see :func:`fit_trajectories`.
    """

    name: ClassVar[str] = "trajectory"
    reference: ClassVar[str] = (
        "R. B. Sousa, M. R. Petry, A. P. Moreira, P. Costa, OptiOdom: a Generic Approach for "
        "Odometry Calibration of Wheeled Mobile Robots, J. Intell. Robot. Syst. 105:39, 2022"
    )
    options_type: ClassVar[type[TrajectoryOptions]] = TrajectoryOptions

    @classmethod
    def session_options(cls, held: Holdings) -> dict[str, Any]:
        """Squares if the session has them, else circles, else free runs; otherwise the
        defaults (and the lab says what is missing)."""
        if held.runs(ExperimentKind.SQUARE, "cw"):
            return {"path": ExperimentKind.SQUARE, **held.square_options()}
        if held.runs(ExperimentKind.CIRCULAR, "cw"):
            circles = held.runs(ExperimentKind.CIRCULAR, "cw")
            return {"path": ExperimentKind.CIRCULAR, "runs_per_direction": circles}
        if held.runs(ExperimentKind.FREE):
            return {"path": ExperimentKind.FREE, "free_runs": held.runs(ExperimentKind.FREE)}
        return {}

    def __init__(
        self,
        side: float = 4.0,
        runs_per_direction: int = 3,
        *,
        path: ExperimentKind | str = ExperimentKind.SQUARE,
        radius: float = 1.0,
        laps: float = 1.0,
        free_runs: int = 3,
        free_length: float = 10.0,
        straight_runs: int = 0,
        straight_distance: float = 3.0,
        sample_distance: float | None = None,
        heading_weight: float = 0.0,
        loss: str = "linear",
    ) -> None:
        self.options = TrajectoryOptions(
            side=side,
            runs_per_direction=runs_per_direction,
            path=parse_choice(ExperimentKind, path, field="path"),
            radius=radius,
            laps=laps,
            free_runs=free_runs,
            free_length=free_length,
            straight_runs=straight_runs,
            straight_distance=straight_distance,
            sample_distance=sample_distance,
            heading_weight=heading_weight,
            loss=loss,
        )
        options = self.options
        self.side = options.side
        self.runs_per_direction = options.runs_per_direction
        self.path = options.path
        self.straight_runs = options.straight_runs
        self.straight_distance = options.straight_distance
        self.sample_distance = options.sample_distance
        self.heading_weight = options.heading_weight
        self.loss = options.loss

    def experiments(self) -> list[Experiment]:
        """The runs of ``path``, then the optional straight runs."""
        options = self.options
        out: list[Experiment]
        if options.path is ExperimentKind.SQUARE:
            out = square_experiments(options.side, options.runs_per_direction)
        elif options.path is ExperimentKind.CIRCULAR:
            out = [
                Experiment(
                    ExperimentKind.CIRCULAR,
                    direction,
                    options.runs_per_direction,
                    options.radius,
                    laps=options.laps,
                )
                for direction in ("cw", "ccw")
            ]
        else:
            out = [Experiment(ExperimentKind.FREE, None, options.free_runs, options.free_length)]
        if options.straight_runs:
            out.append(
                Experiment(
                    ExperimentKind.STRAIGHT, None, options.straight_runs, options.straight_distance
                )
            )
        return out

    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        """Perform the experiments with ``initial`` active and fit (b, D_R, D_L) to them."""
        require_differential(initial, self.name)
        runs0, dist0 = lab.runs_used, lab.distance_used
        calibration = initial if initial is not None else Calibration()
        runs: list[Run] = []
        for experiment in self.experiments():
            runs.extend(
                perform(
                    lab,
                    experiment,
                    calibration,
                    method="trajectory optimisation",
                    hint=" (choose the runs with path = 'square', 'circular' or 'free'; or "
                    "call fit_trajectories(runs, robot) on runs of any shape)",
                )
            )
        fit = fit_trajectories(
            runs,
            lab.robot,
            calibration,
            sample_distance=self.sample_distance,
            heading_weight=self.heading_weight,
            loss=self.loss,
        )
        estimates = {
            "b": fit.parameters["wheelbase"],
            "D_R": fit.parameters["right_diameter"],
            "D_L": fit.parameters["left_diameter"],
            "E_d": fit.calibration.e_d,
            "E_b": fit.calibration.wheelbase_scale,
            "E_s": fit.calibration.distance_scale,
            "rms_before": fit.rms_before,
            "rms_after": fit.rms_after,
            "std_D_L": fit.relative_std[0] * fit.parameters["left_diameter"],
            "std_D_R": fit.relative_std[1] * fit.parameters["right_diameter"],
            "std_b": fit.relative_std[2] * fit.parameters["wheelbase"],
            "condition": fit.condition,
            "evaluations": float(fit.evaluations),
        }
        notes = [
            f"fitted {fit.residuals} residuals of {len(runs)} runs: RMS position error "
            f"{fit.rms_before * 1e3:.1f} mm → {fit.rms_after * 1e3:.1f} mm"
        ]
        if fit.condition > POOR_CONDITION:
            notes.append(
                f"poorly conditioned (Jacobian condition number {fit.condition:.0f}): the runs "
                "hardly tell the parameters apart"
            )
        return CalibrationResult(
            calibration=fit.calibration,
            estimates=estimates,
            runs_used=lab.runs_used - runs0,
            distance_used=lab.distance_used - dist0,
            notes=notes,
        )

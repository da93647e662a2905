"""Run a calibrator and judge its result on runs it has not seen.

* :func:`calibrate_in_simulation` — a hidden true robot in a :class:`~odomgym.lab.simulated.SimLab`;
the
  calibrator performs its experiments (through a sensor model), then fresh UMBmark squares are
  driven with the uncalibrated and with the calibrated odometry, and E_max,syst (Borenstein &
  Feng 1994, Eq. 3.3) is computed from the *true* return errors.
* :func:`calibrate_on_session` — a recorded session of a real robot in a
  :class:`~odomgym.lab.recorded.RecordedLab`; the result is judged by the OptiOdom evaluation
  measures (:mod:`odomgym.odometry.optiodom_measures`) on the session's runs, or on other
  sessions' runs.

And the configuration of methods by callers that configure all of them alike:
:func:`make_calibrator` (options by name, each checked against the method's options dataclass),
:func:`calibrator_for_squares` (the command line's ``--side``/``--runs``) and
:func:`calibrator_for_session` (sized from what a recorded session holds). Each method says
which settings apply to it (:meth:`~odomgym.baselines.base.Calibrator.square_options`,
``session_options``, ``budget_options``, ``min_budget``); nothing is dropped silently.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.baselines.base import CalibrationResult, Calibrator, Holdings, option_names
from odomgym.data import Session
from odomgym.errors import SpecError
from odomgym.floor import FloorSpec, load_floor
from odomgym.lab.experiment import SensorAccuracy
from odomgym.lab.recorded import RecordedLab
from odomgym.lab.simulated import SimLab, random_start_poses
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.optiodom_measures import EvaluationMeasures, evaluate
from odomgym.odometry.runs import Direction, Run, end_error
from odomgym.odometry.umbmark_measures import e_max_syst
from odomgym.robot import RobotSpec, load_robot
from odomgym.sim.route_runs import RunRequests
from odomgym.sim.routes import square_route

__all__ = [
    "SessionReport",
    "SimulationReport",
    "ValidationSquare",
    "calibrate_in_simulation",
    "calibrate_on_session",
    "calibrator_for_session",
    "calibrator_for_squares",
    "make_calibrator",
    "method_options",
    "square_errors",
    "validation_errors",
    "validation_errors_many",
]

FloatArray = NDArray[np.float64]


def method_options(cls: type[Calibrator], options: Mapping[str, object]) -> Any:
    """``options`` as ``cls``'s options dataclass (``cls.options_type``), every value checked.

    Raises:
        SpecError: an option ``cls`` does not take (``field`` = the option; the message names
            the method and lists what it takes), or an invalid value (``field`` = the option).
    """
    takes = option_names(cls.options_type)
    for key in options:
        if key not in takes:
            raise SpecError(
                f"{cls.name} takes no option {key!r}; it takes {', '.join(takes)}", field=key
            )
    return cls.options_type(**options)


def make_calibrator(cls: type[Calibrator], **options: object) -> Calibrator:
    """``cls`` configured by ``options``, each of which it must take (see
    :func:`method_options`); options not given keep the method's defaults."""
    return cls.from_options(method_options(cls, options))


# ------------------------------------------------------------ which settings apply to which method
def calibrator_for_squares(
    cls: type[Calibrator], *, side: float, runs_per_direction: int, **options: object
) -> Calibrator:
    """``cls`` with the square side [m] and squares per direction as the method reads them
    (:meth:`~odomgym.baselines.base.Calibrator.square_options`: what ``odomgym calibrate
    METHOD --side L --runs N`` means for it), and any further ``options`` (each of which the
    method must take)."""
    return make_calibrator(cls, **cls.square_options(side, runs_per_direction), **options)


def calibrator_for_session(
    cls: type[Calibrator], session: Session, conventions: str | None = None
) -> Calibrator:
    """``cls`` sized for what ``session`` holds, by the method's own rule
    (:meth:`~odomgym.baselines.base.Calibrator.session_options`): its square side, and how many
    squares, straights, spins, circles or free runs it has. One rule for the CLI and the
    leaderboard.

    Raises:
        SpecError: ``conventions`` given to a method that takes none (``field="conventions"``),
            or an unknown ``conventions``.
        LookupError: the session holds too little to configure the method at all (e.g. neither
            squares nor spins for least squares); the message says what it holds.
    """
    lab = RecordedLab(session)
    sized = cls.session_options(Holdings(session.side, lab.holdings()))
    if conventions is not None:
        # Not taken by the method, or an unknown value: the user's error, said as such.
        method_options(cls, {"conventions": conventions})
        sized["conventions"] = conventions
    try:
        options = method_options(cls, sized)
    except SpecError as exc:
        raise LookupError(
            f"session {session.name} (holding {lab.describe_holdings()}) cannot configure "
            f"{cls.name}: {exc}"
        ) from exc
    return cls.from_options(options)


@dataclass
class SimulationReport:
    """A calibrator's result on a simulated robot, validated on fresh squares.

    Attributes:
        method: the calibrator's name.
        robot: the true robot (hidden from the calibrator).
        result: what the calibrator returned.
        truth: the calibration that exactly compensates the true E_d, E_b, E_s.
        errors_before, errors_after: true return errors (n, 3) of the validation squares,
            keyed ``"cw"``/``"ccw"``, uncalibrated and calibrated.
        e_max_before, e_max_after: E_max,syst [m] of those squares.
        wall_time: seconds spent in the calibrator (simulating its experiments included).
    """

    method: str
    robot: RobotSpec
    result: CalibrationResult
    truth: Calibration
    errors_before: dict[str, FloatArray]
    errors_after: dict[str, FloatArray]
    e_max_before: float
    e_max_after: float
    wall_time: float
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def improvement(self) -> float:
        """E_max,syst before / after (the "improvement" of Borenstein & Feng 1994, Table III):
        NaN without a validation (both NaN), ∞ only for a calibration that left no error."""
        if math.isnan(self.e_max_before) or math.isnan(self.e_max_after):
            return math.nan
        return self.e_max_before / self.e_max_after if self.e_max_after > 0 else math.inf

    def parameter_errors(self) -> dict[str, float]:
        """Estimated − true E_d, E_b, E_s (dimensionless)."""
        cal = self.result.calibration
        return {
            "E_d": cal.e_d - self.robot.e_d,
            "E_b": cal.wheelbase_scale - self.robot.e_b,
            "E_s": cal.distance_scale - self.robot.e_s,
        }

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        cal = self.result.calibration
        return {
            "method": self.method,
            "robot": self.robot.name,
            "truth": {"E_d": self.robot.e_d, "E_b": self.robot.e_b, "E_s": self.robot.e_s},
            "estimate": {
                "E_d": cal.e_d,
                "E_b": cal.wheelbase_scale,
                "E_s": cal.distance_scale,
                "c_left": cal.c_left,
                "c_right": cal.c_right,
                **cal.parameters(self.robot),
            },
            "estimates": self.result.estimates,
            "e_max_syst_before": self.e_max_before,
            "e_max_syst_after": self.e_max_after,
            "improvement": self.improvement,
            "runs_used": self.result.runs_used,
            "distance_used": self.result.distance_used,
            "wall_time_s": self.wall_time,
            "notes": self.result.notes,
        }


@dataclass(frozen=True)
class ValidationSquare:
    """One fresh UMBmark square to judge a calibration by: ``robot`` drives it with
    ``calibration`` from ``start`` (x, y [m], θ [rad]; the origin if None), its floor noise from
    ``stream`` (None: the batch's shared ``rng``)."""

    robot: RobotSpec
    calibration: Calibration
    start: FloatArray | None = None
    stream: np.random.Generator | None = None


def square_errors(
    squares: Sequence[ValidationSquare],
    floor: FloorSpec,
    direction: Direction,
    *,
    side: float = 4.0,
    rng: np.random.Generator | None = None,
) -> FloatArray:
    """True return errors (K, 3) of ``squares`` of ``side`` [m] driven ``direction``, all in
    one batch: true − odometry in each run's start frame [m, m, rad], heading wrapped.

    The one validation of the benchmark and of :func:`calibrate_in_simulation`. A square not
    finished within the time limit (a calibration so wrong that the robot circles) gets NaN
    errors, and so a NaN E_max,syst: the benchmark reports that calibration as failed and goes
    on; :func:`validation_errors_many` raises instead (one calibration a user asked about).
    """
    batch = RunRequests()
    route = square_route(side, direction)
    for square in squares:
        batch.add(
            square.robot,
            route,
            square.calibration,
            stream=square.stream,
            start=square.start,
            direction=direction,
        )
    sim, odom = batch.simulate(floor, rng=rng, on_timeout="keep")
    return np.array(
        [
            end_error(run, end) if run.meta["finished"] else np.full(3, np.nan)
            for run, end in zip(sim, odom, strict=True)
        ]
    )


def validation_errors_many(
    robot: RobotSpec,
    floor: FloorSpec,
    calibrations: Sequence[Calibration],
    *,
    side: float = 4.0,
    runs: int = 5,
    rng: np.random.Generator | None = None,
    start_region: float | None = None,
) -> list[dict[str, FloatArray]]:
    """True return errors of fresh squares for several calibrations of one robot, simulated in
    one batch per direction (every calibration drives from the same start poses).

    Returns one dict per calibration: ``"cw"``/``"ccw"`` → (runs, 3) errors (true − odometry,
    start frame, heading wrapped) (:func:`square_errors`).

    Raises:
        RuntimeError: a square did not finish within the time limit with some calibration.
    """
    results: list[dict[str, FloatArray]] = [{} for _ in calibrations]
    count = len(calibrations)
    directions: tuple[Direction, Direction] = ("cw", "ccw")
    for direction in directions:
        starts: FloatArray | None = None
        if start_region is not None:
            assert rng is not None, "random start poses need an rng"
            starts = random_start_poses(rng, runs, start_region)
        squares = [
            ValidationSquare(robot, calibration, None if starts is None else starts[r])
            for calibration in calibrations
            for r in range(runs)
        ]
        errors = square_errors(squares, floor, direction, side=side, rng=rng)
        unfinished = sorted({k // runs for k in np.flatnonzero(np.isnan(errors).any(axis=1))})
        if unfinished:
            raise RuntimeError(
                f"validation squares ({direction}) did not finish with calibration(s) "
                f"{unfinished} within the time limit (a calibration that makes the robot "
                "circle, or a slippery floor?)"
            )
        for k in range(count):
            results[k][direction] = errors[k * runs : (k + 1) * runs]
    return results


def validation_errors(
    robot: RobotSpec,
    floor: FloorSpec,
    calibration: Calibration,
    *,
    side: float = 4.0,
    runs: int = 5,
    rng: np.random.Generator | None = None,
    start_region: float | None = None,
) -> dict[str, FloatArray]:
    """True return errors (true − odometry, start frame) of ``runs`` fresh squares per direction
    (started at random poses within ``start_region`` if given; see :class:`SimLab`)."""
    return validation_errors_many(
        robot, floor, [calibration], side=side, runs=runs, rng=rng, start_region=start_region
    )[0]


def calibrate_in_simulation(
    calibrator: Calibrator,
    robot: RobotSpec | str,
    floor: FloorSpec | str | None = None,
    *,
    seed: int = 0,
    sensor: SensorAccuracy | None = None,
    validation_side: float = 4.0,
    validation_runs: int = 5,
    start_region: float | None = None,
) -> SimulationReport:
    """Calibrate the hidden ``robot`` (a spec, preset name or robot file) in simulation and
    validate on fresh squares (``validation_runs = 0`` skips the validation: E_max,syst and the
    improvement are then NaN).

    Randomness (floor roughness, sensor noise) flows from ``numpy.random.default_rng(seed)``:
    one stream for the calibration experiments, an independent one for validation.
    """
    robot = load_robot(robot)  # a spec as it is; a preset name or file loaded
    floor = load_floor(floor) if floor is not None else FloorSpec()
    if isinstance(validation_runs, bool) or not isinstance(validation_runs, int | np.integer):
        raise SpecError(
            f"validation_runs must be a whole number of runs, got {validation_runs!r}",
            field="validation_runs",
        )
    if validation_runs < 0:
        raise SpecError(
            f"validation_runs must be >= 0 (0 skips the validation), got {validation_runs}",
            field="validation_runs",
        )
    calibration_rng, validation_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2)
    )
    lab = SimLab(robot, floor, sensor=sensor, rng=calibration_rng, start_region=start_region)
    start = time.perf_counter()
    result = calibrator.calibrate(lab)
    wall = time.perf_counter() - start
    before: dict[str, FloatArray] = {}
    after: dict[str, FloatArray] = {}
    e_before = e_after = float("nan")
    if validation_runs > 0:
        before, after = validation_errors_many(
            robot,
            floor,
            [Calibration(), result.calibration],
            side=validation_side,
            runs=validation_runs,
            rng=validation_rng,
            start_region=start_region,
        )
        e_before = e_max_syst(before["cw"], before["ccw"])
        e_after = e_max_syst(after["cw"], after["ccw"])
    return SimulationReport(
        method=calibrator.name,
        robot=robot,
        result=result,
        truth=Calibration.from_errors(robot.e_d, robot.e_b, robot.e_s),
        errors_before=before,
        errors_after=after,
        e_max_before=e_before,
        e_max_after=e_after,
        wall_time=wall,
    )


@dataclass
class SessionReport:
    """A calibrator's result on a recorded session, judged by the OptiOdom measures."""

    method: str
    session: str
    result: CalibrationResult
    before: EvaluationMeasures
    after: EvaluationMeasures
    robot: RobotSpec

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready summary (parameters as the published table: b, D_R, D_L [m])."""
        params = self.result.calibration.parameters(self.robot)
        return {
            "method": self.method,
            "session": self.session,
            "b": params["wheelbase"],
            "dr": params["right_diameter"],
            "dl": params["left_diameter"],
            "before": self.before.as_published(),
            "after": self.after.as_published(),
            "estimates": self.result.estimates,
            "notes": self.result.notes,
        }


def calibrate_on_session(
    calibrator: Calibrator,
    session: Session,
    *,
    evaluate_on: Sequence[Run] | None = None,
) -> SessionReport:
    """Calibrate on a recorded session; evaluate on its runs (or on ``evaluate_on``)."""
    lab = RecordedLab(session)
    result = calibrator.calibrate(lab, session.initial)
    runs = list(evaluate_on) if evaluate_on is not None else list(session.runs)
    return SessionReport(
        method=calibrator.name,
        session=session.name,
        result=result,
        before=evaluate(runs, session.robot, session.initial),
        after=evaluate(runs, session.robot, result.calibration),
        robot=session.robot,
    )

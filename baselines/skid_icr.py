"""The skid-steer ICR calibration (Mandow et al. 2007) as a registered calibrator, ``skid_icr``.

A skid-steer robot turns about instantaneous centres of rotation (ICRs) of its sides that lie
outside its wheels (Mandow et al. 2007, Eqs. 4–6): the left side's at (x_ICR, y_L), the right
side's at (x_ICR, y_R) in the body frame. Its odometry is then the differential-drive odometry
with the apparent track y_L − y_R in place of the wheels' spacing, plus a forward motion of
y_ICR = (y_L + y_R)/2 and a sideways motion of −x_ICR per radian turned
(:mod:`odomgym.odometry.calibration`). This method fits all of it at once:

    k_L, k_R   the wheels' travel per count, relative to the nominal (c_L·E_s, c_R·E_s) [-]
    E_b        the apparent track over the nominal b_n (the expansion factor χ) [-]
    x_ICR, y_ICR   the ICRs' offsets [m]

**Experiments.** The skid-steer papers' (Mandow et al. 2007, §IV; Wang et al. 2015, §4): the
bi-directional square (its corners are in-place spins, where the factor is largest) and one lap
of circles of several radii each way (default 0.5, 1, 2, 4 m), measured by the lab's
ground-truth sensor; free paths on request. On a recorded session it takes every square and
circle the session holds both ways and every free path (:meth:`SkidIcr.session_options`); runs
of one curvature alone leave the ICR offsets loose, and the result's notes say so.

**Fit.** Least squares on the motion over short windows (:func:`fit_icr`): each window of
``window`` seconds is dead-reckoned from its measured start pose and compared with its measured
end pose (position [m], and heading [rad] times ``heading_weight`` [m/rad]). Windows keep one
early error from weighting everything after it, as in :func:`odomgym.odometry.icr.fit_skid_model`,
which fits the same model without the wheels' factors.

**What it cannot tell apart.** A constant x_ICR moves the tracked point exactly as tracking a
point −x_ICR ahead of it would (``tests/test_icr.py``): a marker d ahead of the body's centre
reads as x_ICR − d, its own x_ICR and the marker's offset in one number. On a
differential-drive robot the ICRs lie on the axle, and the fit returns offsets near 0 and E_b
near the robot's own.

**Where it sits.** In :data:`odomgym.baselines.base.CALIBRATORS`, so ``odomgym calibrate
skid_icr``, ``odomgym bench calibrators --base scout2`` (a population drawn around a skid-steer
preset; through the API ``BenchConfig(population=Population(base="scout2"), oracle=False)``)
and ``odomgym bench skid`` offer it; its :class:`~odomgym.odometry.calibration.Calibration`
carries the ICR offsets, which every odometry of the project applies (the closed-loop drivers,
the arc driver, the replays); the models of a differential-drive odometry (the classical
calibrators, Chong & Kleeman's covariance, CLAPPER's estimators) refuse them in one line
(:func:`odomgym.odometry.runs.require_differential`). It is made for
skid-steer robots (:attr:`~odomgym.baselines.base.Calibrator.skid_steer`), so the comparisons
of every method on differential-drive robots leave it out unless it is named.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from odomgym.baselines.base import CalibrationResult, Calibrator, Holdings, perform
from odomgym.errors import SpecError, require_count, require_finite, require_positive
from odomgym.lab.experiment import Experiment, ExperimentKind, Lab
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run, wheel_travels
from odomgym.robot import RobotSpec

__all__ = [
    "DEFAULT_RADII",
    "POOR_OFFSET",
    "RECORDED_RADIUS",
    "IcrFit",
    "SkidIcr",
    "SkidIcrOptions",
    "fit_icr",
]

FloatArray = NDArray[np.float64]

POOR_OFFSET = 0.05
"""A fitted ICR offset whose standard error exceeds this fraction of the nominal track is
reported as poorly determined [-] (5 %: 29 mm on the Scout 2.0)."""

DEFAULT_RADII: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0)
"""The calibration circles' radii [m], the range over which Mandow et al. (2007) and Wang et al.
(2015) measured the ICRs move (``odomgym bench skid`` calibrates on the same)."""


RECORDED_RADIUS = 1.0
"""The radius [m] the circles of a recorded session are asked for: a recorded lab serves its
circles whatever their radius (:class:`odomgym.lab.recorded.RecordedLab`), so the value only
names one circle per run and direction; the fit never reads it."""


@dataclass(frozen=True)
class SkidIcrOptions:
    """Options of :class:`SkidIcr`.

    Attributes:
        side: square side L [m] (2 m: a skid-steer robot with its nominal track turns only
            about 52° at a 90° corner, and wider squares take it far off).
        runs_per_direction: squares per direction (0: none).
        radii: circle radii [m], tightest first (empty: no circles).
        circle_runs: circles of each radius per direction, one lap each.
        free_runs: free paths (a recorded session's, or the simulator's random arcs).
        free_length: length of a simulated free path [m].
        window: length of the fit's windows [s].
        heading_weight: weight of a window's heading error [m/rad] (0.3: 1° counts as 5 mm).
    """

    side: float = 2.0
    runs_per_direction: int = 1
    radii: tuple[float, ...] = DEFAULT_RADII
    circle_runs: int = 1
    free_runs: int = 0
    free_length: float = 20.0
    window: float = 2.0
    heading_weight: float = 0.3

    def __post_init__(self) -> None:
        require_positive("side", self.side)
        require_count("runs_per_direction", self.runs_per_direction, 0)
        try:
            radii = tuple(self.radii)
        except TypeError:
            raise SpecError(
                f"radii must be a list of circle radii [m], got {self.radii!r}", field="radii"
            ) from None
        for radius in radii:
            require_positive("radii", radius)
        if len(set(radii)) != len(radii):
            raise SpecError(f"radii must differ, got {radii}", field="radii")
        object.__setattr__(self, "radii", radii)
        require_count("circle_runs", self.circle_runs, 1)
        require_count("free_runs", self.free_runs, 0)
        require_positive("free_length", self.free_length)
        if not (self.runs_per_direction or radii or self.free_runs):
            raise SpecError(
                "skid_icr needs runs to fit: squares (runs_per_direction), circles (radii) or "
                "free paths (free_runs); all are 0",
                field="runs_per_direction",
            )
        require_positive("window", self.window)
        if require_finite("heading_weight", self.heading_weight) < 0.0:
            raise SpecError(
                f"heading_weight must be >= 0 [m/rad], got {self.heading_weight!r}",
                field="heading_weight",
            )


@dataclass(frozen=True)
class IcrFit:
    """The result of :func:`fit_icr`.

    Attributes:
        calibration: the fitted calibration (absolute: relative to the uncalibrated robot).
        windows: how many windows entered the fit.
        rms_before, rms_after: RMS window end-position error [m] with the starting and the
            fitted calibration.
        std: standard errors of (ln k_L, ln k_R, ln E_b, x_ICR [m], y_ICR [m]) from the
            Gauss–Newton covariance (windows treated as independent, so optimistic).
        evaluations: residual evaluations.
    """

    calibration: Calibration
    windows: int
    rms_before: float
    rms_after: float
    std: tuple[float, float, float, float, float]
    evaluations: int


@dataclass(frozen=True)
class _Windows:
    """Every window of the runs, concatenated: the wheels' nominal travel per step (n, 2) [m],
    which window each step belongs to, and each window's measured start and end pose."""

    travels: FloatArray
    first: NDArray[np.intp]
    start: FloatArray
    end: FloatArray


def _windows(runs: Sequence[Run], robot: RobotSpec, window: float) -> _Windows:
    """Cut every run into windows of ``window`` seconds between samples with a measured pose
    (a window whose start or end sample is a ground-truth gap is left out)."""
    travels, firsts, starts, ends = [], [], [], []
    steps = 0
    for run in runs:
        if run.time.shape[0] < 2:
            continue
        travel, _ = wheel_travels(run, robot)
        period = float(np.median(np.diff(run.time)))
        n = max(1, round(window / period)) if period > 0 else 1
        known: NDArray[np.bool_] = np.asarray(np.isfinite(run.true_pose).all(axis=1))
        for a in range(0, run.time.shape[0] - 1, n):
            b = min(a + n, run.time.shape[0] - 1)
            if not (known[a] and known[b]):
                continue
            firsts.append(steps)
            travels.append(travel[a:b])
            starts.append(run.true_pose[a])
            ends.append(run.true_pose[b])
            steps += b - a
    if not firsts:
        raise SpecError(
            "the ICR fit needs runs with measured poses at least a window apart; these have none",
            field="runs",
        )
    return _Windows(
        np.concatenate(travels),
        np.asarray(firsts, dtype=np.intp),
        np.asarray(starts, dtype=float),
        np.asarray(ends, dtype=float),
    )


def _calibration(p: FloatArray) -> Calibration:
    """The calibration of the fit's parameters p = (ln k_L, ln k_R, ln E_b, x_ICR, y_ICR)."""
    k_left, k_right = math.exp(p[0]), math.exp(p[1])
    mean = 0.5 * (k_left + k_right)
    return Calibration(
        c_left=k_left / mean,
        c_right=k_right / mean,
        wheelbase_scale=math.exp(p[2]),
        distance_scale=mean,
        icr_x=float(p[3]),
        icr_y=float(p[4]),
    )


def _window_ends(p: FloatArray, w: _Windows, track: float) -> FloatArray:
    """Each window's end pose (windows, 3), dead-reckoned from its measured start with the
    calibration of ``p`` (the equations of :class:`odomgym.odometry.calibration.Odometry`)."""
    left = w.travels[:, 0] * math.exp(p[0])
    right = w.travels[:, 1] * math.exp(p[1])
    dtheta = (right - left) / (math.exp(p[2]) * track)
    forward = 0.5 * (left + right) + p[4] * dtheta
    leftward = -p[3] * dtheta
    # Each step's heading before it, within its window: a running sum restarted per window.
    total = np.concatenate(([0.0], np.cumsum(dtheta)))
    owner = np.repeat(np.arange(len(w.first)), np.diff(np.append(w.first, len(dtheta))))
    before = total[:-1] - total[w.first][owner]
    mid = w.start[owner, 2] + before + 0.5 * dtheta
    c, s = np.cos(mid), np.sin(mid)
    dx = np.add.reduceat(forward * c - leftward * s, w.first)
    dy = np.add.reduceat(forward * s + leftward * c, w.first)
    turn = np.add.reduceat(dtheta, w.first)
    return np.column_stack((w.start[:, 0] + dx, w.start[:, 1] + dy, w.start[:, 2] + turn))


def fit_icr(
    runs: Sequence[Run],
    robot: RobotSpec,
    initial: Calibration | None = None,
    *,
    window: float = 2.0,
    heading_weight: float = 0.3,
) -> IcrFit:
    """Fit the wheels' factors, the apparent track and the ICR offsets to ``runs`` (module
    docstring), starting from ``initial`` (default: uncalibrated).

    Raises:
        SpecError: no window with measured poses at both ends (``field`` = ``runs``).
    """
    w = _windows(runs, robot, window)
    track = float(robot.wheelbase)
    start = initial if initial is not None else Calibration()
    p0 = np.array(
        [
            math.log(start.c_left * start.distance_scale),
            math.log(start.c_right * start.distance_scale),
            math.log(start.wheelbase_scale),
            start.icr_x,
            start.icr_y,
        ]
    )
    # Bounds keep the model a robot: wheels within a factor 1.65 of their nominal travel, an
    # apparent track between a fifth and ten times the nominal, ICRs within ten tracks.
    reach = 10.0 * track
    low = np.array([-0.5, -0.5, math.log(0.2), -reach, -reach])
    high = np.array([0.5, 0.5, math.log(10.0), reach, reach])
    p0 = np.clip(p0, low + 1e-9, high - 1e-9)

    def residual(p: FloatArray) -> FloatArray:
        ends = _window_ends(p, w, track)
        out = np.empty((len(w.first), 3))
        out[:, :2] = ends[:, :2] - w.end[:, :2]
        out[:, 2] = heading_weight * np.remainder(ends[:, 2] - w.end[:, 2] + math.pi, math.tau)
        out[:, 2] -= heading_weight * math.pi
        return out.ravel()

    def rms(p: FloatArray) -> float:
        r = residual(p).reshape(-1, 3)
        return float(np.sqrt(np.mean(r[:, 0] ** 2 + r[:, 1] ** 2)))

    fit = least_squares(residual, p0, bounds=(low, high), x_scale="jac")
    p = np.asarray(fit.x, dtype=float)
    final = np.asarray(fit.fun, dtype=float)
    jac = np.asarray(fit.jac, dtype=float)
    variance = float(final @ final) / max(final.size - 5, 1)
    std = np.sqrt(np.clip(np.diag(variance * np.linalg.pinv(jac.T @ jac)), 0.0, None))
    return IcrFit(
        calibration=_calibration(p),
        windows=len(w.first),
        rms_before=rms(p0),
        rms_after=rms(p),
        std=(float(std[0]), float(std[1]), float(std[2]), float(std[3]), float(std[4])),
        evaluations=int(fit.nfev),
    )


class SkidIcr(Calibrator):
    """Mandow et al. 2007's ICR model fitted with the wheels' factors (module docstring).

    Args: the fields of :class:`SkidIcrOptions`.
    """

    name: ClassVar[str] = "skid_icr"
    reference: ClassVar[str] = (
        "A. Mandow, J. L. Martínez, J. Morales, J. L. Blanco, A. García-Cerezo, J. González, "
        "Experimental kinematics for wheeled skid-steer mobile robots, IROS 2007"
    )
    options_type: ClassVar[type[Any]] = SkidIcrOptions
    min_budget: ClassVar[int] = 4
    """One square and one circle each way."""
    skid_steer: ClassVar[bool] = True

    def __init__(
        self,
        side: float = 2.0,
        runs_per_direction: int = 1,
        radii: Sequence[float] = DEFAULT_RADII,
        circle_runs: int = 1,
        free_runs: int = 0,
        free_length: float = 20.0,
        window: float = 2.0,
        heading_weight: float = 0.3,
    ) -> None:
        self.options = SkidIcrOptions(
            side=side,
            runs_per_direction=runs_per_direction,
            radii=tuple(radii),
            circle_runs=circle_runs,
            free_runs=free_runs,
            free_length=free_length,
            window=window,
            heading_weight=heading_weight,
        )

    @classmethod
    def budget_options(cls, runs: int) -> dict[str, Any]:
        """Circles first (tightest first, up to the four default radii, both ways), then one
        square each way and the rest as further squares."""
        circles = max(1, min(len(DEFAULT_RADII), (runs - 2) // 2))
        return {
            "radii": DEFAULT_RADII[:circles],
            "runs_per_direction": max(1, (runs - 2 * circles) // 2),
        }

    @classmethod
    def square_options(cls, side: float, runs_per_direction: int) -> dict[str, Any]:
        return {"side": side, "runs_per_direction": runs_per_direction}

    @classmethod
    def session_options(cls, held: Holdings) -> dict[str, Any]:
        """Every square, circle and free path a recorded session holds (squares and circles
        as many as it holds both ways). Its circles are asked for at :data:`RECORDED_RADIUS`:
        a recorded lab serves them whatever their radius, and the fit takes any shape.

        Raises:
            LookupError: the session holds none of them (straight runs and spins alone do not
                show the ICRs: a spin does not move the tracked point far, a straight run
                does not turn).
        """
        squares = min(
            held.runs(ExperimentKind.SQUARE, "cw"), held.runs(ExperimentKind.SQUARE, "ccw")
        )
        circles = min(
            held.runs(ExperimentKind.CIRCULAR, "cw"), held.runs(ExperimentKind.CIRCULAR, "ccw")
        )
        free = held.runs(ExperimentKind.FREE)
        if not (squares or circles or free):
            raise LookupError(
                "skid_icr fits squares or circles driven both ways, or free paths, and the "
                "session holds none"
            )
        out: dict[str, Any] = {
            "runs_per_direction": squares,
            "radii": (RECORDED_RADIUS,) if circles else (),
            "circle_runs": max(circles, 1),
            "free_runs": free,
        }
        if held.side > 0.0:
            out["side"] = held.side
        return out

    def experiments(self) -> list[Experiment]:
        """The cw and ccw squares, then the circles cw and ccw radius by radius, then the free
        paths (each part left out when its count is 0)."""
        o = self.options
        out = []
        if o.runs_per_direction:
            out.append(Experiment(ExperimentKind.SQUARE, "cw", o.runs_per_direction, o.side))
            out.append(Experiment(ExperimentKind.SQUARE, "ccw", o.runs_per_direction, o.side))
        for radius in o.radii:
            out.append(Experiment(ExperimentKind.CIRCULAR, "cw", o.circle_runs, radius))
            out.append(Experiment(ExperimentKind.CIRCULAR, "ccw", o.circle_runs, radius))
        if o.free_runs:
            out.append(Experiment(ExperimentKind.FREE, None, o.free_runs, o.free_length))
        return out

    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        """Drive the experiments with ``initial`` in the odometry and fit (:func:`fit_icr`)."""
        driving = initial if initial is not None else Calibration()
        runs0, dist0 = lab.runs_used, lab.distance_used
        runs: list[Run] = []
        for experiment in self.experiments():
            runs += perform(lab, experiment, driving, method=self.name)
        fit = fit_icr(
            runs,
            lab.robot,
            driving,
            window=self.options.window,
            heading_weight=self.options.heading_weight,
        )
        cal = fit.calibration
        b = cal.wheelbase_scale * lab.robot.wheelbase
        estimates = {
            "E_d": cal.e_d,
            "E_b": cal.wheelbase_scale,
            "E_s": cal.distance_scale,
            "x_icr": cal.icr_x,
            "y_icr": cal.icr_y,
            "y_left": cal.icr_y + 0.5 * b,
            "y_right": cal.icr_y - 0.5 * b,
            "rms_before_m": fit.rms_before,
            "rms_after_m": fit.rms_after,
        }
        notes = [
            "x_ICR also holds any offset of the tracked point along the body: from logs the "
            "two are one (Mandow et al. 2007's ICR model; docs/skid-steer.md)"
        ]
        # Runs of one curvature cannot separate y_ICR from the distance scale, nor x_ICR from
        # a heading offset: say so when the fit's own errors show it.
        loose = [
            f"{name} ± {1e3 * std:.1f} mm"
            for name, std in (("x_ICR", fit.std[3]), ("y_ICR", fit.std[4]))
            if std > POOR_OFFSET * lab.robot.wheelbase
        ]
        if loose:
            notes.append(
                f"poorly determined by these runs ({', '.join(loose)}): turns of several radii "
                "(circles of several radii, free paths) tell the ICR offsets apart"
            )
        return CalibrationResult(
            calibration=cal,
            estimates=estimates,
            runs_used=lab.runs_used - runs0,
            distance_used=lab.distance_used - dist0,
            notes=notes,
        )

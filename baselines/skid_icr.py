"""The skid-steer models as registered calibrators: ``skid_icr`` (Mandow et al. 2007's ICRs)
and ``skid_curvature`` (a track that moves with the turn, Wang et al. 2015's form).

A skid-steer robot turns about instantaneous centres of rotation (ICRs) of its sides that lie
outside its wheels (Mandow et al. 2007, Eqs. 4–6): the left side's at (x_ICR, y_L), the right
side's at (x_ICR, y_R) in the body frame. Its odometry is then the differential-drive odometry
with the apparent track y_L − y_R in place of the wheels' spacing, plus a forward motion of
y_ICR = (y_L + y_R)/2 and a sideways motion of −x_ICR per radian turned
(:mod:`odomgym.odometry.calibration`). This method fits all of it at once:

    k_L, k_R   the wheels' travel per count, relative to the nominal (c_L·E_s, c_R·E_s) [-]
    E_b        the apparent track over the nominal b_n (the expansion factor χ) [-]
    x_ICR, y_ICR   the ICRs' offsets [m]

``skid_curvature`` (:class:`SkidCurvature`) fits, from the same runs and in the same windows,
the wheels' factors and an apparent track that widens as the turn tightens instead of the ICRs:
b_eff(λ) = b_n·(E_b + α/(1 + (β·|λ|)^p)) with λ = (Δs_L + Δs_R)/(Δs_R − Δs_L) per period
(:mod:`odomgym.odometry.calibration`), the curvature model of :mod:`odomgym.odometry.icr`.
Constant ICRs cannot be right both in a spin and on a wide arc of a symmetric robot; the curve
can (docs/skid-steer.md).

**Experiments.** The skid-steer papers' (Mandow et al. 2007, §IV; Wang et al. 2015, §4): the
bi-directional square (its corners are in-place spins, where the factor is largest) and one lap
of circles of several radii each way (default 0.5, 1, 2, 4 m), measured by the lab's
ground-truth sensor; free paths on request. On a recorded session it takes every square and
circle the session holds both ways and every free path (:meth:`SkidIcr.session_options`); runs
of one curvature alone leave the ICR offsets loose, and the result's notes say so.

**Fit.** Least squares on the motion over short windows (:func:`fit_skid`): each window of
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
from typing import Any, ClassVar, Literal

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
    "SkidCurvature",
    "SkidFitModel",
    "SkidIcr",
    "SkidIcrOptions",
    "fit_icr",
    "fit_skid",
]

FloatArray = NDArray[np.float64]
SkidFitModel = Literal["icr", "curvature"]

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
        std: standard errors of the fit's parameters (:func:`_calibration`'s order: for the
            ICR model ln k_L, ln k_R, ln E_b, x_ICR [m], y_ICR [m]) from the Gauss–Newton
            covariance (windows treated as independent, so optimistic).
        evaluations: residual evaluations.
    """

    calibration: Calibration
    windows: int
    rms_before: float
    rms_after: float
    std: tuple[float, ...]
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
            "the skid-steer fit needs runs with measured poses at least a window apart; these "
            "have none",
            field="runs",
        )
    return _Windows(
        np.concatenate(travels),
        np.asarray(firsts, dtype=np.intp),
        np.asarray(starts, dtype=float),
        np.asarray(ends, dtype=float),
    )


def _calibration(p: FloatArray, model: SkidFitModel) -> Calibration:
    """The calibration of the fit's parameters: p = (ln k_L, ln k_R, ln E_b, x_ICR, y_ICR) for
    ``icr``; (ln k_L, ln k_R, ln χ_∞, α, ln β, ln p) for ``curvature``, χ_∞ its E_b."""
    k_left, k_right = math.exp(p[0]), math.exp(p[1])
    mean = 0.5 * (k_left + k_right)
    wheels = {
        "c_left": k_left / mean,
        "c_right": k_right / mean,
        "wheelbase_scale": math.exp(p[2]),
        "distance_scale": mean,
    }
    if model == "icr":
        return Calibration(**wheels, icr_x=float(p[3]), icr_y=float(p[4]))
    return Calibration(
        **wheels,
        track_alpha=float(p[3]),
        track_beta=math.exp(p[4]),
        track_power=math.exp(p[5]),
    )


def _window_ends(cal: Calibration, w: _Windows, track: float) -> FloatArray:
    """Each window's end pose (windows, 3), dead-reckoned from its measured start with ``cal``
    (the equations of :class:`odomgym.odometry.calibration.Odometry`, every skid-steer term)."""
    left = w.travels[:, 0] * (cal.c_left * cal.distance_scale)
    right = w.travels[:, 1] * (cal.c_right * cal.distance_scale)
    forward, leftward, dtheta = cal.body_steps(left, right, track)
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


def _start_and_bounds(
    start: Calibration, model: SkidFitModel, track: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The fit's first point and bounds. The bounds keep the model a robot: wheels within a
    factor 1.65 of their nominal travel, a track between a fifth and ten times the nominal,
    ICRs within ten tracks; a curve that widens the track as the turn tightens (α ≥ 0) with β
    in 10⁻³…10³ and a power in ¼…4 (as :func:`odomgym.odometry.icr.fit_skid_model`)."""
    wheels = [
        math.log(start.c_left * start.distance_scale),
        math.log(start.c_right * start.distance_scale),
        math.log(start.wheelbase_scale),
    ]
    if model == "icr":
        reach = 10.0 * track
        p0 = np.array([*wheels, start.icr_x, start.icr_y])
        low = np.array([-0.5, -0.5, math.log(0.2), -reach, -reach])
        high = np.array([0.5, 0.5, math.log(10.0), reach, reach])
    else:
        # From a constant track the curve starts at α = 0.5, β = 0.3, p = 1 (a spin's track
        # half a nominal wider than a straight path's), where its gradient is not zero.
        curve = (
            [start.track_alpha, math.log(start.track_beta), math.log(start.track_power)]
            if start.has_track_curve
            else [0.5, math.log(0.3), 0.0]
        )
        p0 = np.array([*wheels, *curve])
        low = np.array([-0.5, -0.5, math.log(0.2), 0.0, math.log(1e-3), math.log(0.25)])
        high = np.array([0.5, 0.5, math.log(10.0), 10.0, math.log(1e3), math.log(4.0)])
    return np.clip(p0, low + 1e-9, high - 1e-9), low, high


def fit_skid(
    runs: Sequence[Run],
    robot: RobotSpec,
    model: SkidFitModel = "icr",
    initial: Calibration | None = None,
    *,
    window: float = 2.0,
    heading_weight: float = 0.3,
) -> IcrFit:
    """Fit the wheels' factors and ``model``'s skid-steer terms to ``runs`` (module docstring),
    starting from ``initial`` (default: uncalibrated): ``icr`` the apparent track and the ICR
    offsets (Mandow et al. 2007), ``curvature`` a track that moves with the turn (Wang et al.
    2015's form, with a free asymptote and power).

    Raises:
        SpecError: no window with measured poses at both ends (``field`` = ``runs``).
    """
    w = _windows(runs, robot, window)
    track = float(robot.wheelbase)
    p0, low, high = _start_and_bounds(
        initial if initial is not None else Calibration(), model, track
    )

    def residual(p: FloatArray) -> FloatArray:
        ends = _window_ends(_calibration(p, model), w, track)
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
    variance = float(final @ final) / max(final.size - p.size, 1)
    std = np.sqrt(np.clip(np.diag(variance * np.linalg.pinv(jac.T @ jac)), 0.0, None))
    return IcrFit(
        calibration=_calibration(p, model),
        windows=len(w.first),
        rms_before=rms(p0),
        rms_after=rms(p),
        std=tuple(float(x) for x in std),
        evaluations=int(fit.nfev),
    )


def fit_icr(
    runs: Sequence[Run],
    robot: RobotSpec,
    initial: Calibration | None = None,
    *,
    window: float = 2.0,
    heading_weight: float = 0.3,
) -> IcrFit:
    """:func:`fit_skid` of Mandow et al. 2007's ICR model: the wheels' factors, the apparent
    track and the ICR offsets."""
    return fit_skid(runs, robot, "icr", initial, window=window, heading_weight=heading_weight)


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
    model: ClassVar[SkidFitModel] = "icr"
    """Which skid-steer terms the fit frees beside the wheels' factors (:func:`fit_skid`)."""

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
                f"{cls.name} fits squares or circles driven both ways, or free paths, and the "
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
        """Drive the experiments with ``initial`` in the odometry and fit (:func:`fit_skid`)."""
        driving = initial if initial is not None else Calibration()
        runs0, dist0 = lab.runs_used, lab.distance_used
        runs: list[Run] = []
        for experiment in self.experiments():
            runs += perform(lab, experiment, driving, method=self.name)
        fit = fit_skid(
            runs,
            lab.robot,
            self.model,
            driving,
            window=self.options.window,
            heading_weight=self.options.heading_weight,
        )
        cal = fit.calibration
        estimates = {
            "E_d": cal.e_d,
            "E_b": cal.wheelbase_scale,
            "E_s": cal.distance_scale,
            **self._estimates(cal, lab.robot),
            "rms_before_m": fit.rms_before,
            "rms_after_m": fit.rms_after,
        }
        notes = self._notes(fit, lab.robot)
        return CalibrationResult(
            calibration=cal,
            estimates=estimates,
            runs_used=lab.runs_used - runs0,
            distance_used=lab.distance_used - dist0,
            notes=notes,
        )

    def _estimates(self, cal: Calibration, robot: RobotSpec) -> dict[str, float]:
        """The model's own quantities for the report: the ICRs [m]."""
        b = cal.wheelbase_scale * robot.wheelbase
        return {
            "x_icr": cal.icr_x,
            "y_icr": cal.icr_y,
            "y_left": cal.icr_y + 0.5 * b,
            "y_right": cal.icr_y - 0.5 * b,
        }

    def _notes(self, fit: IcrFit, robot: RobotSpec) -> list[str]:
        """What a user should know: x_ICR's confound with the tracked point, and offsets the
        runs left loose (runs of one curvature cannot separate y_ICR from the distance scale,
        nor x_ICR from a heading offset)."""
        notes = [
            "x_ICR also holds any offset of the tracked point along the body: from logs the "
            "two are one (Mandow et al. 2007's ICR model; docs/skid-steer.md)"
        ]
        loose = [
            f"{name} ± {1e3 * std:.1f} mm"
            for name, std in (("x_ICR", fit.std[3]), ("y_ICR", fit.std[4]))
            if std > POOR_OFFSET * robot.wheelbase
        ]
        if loose:
            notes.append(
                f"poorly determined by these runs ({', '.join(loose)}): turns of several radii "
                "(circles of several radii, free paths) tell the ICR offsets apart"
            )
        return notes


class SkidCurvature(SkidIcr):
    """An apparent track that moves with the turn, fitted with the wheels' factors: b_eff(λ)
    = b_n·(E_b + α/(1 + (β·|λ|)^p)), Wang et al. 2015's form with a free asymptote E_b and
    power p (:mod:`odomgym.odometry.calibration`), from the same experiments as
    :class:`SkidIcr`. Its :class:`~odomgym.odometry.calibration.Calibration` carries α, β, p
    as ``track_alpha``, ``track_beta``, ``track_power``.

    Args: the fields of :class:`SkidIcrOptions`.
    """

    name: ClassVar[str] = "skid_curvature"
    reference: ClassVar[str] = (
        "T. Wang, Y. Wu, J. Liang, C. Han, J. Chen, Q. Zhao, Analysis and experimental "
        "kinematics of a skid-steering wheeled robot based on a laser scanner sensor, "
        "Sensors 15(5):9681-9702, 2015"
    )
    model: ClassVar[SkidFitModel] = "curvature"

    def _estimates(self, cal: Calibration, robot: RobotSpec) -> dict[str, float]:
        """The curve's parameters and the track it gives in a spin and on a 1 m and 5 m arc
        of the nominal track (λ = R/(b_n/2)) [-]."""
        half = 0.5 * robot.wheelbase
        return {
            "alpha": cal.track_alpha,
            "beta": cal.track_beta,
            "power": cal.track_power,
            "factor_spin": float(cal.track_factor(0.0)),
            "factor_1m": float(cal.track_factor(1.0 / half)),
            "factor_5m": float(cal.track_factor(5.0 / half)),
        }

    def _notes(self, fit: IcrFit, robot: RobotSpec) -> list[str]:
        """Whether the track moves with the turn beyond the fit's own error."""
        del robot
        alpha, std = fit.calibration.track_alpha, fit.std[3]
        if alpha <= 2.0 * std:
            return [
                f"the track's curve is within its error (alpha {alpha:.4f} ± {std:.4f}): a "
                "constant track (skid_icr or a classical calibrator) describes these runs"
            ]
        return []

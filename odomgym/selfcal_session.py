"""The self-calibration session: its experiment menu, its end-pose estimator, its observation.

A session (:class:`SelfCalSession`) has a budget of runs; at every step a policy picks one item
of :data:`MENU` (a 4 m or 2 m square either way, a 4 m straight run one way or out and back, an
in-place spin) or ``stop``, the run is driven with the current estimate in the odometry, and a
person at the home position measures where it stopped.

**The estimator** (:class:`EndPoseEstimator`) is a Gauss–Newton fit of the three effective
odometry parameters x = (ln D_L/D_n, ln D_R/D_n, ln b/b_n) to the measured end poses: each run's
encoder counts are dead-reckoned from its (exactly known) start pose with the candidate
parameters (:func:`odomgym.runs.replay_with_jacobian`, which also gives the end pose's
Jacobian), and the residuals against the measured end poses are weighted by the sensor's
accuracy plus the floor's scatter for that kind of run. A Gaussian prior centred on the nominal
robot with σ = the benchmark population's half-ranges (:class:`odomgym.population.Population`:
E_d ± 0.01, E_b ± 0.05, E_s ± 0.02) keeps the fit well posed after one run. The floor's scatter
is :data:`MENU`'s per-run standard deviations, measured on the ``concrete`` benchmark floor,
times a roughness factor ρ ≥ 1 estimated from the residuals (ρ ≈ 5 on the ``rough`` floor): a
rough floor down-weights itself relative to the prior.

The Gymnasium env (:mod:`odomgym.envs.selfcal`), its batched training env and the calibrator
(:class:`odomgym.baselines.selfcal.SelfCal`) all drive this one object, so it lives in the core
below them: the policy acts in deployment exactly as it was trained.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from odomgym.errors import SpecError, require_count
from odomgym.experiments import Experiment, ExperimentKind, SensorAccuracy
from odomgym.odometry import Calibration, wrap_angle
from odomgym.robot import RobotSpec
from odomgym.runs import Run, replay_with_jacobian

__all__ = [
    "CLIP_PRIORS",
    "MAX_BUDGET",
    "MENU",
    "OBSERVATION_BOUND",
    "OBSERVATION_LAYOUT",
    "OBSERVATION_VERSION",
    "PRIOR_STD",
    "REFERENCE_BUDGET",
    "STOP",
    "EndPoseEstimator",
    "MenuItem",
    "SelfCalSession",
]

FloatArray = NDArray[np.float64]

_DEG = math.pi / 180.0


class MenuItem(NamedTuple):
    """One choice of the self-calibration menu.

    Attributes:
        name: the item's name in logs and reports.
        experiment: the run it drives (one run); ``None`` for ``stop``.
        floor_std: standard deviations of the end-pose error one such run scatters by on the
            ``concrete`` benchmark floor (k = 0.0004 m^½), in the run's start frame: x (along
            the start heading), y [m], θ [rad]. Measured: 24 runs of an ideal LabMate at random
            start poses (``benchmarks/bench_selfcal.py --noise``); rougher floors scale them
            by the estimator's roughness factor ρ (the scatter grows in proportion to k).
    """

    name: str
    experiment: Experiment | None
    floor_std: tuple[float, float, float]


MENU: tuple[MenuItem, ...] = (
    MenuItem("stop", None, (0.0, 0.0, 0.0)),
    MenuItem(
        "square4-cw", Experiment(ExperimentKind.SQUARE, "cw", 1, 4.0), (0.017, 0.017, 0.40 * _DEG)
    ),
    MenuItem(
        "square4-ccw", Experiment(ExperimentKind.SQUARE, "ccw", 1, 4.0), (0.017, 0.017, 0.40 * _DEG)
    ),
    MenuItem(
        "square2-cw", Experiment(ExperimentKind.SQUARE, "cw", 1, 2.0), (0.0052, 0.0052, 0.29 * _DEG)
    ),
    MenuItem(
        "square2-ccw",
        Experiment(ExperimentKind.SQUARE, "ccw", 1, 2.0),
        (0.0052, 0.0052, 0.29 * _DEG),
    ),
    MenuItem(
        "straight4",
        Experiment(ExperimentKind.STRAIGHT, None, 1, 4.0),
        (0.0005, 0.0087, 0.18 * _DEG),
    ),
    MenuItem(
        "straight4-back",
        Experiment(ExperimentKind.STRAIGHT, None, 1, 4.0, return_trip=True),
        (0.0010, 0.0069, 0.23 * _DEG),
    ),
    MenuItem(
        "spin360-cw",
        Experiment(ExperimentKind.SPIN, "cw", 1, 2.0 * math.pi),
        (0.0002, 0.0002, 0.12 * _DEG),
    ),
    MenuItem(
        "spin360-ccw",
        Experiment(ExperimentKind.SPIN, "ccw", 1, 2.0 * math.pi),
        (0.0002, 0.0002, 0.12 * _DEG),
    ),
    MenuItem(
        "spin720-cw",
        Experiment(ExperimentKind.SPIN, "cw", 1, 4.0 * math.pi),
        (0.0003, 0.0003, 0.17 * _DEG),
    ),
)
"""The experiments a self-calibration session may choose, one run each; index 0 stops."""

STOP = 0

#: Half-ranges of the benchmark population (E_s, E_d, E_b) [-]: the prior's standard deviations
#: of (ln E_s, ln E_d, ln E_b).
PRIOR_STD: tuple[float, float, float] = (0.02, 0.01, 0.05)
#: Estimates are kept within this many prior half-ranges of nominal, so the odometry can always
#: drive the next run [-].
CLIP_PRIORS = 3.0
#: Largest budget a session accepts [runs].
MAX_BUDGET = 64
#: Budget the observation is scaled by [runs] (the benchmark's default budget).
REFERENCE_BUDGET = 16.0

# (ln E_s, ln E_d, ln E_b) → x = (ln D_L, ln D_R, ln b): D_L = E_s·D/√…, to first order
# ln D_L = ln E_s − ½ ln E_d, ln D_R = ln E_s + ½ ln E_d.
_TO_X = np.array([[1.0, -0.5, 0.0], [1.0, 0.5, 0.0], [0.0, 0.0, 1.0]])
_FROM_X = np.linalg.inv(_TO_X)


class EndPoseEstimator:
    """Gauss–Newton estimate of the effective D_L, D_R and b from runs' measured end poses.

    Args:
        robot: the nominal robot (its owner's knowledge: wheel diameter, wheelbase, encoder).
        sensor: accuracy of the end-pose measurement.
        initial: the prior's mean (default: the nominal robot, x = 0).

    Why end poses only: that is what a person with a tape measure (UMBmark's §6.3 procedure)
    or a sonar calibrator gets, and it is the fair comparison with UMBmark; the start pose of
    every run is exact (the measuring frame is set up there).
    """

    def __init__(
        self, robot: RobotSpec, sensor: SensorAccuracy, initial: Calibration | None = None
    ) -> None:
        self.robot = robot
        self.sensor = sensor
        self._sensor_var = np.array(
            [sensor.position_std**2, sensor.position_std**2, sensor.heading_std**2]
        )
        prior_cov = _TO_X @ np.diag(np.square(PRIOR_STD)) @ _TO_X.T
        self._prior_info = np.linalg.inv(prior_cov)
        self._prior_logdet = float(np.linalg.slogdet(prior_cov)[1])
        self._x0 = self._to_x(initial) if initial is not None else np.zeros(3)
        self._limit = CLIP_PRIORS * np.array(PRIOR_STD)  # on (ln E_s, ln E_d, ln E_b)
        self.x = self._x0.copy()
        self.covariance = prior_cov
        self.roughness = 1.0
        self._runs: list[tuple[Run, FloatArray]] = []  # (run, floor variance at ρ = 1)

    def _to_x(self, calibration: Calibration) -> FloatArray:
        p = calibration.parameters(self.robot)
        d, b = self.robot.wheel_diameter, self.robot.wheelbase
        return np.log([p["left_diameter"] / d, p["right_diameter"] / d, p["wheelbase"] / b]).astype(
            np.float64
        )

    @property
    def calibration(self) -> Calibration:
        """The calibration the estimate stands for (exactly the identity at x = 0)."""
        d, b = self.robot.wheel_diameter, self.robot.wheelbase
        return Calibration.from_parameters(
            self.robot,
            wheelbase=b * math.exp(self.x[2]),
            right_diameter=d * math.exp(self.x[1]),
            left_diameter=d * math.exp(self.x[0]),
        )

    @property
    def errors(self) -> FloatArray:
        """The estimated (E_d, E_b, E_s) [-]."""
        cal = self.calibration
        return np.array([cal.e_d, cal.wheelbase_scale, cal.distance_scale])

    @property
    def relative_std(self) -> FloatArray:
        """Posterior standard deviations of (ln E_s, ln E_d, ln E_b) over the prior's [-]."""
        cov = _FROM_X @ self.covariance @ _FROM_X.T
        out: FloatArray = np.sqrt(np.clip(np.diag(cov), 1e-30, None)) / np.array(PRIOR_STD)
        return out

    @property
    def information_gain(self) -> float:
        """½·ln(det prior covariance / det posterior covariance) [nats]: what the runs so far
        taught the estimator (0 before any run)."""
        return 0.5 * (self._prior_logdet - float(np.linalg.slogdet(self.covariance)[1]))

    def residual(self, run: Run) -> tuple[FloatArray, FloatArray]:
        """Measured − predicted end pose of ``run`` in its start frame (x, y [m], θ [rad]) at
        the current estimate, and the Jacobian (3, 3) of the *predicted* end pose with respect
        to x (the residual's is its negative; Gauss–Newton steps by (JᵀWJ)⁻¹JᵀWr)."""
        poses, jac = replay_with_jacobian(run, self.robot, self.calibration)
        theta0 = float(run.true_pose[0, 2])
        c, s = math.cos(theta0), math.sin(theta0)
        rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        diff = run.true_pose[-1] - poses[-1]
        diff[2] = float(wrap_angle(diff[2]))
        return rot @ diff, rot @ jac[-1]

    def predicted_std(self, item: int) -> FloatArray:
        """Standard deviations of an end-pose residual of a run of menu item ``item`` at the
        current roughness estimate (x, y [m], θ [rad])."""
        floor = np.square(MENU[item].floor_std)
        return np.sqrt(self._sensor_var + self.roughness**2 * floor)

    def add(self, run: Run, item: int, iterations: int = 1) -> FloatArray:
        """Take in one measured run of menu item ``item`` and refit.

        Returns the run's innovation — its residual at the estimate *before* the update,
        divided by :meth:`predicted_std` [-] — which tells a policy how surprising it was.
        """
        r, _ = self.residual(run)
        innovation = r / self.predicted_std(item)
        self._runs.append((run, np.square(np.array(MENU[item].floor_std))))
        self.fit(iterations)
        return innovation

    def fit(self, iterations: int = 2) -> None:
        """Gauss–Newton iterations on all runs so far, re-estimating the roughness factor."""
        for _ in range(iterations):
            info = self._prior_info.copy()
            grad = -self._prior_info @ (self.x - self._x0)
            excess, floor_total = 0.0, 0.0
            for run, floor_var in self._runs:
                r, jac = self.residual(run)
                weight = 1.0 / (self._sensor_var + self.roughness**2 * floor_var)
                info += jac.T @ (weight[:, None] * jac)
                grad += jac.T @ (weight * r)
                floor_dominated = floor_var > self._sensor_var
                excess += float(np.sum((r**2 - self._sensor_var)[floor_dominated]))
                floor_total += float(np.sum(floor_var[floor_dominated]))
            self.covariance = np.linalg.inv(info)
            step = _FROM_X @ (self.x + self.covariance @ grad)
            self.x = _TO_X @ np.clip(step, -self._limit, self._limit)
            if floor_total > 0.0:
                self.roughness = float(
                    np.clip(math.sqrt(max(excess, 0.0) / floor_total), 1.0, 20.0)
                )


# The observation vector: names of its entries, in order (the shipped policy was trained on
# this layout; change it only with a new OBSERVATION_VERSION and a retrained policy).
OBSERVATION_LAYOUT: tuple[str, ...] = (
    "runs_left_fraction",
    "budget_over_16",
    *(f"share_{item.name}" for item in MENU[1:]),
    "E_d_minus_1_over_0.01",
    "E_b_minus_1_over_0.05",
    "E_s_minus_1_over_0.02",
    "log10_rel_std_E_s",
    "log10_rel_std_E_d",
    "log10_rel_std_E_b",
    "log10_roughness",
    "innovation_x",
    "innovation_y",
    "innovation_theta",
    *(f"last_{item.name}" for item in MENU),
)
OBSERVATION_VERSION = 1
OBSERVATION_BOUND = 10.0


class SelfCalSession:
    """One self-calibration session: the books, the estimator and the observation.

    The Gymnasium env, its batched vector env and the :class:`SelfCal` calibrator all drive
    this one object, so the policy acts in deployment exactly as it was trained.

    Args:
        robot: the nominal robot.
        budget: runs the session may perform (1 to :data:`MAX_BUDGET`).
        sensor: the end-pose sensor's accuracy.
        initial: the calibration to start from (default: uncalibrated).
    """

    def __init__(
        self,
        robot: RobotSpec,
        budget: int,
        sensor: SensorAccuracy | None = None,
        initial: Calibration | None = None,
    ) -> None:
        self.budget = require_count("budget", budget, 1)
        if self.budget > MAX_BUDGET:
            raise SpecError(f"budget must be <= {MAX_BUDGET} runs, got {budget}", field="budget")
        self.estimator = EndPoseEstimator(robot, sensor or SensorAccuracy(), initial)
        self.counts = np.zeros(len(MENU), dtype=np.int64)
        self.runs_used = 0
        self.last_item = STOP
        self.innovation = np.zeros(3)
        self.history: list[str] = []

    @property
    def runs_left(self) -> int:
        """Runs the budget still allows."""
        return int(self.budget - self.runs_used)

    @property
    def calibration(self) -> Calibration:
        """The corrections to drive the next run with, and the final result."""
        return self.estimator.calibration

    def experiment(self, action: int) -> Experiment | None:
        """The run menu item ``action`` drives (``None`` for ``stop``)."""
        if not 0 <= action < len(MENU):
            raise SpecError(
                f"action must be a menu index 0..{len(MENU) - 1}, got {action}", field="action"
            )
        return MENU[action].experiment

    def record(self, action: int, runs: list[Run]) -> None:
        """Take in the measured run(s) of menu item ``action``."""
        if self.experiment(action) is None:
            raise SpecError("stop drives no run: nothing to record", field="action")
        for run in runs:
            self.innovation = self.estimator.add(run, action)
        self.counts[action] += len(runs)
        self.runs_used += len(runs)
        self.last_item = action
        self.history.append(MENU[action].name)

    def observation(self) -> NDArray[np.float32]:
        """The policy's view (:data:`OBSERVATION_LAYOUT`), every entry within ±10."""
        est = self.estimator
        e_d, e_b, e_s = est.errors
        last = np.zeros(len(MENU))
        last[self.last_item] = 1.0
        values = np.concatenate(
            [
                [self.runs_left / self.budget, self.budget / REFERENCE_BUDGET],
                self.counts[1:] / self.budget,
                [(e_d - 1.0) / 0.01, (e_b - 1.0) / 0.05, (e_s - 1.0) / 0.02],
                np.log10(est.relative_std),
                [math.log10(est.roughness)],
                self.innovation,
                last,
            ]
        )
        bound = OBSERVATION_BOUND
        obs: NDArray[np.float32] = np.clip(np.nan_to_num(values, nan=0.0), -bound, bound).astype(
            np.float32
        )
        return obs

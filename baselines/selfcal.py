"""Self-calibration: a policy chooses the experiments, an end-pose estimator does the geometry.

UMBmark (Borenstein & Feng 1994, §6.3) prescribes ten 4×4 m squares and reads two numbers off
their end errors. ``selfcal`` asks instead: *which* run should the robot drive next, given
what it has measured so far, and when has it learnt enough? A session has a budget of runs;
at every step a policy picks one item of :data:`MENU` (a 4 m or 2 m square either way, a 4 m
straight run one way or out and back, an in-place spin) or ``stop``. Every run is driven with
the current estimate in the odometry (iterative compensation, as UMBmark's §6.3 second round
and solderspot 2014 do), and a person at the home position measures where it stopped —
the same information UMBmark uses, never the trajectory in between.

**The estimator** (:class:`EndPoseEstimator`) is a Gauss–Newton fit of the three effective
odometry parameters x = (ln D_L/D_n, ln D_R/D_n, ln b/b_n) to the measured end poses: each run's
encoder counts are dead-reckoned from its (exactly known) start pose with the candidate
parameters (:func:`odomgym.baselines.trajectory.replay_with_jacobian`, which also gives the end
pose's Jacobian), and the residuals against the measured end poses are weighted by the sensor's
accuracy plus the floor's scatter for that kind of run. A Gaussian prior centred on the nominal
robot with σ = the benchmark population's half-ranges (:class:`~odomgym.baselines.benchmark.
Population`: E_d ± 0.01, E_b ± 0.05, E_s ± 0.02) keeps the fit well posed after one run. The
floor's scatter is :data:`MENU`'s per-run standard deviations, measured on the ``concrete``
benchmark floor, times a roughness factor ρ ≥ 1 estimated from the residuals (ρ ≈ 5 on the
``rough`` floor): a rough floor down-weights itself relative to the prior.

**The policy** maps the session's fixed-size observation (:func:`SelfCalSession.observation`,
layout :data:`OBSERVATION_LAYOUT`) to a menu item. The shipped policy (``selfcal-ppo.npz``) is a
small MLP trained with PPO (Schulman et al. 2017) in ``SelfCalibration-v0``
(``odomgym train selfcal``); it runs here in numpy, so calibrating needs no torch. The
``scripted`` policy (alternate 4 m squares, a straight run every eighth run) is the ablation
that shows what the estimator does without learning.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np
from numpy.typing import NDArray

from odomgym.baselines.base import CalibrationResult, Calibrator, perform, require_count
from odomgym.baselines.trajectory import replay_with_jacobian
from odomgym.errors import SpecError
from odomgym.experiments import Experiment, ExperimentKind, Lab, SensorAccuracy
from odomgym.odometry import Calibration, wrap_angle
from odomgym.robot import RobotSpec
from odomgym.runs import Run

__all__ = [
    "MENU",
    "OBSERVATION_LAYOUT",
    "OBSERVATION_VERSION",
    "STOP",
    "EndPoseEstimator",
    "MenuItem",
    "MlpPolicy",
    "SelfCal",
    "SelfCalOptions",
    "SelfCalScripted",
    "SelfCalScriptedOptions",
    "SelfCalSession",
    "load_policy",
    "scripted_policy",
]

FloatArray = NDArray[np.float64]
Policy = Callable[[NDArray[np.float32]], int]

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


# ---------------------------------------------------------------------------------- policies


def scripted_policy(observation: NDArray[np.float32], budget: int, runs_used: int) -> int:
    """The fixed schedule the learned policy is compared with: 4 m squares, alternately cw
    and ccw, with a one-way 4 m straight run as every eighth run from the third on (E_s;
    budgets of 8 runs and more),
    until the budget is spent."""
    del observation
    if runs_used >= budget:
        return STOP
    if runs_used % 8 == 2 and budget >= 8:
        return 5  # straight4
    straights_before = (runs_used + 5) // 8 if budget >= 8 else 0  # runs 2, 10, 18, ...
    squares_before = runs_used - straights_before
    return 1 + squares_before % 2  # square4-cw / square4-ccw


@dataclass(frozen=True)
class MlpPolicy:
    """A trained policy network evaluated in numpy: hidden layers with ``meta["activation"]``
    (``"tanh"``, SB3's default for PPO and A2C, or ``"relu"``, DQN's), then the action logits
    or Q-values; the deterministic action is the arg-max (what SB3's
    ``predict(deterministic=True)`` does for a ``Discrete`` space).

    Attributes:
        weights: (W, b) of every layer, the last one giving the logits; W has shape (out, in).
        meta: what the file says about its training (command, versions, time).
    """

    weights: tuple[tuple[FloatArray, FloatArray], ...]
    meta: dict[str, Any]

    def logits(self, observation: NDArray[np.floating[Any]]) -> FloatArray:
        """The action logits (PPO, A2C) or Q-values (DQN) for one observation or a batch."""
        h = np.asarray(observation, dtype=np.float64)
        relu = self.meta.get("activation", "tanh") == "relu"
        for w, b in self.weights[:-1]:
            h = h @ w.T + b
            h = np.maximum(h, 0.0) if relu else np.tanh(h)
        w, b = self.weights[-1]
        out: FloatArray = h @ w.T + b
        return out

    def __call__(self, observation: NDArray[np.float32]) -> int:
        return int(np.argmax(self.logits(observation)))

    def save(self, path: str | Path) -> None:
        """Write the weights and ``meta`` to an ``.npz`` file (atomically)."""
        from odomgym.io import atomic_writer

        arrays = {f"w{k}": w for k, (w, _) in enumerate(self.weights)}
        arrays.update({f"b{k}": b for k, (_, b) in enumerate(self.weights)})
        meta = np.array(json.dumps(self.meta))

        def write(tmp: Path) -> None:  # tmp ends in .npz: numpy adds no suffix
            np.savez(tmp, meta=meta, **arrays)  # type: ignore[arg-type]

        atomic_writer(Path(path), write)

    @classmethod
    def load(cls, path: str | Path) -> MlpPolicy:
        """Read a policy written by :meth:`save`; refuse one trained on another observation
        layout."""
        source = Path(path)

        def refuse(why: str) -> SpecError:
            return SpecError(f"{source}: not a selfcal policy file ({why})", field="policy")

        try:
            data = np.load(source, allow_pickle=False)
            if not isinstance(data, np.lib.npyio.NpzFile):
                raise refuse("a single array, not an .npz archive")
            with data:
                meta = json.loads(str(data["meta"]))
                layers = sum(1 for key in data.files if key.startswith("w"))
                weights = tuple(
                    (np.asarray(data[f"w{k}"], float), np.asarray(data[f"b{k}"], float))
                    for k in range(layers)
                )
        except (OSError, KeyError, ValueError, TypeError) as exc:
            raise refuse(str(exc)) from exc
        if not isinstance(meta, dict):
            raise refuse("its metadata is not a table")
        if meta.get("activation", "tanh") not in ("tanh", "relu"):
            raise refuse(f"unknown activation {meta.get('activation')!r}")
        version = meta.get("observation_version")
        if version != OBSERVATION_VERSION:
            raise SpecError(
                f"{source}: trained on observation layout {version}, this odomgym uses "
                f"{OBSERVATION_VERSION}; retrain with odomgym train selfcal",
                field="policy",
            )
        width = len(OBSERVATION_LAYOUT)
        for k, (w, b) in enumerate(weights):
            if w.ndim != 2 or b.shape != (w.shape[0],) or w.shape[1] != width:
                raise refuse(f"layer {k} has weights {w.shape} and biases {b.shape}")
            width = w.shape[0]
        if not weights or width != len(MENU):
            raise SpecError(
                f"{source}: network shape does not match {len(OBSERVATION_LAYOUT)} observations "
                f"and {len(MENU)} actions",
                field="policy",
            )
        return cls(weights, meta)


SHIPPED_POLICY = "selfcal-ppo.npz"


def load_policy(name: str) -> MlpPolicy:
    """``"learned"`` (the policy shipped in ``odomgym/data/policies``) or a path to an
    ``.npz`` policy file (``odomgym train selfcal`` writes one)."""
    if name == "learned":
        ref = resources.files("odomgym.data.policies") / SHIPPED_POLICY
        with resources.as_file(ref) as path:
            return MlpPolicy.load(path)
    path = Path(name)
    if not path.is_file():
        raise SpecError(
            f"policy must be 'learned', 'scripted' or a policy .npz file; {name!r} is none",
            field="policy",
        )
    return MlpPolicy.load(path)


# ---------------------------------------------------------------------------------- calibrator


@dataclass(frozen=True)
class SelfCalOptions:
    """Options of :class:`SelfCal`.

    Attributes:
        budget: runs the session may perform [runs] (the benchmark's default: 16).
        policy: ``"learned"`` (the shipped PPO policy), ``"scripted"`` (the fixed schedule of
            :func:`scripted_policy`) or the path of a policy ``.npz`` file.
    """

    budget: int = 16
    policy: str = "learned"

    def __post_init__(self) -> None:
        require_count("budget", self.budget, 1)
        if self.budget > MAX_BUDGET:
            raise SpecError(
                f"budget must be <= {MAX_BUDGET} runs, got {self.budget}", field="budget"
            )
        if not isinstance(self.policy, str) or not self.policy:
            raise SpecError(f"policy must be a name or a path, got {self.policy!r}", field="policy")
        if self.policy not in ("learned", "scripted") and not Path(self.policy).is_file():
            raise SpecError(
                f"policy must be 'learned', 'scripted' or a policy .npz file; {self.policy!r} "
                "is none",
                field="policy",
            )


class SelfCal(Calibrator):
    """A learned experiment-design policy with an end-pose estimator (see the module docs)."""

    name: ClassVar[str] = "selfcal"
    reference: ClassVar[str] = (
        "odomgym's SelfCalibration-v0 policy (PPO: Schulman et al. 2017) with a Gauss-Newton "
        "end-pose estimator; compared with Borenstein & Feng 1994"
    )
    options_type: ClassVar[type[Any]] = SelfCalOptions

    def __init__(self, budget: int = 16, policy: str = "learned") -> None:
        self.options = self.options_type(budget, policy)
        self._policy: MlpPolicy | None = None

    @classmethod
    def for_budget(cls, runs: int) -> SelfCal:
        """The learned policy with a budget of ``runs``."""
        return cls(budget=runs)

    def experiments(self) -> list[Experiment]:
        """Chosen as the session goes: the menu's experiments, one run each."""
        return [item.experiment for item in MENU if item.experiment is not None]

    def _choose(self, session: SelfCalSession) -> int:
        if session.runs_left <= 0:
            return STOP
        if self.options.policy == "scripted":
            return scripted_policy(session.observation(), session.budget, session.runs_used)
        if self._policy is None:
            self._policy = load_policy(self.options.policy)
        return self._policy(session.observation())

    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        """Run a session in ``lab``: choose, drive with the current estimate, measure, refit."""
        sensor = getattr(lab, "sensor", None)  # a SimLab's; else the default sonar calibrator
        session = SelfCalSession(lab.robot, self.options.budget, sensor, initial)
        while (action := self._choose(session)) != STOP:
            experiment = session.experiment(action)
            assert experiment is not None
            runs = perform(lab, experiment, session.calibration, method=self.name)
            session.record(action, runs)
        est = session.estimator
        e_d, e_b, e_s = est.errors
        rel = est.relative_std
        return CalibrationResult(
            calibration=session.calibration,
            estimates={
                "E_d": float(e_d),
                "E_b": float(e_b),
                "E_s": float(e_s),
                "roughness": est.roughness,
                "rel_std_E_s": float(rel[0]),
                "rel_std_E_d": float(rel[1]),
                "rel_std_E_b": float(rel[2]),
            },
            runs_used=lab.runs_used,
            distance_used=lab.distance_used,
            notes=[f"experiments: {', '.join(session.history) or 'none'}"],
        )


@dataclass(frozen=True)
class SelfCalScriptedOptions(SelfCalOptions):
    """Options of :class:`SelfCalScripted`: :class:`SelfCalOptions` with the scripted policy."""

    policy: str = "scripted"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.policy != "scripted":
            raise SpecError(
                "selfcal_scripted always drives the scripted schedule; for another policy use "
                f"selfcal --policy {self.policy}",
                field="policy",
            )


class SelfCalScripted(SelfCal):
    """The ablation of ``selfcal``: the same estimator with the fixed schedule of
    :func:`scripted_policy` — what the estimator achieves without a learned policy."""

    name: ClassVar[str] = "selfcal_scripted"
    reference: ClassVar[str] = (
        "odomgym's end-pose Gauss-Newton estimator with a fixed schedule of 4 m squares "
        "(Borenstein & Feng 1994's experiment) and straight runs"
    )
    options_type: ClassVar[type[Any]] = SelfCalScriptedOptions

    def __init__(self, budget: int = 16, policy: str = "scripted") -> None:
        super().__init__(budget, policy)

"""Self-calibration: a policy chooses the experiments, a Kalman filter does the geometry.

UMBmark (Borenstein & Feng 1994, §6.3) prescribes ten 4×4 m squares and reads two numbers off
their end errors. ``selfcal`` asks instead: *which* run should the robot drive next, given
what it has measured so far, and when has it learnt enough? A session has a budget of runs;
at every step a policy picks one item of :data:`ACTION_MENU` (a 4 m or 2 m square either way, a 4 m
straight run one way or out and back, an in-place spin) or ``stop``. Every run is driven with
the current estimate in the odometry (iterative compensation, as UMBmark's §6.3 second round
and solderspot 2014 do), and the lab's ground-truth sensor measures it.

**The estimator** (:class:`odomgym.selfcal.estimators.TrajectoryEstimator`) is an augmented-state
Kalman filter along every measured pose of the runs (Larsen et al. 1998; Martinelli et al.
2007), with a prior from the benchmark population; ``observe="end_pose"``
(:class:`~odomgym.selfcal.estimators.EndPoseEstimator`, the ``selfcal_end_pose`` method) restricts
it to the end poses a person at the home position measures — UMBmark's information. The
session, its menu and its observation are :mod:`odomgym.selfcal.session`, shared with the env.

**The policy** maps the session's fixed-size observation
(:meth:`~odomgym.selfcal.session.SelfCalSession.observation`, layout
:data:`~odomgym.selfcal.session.OBSERVATION_LAYOUT`) to a menu item. The shipped policy
(``selfcal-ppo.npz``) is a small MLP trained with PPO (Schulman et al. 2017) in
``SelfCalibration-v1`` (``odomgym train selfcal``); it runs here in numpy, so calibrating needs
no torch. The ``scripted`` policy (alternate 4 m squares, a straight run every eighth run) is the
ablation that shows what the estimator does without learning.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from odomgym.baselines.base import CalibrationResult, Calibrator, Holdings, perform
from odomgym.errors import SpecError, require_count
from odomgym.lab.experiment import Experiment, Lab
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import require_differential
from odomgym.selfcal.episodes import skid_prior
from odomgym.selfcal.estimators import check_observe
from odomgym.selfcal.menu import ACTION_MENU, STOP
from odomgym.selfcal.session import (
    MAX_BUDGET,
    OBSERVATION_LAYOUT,
    OBSERVATION_VERSION,
    SelfCalSession,
)

__all__ = [
    "MlpPolicy",
    "SelfCal",
    "SelfCalEndPose",
    "SelfCalEndPoseOptions",
    "SelfCalOptions",
    "SelfCalScripted",
    "SelfCalScriptedOptions",
    "load_policy",
    "schedule_items",
    "scripted_policy",
]

FloatArray = NDArray[np.float64]
Policy = Callable[[NDArray[np.float32]], int]

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

        if not zipfile.is_zipfile(source):
            # np.load would try the file as a pickle and refuse with its "allow_pickle" text,
            # which names numpy's switch rather than what the user gave.
            raise SpecError(
                f"{source}: not a selfcal policy file (an .npz written by odomgym train selfcal)",
                field="policy",
            )
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
        if not weights or width != len(ACTION_MENU):
            raise SpecError(
                f"{source}: network shape does not match {len(OBSERVATION_LAYOUT)} observations "
                f"and {len(ACTION_MENU)} actions",
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
    _check_policy_name(name)
    return MlpPolicy.load(Path(name))


def _check_policy_name(name: str) -> None:
    """Refuse a ``policy`` that is neither a name nor an existing file, saying which it is —
    a folder, or no such file — rather than "'adir' is none", which told a user nothing."""
    if name in ("learned", "scripted"):
        return
    path = Path(name)
    if path.is_dir():
        why = "is a folder"
    elif not path.exists():
        why = "no such file"
    elif not path.is_file():
        why = "is not a regular file"
    else:
        return
    raise SpecError(
        f"policy {name}: {why}; give 'learned', 'scripted' or a policy .npz file (written by "
        "odomgym train selfcal)",
        field="policy",
    )


# ---------------------------------------------------------------------------------- calibrator


@dataclass(frozen=True)
class SelfCalOptions:
    """Options of :class:`SelfCal`.

    Attributes:
        budget: runs the session may perform [runs] (the benchmark's default: 16).
        policy: ``"learned"`` (the shipped PPO policy), ``"scripted"`` (the fixed schedule of
            :func:`scripted_policy`) or the path of a policy ``.npz`` file.
        observe: what the estimator sees of each run: ``"trajectory"`` (every measured pose,
            the default) or ``"end_pose"`` (:data:`odomgym.selfcal.estimators.ESTIMATORS`); a
            learned policy must have been trained with the same (its file records it).
    """

    budget: int = 16
    policy: str = "learned"
    observe: str = "trajectory"

    def __post_init__(self) -> None:
        check_observe(self.observe)
        require_count("budget", self.budget, 1)
        if self.budget > MAX_BUDGET:
            raise SpecError(
                f"budget must be <= {MAX_BUDGET} runs, got {self.budget}", field="budget"
            )
        if not isinstance(self.policy, str) or not self.policy:
            raise SpecError(f"policy must be a name or a path, got {self.policy!r}", field="policy")
        _check_policy_name(self.policy)


class SelfCal(Calibrator):
    """A learned experiment-design policy with an end-pose estimator (see the module docs)."""

    name: ClassVar[str] = "selfcal"
    reference: ClassVar[str] = (
        "odomgym's SelfCalibration-v1 policy (PPO: Schulman et al. 2017) with an augmented-"
        "state Kalman filter along the measured runs; compared with Borenstein & Feng 1994"
    )
    options_type: ClassVar[type[Any]] = SelfCalOptions

    def __init__(
        self, budget: int = 16, policy: str = "learned", observe: str = "trajectory"
    ) -> None:
        self.options = self.options_type(budget, policy, observe)
        self._policy: MlpPolicy | None = None

    min_budget: ClassVar[int] = 1
    max_budget: ClassVar[int | None] = MAX_BUDGET

    @classmethod
    def budget_options(cls, runs: int) -> dict[str, Any]:
        """The whole budget is the session's."""
        return {"budget": runs}

    @classmethod
    def square_options(cls, side: float, runs_per_direction: int) -> dict[str, Any]:
        """The policy chooses its runs from a fixed menu: it gets UMBmark's budget for these
        settings (2N squares and the 6 straight runs of its E_s phases; 16 for the defaults)."""
        del side
        return {"budget": 2 * runs_per_direction + 6}

    @classmethod
    def session_options(cls, held: Holdings) -> dict[str, Any]:
        del held
        raise LookupError(
            "selfcal chooses each next run as it goes, which needs a simulated lab; a recorded "
            "session holds only the runs that were driven"
        )

    def experiments(self) -> list[Experiment]:
        """Chosen as the session goes: the menu's experiments, one run each."""
        return [item.experiment for item in ACTION_MENU if item.experiment is not None]

    def _choose(self, session: SelfCalSession) -> int:
        if session.runs_left <= 0:
            return STOP
        if self.options.policy == "scripted":
            return scripted_policy(session.observation(), session.budget, session.runs_used)
        if self._policy is None:
            policy = load_policy(self.options.policy)
            trained = policy.meta.get("observe", "trajectory")
            if trained != self.options.observe:
                raise SpecError(
                    f"policy {self.options.policy!r} was trained with observe={trained!r}, not "
                    f"{self.options.observe!r}: its observations would mean something else",
                    field="observe",
                )
            self._policy = policy
        return self._policy(session.observation())

    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        """Run a session in ``lab``: choose, drive with the current estimate, measure, refit.

        A skid-steer robot without an ``initial`` calibration starts as ``SelfCalibration-v1``
        starts it: from the apparent track of rigid contacts in a slow spin
        (:func:`odomgym.selfcal.episodes.skid_prior`), the estimate centred there; from the
        identity its estimator's prior range would hold E_b far below the track it needs.
        """
        # Its estimators keep E_b, c_L, c_R, E_s of an initial calibration; ICR offsets or a
        # track curve would be dropped, so they are refused.
        require_differential(initial, self.name)
        sensor = getattr(lab, "sensor", None)  # a SimLab's; else the default sonar calibrator
        centred = initial is None and lab.robot.is_skid_steer
        session = SelfCalSession(
            lab.robot,
            self.options.budget,
            sensor,
            skid_prior(lab.robot) if centred else initial,
            observe=self.options.observe,
            centred=centred,
        )
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
    """Options of :class:`SelfCalScripted`: :class:`SelfCalOptions` with the scripted policy.

    Attributes:
        schedule: menu item names (:data:`~odomgym.selfcal.menu.ACTION_MENU`, e.g.
            ``("square4-cw", "square4-ccw", "straight4")``, or one comma-separated string)
            driven in this order, repeated until the budget is spent; empty (the default) for
            :func:`scripted_policy`'s schedule. A lab that can drive only some items, or an
            experiment design of your own (``benchmarks/design_bound.py``).
    """

    policy: str = "scripted"
    schedule: Sequence[str] | str = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.policy != "scripted":
            raise SpecError(
                "selfcal_scripted always drives the scripted schedule; for another policy use "
                f"selfcal --policy {self.policy}",
                field="policy",
            )
        object.__setattr__(self, "schedule", schedule_items(self.schedule))


def schedule_items(schedule: object) -> tuple[str, ...]:
    """``schedule`` checked: a sequence (or comma-separated string) of menu item names other
    than ``stop``; a :class:`SpecError` (field ``schedule``) names the first unknown one."""
    if isinstance(schedule, str):
        text = schedule
        schedule = [name.strip() for name in text.split(",") if name.strip()]
        if not schedule:
            raise SpecError(
                f"schedule {text!r} names no menu item (leave it out for the scripted schedule)",
                field="schedule",
            )
    if not isinstance(schedule, (list, tuple)):
        raise SpecError(
            f"schedule must be a list of menu item names, got {schedule!r}", field="schedule"
        )
    names = [item.name for item in ACTION_MENU[1:]]
    for name in schedule:
        if name not in names:
            raise SpecError(
                f"schedule: {name!r} is not a menu item; the menu has {', '.join(names)}",
                field="schedule",
            )
    return tuple(schedule)


class SelfCalScripted(SelfCal):
    """The ablation of ``selfcal``: the same estimator with the fixed schedule of
    :func:`scripted_policy` — what the estimator achieves without a learned policy — or any
    fixed ``schedule`` of menu items."""

    name: ClassVar[str] = "selfcal_scripted"
    reference: ClassVar[str] = (
        "odomgym's trajectory Kalman filter with a fixed schedule of 4 m squares "
        "(Borenstein & Feng 1994's experiment) and straight runs"
    )
    options_type: ClassVar[type[Any]] = SelfCalScriptedOptions

    def __init__(
        self,
        budget: int = 16,
        policy: str = "scripted",
        observe: str = "trajectory",
        schedule: Sequence[str] | str = (),
    ) -> None:
        super().__init__(budget, policy, observe)
        self.options = self.options_type(
            budget=budget, policy=policy, observe=observe, schedule=schedule
        )

    def _choose(self, session: SelfCalSession) -> int:
        schedule = self.options.schedule
        if not schedule or session.runs_left <= 0:
            return super()._choose(session)
        name = schedule[session.runs_used % len(schedule)]
        return next(i for i, item in enumerate(ACTION_MENU) if item.name == name)


@dataclass(frozen=True)
class SelfCalEndPoseOptions(SelfCalScriptedOptions):
    """Options of :class:`SelfCalEndPose`: the scripted schedule, end poses only."""

    observe: str = "end_pose"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.observe != "end_pose":
            raise SpecError(
                "selfcal_end_pose always sees end poses only; for the trajectory use "
                "selfcal_scripted",
                field="observe",
            )


class SelfCalEndPose(SelfCalScripted):
    """The second ablation: the scripted schedule with the estimator restricted to each run's
    end pose (:class:`~odomgym.selfcal.estimators.EndPoseEstimator`) — UMBmark's information, a
    tape measure at the home position — so the gain of seeing the whole trajectory is measured
    on its own."""

    name: ClassVar[str] = "selfcal_end_pose"
    reference: ClassVar[str] = (
        "odomgym's end-pose Gauss-Newton estimator with the fixed schedule of selfcal_scripted "
        "(end poses only, as Borenstein & Feng 1994 measure them)"
    )
    options_type: ClassVar[type[Any]] = SelfCalEndPoseOptions

    def __init__(
        self,
        budget: int = 16,
        policy: str = "scripted",
        observe: str = "end_pose",
        schedule: Sequence[str] | str = (),
    ) -> None:
        super().__init__(budget, policy, observe, schedule)

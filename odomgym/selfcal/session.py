"""The self-calibration session: its books, its observation, and the estimator it feeds.

A session (:class:`SelfCalSession`) has a budget of runs; at every step a policy picks one item
of :data:`~odomgym.selfcal.menu.ACTION_MENU` (a 4 m or 2 m square either way, a 4 m straight
run one way or out and back, an in-place spin) or ``stop``, the run is driven with the current
estimate in the odometry, and the lab's ground-truth sensor measures it; the session's
estimator (:mod:`odomgym.selfcal.estimators`) updates the estimate.

The Gymnasium env (:mod:`odomgym.envs.selfcal`), its batched training env and the calibrator
(:class:`odomgym.baselines.selfcal.SelfCal`) all drive this one object, so it lives in the core
below them: the policy acts in deployment exactly as it was trained.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from odomgym.errors import SpecError, require_count
from odomgym.lab.experiment import Experiment, SensorAccuracy
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec
from odomgym.selfcal.estimators import ESTIMATORS, check_observe
from odomgym.selfcal.menu import ACTION_MENU, STOP

__all__ = [
    "MAX_BUDGET",
    "OBSERVATION_BOUND",
    "OBSERVATION_LAYOUT",
    "OBSERVATION_VERSION",
    "REFERENCE_BUDGET",
    "SelfCalSession",
]

FloatArray = NDArray[np.float64]

#: Largest budget a session accepts [runs].
MAX_BUDGET = 64
#: Budget the observation is scaled by [runs] (the benchmark's default budget).
REFERENCE_BUDGET = 16.0

# The observation vector: names of its entries, in order (the shipped policy was trained on
# this layout; change it only with a new OBSERVATION_VERSION and a retrained policy).
OBSERVATION_LAYOUT: tuple[str, ...] = (
    "runs_left_fraction",
    "budget_over_16",
    *(f"share_{item.name}" for item in ACTION_MENU[1:]),
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
    *(f"last_{item.name}" for item in ACTION_MENU),
)
OBSERVATION_VERSION = 2
"""2: the estimate and its spreads come from the session's estimator, by default the
trajectory filter (version 1 had only end poses; a version-1 policy reads the spreads wrongly)."""

OBSERVATION_BOUND = 10.0


class SelfCalSession:
    """One self-calibration session: the books, the estimator and the observation.

    The Gymnasium env, its batched vector env and the :class:`SelfCal` calibrator all drive
    this one object, so the policy acts in deployment exactly as it was trained.

    Args:
        robot: the nominal robot.
        budget: runs the session may perform (1 to :data:`MAX_BUDGET`).
        sensor: the ground-truth sensor's accuracy (each pose sample).
        initial: the calibration to start from (default: uncalibrated).
        observe: ``"trajectory"`` or ``"end_pose"``
            (:data:`~odomgym.selfcal.estimators.ESTIMATORS`).
        centred: keep the estimate within the prior's range of ``initial`` rather than of the
            nominal robot, and observe E_b relative to it (skid-steer sessions).
    """

    def __init__(
        self,
        robot: RobotSpec,
        budget: int,
        sensor: SensorAccuracy | None = None,
        initial: Calibration | None = None,
        observe: str = "trajectory",
        *,
        centred: bool = False,
    ) -> None:
        self.budget = require_count("budget", budget, 1)
        if self.budget > MAX_BUDGET:
            raise SpecError(f"budget must be <= {MAX_BUDGET} runs, got {budget}", field="budget")
        self.observe = check_observe(observe)
        self.estimator = ESTIMATORS[observe](robot, sensor or SensorAccuracy(), initial)
        # ``centred``: the estimate stays near ``initial`` and the observed E_b is relative to
        # it (a skid-steer session starts from its apparent track, far from 1; otherwise the
        # observation is E_b − 1 as always).
        self.estimator.centred = centred
        self._e_b0 = float(initial.wheelbase_scale) if centred and initial is not None else 1.0
        self.counts = np.zeros(len(ACTION_MENU), dtype=np.int64)
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
        if not 0 <= action < len(ACTION_MENU):
            raise SpecError(
                f"action must be a menu index 0..{len(ACTION_MENU) - 1}, got {action}",
                field="action",
            )
        return ACTION_MENU[action].experiment

    def record(self, action: int, runs: list[Run]) -> None:
        """Take in the measured run(s) of menu item ``action``."""
        if self.experiment(action) is None:
            raise SpecError("stop drives no run: nothing to record", field="action")
        for run in runs:
            self.innovation = self.estimator.add(run, action)
        self.counts[action] += len(runs)
        self.runs_used += len(runs)
        self.last_item = action
        self.history.append(ACTION_MENU[action].name)

    def observation(self) -> NDArray[np.float32]:
        """The policy's view (:data:`OBSERVATION_LAYOUT`), every entry within ±10."""
        est = self.estimator
        e_d, e_b, e_s = est.errors
        last = np.zeros(len(ACTION_MENU))
        last[self.last_item] = 1.0
        values = np.concatenate(
            [
                [self.runs_left / self.budget, self.budget / REFERENCE_BUDGET],
                self.counts[1:] / self.budget,
                [(e_d - 1.0) / 0.01, (e_b / self._e_b0 - 1.0) / 0.05, (e_s - 1.0) / 0.02],
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

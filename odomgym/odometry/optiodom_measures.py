"""The OptiOdom evaluation measures: how far odometry drifts from the ground truth.

Sousa et al. (OptiOdom, J. Intell. Robot. Syst. 105:39, 2022) compare calibration methods by
replaying every run's encoder counts with the calibrated parameters and measuring the pose
error e(t) = ground truth − odometry, the odometry started at the first ground-truth pose.
Their ``computeEvaluationMeasures.m`` (github.com/sousarbarb/optiodom) reports four numbers over
a set of runs, which ``published_results.csv`` lists as ``max_pos``, ``max_th_deg``,
``final_pos`` and ``final_th_deg``:

* the largest position error ‖(e_x, e_y)‖ over all samples of all runs [m];
* the largest heading error |wrap(e_θ)| over all samples of all runs [rad];
* the largest *final* position error (last sample of each run) [m];
* the largest final heading error [rad].

Why whole trajectories and not just return errors: a calibration can close the loop at the end
of a square while being wrong in between (Type A and Type B errors cancelling, Borenstein & Feng
1994, §6), and the maxima over all samples expose that. Position errors are frame-independent in
magnitude, so no frame choice is needed here.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym.odometry.calibration import Calibration, wrap_angle
from odomgym.odometry.runs import Run, replay_odometry
from odomgym.robot import RobotSpec

__all__ = ["EvaluationMeasures", "evaluate", "pose_errors"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class EvaluationMeasures:
    """The four OptiOdom evaluation measures over a set of runs.

    Attributes:
        max_position: largest position error over all samples of all runs [m].
        max_heading: largest absolute heading error over all samples [rad].
        final_position: largest position error at the end of a run [m].
        final_heading: largest absolute heading error at the end of a run [rad].
    """

    max_position: float
    max_heading: float
    final_position: float
    final_heading: float

    def as_published(self) -> dict[str, float]:
        """The measures under the column names and units of ``published_results.csv``
        (``max_pos`` [m], ``max_th_deg`` [deg], ``final_pos`` [m], ``final_th_deg`` [deg])."""
        return {
            "max_pos": self.max_position,
            "max_th_deg": math.degrees(self.max_heading),
            "final_pos": self.final_position,
            "final_th_deg": math.degrees(self.final_heading),
        }


def pose_errors(run: Run, robot: RobotSpec, calibration: Calibration | None = None) -> FloatArray:
    """Ground truth − odometry at every sample of ``run`` (T, 3), in the ground-truth frame.

    The odometry is :func:`odomgym.odometry.runs.replay_odometry` (started at the first ground-truth
    pose, midpoint integration, as the authors' ``simulateRobot_diff.m``). Columns: e_x, e_y [m]
    and e_θ [rad] wrapped to [−π, π).
    """
    errors = run.true_pose - replay_odometry(run, robot, calibration)
    errors[:, 2] = wrap_angle(errors[:, 2])
    return errors


def evaluate(
    runs: Iterable[Run], robot: RobotSpec, calibration: Calibration | None = None
) -> EvaluationMeasures:
    """The OptiOdom evaluation measures of ``calibration`` on ``runs`` (default: uncalibrated).

    Raises:
        ValueError: if ``runs`` is empty.
    """
    max_pos = max_th = final_pos = final_th = -math.inf
    count = 0
    for run in runs:
        errors = pose_errors(run, robot, calibration)
        position = np.hypot(errors[:, 0], errors[:, 1])
        heading = np.abs(errors[:, 2])
        max_pos = max(max_pos, float(position.max()))
        max_th = max(max_th, float(heading.max()))
        final_pos = max(final_pos, float(position[-1]))
        final_th = max(final_th, float(heading[-1]))
        count += 1
    if count == 0:
        raise ValueError("evaluate() needs at least one run")
    return EvaluationMeasures(max_pos, max_th, final_pos, final_th)

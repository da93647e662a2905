"""Replay a logged run's wheel motions through a robot model: the predicted tracked poses.

The model is a :class:`~odomgym.robot.RobotSpec` with its effects: the logged encoder counts are
the motor rotations; the replay applies, per sample interval, the equations of
``docs/effects.md`` — transmission (backlash), the true wheel geometry, body increments (turn skid,
wheel toe), midpoint integration, the tracked point — i.e. the World's physics without Chipmunk.
It starts from the first measured pose, moved from the tracked point to the axle.

Everything is vectorised over the samples of a run (numpy), so a fit can replay dozens of runs
per millisecond-scale evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym.effects import EFFECTS, ReplayArrays
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = ["Replay", "replay_run", "session_time", "wheel_angles"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Replay:
    """A run replayed through a model.

    Attributes:
        pose: predicted axle-midpoint poses (T, 3) [m, m, rad].
        tracked: predicted poses of the tracked point (T, 3), comparable with ``run.true_pose``.
        travel: each wheel's ground travel per sample interval (n, 2) [m], n = T − 1.
        ds, dtheta: body increments per interval [m], [rad].
        wheelbase: the model's true wheelbase [m].
    """

    pose: FloatArray
    tracked: FloatArray
    travel: FloatArray
    ds: FloatArray
    dtheta: FloatArray
    wheelbase: float


def _effects_of(spec: RobotSpec) -> list[tuple[str, dict[str, float]]]:
    return [(name, values) for name, values in spec.effect_dict().items() if name in EFFECTS]


def replay_run(run: Run, spec: RobotSpec) -> Replay:
    """Replay ``run``'s counts through ``spec`` (its true geometry and its effects).

    The first sample must carry a full measured pose (the readers check it).
    """
    effects = _effects_of(spec)
    dt = np.diff(run.time)
    motor = np.diff(run.counts, axis=0).astype(np.float64) * (2.0 * np.pi / spec.ticks_per_rev)
    radius = 0.5 * np.array([spec.true_left_diameter, spec.true_right_diameter], dtype=float)
    arrays = ReplayArrays(
        dt=dt,
        wheel=motor,
        wheelbase=float(spec.true_wheelbase),
        radius=radius,
        angle=wheel_angles(run, motor),
        time=session_time(run),
    )
    for name, values in effects:
        EFFECTS[name].replay("transmission", values, arrays)
    travel = arrays.wheel * radius
    wheelbase = float(spec.true_wheelbase)
    arrays.travel = travel
    arrays.ds = 0.5 * (travel[:, 0] + travel[:, 1])
    arrays.dtheta = (travel[:, 1] - travel[:, 0]) / wheelbase
    arrays.crab = np.zeros_like(dt)
    for name, values in effects:
        EFFECTS[name].replay("body", values, arrays)
    start = _start_pose(run.true_pose[0], effects)
    ds, dtheta = arrays.ds, arrays.dtheta
    theta = start[2] + np.concatenate([[0.0], np.cumsum(dtheta)])
    direction = theta[:-1] + 0.5 * dtheta + arrays.crab
    pose = np.empty((len(run.time), 3))
    pose[:, 0] = start[0] + np.concatenate([[0.0], np.cumsum(ds * np.cos(direction))])
    pose[:, 1] = start[1] + np.concatenate([[0.0], np.cumsum(ds * np.sin(direction))])
    pose[:, 2] = theta
    tracked = _measure(pose, effects, arrays)
    return Replay(pose, tracked, travel, ds, dtheta, wheelbase)


def wheel_angles(run: Run, motor: FloatArray) -> FloatArray:
    """Each wheel's angle at the middle of every interval [rad], from the session's start when
    the run records where its wheels began (``meta["wheel_angle0"]``), else from the run's."""
    start = np.zeros(2)
    given = run.meta.get("wheel_angle0")
    if given is not None:
        start = np.asarray(given, dtype=float).reshape(2)
    before = np.concatenate([np.zeros((1, 2)), np.cumsum(motor, axis=0)[:-1]])
    angles: FloatArray = start + before + 0.5 * motor
    return angles


def session_time(run: Run) -> FloatArray:
    """Time since the session started at the middle of every interval [s]."""
    t0 = float(run.meta.get("session_time", 0.0))  # type: ignore[arg-type]
    middle: FloatArray = t0 + 0.5 * (run.time[1:] + run.time[:-1]) - run.time[0]
    return middle


def _measure(
    pose: FloatArray, effects: list[tuple[str, dict[str, float]]], arrays: ReplayArrays
) -> FloatArray:
    arrays.pose = pose
    arrays.tracked = pose.copy()
    for name, values in effects:
        EFFECTS[name].replay("measurement", values, arrays)
    return arrays.tracked


def _start_pose(measured: FloatArray, effects: list[tuple[str, dict[str, float]]]) -> FloatArray:
    """The axle pose whose tracked point is the measured first pose (fixed-point iteration:
    exact in two steps for rigid offsets, which do not change the heading)."""
    target = np.asarray(measured, dtype=float)[None, :]
    pose = target.copy()
    arrays = ReplayArrays(dt=np.zeros(0), wheel=np.zeros((0, 2)))
    for _ in range(3):
        seen = _measure(pose, effects, arrays)
        pose = pose + (target - seen)
    start: FloatArray = pose[0]
    return start

"""The compiled kernels of one control step after the physics: dead reckoning, route progress,
rewards and the reported poses.

Why one module: these kernels call each other (an env's step runs them in one compiled call,
:func:`after_step_report`, because numba's dispatch costs ~0.1 µs per array argument and the
single-robot env step is a few µs), and numba's on-disk cache only notices edits to a kernel's
own module (see :mod:`odomgym._jit`). The classes that own the state
(:class:`odomgym.odometry.Odometry`, :class:`odomgym.routes.RouteProgress`,
:class:`odomgym.trial.Trial`, the envs' ``RouteEpisodes``) call them.

Units: metres, radians, seconds.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel

__all__ = [
    "REPORT_COLUMNS",
    "after_step",
    "after_step_report",
    "episode_report",
    "integrate_odometry",
    "pose_error_into",
    "route_update",
    "start_frame",
]

FloatArray = NDArray[np.float64]

#: Columns of :func:`episode_report`'s rows: name -> (first, stop).
REPORT_COLUMNS: dict[str, tuple[int, int]] = {
    "reward": (0, 1),
    "terminated": (1, 2),
    "progress": (2, 3),
    "time": (3, 4),
    "completion": (4, 5),
    "odom_pose": (5, 8),
    "true_pose": (8, 11),
    "pose_error": (11, 14),
    "encoder_counts": (14, 16),
    "segment": (16, 17),
    "episode_time": (17, 18),
}
REPORT_WIDTH = 18


@kernel
def integrate_odometry(
    counts: NDArray[np.int64],
    last_counts: NDArray[np.int64],
    travel_per_tick: FloatArray,
    wheelbase: FloatArray,
    inv_dt: float,
    pose: FloatArray,
    wheel_speed: FloatArray,
) -> None:
    """Midpoint dead reckoning of one sampling period, in place (:mod:`odomgym.odometry`'s
    equations): ``pose`` (N, 3) and ``wheel_speed`` (N, 2) [m/s] from cumulative ``counts``."""
    for i in range(counts.shape[0]):
        left = (counts[i, 0] - last_counts[i, 0]) * travel_per_tick[i, 0]
        right = (counts[i, 1] - last_counts[i, 1]) * travel_per_tick[i, 1]
        last_counts[i, 0] = counts[i, 0]
        last_counts[i, 1] = counts[i, 1]
        wheel_speed[i, 0] = left * inv_dt
        wheel_speed[i, 1] = right * inv_dt
        ds = 0.5 * (left + right)
        dtheta = (right - left) / wheelbase[i]
        mid = pose[i, 2] + 0.5 * dtheta
        pose[i, 0] += ds * math.cos(mid)
        pose[i, 1] += ds * math.sin(mid)
        pose[i, 2] += dtheta


@kernel
def route_update(
    pose: FloatArray,
    wheel_speed: FloatArray,
    max_speed: FloatArray,
    count: NDArray[np.intp],
    is_turn: NDArray[np.bool_],
    segments: FloatArray,
    cumulative: FloatArray,
    limits: FloatArray,
    advance: bool,
    index: NDArray[np.intp],
    state: FloatArray,
    progress: FloatArray,
    advanced: NDArray[np.bool_],
) -> None:
    """Route features of each robot's current segment (:meth:`odomgym.routes.RouteProgress.update`).

    ``segments`` (N, S, 7): start x, y [m], unit direction x, y, length [m or rad], held heading
    [rad], direction (+1 forwards, −1 reversing); ``limits`` (N, 3): position tolerance [m],
    heading tolerance [rad], stop speed [m/s].
    """
    two_pi = 2.0 * math.pi
    for i in range(pose.shape[0]):
        advanced[i] = False
        for _attempt in range(2):  # the second pass describes the segment just moved on to
            k = index[i]
            finished = k >= count[i]
            s = min(k, count[i] - 1)
            # A turn counts the rotation left unwrapped (a 360° spin must not look finished at
            # the start): that goes to ``remaining``; the heading error itself is wrapped.
            rotation_left = segments[i, s, 5] - pose[i, 2]
            error = (rotation_left + math.pi) % two_pi - math.pi
            rel_x = pose[i, 0] - segments[i, s, 0]
            rel_y = pose[i, 1] - segments[i, s, 1]
            travelled = rel_x * segments[i, s, 2] + rel_y * segments[i, s, 3]
            cross = segments[i, s, 2] * rel_y - segments[i, s, 3] * rel_x
            turn = is_turn[i, s]
            direction = segments[i, s, 6]
            if turn:
                remaining = rotation_left
                done_part = segments[i, s, 4] - abs(rotation_left)
                cross = 0.0
            else:
                remaining = segments[i, s, 4] - travelled
                done_part = travelled
                cross = cross * direction
            if finished:
                remaining = 0.0
                cross = 0.0
                error = 0.0
                progress[i] = cumulative[i, count[i]]
            else:
                progress[i] = cumulative[i, s] + min(max(done_part, 0.0), segments[i, s, 4])
            state[i, 0] = remaining
            state[i, 1] = cross
            state[i, 2] = error
            state[i, 3] = wheel_speed[i, 0] / max_speed[i]
            state[i, 4] = wheel_speed[i, 1] / max_speed[i]
            state[i, 5] = 1.0 if turn else 0.0
            state[i, 6] = direction
            total = cumulative[i, count[i]]
            state[i, 7] = progress[i] / total if total > 0.0 else 1.0
            if not advance or finished or advanced[i]:
                break
            stopped = max(abs(wheel_speed[i, 0]), abs(wheel_speed[i, 1])) < limits[i, 2]
            if turn:
                reached = abs(remaining) < limits[i, 1]
            else:
                reached = remaining < limits[i, 0]
            if not (reached and stopped):
                break
            index[i] = k + 1
            advanced[i] = True


@kernel
def start_frame(pose: FloatArray, start: FloatArray, out: FloatArray) -> None:
    """World-frame poses (N, 3) expressed in each robot's start frame, into ``out``."""
    for i in range(pose.shape[0]):
        c = math.cos(start[i, 2])
        s = math.sin(start[i, 2])
        dx = pose[i, 0] - start[i, 0]
        dy = pose[i, 1] - start[i, 1]
        out[i, 0] = c * dx + s * dy
        out[i, 1] = -s * dx + c * dy
        out[i, 2] = pose[i, 2] - start[i, 2]


@kernel
def pose_error_into(pose: FloatArray, start: FloatArray, odom: FloatArray, out: FloatArray) -> None:
    """True pose (world frame) in each robot's start frame minus odometry (N, 3), heading
    wrapped to [−π, π), into ``out`` (compiled; callable from other kernels)."""
    start_frame(pose, start, out)
    two_pi = 2.0 * math.pi
    for i in range(pose.shape[0]):
        out[i, 0] -= odom[i, 0]
        out[i, 1] -= odom[i, 1]
        out[i, 2] = (out[i, 2] - odom[i, 2] + math.pi) % two_pi - math.pi


@kernel
def after_step(
    counts: NDArray[np.int64],
    last_counts: NDArray[np.int64],
    travel_per_tick: FloatArray,
    wheelbase: FloatArray,
    inv_dt: float,
    pose: FloatArray,
    wheel_speed: FloatArray,
    max_speed: FloatArray,
    count: NDArray[np.intp],
    is_turn: NDArray[np.bool_],
    segments: FloatArray,
    cumulative: FloatArray,
    limits: FloatArray,
    index: NDArray[np.intp],
    state: FloatArray,
    progress: FloatArray,
    advanced: NDArray[np.bool_],
) -> None:
    """:func:`integrate_odometry` then :func:`route_update` (moving on to the next segment)."""
    integrate_odometry(counts, last_counts, travel_per_tick, wheelbase, inv_dt, pose, wheel_speed)
    route_update(
        pose,
        wheel_speed,
        max_speed,
        count,
        is_turn,
        segments,
        cumulative,
        limits,
        True,
        index,
        state,
        progress,
        advanced,
    )


@kernel
def episode_report(
    true_pose: FloatArray,
    start_poses: FloatArray,
    odom_pose: FloatArray,
    counts: NDArray[np.int64],
    index: NDArray[np.intp],
    count: NDArray[np.intp],
    state: FloatArray,
    time: float,
    episodes: FloatArray,
    weights: FloatArray,
    rewarded: bool,
    out: FloatArray,
) -> None:
    """One row per robot of what a route-following env reports after a step (columns in
    :data:`REPORT_COLUMNS`): the reward and its terms, whether the route is done, the
    odometry and true poses and their error, encoder counts, segment and episode time [s].

    ``episodes`` (N, 2): each robot's episode start time [s] and its route share at its last
    reward; ``weights`` = (progress, time, completion) reward weights. With ``rewarded`` the
    reward terms are those of this step and the route share moves on; without (after a reset),
    they are zero and the share stays.
    """
    pose_error_into(true_pose, start_poses, odom_pose, out[:, 11:14])
    for i in range(true_pose.shape[0]):
        done = index[i] >= count[i]
        if rewarded:
            now = state[i, 7]
            out[i, 2] = weights[0] * (now - episodes[i, 1])
            out[i, 3] = -weights[1]
            out[i, 4] = weights[2] * (1.0 if done else 0.0)
            out[i, 0] = out[i, 2] + out[i, 3] + out[i, 4]
            episodes[i, 1] = now
        else:
            out[i, 0] = 0.0
            out[i, 2] = 0.0
            out[i, 3] = 0.0
            out[i, 4] = 0.0
        out[i, 1] = 1.0 if done else 0.0
        for k in range(3):
            out[i, 5 + k] = odom_pose[i, k]
            out[i, 8 + k] = true_pose[i, k]
        out[i, 14] = counts[i, 0]
        out[i, 15] = counts[i, 1]
        out[i, 16] = index[i]
        out[i, 17] = time - episodes[i, 0]


@kernel
def after_step_report(
    counts: NDArray[np.int64],
    last_counts: NDArray[np.int64],
    travel_per_tick: FloatArray,
    wheelbase: FloatArray,
    inv_dt: float,
    pose: FloatArray,
    wheel_speed: FloatArray,
    max_speed: FloatArray,
    count: NDArray[np.intp],
    is_turn: NDArray[np.bool_],
    segments: FloatArray,
    cumulative: FloatArray,
    limits: FloatArray,
    index: NDArray[np.intp],
    state: FloatArray,
    progress: FloatArray,
    advanced: NDArray[np.bool_],
    true_pose: FloatArray,
    start_poses: FloatArray,
    time: float,
    episodes: FloatArray,
    weights: FloatArray,
    out: FloatArray,
) -> None:
    """:func:`after_step` then the rewarded :func:`episode_report` into ``out``: everything a
    route-following env computes after the physics, in one compiled call."""
    after_step(
        counts,
        last_counts,
        travel_per_tick,
        wheelbase,
        inv_dt,
        pose,
        wheel_speed,
        max_speed,
        count,
        is_turn,
        segments,
        cumulative,
        limits,
        index,
        state,
        progress,
        advanced,
    )
    episode_report(
        true_pose,
        start_poses,
        pose,
        counts,
        index,
        count,
        state,
        time,
        episodes,
        weights,
        True,
        out,
    )

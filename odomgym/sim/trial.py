"""A trial: a batch of robots driving routes by odometry — World + Odometry + RouteProgress.

This is the one place where the physics, the dead reckoning and the route meet. The Gymnasium
envs (single and vector) wrap a trial and add spaces, rewards and rendering; the simulated lab
(:class:`odomgym.lab.simulated.SimLab`) drives a trial with the reference driver to produce runs. So
the env a policy is trained in and the experiments a calibrator runs are the same code.

Observation layout (one row per robot, ``float32``), in the odometry frame:

====  =====================  ==========================================================  =========
idx   name                   meaning                                                     unit
====  =====================  ==========================================================  =========
0     ``remaining``          distance left on a drive, or rotation left to turn          m / rad
                             (unwrapped: a 360° spin starts at 2π)
1     ``cross``              lateral offset from the drive's line (left +)               m
2     ``heading_error``      target heading − odometry heading, wrapped                  rad
3     ``wheel_speed_left``   left wheel speed from the encoders / max wheel speed        -
4     ``wheel_speed_right``  right wheel speed from the encoders / max wheel speed       -
5     ``is_turn``            1 during an in-place turn, 0 on a drive                     -
6     ``direction``          +1 driving forwards, −1 backwards                           -
7     ``route_fraction``     share of the route completed                                -
====  =====================  ==========================================================  =========
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym._kernels import (
    REPORT_WIDTH,
    StepArrays,
    check_step_status,
    control_step,
    pose_error_into,
)
from odomgym.floor import FloorSpec
from odomgym.odometry.calibration import Calibration, Odometry
from odomgym.robot import RobotSpec
from odomgym.sim.routes import Route, RouteProgress
from odomgym.sim.world import World

__all__ = ["OBSERVATION_NAMES", "Trial"]

FloatArray = NDArray[np.float64]

# control_step's report arguments when no report is asked for: empty, never read.
_NO_REPORT = (np.zeros((0, 2)), np.zeros(3), np.zeros((0, REPORT_WIDTH)))

OBSERVATION_NAMES = (
    "remaining",
    "cross",
    "heading_error",
    "wheel_speed_left",
    "wheel_speed_right",
    "is_turn",
    "direction",
    "route_fraction",
)


class Trial:
    """N robots on one floor, each following its route by its own odometry.

    Args:
        robots: one spec per robot.
        floor: the shared floor.
        routes: one route per robot, or one for all.
        calibration: odometry calibration, one for all or one per robot.
        dt: control period [s]; substeps: physics steps per control period.
        rng: floor-roughness noise source (required on rough floors).
        track_slip: accumulate per-wheel slip in ``world.slip``.
        start_poses: where each robot starts on the floor (N, 3) [m, m, rad] (default: the
            origin); odometry and route live in each robot's start frame.
    """

    def __init__(
        self,
        robots: RobotSpec | Sequence[RobotSpec],
        floor: FloorSpec,
        routes: Route | Sequence[Route],
        *,
        calibration: Calibration | Sequence[Calibration] | None = None,
        dt: float = 0.05,
        substeps: int = 1,
        rng: np.random.Generator | Sequence[np.random.Generator] | None = None,
        track_slip: bool = False,
        start_poses: FloatArray | None = None,
    ) -> None:
        specs = [robots] if isinstance(robots, RobotSpec) else list(robots)
        self.n = len(specs)
        self.robots = tuple(specs)
        self.world = World(specs, floor, dt=dt, substeps=substeps, rng=rng, track_slip=track_slip)
        # Where each robot starts on the floor (world frame). The odometry and the route live in
        # each robot's start frame, so the same route can be driven anywhere on a floor.
        self.start_poses = (
            np.zeros((self.n, 3)) if start_poses is None else np.array(start_poses, dtype=float)
        )
        if self.start_poses.shape != (self.n, 3) or not np.isfinite(self.start_poses).all():
            raise ValueError(f"start_poses must be a finite array of shape ({self.n}, 3)")
        if np.any(self.start_poses != 0.0):
            self.world.reset(self.start_poses)
        self.odometry = Odometry(specs, calibration)
        route_list = [routes] * self.n if isinstance(routes, Route) else list(routes)
        if len(route_list) != self.n:
            raise ValueError(f"need one route per robot ({self.n}), got {len(route_list)}")
        # Tolerances above one encoder count, so every robot can arrive (see RouteProgress).
        per_tick = np.array([s.metres_per_tick for s in specs])
        wheelbase = np.array([s.wheelbase for s in specs])
        self.progress = RouteProgress(
            route_list,
            position_tolerance=np.maximum(0.002, 2.0 * per_tick),
            heading_tolerance=np.maximum(0.0005, 1.5 * per_tick / wheelbase),
            stop_speed=np.maximum(0.005, 1.5 * per_tick / dt),
        )
        self._max_speed = np.array([s.max_wheel_speed for s in specs])
        # An action of 1 is the robot's top wheel speed: its wheel rate [rad/s] per unit action.
        self._action_to_rate = self._max_speed / self.world.nominal_radius
        self._route_arrays = self.progress.step_arrays()
        self._bind_step_arrays()
        self._refresh(advance=False)

    def _bind_step_arrays(self) -> None:
        """Gather the arrays of a control step for :func:`odomgym._kernels.control_step`
        (after construction, and after a reset, which may reallocate the route arrays)."""
        world, odometry = self.world, self.odometry
        self._step_arrays = StepArrays(
            self._action_to_rate,
            *world.step_arrays(),
            odometry.last_counts,
            odometry.travel_per_tick,
            odometry.effective_wheelbase,
            odometry.skid_terms,
            odometry.pose,
            odometry.wheel_speed,
            self._max_speed,
            *self._route_arrays,
            self.start_poses,
            world.substep,
            world.substeps,
            world.dt,
        )

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        del state["_step_arrays"]  # numba's object does not pickle; the copy gathers its own
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._bind_step_arrays()

    @property
    def dt(self) -> float:
        """Control period [s]."""
        return self.world.dt

    def reset(
        self,
        indices: NDArray[np.intp] | None = None,
        routes: Sequence[Route] | None = None,
    ) -> None:
        """Put robots (all, or ``indices``) back at their start poses, at rest, at the route
        start."""
        chosen_rows = np.arange(self.n) if indices is None else np.asarray(indices)
        self.world.reset(self.start_poses[chosen_rows], indices=indices)
        self.odometry.reset(indices=indices)
        if routes is not None:
            self.progress.set_routes(list(routes), indices)
        else:
            keep = self.progress.routes
            chosen = np.arange(self.n) if indices is None else np.asarray(indices)
            self.progress.set_routes([keep[i] for i in chosen], chosen)
        self._route_arrays = self.progress.step_arrays()  # set_routes may reallocate them
        self._bind_step_arrays()
        self._refresh(advance=False)

    def step(
        self,
        actions: FloatArray,
        report: tuple[FloatArray, FloatArray, FloatArray] | None = None,
    ) -> NDArray[np.bool_]:
        """Apply wheel-speed actions (N, 2) in [−1, 1] for one control period.

        With ``report`` = (episodes, weights, out), also writes the rewarded episode report
        into ``out`` (:func:`odomgym._kernels.episode_report`, where the arguments are
        described).

        Returns the robots that completed a segment this step.
        """
        world = self.world
        command = world.commands(actions)
        # Physics (when the World can fuse its step), dead reckoning, route progress and the
        # report in one compiled call; otherwise the World steps first, on its own.
        fused = world.fuses_substeps
        if not fused:
            world.step(command, scale=self._action_to_rate)
        episodes, weights, out = _NO_REPORT if report is None else report
        check_step_status(
            control_step(
                command, self._step_arrays, fused, report is not None, episodes, weights, out
            )
        )
        return self._route_arrays[-1].copy()

    def _refresh(self, advance: bool) -> NDArray[np.bool_]:
        return self.progress.update(
            self.odometry.pose, self.odometry.wheel_speed, self._max_speed, advance
        )

    # ------------------------------------------------------------------ views
    def observation(self) -> NDArray[np.float32]:
        """The observation rows (N, 8); see the module docstring for the layout."""
        return self.progress.state.astype(np.float32)

    @property
    def done(self) -> NDArray[np.bool_]:
        """Robots whose odometry says they completed their route and stopped."""
        return self.progress.done

    @property
    def true_pose(self) -> FloatArray:
        """Ground-truth poses (N, 3) [m, m, rad]."""
        return self.world.pose

    @property
    def odom_pose(self) -> FloatArray:
        """Odometry poses (N, 3) [m, m, rad]."""
        return self.odometry.pose

    def pose_error(self, out: FloatArray | None = None) -> FloatArray:
        """True − odometry (N, 3) in the start frame, heading wrapped to [−π, π) [m, m, rad];
        written into ``out`` (N, 3) if given."""
        if out is None:
            out = np.empty((self.n, 3))
        pose_error_into(self.world.pose, self.start_poses, self.odometry.pose, out)
        return out

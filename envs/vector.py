"""A native vector env: many robots in one World, stepped together.

``gymnasium.make_vec("UMBmarkSquare-v0", num_envs=256, vectorization_mode="vector_entry_point")``
returns an :class:`OdometryVectorEnv` whose sub-envs are the robots of one
:class:`odomgym.trial.Trial`: one pymunk space, ``pymunk.batch`` state I/O and compiled
per-robot kernels, instead of 256 Python env objects. Spaces, reward, ``info`` and episode ends
are those of the single envs (``odomgym.envs.umbmark``, ``odomgym.envs.straight``); ``info``
entries are arrays with a leading robot axis (``odom_covariance`` is not offered here: the
closed-form propagation is per robot and would cost more than the physics). ``time`` is the
simulated time since the vector env's reset. Autoreset follows Gymnasium's default
``NEXT_STEP`` mode: the step after a sub-env ends resets it and ignores its action.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from numpy.typing import NDArray

from odomgym.envs.base import RewardWeights, action_space, observation_space, resolve_specs
from odomgym.floor import FloorSpec
from odomgym.odometry import Calibration
from odomgym.paths import Route, square_route, straight_route
from odomgym.robot import RobotSpec
from odomgym.trial import Trial

__all__ = ["OdometryVectorEnv", "make_square_vector_env", "make_straight_vector_env"]

FloatArray = NDArray[np.float64]


class OdometryVectorEnv(VectorEnv[NDArray[np.float32], NDArray[np.float32], NDArray[Any]]):
    """``num_envs`` robots following routes by odometry, as one vector env.

    Args:
        num_envs: number of robots.
        robot: one spec for all, or a sequence of ``num_envs`` specs (a robot population).
        floor, calibration, dt, reward_weights: as the single envs.
        routes: one route for all, or one per robot.
        max_episode_steps: truncation limit per sub-env.
    """

    # Gymnasium declares ``metadata`` an instance attribute; every env overrides it this way.
    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}  # noqa: RUF012

    def __init__(
        self,
        num_envs: int,
        routes: Route | Sequence[Route],
        robot: RobotSpec | str | Sequence[RobotSpec] = "labmate",
        floor: FloorSpec | str = "smooth",
        calibration: Calibration | str | None = None,
        *,
        dt: float = 0.05,
        reward_weights: RewardWeights | None = None,
        max_episode_steps: int = 6000,
        covariance_k: tuple[float, float] | None = None,
    ) -> None:
        if covariance_k is not None:
            raise ValueError(
                "covariance_k is offered by the single envs only (gymnasium.make); the vector "
                "env does not propagate the odometry covariance"
            )
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        if isinstance(robot, (RobotSpec, str)):
            spec, self.floor, self.calibration = resolve_specs(robot, floor, calibration)
            self.robots: list[RobotSpec] = [spec] * num_envs
        else:
            self.robots = list(robot)
            if len(self.robots) != num_envs:
                raise ValueError(f"need {num_envs} robot specs, got {len(self.robots)}")
            _, self.floor, self.calibration = resolve_specs(self.robots[0], floor, calibration)
        self.num_envs = num_envs
        self.routes = [routes] * num_envs if isinstance(routes, Route) else list(routes)
        self.dt = float(dt)
        self.weights = reward_weights or RewardWeights()
        self.max_episode_steps = int(max_episode_steps)
        self.single_observation_space = observation_space()
        self.single_action_space = action_space()
        self.observation_space = observation_space((num_envs, 8))
        self.action_space = action_space((num_envs, 2))
        self.render_mode = None
        self._trial: Trial | None = None

    def reset(
        self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        if isinstance(seed, list):
            seed = seed[0] if seed else None
        super().reset(seed=seed)
        self._trial = Trial(
            self.robots,
            self.floor,
            self.routes,
            calibration=self.calibration,
            dt=self.dt,
            rng=self.np_random,
        )
        self._steps = np.zeros(self.num_envs, dtype=np.int64)
        self._fraction = np.zeros(self.num_envs)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        obs = self._trial.observation()
        return obs, self._info(self._trial, np.zeros(self.num_envs, dtype=bool))

    def step(
        self, actions: NDArray[np.float32]
    ) -> tuple[
        NDArray[np.float32], FloatArray, NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]
    ]:
        trial = self._trial
        if trial is None:
            raise RuntimeError("call reset() before step()")
        array = np.asarray(actions, dtype=np.float64)
        if array.shape != (self.num_envs, 2):
            raise ValueError(f"actions must have shape ({self.num_envs}, 2), got {array.shape}")
        if not np.isfinite(array).all():
            raise ValueError("actions must be finite")
        array = np.clip(array, -1.0, 1.0)
        resetting = self._autoreset
        if resetting.any():
            array[resetting] = 0.0
        trial.step(array)
        if resetting.any():
            idx = np.flatnonzero(resetting)
            trial.reset(indices=idx)
            self._steps[idx] = 0
            self._fraction[idx] = 0.0
        self._steps[~resetting] += 1  # the reset step is not a step of the new episode
        obs = trial.observation()
        fraction = trial.progress.state[:, 7]
        terminated = trial.done & ~resetting
        truncated = (self._steps >= self.max_episode_steps) & ~terminated & ~resetting
        terms = {
            "progress": self.weights.progress * (fraction - self._fraction),
            "time": np.full(self.num_envs, -self.weights.time),
            "completion": self.weights.completion * terminated.astype(float),
        }
        for values in terms.values():
            values[resetting] = 0.0
        rewards = terms["progress"] + terms["time"] + terms["completion"]
        self._fraction = fraction.copy()
        self._autoreset = terminated | truncated
        info = self._info(trial, terminated)
        info["reward_terms"] = terms
        return obs, rewards, terminated, truncated, info

    def _info(self, trial: Trial, terminated: NDArray[np.bool_]) -> dict[str, Any]:
        error = trial.pose_error()
        info: dict[str, Any] = {
            "odom_pose": trial.odom_pose.copy(),
            "true_pose": trial.true_pose.copy(),
            "pose_error": error,
            "encoder_counts": trial.world.counts.copy(),
            "segment": trial.progress.index.copy(),
            "time": np.full(self.num_envs, trial.world.time),
        }
        if terminated.any():
            info["return_error"] = np.where(terminated[:, None], error, np.nan)
            info["_return_error"] = terminated.copy()
        return info


def make_square_vector_env(
    num_envs: int = 1,
    *,
    side: float = 4.0,
    direction: Literal["cw", "ccw"] = "cw",
    **kwargs: Any,
) -> OdometryVectorEnv:
    """Vector entry point of ``UMBmarkSquare-v0`` (``gymnasium.make_vec``)."""
    kwargs.pop("render_mode", None)
    return OdometryVectorEnv(num_envs, square_route(side, direction), **kwargs)


def make_straight_vector_env(
    num_envs: int = 1,
    *,
    distance: float = 10.0,
    return_trip: bool = False,
    **kwargs: Any,
) -> OdometryVectorEnv:
    """Vector entry point of ``StraightLine-v0`` (``gymnasium.make_vec``)."""
    kwargs.pop("render_mode", None)
    return OdometryVectorEnv(num_envs, straight_route(distance, return_trip), **kwargs)

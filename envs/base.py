"""The thin shared base of odomgym's route-following envs.

An env assembles a :class:`odomgym.trial.Trial` (physics + odometry + route) and defines only
what makes it a task: which route, the observation and action spaces, the reward and the end of
an episode. Everything physical lives in the core (``odomgym.physics``); everything the robot
believes lives in ``odomgym.odometry``.

Reward (all episodes, per step; each term is reported in ``info["reward_terms"]``):

===============  =======================================================================
term             value
===============  =======================================================================
``progress``     ``progress_weight`` × share of the route completed this step, by odometry
``time``         −``time_weight`` per step
``completion``   +``completion_weight`` on the step the odometry says the route is done
===============  =======================================================================

The robot can only know where it is through its odometry, so progress is measured by odometry;
the truth is reported in ``info`` for evaluation, never rewarded.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from os import PathLike
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.floor import FloorSpec, load_floor
from odomgym.odometry import Calibration, load_calibration
from odomgym.paths import Route
from odomgym.robot import RobotSpec, load_robot
from odomgym.trial import OBSERVATION_NAMES, Trial

__all__ = [
    "FixedRoute",
    "RewardWeights",
    "RouteEnv",
    "RouteEpisodes",
    "action_space",
    "observation_space",
    "validate_actions",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class RewardWeights:
    """Weights of the reward terms (see the module docstring)."""

    progress: float = 1.0
    time: float = 0.001
    completion: float = 1.0


def observation_space(shape: tuple[int, ...] = (len(OBSERVATION_NAMES),)) -> gym.spaces.Box:
    """Observation space of the layout in :mod:`odomgym.trial` (per-entry bounds)."""
    # Finite bounds (RL libraries normalise with them): routes are far shorter than 1 km, and a
    # wheel cannot turn at ten times its speed limit.
    per_row_low = np.array([-1e3, -1e3, -np.pi, -10.0, -10.0, 0.0, -1.0, 0.0], np.float32)
    per_row_high = np.array([1e3, 1e3, np.pi, 10.0, 10.0, 1.0, 1.0, 1.0], np.float32)
    low = np.broadcast_to(per_row_low, shape).copy()
    high = np.broadcast_to(per_row_high, shape).copy()
    return gym.spaces.Box(low, high, dtype=np.float32)


def action_space(shape: tuple[int, ...] = (2,)) -> gym.spaces.Box:
    """Wheel speed commands [left, right] as fractions of the robot's ``max_wheel_speed``."""
    return gym.spaces.Box(-1.0, 1.0, shape=shape, dtype=np.float32)


def validate_actions(action: Any, shape: tuple[int, ...]) -> FloatArray:
    """Check and clip actions: NaN/inf or a wrong shape raise ValueError; values outside
    [−1, 1] are clipped (the documented rule: a motor controller saturates).

    Returns a new float64 array (never the caller's array, which is left untouched).
    """
    try:
        array = np.array(action, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"action must be numbers of shape {shape}, got {type(action).__name__}"
        ) from None
    if array.shape != shape:
        raise ValueError(f"action must have shape {shape}, got {array.shape}")
    if not _clip_unit(array.reshape(-1)):
        raise ValueError(f"action must be finite, got {array.tolist()}")
    return array


@kernel
def _clip_unit(values: FloatArray) -> bool:
    """Clip to [−1, 1] in place; False (values untouched) if any is NaN or infinite."""
    for k in range(values.shape[0]):
        if not math.isfinite(values[k]):
            return False
    for k in range(values.shape[0]):
        values[k] = min(max(values[k], -1.0), 1.0)
    return True


def resolve_specs(
    robot: RobotSpec | str | PathLike[str],
    floor: FloorSpec | str | PathLike[str],
    calibration: Calibration | str | PathLike[str] | None,
) -> tuple[RobotSpec, FloorSpec, Calibration]:
    """Accept specs or their names/paths (presets, ``.toml`` files as ``str`` or
    :class:`pathlib.Path`)."""
    robot_spec = robot if isinstance(robot, RobotSpec) else load_robot(os.fspath(robot))
    floor_spec = floor if isinstance(floor, FloorSpec) else load_floor(os.fspath(floor))
    if calibration is None:
        cal = Calibration()
    elif isinstance(calibration, Calibration):
        cal = calibration
    else:
        cal = load_calibration(os.fspath(calibration))
    return robot_spec, floor_spec, cal


@dataclass(frozen=True)
class FixedRoute:
    """The same route every episode, whatever the ``reset`` options."""

    route: Route

    def __call__(self, options: dict[str, Any]) -> Route:
        del options
        return self.route


class RouteEpisodes:
    """Reward, termination and ``info`` of route-following for every robot of a
    :class:`~odomgym.trial.Trial`: the one place the single envs and the native vector env
    compute them (arrays with a leading robot axis; a single env takes row 0).

    Args:
        weights: the reward weights (module docstring).
        n: number of robots.
    """

    def __init__(self, weights: RewardWeights, n: int) -> None:
        self.weights = weights
        self._fraction = np.zeros(n)
        self._start_time = np.zeros(n)

    def begin(self, trial: Trial, indices: NDArray[np.intp] | None = None) -> None:
        """Start new episodes for ``indices`` (default: every robot)."""
        chosen = slice(None) if indices is None else indices
        self._fraction[chosen] = 0.0
        self._start_time[chosen] = trial.world.time

    def advance(self, trial: Trial) -> tuple[FloatArray, NDArray[np.bool_], dict[str, FloatArray]]:
        """After a step: rewards (N,), terminated (N,) and the reward terms (each (N,)), all
        fresh arrays the caller may keep or change."""
        n = self._fraction.shape[0]
        terms = np.empty((3, n))
        rewards = np.empty(n)
        terminated = np.empty(n, dtype=np.bool_)
        weights = self.weights
        progress = trial.progress
        _advance_episodes(
            progress.state,
            progress.index,
            progress.segment_counts,
            weights.progress,
            weights.time,
            weights.completion,
            self._fraction,
            terms,
            rewards,
            terminated,
        )
        return rewards, terminated, {"progress": terms[0], "time": terms[1], "completion": terms[2]}

    def info(self, trial: Trial) -> dict[str, Any]:
        """The per-step ``info`` entries (each a fresh array with a leading robot axis): poses,
        their error, encoder counts, route segment and the time since each robot's episode
        began [s]."""
        poses, counts, segment, elapsed = trial.snapshot(self._start_time)
        return {
            "odom_pose": poses[:, 0:3],
            "true_pose": poses[:, 3:6],
            "pose_error": poses[:, 6:9],
            "encoder_counts": counts,
            "segment": segment,
            "time": elapsed,
        }


@kernel
def _advance_episodes(
    state: FloatArray,
    index: NDArray[np.intp],
    count: NDArray[np.intp],
    w_progress: float,
    w_time: float,
    w_completion: float,
    fraction: FloatArray,
    terms: FloatArray,
    rewards: FloatArray,
    terminated: NDArray[np.bool_],
) -> None:
    """Reward terms (3, N) = progress, time, completion (module docstring), their sum, and
    which robots finished their route; ``fraction`` (the route share at the last step) moves
    on in place."""
    for i in range(state.shape[0]):
        done = index[i] >= count[i]
        now = state[i, 7]
        terms[0, i] = w_progress * (now - fraction[i])
        terms[1, i] = -w_time
        terms[2, i] = w_completion * (1.0 if done else 0.0)
        rewards[i] = terms[0, i] + terms[1, i] + terms[2, i]
        terminated[i] = done
        fraction[i] = now


class RouteEnv(gym.Env[NDArray[Any], NDArray[Any]]):
    """Base of the single-robot envs: a robot follows a route by its own odometry.

    Subclasses implement :meth:`_route` (which route an episode drives). See
    :class:`odomgym.envs.umbmark.UMBmarkSquareEnv` for the full documentation of spaces,
    reward, ``info`` and episode end.
    """

    # Gymnasium declares ``metadata`` an instance attribute; every env overrides it this way.
    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 20}  # noqa: RUF012

    def __init__(
        self,
        robot: RobotSpec | str | PathLike[str] = "labmate",
        floor: FloorSpec | str | PathLike[str] = "smooth",
        calibration: Calibration | str | PathLike[str] | None = None,
        *,
        dt: float = 0.05,
        reward_weights: RewardWeights | None = None,
        render_mode: str | None = None,
        covariance_k: tuple[float, float] | None = None,
    ) -> None:
        self.robot, self.floor, self.calibration = resolve_specs(robot, floor, calibration)
        if covariance_k is not None:
            kl, kr = (float(k) for k in covariance_k)
            if not (math.isfinite(kl) and math.isfinite(kr) and kl >= 0 and kr >= 0):
                raise ValueError(
                    f"covariance_k must be two finite k >= 0 [m^0.5], got {covariance_k!r}"
                )
            covariance_k = (kl, kr)
        self.covariance_k = covariance_k
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        self.dt = float(dt)
        # Frames are one control period apart: played back at 1/dt they run in real time.
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / self.dt}
        self.render_mode = render_mode
        self.weights = reward_weights or RewardWeights()
        self._episodes = RouteEpisodes(self.weights, 1)
        self.observation_space = observation_space()
        self.action_space = action_space()
        self._trial: Trial | None = None
        self._terminated = False
        self._renderer: Any = None
        self._history: list[tuple[float, float, float, float, float, float]] = []

    # ------------------------------------------------------------------ to implement
    def _route(self, options: dict[str, Any]) -> Route:
        raise NotImplementedError

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        super().reset(seed=seed)
        route = self._route(dict(options or {}))
        # A fresh World each episode: the same seed then gives the same trajectory whatever
        # ran before (Chipmunk keeps solver warm-start state inside its joints).
        self._trial = Trial(
            self.robot,
            self.floor,
            route,
            calibration=self.calibration,
            dt=self.dt,
            rng=self.np_random,
        )
        self.route = route
        self._episodes.begin(self._trial)
        self._terminated = False
        self._covariance = np.zeros((3, 3))
        self._history = [(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)]
        if self.render_mode == "human":
            self.render()
        return self._trial.observation()[0], self._info(self._trial, {}, False)

    def step(
        self, action: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        trial = self._require_trial()
        if self._terminated:
            raise RuntimeError("the episode has terminated; call reset() first")
        previous_pose = trial.odom_pose[0].copy() if self.covariance_k is not None else None
        trial.step(validate_actions(action, (2,)).reshape(1, 2))
        if previous_pose is not None:
            self._propagate_covariance(trial, previous_pose)
        obs = trial.observation()[0]
        rewards, done, terms = self._episodes.advance(trial)
        terminated = bool(done[0])
        self._terminated = terminated
        reward_terms = {
            "progress": float(terms["progress"][0]),
            "time": float(terms["time"][0]),
            "completion": float(terms["completion"][0]),
        }
        if self.render_mode is not None:
            t, o = trial.true_pose[0], trial.odom_pose[0]
            self._history.append((t[0], t[1], t[2], o[0], o[1], o[2]))
            if self.render_mode == "human":
                self.render()
        info = self._info(trial, reward_terms, terminated)
        return obs, float(rewards[0]), terminated, False, info

    def _propagate_covariance(self, trial: Trial, previous_pose: FloatArray) -> None:
        """Chong & Kleeman 1997, Eq. 23: carry the odometry covariance through this step's
        wheel travels as one constant-curvature segment."""
        from odomgym.covariance import PoseEstimate, propagate_segment

        assert self.covariance_k is not None
        travel = trial.odometry.wheel_speed[0] * trial.dt
        wheelbase = self.calibration.wheelbase_scale * self.robot.wheelbase
        estimate = propagate_segment(
            PoseEstimate(previous_pose, self._covariance),
            float(travel[0]),
            float(travel[1]),
            wheelbase,
            *self.covariance_k,
        )
        self._covariance = estimate.cov

    def _info(self, trial: Trial, terms: dict[str, float], terminated: bool) -> dict[str, Any]:
        entries = self._episodes.info(trial)
        info: dict[str, Any] = {
            "odom_pose": entries["odom_pose"][0],
            "true_pose": entries["true_pose"][0],
            "pose_error": entries["pose_error"][0],
            "encoder_counts": entries["encoder_counts"][0],
            "segment": int(entries["segment"][0]),
            "time": float(entries["time"][0]),
            "reward_terms": terms,
        }
        if self.covariance_k is not None:
            info["odom_covariance"] = self._covariance.copy()
        if terminated:
            # The robot started at the origin heading +x, so the world frame is the UMBmark
            # start frame: ε = true − odometry (Borenstein & Feng 1994, §6.1).
            info["return_error"] = info["pose_error"].copy()
        return info

    def _require_trial(self) -> Trial:
        if self._trial is None:
            raise RuntimeError("call reset() before step()")
        return self._trial

    # ------------------------------------------------------------------ rendering
    def render(self) -> NDArray[np.uint8] | None:
        """Top-down view: floor bumps, the route, the true path (blue), the odometry path
        (orange), the robot at its true pose and a ghost at its odometry pose, with a legend
        and a scale bar."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode to make()")
            return None
        from odomgym.envs.render import TopDownRenderer

        if self._renderer is None:
            self._renderer = TopDownRenderer(
                self.robot, self.floor, self.render_mode, self.metadata["render_fps"]
            )
        return self._renderer.draw(self.route, self._history)  # type: ignore[no-any-return]

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_renderer"] = None  # pygame surfaces do not pickle; re-created on demand
        return state

"""The thin shared base of odomgym's route-following envs.

An env assembles a :class:`odomgym.sim.trial.Trial` (physics + odometry + route) and defines only
what makes it a task: which route, the observation and action spaces, the reward and the end of
an episode. Everything physical lives in the core (``odomgym.sim.world``); everything the robot
believes lives in ``odomgym.odometry.calibration``.

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

import dataclasses
import decimal
import functools
import math
import numbers
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from os import PathLike
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym._kernels import REPORT_COLUMNS, REPORT_WIDTH, episode_report
from odomgym.envs.info import LazyInfo
from odomgym.errors import SpecError, plain_number, require_finite
from odomgym.floor import FloorSpec, load_floor
from odomgym.odometry.calibration import Calibration, load_calibration
from odomgym.odometry.runs import require_differential
from odomgym.robot import RobotSpec, load_robot
from odomgym.sim.routes import Route
from odomgym.sim.trial import OBSERVATION_NAMES, Trial

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
    """Observation space of the layout in :mod:`odomgym.sim.trial` (per-entry bounds)."""
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


def describe_action(action: Any) -> str:
    """``action`` in one short line, for error messages (an array's repr spans lines)."""
    text = " ".join(repr(action).split())
    return text if len(text) <= 80 else f"{text[:77]}..."


_REAL = (numbers.Real, np.bool_, decimal.Decimal)


def real_array(action: Any, expected: str) -> FloatArray:
    """``action`` as a new C-ordered float64 array if it holds real numbers only (booleans,
    integers, floats); text, None, complex numbers, other objects and integers too large for a
    float raise a one-line ValueError ("action must be ``expected``, got …")."""
    try:
        raw = np.asarray(action)
        kind = raw.dtype.kind
        if kind not in "biufO" or (kind == "O" and not all(isinstance(v, _REAL) for v in raw.flat)):
            raise TypeError(kind)
        return raw.astype(np.float64, order="C")
    except (TypeError, ValueError):
        raise ValueError(f"action must be {expected}, got {describe_action(action)}") from None
    except OverflowError:
        raise ValueError(f"action must be finite, got {describe_action(action)}") from None


def validate_actions(action: Any, shape: tuple[int, ...]) -> FloatArray:
    """Check and clip actions: NaN/inf, anything but real numbers or a wrong shape raise
    ValueError; values outside [−1, 1] are clipped (the documented rule: a motor controller
    saturates).

    Returns a new float64 array (never the caller's array, which is left untouched).
    """
    array = real_array(action, _numbers_of_shape(shape))
    if array.shape != shape:
        raise ValueError(f"action must have shape {shape}, got {array.shape}")
    if not _clip_unit(array):
        raise ValueError(f"action must be finite, got {array.tolist()}")
    return array


@functools.cache
def _numbers_of_shape(shape: tuple[int, ...]) -> str:
    """What an action must be, for error messages (made once per shape: formatting it costs
    about a third of a valid action's check)."""
    return f"numbers of shape {shape}"


@kernel
def _clip_unit(values: FloatArray) -> bool:
    """Clip a C-contiguous array of any shape to [−1, 1] in place; False (values untouched) if
    any is NaN or infinite."""
    flat = values.reshape(values.size)  # a view, here in compiled code (~0.2 µs in Python)
    for k in range(flat.shape[0]):
        if not math.isfinite(flat[k]):
            return False
    for k in range(flat.shape[0]):
        flat[k] = min(max(flat[k], -1.0), 1.0)
    return True


MAX_DT = 1.0
"""The longest control period an env takes [s]. The reference driver and a policy steer once a
period; at 10 s a 1 m straight was overshot to 2 m in three steps and called done."""


def _plain_real(value: object) -> float | None:
    """``value`` as a float when it is a real number (a NumPy scalar included, a bool not),
    else None: the number test :func:`control_period` and :func:`route_size` share."""
    number = plain_number(value)
    if isinstance(number, bool) or not isinstance(number, int | float):
        return None
    return float(number)


def control_period(dt: object) -> float:
    """``dt`` [s] as a float in (0, :data:`MAX_DT`], else a one-line error naming it (a string
    had ended in numpy's ``isfinite`` TypeError)."""
    number = _plain_real(dt)
    if number is None or not 0.0 < number <= MAX_DT:
        raise SpecError(
            f"dt must be a number of seconds in (0, {MAX_DT:g}] (the control period; default "
            f"0.05), got {dt!r}",
            field="dt",
        )
    return number


def route_size(name: str, value: object) -> float:
    """A route's ``side``/``distance`` [m] as a float, refusing a non-number in one line (a
    string such as ``"4"`` was taken by ``float``, where the robot's own fields refuse one);
    its range is the route's to check."""
    number = _plain_real(value)
    if number is None:
        raise SpecError(f"{name} must be a number of metres, got {value!r}", field=name)
    return number


def reset_options(options: Any) -> dict[str, Any]:
    """``reset``'s ``options`` as a dict (None: empty); anything but a mapping is refused in
    one line, where a list had ended in ``ValueError: dictionary update sequence``."""
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise SpecError(
            f"reset options must be a dict, got {type(options).__name__}", field="options"
        )
    return dict(options)


def resolve_specs(
    robot: RobotSpec | str | PathLike[str],
    floor: FloorSpec | str | PathLike[str],
    calibration: Calibration | str | PathLike[str] | None,
) -> tuple[RobotSpec, FloorSpec, Calibration]:
    """Accept specs or their names/paths (presets, ``.toml`` files as ``str`` or
    :class:`pathlib.Path`)."""
    robot_spec = load_robot(_named(robot))  # a spec passes; a non-name is refused, named
    floor_spec = load_floor(_named(floor))
    if calibration is None:
        cal = Calibration()
    elif isinstance(calibration, Calibration):
        cal = calibration
    elif isinstance(calibration, str | os.PathLike):
        cal = load_calibration(os.fspath(calibration))
    else:
        raise SpecError(
            "calibration must be a Calibration, a .toml file or None, got "
            f"{type(calibration).__name__}",
            field="calibration",
        )
    return robot_spec, floor_spec, cal


def _named(spec: Any) -> Any:
    """``spec`` with an ``os.PathLike`` made its path string (the loaders take names, paths and
    specs, and refuse anything else in one line)."""
    return os.fspath(spec) if isinstance(spec, os.PathLike) else spec


def resolve_weights(weights: Any) -> RewardWeights:
    """The reward weights from a :class:`RewardWeights`, a mapping of some of its fields, or
    None (the defaults); anything else is refused, naming the field. A dict had ended in
    ``AttributeError: 'dict' object has no attribute 'progress'`` at the first step."""
    if weights is None:
        return RewardWeights()
    if isinstance(weights, RewardWeights):
        return weights
    if isinstance(weights, Mapping):
        known = [f.name for f in dataclasses.fields(RewardWeights)]
        for key, value in weights.items():
            if key not in known:
                raise SpecError(
                    f"unknown reward weight {key!r}; weights: {', '.join(known)}",
                    field=f"reward_weights.{key}",
                )
            require_finite(f"reward_weights.{key}", value)
        return RewardWeights(**{k: float(v) for k, v in weights.items()})
    raise SpecError(
        f"reward_weights must be a RewardWeights or a dict of its fields, got "
        f"{type(weights).__name__}",
        field="reward_weights",
    )


@dataclass(frozen=True)
class FixedRoute:
    """The same route every episode, whatever the ``reset`` options."""

    route: Route

    def __call__(self, options: dict[str, Any]) -> Route:
        del options
        return self.route


class RouteEpisodes:
    """Reward, termination and ``info`` of route-following for every robot of a
    :class:`~odomgym.sim.trial.Trial`: the one place the single envs and the native vector env
    compute them (arrays with a leading robot axis; a single env takes row 0).

    Args:
        weights: the reward weights (module docstring).
        n: number of robots.
    """

    def __init__(self, weights: RewardWeights, n: int) -> None:
        self.weights = weights
        self._weights = np.array([weights.progress, weights.time, weights.completion])
        # Per robot: the episode's start time [s] and the route share at the last reward.
        self._episodes = np.zeros((n, 2))

    def begin(self, trial: Trial, indices: NDArray[np.intp] | None = None) -> None:
        """Start new episodes for ``indices`` (default: every robot)."""
        chosen = slice(None) if indices is None else indices
        self._episodes[chosen] = (trial.world.time, 0.0)

    def step(self, trial: Trial, actions: FloatArray) -> FloatArray:
        """Step ``trial`` with ``actions`` (N, 2) and return this step's report rows (the columns
        of :meth:`report`, with this step's reward), made in the compiled call that follows the
        physics (:meth:`odomgym.sim.trial.Trial.step`)."""
        out = np.empty((trial.n, REPORT_WIDTH))
        trial.step(actions, report=(self._episodes, self._weights, out))
        return out

    def report(self, trial: Trial) -> FloatArray:
        """After a reset: one fresh row per robot with the reward and its terms (zero), whether
        the route is done and every ``info`` entry, in the columns of
        :data:`odomgym._kernels.REPORT_COLUMNS` (:func:`odomgym._kernels.episode_report`; a
        step's rewarded rows come from :meth:`step`)."""
        out = np.empty((trial.n, REPORT_WIDTH))
        world, progress = trial.world, trial.progress
        episode_report(
            world.pose,
            trial.start_poses,
            trial.odom_pose,
            world.counts,
            progress.index,
            progress.segment_counts,
            progress.state,
            world.time,
            self._episodes,
            self._weights,
            False,
            out,
        )
        return out

    @staticmethod
    def terms(report: FloatArray) -> dict[str, FloatArray]:
        """The reward terms of a :meth:`report` (each (N,), views of it)."""
        return {name: report[:, _COLUMN[name]] for name in _TERMS}

    @staticmethod
    def info(report: FloatArray) -> dict[str, Any]:
        """The ``info`` entries of a :meth:`report` (N, W), each with a leading robot axis, or
        of one row of it (W,), with the segment and time as Python numbers: poses, their error,
        encoder counts, route segment and the time since the robot's episode began [s]."""
        if report.ndim == 1:
            segment: Any = int(report[_COLUMN["segment"]])
            elapsed: Any = float(report[_COLUMN["episode_time"]])
        else:
            segment = report[:, _COLUMN["segment"]].astype(np.int64)
            elapsed = report[:, _COLUMN["episode_time"]]
        return {
            "odom_pose": report[..., _SLICE["odom_pose"]],
            "true_pose": report[..., _SLICE["true_pose"]],
            "pose_error": report[..., _SLICE["pose_error"]],
            "encoder_counts": report[..., _SLICE["encoder_counts"]].astype(np.int64),
            "segment": segment,
            "time": elapsed,
        }


_SLICE = {name: slice(first, stop) for name, (first, stop) in REPORT_COLUMNS.items()}
_COLUMN = {name: first for name, (first, _) in REPORT_COLUMNS.items()}
_TERMS = ("progress", "time", "completion")
_REWARD, _TERMINATED = _COLUMN["reward"], _COLUMN["terminated"]
_PROGRESS, _TIME, _COMPLETION = (_COLUMN[name] for name in _TERMS)


def _step_info(
    row: FloatArray, values: list[float], terminated: bool, covariance: FloatArray | None
) -> dict[str, Any]:
    """``info`` of a single env's step from its report row (``values`` = ``row.tolist()``) and
    the odometry covariance, if propagated."""
    info = RouteEpisodes.info(row)
    info["reward_terms"] = {
        "progress": values[_PROGRESS],
        "time": values[_TIME],
        "completion": values[_COMPLETION],
    }
    if covariance is not None:
        info["odom_covariance"] = covariance
    if terminated:
        # The robot started at the origin heading +x, so the world frame is the UMBmark
        # start frame: ε = true − odometry (Borenstein & Feng 1994, §6.1).
        info["return_error"] = info["pose_error"].copy()
    return info


class DrawsLazily:
    """``close()`` and pickling for an env whose renderer (``_renderer``) is created on the first
    ``render()`` call: rendering costs nothing until asked for, pygame surfaces do not pickle
    (a copy re-creates its renderer on demand), and closing releases the window."""

    _renderer: Any
    render_mode: str | None
    metadata: dict[str, Any]

    def _set_render_mode(self, render_mode: str | None) -> None:
        """Check ``render_mode`` against ``metadata["render_modes"]`` (a :class:`SpecError`
        naming it) and keep it; no renderer exists until the first ``render()``."""
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise SpecError(
                f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}",
                field="render_mode",
            )
        self.render_mode = render_mode
        self._renderer = None

    def _render_mode_or_warn(self) -> str | None:
        """The render mode; None, with Gymnasium's warning, when ``render()`` is called without
        one."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode to make()")
        return self.render_mode

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_renderer"] = None
        return state


class RouteEnv(DrawsLazily, gym.Env[NDArray[Any], NDArray[Any]]):
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
            if isinstance(covariance_k, str) or not (
                isinstance(covariance_k, Sequence | np.ndarray) and len(covariance_k) == 2
            ):
                raise ValueError(
                    f"covariance_k must be two k (k_L, k_R) >= 0 [m^0.5], got {covariance_k!r}"
                )
            kl, kr = (float(k) for k in covariance_k)
            if not (math.isfinite(kl) and math.isfinite(kr) and kl >= 0 and kr >= 0):
                raise ValueError(
                    f"covariance_k must be two finite k >= 0 [m^0.5], got {covariance_k!r}"
                )
            covariance_k = (kl, kr)
            require_differential(self.calibration, "covariance_k (Chong & Kleeman's covariance)")
        self.covariance_k = covariance_k
        self._set_render_mode(render_mode)
        self.dt = control_period(dt)
        # Frames are one control period apart: played back at 1/dt they run in real time.
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / self.dt}
        self.weights = resolve_weights(reward_weights)
        self._episodes = RouteEpisodes(self.weights, 1)
        self.observation_space = observation_space()
        self.action_space = action_space()
        self._trial: Trial | None = None
        self._terminated = False
        self._history: list[tuple[float, float, float, float, float, float]] = []

    # ------------------------------------------------------------------ to implement
    def _route(self, options: dict[str, Any]) -> Route:
        raise NotImplementedError

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        super().reset(seed=seed)
        route = self._route(reset_options(options))
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
        report = self._episodes.report(self._trial)
        return self._trial.observation()[0], self._reset_info(report[0])

    def step(
        self, action: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        trial = self._trial
        if trial is None:
            raise RuntimeError("call reset() before step()")
        if self._terminated:
            raise RuntimeError("the episode has terminated; call reset() first")
        previous_pose = trial.odom_pose[0].copy() if self.covariance_k is not None else None
        row = self._episodes.step(trial, validate_actions(action, (2,))[None])[0]
        covariance = None
        if previous_pose is not None:
            self._propagate_covariance(trial, previous_pose)
            covariance = self._covariance.copy()
        obs = trial.observation()[0]
        values = row.tolist()  # Python floats: cheaper than indexing numpy scalars one by one
        terminated = values[_TERMINATED] > 0.0
        self._terminated = terminated
        if self.render_mode is not None:
            t, o = trial.true_pose[0], trial.odom_pose[0]
            self._history.append((t[0], t[1], t[2], o[0], o[1], o[2]))
            if self.render_mode == "human":
                self.render()
        # Made when first read (envs/info.py); everything it uses is fixed now.
        info = LazyInfo(functools.partial(_step_info, row, values, terminated, covariance))
        return obs, values[_REWARD], terminated, False, info

    def _propagate_covariance(self, trial: Trial, previous_pose: FloatArray) -> None:
        """Chong & Kleeman 1997, Eq. 23: carry the odometry covariance through this step's
        wheel travels as one constant-curvature segment."""
        from odomgym.noise.covariance import PoseEstimate, propagate_segment

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

    def _reset_info(self, row: FloatArray) -> dict[str, Any]:
        """``info`` of a reset from its row of :meth:`RouteEpisodes.report` (no reward terms)."""
        covariance = self._covariance.copy() if self.covariance_k is not None else None
        info = RouteEpisodes.info(row)
        info["reward_terms"] = {}
        if covariance is not None:
            info["odom_covariance"] = covariance
        return info

    # ------------------------------------------------------------------ rendering
    def render(self) -> NDArray[np.uint8] | None:
        """Top-down view: floor bumps, the route, the true path (blue), the odometry path
        (orange), the robot at its true pose and a ghost at its odometry pose, with a legend
        and a scale bar."""
        mode = self._render_mode_or_warn()
        if mode is None:
            return None
        from odomgym.envs.render import TopDownRenderer

        if self._renderer is None:
            self._renderer = TopDownRenderer(
                self.robot, self.floor, mode, self.metadata["render_fps"]
            )
        return self._renderer.draw(self.route, self._history)  # type: ignore[no-any-return]

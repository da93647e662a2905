"""A native vector env: many robots in one World, stepped together.

``gymnasium.make_vec("UMBmarkSquare-v0", num_envs=256, vectorization_mode="vector_entry_point")``
returns an :class:`OdometryVectorEnv` whose sub-envs are the robots of one
:class:`odomgym.sim.trial.Trial`: one pymunk space, ``pymunk.batch`` state I/O and compiled
per-robot kernels, instead of 256 Python env objects. Spaces, reward, termination and ``info``
are computed by the same code as the single envs' (:class:`odomgym.envs.base.RouteEpisodes`),
and ``info`` has the layout :class:`gymnasium.vector.SyncVectorEnv` gives: every entry an array
with a leading sub-env axis and a boolean mask ``_key`` beside it (``reward_terms`` a dict of
such arrays; ``return_error`` only where an episode ended). A step's ``info`` is made at its
first read, as the single envs' (:class:`odomgym.envs.info.LazyInfo`). ``odom_covariance`` is not
offered here (the closed-form propagation is per robot and would cost more than the physics).

Seeding follows Gymnasium's ``VectorEnv.reset``: ``seed=s`` gives sub-env k the seed s + k, a
list gives each sub-env its own, and sub-env k then draws exactly what a single env reset with
its seed draws. ``options`` (e.g. ``{"direction": "ccw"}``) reach every sub-env, and
``options["reset_mask"]`` resets only some. Autoreset follows Gymnasium's ``NEXT_STEP`` mode:
the step after a sub-env ends resets it (from its own random stream) and ignores its action.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from os import PathLike
from typing import Any, Literal

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from numpy.typing import NDArray

from odomgym._kernels import REPORT_COLUMNS
from odomgym.envs.base import (
    FixedRoute,
    RewardWeights,
    RouteEpisodes,
    action_space,
    control_period,
    observation_space,
    reset_options,
    resolve_specs,
    resolve_weights,
    validate_actions,
)
from odomgym.envs.info import LazyInfo
from odomgym.envs.straight import StraightRoute
from odomgym.envs.umbmark import SquareRoute
from odomgym.errors import SpecError
from odomgym.floor import FloorSpec
from odomgym.odometry.calibration import Calibration
from odomgym.robot import RobotSpec
from odomgym.sim.routes import Route
from odomgym.sim.trial import Trial

_REWARD = REPORT_COLUMNS["reward"][0]  # columns of the episode report
_TERMINATED = REPORT_COLUMNS["terminated"][0]

__all__ = ["OdometryVectorEnv", "make_square_vector_env", "make_straight_vector_env"]

FloatArray = NDArray[np.float64]
RouteFactory = Callable[[dict[str, Any]], Route]


class OdometryVectorEnv(VectorEnv[NDArray[np.float32], NDArray[np.float32], NDArray[Any]]):
    """``num_envs`` robots following routes by odometry, as one vector env.

    Args:
        num_envs: number of robots.
        route: the route of an episode from the ``reset`` options (the single env's rule), or
            one fixed :class:`~odomgym.sim.routes.Route` for all.
        robot: one spec for all, or a sequence of ``num_envs`` specs (a robot population).
        floor, calibration, dt, reward_weights: as the single envs.
        max_episode_steps: truncation limit per sub-env.
    """

    # Gymnasium declares ``metadata`` an instance attribute; every env overrides it this way.
    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}  # noqa: RUF012

    def __init__(
        self,
        num_envs: int,
        route: RouteFactory | Route,
        robot: RobotSpec | str | PathLike[str] | Sequence[RobotSpec] = "labmate",
        floor: FloorSpec | str | PathLike[str] = "smooth",
        calibration: Calibration | str | PathLike[str] | None = None,
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
        if isinstance(robot, (RobotSpec, str, PathLike)):
            spec, self.floor, self.calibration = resolve_specs(robot, floor, calibration)
            self.robots: list[RobotSpec] = [spec] * num_envs
        else:
            self.robots = list(robot)
            if len(self.robots) != num_envs:
                raise ValueError(f"need {num_envs} robot specs, got {len(self.robots)}")
            _, self.floor, self.calibration = resolve_specs(self.robots[0], floor, calibration)
        self.num_envs = num_envs
        self._route: RouteFactory = FixedRoute(route) if isinstance(route, Route) else route
        self.dt = control_period(dt)
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / self.dt}
        self.weights = resolve_weights(reward_weights)
        self.max_episode_steps = int(max_episode_steps)
        self.single_observation_space = observation_space()
        self.single_action_space = action_space()
        self.observation_space = observation_space((num_envs, 8))
        self.action_space = action_space((num_envs, 2))
        self.render_mode = None
        self._trial: Trial | None = None
        self._episodes = RouteEpisodes(self.weights, num_envs)
        self._rngs: list[np.random.Generator] = []
        self._everyone = np.ones(num_envs, dtype=bool)

    def _seeds(self, seed: int | Sequence[int | None] | None) -> list[int | None]:
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, (int, np.integer)):
            return [int(seed) + k for k in range(self.num_envs)]
        seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ValueError(
                f"seed: a list of seeds needs one per sub-env ({self.num_envs}), got {len(seeds)}"
            )
        return seeds

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        options = reset_options(options)
        mask = options.pop("reset_mask", None)
        seeds = self._seeds(seed)
        if mask is None or self._trial is None:
            chosen = np.arange(self.num_envs)
        else:
            mask = np.asarray(mask)
            if mask.shape != (self.num_envs,) or mask.dtype != np.bool_ or not mask.any():
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({self.num_envs},) "
                    "with at least one True"
                )
            chosen = np.flatnonzero(mask)
        if not self._rngs:
            self._rngs = [seeding.np_random(s)[0] for s in seeds]
        else:
            for k in chosen:
                if seeds[k] is not None:
                    self._rngs[k] = seeding.np_random(seeds[k])[0]
        route = self._route(options)
        if self._trial is None or len(chosen) == self.num_envs:
            # A fresh World, as a single env builds one per episode; sub-env k's noise comes
            # from its own generator exactly as a single env's World takes it (one child).
            self._trial = Trial(
                self.robots,
                self.floor,
                route,
                calibration=self.calibration,
                dt=self.dt,
                rng=[rng.spawn(1)[0] for rng in self._rngs],
            )
            self._steps = np.zeros(self.num_envs, dtype=np.int64)
            self._autoreset = np.zeros(self.num_envs, dtype=bool)
            self._episodes.begin(self._trial)
        else:
            self._restart(chosen, [route] * len(chosen))
        present = np.zeros(self.num_envs, dtype=bool)
        present[chosen] = True
        report = self._episodes.report(self._trial)
        return self._trial.observation(), self._vector_info(present, report, None)

    def _restart(self, indices: NDArray[np.intp], routes: Sequence[Route]) -> None:
        """New episodes for sub-envs ``indices``: fresh noise streams from their generators,
        then back at the start of ``routes``."""
        trial = self._trial
        assert trial is not None
        if trial.world.uses_noise:  # (a noiseless World would not take the streams)
            trial.world.rebind_noise(indices, [self._rngs[k].spawn(1)[0] for k in indices])
        trial.reset(indices=indices, routes=routes)
        self._steps[indices] = 0
        self._autoreset[indices] = False
        self._episodes.begin(trial, indices)

    def step(
        self, actions: NDArray[np.float32]
    ) -> tuple[
        NDArray[np.float32], FloatArray, NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]
    ]:
        trial = self._trial
        if trial is None:
            raise RuntimeError("call reset() before step()")
        array = validate_actions(actions, (self.num_envs, 2))
        any_reset = bool(self._autoreset.any())
        if any_reset:
            resetting = self._autoreset.copy()  # _restart clears the flags
            array[resetting] = 0.0
        report = self._episodes.step(trial, array)
        rewards = report[:, _REWARD].copy()
        done = report[:, _TERMINATED] > 0.0
        terms = RouteEpisodes.terms(report)
        if any_reset:
            idx = np.flatnonzero(resetting)
            # As Gymnasium's autoreset: reset() without options, so the default route.
            self._restart(idx, [self._route({})] * len(idx))
            rewards[resetting] = 0.0
            for values in terms.values():
                values[resetting] = 0.0
            running = ~resetting
            self._steps += running  # the reset step is not a step of the new episode
            terminated = done & running
            # The reset sub-envs report their new episode's start.
            report = self._episodes.report(trial)
        else:
            running = self._everyone
            self._steps += 1
            terminated = done
        truncated = (self._steps >= self.max_episode_steps) & ~terminated
        if any_reset:
            truncated &= running
        self._autoreset = terminated | truncated
        # Made at the first read (odomgym.envs.info): a training loop that never reads ``info``
        # does not pay for its fourteen arrays, about a tenth of a step at 256 robots. Its
        # inputs are this step's own arrays (``terminated`` copied: the caller owns it).
        info = LazyInfo(
            functools.partial(self._step_info, report, terms, running, terminated.copy())
        )
        return trial.observation(), rewards, terminated, truncated, info

    def _step_info(
        self,
        report: FloatArray,
        terms: dict[str, FloatArray],
        running: NDArray[np.bool_],
        terminated: NDArray[np.bool_],
    ) -> dict[str, Any]:
        """A step's ``info`` (:meth:`_vector_info` of every sub-env, and ``return_error`` where
        an episode ended)."""
        info = self._vector_info(self._everyone, report, terms, running)
        if terminated.any():
            info["return_error"] = np.where(terminated[:, None], info["pose_error"], 0.0)
            info["_return_error"] = terminated
        return info

    def _vector_info(
        self,
        present: NDArray[np.bool_],
        report: FloatArray,
        terms: dict[str, FloatArray] | None,
        rewarded: NDArray[np.bool_] | None = None,
    ) -> dict[str, Any]:
        """``info`` in :class:`gymnasium.vector.SyncVectorEnv`'s layout from a
        :meth:`RouteEpisodes.report`: ``present`` marks the sub-envs that report (all after a
        step, the reset ones after a reset), ``rewarded`` those with reward terms (not the ones
        autoreset this step: a reset reports none)."""
        info: dict[str, Any] = {}
        entries = RouteEpisodes.info(report)
        # The masks are rows of one block (distinct arrays, as SyncVectorEnv gives): one
        # allocation instead of one per entry.
        masks = np.empty((len(entries) + 1, self.num_envs), dtype=np.bool_)
        masks[:] = present
        everyone = present is self._everyone or bool(present.all())
        for (key, value), mask in zip(entries.items(), masks[:-1], strict=True):
            # The entries are fresh arrays; only a partial reset blanks the absent sub-envs.
            if not everyone:
                value[~present] = 0
            info[key] = value
            info[f"_{key}"] = mask
        reward_terms: dict[str, Any] = {}
        if (
            terms is not None
            and rewarded is not None
            and (rewarded is self._everyone or rewarded.any())
        ):
            term_masks = np.empty((len(terms), self.num_envs), dtype=np.bool_)
            term_masks[:] = rewarded
            for (key, value), mask in zip(terms.items(), term_masks, strict=True):
                reward_terms[key] = value
                reward_terms[f"_{key}"] = mask
        info["reward_terms"] = reward_terms
        info["_reward_terms"] = masks[-1]
        return info


def make_square_vector_env(
    num_envs: int = 1,
    *,
    side: float = 4.0,
    direction: Literal["cw", "ccw"] = "cw",
    **kwargs: Any,
) -> OdometryVectorEnv:
    """Vector entry point of ``UMBmarkSquare-v0`` (``gymnasium.make_vec``)."""
    _no_render(kwargs)
    return OdometryVectorEnv(num_envs, SquareRoute(side, direction), **kwargs)


def make_straight_vector_env(
    num_envs: int = 1,
    *,
    distance: float = 10.0,
    return_trip: bool = False,
    **kwargs: Any,
) -> OdometryVectorEnv:
    """Vector entry point of ``StraightLine-v0`` (``gymnasium.make_vec``)."""
    _no_render(kwargs)
    return OdometryVectorEnv(num_envs, StraightRoute(distance, return_trip), **kwargs)


def _no_render(kwargs: dict[str, Any]) -> None:
    """Take ``render_mode`` out of ``gymnasium.make_vec``'s keywords, refusing any but None in
    one line: the native vector env draws nothing (its ``render_modes`` are empty), and a
    ``render_mode="rgb_array"`` it accepted failed only at the first ``render()``."""
    mode = kwargs.pop("render_mode", None)
    if mode is not None:
        raise SpecError(
            f"render_mode {mode!r}: the native vector env does not render; "
            "gymnasium.make_vec(..., vectorization_mode='sync') makes one that renders each env",
            field="render_mode",
        )

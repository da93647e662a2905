"""``SelfCalibration-v1``: choose the experiments that calibrate a robot, within a budget of runs.

## Description

An episode is one calibration session (:class:`odomgym.selfcal.session.SelfCalSession`) on a
freshly sampled robot: systematic errors drawn over the benchmark's ranges
(:class:`~odomgym.lab.population.Population`: E_d ∈ [0.99, 1.01], E_b ∈ [0.95, 1.05],
E_s ∈ [0.98, 1.02], on the LabMate) and a floor drawn from ``floors`` (the benchmark's
``concrete``, ``rough`` and ``cables``; on ``cables`` every run starts at a random pose on a
field of random cables, so cables are met at random — one fixed field, not the benchmark's own,
so the benchmark evaluates on cables the agent never trained on).

Each run is measured by the lab's ground-truth sensor (every pose sample with its noise,
σ = 2 mm and 0.4°, the accuracy of Borenstein & Feng 1994, §6.3), and the estimator updates the
corrections (iterative compensation): by default (``observe="trajectory"``) a Kalman filter
along the whole measured run (:class:`~odomgym.selfcal.estimators.TrajectoryEstimator`); with
``observe="end_pose"`` a fit to the end poses alone, what a person with a tape measure at the
home position gets (:class:`~odomgym.selfcal.estimators.EndPoseEstimator`).

## Action Space

``Discrete(10)``: an index into :data:`~odomgym.selfcal.menu.ACTION_MENU`. 0 stops the
session; 1–9 drive one run (4 m / 2 m square cw or ccw, 4 m straight one way or out and back,
in-place spins of 360° either way or 720°) with the reference driver and the current
corrections in the odometry.

## Observation Space

``Box(-10, 10, (31,), float32)``, laid out as
:data:`~odomgym.selfcal.session.OBSERVATION_LAYOUT` names it: budget left and size, how often
each item was driven, the estimated E_d, E_b, E_s and their posterior spreads, the
floor-roughness estimate, the last run's normalised innovation and which item it was.
Everything a person at the home position could know — never the truth.

## Rewards

At the end of the session, the final corrections are validated on fresh runs the agent
never sees — a 4×4 m square each way and a 4 m straight run, driven on the noiseless ``smooth``
floor by the true robot with the final corrections and without any (same start, same floor, so
the comparison is exact and free of luck). With E the square family's E_max,syst (Borenstein &
Feng 1994, Eq. 3.3) and the straight run's position error, per family
t_f = clip(ln((E_ref,f + 1 mm) / (E_after,f + 1 mm)), −3, ln 300), and

    r_T = t_square + 0.25·t_straight − 2·(max(0, −t_square) + max(0, −t_straight)),

so corrections that close the squares while wrecking straight runs (or the reverse) lose.
Stopping at once keeps the uncalibrated robot: r_T = 0 exactly. A session whose robot cannot
finish a run (corrections so wrong that it circles) ends with
:data:`~odomgym.selfcal.episodes.FAILED_REWARD`.
Shaping (``shaping`` = c, default 0.1): every step also pays c·(Φ(s′) − Φ(s)) with Φ the
estimator's information gain (½·ln det Σ_prior/Σ_posterior) and Φ = 0 at the end — potential-
based (Ng, Harada & Russell 1999), so it sums to exactly zero over an episode and cannot change
which policy is best; it only credits informative runs early. (With γ = 1, which the shipped
hyperparameters use: for γ < 1 the potential difference would have to be c·(γΦ′ − Φ).)

## Starting State

A robot drawn from ``population``, a floor from ``floors`` and a budget, nothing driven yet:
the estimate is the nominal robot (the prior's centre).

## Episode End

Terminated when the agent stops, or on the step after the budget is spent (any
action then stops; that step validates and carries the terminal reward), or when a run cannot
finish; the registered step limit (66 ≥ budget + 1) never truncates.

## Info

``runs_used``, ``budget``, ``travel_m`` (true path length driven so far [m]),
``floor``, ``item`` (the menu item's name); at the end also ``reward_terms``,
``e_max_before_mm``/``e_max_after_mm`` (validation squares), ``improvement`` (their ratio),
``true_errors``/``estimated_errors`` (E_d, E_b, E_s), ``calibration`` and ``experiments``;
a session whose run could not finish ends with ``failed`` (the reason) instead of the
validation entries.

## Arguments

``floors`` (benchmark floor names to draw each episode's floor from; default all three, ``concrete``
and ``rough`` for a skid-steer robot, which takes ``cables`` when asked), ``budget`` (runs, or a
list to draw from per episode; default 16), ``shaping`` (the coefficient c, default 0.1),
``population`` (:class:`~odomgym.lab.population.Population`, the ranges of the hidden errors and the
robot they apply to: ``Population(base="scout2")`` makes the sessions skid-steer, below), ``sensor``
(:class:`~odomgym.lab.experiment.SensorAccuracy` of each measured pose), ``observe``
(``"trajectory"`` or ``"end_pose"``: what the estimator sees; version 2 of the observation,
:data:`~odomgym.selfcal.session.OBSERVATION_VERSION`), ``render_mode``.
Reset options: ``{"floor": name, "budget": runs}``.

## Rendering

``render_mode="rgb_array"`` (an (H, W, 3) uint8 frame per ``render()``) or
``"human"`` (a pygame window), with the ``[render]`` extra. A frame shows the session so far:
every run in its start frame (the robot starts at the origin heading +x), its true path (blue)
and its odometry path as the robot computed it with the corrections it drove with (orange),
the latest run bold and earlier ones faded, over the nominal shapes of the items driven (grey);
beside it the experiment just chosen, the budget used and left (a bar), the current estimates
of E_d, E_b, E_s next to the true values (hidden from the agent: shown for the viewer), the
runs in order and, at the end, the validated improvement. One frame per step (one run), so
``metadata["render_fps"]`` is 2. With ``render_mode=None`` (the default) no run is kept for
drawing.

## Skid-steer robots

With a skid-steer ``population.base`` (``scout2``, ``husky``, ``pioneer3at``, ``jackal``) each
session starts from the apparent track of rigid contacts in a slow spin, E_b = 1 + (a/b)² from the
nominal geometry (:func:`~odomgym.selfcal.episodes.skid_prior`): the estimator's prior is
centred there and kept within its range of it, the observed E_b is relative to it, and the
validation's "before" is the robot with it, so stopping at once still gives r_T = 0. Its runs
are simulated with the bench floor's roughness as the floor's own (a skid-steer robot carries
no catalogue effect): on ``cables`` over the same cable field the differential-drive sessions
cross, each wheel meeting the cables at its own contact, else on a plain floor. ``cables`` is
not among a skid-steer robot's default floors (the default episodes stay as they were); name
it in ``floors`` or in the reset options. The estimator's
model is still a constant apparent track: it cannot follow a track that moves with the turn
radius (docs/skid-steer.md). The shipped policy was trained on LabMates.

## Version History

* v0: initial version. Rendering (``render_mode``, ``"human"`` and ``"rgb_array"``) was added
  in odomgym 0.2.0 without changing spaces, dynamics, reward or ``info`` (before, any
  ``render_mode`` raised :class:`~odomgym.errors.SpecError`, which stopped
  ``stable_baselines3.PPO("MlpPolicy", "SelfCalibration-v0")``): a compatible addition, so the
  version stays v0.
* v1, compatible addition (issue 43): ``population`` may have a skid-steer base (above);
  differential-drive sessions are unchanged (bit-identical, ``tests/test_selfcal_skid.py``).
  Later, a compatible addition: skid-steer sessions on ``cables`` (refused before), not among
  their default floors.
* v1 (odomgym 0.2.0): the estimator became the trajectory filter
  (:class:`~odomgym.selfcal.estimators.TrajectoryEstimator`, ``observe="trajectory"``,
  observation version 2). Spaces, dynamics and episode end are unchanged, but the
  observation's values and, through the final corrections, the reward differ, so the id
  changed. ``SelfCalibration-v0`` is still registered: it is this class with
  ``observe="end_pose"``, whose observations, rewards and ``info`` are bit-identical to v0's
  before the change (checked on seeds 0–2 with a fixed action sequence).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from odomgym.envs.base import DrawsLazily, describe_action, reset_options
from odomgym.errors import SpecError
from odomgym.lab.experiment import SensorAccuracy
from odomgym.lab.population import Population, check_bench_floor
from odomgym.lab.simulated import experiment_route
from odomgym.odometry.runs import to_frame
from odomgym.robot import PRESETS
from odomgym.selfcal.episodes import Episode, new_episode, step_episodes
from odomgym.selfcal.estimators import check_observe
from odomgym.selfcal.menu import ACTION_MENU
from odomgym.selfcal.session import MAX_BUDGET, OBSERVATION_BOUND, OBSERVATION_LAYOUT
from odomgym.sim.routes import Route

__all__ = [
    "SelfCalibrationEnv",
    "menu_index",
]

FloatArray = NDArray[np.float64]


def menu_index(action: object) -> int:
    """``action`` as a menu index, or :class:`SpecError` (field ``action``): a whole number
    (Python or numpy, or a 0-d array of one) in 0..len(ACTION_MENU)−1."""
    value = action.item() if isinstance(action, np.ndarray) and action.shape == () else action
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise SpecError(
            f"action must be a whole menu index 0..{len(ACTION_MENU) - 1}, "
            f"got {describe_action(action)}",
            field="action",
        )
    if not 0 <= int(value) < len(ACTION_MENU):
        raise SpecError(
            f"action must be a menu index 0..{len(ACTION_MENU) - 1}, got {int(value)}",
            field="action",
        )
    return int(value)


def _budgets(budget: object) -> tuple[int, ...]:
    if isinstance(budget, (int, np.integer)):
        values: tuple[object, ...] = (budget,)
    elif isinstance(budget, (list, tuple)):
        values = tuple(budget)
    else:
        raise SpecError(
            f"budget must be a whole number of runs or a list of them, got {budget!r}",
            field="budget",
        )
    if not values:
        raise SpecError("budget needs at least one value", field="budget")
    for value in values:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise SpecError(f"budget must be whole numbers of runs, got {value!r}", field="budget")
        if not 1 <= value <= MAX_BUDGET:
            raise SpecError(f"budget must be 1..{MAX_BUDGET} runs, got {value}", field="budget")
    return tuple(int(v) for v in values)  # type: ignore[call-overload]


class SelfCalibrationEnv(DrawsLazily, gym.Env[NDArray[np.float32], np.int64]):
    """One self-calibration session per episode (see the module docs).

    Args:
        floors: benchmark floor names to draw each episode's floor from.
        budget: the session's budget in runs, or several to draw from per episode (training
            uses (4, 8, 16) so one policy serves every budget; the budget is observed).
        shaping: coefficient c of the potential-based shaping (0 turns it off).
        population: the ranges the robots' systematic errors are drawn from.
        sensor: the ground-truth sensor's accuracy (each pose sample).
        observe: what the estimator sees of each run: ``"trajectory"`` (default) or
            ``"end_pose"`` (:data:`~odomgym.selfcal.estimators.ESTIMATORS`).
        render_mode: ``None`` (no drawing), ``"rgb_array"`` or ``"human"`` (module docs,
            "Rendering").
    """

    # One frame per run: at 2 frames/s a 16-run session plays back in about 8 s.
    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array"], "render_fps": 2}  # noqa: RUF012

    def __init__(
        self,
        floors: Sequence[str] | None = None,
        budget: int | Sequence[int] = 16,
        shaping: float = 0.1,
        population: Population | None = None,
        sensor: SensorAccuracy | None = None,
        observe: str = "trajectory",
        render_mode: str | None = None,
    ) -> None:
        self._set_render_mode(render_mode)
        self.observe = check_observe(observe)
        if population is not None and not isinstance(population, Population):
            raise SpecError(
                "population must be an odomgym.lab.population.Population (e.g. "
                f"Population(base='scout2')), got {type(population).__name__} {population!r}",
                field="population",
            )
        self.population = population or Population()
        skid = PRESETS[self.population.base].is_skid_steer
        if floors is None:  # the bench floors (skid-steer: cables only when asked, see below)
            floors = ("concrete", "rough") if skid else ("concrete", "rough", "cables")
        if isinstance(floors, str):
            floors = (floors,)
        if not isinstance(floors, (list, tuple)):
            raise SpecError(f"floors must be a list of floor names, got {floors!r}", field="floors")
        self.floors = tuple(floors)
        if not self.floors:
            raise SpecError("floors needs at least one floor", field="floors")
        for name in self.floors:
            check_bench_floor(name)
        self.budgets = _budgets(budget)
        if (
            isinstance(shaping, bool)
            or not isinstance(shaping, (int, float))
            or not (math.isfinite(shaping) and shaping >= 0.0)
        ):
            raise SpecError(f"shaping must be finite and >= 0, got {shaping}", field="shaping")
        self.shaping = float(shaping)
        self.sensor = sensor or SensorAccuracy()
        self.action_space = gym.spaces.Discrete(len(ACTION_MENU))
        bound = OBSERVATION_BOUND
        self.observation_space = gym.spaces.Box(
            -bound, bound, (len(OBSERVATION_LAYOUT),), dtype=np.float32
        )
        self.episode: Episode | None = None
        self._drawn: list[Any] = []  # the runs converted for drawing (rendering only)
        self._improvement: float | None = None
        self._last_item = "(none yet)"

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Start a session; ``options`` may fix ``floor`` and ``budget``."""
        super().reset(seed=seed)
        opts = reset_options(options)
        if "budget" in opts:
            if not isinstance(opts["budget"], (int, np.integer)):
                raise SpecError(
                    f"options['budget'] must be a whole number of runs, got {opts['budget']!r}",
                    field="budget",
                )
            opts["budget"] = _budgets(opts["budget"])[0]
        self.episode = new_episode(
            self.np_random,
            self.floors,
            self.budgets,
            self.population,
            self.sensor,
            opts,
            self.observe,
        )
        info = {
            "runs_used": 0,
            "budget": self.episode.session.budget,
            "travel_m": 0.0,
            "floor": self.episode.floor_name,
        }
        if self.render_mode is not None:
            self.episode.trace = []
            self._drawn = []
            self._improvement = None
            self._last_item = "(none yet)"
            if self.render_mode == "human":
                self.render()
        return self.episode.session.observation(), info

    def step(
        self, action: np.int64 | int
    ) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """Drive one run of menu item ``action`` (or stop) and refit."""
        if self.episode is None:
            raise RuntimeError("call reset() before step()")
        index = menu_index(action)
        obs, reward, terminated, info = step_episodes([self.episode], [index], self.shaping)[0]
        if self.render_mode is not None:
            self._improvement = info.get("improvement")
            self._last_item = str(info["item"])
            if self.render_mode == "human":
                self.render()
        return obs, reward, terminated, False, info

    def render(self) -> NDArray[np.uint8] | None:
        """The session so far (module docs, "Rendering")."""
        mode = self._render_mode_or_warn()
        if mode is None:
            return None
        episode = self.episode
        if episode is None or episode.trace is None:
            raise RuntimeError("call reset() before render()")
        from odomgym.envs.render import SessionRenderer, SessionRun, SessionState
        from odomgym.odometry.runs import replay_odometry

        if self._renderer is None:
            self._renderer = SessionRenderer(mode, self.metadata["render_fps"])
        for action, run, calibration in episode.trace[len(self._drawn) :]:
            start = run.true_pose[0]
            odometry = replay_odometry(run, episode.robot, calibration)
            self._drawn.append(
                SessionRun(
                    ACTION_MENU[action].name,
                    to_frame(run.true_pose[:, :2], start),
                    to_frame(odometry[:, :2], start),
                    bool(run.meta["finished"]),
                )
            )
        session = episode.session
        items = sorted({action for action, _, _ in episode.trace})
        routes = [_route_points(experiment_route(ACTION_MENU[a].experiment)) for a in items]  # type: ignore[arg-type]
        state = SessionState(
            floor=episode.floor_name,
            budget=session.budget,
            runs_used=session.runs_used,
            estimated=tuple(float(v) for v in session.estimator.errors),  # type: ignore[arg-type]
            true=(episode.robot.e_d, episode.robot.e_b, episode.robot.e_s),
            last_item=self._last_item,
            improvement=self._improvement,
        )
        return self._renderer.draw(self._drawn, state, routes)  # type: ignore[no-any-return]


def _route_points(route: Route) -> FloatArray:
    """The polyline (K, 2) [m] of a route's driven segments (an empty one for a spin)."""
    drives = [seg for seg in route.segments if seg.kind == "drive"]
    if not drives:
        return np.zeros((0, 2))
    return np.array([drives[0].start, *(seg.end for seg in drives)], dtype=np.float64)

"""The self-calibration episodes: a session on a hidden true robot, stepped in batches, and its
guarded terminal reward — the engine ``SelfCalibration-v1`` and its batched training vector env
(:mod:`odomgym.baselines.selfcal_vec_env`) share.

:func:`new_episode` draws a robot (:class:`~odomgym.lab.population.Population`), a benchmark
floor and a budget; :func:`step_episodes` advances many episodes by one action each with all
their runs — the experiments of the sessions that go on and the validation runs of those that
stop — simulated as one physics batch on one shared floor (each robot carries its floor's
roughness as an effect); :func:`validation_terms` is the noiseless validation and the reward's
terms (the env's docs, "Rewards"). Units: metres, radians; rewards in nats.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.errors import require_known_options
from odomgym.floor import FloorSpec
from odomgym.lab.experiment import SensorAccuracy
from odomgym.lab.population import (
    BENCH_FLOORS,
    CABLES_START_REGION,
    Population,
    cable_field,
    check_bench_floor,
)
from odomgym.lab.simulated import experiment_route, measure, random_start_poses
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run, end_error
from odomgym.odometry.umbmark_measures import e_max_syst
from odomgym.robot import RobotSpec
from odomgym.selfcal.menu import ACTION_MENU
from odomgym.selfcal.session import SelfCalSession
from odomgym.sim.route_runs import RunRequests
from odomgym.sim.routes import Route, square_route, straight_route

__all__ = [
    "ERROR_FLOOR",
    "FAILED_REWARD",
    "STRAIGHT_WEIGHT",
    "TERM_CLIP",
    "WORSE_PENALTY",
    "Episode",
    "new_episode",
    "step_episodes",
    "validation_terms",
]

FloatArray = NDArray[np.float64]

#: Weight of the straight-run family in the terminal reward [-].
STRAIGHT_WEIGHT = 0.25
#: Extra weight on every family the corrections made worse than uncalibrated [-].
WORSE_PENALTY = 2.0
#: Clip of each family's log improvement [nats].
TERM_CLIP = (-3.0, math.log(300.0))
#: Added to every validation error before the ratio, so a robot that is nearly right already
#: cannot make the ratio explode [m].
ERROR_FLOOR = 0.001
#: The terminal reward of a session that could not finish a run: the lowest reward any
#: finished session can get.
FAILED_REWARD = (1.0 + STRAIGHT_WEIGHT) * TERM_CLIP[0] + WORSE_PENALTY * 2.0 * TERM_CLIP[0]

_VALIDATION_ROUTES: tuple[tuple[Route, str, str | None], ...] = (
    (square_route(4.0, "cw"), "square", "cw"),
    (square_route(4.0, "ccw"), "square", "ccw"),
    (straight_route(4.0, False), "straight", None),
)


#: Where runs on the cable-free floors start, and where validation runs start [m]: far enough
#: from the cable field (±18 m) that no wheel ever meets a cable.
_PLAIN_ORIGIN = np.array([100.0, 0.0, 0.0])
_VALIDATION_ORIGIN = np.array([-100.0, 0.0, 0.0])


@functools.cache
def _shared_floor() -> FloorSpec:
    """The one floor every session of a step shares: the benchmark's cable field geometry
    (10 mm cables, 1.5 per m², over ±18 m; a fixed layout, not the benchmark's own) with no
    roughness of its own — each robot carries its floor's roughness as the
    ``floor_roughness`` effect (variances add, Chong & Kleeman 1997, Eq. 4), so sessions on
    different floors and the noiseless validation runs share one physics batch."""
    rng = np.random.default_rng(np.random.SeedSequence([0, 1995]))
    return cable_field(rng, roughness=0.0, name="selfcal-shared")


@functools.cache
def _skid_floor(name: str) -> FloorSpec:
    """The floor of a skid-steer robot's session on benchmark floor ``name`` (``""``: the
    noiseless validation floor), with the bench floor's roughness as the floor's own (a
    skid-steer session's robot carries no catalogue effect): on a cables floor, the shared
    floor's cable field itself (the same layout its differential-drive sessions cross; each
    wheel meets the cables at its own contact, :func:`odomgym.sim.cables.skid_cable_losses`),
    else a plain floor of the shared floor's friction. Skid-steer sessions on one bench floor
    share one physics batch; they are not batched with the differential-drive sessions, whose
    floor carries no roughness."""
    shared = _shared_floor()
    roughness = BENCH_FLOORS[name].roughness if name else 0.0
    if name and BENCH_FLOORS[name].cables:
        return dataclasses.replace(shared, roughness=roughness, name=f"selfcal-skid-{name}")
    return FloorSpec(friction=shared.friction, roughness=roughness, name=f"selfcal-skid-{name}")


def skid_prior(robot: RobotSpec) -> Calibration:
    """The calibration a skid-steer session starts from: the apparent track of rigid contacts
    in a slow spin, b·(1 + (a/b)²) from the nominal geometry (docs/skid-steer.md, "The
    analytic checks") — what an engineer who knows the robot is skid-steered would put in
    first. Differential-drive robots start uncalibrated (the identity)."""
    if not robot.is_skid_steer:
        return Calibration()
    return Calibration(wheelbase_scale=1.0 + (robot.axle_spacing / robot.wheelbase) ** 2)


@dataclass
class Episode:
    """One session in progress on a hidden true robot (shared by the env and its batched
    vector env)."""

    robot: RobotSpec
    floor_name: str
    session: SelfCalSession
    rng: np.random.Generator
    sensor: SensorAccuracy
    potential: float = 0.0
    travel: float = 0.0
    done: bool = False
    #: Every run driven, with its menu index and the calibration it was driven with — kept
    #: only when the env renders (None: nothing is kept).
    trace: list[tuple[int, Run, Calibration]] | None = None
    driven: RobotSpec = field(init=False)

    def __post_init__(self) -> None:
        if self.robot.is_skid_steer:  # its floor carries the roughness (_skid_floor)
            self.driven = self.robot
            return
        k = BENCH_FLOORS[self.floor_name].roughness
        self.driven = self.robot.apply_effect("floor_roughness", {"k_left": k, "k_right": k})

    @property
    def batch_key(self) -> str:
        """Which physics batch of a step drives this session's runs: ``""`` the shared floor
        (:func:`_shared_floor`), else the skid-steer floor of that name (:func:`_skid_floor`)."""
        return self.floor_name if self.robot.is_skid_steer else ""

    @property
    def validation_key(self) -> str:
        """Which batch drives the validation runs: the shared floor, or ``"skid-quiet"``."""
        return "skid-quiet" if self.robot.is_skid_steer else ""


def new_episode(
    rng: np.random.Generator,
    floors: Sequence[str],
    budgets: Sequence[int],
    population: Population,
    sensor: SensorAccuracy,
    options: Mapping[str, Any] | None = None,
    observe: str = "trajectory",
) -> Episode:
    """A new session: robot, floor, budget and run stream all drawn from ``rng``.

    ``options`` may fix ``floor`` (a benchmark floor name) and ``budget`` (runs).
    """
    opts = dict(options or {})
    require_known_options(opts, ("floor", "budget"), "SelfCalibration-v1")
    robot_rng, run_rng = rng.spawn(2)
    floor_name = str(opts.get("floor", floors[int(rng.integers(len(floors)))]))
    check_bench_floor(floor_name)
    budget = opts.get("budget", budgets[int(rng.integers(len(budgets)))])
    robot = population.sample(robot_rng, "selfcal-robot")
    # The session reads only the nominal parameters.
    if robot.is_skid_steer:
        session = SelfCalSession(
            robot, budget, sensor, initial=skid_prior(robot), observe=observe, centred=True
        )
    else:
        session = SelfCalSession(robot, budget, sensor, observe=observe)
    return Episode(robot, floor_name, session, run_rng, sensor)


def _add_validation(
    batch: RunRequests,
    robot: RobotSpec,
    calibration: Calibration,
    reference: Calibration | None = None,
) -> list[int]:
    """A 4 m square each way and a 4 m straight run, with ``calibration`` and with
    ``reference`` (default: none, the identity; a skid-steer session's: its starting
    :func:`skid_prior`), on a noiseless patch of floor (the robot without any roughness);
    returns their batch slots."""
    slots = []
    for cal in (calibration, reference if reference is not None else Calibration()):
        for route, kind, direction in _VALIDATION_ROUTES:
            quiet = np.random.default_rng(0)  # never drawn from: k = 0 on these wheels
            slot = batch.add(
                robot,
                route,
                cal,
                stream=quiet,
                start=_VALIDATION_ORIGIN,
                kind=kind,
                direction=direction,
            )
            slots.append(slot)
    return slots


def validation_terms(
    robots: Sequence[RobotSpec], calibrations: Sequence[Calibration]
) -> list[dict[str, float]]:
    """Validate each calibration on its robot: a 4 m square each way and a 4 m straight run,
    with it and without any, on noiseless floor from the same start (one batch).

    Returns per robot the errors [m] (``e_max_before``/``after``, ``straight_before``/
    ``after``), the family terms ``t_square``/``t_straight`` [nats], ``reward`` and
    ``finished`` (1.0 or 0.0).
    """
    batch = RunRequests()
    slots = [_add_validation(batch, r, c) for r, c in zip(robots, calibrations, strict=True)]
    runs, odom = batch.simulate(_shared_floor())
    return [_verdict(runs, odom, own) for own in slots]


def _verdict(runs: Sequence[Run], odom: FloatArray, slots: Sequence[int]) -> dict[str, float]:
    finished = all(bool(runs[i].meta["finished"]) for i in slots)
    errors = [end_error(runs[i], odom[i]) for i in slots]
    after_sq = e_max_syst(errors[0][None], errors[1][None])
    before_sq = e_max_syst(errors[3][None], errors[4][None])
    after_st = float(np.hypot(*errors[2][:2]))
    before_st = float(np.hypot(*errors[5][:2]))
    t_sq = _term(before_sq, after_sq)
    t_st = _term(before_st, after_st)
    reward = t_sq + STRAIGHT_WEIGHT * t_st - WORSE_PENALTY * (max(0.0, -t_sq) + max(0.0, -t_st))
    return {
        "e_max_before": before_sq,
        "e_max_after": after_sq,
        "straight_before": before_st,
        "straight_after": after_st,
        "t_square": t_sq,
        "t_straight": t_st,
        "reward": reward if finished else FAILED_REWARD,
        "finished": 1.0 if finished else 0.0,
    }


def _term(before: float, after: float) -> float:
    value = math.log((before + ERROR_FLOOR) / (after + ERROR_FLOOR))
    return min(max(value, TERM_CLIP[0]), TERM_CLIP[1])


def step_episodes(
    episodes: Sequence[Episode], actions: Sequence[int], shaping: float
) -> list[tuple[NDArray[np.float32], float, bool, dict[str, Any]]]:
    """Advance every episode by one action, all their runs simulated as one physics batch:
    the experiment runs of the sessions that go on and the validation runs of those that stop.

    A session whose budget is spent stops whatever the action (its observation says so: no
    runs left). Returns ``(observation, reward, terminated, info)`` per episode.
    """
    # One physics batch per floor: the shared floor for differential-drive sessions (all of
    # them, validations included), and for skid-steer sessions a floor per bench floor (the
    # shared cable field on cables floors, else plain) plus a noiseless one for their
    # validations (_skid_floor).
    batches: dict[str, RunRequests] = {}
    experiment_slot: dict[int, tuple[str, int]] = {}
    validation_slots: dict[int, tuple[str, list[int]]] = {}
    for i, (episode, action) in enumerate(zip(episodes, actions, strict=True)):
        if episode.done:
            raise RuntimeError("the session has ended: call reset() before step()")
        session = episode.session
        experiment = session.experiment(int(action))
        if experiment is None or session.runs_left <= 0:
            key = episode.validation_key
            batch = batches.setdefault(key, RunRequests())
            reference = skid_prior(episode.robot) if episode.robot.is_skid_steer else None
            validation_slots[i] = (
                key,
                _add_validation(batch, episode.robot, session.calibration, reference),
            )
            continue
        if BENCH_FLOORS[episode.floor_name].cables:
            poses = random_start_poses(episode.rng, 1, CABLES_START_REGION)
            assert poses is not None
            start = poses[0]
        else:
            start = _PLAIN_ORIGIN
        key = episode.batch_key
        batch = batches.setdefault(key, RunRequests())
        experiment_slot[i] = (
            key,
            batch.add(
                episode.driven,
                experiment_route(experiment),
                session.calibration,
                stream=episode.rng.spawn(1)[0],
                start=start,
                kind=experiment.kind,
                direction=experiment.direction,
            ),
        )
    simulated = {
        key: batch.simulate(
            _shared_floor() if key == "" else _skid_floor("" if key == "skid-quiet" else key)
        )
        for key, batch in batches.items()
    }
    results = []
    for i, episode in enumerate(episodes):
        session = episode.session
        info: dict[str, Any] = {
            "floor": episode.floor_name,
            "budget": session.budget,
            "item": ACTION_MENU[int(actions[i])].name if i in experiment_slot else "stop",
        }
        reward = 0.0
        terminated = False
        if i in experiment_slot:
            key, slot = experiment_slot[i]
            run = simulated[key][0][slot]
            if episode.trace is not None:
                episode.trace.append((int(actions[i]), run, session.calibration))
            if run.meta["finished"]:
                session.record(int(actions[i]), measure([run], episode.sensor, episode.rng))
                episode.travel += run.distance
                gain = session.estimator.information_gain
                reward = shaping * (gain - episode.potential)
                episode.potential = gain
            else:
                terminated = True
                reward = FAILED_REWARD - shaping * episode.potential
                info["failed"] = (
                    f"the robot did not finish its {ACTION_MENU[int(actions[i])].name} run (a "
                    "slippery floor, or corrections that make it circle?)"
                )
        else:
            terminated = True
            key, slots = validation_slots[i]
            verdict = _verdict(*simulated[key], slots)
            final = -shaping * episode.potential  # Φ = 0 at the end: the shaping telescopes
            reward = verdict["reward"] + final
            if not verdict["finished"]:
                info["failed"] = "the validation runs did not finish with these corrections"
            info["reward_terms"] = {
                "square": verdict["t_square"],
                "straight": verdict["t_straight"],
                "shaping": final,
            }
            info["e_max_before_mm"] = 1e3 * verdict["e_max_before"]
            info["e_max_after_mm"] = 1e3 * verdict["e_max_after"]
            after = verdict["e_max_after"]
            info["improvement"] = verdict["e_max_before"] / max(after, 1e-9)
        info["runs_used"] = session.runs_used
        info["travel_m"] = episode.travel
        if terminated:
            episode.done = True
            robot = episode.robot
            info["true_errors"] = (robot.e_d, robot.e_b, robot.e_s)
            info["estimated_errors"] = tuple(float(v) for v in session.estimator.errors)
            info["calibration"] = session.calibration.to_dict()
            info["experiments"] = list(session.history)
        results.append((session.observation(), float(reward), terminated, info))
    return results

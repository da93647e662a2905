"""``SelfCalibration-v1`` with skid-steer robots: a compatible addition (issue 43).

A skid-steer session starts from the apparent track of rigid contacts in a slow spin
(:func:`odomgym.selfcal.episodes.skid_prior`), drives its runs on a plain floor of its own and
validates against that start; differential-drive sessions do not notice skid-steer ones in
the same physics step.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import odomgym  # noqa: F401  (registers the envs)
from odomgym.lab.experiment import SensorAccuracy
from odomgym.lab.population import Population
from odomgym.lab.simulated import experiment_route
from odomgym.odometry.calibration import Calibration
from odomgym.robot import PRESETS
from odomgym.selfcal.episodes import _skid_floor, new_episode, skid_prior, step_episodes
from odomgym.selfcal.menu import ACTION_MENU
from odomgym.sim.route_runs import RunRequests

SKID = Population(base="scout2", e_b=(0.97, 1.03))


def test_the_skid_prior_is_the_rigid_spin_track() -> None:
    scout = PRESETS["scout2"]
    assert skid_prior(scout).wheelbase_scale == pytest.approx(1.0 + (0.498 / 0.583) ** 2)
    assert skid_prior(PRESETS["labmate"]).wheelbase_scale == 1.0


def test_stopping_at_once_keeps_the_prior_and_earns_nothing() -> None:
    env = gym.make("SelfCalibration-v1", population=SKID, budget=4)
    env.reset(seed=0)
    _, reward, terminated, _, info = env.step(0)
    assert terminated and reward == 0.0
    assert info["e_max_before_mm"] == info["e_max_after_mm"]
    assert info["estimated_errors"][1] == pytest.approx(
        skid_prior(PRESETS["scout2"]).wheelbase_scale
    )


def test_a_skid_steer_session_calibrates_its_apparent_track() -> None:
    """Four squares on ``concrete`` fit the apparent track of the squares' spins (the World's
    tyres: 1.667 on scout2 at 0.3 m/s, docs/skid-steer.md) and take the validation squares'
    E_max,syst from the prior's metre to centimetres."""
    env = gym.make("SelfCalibration-v1", population=SKID, budget=4, floors=["concrete"])
    env.reset(seed=1)
    for action in (1, 2, 1, 2, 0):  # the step after the budget validates
        _, reward, terminated, _, info = env.step(action)
    assert terminated and "failed" not in info
    assert info["e_max_before_mm"] > 500.0
    assert info["e_max_after_mm"] < info["e_max_before_mm"] / 20.0
    assert reward > 2.0
    true_e_b = info["true_errors"][1]  # the track's own error; the apparent one is ~1.67 × it
    assert 1.55 < info["estimated_errors"][1] / true_e_b < 1.75


@pytest.mark.slow
def test_a_skid_steer_session_on_cables_crosses_them_and_calibrates() -> None:
    """``cables`` is a skid-steer robot's floor when asked (not among its defaults): its runs
    cross the shared cable field, each wheel at its own contact (a square from a start inside
    the field ends elsewhere than on the same floor without its cables), the session still
    calibrates its apparent track, and the same seed gives the same bytes."""
    env = gym.make("SelfCalibration-v1", population=SKID, budget=4, floors=["cables"])
    assert gym.make("SelfCalibration-v1", population=SKID).unwrapped.floors == (
        "concrete",
        "rough",
    )

    def session(seed: int) -> tuple[list[np.ndarray], dict[str, Any]]:
        observations = [env.reset(seed=seed)[0]]
        info: dict[str, Any] = {}
        for action in (1, 2, 1, 2, 0):
            obs, _, terminated, _, info = env.step(action)
            observations.append(obs)
        assert terminated and "failed" not in info and info["floor"] == "cables"
        return observations, info

    first, info = session(1)
    again, _ = session(1)
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a, b)
    assert info["e_max_after_mm"] < info["e_max_before_mm"] / 10.0
    true_e_b = info["true_errors"][1]
    assert 1.5 < info["estimated_errors"][1] / true_e_b < 1.8
    square = ACTION_MENU[1].experiment
    assert square is not None
    route = experiment_route(square)
    start = np.array([2.0, -3.0, 0.3])  # inside the cable field (±18 m)
    cables = _skid_floor("cables")
    assert len(cables.bumps) > 100
    ends = []
    for floor in (cables, dataclasses.replace(cables, bumps=())):
        batch = RunRequests()
        batch.add(PRESETS["scout2"], route, Calibration(wheelbase_scale=1.7),
                  stream=np.random.default_rng(0), start=start)  # fmt: skip
        (run,), _ = batch.simulate(floor)
        ends.append(run.true_pose[-1])
    assert np.abs(ends[0][:2] - ends[1][:2]).max() > 1e-3  # the cables moved the square's end


@pytest.mark.parametrize("skid_floor", ["rough", "cables"])
def test_differential_drive_sessions_do_not_notice_skid_steer_ones_beside_them(
    skid_floor: str,
) -> None:
    """The same LabMate session stepped alone and in one physics step with a skid-steer
    session (on ``rough``, and on ``cables``, where the two cross the same cable field in
    batches of their own): bit-identical observations, rewards and estimates."""
    sensor = SensorAccuracy()

    def labmate(seed: int):  # type: ignore[no-untyped-def]
        return new_episode(np.random.default_rng(seed), ["concrete"], [3], Population(), sensor)

    alone, paired = labmate(5), labmate(5)
    skid = new_episode(np.random.default_rng(6), [skid_floor], [3], SKID, sensor)
    for action in (1, 5, 2, 0):
        ((obs_a, r_a, t_a, _),) = step_episodes([alone], [action], 0.1)
        (obs_p, r_p, t_p, _), _ = step_episodes([paired, skid], [action, action], 0.1)
        np.testing.assert_array_equal(obs_a, obs_p)
        assert (r_a, t_a) == (r_p, t_p)
    np.testing.assert_array_equal(alone.session.estimator.x, paired.session.estimator.x)


def test_the_selfcal_calibrator_starts_a_skid_steer_robot_from_its_prior() -> None:
    """``odomgym calibrate selfcal`` / ``bench calibrators`` on a skid-steer robot: without an
    initial calibration the calibrator starts where the env starts (the rigid spin track,
    centred), so its estimate can reach the apparent track the robot needs (about 1.67 on
    `concrete`); from the identity its prior held E_b near 1.16 (stop 72's measurement)."""
    from odomgym.baselines import SelfCalScripted
    from odomgym.floor import FLOORS
    from odomgym.lab.simulated import SimLab

    lab = SimLab(PRESETS["scout2"], FLOORS["concrete"], rng=np.random.default_rng(2))
    result = SelfCalScripted(budget=6).calibrate(lab)
    assert 1.6 < result.calibration.wheelbase_scale < 1.75
    start = Calibration(wheelbase_scale=1.2)  # a given start is kept as given (not centred)
    again = SelfCalScripted(budget=6).calibrate(
        SimLab(PRESETS["scout2"], FLOORS["concrete"], rng=np.random.default_rng(2)), start
    )
    assert again.calibration.wheelbase_scale < 1.6


@pytest.mark.parametrize(
    ("make", "field", "words"),
    [
        (lambda: Population(base="scout3"), "base", "unknown robot preset 'scout3'; presets: "),
        (lambda: Population(base="scout2", e_b=(1.1, 0.9)), "e_b", "low <= high, got (1.1, 0.9)"),
        (lambda: Population(e_s=(float("nan"), 1.0)), "e_s", "finite positive factors"),
        (lambda: Population(e_d=(1.0,)), "e_d", "a (low, high) pair of factors"),
        (lambda: Population(base="scout2", e_b=(3, 3)), "e_b", "no valid scout2: true_wheelbase"),
        (lambda: Population(e_d=(0.1, 1.0)), "e_d, e_s", "a robot drawn at e_d = 0.1"),
        (lambda: gym.make("SelfCalibration-v1", population="scout2"), "population", "got str"),
    ],
)
def test_a_bad_population_is_one_line_naming_its_field(make: Any, field: str, words: str) -> None:
    """A misspelled base raised a KeyError when the env was made, a population given as the
    preset's name an AttributeError, and reversed or NaN bounds numpy's errors at reset; a
    range that draws invalid robots named the derived field (true_wheelbase) at reset."""
    from odomgym.errors import SpecError

    with pytest.raises(SpecError) as caught:
        make()
    assert caught.value.field == field and words in str(caught.value)
    assert "\n" not in str(caught.value)

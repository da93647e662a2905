"""``SelfCalibration-v1`` with skid-steer robots: a compatible addition (issue 43).

A skid-steer session starts from the apparent track of rigid contacts in a slow spin
(:func:`odomgym.selfcal.episodes.skid_prior`), drives its runs on a plain floor of its own and
validates against that start; differential-drive sessions do not notice skid-steer ones in
the same physics step.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import odomgym  # noqa: F401  (registers the envs)
from odomgym.errors import SpecError
from odomgym.lab.experiment import SensorAccuracy
from odomgym.lab.population import Population
from odomgym.robot import PRESETS
from odomgym.selfcal.episodes import new_episode, skid_prior, step_episodes

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


def test_cables_are_refused_for_skid_steer_sessions_in_one_line() -> None:
    with pytest.raises(SpecError) as caught:
        gym.make("SelfCalibration-v1", population=SKID, floors=["cables"])
    assert caught.value.field == "floors" and "\n" not in str(caught.value)
    env = gym.make("SelfCalibration-v1", population=SKID)
    with pytest.raises(SpecError) as caught:
        env.reset(seed=0, options={"floor": "cables"})
    assert caught.value.field == "floor"


def test_differential_drive_sessions_do_not_notice_skid_steer_ones_beside_them() -> None:
    """The same LabMate session stepped alone and in one physics step with a skid-steer
    session: bit-identical observations, rewards and estimates."""
    sensor = SensorAccuracy()

    def labmate(seed: int):  # type: ignore[no-untyped-def]
        return new_episode(np.random.default_rng(seed), ["concrete"], [3], Population(), sensor)

    alone, paired = labmate(5), labmate(5)
    skid = new_episode(np.random.default_rng(6), ["rough"], [3], SKID, sensor)
    for action in (1, 5, 2, 0):
        ((obs_a, r_a, t_a, _),) = step_episodes([alone], [action], 0.1)
        (obs_p, r_p, t_p, _), _ = step_episodes([paired, skid], [action, action], 0.1)
        np.testing.assert_array_equal(obs_a, obs_p)
        assert (r_a, t_a) == (r_p, t_p)
    np.testing.assert_array_equal(alone.session.estimator.x, paired.session.estimator.x)

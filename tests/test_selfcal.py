"""SelfCalibration-v1, its estimator, its reward guards and the selfcal calibrator.

The guards are the issue's list of exploits, one test each: corrections that help one path and
wreck another, ending early, farming noise, free experiments, absurd corrections.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence

import gymnasium as gym
import numpy as np
import pytest

import odomgym  # noqa: F401  (registers the envs)
from odomgym.baselines.selfcal import MlpPolicy, SelfCal, load_policy, scripted_policy
from odomgym.baselines.validation import calibrate_in_simulation
from odomgym.envs.selfcal import SelfCalibrationEnv
from odomgym.errors import SpecError
from odomgym.floor import FLOORS
from odomgym.lab.experiment import SensorAccuracy
from odomgym.lab.population import Population
from odomgym.odometry.calibration import Calibration
from odomgym.robot import PRESETS
from odomgym.selfcal.episodes import (
    FAILED_REWARD,
    STRAIGHT_WEIGHT,
    WORSE_PENALTY,
    Episode,
    new_episode,
    step_episodes,
    validation_terms,
)
from odomgym.selfcal.menu import ACTION_MENU, STOP
from odomgym.selfcal.session import OBSERVATION_LAYOUT, OBSERVATION_VERSION, SelfCalSession

ITEM = {item.name: k for k, item in enumerate(ACTION_MENU)}


def _episodes(
    seeds: Sequence[int], floor: str, budget: int, observe: str = "trajectory"
) -> list[Episode]:
    return [
        new_episode(
            np.random.default_rng(seed),
            (floor,),
            (budget,),
            Population(),
            SensorAccuracy(),
            observe=observe,
        )
        for seed in seeds
    ]


def _play(
    episodes: list[Episode],
    choose: Callable[[Episode, np.ndarray], int],
    shaping: float = 0.1,
) -> list[tuple[float, dict]]:
    """Run every episode to its end in one batch; (total reward, final info) per episode."""
    totals = [0.0] * len(episodes)
    finals: list[dict | None] = [None] * len(episodes)
    obs = [ep.session.observation() for ep in episodes]
    while any(f is None for f in finals):
        live = [i for i, f in enumerate(finals) if f is None]
        actions = [choose(episodes[i], obs[i]) for i in live]
        results = step_episodes([episodes[i] for i in live], actions, shaping)
        for i, (o, r, done, info) in zip(live, results, strict=True):
            obs[i] = o
            totals[i] += r
            if done:
                finals[i] = info
    return [(t, f) for t, f in zip(totals, finals, strict=True) if f is not None]


def _scripted(episode: Episode, obs: np.ndarray) -> int:
    return scripted_policy(obs, episode.session.budget, episode.session.runs_used)


# ---------------------------------------------------------------------------- the env itself
def test_check_env_gymnasium_and_sb3() -> None:
    from gymnasium.utils.env_checker import check_env

    env = gym.make("SelfCalibration-v1", budget=4, floors=("concrete",))
    check_env(env.unwrapped, skip_render_check=True)
    sb3 = pytest.importorskip("stable_baselines3.common.env_checker")
    sb3.check_env(SelfCalibrationEnv(budget=4, floors=("concrete",)), warn=True)


def test_v0_keeps_the_end_pose_estimator_and_v1_filters_the_trajectory() -> None:
    """The trajectory filter changed the observation's values and the reward, so by the
    project's versioning rule it is a new id, ``SelfCalibration-v1``; ``-v0`` stays registered
    as the same class with ``observe="end_pose"`` (its earlier estimator)."""

    def trace(env_id: str, **kwargs: str) -> list[np.ndarray]:
        env = gym.make(env_id, budget=2, floors=("concrete",), **kwargs)
        obs, _ = env.reset(seed=5)
        out = [obs]
        for action in (1, 5):  # a 4 m square cw, then a 4 m straight run
            obs, reward, *_ = env.step(action)
            out += [obs, np.float64(reward)]
        return out

    with pytest.warns(DeprecationWarning, match="out of date"):  # Gymnasium's own notice
        v0 = trace("SelfCalibration-v0")
    v1 = trace("SelfCalibration-v1")
    v1_end_pose = trace("SelfCalibration-v1", observe="end_pose")
    assert all(np.array_equal(a, b) for a, b in zip(v0, v1_end_pose, strict=True))
    assert not all(np.array_equal(a, b) for a, b in zip(v0, v1, strict=True))
    assert gym.spec("SelfCalibration-v0").kwargs == {"observe": "end_pose"}
    assert gym.spec("SelfCalibration-v1").kwargs == {}


def test_spaces_and_observation_layout() -> None:
    env = SelfCalibrationEnv(budget=4)
    assert env.action_space.n == len(ACTION_MENU) == 10
    assert env.observation_space.shape == (len(OBSERVATION_LAYOUT),) == (31,)
    obs, info = env.reset(seed=3, options={"floor": "rough", "budget": 2})
    assert env.observation_space.contains(obs)
    assert info["budget"] == 2 and info["floor"] == "rough"
    assert obs[OBSERVATION_LAYOUT.index("runs_left_fraction")] == 1.0


def test_same_seed_same_session_bit_for_bit() -> None:
    def rollout() -> list[np.ndarray]:
        env = SelfCalibrationEnv(budget=3)
        obs, _ = env.reset(seed=11)
        out = [obs]
        for action in (ITEM["square2-cw"], ITEM["straight4"], ITEM["spin360-ccw"], STOP):
            obs, reward, terminated, _, _ = env.step(action)
            out.append(np.append(obs, reward))
            if terminated:
                break
        return out

    first, second = rollout(), rollout()
    assert len(first) == len(second) == 5
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a, b)


def test_bad_settings_and_actions_are_one_line_errors() -> None:
    with pytest.raises(SpecError, match=r"budget must be 1\.\.64"):
        SelfCalibrationEnv(budget=0)
    with pytest.raises(SpecError, match="unknown benchmark floor 'bumpy'"):
        SelfCalibrationEnv(floors=("bumpy",))
    with pytest.raises(SpecError, match="shaping"):
        SelfCalibrationEnv(shaping=float("nan"))
    env = SelfCalibrationEnv(budget=2)
    env.reset(seed=0)
    for bad in (10, -1, 2.5, np.nan, True, "1"):
        with pytest.raises(SpecError) as caught:
            env.step(bad)  # type: ignore[arg-type]
        assert caught.value.field == "action"
    with pytest.raises(SpecError, match="unknown reset option"):
        env.reset(seed=0, options={"floors": "rough"})
    with pytest.raises(SpecError, match="reset options must be a dict"):
        env.reset(seed=0, options=["floor"])  # type: ignore[arg-type]
    with pytest.raises(SpecError, match=r"options\['budget'\] must be a whole number"):
        env.reset(seed=0, options={"budget": [8, 4]})
    for kwargs, field in (
        ({"budget": 4.0}, "budget"),
        ({"shaping": "0.1"}, "shaping"),
        ({"floors": 5}, "floors"),  # None is the default: every floor the robot can drive
    ):
        with pytest.raises(SpecError) as caught:
            SelfCalibrationEnv(**kwargs)  # type: ignore[arg-type]
        assert caught.value.field == field
    env.reset(seed=0)
    env.step(STOP)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(STOP)


# ---------------------------------------------------------------------------- the estimator
def test_estimator_recovers_the_true_errors_on_a_noiseless_floor() -> None:
    """The scripted schedule (4 m squares both ways and a straight run) with the end-pose
    estimator recovers E_d, E_b and E_s of a robot on the noiseless floor to the precision
    the sensor allows (σ = 2 mm, 0.4°)."""
    robot = PRESETS["labmate"].with_errors(1.006, 0.97, 1.012)
    report = calibrate_in_simulation(
        SelfCal(budget=8, policy="scripted", observe="end_pose"), robot, FLOORS["smooth"], seed=5
    )
    est = report.result.estimates
    assert abs(est["E_d"] - robot.e_d) < 2e-4
    assert abs(est["E_b"] - robot.e_b) < 5e-4
    assert abs(est["E_s"] - robot.e_s) < 1e-3
    assert report.result.runs_used == 8
    assert report.improvement > 20.0
    assert report.result.notes[0].startswith("experiments: square4-cw, square4-ccw, straight4")


def test_a_fixed_schedule_is_driven_in_order_and_checked(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``selfcal_scripted``'s ``schedule`` (and ``odomgym calibrate --schedule``): the items are
    driven in the given order and repeated until the budget is spent; an unknown item, or the
    option on a method that does not take it, is a one-line error naming ``schedule``."""
    from odomgym.baselines.selfcal import SelfCalEndPose, SelfCalScripted
    from odomgym.cli import main

    robot = PRESETS["labmate"].with_errors(1.004, 0.98, 1.01)
    report = calibrate_in_simulation(
        SelfCalScripted(5, schedule=("square2-ccw", "straight4-back")),
        robot,
        FLOORS["concrete"],
        seed=1,
    )
    assert report.result.notes == [
        "experiments: square2-ccw, straight4-back, square2-ccw, straight4-back, square2-ccw"
    ]
    assert report.improvement > 3.0
    assert SelfCalEndPose(2, schedule="spin360-cw, square4-cw").options.schedule == (
        "spin360-cw",
        "square4-cw",
    )
    with pytest.raises(SpecError, match="'square5' is not a menu item") as err:
        SelfCalScripted(4, schedule=("square4-cw", "square5"))
    assert err.value.field == "schedule"
    with pytest.raises(SpecError):
        SelfCalScripted(4, schedule=("stop",))
    with pytest.raises(SpecError, match="names no menu item"):
        SelfCalScripted(4, schedule=" , ")
    assert main(["calibrate", "umbmark", "--schedule", "square4-cw"]) == 2
    assert "umbmark takes no option 'schedule'" in capsys.readouterr().err
    code = main(["calibrate", "selfcal_scripted", "--schedule", "spin720-cw,square4-ccw", "--json"])
    assert code == 0
    notes = json.loads(capsys.readouterr().out)["notes"]
    assert notes[0].startswith("experiments: spin720-cw, square4-ccw, spin720-cw")


def test_roughness_estimate_tracks_the_floor() -> None:
    """ρ (the floor's scatter over the concrete floor's) comes out near 1 on concrete and
    near k_rough/k_concrete = 5 on the rough floor."""
    rho = {}
    for floor in ("concrete", "rough"):
        episodes = _episodes(range(4), floor, 12)
        _play(episodes, _scripted)
        rho[floor] = float(np.median([ep.session.estimator.roughness for ep in episodes]))
    assert rho["concrete"] < 1.6
    assert 3.0 < rho["rough"] < 7.5


# ---------------------------------------------------------------------------- the guards
def test_guard_ending_early_earns_exactly_nothing() -> None:
    env = SelfCalibrationEnv()
    for seed in range(3):
        env.reset(seed=seed)
        _, reward, terminated, truncated, info = env.step(STOP)
        assert terminated and not truncated
        assert reward == 0.0  # the uncalibrated robot against itself, on the same runs
        assert info["improvement"] == 1.0 and info["runs_used"] == 0


def test_guard_shaping_sums_to_zero_over_an_episode() -> None:
    """Potential-based shaping (Ng et al. 1999) telescopes: every episode's return is the same
    with and without it, so it cannot change which policy is best."""
    totals = {}
    for shaping in (0.0, 0.1, 1.0):
        episodes = _episodes([7, 8], "concrete", 5)
        totals[shaping] = [t for t, _ in _play(episodes, _scripted, shaping)]
    np.testing.assert_allclose(totals[0.1], totals[0.0], atol=1e-12)
    np.testing.assert_allclose(totals[1.0], totals[0.0], atol=1e-12)


def test_guard_free_experiments_spins_cost_a_run_each() -> None:
    env = SelfCalibrationEnv(budget=4)
    env.reset(seed=1)
    for step in range(4):
        _, _, terminated, _, info = env.step(ITEM["spin720-cw"])
        assert not terminated and info["runs_used"] == step + 1
    _, _, terminated, _, info = env.step(ITEM["square4-cw"])  # the budget is spent: it stops
    assert terminated and info["runs_used"] == 4 and info["item"] == "stop"


def test_guard_noise_farming_validation_is_exact_and_independent_of_the_session() -> None:
    """The validation runs are noiseless and start from the same pose, so a calibration's
    verdict is a fact about it, not a draw: the same alone or in a batch, and no measurement
    luck in the session can reach it. Repeating the cheapest run (a spin) scores below the
    scripted schedule."""
    robot = Population().sample(np.random.default_rng(3), "r")
    cal = Calibration.from_errors(robot.e_d, robot.e_b, robot.e_s)
    other = Population().sample(np.random.default_rng(4), "s")
    alone = validation_terms([robot], [cal])[0]
    batched = validation_terms([other, robot], [Calibration(), cal])[1]
    assert alone == batched
    spins = _play(_episodes(range(6), "concrete", 6), lambda ep, o: ITEM["spin360-cw"])
    scripted = _play(_episodes(range(6), "concrete", 6), _scripted)
    assert np.mean([t for t, _ in spins]) < np.mean([t for t, _ in scripted]) - 1.0


def test_guard_corrections_that_wreck_another_path_lose() -> None:
    """The truth beats (a) right for the squares but E_s off by 3 % — the straight family
    loses — and (b) right on straight runs but an E_d correction overdone threefold — the
    square family loses; a family made worse than uncalibrated pays WORSE_PENALTY."""
    robots = [Population().sample(np.random.default_rng(s), f"r{s}") for s in range(5)]
    for robot in robots:
        truth = Calibration.from_errors(robot.e_d, robot.e_b, robot.e_s)
        scale_off = Calibration.from_errors(robot.e_d, robot.e_b, robot.e_s * 1.03)
        overdone = Calibration.from_errors(1.0 + 3.0 * (robot.e_d - 1.0), robot.e_b, robot.e_s)
        verdicts = validation_terms([robot] * 3, [truth, scale_off, overdone])
        good, scaled, over = verdicts
        assert good["reward"] > scaled["reward"] and good["reward"] > over["reward"]
        assert scaled["t_straight"] < good["t_straight"] - 1.0  # 12 cm off over 4 m
        assert over["t_square"] < good["t_square"] - 1.0
        for v in verdicts:
            expected = (
                v["t_square"]
                + STRAIGHT_WEIGHT * v["t_straight"]
                - WORSE_PENALTY * (max(0.0, -v["t_square"]) + max(0.0, -v["t_straight"]))
            )
            assert v["reward"] == pytest.approx(expected, abs=1e-12)


def test_guard_absurd_corrections_score_low_without_an_exception() -> None:
    robot = Population().sample(np.random.default_rng(0), "r")
    verdict = validation_terms([robot], [Calibration(c_left=0.5, c_right=1.5)])[0]
    assert verdict["finished"] == 1.0 and math.isfinite(verdict["reward"])
    assert verdict["t_straight"] == -3.0  # clipped: the straight run ends metres away
    assert verdict["reward"] < -(1.0 + WORSE_PENALTY) * 3.0


def test_a_run_that_cannot_finish_ends_the_session_with_the_lowest_reward(monkeypatch) -> None:
    """Simulated here by a time limit too short for a 4 m square: the session ends at once,
    says why, and scores FAILED_REWARD (minus the shaping collected, which telescopes)."""
    import odomgym.sim.route_runs as lab

    real = lab.simulate_runs

    def hurried(*args, **kwargs):
        return real(*args, **{**kwargs, "max_time": 30.0})

    env = SelfCalibrationEnv(budget=4, shaping=0.0)
    env.reset(seed=2)
    monkeypatch.setattr(lab, "simulate_runs", hurried)
    _, reward, terminated, _, info = env.step(ITEM["square4-cw"])
    assert terminated and reward == FAILED_REWARD
    assert "did not finish its square4-cw run" in info["failed"]
    assert "improvement" not in info and info["runs_used"] == 0


# ---------------------------------------------------------------------------- sessions, policies
def test_session_refuses_bad_budgets_and_actions() -> None:
    robot = PRESETS["labmate"]
    with pytest.raises(SpecError, match="budget must be <= 64"):
        SelfCalSession(robot, 65)
    session = SelfCalSession(robot, 4)
    with pytest.raises(SpecError, match="menu index"):
        session.experiment(len(ACTION_MENU))
    with pytest.raises(SpecError, match="stop drives no run"):
        session.record(STOP, [])


def test_scripted_schedule() -> None:
    names = [ACTION_MENU[scripted_policy(np.zeros(1, np.float32), 16, k)].name for k in range(17)]
    assert names[:4] == ["square4-cw", "square4-ccw", "straight4", "square4-cw"]
    assert names.count("straight4") == 2 and names[10] == "straight4" and names[16] == "stop"
    assert names.count("square4-cw") == names.count("square4-ccw") == 7
    short = [ACTION_MENU[scripted_policy(np.zeros(1, np.float32), 4, k)].name for k in range(4)]
    assert short == ["square4-cw", "square4-ccw"] * 2


def test_policy_files_are_checked(tmp_path) -> None:
    shipped = load_policy("learned")
    assert shipped.meta["observation_version"] == OBSERVATION_VERSION == 2
    assert shipped.meta["observe"] == "trajectory"
    assert shipped.meta["command"].startswith("odomgym train selfcal --algo ppo --steps ")
    assert shipped.meta["steps"] >= 100_000
    for old in (0, 1):  # version 1: the end-pose policy's spreads mean something else
        bad = MlpPolicy(shipped.weights, {**shipped.meta, "observation_version": old})
        bad.save(tmp_path / "old.npz")
        with pytest.raises(SpecError, match=f"observation layout {old}"):
            load_policy(str(tmp_path / "old.npz"))
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(SpecError, match="not a selfcal policy file"):
        load_policy(str(tmp_path / "junk.npz"))
    with pytest.raises(SpecError, match="'learned', 'scripted' or a policy"):
        load_policy(str(tmp_path / "missing.npz"))

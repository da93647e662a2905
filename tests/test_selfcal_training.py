"""Training the self-calibration policy (the rl extra): the batched vector env, the export of
the policy network to numpy, the command, a short training run, and the shipped policy
against UMBmark."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from stable_baselines3 import DQN, PPO
from stable_baselines3.common.vec_env import DummyVecEnv

from odomgym.baselines.benchmark import BenchConfig, run_benchmark, summarize
from odomgym.baselines.selfcal import load_policy
from odomgym.baselines.selfcal_train import evaluate, export_policy, load_hyperparams
from odomgym.baselines.selfcal_vec_env import SelfCalVecEnv
from odomgym.cli import main
from odomgym.envs.selfcal import SelfCalibrationEnv
from odomgym.errors import SpecError
from odomgym.selfcal.menu import ACTION_MENU
from odomgym.selfcal.session import OBSERVATION_VERSION

KWARGS = {"budget": [2, 3], "floors": ["concrete", "rough", "cables"]}


def _rollout(venv, steps: int) -> list[np.ndarray]:
    venv.seed(40)
    obs = venv.reset()
    rng = np.random.default_rng(0)
    out = [obs]
    for _ in range(steps):
        actions = rng.integers(0, len(ACTION_MENU), size=venv.num_envs)
        obs, rewards, dones, infos = venv.step(actions)
        terminal = [info.get("terminal_observation", np.zeros(1)).sum() for info in infos]
        out += [obs, rewards, dones.astype(float), np.array(terminal)]
    venv.close()
    return out


@pytest.mark.slow
def test_batched_vector_env_equals_single_envs_and_ignores_the_worker_count() -> None:
    """Sub-env i of the batched env plays exactly the episodes a DummyVecEnv of single envs
    plays (same seeds, same actions, SB3's auto-reset), whether its sessions live in one
    process or two: each session's randomness is its own."""
    n, steps = 4, 10
    reference = _rollout(
        DummyVecEnv([lambda: SelfCalibrationEnv(**KWARGS) for _ in range(n)]), steps
    )
    for workers in (1, 2):
        batched = _rollout(SelfCalVecEnv(n, workers=workers, env_kwargs=KWARGS), steps)
        for a, b in zip(reference, batched, strict=True):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("algo", ["ppo", "dqn"])
@pytest.mark.slow
def test_exported_policy_acts_as_sb3_predicts(algo: str, tmp_path) -> None:
    """The numpy policy (tanh for PPO, ReLU for DQN) picks SB3's deterministic action, also
    after a round trip through its file."""
    env = SelfCalibrationEnv(budget=2)
    if algo == "ppo":
        model = PPO(
            "MlpPolicy",
            env,
            seed=3,
            n_steps=32,
            batch_size=32,
            policy_kwargs={"net_arch": [16, 16]},
        )
    else:
        model = DQN(
            "MlpPolicy", env, seed=3, learning_starts=16, policy_kwargs={"net_arch": [16, 16]}
        )
    model.learn(64)
    policy = export_policy(model, {"observation_version": OBSERVATION_VERSION})
    policy.save(tmp_path / "p.npz")
    loaded = load_policy(str(tmp_path / "p.npz"))
    assert loaded.meta["activation"] == ("tanh" if algo == "ppo" else "relu")
    rng = np.random.default_rng(1)
    obs = rng.uniform(-3, 3, size=(200, env.observation_space.shape[0])).astype(np.float32)
    expected, _ = model.predict(obs, deterministic=True)
    np.testing.assert_array_equal(np.argmax(loaded.logits(obs), axis=1), expected)


@pytest.mark.slow
def test_vector_env_attributes_and_errors_keep_the_workers_in_step() -> None:
    venv = SelfCalVecEnv(4, workers=2, env_kwargs={"budget": 2})
    try:
        assert venv.get_attr("budgets", [2, 0]) == [(2,), (2,)]
        venv.set_attr("shaping", 0.5, [1, 3])
        assert venv.get_attr("shaping") == [0.1, 0.5, 0.1, 0.5]
        venv.seed(0)
        venv.reset()
        with pytest.raises(SpecError, match="menu index"):
            venv.step(np.array([1, 10, 0, 0]))
        with pytest.raises(SpecError, match="one action per session"):
            venv.step(np.array([1, 2]))
        obs, *_ = venv.step(np.array([0, 0, 0, 0]))  # the shards still answer in step
        assert obs.shape == (4, 31)
    finally:
        venv.close()
    with pytest.raises(SpecError, match="unknown env_kwargs budgte"):
        SelfCalVecEnv(2, env_kwargs={"budgte": 4})


def test_hyperparameters_come_from_the_data_file_keyed_by_env_id(tmp_path) -> None:
    params = load_hyperparams("ppo")
    assert params["policy"] == "MlpPolicy" and params["gamma"] == 1.0
    with pytest.raises(SpecError, match="unknown algorithm 'sac'"):
        load_hyperparams("sac")
    assert load_hyperparams("dqn")["buffer_size"] == 50_000  # each algorithm its own file
    (tmp_path / "h.yml").write_text("Other-v0:\n  n_envs: 2\n")
    with pytest.raises(SpecError, match=r"h\.yml: no key 'SelfCalibration-v1'"):
        load_hyperparams("ppo", tmp_path / "h.yml")
    (tmp_path / "bad.yml").write_text("SelfCalibration-v1: [\n")
    with pytest.raises(SpecError, match=r"bad\.yml: not valid YAML"):
        load_hyperparams("ppo", tmp_path / "bad.yml")


@pytest.mark.slow
def test_train_command_writes_the_policy_and_its_record(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    code = main(
        [
            "train",
            "selfcal",
            "--steps",
            "64",
            "--envs",
            "4",
            "--workers",
            "1",
            "--eval-sessions",
            "2",
            "--out",
            str(out),
            "--json",
        ]
    )
    assert code == 0, capsys.readouterr().err
    summary = json.loads(capsys.readouterr().out)
    assert summary["steps"] == 64
    assert summary["evaluation"]["failures"] == 0 and summary["evaluation"]["runs_mean"] > 0
    for name in ("policy.npz", "model.zip", "policy.json", "progress.csv", "learning_curve.png"):
        assert (out / name).stat().st_size > 0
    meta = json.loads((out / "policy.json").read_text())
    assert meta["command"].startswith("odomgym train selfcal --algo ppo --steps 64 --envs 4")
    assert meta["command"].endswith("--eval-sessions 2")  # the evaluation as it was run
    assert load_policy(str(out / "policy.npz")).meta["steps"] == 64
    code = main(
        ["calibrate", "selfcal", "--policy", str(out / "policy.npz"), "--runs", "1", "--json"]
    )
    assert code == 0
    assert json.loads(capsys.readouterr().out)["runs_used"] <= 2 * 1 + 6


@pytest.mark.slow
def test_short_training_improves_on_the_untrained_policy() -> None:
    """PPO from scratch, 3 072 steps on budget-4 sessions: the deterministic policy's mean
    reward on 16 held-out sessions rises by more than 0.5 nats over the untrained network's."""
    kwargs = {"budget": 4, "floors": ["concrete"]}
    venv = SelfCalVecEnv(16, workers=1, env_kwargs=kwargs)
    venv.seed(0)
    model = PPO(
        "MlpPolicy",
        venv,
        seed=0,
        n_steps=16,
        batch_size=64,
        gamma=1.0,
        learning_rate=1e-3,
        policy_kwargs={"net_arch": [64, 64]},
        device="cpu",
    )

    def act(obs: np.ndarray) -> np.ndarray:
        actions, _ = model.predict(obs, deterministic=True)
        return actions

    seeds = range(500, 516)
    before = evaluate(act, seeds=seeds, env_kwargs=kwargs)
    model.learn(3072)
    after = evaluate(act, seeds=seeds, env_kwargs=kwargs)
    venv.close()
    assert after["reward_mean"] > before["reward_mean"] + 0.5, (before, after)


@pytest.mark.slow
def test_shipped_policy_against_umbmark_on_twenty_robots() -> None:
    """The shipped policy, on the benchmark's first 20 robots (concrete floor, budget 16, the
    benchmark's own noisy validation squares): its median improvement is at least MARGIN of
    UMBmark's."""
    config = BenchConfig(robots=20, floors=("concrete",), methods=("selfcal", "umbmark"))
    summary = {s["method"]: s for s in summarize(run_benchmark(config, jobs=2))}
    ratio = summary["selfcal"]["improvement_median"] / summary["umbmark"]["improvement_median"]
    assert summary["selfcal"]["failures"] == 0
    assert ratio >= MARGIN, summary


MARGIN = 0.8
"""Stated margin: selfcal's median improvement over 20 robots is at least 0.8 of UMBmark's
(the medians of 20 paired robots scatter by about ±15 %)."""


@pytest.mark.slow
def test_training_is_reproducible_from_its_command(tmp_path) -> None:
    """The same command twice (two worker processes each time) gives bit-identical weights:
    the shipped policy's recorded command reproduces it."""
    from odomgym.baselines.selfcal_train import train

    weights = []
    for k in range(2):
        result = train(
            steps=128,
            envs=4,
            workers=2,
            seed=5,
            out=tmp_path / f"r{k}",
            progress=False,
            eval_seeds=range(2),
        )
        weights.append(load_policy(str(result.policy_file)).weights)
    for (w0, b0), (w1, b1) in zip(*weights, strict=True):
        np.testing.assert_array_equal(w0, w1)
        np.testing.assert_array_equal(b0, b1)

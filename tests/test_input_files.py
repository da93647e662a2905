"""A new user's bad input files: a ``train selfcal --hyperparams`` file whose values SB3 would
refuse (or choke on after a rollout), and OptiOdom session metadata written in other units. Each is
refused before any work in one line naming the file, the line and the key the user wrote (not
an odomgym-internal field), and valid inputs read as before."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest

from odomgym.cli import main
from odomgym.data.optiodom import read_session
from odomgym.data.samples import sample_session
from odomgym.errors import SpecError

SHIPPED_PPO = (
    Path(__file__).resolve().parents[1] / "odomgym" / "data" / "hyperparams" / "ppo.yml"
).read_text()


# ---------------------------------------------------------------- hyperparameter files


def _hyperparams(tmp_path: Path, old: str, new: str, name: str = "hp.yml") -> tuple[Path, int]:
    """The shipped ppo.yml with the line holding ``old`` changed to ``new`` (as a user edits
    it), and that line's 1-based number."""
    lines = SHIPPED_PPO.splitlines()
    (index,) = [i for i, line in enumerate(lines) if old in line]
    lines[index] = lines[index].replace(old, new)
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path, index + 1


def _no_training(**kwargs: Any) -> Any:
    raise AssertionError("training started although the hyperparameter file is invalid")


@pytest.mark.parametrize(
    ("old", "new", "key", "says"),
    [
        ("learning_rate: 0.0003", "learning_rate: -0.0003", "learning_rate", "> 0"),
        ("n_epochs: 10", "n_epochs: ten", "n_epochs", "whole number >= 1"),
        (
            "floors: [concrete, rough, cables]",
            "floors: [concret]",
            "env_kwargs.floors",
            "unknown benchmark floor 'concret'",
        ),
    ],
)
def test_train_refuses_a_bad_hyperparameter_at_its_line_before_any_work(
    old: str,
    new: str,
    key: str,
    says: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A user's negative learning rate, text epochs and misspelt floor: exit 2,
    ``file:line: key …``, and no output folder (SB3 had said 'internal error: ValueError' or
    failed after a rollout, leaving progress.csv behind)."""
    pytest.importorskip("stable_baselines3")
    import odomgym.baselines.selfcal_train as selfcal_train

    monkeypatch.setattr(selfcal_train, "train", _no_training)
    path, line = _hyperparams(tmp_path, old, new)
    out = tmp_path / "D"
    args = ["train", "selfcal", "--steps", "64", "--envs", "2", "--workers", "1"]
    code = main([*args, "--eval-sessions", "1", "--hyperparams", str(path), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith(f"odomgym: error: {path}:{line}: {key}"), err
    assert says in err and "internal error" not in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize(
    ("algo", "old", "new", "key", "says"),
    [
        ("ppo", "learning_rate: 0.0003", "learning_rate: 3e-4", "learning_rate", "3.0e-4"),
        ("ppo", "learning_rate: 0.0003", "learning_rate: lin_0.0003", "learning_rate", "constant"),
        ("ppo", "batch_size: 256", "batch_size: 1", "batch_size", ">= 2"),
        ("ppo", "batch_size: 256", "batch_size: 0", "batch_size", ">= 2"),
        ("ppo", "n_steps: 32 ", "n_steps: 32.5 ", "n_steps", "whole number"),
        ("ppo", "n_timesteps: 150000", "n_timesteps: -5", "n_timesteps", ">= 1"),
        ("ppo", "n_envs: 32 ", "n_envs: true ", "n_envs", "whole number"),
        ("ppo", "gamma: 1.0 ", "gamma: 1.5 ", "gamma", "[0, 1]"),
        ("ppo", "gae_lambda: 0.95", "gae_lambda: .nan", "gae_lambda", "[0, 1]"),
        ("ppo", "ent_coef: 0.01", "ent_coef: -0.01", "ent_coef", ">= 0"),
        ("ppo", "ent_coef: 0.01", "seed: 3", "seed", "--seed"),
        ("ppo", "ent_coef: 0.01", "use_sde: true", "use_sde", "Discrete"),
        (
            "ppo",
            "ent_coef: 0.01",
            "buffer_size: 10",
            "buffer_size",
            "buffer_size is not a hyperparameter of ppo",
        ),
        ("ppo", "batch_size: 256", "batch_sise: 256", "batch_sise", "did you mean batch_size"),
        ("ppo", "policy: MlpPolicy", "policy: CnnPolicy", "policy", "MlpPolicy"),
        (
            "ppo",
            "net_arch: [64, 64]",
            "net_arch: [64, -1]",
            "policy_kwargs.net_arch",
            "layer widths",
        ),
        (
            "ppo",
            "net_arch: [64, 64]",
            "activation_fn: nn.ReLU",
            "policy_kwargs.activation_fn",
            "Python object",
        ),
        ("ppo", "budget: [4, 8, 16]", "budget: [0]", "env_kwargs.budget", "budget"),
        ("ppo", "shaping: 0.1", "shapping: 0.1", "env_kwargs.shapping", "no setting"),
        ("ppo", "shaping: 0.1", "shaping: -1", "env_kwargs.shaping", ">= 0"),
        (
            "a2c",
            "batch_size: 256",
            "batch_size: 256",
            "batch_size",
            "batch_size is not a hyperparameter of a2c",
        ),
    ],
)
def test_hyperparameter_values_are_checked_with_file_line_and_key(
    algo: str, old: str, new: str, key: str, says: str, tmp_path: Path
) -> None:
    """Types and ranges from SB3's documented constraints (and PPO's batch_size > 1 assert),
    odomgym's own keys, and the env's settings, each at the line of its key."""
    pytest.importorskip("stable_baselines3")
    from odomgym.baselines.selfcal_train import load_hyperparams

    path, line = _hyperparams(tmp_path, old, new)
    with pytest.raises(SpecError) as caught:
        load_hyperparams(algo, path)
    message = str(caught.value)
    assert message.startswith(f"{path}:{line}: {key}"), message
    assert says in message, message
    assert caught.value.field == key


@pytest.mark.parametrize(
    ("line", "key", "says"),
    [
        ("learning_rate: 0", "learning_rate", "> 0"),
        ("exploration_fraction: 1.5", "exploration_fraction", "[0, 1]"),
        ("train_freq: [4, epoch]", "train_freq", "[n, episode]"),
        ("tau: 0", "tau", "(0, 1]"),
        ("learning_starts: -1", "learning_starts", ">= 0"),
        ("gradient_steps: 0", "gradient_steps", ">= 1 or -1"),
        ("n_epochs: 4", "n_epochs", "n_epochs is not a hyperparameter of dqn"),
    ],
)
def test_dqn_hyperparameters_are_checked(line: str, key: str, says: str, tmp_path: Path) -> None:
    """DQN's own keys, in a file of the shipped dqn.yml's layout."""
    pytest.importorskip("stable_baselines3")
    from odomgym.baselines.selfcal_train import load_hyperparams

    path = tmp_path / "dqn.yml"
    path.write_text(f"# DQN\nSelfCalibration-v1:\n  policy: MlpPolicy\n  {line}\n  gamma: 1.0\n")
    with pytest.raises(SpecError) as caught:
        load_hyperparams("dqn", path)
    assert str(caught.value).startswith(f"{path}:4: {key}"), caught.value
    assert says in str(caught.value), caught.value


def test_valid_hyperparameter_files_load_as_before(tmp_path: Path) -> None:
    """The shipped files, a user's own layout, a DQN train_freq pair and nulls still load,
    to the same values."""
    pytest.importorskip("stable_baselines3")
    from odomgym.baselines.selfcal_train import load_hyperparams, sb3_arguments

    for algo in ("ppo", "a2c", "dqn"):
        assert load_hyperparams(algo)["policy"] == "MlpPolicy"
    params = load_hyperparams("ppo", _hyperparams(tmp_path, "gamma: 1.0", "gamma: 0.99")[0])
    assert params["learning_rate"] == 0.0003 and params["gamma"] == 0.99
    assert params["env_kwargs"]["floors"] == ["concrete", "rough", "cables"]
    extra = "target_kl: null\n  clip_range_vf: 0.2\n  learning_rate: !!float 3e-4"
    path = _hyperparams(tmp_path, "learning_rate: 0.0003", extra, "ok.yml")[0]
    assert load_hyperparams("ppo", path)["learning_rate"] == 0.0003
    dqn = (
        "SelfCalibration-v1:\n  policy: MlpPolicy\n  train_freq: [1, episode]\n"
        "  gradient_steps: -1\n  policy_kwargs:\n    net_arch: [32]\n"
    )
    (tmp_path / "dqn.yml").write_text(dqn)
    loaded = load_hyperparams("dqn", tmp_path / "dqn.yml")
    assert loaded["train_freq"] == [1, "episode"]  # as YAML wrote it; train hands SB3 a tuple:
    assert sb3_arguments(loaded)["train_freq"] == (1, "episode")  # SB3 refuses the list
    # rl-zoo3 writes step counts as floats (`!!float 1.5e5`); train takes int() of them.
    zoo = _hyperparams(tmp_path, "n_timesteps: 150000", "n_timesteps: !!float 1.5e5", "zoo.yml")
    assert load_hyperparams("ppo", zoo[0])["n_timesteps"] == 150000.0
    half = _hyperparams(tmp_path, "n_timesteps: 150000", "n_timesteps: 1.5", "half.yml")
    with pytest.raises(SpecError, match=r"n_timesteps must be a whole number >= 1, got 1\.5"):
        load_hyperparams("ppo", half[0])


def test_ppo_with_a_one_transition_rollout_is_refused_before_any_work(tmp_path: Path) -> None:
    """n_steps × sessions = 1: PPO's constructor asserts (exit 3 before); now a SpecError
    naming n_steps, with no output folder made."""
    pytest.importorskip("stable_baselines3")
    from odomgym.baselines.selfcal_train import train

    path, _ = _hyperparams(tmp_path, "n_steps: 32 ", "n_steps: 1 ")
    out = tmp_path / "o"
    with pytest.raises(SpecError, match=r"n_steps × sessions = 1 × 1 must be >= 2") as caught:
        train(steps=8, envs=1, workers=1, out=out, hyperparams=path, progress=False)
    assert caught.value.field == "n_steps"
    assert not out.exists()


# ---------------------------------------------------------------- OptiOdom metadata units

SESSION = "square/230620202042"


def _session_with(tmp_path: Path, key: str, values: str) -> tuple[Path, Path, int]:
    """A copy of a shipped square session whose metadata row ``key`` holds ``values``: the
    session folder, its metadata file and the row's line."""
    source = sample_session(SESSION)
    folder = tmp_path / "square" / source.name
    shutil.copytree(source, folder)
    (meta,) = folder.glob("*_metadata.csv")
    lines = meta.read_text(encoding="utf-8-sig").splitlines()
    (index,) = [i for i, line in enumerate(lines) if line.split(",")[0] == key]
    width = lines[index].count(",")
    cells = values.split(",")
    lines[index] = ",".join([key, *cells, *[""] * (width - len(cells))])
    meta.write_text("\n".join(lines) + "\n")
    return folder, meta, index + 1


@pytest.mark.parametrize(
    ("key", "values", "says"),
    [
        ("Li", "200", "Li must lie in [0.02, 5.0] m (the wheelbase in metres), got 200.0"),
        ("Di", "84,84", "Di must lie in [0.005, 2.0] m"),
        ("Di", "0.084,84", "Di must lie in [0.005, 2.0] m"),
        ("encRes", "1e9", "ngear × encRes (counts per wheel revolution) must lie in"),
        ("ngear", "1e9", "ngear × encRes"),
        ("encRes", "1e-3", "got 43.7 × 0.001 = 0.0437"),
        ("L", "750", "L must lie in [0.00025, 250] m"),
    ],
)
def test_metadata_in_other_units_is_refused_at_its_line_under_its_key(
    key: str, values: str, says: str, tmp_path: Path
) -> None:
    """Millimetres for metres (Li 200, Di 84, L 750) or an encoder resolution off by 10^7 name
    the metadata file, the line and the metadata key, not RobotSpec's wheelbase or a route's
    'size' (which named neither file nor key)."""
    folder, meta, line = _session_with(tmp_path, key, values)
    with pytest.raises(SpecError) as caught:
        read_session(folder)
    message = str(caught.value)
    assert message.startswith(f"{meta}:{line}: "), message
    assert says in message, message
    assert caught.value.field == key


def test_calibrate_says_the_metadata_line_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The review's command: exit 2 with the metadata file's line, the side L of a square
    session in millimetres."""
    folder, meta, line = _session_with(tmp_path, "L", "750")
    code = main(["calibrate", "umbmark", "--data", str(folder)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith(f"odomgym: error: {meta}:{line}: L must lie in"), err


def test_valid_sessions_read_as_before(tmp_path: Path) -> None:
    """The shipped session's robot, initial calibration and runs are unchanged by the new
    checks: a copy reads identically, to the metadata's own values."""
    session = read_session(sample_session(SESSION))
    assert session.robot.wheelbase == 0.2 and session.robot.wheel_diameter == 0.084
    assert session.robot.ticks_per_rev == pytest.approx(43.7 * 64)
    assert session.side == 0.75 and session.n_runs == 6
    folder, _, _ = _session_with(tmp_path, "Li", "0.2")
    copy = read_session(folder)
    assert (copy.robot.wheelbase, copy.initial, copy.side) == (
        session.robot.wheelbase,
        session.initial,
        session.side,
    )
    for a, b in zip(copy.runs, session.runs, strict=True):
        assert (a.kind, a.direction, a.side) == (b.kind, b.direction, b.side)
        assert (a.counts == b.counts).all() and (a.true_pose == b.true_pose).all()

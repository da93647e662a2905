"""Training the self-calibration policy with stable-baselines3 (the ``rl`` extra).

:func:`train` steps :class:`odomgym.baselines.selfcal_vec_env.SelfCalVecEnv` (every session's
runs of a step in one physics batch, sessions split over worker shards), reads the
hyperparameters from ``odomgym/data/hyperparams/<algo>.yml``, files in rl-baselines3-zoo's own
format (one key per env id) that the zoo reads as they are (``python -m rl_zoo3.train …
-conf``): one source of truth, no second copy to drift, logs SB3's progress to
``progress.csv`` (and TensorBoard when it is installed), shows a tqdm progress bar, writes
checkpoints and resumes from them (:class:`odomgym.baselines.selfcal_checkpoints.Checkpoints`),
plots the learning curve and exports the policy network to the ``.npz`` file that
:class:`odomgym.baselines.selfcal.MlpPolicy` runs without torch.
"""

from __future__ import annotations

import importlib.util
import inspect
import json
import math
import os
import platform
import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym import interrupt
from odomgym.baselines.selfcal import MlpPolicy
from odomgym.baselines.selfcal_checkpoints import Checkpoints, write_json
from odomgym.baselines.selfcal_vec_env import SelfCalVecEnv
from odomgym.errors import SpecError
from odomgym.io import atomic_writer
from odomgym.selfcal.estimators import check_observe
from odomgym.selfcal.session import OBSERVATION_LAYOUT, OBSERVATION_VERSION

__all__ = [
    "ALGORITHMS",
    "CHECKPOINT_EVERY",
    "ENV_ID",
    "EVAL_SEEDS",
    "TrainResult",
    "evaluate",
    "export_policy",
    "load_hyperparams",
    "plot_learning_curve",
    "train",
]

ENV_ID = "SelfCalibration-v1"
"""The env the policy is trained in."""

ALGORITHMS = ("ppo", "a2c", "dqn")
"""SB3 algorithms that accept a ``Discrete`` action space (SAC and TD3 need ``Box``)."""

CHECKPOINT_EVERY = 10_000
"""Default environment steps between checkpoints: about two minutes of training on two cores."""

EVAL_SEEDS: tuple[int, ...] = tuple(range(10_000, 10_032))
"""The held-out sessions every trained policy is evaluated on (seeds never used in training,
which seeds sub-env i with seed + i for small seeds)."""


def load_hyperparams(algo: str, path: str | Path | None = None) -> dict[str, Any]:
    """The hyperparameters of ``algo`` for ``SelfCalibration-v1``: the ``SelfCalibration-v1``
    key of ``path``, a YAML file in rl-baselines3-zoo's format (default: the shipped
    ``odomgym/data/hyperparams/<algo>.yml``, which the zoo reads too)."""
    import yaml

    if algo not in ALGORITHMS:
        raise SpecError(
            f"unknown algorithm {algo!r}; algorithms for a Discrete action space: "
            f"{', '.join(ALGORITHMS)}",
            field="algo",
        )
    if path is None:
        text = (resources.files("odomgym.data.hyperparams") / f"{algo}.yml").read_text()
        source = f"{algo}.yml"
    else:
        source = str(path)
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise SpecError(f"{path}: cannot read ({exc.strerror})", field="hyperparams") from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        problem = " ".join(str(exc).split())
        raise SpecError(f"{source}: not valid YAML ({problem})", field="hyperparams") from None
    table = data.get(ENV_ID) if isinstance(data, dict) else None
    if not isinstance(table, dict):
        raise SpecError(f"{source}: no key {ENV_ID!r} (rl-zoo3 format)", field="hyperparams")
    return dict(table)


def export_policy(model: Any, meta: dict[str, Any]) -> MlpPolicy:
    """The deterministic policy of an SB3 PPO/A2C (tanh MLP + action head) or DQN (ReLU
    Q-network) model as a numpy :class:`MlpPolicy`."""
    import torch

    policy = model.policy
    if hasattr(policy, "q_net"):  # DQN: the greedy action of the Q-network
        layers = [m for m in policy.q_net.q_net if isinstance(m, torch.nn.Linear)]
        activation = "relu"
    else:
        layers = [m for m in policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
        layers.append(policy.action_net)
        name = type(policy.activation_fn()).__name__.lower() if policy.activation_fn else "tanh"
        activation = "relu" if name == "relu" else "tanh"
    weights = tuple(
        (
            layer.weight.detach().cpu().numpy().astype(np.float64),
            layer.bias.detach().cpu().numpy().astype(np.float64),
        )
        for layer in layers
    )
    return MlpPolicy(weights, {**meta, "activation": activation})


def evaluate(
    policy: Callable[[NDArray[np.float32]], NDArray[np.int64]],
    *,
    seeds: Sequence[int],
    env_kwargs: dict[str, Any] | None = None,
) -> dict[str, float]:
    """Mean terminal reward, validation improvement and runs of ``policy`` (a batch of
    observations → a batch of actions) on one session per seed (in one batch)."""
    venv = SelfCalVecEnv(len(seeds), env_kwargs=env_kwargs)
    try:
        venv.seed(0)
        venv._seeds = list(seeds)
        obs = np.asarray(venv.reset(), dtype=np.float32)
        done = np.zeros(len(seeds), dtype=bool)
        totals = np.zeros(len(seeds))
        finals: list[dict[str, Any]] = [{} for _ in seeds]
        while not done.all():
            actions = np.asarray(policy(obs)).reshape(-1)
            stepped, rewards, dones, infos = venv.step(actions)
            obs = np.asarray(stepped, dtype=np.float32)
            for i in np.flatnonzero(~done):
                totals[i] += rewards[i]
                if dones[i]:
                    finals[i] = infos[i]
            done |= dones
    finally:
        venv.close()
    improvement = [math.log(f["improvement"]) for f in finals if "improvement" in f]
    return {
        "reward_mean": float(totals.mean()),
        "log_improvement_mean": float(np.mean(improvement)) if improvement else float("nan"),
        "runs_mean": float(np.mean([f["runs_used"] for f in finals])),
        "travel_m_mean": float(np.mean([f["travel_m"] for f in finals])),
        "stop_first_rate": float(np.mean([f["runs_used"] == 0 for f in finals])),
        "failures": float(sum(1 for f in finals if "failed" in f)),
    }


@dataclass
class TrainResult:
    """What :func:`train` wrote and measured."""

    out: Path
    policy_file: Path
    model_file: Path
    wall_time_s: float
    steps: int
    evaluation: dict[str, float]
    written: list[Path] = field(default_factory=list)
    """Every file written, in this order: the numpy policy, the SB3 model, the policy's
    metadata, the learning curve's CSV and its plot."""


def _git_commit() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).resolve().parent,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def train(
    *,
    algo: str = "ppo",
    steps: int | None = None,
    envs: int | None = None,
    workers: int = 2,
    seed: int = 0,
    out: str | Path = "runs/selfcal",
    hyperparams: str | Path | None = None,
    progress: bool = True,
    eval_seeds: Sequence[int] = EVAL_SEEDS,
    command: str | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
    resume: bool = False,
) -> TrainResult:
    """Train a self-calibration policy and write it to ``out``.

    Writes ``model.zip`` (SB3), ``policy.npz`` (the numpy policy ``--policy`` accepts, with
    the command, versions and wall time in its metadata), ``policy.json`` (the same metadata),
    ``progress.csv`` and ``learning_curve.png``. ``steps``/``envs`` override the data file's
    ``n_timesteps``/``n_envs``.

    Every ``checkpoint_every`` steps a checkpoint is written (:class:`Checkpoints`); with
    ``resume`` the training goes on from the one in ``out`` to ``steps`` in all.
    """
    import stable_baselines3 as sb3
    import torch
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecMonitor
    from tqdm import tqdm

    params = load_hyperparams(algo, hyperparams)
    total = int(steps if steps is not None else params.pop("n_timesteps", 100_000))
    params.pop("n_timesteps", None)
    n_envs = int(envs if envs is not None else params.pop("n_envs", 8))
    params.pop("n_envs", None)
    env_kwargs = dict(params.pop("env_kwargs", {}))
    policy_name = params.pop("policy", "MlpPolicy")
    if total < 1:
        raise SpecError(f"steps must be >= 1, got {total}", field="steps")
    algorithm = getattr(sb3, algo.upper())
    takes = set(inspect.signature(algorithm).parameters) - {"self", "policy", "env"}
    unknown = sorted(set(params) - takes)
    if unknown:
        raise SpecError(
            f"{hyperparams or f'{algo}.yml'}: {algo} takes no hyperparameter {', '.join(unknown)}",
            field="hyperparams",
        )
    if checkpoint_every < 1:
        raise SpecError(
            f"checkpoint_every must be >= 1, got {checkpoint_every}", field="checkpoint"
        )
    folder = Path(out)
    torch.set_num_threads(1)  # the physics workers need the cores, the MLP does not
    rollout = int(params.get("n_steps", 0)) * n_envs
    if rollout and int(params.get("batch_size", 0)) > rollout:
        params["batch_size"] = rollout  # a short test run with few sessions: one mini-batch
    checkpoints = Checkpoints(folder)
    settings = json.loads(
        json.dumps(
            {"algo": algo, "n_envs": n_envs, "seed": seed, "policy": policy_name}
            | {"hyperparams": params, "env_kwargs": env_kwargs}
        )
    )
    record = checkpoints.read(settings) if resume else None
    folder.mkdir(parents=True, exist_ok=True)
    done = int(record["steps"]) if record else 0
    wall_before = float(record["wall_time_s"]) if record else 0.0
    resumed = [*record.get("resumed_at", []), done] if record else []
    if record:
        checkpoints.keep_progress(done)
    else:
        checkpoints.clear()
    venv = VecMonitor(SelfCalVecEnv(n_envs, workers=workers, env_kwargs=env_kwargs))
    venv.seed((seed + done) % 2**32)  # a resumed run: fresh sessions, not the first attempt's again
    start = time.perf_counter()

    def save_checkpoint(model: Any) -> None:
        wall_time_s = wall_before + time.perf_counter() - start
        checkpoints.save(model, settings, {"wall_time_s": wall_time_s, "resumed_at": resumed})

    class Progress(BaseCallback):
        """A tqdm bar, the sessions' terminal outcomes in the log, and the checkpoints."""

        def _on_training_start(self) -> None:
            self.bar = tqdm(
                total=total, initial=done, unit="step", desc=f"train {algo}", disable=not progress
            )
            self.saved = done

        def _on_rollout_start(self) -> None:
            # The last update is done here: the model is whole and its step count exact.
            if self.model.num_timesteps - self.saved >= checkpoint_every:
                save_checkpoint(self.model)
                self.saved = self.model.num_timesteps

        def _on_step(self) -> bool:
            interrupt.check()  # a stop request a finalizer swallowed (odomgym.interrupt)
            self.bar.update(self.training_env.num_envs)
            for info in self.locals.get("infos", []):
                if "improvement" in info:
                    self.logger.record_mean(
                        "selfcal/log_improvement", math.log(info["improvement"])
                    )
                    self.logger.record_mean("selfcal/runs_used", info["runs_used"])
                    self.logger.record_mean("selfcal/travel_m", info["travel_m"])
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    try:
        if record:
            model = algorithm.load(checkpoints.model, env=venv, device="cpu")
            if int(model.num_timesteps) != done:  # files mixed from two checkpoints by hand
                raise SpecError(
                    f"{checkpoints.record}: records {done} steps but checkpoint.zip holds "
                    f"{model.num_timesteps}; start without --resume",
                    field="resume",
                )
            model.set_random_seed((seed + done) % 2**32)
            if checkpoints.replay.exists():
                model.load_replay_buffer(checkpoints.replay)
        else:
            model = algorithm(policy_name, venv, seed=seed, verbose=0, device="cpu", **params)
        formats = ["csv"] + (["tensorboard"] if importlib.util.find_spec("tensorboard") else [])
        model.set_logger(configure(str(folder), formats))
        if done < total:
            model.learn(
                total_timesteps=total - done, callback=Progress(), reset_num_timesteps=not record
            )
    except OSError as exc:
        if exc.filename is not None:
            raise
        # SB3's logger (progress.csv, TensorBoard) names no file when a write fails.
        raise OSError(exc.errno, exc.strerror or str(exc), str(folder)) from exc
    finally:
        venv.close()
    wall = wall_before + time.perf_counter() - start
    model_file = folder / "model.zip"
    atomic_writer(model_file, model.save)  # SB3 writes the zip in place: renamed when whole
    meta = {
        "env_id": ENV_ID,
        "algo": algo,
        "command": command or "odomgym train selfcal " + shlex.join(sys.argv[1:]),
        "steps": total,
        "n_envs": n_envs,
        "workers": workers,
        "seed": seed,
        "wall_time_s": round(wall, 1),
        "resumed_at_steps": resumed,
        "cpus": os.cpu_count(),
        "machine": platform.platform(),
        "git_commit": _git_commit(),
        "versions": {
            "stable_baselines3": sb3.__version__,
            "torch": torch.__version__,
            "numpy": np.__version__,
        },
        "hyperparams": {k: v for k, v in params.items() if k != "policy_kwargs"}
        | {"policy_kwargs": json.loads(json.dumps(params.get("policy_kwargs", {})))},
        "env_kwargs": env_kwargs,
        "observe": check_observe(env_kwargs.get("observe", "trajectory")),
        "observation_version": OBSERVATION_VERSION,
        "observation_layout": list(OBSERVATION_LAYOUT),
    }
    exported = export_policy(model, meta)

    def predict(obs: NDArray[np.float32]) -> NDArray[np.int64]:
        actions: NDArray[np.int64] = np.argmax(exported.logits(obs), axis=-1)
        return actions

    evaluation = evaluate(predict, seeds=eval_seeds, env_kwargs=env_kwargs)
    exported = MlpPolicy(exported.weights, {**exported.meta, "evaluation": evaluation})
    policy_file = folder / "policy.npz"
    exported.save(policy_file)
    meta_file = folder / "policy.json"
    write_json(meta_file, exported.meta)
    checkpoints.finish()
    curve_csv, curve_png = folder / "progress.csv", folder / "learning_curve.png"
    plot_learning_curve(curve_csv, curve_png)
    written = [policy_file, model_file, meta_file, curve_csv, curve_png]
    return TrainResult(folder, policy_file, model_file, wall, total, evaluation, written)


def plot_learning_curve(csv_path: Path, png_path: Path) -> None:
    """Mean episode reward and log-improvement against environment steps, from SB3's
    ``progress.csv``."""
    import csv

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with csv_path.open() as f:
        rows = list(csv.DictReader(f))

    def column(name: str) -> tuple[list[float], list[float]]:
        xs, ys = [], []
        for row in rows:
            if row.get(name) and row.get("time/total_timesteps"):
                xs.append(float(row["time/total_timesteps"]))
                ys.append(float(row[name]))
        return xs, ys

    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for name, label in (
        ("rollout/ep_rew_mean", "episode reward"),
        ("selfcal/log_improvement", "ln(E_max before / after), validation"),
    ):
        xs, ys = column(name)
        if xs:
            ax.plot(xs, ys, label=label)
    ax.set_xlabel("environment steps (runs and stops)")
    ax.set_ylabel("nats")
    ax.set_title("SelfCalibration-v1 learning curve")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    try:
        atomic_writer(png_path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    finally:
        plt.close(fig)

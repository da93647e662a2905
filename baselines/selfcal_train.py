"""Training the self-calibration policy with stable-baselines3 (the ``rl`` extra).

:class:`SelfCalVecEnv` is an SB3 ``VecEnv`` of ``SelfCalibration-v1`` sessions that simulates
all their runs of a step as one physics batch per floor (:func:`odomgym.envs.selfcal.
step_episodes`; one physics batch per shard and step) — a batch of 8 costs about as much wall
time as 2 single runs — and splits the sessions over ``workers`` processes (shards) so both
cores simulate. Sub-env i is seeded ``seed + i``
and resets itself as SB3's ``DummyVecEnv`` does, so its episodes are the same whatever the
number of workers, and the same as a ``DummyVecEnv`` of single envs
(tests/test_selfcal_training.py).

:func:`train` reads the hyperparameters from ``odomgym/data/hyperparams/<algo>.yml``, files in
rl-baselines3-zoo's own format (one key per env id) that the zoo reads as they are
(``python -m rl_zoo3.train … -conf``): one source of truth, no second copy to drift,
logs SB3's progress to ``progress.csv`` (and TensorBoard when it is installed), shows a tqdm
progress bar, plots the learning curve and exports the policy network to the ``.npz`` file
that :class:`odomgym.baselines.selfcal.MlpPolicy` runs without torch.
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
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym import interrupt
from odomgym.baselines.selfcal import MlpPolicy
from odomgym.envs.selfcal import SelfCalibrationEnv, menu_index, step_episodes
from odomgym.errors import SpecError
from odomgym.io import atomic_write_text, atomic_writer
from odomgym.selfcal.session import OBSERVATION_LAYOUT, OBSERVATION_VERSION, check_observe
from odomgym.workers import Shards

try:
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv
except ImportError as exc:  # pragma: no cover - the rl extra is missing
    raise ImportError(
        "training needs stable-baselines3 and torch: pip install 'odomgym[rl]'"
    ) from exc

__all__ = [
    "ALGORITHMS",
    "CHECKPOINT_EVERY",
    "ENV_ID",
    "EVAL_SEEDS",
    "Checkpoints",
    "SelfCalVecEnv",
    "TrainResult",
    "evaluate",
    "export_policy",
    "load_hyperparams",
    "train",
]

ENV_ID = "SelfCalibration-v1"
ALGORITHMS = ("ppo", "a2c", "dqn")
CHECKPOINT_EVERY = 10_000
"""Default environment steps between checkpoints: about two minutes of training on two cores."""
"""SB3 algorithms that accept a ``Discrete`` action space (SAC and TD3 need ``Box``)."""

EVAL_SEEDS: tuple[int, ...] = tuple(range(10_000, 10_032))
"""The held-out sessions every trained policy is evaluated on (seeds never used in training,
which seeds sub-env i with seed + i for small seeds)."""

StepResult = tuple[NDArray[np.float32], float, bool, dict[str, Any]]


class _Batch:
    """Sessions stepped together in this process (SB3 reset semantics)."""

    def __init__(self, count: int, env_kwargs: dict[str, Any]) -> None:
        self.envs = [SelfCalibrationEnv(**env_kwargs) for _ in range(count)]

    def reset(
        self, seeds: Sequence[int | None], options: Sequence[dict[str, Any]]
    ) -> list[NDArray[np.float32]]:
        out = []
        for env, seed, opts in zip(self.envs, seeds, options, strict=True):
            obs, _ = env.reset(seed=seed, options=opts or None)
            out.append(obs)
        return out

    def step(self, actions: Sequence[int]) -> list[StepResult]:
        episodes = []
        for env in self.envs:
            assert env.episode is not None, "reset() first"
            episodes.append(env.episode)
        # SelfCalVecEnv.step_async has checked every action (menu_index) before any shard steps.
        results = step_episodes(episodes, list(actions), self.envs[0].shaping)
        out: list[StepResult] = []
        for env, (obs, reward, done, info) in zip(self.envs, results, strict=True):
            info["TimeLimit.truncated"] = False
            if done:
                info["terminal_observation"] = obs
                obs, _ = env.reset()
            out.append((obs, reward, done, info))
        return out

    def get_attr(self, name: str, indices: Sequence[int]) -> list[Any]:
        return [getattr(self.envs[i], name) for i in indices]

    def set_attr(self, name: str, value: Any, indices: Sequence[int]) -> None:
        for i in indices:
            setattr(self.envs[i], name, value)


def _worker(conn: Connection, count: int, env_kwargs: dict[str, Any]) -> None:
    import torch

    torch.set_num_threads(1)
    batch = _Batch(count, env_kwargs)
    while True:
        command, payload = conn.recv()
        if command == "close":
            conn.close()
            return
        try:
            conn.send(("ok", getattr(batch, command)(*payload)))
        except Exception as exc:  # reported to the parent, which raises it
            conn.send(("error", exc))


class SelfCalVecEnv(VecEnv):
    """``n_envs`` self-calibration sessions, their runs simulated in batches.

    Args:
        n_envs: sessions stepped together.
        workers: processes to split them over (1: this process).
        env_kwargs: keyword arguments of :class:`~odomgym.envs.selfcal.SelfCalibrationEnv`.
    """

    def __init__(
        self, n_envs: int, *, workers: int = 1, env_kwargs: dict[str, Any] | None = None
    ) -> None:
        for name, value in (("n_envs", n_envs), ("workers", workers)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise SpecError(f"{name} must be a whole number >= 1, got {value!r}", field=name)
        kwargs = dict(env_kwargs or {})
        known = set(inspect.signature(SelfCalibrationEnv).parameters)
        unknown = sorted(set(kwargs) - known)
        if unknown:
            raise SpecError(
                f"unknown env_kwargs {', '.join(unknown)}; SelfCalibration-v1 takes "
                f"{', '.join(sorted(known))}",
                field="env_kwargs",
            )
        probe = SelfCalibrationEnv(**kwargs)  # validates the settings here, in one line
        self._bounds = [
            (int(a[0]), int(a[-1]) + 1)
            for a in np.array_split(np.arange(n_envs), min(workers, n_envs))
        ]
        self._local: _Batch | None = None
        self._shards: Shards | None = None
        if len(self._bounds) == 1:
            self._local = _Batch(n_envs, kwargs)
        else:
            self._shards = Shards(_worker, [(hi - lo, kwargs) for lo, hi in self._bounds])
        self._actions: list[int] = []
        self.closed = False
        super().__init__(n_envs, probe.observation_space, probe.action_space)

    # ---------------------------------------------------------------- plumbing
    def _call(self, command: str, per_shard: Callable[[int, int], tuple[Any, ...]]) -> list[Any]:
        """Run ``command`` on every shard with its slice of the arguments; concatenated."""
        if self._local is not None:
            lo, hi = self._bounds[0]
            return list(getattr(self._local, command)(*per_shard(lo, hi)) or [])
        assert self._shards is not None
        values = self._shards.call(command, [per_shard(lo, hi) for lo, hi in self._bounds])
        return [item for value in values for item in (value or [])]

    def _indices(self, indices: Any) -> list[int]:
        return list(self._get_indices(indices))

    # ---------------------------------------------------------------- VecEnv API
    def reset(self) -> NDArray[np.float32]:
        seeds, options = list(self._seeds), list(self._options)
        obs = self._call("reset", lambda lo, hi: (seeds[lo:hi], options[lo:hi]))
        self._reset_seeds()
        self._reset_options()
        return np.stack(obs)

    def step_async(self, actions: NDArray[Any]) -> None:
        flat = np.asarray(actions).reshape(-1)
        if flat.size != self.num_envs:
            raise SpecError(
                f"need one action per session ({self.num_envs}), got {flat.size}", field="action"
            )
        self._actions = [menu_index(a) for a in flat]  # checked here, before any shard steps

    def step_wait(
        self,
    ) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.bool_], list[dict[str, Any]]]:
        actions = self._actions
        results = self._call("step", lambda lo, hi: (actions[lo:hi],))
        obs = np.stack([r[0] for r in results])
        rewards = np.array([r[1] for r in results], dtype=np.float32)
        dones = np.array([r[2] for r in results], dtype=bool)
        return obs, rewards, dones, [r[3] for r in results]

    def close(self) -> None:
        if self.closed:
            return
        if self._shards is not None:
            self._shards.close()
        self.closed = True

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        values = self._call("get_attr", lambda lo, hi: (attr_name, list(range(hi - lo))))
        return [values[i] for i in self._indices(indices)]  # in the order asked for

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        wanted = set(self._indices(indices))
        self._call(
            "set_attr",
            lambda lo, hi: (attr_name, value, [i - lo for i in range(lo, hi) if i in wanted]),
        )

    def env_method(
        self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any
    ) -> list[Any]:
        raise NotImplementedError(
            "SelfCalVecEnv steps its sessions together; call methods on SelfCalibrationEnv"
        )

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False for _ in self._indices(indices)]


# -------------------------------------------------------------------------------- training


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


class Checkpoints:
    """The checkpoint of an interrupted training in its output folder, and the resume.

    Every ``every`` environment steps (at the start of a rollout, when the last update is
    done) the model — weights, optimizer state, step count, and for DQN the replay buffer —
    is written to ``checkpoint.zip`` (``checkpoint_replay.pkl``) and its record to
    ``checkpoint.json``, each whole by a rename. ``--resume`` loads them and trains on to the
    same total; the settings that shape the model (algorithm, sessions, seed, hyperparameters)
    must match the record. The learning-curve rows logged before the checkpoint are kept in
    ``progress.prev.csv`` and joined with the new ones at the end.

    A resumed run is not bit-identical to an uninterrupted one: the sessions in flight at the
    checkpoint are started afresh (seeded ``seed + steps``), as SB3 keeps no env state.
    """

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.model = folder / "checkpoint.zip"
        self.record = folder / "checkpoint.json"
        self.replay = folder / "checkpoint_replay.pkl"
        self.progress = folder / "progress.csv"
        self.previous = folder / "progress.prev.csv"

    def read(self, settings: dict[str, Any]) -> dict[str, Any]:
        """The record of the checkpoint to resume from; one-line errors when there is none or
        it was made with other settings."""
        if not self.record.exists() or not self.model.exists():
            raise SpecError(
                f"{self.folder}: no checkpoint to resume from (checkpoint.json and "
                "checkpoint.zip); start without --resume",
                field="resume",
            )
        try:
            record = json.loads(self.record.read_text(encoding="utf-8"))
            steps = int(record["steps"])
            saved = dict(record["settings"])
            record["wall_time_s"] = float(record["wall_time_s"])
            record["resumed_at"] = [int(k) for k in record["resumed_at"]]
        except (ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
            raise SpecError(
                f"{self.record}: not a checkpoint record odomgym wrote ({exc})", field="resume"
            ) from exc
        differ = sorted(k for k in set(saved) | set(settings) if saved.get(k) != settings.get(k))
        if differ:
            shown = "; ".join(f"{k} {saved.get(k)!r} then, {settings.get(k)!r} now" for k in differ)
            raise SpecError(
                f"{self.record}: the checkpoint was made with other settings ({shown}); "
                "resume with the same --algo, --envs, --seed and --hyperparams",
                field="resume",
            )
        if steps < 0:
            raise SpecError(f"{self.record}: steps {steps} is negative", field="resume")
        return dict(record)

    def save(self, model: Any, settings: dict[str, Any], extra: dict[str, Any]) -> None:
        """Write the checkpoint of ``model`` now (each file whole, the record last, with
        ``extra`` in it)."""
        # The three files are one checkpoint: a stop between them would pair a new model with
        # an old record, so Ctrl-C/SIGTERM wait until all are written.
        with interrupt.deferred():
            atomic_writer(self.model, model.save)  # the temporary name ends in .zip, as SB3 needs
            if hasattr(model, "save_replay_buffer"):  # off-policy (DQN): its buffer is its data
                atomic_writer(self.replay, model.save_replay_buffer)
            record = {"steps": int(model.num_timesteps), **extra, "settings": settings}
            _write_json(self.record, record)

    def keep_progress(self, steps: int) -> None:
        """Before a resume: the learning-curve rows logged up to ``steps`` (of every earlier
        attempt) go to ``progress.prev.csv``; SB3 starts ``progress.csv`` afresh."""
        rows, fields = _csv_rows([self.previous, self.progress])
        rows = [r for r in rows if _timesteps(r) <= steps]
        _write_csv(self.previous, rows, fields)

    def finish(self) -> None:
        """After the final model is written: one ``progress.csv`` of every attempt, and no
        checkpoint left to resume from."""
        if self.previous.exists():
            rows, fields = _csv_rows([self.previous, self.progress])
            _write_csv(self.progress, rows, fields)
        self.clear()

    def clear(self) -> None:
        """No checkpoint left: after a finished training, or at a fresh start in a folder an
        earlier training left one in."""
        for path in (self.record, self.model, self.replay, self.previous):
            path.unlink(missing_ok=True)


def _timesteps(row: dict[str, str]) -> float:
    try:
        return float(row.get("time/total_timesteps") or "inf")
    except ValueError:
        return math.inf


def _csv_rows(paths: Sequence[Path]) -> tuple[list[dict[str, str]], list[str]]:
    import csv

    rows: list[dict[str, str]] = []
    fields: list[str] = []
    for path in paths:
        if not path.exists():
            continue
        with path.open(newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            fields += [k for k in reader.fieldnames or [] if k not in fields]
            rows += list(reader)
    return rows, fields


def _write_csv(path: Path, rows: list[dict[str, str]], fields: list[str]) -> None:
    import csv

    def write(tmp: Path) -> None:
        with tmp.open("w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=fields, restval="")
            writer.writeheader()
            writer.writerows(rows)

    atomic_writer(path, write)


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
    _write_json(meta_file, exported.meta)
    checkpoints.finish()
    curve_csv, curve_png = folder / "progress.csv", folder / "learning_curve.png"
    plot_learning_curve(curve_csv, curve_png)
    written = [policy_file, model_file, meta_file, curve_csv, curve_png]
    return TrainResult(folder, policy_file, model_file, wall, total, evaluation, written)


def _write_json(path: Path, data: dict[str, Any]) -> None:
    atomic_write_text(path, json.dumps(data, indent=2) + "\n")


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

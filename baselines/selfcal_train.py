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

import difflib
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
    "HYPERPARAM_CHECKS",
    "TrainResult",
    "check_hyperparams",
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
    ``odomgym/data/hyperparams/<algo>.yml``, which the zoo reads too).

    Every value is checked here (:func:`check_hyperparams`), so that a wrong one is refused
    in one line naming the file, its line and the key *before* training starts: SB3 checks
    some of them only in its constructor (``Invalid learning rate``, with no file) and others
    not at all until a rollout has been written (``n_epochs: ten``).
    """
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
    params = dict(table)
    check_hyperparams(algo, params, source=source, lines=_key_lines(yaml.compose(text)))
    return params


def _key_lines(document: Any) -> dict[str, int]:
    """The 1-based line of each key of the ``SelfCalibration-v1`` table, and of the keys of its
    ``env_kwargs`` and ``policy_kwargs`` tables as ``"env_kwargs.floors"``: PyYAML's plain
    load keeps no positions, its node graph (``yaml.compose``) does."""
    import yaml

    lines: dict[str, int] = {}

    def pairs(node: Any) -> list[tuple[Any, Any]]:
        if not isinstance(node, yaml.MappingNode):
            return []
        return [(k, v) for k, v in node.value if isinstance(k, yaml.ScalarNode)]

    for key, table in pairs(document):
        if key.value != ENV_ID:
            continue
        for name, value in pairs(table):
            lines[name.value] = name.start_mark.line + 1
            for inner, _ in pairs(value):
                lines[f"{name.value}.{inner.value}"] = inner.start_mark.line + 1
    return lines


_Check = Callable[[object], str | None]
"""A hyperparameter's check: what is wrong with a value (``"must be …, got …"``) or ``None``."""


def _shown(value: object) -> str:
    """``value`` as the message shows it, with a hint where YAML read a number as text."""
    if isinstance(value, str):
        try:
            float(value)
        except ValueError:
            if value.startswith(("lin_", "linear_")):
                return f"{value!r} (rl-zoo3's schedule; odomgym train takes a constant number)"
            return f"the text {value!r}"
        # YAML 1.1, which PyYAML and rl-zoo3 read, takes 3e-4 for text: it wants 3.0e-4.
        return (
            f"the text {value!r} (YAML reads an exponent without a dot as text: write it "
            "with one, e.g. 3.0e-4, or as 0.0003)"
        )
    return repr(value)


def _is_number(value: object) -> bool:
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(float(value))
    )


def _whole(minimum: int, *, also: int | None = None, written_as_float: bool = False) -> _Check:
    """A whole number >= ``minimum`` (or equal to ``also``, SB3's ``-1`` for "all"); with
    ``written_as_float`` also a float with no fraction (rl-zoo3's files write
    ``n_timesteps: !!float 1e6``, and it and ``train`` take ``int()`` of it)."""
    wanted = f"a whole number >= {minimum}" + (f" or {also}" if also is not None else "")

    def check(value: object) -> str | None:
        if written_as_float and isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, int) and not isinstance(value, bool):
            if value >= minimum or value == also:
                return None
        return f"must be {wanted}, got {_shown(value)}"

    return check


def _number(low: float, high: float = math.inf, *, open_low: bool = False) -> _Check:
    """A finite number in [low, high] (in (low, high] with ``open_low``)."""
    lower = "(" if open_low else "["
    wanted = (
        f"a number {'>' if open_low else '>='} {low:g}"
        if high == math.inf
        else f"a number in {lower}{low:g}, {high:g}]"
    )

    def check(value: object) -> str | None:
        if _is_number(value):
            number = float(value)  # type: ignore[arg-type]
            if (number > low if open_low else number >= low) and number <= high:
                return None
        return f"must be {wanted}, got {_shown(value)}"

    return check


def _optional(check: _Check) -> _Check:
    """``check``, or null (YAML ``null`` / ``~``: SB3's "off")."""

    def optional(value: object) -> str | None:
        problem = check(value)
        return None if value is None or problem is None else f"{problem} (or null)"

    return optional


def _flag(value: object) -> str | None:
    return None if isinstance(value, bool) else f"must be true or false, got {_shown(value)}"


def _null(what: str) -> _Check:
    """Only null: a Python class (a replay buffer, say) cannot be written in YAML."""

    def check(value: object) -> str | None:
        return None if value is None else f"must be null ({what}), got {_shown(value)}"

    return check


def _table(value: object) -> str | None:
    if value is None or isinstance(value, dict):
        return None
    return f"must be a table of keyword arguments (key: value lines), got {_shown(value)}"


def _train_freq(value: object) -> str | None:
    """DQN's ``train_freq``: a whole number of steps, or ``[n, step|episode]``."""
    if _whole(1)(value) is None:
        return None
    if (
        isinstance(value, list)
        and len(value) == 2
        and _whole(1)(value[0]) is None
        and value[1] in ("step", "episode")
    ):
        return None
    return f"must be a whole number >= 1 or [n, step] / [n, episode], got {_shown(value)}"


def _no_sde(value: object) -> str | None:
    if value is False:
        return None
    return f"must be false (gSDE needs a continuous action space; {ENV_ID}'s is Discrete), " + (
        f"got {_shown(value)}"
    )


_SET_BY_TRAIN = {
    "seed": "--seed sets it",
    "verbose": "odomgym train shows its own progress",
    "device": "odomgym train runs the small network on the CPU",
    "_init_setup_model": "odomgym train builds the model",
    "env": f"odomgym train makes the {ENV_ID} sessions",
}
"""Constructor arguments ``odomgym train`` passes itself: in the file they would clash."""

HYPERPARAM_CHECKS: dict[str, _Check] = {
    # odomgym's own keys (rl-zoo3's): the rest go to the SB3 algorithm's constructor.
    "n_timesteps": _whole(1, written_as_float=True),
    "n_envs": _whole(1, written_as_float=True),
    "env_kwargs": _table,
    "policy_kwargs": _table,
    # SB3 2.x (PPO, A2C, DQN), the constraints their documentation and asserts state.
    "learning_rate": _number(0.0, open_low=True),
    "n_steps": _whole(1),
    "batch_size": _whole(1),
    "n_epochs": _whole(1),
    "gamma": _number(0.0, 1.0),
    "gae_lambda": _number(0.0, 1.0),
    "clip_range": _number(0.0, open_low=True),
    "clip_range_vf": _optional(_number(0.0, open_low=True)),
    "normalize_advantage": _flag,
    "ent_coef": _number(0.0),
    "vf_coef": _number(0.0),
    "max_grad_norm": _number(0.0, open_low=True),
    "use_sde": _no_sde,
    "sde_sample_freq": _whole(1, also=-1),
    "rollout_buffer_class": _null("a Python class cannot be written in YAML"),
    "rollout_buffer_kwargs": _table,
    "target_kl": _optional(_number(0.0, open_low=True)),
    "stats_window_size": _whole(1),
    "tensorboard_log": _optional(lambda v: None if isinstance(v, str) else "must be a folder"),
    "rms_prop_eps": _number(0.0, open_low=True),
    "use_rms_prop": _flag,
    "buffer_size": _whole(1),
    "learning_starts": _whole(0),
    "tau": _number(0.0, 1.0, open_low=True),
    "train_freq": _train_freq,
    "gradient_steps": _whole(1, also=-1),
    "replay_buffer_class": _null("a Python class cannot be written in YAML"),
    "replay_buffer_kwargs": _table,
    "optimize_memory_usage": _flag,
    "target_update_interval": _whole(1),
    "exploration_fraction": _number(0.0, 1.0),
    "exploration_initial_eps": _number(0.0, 1.0),
    "exploration_final_eps": _number(0.0, 1.0),
}
"""The check of each hyperparameter a file may set (keys an algorithm does not take are
refused before these run; keys a newer SB3 adds pass unchecked)."""

_PER_ALGO: dict[str, dict[str, _Check]] = {
    # PPO asserts batch_size > 1 (SB3 issue 440: the advantage of one sample normalises to NaN).
    "ppo": {"batch_size": _whole(2)},
}


def check_hyperparams(
    algo: str, params: dict[str, Any], *, source: str, lines: dict[str, int] | None = None
) -> None:
    """Refuse a hyperparameter ``algo`` does not take or a value of the wrong type or range,
    in one line naming ``source``, the key's line (from ``lines``, see :func:`_key_lines`) and
    the key; ``env_kwargs`` are checked by :class:`~odomgym.envs.selfcal.SelfCalibrationEnv`
    itself, one key at a time so that the line is the key's.

    Raises:
        SpecError: with ``field`` the key (``env_kwargs.floors`` for an env setting).
    """
    lines = lines or {}

    def where(key: str) -> str:
        line = lines.get(key)
        return f"{source}:{line}" if line else source

    def refuse(key: str, message: str) -> None:
        raise SpecError(message, field=key, source=where(key))

    takes = _algorithm_keys(algo)
    for key, value in params.items():
        if not isinstance(key, str):
            refuse(str(key), f"key {key!r} is not a name")
        if key in _SET_BY_TRAIN:
            refuse(key, f"{key} cannot be set in the hyperparameter file: {_SET_BY_TRAIN[key]}")
        if takes is not None and key not in takes:
            allowed = sorted(takes - set(_SET_BY_TRAIN))
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f"did you mean {close[0]}? " if close else ""
            refuse(
                key,
                f"{key} is not a hyperparameter of {algo}; {hint}it takes {', '.join(allowed)}",
            )
        if key == "policy":
            if value != "MlpPolicy":
                refuse(
                    key,
                    "policy must be MlpPolicy (the observation is a flat vector, and "
                    f"odomgym exports an MLP), got {_shown(value)}",
                )
            continue
        check = _PER_ALGO.get(algo, {}).get(key) or HYPERPARAM_CHECKS.get(key)
        problem = check(value) if check else None
        if problem:
            refuse(key, f"{key} {problem}")
    _check_policy_kwargs(algo, params.get("policy_kwargs") or {}, refuse)
    _check_env_kwargs(params.get("env_kwargs") or {}, refuse)


def _algorithm_keys(algo: str) -> set[str] | None:
    """The keys a file may give ``algo``: rl-zoo3's own and the SB3 constructor's arguments
    (``None`` without SB3, whose absence the caller reports)."""
    try:
        import stable_baselines3 as sb3
    except ImportError:
        return None
    algorithm = getattr(sb3, algo.upper())
    constructor = set(inspect.signature(algorithm).parameters) - {"self", "policy"}
    return constructor | {"n_timesteps", "n_envs", "policy", "env_kwargs"}


def _check_policy_kwargs(
    algo: str, kwargs: dict[str, Any], refuse: Callable[[str, str], None]
) -> None:
    """``net_arch`` as whole layer widths (PPO/A2C: or ``{pi: […], vf: […]}``), and no key
    whose value would be a Python object (``activation_fn``, ``*_class``): YAML cannot give
    one, and rl-zoo3's ``"dict(…)"`` strings are Python, which odomgym does not run."""
    for key, value in kwargs.items():
        field = f"policy_kwargs.{key}"
        if key == "net_arch":
            widths = [value] if algo == "dqn" or isinstance(value, list) else None
            if algo != "dqn" and isinstance(value, dict):
                unknown = sorted(set(value) - {"pi", "vf"})
                if unknown:
                    refuse(field, f"{field} takes the keys pi and vf, got {', '.join(unknown)}")
                widths = list(value.values())
            good = widths is not None and all(
                isinstance(w, list) and all(_whole(1)(n) is None for n in w) for w in widths
            )
            if not good:
                refuse(
                    field,
                    f"{field} must be a list of layer widths (whole numbers >= 1), e.g. "
                    f"[64, 64]"
                    + ("" if algo == "dqn" else ", or {pi: [64, 64], vf: [64, 64]}")
                    + f", got {_shown(value)}",
                )
        elif key == "activation_fn" or key.endswith("_class"):
            refuse(
                field,
                f"{field} names a Python object, which a YAML file cannot give (the exported "
                "policy runs tanh for ppo/a2c and ReLU for dqn, SB3's defaults): leave it out",
            )


def _check_env_kwargs(kwargs: dict[str, Any], refuse: Callable[[str, str], None]) -> None:
    """Each ``env_kwargs`` key as :class:`~odomgym.envs.selfcal.SelfCalibrationEnv` checks it
    (alone, so that an error is at its own line), then all of them together."""
    from odomgym.envs.selfcal import SelfCalibrationEnv

    known = set(inspect.signature(SelfCalibrationEnv).parameters)
    for key, value in kwargs.items():
        field = f"env_kwargs.{key}"
        if key not in known:
            takes = ", ".join(sorted(known))
            refuse(field, f"{field}: {ENV_ID} takes no setting {key}; it takes {takes}")
        try:
            SelfCalibrationEnv(**{key: value})
        except SpecError as exc:
            refuse(field, f"{field}: {exc}")
    try:
        SelfCalibrationEnv(**kwargs)
    except SpecError as exc:
        refuse("env_kwargs", f"env_kwargs: {exc}")


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


def sb3_arguments(params: dict[str, Any]) -> dict[str, Any]:
    """``params`` as SB3's constructors take them: a ``train_freq`` written as a YAML list
    ``[n, step|episode]`` made the tuple SB3 needs (YAML has no tuple; SB3 refuses the list,
    "frequency … must be an integer"; rl-zoo3 converts it too)."""
    out = dict(params)
    if isinstance(out.get("train_freq"), list):
        out["train_freq"] = tuple(out["train_freq"])
    return out


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
    params = sb3_arguments(params)
    if total < 1:
        raise SpecError(f"steps must be >= 1, got {total}", field="steps")
    algorithm = getattr(sb3, algo.upper())  # load_hyperparams refused what it does not take
    rollout_steps = int(params.get("n_steps", 2048))
    if algo == "ppo" and rollout_steps * n_envs < 2 and params.get("normalize_advantage", True):
        # PPO asserts this in its constructor: one transition's advantage normalises to NaN.
        raise SpecError(
            f"n_steps × sessions = {rollout_steps} × {n_envs} must be >= 2 for ppo (one "
            "transition per rollout cannot have its advantage normalised): raise n_steps in "
            f"{hyperparams or f'{algo}.yml'} or --envs",
            field="n_steps",
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

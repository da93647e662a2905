"""The self-calibration sessions as a stable-baselines3 ``VecEnv`` (the ``rl`` extra), in a module
of its own as SB3 keeps its VecEnvs.

:class:`SelfCalVecEnv` steps ``SelfCalibration-v1`` sessions and simulates all their runs of a
step as one physics batch per floor (:func:`odomgym.selfcal.episodes.step_episodes`; one physics
batch per shard and step) — a batch of 8 costs about as much wall time as 2 single runs — and
splits the sessions over ``workers`` processes (shards) so both cores simulate. Sub-env i is
seeded ``seed + i`` and resets itself as SB3's ``DummyVecEnv`` does, so its episodes are the same
whatever the number of workers, and the same as a ``DummyVecEnv`` of single envs
(tests/test_selfcal_training.py).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.envs.selfcal import SelfCalibrationEnv, menu_index
from odomgym.errors import SpecError
from odomgym.selfcal.episodes import step_episodes
from odomgym.workers import Shards

try:
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv
except ImportError as exc:  # pragma: no cover - the rl extra is missing
    raise ImportError(
        "training needs stable-baselines3 and torch: pip install 'odomgym[rl]'"
    ) from exc

__all__ = ["SelfCalVecEnv"]

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

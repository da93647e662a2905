"""Compile odomgym's numba kernels once, into numba's on-disk cache, before anything else runs.

    python scripts/warm_kernels.py          # after a fresh install (a venv, a Docker image)

Why: every kernel (:mod:`odomgym._jit`) is compiled on its first call with given argument
types and cached on disk next to its module, so a fresh install pays the compilation once —
but two processes that start at the same time (pytest's xdist workers, a fleet's worker
processes) each compile the same kernels before either has written them to the cache. In the
test command's fast lane that was about 40 s of CPU in each of the two workers. This script
makes the calls that compile the common kernels, in one process: every registered env reset
and stepped (its vector env too; the CLAPPER's among them), a skid-steer preset in the square
env, every catalogue effect the World injects, and one blind diagnosis of simulated logs (the
filter, the replays, the open-loop fits and the discovery's term replays). Kernels it misses
are compiled where they are first called, as before; nothing it computes is kept.

Its output: one line per part with its time [s], then the total.
"""

from __future__ import annotations

import time
import warnings
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import gymnasium


def _envs() -> None:
    """Every registered odomgym env: make, reset, a few steps; its vector env where it has one."""
    import gymnasium as gym

    import odomgym  # noqa: F401  (registers the envs)

    ids = sorted(i for i, s in gym.registry.items() if str(s.entry_point).startswith("odomgym."))
    for env_id in ids:
        _steps(gym.make(env_id))
        if gym.registry[env_id].vector_entry_point:
            vec = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
            vec.action_space.seed(0)
            vec.reset(seed=0)
            vec.step(vec.action_space.sample())
            vec.close()


def _steps(env: gymnasium.Env[Any, Any], count: int = 3) -> None:
    """``count`` seeded random steps of ``env`` (reset again where an episode ends: a
    self-calibration session may end on its first action), then close it."""
    env.action_space.seed(0)
    env.reset(seed=0)
    for _ in range(count):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    env.close()


def _skid_steer() -> None:
    """A skid-steer preset driven in the square env (its four contacts' kernels)."""
    import gymnasium as gym

    _steps(gym.make("UMBmarkSquare-v0", robot="scout2"))


def _effects() -> None:
    """Every catalogue effect the World injects, on the bumpy (cable-strewn) floor: one short
    straight run of a robot carrying each effect at three times its detection limit."""
    import numpy as np

    from odomgym.diagnose.generate import NOMINAL_ROBOT, hidden_effect
    from odomgym.effects import EFFECTS, catalogue
    from odomgym.floor import load_floor
    from odomgym.sim.route_runs import simulate_runs
    from odomgym.sim.routes import straight_route

    rng = np.random.default_rng(0)
    robot = NOMINAL_ROBOT
    for name in catalogue():
        robot = EFFECTS[name].write(robot, hidden_effect(name, 3.0, "rich", rng))
    simulate_runs(robot, load_floor("bumpy"), straight_route(1.0), rng=rng, kind="straight")


def _diagnosis() -> None:
    """One blind diagnosis of simulated logs with a hidden wheelbase error."""
    from odomgym.diagnose.generate import hidden_effect_trial

    hidden_effect_trial("wheelbase", "rich", seed=0)


def main() -> None:
    """Run the parts in order, each timed. Gymnasium's deprecation notices (``SelfCalibration-
    v0``) are silenced; numba's warnings are not (one that it cannot cache a kernel would make
    this script useless)."""
    import gymnasium  # noqa: F401  (its logger sets a DeprecationWarning filter on import)

    warnings.simplefilter("ignore", DeprecationWarning)
    start = time.perf_counter()
    for name, part in (
        ("envs", _envs),
        ("skid-steer", _skid_steer),
        ("effects", _effects),
        ("diagnose", _diagnosis),
    ):
        t = time.perf_counter()
        part()
        print(f"warm_kernels: {name} {time.perf_counter() - t:.1f} s", flush=True)
    print(f"warm_kernels: total {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()

"""Speed of odomgym's simulator, measured side by side with references in one run.

    python benchmarks/bench_speed.py [--json] [--robots 256] [--seconds 2]

Figures (the project's targets in brackets):
1. one LabMate 4×4 m UMBmark run with the reference driver, simulated time / wall time
   [≥ 1000× real time on one core];
2. env steps per second of ``UMBmarkSquare-v0`` against Gymnasium's ``LunarLander-v3``, both
   through ``gymnasium.make`` with random actions [ratio ≥ 2.0];
3. robot-steps per second of the native vector env, and against ``SyncVectorEnv`` over the
   single env, at N robots [≥ 1 M robot-steps/s and ratio ≥ 20 at 256];
4. the CLAPPER's 36 m straight out and back (Borenstein 1995, §6.1) with IPEC on and twenty
   cables on the concrete floor, simulated time / wall time [≥ 500× real time], beside the
   same run with IPEC off.

Compilation of the numba kernels happens once, before timing; its cost is printed separately.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from typing import Any

import gymnasium as gym
import numpy as np

import odomgym
from odomgym.floor import FLOORS
from odomgym.lab import simulate_runs
from odomgym.routes import square_route


def umbmark_run(repeats: int = 5) -> dict[str, float]:
    robot = odomgym.PRESETS["labmate"]
    start = time.perf_counter()
    simulate_runs(robot, FLOORS["smooth"], square_route(4.0, "cw"))  # compiles the kernels
    compile_s = time.perf_counter() - start
    best = float("inf")
    simulated = 0.0
    for _ in range(repeats):
        start = time.perf_counter()
        runs, _ = simulate_runs(robot, FLOORS["smooth"], square_route(4.0, "cw"))
        best = min(best, time.perf_counter() - start)
        simulated = float(runs[0].time[-1])
    return {
        "first_call_s": compile_s,
        "simulated_s": simulated,
        "wall_s": best,
        "real_time_factor": simulated / best,
    }


def clapper_run(repeats: int = 5) -> dict[str, float]:
    """The 36 m straight out and back with IPEC (``recommended``) and 20 cables, best of
    ``repeats``, and the same without IPEC (the estimator's share of the time)."""
    from odomgym.clapper import CLAPPER_FLOOR, CableLayer, drive_vehicles, evenly, straight_path
    from odomgym.ipec import ipec_estimator
    from odomgym.vehicle import load_vehicle

    spec = load_vehicle("clapper")
    floor = FLOORS[CLAPPER_FLOOR]
    out: dict[str, float] = {}
    for label, estimator in (
        ("ipec", ipec_estimator(rotary_resolution=spec.rotary_resolution)),
        ("no_ipec", None),
    ):
        best, simulated = float("inf"), 0.0
        for k in range(repeats + 1):  # the first run compiles and warms up
            start = time.perf_counter()
            outcome = drive_vehicles(
                spec,
                floor,
                straight_path(18.0),
                estimator=estimator,
                cables=CableLayer(evenly(20)),
                rng=np.random.default_rng(k),
            )
            wall = time.perf_counter() - start
            if k:
                best = min(best, wall)
            simulated = outcome.time
        out[f"{label}_wall_s"] = best
        out[f"{label}_real_time_factor"] = simulated / best
        out["simulated_s"] = simulated
    return out


def env_steps_per_second(env_id: str, seconds: float, **kwargs: Any) -> float:
    """Steps per second through ``gymnasium.make`` (with its default wrappers).

    Random actions are drawn from the env's own action space *before* timing, so the figure
    measures the env, not the sampler (a Box sample costs more than a Discrete one).
    """
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(1000)]
    for action in actions[:200]:  # warm-up (and JIT)
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    steps = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        steps += len(actions)
    return steps / (time.perf_counter() - start)


def vector_robot_steps_per_second(num_envs: int, mode: str, seconds: float) -> float:
    envs = gym.make_vec("UMBmarkSquare-v0", num_envs=num_envs, vectorization_mode=mode)
    envs.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(num_envs, 2)).astype(np.float32)
    for _ in range(5):
        envs.step(actions)
    steps = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        envs.step(actions)
        steps += 1
    elapsed = time.perf_counter() - start
    envs.close()
    return steps * num_envs / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--robots", type=int, default=256)
    parser.add_argument("--seconds", type=float, default=2.0)
    args = parser.parse_args()

    run = umbmark_run()
    ours = env_steps_per_second("UMBmarkSquare-v0", args.seconds)
    lunar = env_steps_per_second("LunarLander-v3", args.seconds)
    native = vector_robot_steps_per_second(args.robots, "vector_entry_point", args.seconds)
    sync = vector_robot_steps_per_second(args.robots, "sync", args.seconds)
    clapper = clapper_run()
    result = {
        "machine": {"cpu_count": os.cpu_count(), "python": platform.python_version()},
        "umbmark_run": run,
        "env_steps_per_s": {
            "UMBmarkSquare-v0": ours,
            "LunarLander-v3": lunar,
            "ratio": ours / lunar,
        },
        "vector_robot_steps_per_s": {
            "robots": args.robots,
            "native": native,
            "sync": sync,
            "ratio": native / sync,
        },
        "clapper_straight": clapper,
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"machine: {os.cpu_count()} cores, Python {platform.python_version()}")
    print(
        f"UMBmark 4x4 m run (LabMate, reference driver): {run['simulated_s']:.1f} s simulated in "
        f"{1e3 * run['wall_s']:.1f} ms -> {run['real_time_factor']:.0f}x real time "
        f"(first call incl. compilation {run['first_call_s']:.2f} s)   [target >= 1000x]"
    )
    print(
        f"env steps/s: UMBmarkSquare-v0 {ours:,.0f} vs LunarLander-v3 {lunar:,.0f} "
        f"-> ratio {ours / lunar:.2f}   [target >= 2.0]"
    )
    print(
        f"robot-steps/s at {args.robots} robots: native vector env {native:,.0f} vs "
        f"SyncVectorEnv {sync:,.0f} -> ratio {native / sync:.1f}   "
        "[targets >= 1,000,000 and >= 20 at 256]"
    )
    print(
        f"CLAPPER 36 m straight, 20 cables, concrete: {clapper['simulated_s']:.1f} s simulated "
        f"in {1e3 * clapper['ipec_wall_s']:.0f} ms with IPEC -> "
        f"{clapper['ipec_real_time_factor']:.0f}x real time (without IPEC "
        f"{clapper['no_ipec_real_time_factor']:.0f}x)   [target >= 500x]"
    )


if __name__ == "__main__":
    main()

"""Speed of odomgym's simulator, measured side by side with references in one run.

    python benchmarks/bench_speed.py [--json] [--robots 256] [--seconds 2]
        [--limit-robots 16 256 1024]

Figures (the project's targets in brackets):
1. one LabMate 4×4 m UMBmark run with the reference driver, simulated time / wall time
   [≥ 1000× real time on one core];
2. env steps per second of ``UMBmarkSquare-v0`` against Gymnasium's ``LunarLander-v3``, both
   through ``gymnasium.make`` with random actions [ratio ≥ 2.0];
3. robot-steps per second of the native vector env, and against ``SyncVectorEnv`` over the
   single env, at N robots [≥ 1 M robot-steps/s and ratio ≥ 20 at 256];
4. the CLAPPER's 36 m straight out and back (Borenstein 1995, §6.1) with IPEC on and twenty
   cables on the concrete floor, simulated time / wall time [≥ 500× real time], beside the
   same run with IPEC off;
5. against the physical limit: Chipmunk's own step (``cpSpaceStep`` × substeps, called through
   pymunk's cffi library) of the very space the env's World steps, timed interleaved in blocks
   with ``World.step`` and ``env.step`` of that env (``gymnasium.make``, pre-sampled actions),
   medians of the per-step times [``env.step`` ≤ 10×, ``World.step`` ≤ 4× the limit];
6. the same for the native vector env at 16, 256 and 1024 robots, per robot-step [≤ 1.5× the
   limit at 256], beside its World alone;
7. a skid-steer robot-step (the ``scout2`` preset: four friction-limited contacts) against a
   differential-drive one of the same size and mass (``scout2`` on one axle), through
   ``gymnasium.make`` and in the native vector env at ``--robots``, timed interleaved
   [≤ 3×].

No pymunk robot steps faster than Chipmunk's step of its space, so 5 and 6 measure what odomgym
adds around it. Every figure of one run comes from one process on one machine; ratios are
measured side by side because the machine's load moves absolute figures by tens of percent.

Compilation of the numba kernels happens once, before timing; its cost is printed separately.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import time
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import pymunk.batch

import odomgym
from odomgym.floor import FLOORS
from odomgym.sim.route_runs import simulate_runs
from odomgym.sim.routes import square_route
from odomgym.sim.world import World


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
    from odomgym.vehicle.cable_layout import CableLayer, evenly
    from odomgym.vehicle.ipec import ipec_estimator
    from odomgym.vehicle.paths import straight_path
    from odomgym.vehicle.spec import load_vehicle
    from odomgym.vehicle.trial import CLAPPER_FLOOR, drive_vehicles

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


# Chipmunk's C library as pymunk's own ``Space.step`` calls it: the limit below which no pymunk
# robot steps (pymunk's wrapper adds a Python loop over new bodies and a lock around the call).
_CP_SPACE_STEP = pymunk.batch.lib.cpSpaceStep


def _interleaved_medians(
    blocks: dict[str, Callable[[], int]], seconds: float, min_rounds: int = 15
) -> dict[str, float]:
    """Median seconds per step of each block: the blocks run one after another in rounds (the
    order rotating), so all of them see the same machine load; each returns its step count."""
    per_step: dict[str, list[float]] = {name: [] for name in blocks}
    names = list(blocks)
    start = time.perf_counter()
    rounds = 0
    while rounds < min_rounds or time.perf_counter() - start < seconds:
        for name in names[rounds % len(names) :] + names[: rounds % len(names)]:
            begin = time.perf_counter()
            steps = blocks[name]()
            per_step[name].append((time.perf_counter() - begin) / steps)
        rounds += 1
    return {name: statistics.median(times) for name, times in per_step.items()}


def _limit_block(world: World, steps: int) -> int:
    """``steps`` control periods of Chipmunk's own step on ``world``'s space; returns ``steps``.

    The bodies keep the velocities the World last gave them, so the solver does the same work
    as inside :meth:`World.step` (two saturating or not pivot joints per robot)."""
    raw_space = world.space._space  # the cpSpace* pymunk's Space.step passes to Chipmunk
    h = world.dt / world.substeps
    for _ in range(steps * world.substeps):
        _CP_SPACE_STEP(raw_space, h)
    return steps


def single_env_limit(seconds: float, block: int = 500) -> dict[str, float]:
    """``env.step`` of ``UMBmarkSquare-v0`` through ``gymnasium.make`` (its wrappers included)
    and ``World.step`` of that env's own World, against Chipmunk's step of that World's space.

    Per step [µs] and the ratios to the limit. The World is stepped outside the env (its state
    moves on under the env's odometry, which does not change the cost of a step); a reset builds
    a new World, so every block looks the World up again.
    """
    env = gym.make("UMBmarkSquare-v0")
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(block)]
    # World.step takes (N, 2) float64 commands in [-1, 1] times each robot's top wheel rate,
    # which is what the env passes it after checking an action.
    commands = [np.asarray(a, dtype=np.float64).reshape(1, 2) for a in actions]
    unwrapped = env.unwrapped

    def world() -> World:
        return unwrapped._trial.world  # type: ignore[attr-defined, no-any-return]

    def env_block() -> int:
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        return len(actions)

    def world_block() -> int:
        w = world()
        for command in commands:
            w.step(command, w.max_rate)
        return len(commands)

    blocks = {
        "env_step": env_block,
        "world_step": world_block,
        "limit": lambda: _limit_block(world(), block),
    }
    for run in blocks.values():  # warm-up (and JIT)
        run()
    median = _interleaved_medians(blocks, seconds)
    env.close()
    return {
        "limit_us": 1e6 * median["limit"],
        "world_step_us": 1e6 * median["world_step"],
        "env_step_us": 1e6 * median["env_step"],
        "world_ratio": median["world_step"] / median["limit"],
        "env_ratio": median["env_step"] / median["limit"],
    }


def vector_env_limit(num_envs: int, seconds: float) -> dict[str, float]:
    """The native vector env's ``step`` and its World's, per robot-step, against Chipmunk's
    step of that World's space; pre-sampled random actions."""
    envs = gym.make_vec(
        "UMBmarkSquare-v0", num_envs=num_envs, vectorization_mode="vector_entry_point"
    )
    envs.reset(seed=0)
    block = max(10, 8192 // num_envs)  # a few ms per block
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-1, 1, size=(num_envs, 2)).astype(np.float32) for _ in range(block)]
    commands = [a.astype(np.float64) for a in actions]
    unwrapped = envs.unwrapped
    world: World = unwrapped._trial.world  # type: ignore[attr-defined]  # reset steps build none

    def env_block() -> int:
        for action in actions:
            envs.step(action)
        return len(actions)

    def world_block() -> int:
        for command in commands:
            world.step(command, world.max_rate)
        return len(commands)

    blocks = {
        "env_step": env_block,
        "world_step": world_block,
        "limit": lambda: _limit_block(world, block),
    }
    for run in blocks.values():
        run()
    median = _interleaved_medians(blocks, seconds)
    envs.close()
    return {
        "robots": num_envs,
        "limit_us_per_robot_step": 1e6 * median["limit"] / num_envs,
        "world_us_per_robot_step": 1e6 * median["world_step"] / num_envs,
        "env_us_per_robot_step": 1e6 * median["env_step"] / num_envs,
        "env_robot_steps_per_s": num_envs / median["env_step"],
        "world_robot_steps_per_s": num_envs / median["world_step"],
        "world_ratio": median["world_step"] / median["limit"],
        "env_ratio": median["env_step"] / median["limit"],
    }


def skid_steer_cost(num_envs: int, seconds: float) -> dict[str, float]:
    """Seconds per robot-step of ``UMBmarkSquare-v0`` with the ``scout2`` preset and with the
    same robot on one axle (differential drive, casters under the rest), single env and native
    vector env, and their ratios; blocks interleaved so both see the same load."""
    skid = odomgym.PRESETS["scout2"]
    diff = dataclasses.replace(
        skid,
        axle_spacing=0.0,
        drive_load_fraction=0.9,
        tyre_slip_stiffness=0.0,
        tyre_cornering_stiffness=0.0,
        name="scout2-diff",
    )
    rng = np.random.default_rng(0)
    blocks: dict[str, Callable[[], int]] = {}
    closers = []
    for label, robot in (("skid", skid), ("diff", diff)):
        single = gym.make("UMBmarkSquare-v0", robot=robot, side=1.0)
        single.reset(seed=0)
        vector = gym.make_vec("UMBmarkSquare-v0", num_envs=num_envs, robot=robot, side=1.0)
        vector.reset(seed=0)
        one = [rng.uniform(-1, 1, size=2).astype(np.float32) for _ in range(500)]
        many = [rng.uniform(-1, 1, size=(num_envs, 2)).astype(np.float32) for _ in range(20)]

        def single_block(env: Any = single, actions: list[Any] = one) -> int:
            for action in actions:
                _, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    env.reset()
            return len(actions)

        def vector_block(env: Any = vector, actions: list[Any] = many) -> int:
            for action in actions:
                env.step(action)
            return len(actions) * num_envs

        blocks[f"{label}_single"] = single_block
        blocks[f"{label}_vector"] = vector_block
        closers += [single, vector]
    for run in blocks.values():
        run()
    median = _interleaved_medians(blocks, seconds)
    for env in closers:
        env.close()
    return {
        "robots": num_envs,
        "single_skid_us": 1e6 * median["skid_single"],
        "single_diff_us": 1e6 * median["diff_single"],
        "single_ratio": median["skid_single"] / median["diff_single"],
        "vector_skid_us_per_robot_step": 1e6 * median["skid_vector"],
        "vector_diff_us_per_robot_step": 1e6 * median["diff_vector"],
        "vector_ratio": median["skid_vector"] / median["diff_vector"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--robots", type=int, default=256)
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--limit-robots", type=int, nargs="+", default=[16, 256, 1024])
    args = parser.parse_args()

    run = umbmark_run()
    ours = env_steps_per_second("UMBmarkSquare-v0", args.seconds)
    lunar = env_steps_per_second("LunarLander-v3", args.seconds)
    native = vector_robot_steps_per_second(args.robots, "vector_entry_point", args.seconds)
    sync = vector_robot_steps_per_second(args.robots, "sync", args.seconds)
    clapper = clapper_run()
    single = single_env_limit(args.seconds)
    vector = {n: vector_env_limit(n, args.seconds) for n in args.limit_robots}
    skid = skid_steer_cost(args.robots, args.seconds)
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
        "limit_single_env": single,
        "limit_vector_env": {str(n): row for n, row in vector.items()},
        "skid_steer_cost": skid,
    }
    rows: list[tuple[str, str, str, bool | None]] = [
        (
            "UMBmark 4x4 m run (LabMate, reference driver)",
            f"{run['real_time_factor']:.0f}x real time ({run['simulated_s']:.1f} s in "
            f"{1e3 * run['wall_s']:.1f} ms; first call {run['first_call_s']:.2f} s)",
            ">= 1000x",
            run["real_time_factor"] >= 1000,
        ),
        (
            "env steps/s, UMBmarkSquare-v0 vs LunarLander-v3",
            f"{ours:,.0f} vs {lunar:,.0f} -> {ours / lunar:.2f}",
            ">= 2.0",
            ours / lunar >= 2.0,
        ),
        (
            f"robot-steps/s at {args.robots} robots, native vector env",
            f"{native:,.0f}",
            ">= 1,000,000" if args.robots == 256 else "-",
            native >= 1e6 if args.robots == 256 else None,
        ),
        (
            "  the same against SyncVectorEnv",
            f"{sync:,.0f} -> {native / sync:.1f}x",
            ">= 20x" if args.robots == 256 else "-",
            native / sync >= 20 if args.robots == 256 else None,
        ),
        (
            "CLAPPER 36 m straight, 20 cables, concrete, IPEC on (off)",
            f"{clapper['ipec_real_time_factor']:.0f}x ({clapper['no_ipec_real_time_factor']:.0f}x)"
            f" real time, {1e3 * clapper['ipec_wall_s']:.0f} ms for {clapper['simulated_s']:.1f} s",
            ">= 500x",
            clapper["ipec_real_time_factor"] >= 500,
        ),
        (
            "the limit: cpSpaceStep x substeps, single env's space",
            f"{single['limit_us']:.2f} us/step",
            "1x",
            None,
        ),
        (
            "  World.step (physics core, no env)",
            f"{single['world_step_us']:.2f} us -> {single['world_ratio']:.1f}x",
            "<= 4x",
            single["world_ratio"] <= 4.0,
        ),
        (
            "  env.step through gymnasium.make",
            f"{single['env_step_us']:.2f} us -> {single['env_ratio']:.1f}x",
            "<= 10x",
            single["env_ratio"] <= 10.0,
        ),
    ]
    for n, row in vector.items():
        rows += [
            (
                f"the limit at {n} robots (per robot-step)",
                f"{1e3 * row['limit_us_per_robot_step']:.0f} ns",
                "1x",
                None,
            ),
            (
                f"  native vector env, {n} robots",
                f"{1e3 * row['env_us_per_robot_step']:.0f} ns "
                f"({row['env_robot_steps_per_s'] / 1e6:.2f} M robot-steps/s) "
                f"-> {row['env_ratio']:.2f}x",
                "<= 1.5x" if n == 256 else "-",
                row["env_ratio"] <= 1.5 if n == 256 else None,
            ),
            (
                f"  its World alone, {n} robots",
                f"{1e3 * row['world_us_per_robot_step']:.0f} ns "
                f"({row['world_robot_steps_per_s'] / 1e6:.2f} M robot-steps/s) "
                f"-> {row['world_ratio']:.2f}x",
                "-",
                None,
            ),
        ]
    rows += [
        (
            "skid-steer robot-step (scout2) vs differential, env.step",
            f"{skid['single_skid_us']:.1f} vs {skid['single_diff_us']:.1f} us "
            f"-> {skid['single_ratio']:.2f}x",
            "<= 3x",
            skid["single_ratio"] <= 3.0,
        ),
        (
            f"  the same in the native vector env, {args.robots} robots",
            f"{1e3 * skid['vector_skid_us_per_robot_step']:.0f} vs "
            f"{1e3 * skid['vector_diff_us_per_robot_step']:.0f} ns -> {skid['vector_ratio']:.2f}x",
            "<= 3x",
            skid["vector_ratio"] <= 3.0,
        ),
    ]
    result["rows"] = [
        {"figure": figure, "measured": measured, "target": target, "met": met}
        for figure, measured, target, met in rows
    ]
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"machine: {os.cpu_count()} cores, Python {platform.python_version()}")
    width = max(len(figure) for figure, *_ in rows)
    for figure, measured, target, met in rows:
        verdict = "" if met is None else ("met" if met else "MISSED")
        print(f"{figure:<{width}}  {measured:<62} {target:<12} {verdict}")


if __name__ == "__main__":
    main()

"""Soak: a million env steps at the extremes that validation accepts, and 10⁵ resets.

    python benchmarks/soak.py                      # 10⁶ robot-steps, 10⁵ resets
    python benchmarks/soak.py --steps 100000 --resets 10000 --json

Robots at the edges of ``odomgym.robot.ROBOT_RANGES`` (the smallest and the largest robot, the
fastest wheels with the hardest accelerations, wheel diameters and wheelbase 0.5 and 2 × their
nominal values), on floors at the edges of ``FloorSpec`` (μ = 0.05, the largest roughness
k = 0.1 m^½, dense random cables), driven by random wheel commands through the native vector env
of ``UMBmarkSquare-v0``. Printed per configuration, and as totals:

* NaN or infinite values in observations, rewards and ``info`` poses (must be 0);
* observations outside the observation space (must be 0);
* the largest body speed seen over what the wheels can give (max_wheel_speed × the larger true
  over nominal diameter): above 1 means energy from nowhere, except on rough floors, whose
  noise adds k·√(|v|·h)·ξ of ground travel per step by design (Chong & Kleeman 1997, Eq. 4;
  ±1.0 m/s of body speed at 10 m/s with k = 0.1 m^½ and h = 50 ms);
* the largest distance from the start over what that speed allows in the time driven;

then the memory growth over the resets (``ru_maxrss`` after the first 10 % and at the end).
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from typing import Any

import gymnasium as gym
import numpy as np

import odomgym
from odomgym.floor import MAX_ROUGHNESS, FloorSpec
from odomgym.robot import ROBOT_RANGES, RobotSpec


def robots() -> dict[str, RobotSpec]:
    """The extreme robots."""
    lo = {k: v[0] for k, v in ROBOT_RANGES.items()}
    hi = {k: v[1] for k, v in ROBOT_RANGES.items()}
    small = RobotSpec(
        wheel_diameter=lo["wheel_diameter"] * 2,
        wheelbase=lo["wheelbase"],
        ticks_per_rev=lo["ticks_per_rev"] * 16,
        mass=lo["mass"],
        chassis_length=lo["wheelbase"],
        chassis_width=lo["wheelbase"],
        max_wheel_speed=hi["max_wheel_speed"],
        max_wheel_accel=hi["max_wheel_accel"],
        name="smallest-fastest",
    )
    large = RobotSpec(
        wheel_diameter=hi["wheel_diameter"] / 2,
        wheelbase=hi["wheelbase"] / 2,
        ticks_per_rev=hi["ticks_per_rev"],
        mass=hi["mass"],
        chassis_length=hi["chassis_length"] / 4,
        chassis_width=hi["chassis_width"] / 4,
        max_wheel_speed=hi["max_wheel_speed"],
        max_wheel_accel=hi["max_wheel_accel"],
        name="largest-fastest",
    )
    lopsided = odomgym.PRESETS["labmate"].with_errors(e_d=1.9, e_b=0.55, e_s=1.0)
    lopsided = RobotSpec(
        **{
            **lopsided.to_dict(),
            "max_wheel_speed": hi["max_wheel_speed"],
            "max_wheel_accel": hi["max_wheel_accel"],
            "name": "lopsided-fastest",
        }
    )
    return {r.name: r for r in (small, large, lopsided)}


def floors() -> dict[str, FloorSpec]:
    """The extreme floors."""
    cables = FloorSpec.scattered_cables(
        np.random.default_rng(0), half_size=30.0, per_square_metre=5.0, friction=0.05, name="x"
    )
    return {
        "ice+cables": FloorSpec(friction=0.05, bumps=cables.bumps, name="ice+cables"),
        "roughest": FloorSpec(friction=0.8, roughness=MAX_ROUGHNESS, name="roughest"),
        "ice+rough": FloorSpec(friction=0.05, roughness=0.05, name="ice+rough"),
    }


def soak(robot: RobotSpec, floor: FloorSpec, steps: int, n: int, seed: int) -> dict[str, Any]:
    env = gym.make_vec("UMBmarkSquare-v0", num_envs=n, robot=robot, floor=floor)
    space = env.single_observation_space
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    dt = float(env.unwrapped.dt) if hasattr(env.unwrapped, "dt") else 0.05
    ratio = max(robot.true_left_diameter, robot.true_right_diameter) / robot.wheel_diameter
    top_speed = robot.max_wheel_speed * ratio  # [m/s]
    bad_values = outside = 0
    fastest = 0.0
    farthest = 0.0
    start = np.array(info["true_pose"])[:, :2]
    elapsed = np.zeros(n)
    previous = start.copy()
    resetting = np.zeros(n, dtype=bool)  # NEXT_STEP autoreset: this step only resets them
    action = np.ones((n, 2), dtype=np.float32)
    for _ in range(max(1, steps // n)):
        # Hold each robot's command for ~20 steps (so it can reach full speed), then switch,
        # a third of the time to full opposite commands: the hardest accelerations.
        switch = rng.random(n) < 0.05
        fresh = rng.uniform(-1.0, 1.0, size=(n, 2)).astype(np.float32)
        bang = rng.random(n) < 0.3
        fresh[bang] = np.sign(fresh[bang])
        action[switch] = fresh[switch]
        obs, reward, terminated, truncated, info = env.step(action)
        pose = np.asarray(info["true_pose"], dtype=float)
        values = [obs, reward, pose, np.asarray(info["odom_pose"], dtype=float)]
        bad_values += int(sum(int(np.count_nonzero(~np.isfinite(v))) for v in values))
        outside += int(sum(not space.contains(o) for o in obs))
        live = ~resetting
        elapsed[live] += dt
        if live.any():
            moved = np.hypot(*(pose[:, :2] - previous).T)[live]
            fastest = max(fastest, float(np.max(moved)) / dt)
            reach = np.hypot(*(pose[:, :2] - start).T)[live]
            farthest = max(farthest, float(np.max(reach / (top_speed * elapsed[live]))))
        start[resetting] = pose[resetting, :2]
        elapsed[resetting] = 0.0
        previous = pose[:, :2].copy()
        resetting = np.asarray(terminated) | np.asarray(truncated)
    env.close()
    return {
        "robot": robot.name,
        "floor": floor.name,
        "steps": max(1, steps // n) * n,
        "nonfinite": bad_values,
        "outside_space": outside,
        "speed_over_wheels": fastest / top_speed,
        "reach_over_possible": farthest,
    }


def resets(count: int) -> dict[str, Any]:
    env = gym.make("UMBmarkSquare-v0", robot="labmate", floor="concrete")
    tenth = max(1, count // 10)
    start = time.perf_counter()
    early = 0
    for k in range(count):
        env.reset(seed=k)
        if k == tenth:
            early = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    late = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    env.close()
    return {
        "resets": count,
        "seconds": round(time.perf_counter() - start, 1),
        "maxrss_after_10pct_mb": early / 1024,
        "maxrss_end_mb": late / 1024,
        "growth_mb": (late - early) / 1024,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=1_000_000, help="robot-steps in total")
    parser.add_argument("--resets", type=int, default=100_000, help="single-env resets")
    parser.add_argument("--envs", type=int, default=32, help="robots per vector env")
    parser.add_argument("--json", action="store_true", help="JSON lines")
    args = parser.parse_args()
    configs = [(r, f) for r in robots().values() for f in floors().values()]
    per = args.steps // len(configs)
    results = []
    start = time.perf_counter()
    for k, (robot, floor) in enumerate(configs):
        result = soak(robot, floor, per, args.envs, seed=k)
        results.append(result)
        print(
            json.dumps(result)
            if args.json
            else f"{result['robot']:<18} {result['floor']:<11} {result['steps']:>8} steps  "
            f"non-finite {result['nonfinite']}  outside {result['outside_space']}  "
            f"speed/wheels {result['speed_over_wheels']:.2f}  "
            f"reach/possible {result['reach_over_possible']:.2f}",
            flush=True,
        )
    total = {
        "steps": sum(r["steps"] for r in results),
        "nonfinite": sum(r["nonfinite"] for r in results),
        "outside_space": sum(r["outside_space"] for r in results),
        "seconds": round(time.perf_counter() - start, 1),
    }
    memory = resets(args.resets)
    if args.json:
        print(json.dumps({"total": total, "resets": memory}))
    else:
        print(
            f"total: {total['steps']} steps in {total['seconds']} s, non-finite "
            f"{total['nonfinite']}, outside the space {total['outside_space']}"
        )
        print(
            f"resets: {memory['resets']} in {memory['seconds']} s; max RSS "
            f"{memory['maxrss_after_10pct_mb']:.0f} MB after 10 %, {memory['maxrss_end_mb']:.0f} "
            f"MB at the end (growth {memory['growth_mb']:.1f} MB)"
        )
    return 0 if total["nonfinite"] == 0 and total["outside_space"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())

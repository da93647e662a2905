"""Logs of a simulated robot carrying a hidden effect, for proving the workflow.

:func:`simulate_protocol` drives a robot spec (with whatever effects it carries) through the pymunk
World under one of two documented protocols and returns runs as a tracking system would log them
(the tracked point with Gaussian sensor noise on every logged row):

* ``"rich"`` — the characterisation protocol: 1.5 m squares (2 cw, 2 ccw, by odometry with the
  reference driver at 0.2 m/s), 3 m straights out and back in reverse (2) and one way (2),
  in-place turns of 90°, 180° and 360° both ways at wheel speeds 0.1 and 0.3 m/s (12), and
  half circles of 1 m radius both ways at 0.15 and 0.35 m/s (4, open-loop wheel commands);
  ground truth at every 50 ms sample;
* ``"umbmark"`` — 5 cw + 5 ccw 1.5 m squares, ground truth at the first and last rows only.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.floor import FloorSpec
from odomgym.lab import simulate_runs
from odomgym.paths import spin_route, square_route, straight_route
from odomgym.physics import World
from odomgym.robot import RobotSpec
from odomgym.runs import Direction, Run

__all__ = ["Protocol", "simulate_protocol"]

FloatArray = NDArray[np.float64]
Protocol = Literal["rich", "umbmark"]
_DIRECTIONS: tuple[Direction, ...] = ("cw", "ccw")


def _arc(
    robot: RobotSpec, radius: float, speed: float, sign: float, rng: np.random.Generator
) -> Run:
    """An open-loop half circle: ramp up, hold (v, ω = v/R), ramp down, at 20 Hz."""
    dt = 0.05
    world = World(robot, FloorSpec(), dt=dt, rng=rng)
    half_b = 0.5 * robot.wheelbase
    r_nom = 0.5 * robot.wheel_diameter
    omega = sign * speed / radius
    rates = np.array([speed - omega * half_b, speed + omega * half_b]) / r_nom
    hold = round((math.pi * radius / speed) / dt)
    ramp = 20
    profile = np.concatenate([np.linspace(0.05, 1, ramp), np.ones(hold), np.linspace(1, 0, ramp)])
    profile = np.concatenate([profile, np.zeros(10)])
    times, counts, poses = [0.0], [world.counts[0].copy()], [world.tracked_pose()[0]]
    for f in profile:
        world.step((rates * f)[None, :])
        times.append(world.time)
        counts.append(world.counts[0].copy())
        poses.append(world.tracked_pose()[0])
    return Run("free", np.array(times), np.array(counts), np.array(poses))


def simulate_protocol(
    robot: RobotSpec,
    protocol: Protocol,
    rng: np.random.Generator,
    *,
    sensor: tuple[float, float] = (0.001, 0.002),
    floor: FloorSpec | None = None,
) -> list[Run]:
    """Runs of ``robot`` under ``protocol`` (module docstring), logged with sensor noise
    ``sensor`` = (position σ [m], heading σ [rad])."""
    ground = floor if floor is not None else FloorSpec()
    plans: list[tuple[str, list[Run]]] = []
    if protocol == "umbmark":
        for d in _DIRECTIONS:
            runs, _ = simulate_runs(robot, ground, square_route(1.5, d), rng=rng, repeats=5)
            plans.append((f"square_{d}", runs))
    else:
        for d in _DIRECTIONS:
            runs, _ = simulate_runs(robot, ground, square_route(1.5, d), rng=rng, repeats=2)
            plans.append((f"square_{d}", runs))
        runs, _ = simulate_runs(robot, ground, straight_route(3.0, True), rng=rng, repeats=2)
        plans.append(("straight_return", runs))
        runs, _ = simulate_runs(robot, ground, straight_route(3.0), rng=rng, repeats=2)
        plans.append(("straight_oneway", runs))
        for speed, tag in ((0.1, "slow"), (0.3, "fast")):
            for angle in (90, 180, 360):
                for d in _DIRECTIONS:
                    runs, _ = simulate_runs(
                        robot,
                        ground,
                        spin_route(math.radians(angle), d),
                        rng=rng,
                        cruise_speed=min(speed, robot.max_wheel_speed),
                    )
                    plans.append((f"spin_{d}_{angle}_{tag}", runs))
        for speed, tag in ((0.15, "slow"), (0.35, "fast")):
            for sign, d in ((-1.0, "cw"), (1.0, "ccw")):
                plans.append((f"arc_{d}_{tag}", [_arc(robot, 1.0, speed, sign, rng)]))
    out: list[Run] = []
    for label, runs in plans:
        for run in runs:
            pose = run.true_pose + rng.standard_normal(run.true_pose.shape) * np.array(
                [sensor[0], sensor[0], sensor[1]]
            )
            if protocol == "umbmark":
                pose[1:-1] = np.nan
            out.append(
                Run(
                    run.kind,
                    run.time,
                    run.counts,
                    pose,
                    run.direction,
                    run.side,
                    source="sim",
                    meta={"run": f"{len(out) + 1:03d}", "experiment": label},
                )
            )
    return out

"""Steady turns in the World: the apparent track a robot's odometry would need.

A robot commanded with the wheel rates of a turn of radius R at speed v (rims at v ∓ ω·b/2, or
at ∓v for a spin) settles into a steady circle. Its *apparent track* is the track for which the
kinematic odometry ω = (v_R − v_L)/b_app gives the yaw rate it really turned at: b_app =
(v_R − v_L)/ω. Over the true track b it is the expansion factor χ = b_app/b of the skid-steer
literature (Mandow et al. 2007: the ICRs of the two sides at ±χ·b/2; Wang et al. 2015: the "ICR
coefficient"). For a differential-drive robot that does not slip it is 1.

Used by ``tests/test_skid.py`` and ``examples/skid_icr.py`` (docs/skid-steer.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from odomgym.floor import FLOORS, FloorSpec
from odomgym.robot import RobotSpec
from odomgym.sim.world import World

__all__ = ["SteadyTurn", "steady_turn"]


@dataclass(frozen=True)
class SteadyTurn:
    """One steady turn, averaged over its second half.

    Attributes:
        factor: apparent over true track, (v_R − v_L)/(ω·b) [-].
        radius: radius of the circle the reported point drove, |v|/|ω| [m] (0 for a spin).
        yaw_rate: ω [rad/s].
        speed: |v| of the reported point [m/s].
    """

    factor: float
    radius: float
    yaw_rate: float
    speed: float


def steady_turn(
    robot: RobotSpec,
    speed: float,
    radius: float,
    floor: FloorSpec | None = None,
    *,
    seconds: float = 12.0,
    dt: float = 0.05,
) -> SteadyTurn:
    """Drive ``robot`` from rest with the wheel rates of a turn of ``radius`` [m] at ``speed``
    [m/s] (``radius = 0``: a spin, the rims at ∓``speed``) on ``floor`` (default ``smooth``)
    for ``seconds``, and measure the turn over its second half (the first half lets the wheel
    controllers and the chassis settle)."""
    if not (math.isfinite(speed) and speed > 0.0):
        raise ValueError(f"speed must be a positive number of m/s, got {speed!r}")
    if not (math.isfinite(radius) and radius >= 0.0):
        raise ValueError(f"radius must be >= 0 m (0: a spin), got {radius!r}")
    world = World(robot, floor if floor is not None else FLOORS["smooth"], dt=dt)
    b = float(robot.true_wheelbase)
    if radius == 0.0:
        left, right = -speed, speed
    else:
        omega = speed / radius
        left, right = speed - 0.5 * omega * b, speed + 0.5 * omega * b
    if max(abs(left), abs(right)) > robot.max_wheel_speed:
        raise ValueError(
            f"a turn of radius {radius} m at {speed} m/s asks a wheel for "
            f"{max(abs(left), abs(right)):.3g} m/s, more than the robot's max_wheel_speed "
            f"{robot.max_wheel_speed} m/s (the controller would clip it and drive another turn)"
        )
    r = 0.5 * float(robot.wheel_diameter)
    command = np.array([[left / r, right / r]])
    steps = round(seconds / dt)
    yaw, travel = [], []
    for step in range(steps):
        world.step(command)
        if step >= steps // 2:
            yaw.append(float(world.velocity[0, 2]))
            travel.append(math.hypot(float(world.velocity[0, 0]), float(world.velocity[0, 1])))
    yaw_rate = float(np.mean(yaw))
    mean_speed = float(np.mean(travel))
    return SteadyTurn(
        factor=(right - left) / (yaw_rate * b),
        radius=mean_speed / abs(yaw_rate),
        yaw_rate=yaw_rate,
        speed=mean_speed,
    )

"""Steady turns in the World: the apparent track a robot's odometry would need.

A robot commanded with the wheel rates of a turn of radius R at speed v (rims at v ∓ ω·b/2, or
at ∓v for a spin) settles into a steady circle. Its *apparent track* is the track for which the
kinematic odometry ω = (v_R − v_L)/b_app gives the yaw rate it really turned at: b_app =
(v_R − v_L)/ω. Over the true track b it is the expansion factor χ = b_app/b of the skid-steer
literature (Mandow et al. 2007: the ICRs of the two sides at ±χ·b/2; Wang et al. 2015: the "ICR
coefficient"). For a differential-drive robot that does not slip it is 1.

:func:`contact_steady_turn` is the reference the World is checked against: the same robot's
steady circle solved directly from its contacts' force law (:func:`contact_forces`: Coulomb's
μ·N_i opposite the slip for rigid contacts, the elastic-then-sliding law for tyres with
stiffness), the loads of :meth:`odomgym.robot.RobotSpec.contact_loads`. For rigid contacts in
a slow spin it is the closed form b·(1 + (a/b)²).

Used by ``tests/test_skid.py`` and ``examples/skid_icr.py`` (docs/skid-steer.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from odomgym.floor import FLOORS, FloorSpec
from odomgym.robot import RobotSpec
from odomgym.sim.world import SKID_CREEP, World

__all__ = ["SteadyTurn", "contact_forces", "contact_steady_turn", "steady_turn"]


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
    rng: np.random.Generator | None = None,
) -> SteadyTurn:
    """Drive ``robot`` from rest with the wheel rates of a turn of ``radius`` [m] at ``speed``
    [m/s] (``radius = 0``: a spin, the rims at ∓``speed``) on ``floor`` (default ``smooth``)
    for ``seconds``, and measure the turn over its second half (the first half lets the wheel
    controllers and the chassis settle). ``rng``: the texture of a rough floor (and a noisy
    robot's noise) is drawn from it; required there, as by :class:`~odomgym.sim.world.World`."""
    if not (math.isfinite(speed) and speed > 0.0):
        raise ValueError(f"speed must be a positive number of m/s, got {speed!r}")
    if not (math.isfinite(radius) and radius >= 0.0):
        raise ValueError(f"radius must be >= 0 m (0: a spin), got {radius!r}")
    world = World(robot, floor if floor is not None else FLOORS["smooth"], dt=dt, rng=rng)
    b = float(robot.true_wheelbase)
    left, right = _rims(robot, speed, radius)
    # Wheel rates from the *true* radii, so that the rims turn at exactly these speeds; the
    # controller clips a rate at max_wheel_speed over the *nominal* radius.
    command = np.array(
        [[2.0 * left / robot.true_left_diameter, 2.0 * right / robot.true_right_diameter]]
    )
    top_rate = robot.max_wheel_speed / (0.5 * robot.wheel_diameter)
    if float(np.max(np.abs(command))) > top_rate:
        raise ValueError(
            f"a turn of radius {radius} m at {speed} m/s asks a wheel for "
            f"{max(abs(left), abs(right)):.3g} m/s, more than the robot's max_wheel_speed "
            f"{robot.max_wheel_speed} m/s (the controller would clip it and drive another turn)"
        )
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


def _rims(robot: RobotSpec, speed: float, radius: float) -> tuple[float, float]:
    """Left and right rim speeds [m/s] of a turn of ``radius`` at ``speed`` (0: a spin)."""
    if radius == 0.0:
        return -speed, speed
    omega = speed / radius
    half = 0.5 * float(robot.true_wheelbase)
    return speed - omega * half, speed + omega * half


def contact_forces(
    robot: RobotSpec,
    slip: np.ndarray,
    rim: np.ndarray,
    friction: float,
    loads: np.ndarray,
    *,
    floor_creep: float = SKID_CREEP,
) -> np.ndarray:
    """Each contact's force [N] (n, 2), body frame, for its slip ``slip`` (n, 2) [m/s] against
    its side's rim speed ``rim`` (n,) [m/s] under loads ``loads`` (n,) [N]: the law of
    :func:`odomgym.sim.world.skid_contacts`, written again in numpy for the reference
    (``floor_creep``: the least creep speed; the World's ``SKID_CREEP``)."""
    limit = friction * loads
    speed = np.hypot(slip[:, 0], slip[:, 1])
    if robot.tyre_slip_stiffness == 0.0:
        rigid: np.ndarray = -(limit / np.maximum(speed, floor_creep))[:, None] * slip
        return rigid
    ex = np.maximum(friction * np.abs(rim) / robot.tyre_slip_stiffness, floor_creep)
    ey = np.maximum(friction * np.abs(rim) / robot.tyre_cornering_stiffness, floor_creep)
    w = np.column_stack((slip[:, 0] / ex, slip[:, 1] / ey))
    kappa = np.hypot(w[:, 0], w[:, 1])
    elastic = np.where(kappa <= 1.0, 1.0, 1.0 / np.maximum(kappa, 1.0) ** 2)
    sliding = np.where(kappa <= 1.0, 0.0, 1.0 - 1.0 / np.maximum(kappa, 1.0))
    direction = slip / np.maximum(speed, 1e-300)[:, None]
    force: np.ndarray = -limit[:, None] * (elastic[:, None] * w + sliding[:, None] * direction)
    return force


def contact_steady_turn(
    robot: RobotSpec, speed: float, radius: float, friction: float, *, gravity: float = 9.81
) -> SteadyTurn:
    """The steady circle of ``robot`` under its contacts' force law, solved directly.

    Unknowns: the body-frame velocity (u, v) of the centre of mass and the yaw rate ω. Contact i
    at (x_i, y_i) slides at s_i = (u − ω·y_i − g_i, v + ω·x_i), with g_i its side's rim speed,
    and is pushed by :func:`contact_forces` (for rigid contacts −μ·N_i·s_i/|s_i|, regularised
    below 10⁻⁷ m/s). In a steady circle the forces supply the centripetal acceleration, Σf =
    m·(−ω·v, ω·u), and the yaw moment is zero. The wheel commands are those
    :func:`steady_turn` gives (rims at v ∓ ω·b/2)."""
    left, right = _rims(robot, speed, radius)
    contacts = robot.contacts()
    loads = np.asarray(robot.contact_loads(gravity))
    mass = float(robot.mass)
    xy = np.array([(x, y) for _, x, y in contacts])
    rim = np.array([left if side == 0 else right for side, _, _ in contacts])
    creep = 1e-7 if robot.tyre_slip_stiffness == 0.0 else SKID_CREEP

    def residual(q: np.ndarray) -> np.ndarray:
        u, v, omega = q
        slip = np.column_stack((u - omega * xy[:, 1] - rim, v + omega * xy[:, 0]))
        force = contact_forces(robot, slip, rim, friction, loads, floor_creep=creep)
        total = force.sum(axis=0)
        moment = float(np.sum(xy[:, 0] * force[:, 1] - xy[:, 1] * force[:, 0]))
        return np.array([total[0] + mass * omega * v, total[1] - mass * omega * u, moment])

    kinematic = (right - left) / float(robot.true_wheelbase)
    best = None
    for share in (0.5, 0.7, 0.9):  # the yaw rate lies below the no-slip one: start there
        for lateral in (0.0, -0.1 * speed, 0.1 * speed):
            start = np.array([0.5 * (left + right), lateral, share * kinematic])
            fit = least_squares(residual, start, xtol=1e-14, ftol=1e-14, gtol=1e-14)
            if best is None or fit.cost < best.cost:
                best = fit
    assert best is not None
    u, v, omega = (float(x) for x in best.x)
    travel = math.hypot(u, v)
    return SteadyTurn(
        factor=(right - left) / (omega * float(robot.true_wheelbase)),
        radius=travel / abs(omega),
        yaw_rate=omega,
        speed=travel,
    )

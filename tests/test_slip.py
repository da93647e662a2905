"""Issue #2 must-pass 4: slip is physical — it emerges from the friction limit, not a script."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from odomgym.floor import FloorSpec
from odomgym.robot import PRESETS, RobotSpec
from odomgym.sim.route_runs import simulate_runs
from odomgym.sim.routes import Route, square_route, straight_route
from odomgym.sim.world import World

CAREFUL = PRESETS["labmate"].ideal()  # 1 m/s² wheel acceleration limit
HARD = dataclasses.replace(CAREFUL, max_wheel_accel=6.0)  # a "bang-bang" controller


def _end_error(robot: RobotSpec, friction: float, route: Route, speed: float) -> float:
    runs, odom = simulate_runs(robot, FloorSpec(friction=friction), route, cruise_speed=speed)
    error = runs[0].true_pose[-1] - odom[0]
    return math.hypot(error[0], error[1])


def test_careful_driving_does_not_slip() -> None:
    """0.2 m/s on μ = 0.8: the slip-induced error is below 1 mm per leg."""
    assert _end_error(CAREFUL, 0.8, straight_route(4.0), 0.2) < 0.001
    assert _end_error(CAREFUL, 0.8, square_route(4.0, "cw"), 0.2) < 4 * 0.001


@pytest.mark.parametrize(
    ("robot", "friction", "route"),
    [
        (HARD, 0.8, square_route(4.0, "cw")),  # hard accelerations: the turns slip
        (CAREFUL, 0.2, square_route(4.0, "ccw")),  # slippery floor: the turns slip
        (HARD, 0.2, straight_route(4.0)),  # both: even straight starts and stops slip
    ],
    ids=["hard-accel-mu0.8-square", "mu0.2-square", "hard-accel-mu0.2-straight"],
)
def test_slip_error_grows_with_speed(robot: RobotSpec, friction: float, route: Route) -> None:
    errors = [_end_error(robot, friction, route, speed) for speed in (0.2, 0.3, 0.4)]
    assert errors[0] < errors[1] < errors[2]
    assert errors[2] > 0.01  # centimetres, against sub-millimetre when nothing slips


def test_slip_only_when_friction_saturates() -> None:
    """A 1 m/s step command with a 6 m/s² controller: on μ = 0.8 (force limit 7 m/s² of
    grip) the wheels never slip (World.slip < 1 µm); on μ = 0.05 they slip by centimetres."""
    for friction, expect_slip in ((0.8, False), (0.05, True)):
        world = World(HARD, FloorSpec(friction=friction), track_slip=True)
        rate = 1.0 / (0.5 * HARD.wheel_diameter)  # 1 m/s rim speed, commanded as a step
        for _ in range(20):
            world.step(np.array([[rate, rate]]))
        slipped = float(world.slip.max())
        if expect_slip:
            assert slipped > 0.01
        else:
            assert slipped < 1e-6

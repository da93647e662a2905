"""The independent skid-steer robot (``tests/independent_skid.py``): rigid wheels on Coulomb
friction, checked against the closed forms it must meet before the diagnosis is tried on it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from independent_skid import CoulombSkidRobot, generate_skid, skid_protocol
from module_imports import module_imports


@pytest.mark.parametrize("radius", [0.0, 0.1, 0.25, 1.0, 4.0])
def test_apparent_track_is_one_plus_a_over_b_squared_at_every_radius(radius: float) -> None:
    """Equal loads on rigid Coulomb wheels: χ = 1 + (a/B)² in a spin and on every arc, and no
    sideways slip of the centre (v_y = 0: the sides' ICRs lie abreast of it). The same χ
    follows in closed form for a linear friction law (moment balance: ω = B·(u_R − u_L)/(a² +
    B²)); Coulomb's saturated forces keep it."""
    robot = CoulombSkidRobot(track=0.2, axle_spacing=0.16)
    half = 0.5 * robot.track
    psi = math.atan2(radius + half, radius - half)  # a ccw arc: u_L = R − B/2, u_R = R + B/2
    assert robot.apparent_track(psi) == pytest.approx(1.0 + (0.16 / 0.2) ** 2, rel=1e-5)
    assert abs(robot.solve(psi)[1]) < 1e-7


def test_straight_motion_does_not_slip() -> None:
    """Equal rim speeds: the body moves at the rim speed, without turning."""
    vx, vy, w = CoulombSkidRobot().solve(math.pi / 4)
    assert vx == pytest.approx(math.sqrt(0.5), rel=1e-7)
    assert abs(vy) < 1e-8 and abs(w) < 1e-7


def test_interpolated_twist_matches_direct_solutions() -> None:
    """The per-step twist comes from a table in ψ scaled by |u|: within 1e-5 of the twist's size
    from solving the balance directly, for random rim speeds of both signs (a heading error of
    10 µrad per radian turned, far below the ground truth's 2 mrad)."""
    robot = CoulombSkidRobot()
    rng = np.random.default_rng(5)
    rims = rng.uniform(-0.4, 0.4, size=(40, 2))
    table = robot.twist(rims)
    for u, got in zip(rims, table, strict=True):
        size = math.hypot(*u)
        direct = size * robot.solve(math.atan2(u[1], u[0]))
        assert np.max(np.abs(got - direct)) < 1e-5 * np.linalg.norm(direct)


def test_a_spin_turns_by_the_planned_angle_over_chi() -> None:
    """A 360° spin planned with the nominal track turns the robot by 360°/χ (the logged heading,
    1 mm / 0.1° noise)."""
    robot = CoulombSkidRobot(sensor_heading_std=0.0, sensor_position_std=0.0)
    spin = [m for m in skid_protocol() if m.experiment == "spin_ccw_360"]
    (run,) = generate_skid(robot, spin, np.random.default_rng(0))
    turned = run.true_pose[-1, 2] - run.true_pose[0, 2]
    assert math.degrees(turned) == pytest.approx(360.0 / 1.64, rel=1e-4)


def test_independent_of_odomgym_simulator() -> None:
    """The generator imports numpy, scipy's optimiser, the standard library, the independent
    robot's motion planner and odomgym.odometry.runs (the log format) only."""
    modules = module_imports(Path(__file__).parent / "independent_skid.py")
    assert {m for m in modules if m.split(".")[0] == "odomgym"} == {"odomgym.odometry.runs"}
    assert "pymunk" not in {m.split(".")[0] for m in modules}
    assert {m for m in modules if m.split(".")[0] == "scipy"} == {"scipy.optimize"}

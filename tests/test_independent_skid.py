"""The independent skid-steer robots (``tests/independent_skid.py``): rigid wheels on Coulomb
friction and elastic tyres, checked against the closed forms they must meet before the diagnosis
is tried on them."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from independent_skid import CoulombSkidRobot, ElasticSkidRobot, generate_skid, skid_protocol
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


@pytest.mark.parametrize(
    "robot",
    [CoulombSkidRobot(), pytest.param(ElasticSkidRobot(), marks=pytest.mark.slow)],
    ids=lambda robot: type(robot).__name__,
)
def test_interpolated_twist_matches_direct_solutions(robot: CoulombSkidRobot) -> None:
    """The per-step twist comes from a table in ψ scaled by |u|: within 1e-5 of the twist's size
    from solving the balance directly, for random rim speeds of both signs (a heading error of
    10 µrad per radian turned, far below the ground truth's 2 mrad)."""
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


def _ccw_arc(robot: CoulombSkidRobot, radius: float) -> float:
    """ψ of a ccw arc of ``radius`` [m] planned with the nominal track (u_L = R − B/2, u_R = R +
    B/2; a spin at 0)."""
    half = 0.5 * robot.track
    return math.atan2(radius + half, radius - half)


def test_elastic_tyres_give_the_linear_closed_form_on_wide_arcs() -> None:
    """On a wide arc every contact is in its linear range, and the moment balance of the four
    linear forces gives ω = (u_R − u_L)/(B·(1 + (C_α/C_κ)·(a/B)²)): χ_∞ = 1 + ½·0.8² = 1.32 for
    C_α/C_κ = ½ and a/B = 0.8 (the module docstring). At R = 200 m the saturation is 5·10⁻⁴ of
    the excess away; the centre does not slip sideways (equal loads)."""
    robot = ElasticSkidRobot(track=0.2, axle_spacing=0.16, slip_stiffness=12.0,
                             cornering_stiffness=6.0)  # fmt: skip
    wide = _ccw_arc(robot, 200.0)
    assert robot.apparent_track(wide) == pytest.approx(1.32, rel=1e-3)
    assert abs(robot.solve(wide)[1]) < 1e-9
    # The closed form moves with the stiffness ratio: C_α = C_κ gives the rigid robot's 1.64.
    even = ElasticSkidRobot(track=0.2, axle_spacing=0.16, slip_stiffness=8.0,
                            cornering_stiffness=8.0)  # fmt: skip
    assert even.apparent_track(_ccw_arc(even, 200.0)) == pytest.approx(1.64, rel=1e-3)


def test_elastic_tyres_slide_like_coulomb_in_a_spin_and_the_track_falls_with_radius() -> None:
    """In a spin the wheels' lateral slips of about a/(χ·B) saturate their tyres, and the forces
    turn to Coulomb's, opposite the sliding: χ within 0.1 % of the rigid robot's 1 + (a/B)².
    Between the two limits the apparent track falls monotonically as the arc widens (Mandow et
    al. 2007's measured trend), by more than half its excess between a spin and a 1 m radius
    (λ = 10) — where, and how fast, follows from C_κ, C_α and μ alone."""
    robot = ElasticSkidRobot(track=0.2, axle_spacing=0.16)
    spin = robot.apparent_track(_ccw_arc(robot, 0.0))
    assert spin == pytest.approx(1.64, rel=1e-3)
    radii = [0.0, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0, 10.0, 50.0]
    chi = [robot.apparent_track(_ccw_arc(robot, r)) for r in radii]
    assert all(a > b for a, b in itertools.pairwise(chi)), chi
    assert chi[radii.index(1.0)] - 1.32 < 0.5 * (spin - 1.32)
    # A lower friction saturates wider arcs too: the track stays near the spin's further out.
    slick = ElasticSkidRobot(track=0.2, axle_spacing=0.16, friction=0.3)
    assert slick.apparent_track(_ccw_arc(slick, 1.0)) > chi[radii.index(1.0)]


@pytest.mark.slow
def test_elastic_balance_holds_at_the_tabled_twists() -> None:
    """Every tabled twist is a root of the four tyres' force and moment balance (residual below
    10⁻⁹ of the unit load), the straight-line rows exact."""
    robot = ElasticSkidRobot()
    psi, table = robot._table
    for k in range(0, len(psi), 50):
        rims = (math.cos(psi[k]), math.sin(psi[k]))
        assert np.max(np.abs(robot.balance(table[k], rims))) < 1e-9
    forward = robot.solve(math.pi / 4)
    assert forward[0] == pytest.approx(math.sqrt(0.5), rel=1e-12) and abs(forward[2]) < 1e-12


def test_elastic_robot_refuses_a_non_positive_stiffness() -> None:
    with pytest.raises(ValueError, match="cornering_stiffness"):
        ElasticSkidRobot(cornering_stiffness=0.0)


def test_independent_of_odomgym_simulator() -> None:
    """The generator imports numpy, scipy's optimiser, the standard library, the independent
    robot's motion planner and odomgym.odometry.runs (the log format) only."""
    modules = module_imports(Path(__file__).parent / "independent_skid.py")
    assert {m for m in modules if m.split(".")[0] == "odomgym"} == {"odomgym.odometry.runs"}
    assert "pymunk" not in {m.split(".")[0] for m in modules}
    assert {m for m in modules if m.split(".")[0] == "scipy"} == {"scipy.optimize"}

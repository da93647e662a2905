"""Physics against analytic predictions.

Borenstein & Feng 1994, §6.1 (UMBmark); Borenstein 1995, Table I (bumps).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from odomgym.floor import CableBump, FloorSpec
from odomgym.odometry.runs import return_error
from odomgym.robot import PRESETS
from odomgym.sim.cables import bump_extra_rotation, cable_advance
from odomgym.sim.route_runs import simulate_runs
from odomgym.sim.routes import square_route, straight_route

LABMATE = PRESETS["labmate"]
SIDE = 4.0


def _square_errors(robot, direction: str) -> np.ndarray:
    runs, odom = simulate_runs(
        robot, FloorSpec(), square_route(SIDE, direction), direction=direction
    )
    error = runs[0].true_pose[-1] - odom[0]
    return error


@pytest.mark.parametrize("direction", ["cw", "ccw"])
def test_ideal_robot_square_is_exact(direction: str) -> None:
    """Issue #2 must-pass 1: ideal robot, smooth floor, 0.2 m/s:
    |true − odometry| < 2 mm and < 0.05°."""
    error = _square_errors(LABMATE.ideal(), direction)
    assert math.hypot(error[0], error[1]) < 0.002
    assert abs(math.degrees(error[2])) < 0.05


def _first_order_prediction(e_d: float, e_b: float, b: float, side: float) -> dict[str, float]:
    """Return errors of Borenstein & Feng 1994, Eqs. 6.19-6.20 (x), and their y counterparts
    (6.22b, 6.26b)."""
    alpha = (math.pi / 2) * (1.0 - 1.0 / e_b)  # Eq. 6.29 solved for α [rad]
    if e_d == 1.0:
        beta = 0.0
    else:
        radius = (b / 2) * (e_d + 1) / (e_d - 1)  # Eq. 6.24 solved for R
        beta = 2 * math.asin(side / (2 * radius))  # Eq. 6.23 solved for β
    return {
        "x_cw": -2 * side * (alpha + beta),
        "y_cw": -2 * side * (alpha + beta),
        "x_ccw": -2 * side * (alpha - beta),
        "y_ccw": 2 * side * (alpha - beta),
    }


@pytest.mark.parametrize(("e_d", "e_b"), [(1.002, 1.0), (1.0, 1.01), (0.998, 1.0), (1.0, 0.99)])
def test_umbmark_first_order_predictions(e_d: float, e_b: float) -> None:
    """Issue #2 must-pass 2: E_d or E_b alone → return errors within 10 % of the first-order
    predictions of Borenstein & Feng 1994, Eqs. 6.3-6.20."""
    robot = LABMATE.with_errors(e_d, e_b, 1.0)
    predicted = _first_order_prediction(e_d, e_b, LABMATE.wheelbase, SIDE)
    measured = {}
    for direction in ("cw", "ccw"):
        error = _square_errors(robot, direction)
        measured[f"x_{direction}"] = error[0]
        measured[f"y_{direction}"] = error[1]
    for key, value in predicted.items():
        assert measured[key] == pytest.approx(value, rel=0.10), key


def test_cable_geometry_of_borenstein_1995_table_1() -> None:
    """Rigid 75 mm wheel over a 10 mm cable: the encoder over-reports R·2ψ₀ − 2w.

    Borenstein 1995, Table I, estimates 2.63 mm with a chord approximation (Eqs. 1-3); the exact
    arc of a wheel rolling over a cylinder gives 3.40 mm, i.e. 0.57° of heading on b = 340 mm,
    close to the ≈ 0.6° per bump measured in Borenstein 1995, §6.1.
    """
    extra = bump_extra_rotation(0.075, 0.010)
    r, rho = 0.075, 0.005
    w = 2 * math.sqrt(r * rho)
    assert extra == pytest.approx(2 * (r + rho) * math.asin(w / (r + rho)) - 2 * w, rel=1e-12)
    assert extra == pytest.approx(3.40e-3, abs=0.01e-3)
    # The stepwise map is exact for any step size and reversible.
    total = 0.0
    x = -0.1
    for _ in range(200):
        advance = float(cable_advance(np.array(x), np.array(0.001), np.array(r), np.array(rho)))
        total += advance
        x += advance
    assert 0.2 - total == pytest.approx(extra, abs=1e-12)
    back = float(cable_advance(np.array(x), np.array(-0.2), np.array(r), np.array(rho)))
    assert x + back == pytest.approx(-0.1, abs=1e-12)


def test_single_bump_heading_and_lateral_error() -> None:
    """Issue #2 must-pass 3: one 10 mm cable under one LabMate wheel at 0.5 m/s."""
    bump_x = 0.6
    floor = FloorSpec(
        bumps=(CableBump(x=bump_x, y=-0.17, angle=math.pi / 2, diameter=0.010, length=0.12),)
    )
    robot = LABMATE.ideal()
    after = 10.0
    runs, odom = simulate_runs(
        robot, floor, straight_route(bump_x + after), cruise_speed=0.5, kind="straight"
    )
    true_end = runs[0].true_pose[-1]
    heading_error = true_end[2] - odom[0][2]
    assert 0.40 < abs(math.degrees(heading_error)) < 0.65
    assert heading_error < 0  # the right wheel lost travel: the robot turned right
    lateral = true_end[1] - odom[0][1]
    assert lateral == pytest.approx(after * math.sin(heading_error), rel=0.20)


def test_return_error_replay_matches_live_odometry() -> None:
    """Calibrators replay runs from counts; the replay must equal the robot's own odometry."""
    runs, odom = simulate_runs(LABMATE, FloorSpec(), square_route(2.0, "ccw"), direction="ccw")
    replayed = return_error(runs[0], LABMATE)
    live = runs[0].true_pose[-1] - odom[0]
    np.testing.assert_allclose(replayed[:2], live[:2], atol=1e-9)
    assert replayed[2] == pytest.approx(live[2], abs=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cable_grid_lists_each_cell_the_cables_that_reach_it(seed: int) -> None:
    """The cable index (``CableGrid``) against a brute-force one: a cable is listed in every
    cell its reach (half its length along its axis, the contact half-width plus one step
    across) overlaps, and a cell lists its cables in index order — the lookup the compiled
    contact code relies on, whatever the cables' angles and the field's size."""
    from odomgym.lab.population import cable_field
    from odomgym.sim.cables import CableGrid

    rng = np.random.default_rng(seed)
    floor = (
        cable_field(rng, roughness=0.0, name="t")
        if seed == 0
        else FloorSpec(
            name="t",
            bumps=tuple(
                CableBump(x=x, y=y, angle=a, diameter=0.01, length=length)
                for x, y, a, length in zip(
                    rng.uniform(-3, 3, 40),
                    rng.uniform(-2, 5, 40),
                    rng.uniform(-math.pi, math.pi, 40),
                    rng.uniform(0.1, 1.2, 40),
                    strict=True,
                )
            ),
        )
    )
    wheel_radius, step = 0.1, 0.02 * seed + 0.01
    grid = CableGrid.build(floor, wheel_radius, step)
    cx, cy, ax, ay, half, radius, _ = floor.bump_arrays()
    reach = 2.0 * np.sqrt(wheel_radius * radius) + step + 1e-6
    listed: list[list[int]] = [[] for _ in range(grid.nx * grid.ny)]
    for m in range(cx.size):
        ex = abs(ax[m]) * half[m] + abs(ay[m]) * reach[m]
        ey = abs(ay[m]) * half[m] + abs(ax[m]) * reach[m]
        x0, x1 = (int((cx[m] + s * ex - grid.origin_x) // grid.cell) for s in (-1, 1))
        y0, y1 = (int((cy[m] + s * ey - grid.origin_y) // grid.cell) for s in (-1, 1))
        for gy in range(y0, y1 + 1):
            for gx in range(x0, x1 + 1):
                listed[gy * grid.nx + gx].append(m)
    assert grid.starts.shape == (grid.nx * grid.ny + 1,)
    for c, expected in enumerate(listed):
        assert grid.items[grid.starts[c] : grid.starts[c + 1]].tolist() == expected, c

"""The measurement nuisances of a session — time offset, tracked point, yaw misalignment — on
data with a known answer.

Real data: three of the June OptiOdom sessions shipped in the package (a square, an Ivanjko
and a circular session; Sousa et al. 2022, MIT), one of them with its encoder ticks shifted by a
known 50–500 ms and its measured headings rotated by a known 20°. The shift and the rotation
must be recovered (within 10 ms and 0.2°) while the robot's E_s and E_b stay where they were
(within their session-clustered standard errors). Simulated data pin the sign convention and
the frame correction against hand-computed values.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from independent_robot import IndependentRobot, generate, rich_protocol

from odomgym.data import sample_session
from odomgym.data.logs import read_log
from odomgym.diagnose.gate import model_effect
from odomgym.diagnose.nuisances import SessionNuisance, correct_run
from odomgym.diagnose.openloop import NuisanceOptions, OpenLoopData, OpenLoopFit, fit_open_loop
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec, load_robot

ROBOT = RobotSpec(wheel_diameter=0.084, wheelbase=0.2, ticks_per_rev=2796.8, max_wheel_speed=0.6)
GEOMETRY = model_effect(("wheel_diameter_ratio", "wheelbase", "distance_scale"), ())
JUNE = ("square/230620202042", "ivanjko/250620201618", "circular/250620202104")


def shifted(run: Run, lag: float, yaw: float) -> Run:
    """``run`` with its encoder log stamped ``lag`` seconds late and ``yaw`` added to every
    measured heading (a marker body turned on the robot)."""
    counts = np.stack(
        [np.interp(run.time - lag, run.time, run.counts[:, k].astype(float)) for k in range(2)],
        axis=1,
    )
    pose = run.true_pose.copy()
    pose[:, 2] += yaw
    return dataclasses.replace(run, counts=counts, true_pose=pose)


@pytest.fixture(scope="module")
def june() -> list[Run]:
    robot = load_robot(Path(__file__).resolve().parents[1] / "examples" / "optiodom_nominal.toml")
    runs: list[Run] = []
    for name in JUNE:
        found, _ = read_log(sample_session(name), robot=robot, format="optiodom")
        runs.extend(found)
    return runs


@pytest.fixture(scope="module")
def june_fit(june: list[Run]) -> OpenLoopFit:
    return fit_open_loop(
        OpenLoopData(june, 0.25, ROBOT.wheelbase), ROBOT, GEOMETRY, NuisanceOptions(frames=True)
    )


@pytest.mark.parametrize(
    ("session", "lag"), [("230620202042", 0.05), ("250620201618", 0.2), ("250620202104", 0.5)]
)
def test_injected_time_offset_and_yaw_are_recovered_and_the_robot_stays_put(
    june: list[Run], june_fit: OpenLoopFit, session: str, lag: float
) -> None:
    yaw = math.radians(20.0)
    moved = [shifted(r, lag, yaw) if r.meta["session"] == session else r for r in june]
    fit = fit_open_loop(
        OpenLoopData(moved, 0.25, ROBOT.wheelbase), ROBOT, GEOMETRY, NuisanceOptions(frames=True)
    )
    before, after = june_fit.nuisances[session], fit.nuisances[session]
    assert abs((after.time_offset - before.time_offset) - lag) < 0.010, (before, after)
    assert abs(math.degrees(after.yaw - before.yaw) - 20.0) < 0.2, (before, after)
    for key in ("wheelbase.e_b", "distance_scale.e_s", "wheel_diameter_ratio.e_d"):
        error = june_fit.stderr_sessions[key]
        assert abs(fit.values[key] - june_fit.values[key]) < error, key
    # The other sessions' nuisances do not move either.
    for other, nuisance in june_fit.nuisances.items():
        if other != session:
            assert abs(fit.nuisances[other].time_offset - nuisance.time_offset) < 0.002


def test_june_sessions_put_the_mean_wheel_diameter_below_nominal(june_fit: OpenLoopFit) -> None:
    """Every published calibration of these sessions puts the mean diameter 0–1 % below
    84 mm (UMBmark, Jung & Chung, Ivanjko et al., OptiOdom: ``published_results.csv``) and the
    wheelbase 0–0.7 % above 0.2 m; so does the open-loop fit with the nuisances beside it."""
    e_s = june_fit.values["distance_scale.e_s"]
    e_b = june_fit.values["wheelbase.e_b"]
    assert 0.988 < e_s < 1.0, e_s
    assert 1.0 < e_b < 1.008, e_b


def test_time_offset_sign_and_size_on_a_simulated_robot() -> None:
    """A robot without effects whose encoder log is stamped 120 ms late: the fitted offset is
    +120 ms (positive: the encoder log lags the ground truth) within 10 ms."""
    runs = generate(IndependentRobot(), rich_protocol()[:8], np.random.default_rng(5))
    late = [shifted(r, 0.12, 0.0) for r in runs]
    fit = fit_open_loop(OpenLoopData(late, 0.25, ROBOT.wheelbase), ROBOT, None, NuisanceOptions())
    (nuisance,) = fit.nuisances.values()
    assert abs(nuisance.time_offset - 0.12) < 0.010, nuisance


def test_a_large_yaw_misalignment_is_found_from_any_start() -> None:
    """Yaw misalignments of any size (a marker body can sit at any yaw): 120° and −75° are
    found by the closed-form start and refined, with the tracked point."""
    runs = generate(IndependentRobot(), rich_protocol()[:8], np.random.default_rng(6))
    for yaw, dx, dy in ((math.radians(120.0), 0.03, -0.01), (math.radians(-75.0), -0.02, 0.0)):
        moved = []
        for run in runs:
            pose = run.true_pose.copy()
            c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
            pose[:, 0] += c * dx - s * dy
            pose[:, 1] += s * dx + c * dy
            pose[:, 2] += yaw
            moved.append(dataclasses.replace(run, true_pose=pose))
        fit = fit_open_loop(
            OpenLoopData(moved, 0.25, ROBOT.wheelbase), ROBOT, None, NuisanceOptions(frames=True)
        )
        (nuisance,) = fit.nuisances.values()
        assert abs(math.degrees(nuisance.yaw - yaw)) < 0.05, nuisance
        assert abs(nuisance.dx - dx) < 5e-4 and abs(nuisance.dy - dy) < 5e-4, nuisance


def test_correct_run_moves_the_measured_poses_into_the_robot_frame() -> None:
    """Hand-computed: a body 10 cm ahead of the axle at a yaw of 90°, measured at (1, 2) with
    heading π/2 + 90°: the robot's heading is π/2, its axle at (1, 2) − R(π/2)·(0.1, 0) =
    (1, 1.9); counts shifted by τ are the logged ones at t + τ."""
    run = Run(
        kind="straight",
        time=np.array([0.0, 1.0, 2.0]),
        counts=np.array([[0, 0], [100, 100], [200, 200]]),
        true_pose=np.array([[1.0, 2.0, math.pi], [1.0, 2.0, math.pi], [1.0, 2.0, math.pi]]),
    )
    fixed = correct_run(run, SessionNuisance("", dx=0.1, yaw=math.pi / 2, time_offset=0.5))
    assert np.allclose(fixed.true_pose[0], [1.0, 1.9, math.pi / 2])
    assert np.allclose(fixed.counts[:, 0], [50.0, 150.0, 200.0])
    assert fixed.meta["nuisance"]["yaw_deg"] == pytest.approx(90.0)

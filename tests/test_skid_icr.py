"""The skid-steer ICR calibration as a registered calibrator (``skid_icr``,
:mod:`odomgym.baselines.skid_icr`) and the ICR offsets a :class:`Calibration` carries.

The odometry's ICR terms are checked against Mandow et al. 2007's model as
:mod:`odomgym.odometry.icr` writes it (an independent vectorised form), and the fit on runs
whose ground truth *is* an ICR robot with known parameters, so that the answer is exact; the
simulated robots' figures live in ``odomgym bench skid`` (tests/test_skid_bench.py).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from cli_errors import one_line_error

from odomgym.baselines import CALIBRATORS
from odomgym.baselines.base import Holdings, default_methods
from odomgym.baselines.skid_bench import calibration_model
from odomgym.baselines.skid_icr import (
    DEFAULT_RADII,
    SkidCurvature,
    SkidIcr,
    SkidIcrOptions,
    fit_icr,
    fit_skid,
)
from odomgym.baselines.validation import calibrator_for_session
from odomgym.cli import main
from odomgym.data.optiodom import Session
from odomgym.envs.umbmark import UMBmarkSquareEnv
from odomgym.errors import SpecError
from odomgym.floor import FLOORS
from odomgym.lab.experiment import Experiment, ExperimentKind
from odomgym.lab.recorded import RecordedLab
from odomgym.lab.simulated import SimLab
from odomgym.noise.fit import run_noise_basis
from odomgym.odometry.calibration import Calibration, Odometry, load_calibration
from odomgym.odometry.icr import SkidModel, skid_dead_reckon
from odomgym.odometry.runs import Run, replay_odometry, wheel_steps, wheel_travels
from odomgym.robot import PRESETS
from odomgym.sim.arc_runs import circle_plan, drive_arcs

ROBOT = PRESETS["scout2"]
B = ROBOT.wheelbase
TICK = ROBOT.metres_per_tick


def _counts(curvatures: list[float], seconds: float = 6.0) -> np.ndarray:
    """Cumulative whole encoder counts (T, 2) of 0.05 s samples driving legs of the given
    curvatures [1/m] at 0.3 m/s with the nominal track, each ``seconds`` long."""
    rows = []
    for kappa in curvatures:
        step = 0.3 * 0.05
        half = 0.5 * B * kappa * step
        rows += [(step - half, step + half)] * round(seconds / 0.05)
    travel = np.vstack(([0.0, 0.0], np.cumsum(rows, axis=0)))
    return np.round(travel / TICK).astype(np.int64)


def _truth(model: SkidModel, counts: np.ndarray, k: tuple[float, float]) -> Run:
    """A run whose ground truth is ``model`` driven by wheels travelling ``k`` times their
    nominal distance per count."""
    travels = np.diff(counts, axis=0) * TICK * np.array(k)
    pose = skid_dead_reckon(model, travels, np.array([0.3, -0.2, 0.4]))
    return Run(kind="free", time=0.05 * np.arange(len(pose)), counts=counts, true_pose=pose)


def test_the_odometry_applies_the_icr_offsets_as_mandows_model() -> None:
    """Odometry (the compiled kernel every driver uses) and replay_odometry both dead-reckon
    an ICR calibration exactly as Mandow et al. 2007's model with y_L, y_R = y_ICR ± E_b·b/2."""
    counts = _counts([0.0, 1.5, -0.7, 3.0, 0.2])
    cal = Calibration(c_left=1.01, c_right=0.99, wheelbase_scale=1.6, icr_x=0.04, icr_y=-0.02)
    run = _truth(SkidModel("constant", B, chi_inf=1.0), counts, (1.0, 1.0))
    odometry = Odometry(ROBOT, cal)
    odometry.reset(run.true_pose[:1])
    poses = []
    for row in counts:
        poses.append(odometry.update(row[None, :], 0.05)[0].copy())
    model = calibration_model(cal, ROBOT)
    assert model.kind == "icr"
    travels = np.diff(counts, axis=0) * TICK * np.array([1.01, 0.99])
    expected = skid_dead_reckon(model, travels, run.true_pose[0])
    np.testing.assert_allclose(np.array(poses), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(replay_odometry(run, ROBOT, cal), expected, rtol=0, atol=1e-12)
    # The ICR terms matter at this size: 4 cm of x_ICR moves the end pose by centimetres.
    plain = replay_odometry(run, ROBOT, Calibration(1.01, 0.99, 1.6))
    assert np.hypot(*(plain[-1, :2] - expected[-1, :2])) > 0.02


def test_zero_offsets_are_the_differential_drive_odometry_bit_for_bit() -> None:
    counts = _counts([0.0, 2.0, -1.0])
    run = _truth(SkidModel("constant", B, chi_inf=1.0), counts, (1.0, 1.0))
    cal = Calibration(1.01, 0.99, 1.2, 1.02)
    assert not cal.has_icr
    odometry = Odometry(ROBOT, cal)
    odometry.reset(run.true_pose[:1])
    poses = np.array([odometry.update(row[None, :], 0.05)[0].copy() for row in counts])
    # The differential-drive equations written out (odomgym.odometry.calibration's docstring),
    # in the kernel's order of operations.
    per_tick, wheelbase = odometry.travel_per_tick[0], odometry.effective_wheelbase[0]
    pose = run.true_pose[0].copy()
    for increment, got in zip(np.diff(counts, axis=0), poses[1:], strict=True):
        left, right = increment[0] * per_tick[0], increment[1] * per_tick[1]
        ds, dtheta = 0.5 * (left + right), (right - left) / wheelbase
        mid = pose[2] + 0.5 * dtheta
        pose += (ds * math.cos(mid), ds * math.sin(mid), dtheta)
        np.testing.assert_array_equal(got, pose)


def test_fit_icr_recovers_a_known_icr_robot() -> None:
    """Ground truth from an ICR robot (y_L = 0.47, y_R = −0.43, x_ICR = 0.05 m) whose wheels
    travel 1.01 and 0.99 times their nominal distance: the fit finds every parameter."""
    counts = [_counts(legs) for legs in ([0.0, 2.0, -2.0], [0.5, -1.0, 0.25, 4.0], [-0.3, 1.0])]
    truth = SkidModel("icr", B, y_left=0.47, y_right=-0.43, x_icr=0.05)
    runs = [_truth(truth, c, (1.01, 0.99)) for c in counts]
    fit = fit_icr(runs, ROBOT)
    cal = fit.calibration
    assert cal.c_left * cal.distance_scale == pytest.approx(1.01, abs=1e-7)
    assert cal.c_right * cal.distance_scale == pytest.approx(0.99, abs=1e-7)
    assert cal.wheelbase_scale * B == pytest.approx(0.90, abs=1e-6)
    assert cal.icr_y == pytest.approx(0.02, abs=1e-6)
    assert cal.icr_x == pytest.approx(0.05, abs=1e-6)
    assert fit.rms_after < 1e-7 < fit.rms_before
    # Gaps in the ground truth leave windows out, not NaN in the fit.
    gappy = [_truth(truth, c, (1.01, 0.99)) for c in counts]
    for run in gappy:
        run.true_pose[5:60] = np.nan
    again = fit_icr(gappy, ROBOT).calibration
    assert again.icr_x == pytest.approx(0.05, abs=1e-6)
    assert fit_icr(gappy, ROBOT).windows < fit.windows


def test_a_calibration_keeps_its_icr_offsets_in_files_and_says_what_ros_cannot(
    tmp_path: Path,
) -> None:
    plain = Calibration(1.01, 0.99, 1.2, 1.02)
    assert set(plain.to_dict()) == {"c_left", "c_right", "wheelbase_scale", "distance_scale"}
    skid = Calibration(1.0, 1.0, 1.6, 1.0, icr_x=-0.03, icr_y=0.01)
    path = tmp_path / "cal.toml"
    skid.save(path)
    assert load_calibration(path) == skid
    assert "icr_x = -0.030000 m" in skid.ros2_yaml()
    assert "icr_x" not in plain.ros2_yaml()
    assert plain.then(skid) == Calibration(1.01, 0.99, 1.92, 1.02, icr_x=-0.03, icr_y=0.01)
    assert skid.parameters(ROBOT)["icr_y_left"] == pytest.approx(0.01 + 0.8 * B)
    path.write_text("[calibration]\nc_left = 1.0\nicr_x = nan\n")
    with pytest.raises(SpecError, match="icr_x must be finite") as info:
        load_calibration(path)
    assert info.value.field == "icr_x"
    assert "cal.toml:3:" in str(info.value)
    with pytest.raises(SpecError, match="c_left must be > 0"):
        Calibration(c_left=-1.0, icr_x=0.1)


def test_differential_drive_models_refuse_an_icr_calibration() -> None:
    """The differential-drive replays with Jacobians, Chong & Kleeman's covariance (noise fit,
    env option) would drop a calibration's ICR steps: each says so instead."""
    run = _truth(SkidModel("constant", B, chi_inf=1.0), _counts([1.0]), (1.0, 1.0))
    skid = Calibration(icr_x=0.01)
    with pytest.raises(ValueError, match="ICR offsets"):
        wheel_steps(run, ROBOT, skid)
    with pytest.raises(ValueError, match="Chong & Kleeman"):
        run_noise_basis(run, ROBOT, skid)
    with pytest.raises(ValueError, match="covariance_k"):
        UMBmarkSquareEnv(robot="scout2", calibration=skid, covariance_k=(0.001, 0.001))


def test_skid_icr_is_registered_with_its_experiments_and_sizing() -> None:
    assert CALIBRATORS["skid_icr"] is SkidIcr
    # Made for skid-steer robots: the comparisons on differential-drive robots run it only
    # when it is named; every other method stays in them.
    skid = {"skid_icr", "skid_curvature"}
    assert default_methods() == [m for m in CALIBRATORS if m not in skid]
    assert default_methods(skid_steer=True) == list(CALIBRATORS)
    method = SkidIcr()
    kinds = [(e.kind, e.direction, e.size) for e in method.experiments()]
    assert kinds[:2] == [(ExperimentKind.SQUARE, "cw", 2.0), (ExperimentKind.SQUARE, "ccw", 2.0)]
    assert [size for kind, _, size in kinds if kind is ExperimentKind.CIRCULAR] == [
        r for r in DEFAULT_RADII for _ in ("cw", "ccw")
    ]
    assert SkidIcr.budget_options(4) == {"radii": (0.5,), "runs_per_direction": 1}
    assert SkidIcr.budget_options(16) == {"radii": DEFAULT_RADII, "runs_per_direction": 4}
    spins_only = Holdings(0.0, {(ExperimentKind.SPIN, "cw"): 4, (ExperimentKind.SPIN, "ccw"): 4})
    with pytest.raises(LookupError, match="holds none"):
        SkidIcr.session_options(spins_only)


def test_skid_icr_calibrates_a_recorded_session_of_a_skid_steer_robot() -> None:
    """A session (squares, circles of one radius both ways, free paths) of the World's Scout on
    the slippery floor, served by a RecordedLab as a user's logs would be: the method takes
    every run it can use and finds the apparent track the same lab's own calibration finds."""
    robot = PRESETS["scout2"]
    lab = SimLab(robot, FLOORS["slippery"], rng=np.random.default_rng(3), cruise_speed=0.3)
    runs = []
    for experiment in (
        Experiment("square", "cw", 1, 2.0),
        Experiment("square", "ccw", 1, 2.0),
        Experiment("circular", "cw", 1, 1.0),
        Experiment("circular", "ccw", 1, 1.0),
        Experiment("free", None, 2, 20.0),
    ):
        runs += lab.perform(experiment, Calibration())
    for k, run in enumerate(runs):
        run.source = f"sim-{k}"
    session = Session("sim", Path("."), "free", robot, Calibration(), 2.0, tuple(runs))
    method = calibrator_for_session(SkidIcr, session)
    assert method.options.runs_per_direction == 1 and method.options.free_runs == 2
    result = method.calibrate(RecordedLab(session))
    assert result.runs_used == len(runs)
    assert result.calibration.has_icr
    # The World's Scout needs about 1.7 on this floor (docs/skid-steer.md).
    assert 1.6 < result.calibration.wheelbase_scale < 1.85
    assert abs(result.calibration.e_d - 1.0) < 0.01


@pytest.mark.parametrize(
    ("options", "field"),
    [
        ({"radii": (), "runs_per_direction": 0}, "runs_per_direction"),
        ({"circle_runs": 0}, "circle_runs"),
        ({"free_runs": -1}, "free_runs"),
        ({"radii": (1.0, -2.0)}, "radii"),
        ({"radii": (1.0, 1.0)}, "radii"),
        ({"side": 0.0}, "side"),
        ({"runs_per_direction": -1}, "runs_per_direction"),
        ({"window": -1.0}, "window"),
        ({"heading_weight": -0.1}, "heading_weight"),
    ],
)
def test_bad_options_name_the_field(options: dict[str, object], field: str) -> None:
    with pytest.raises(SpecError) as info:
        SkidIcrOptions(**options)  # type: ignore[arg-type]
    assert info.value.field == field


@pytest.mark.slow
def test_bench_calibrators_on_a_skid_steer_population(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``bench calibrators --base scout2`` draws the population around the skid-steer preset,
    runs skid_icr beside the classical methods on it, and leaves the oracle out; every method's
    calibration is validated on the same fresh squares, which the ICR calibration drives in
    closed loop (its offsets in the odometry)."""
    out = tmp_path / "bench"
    argv = ["bench", "calibrators", "--base", "scout2", "--robots", "1", "--floor", "concrete"]
    argv += ["--methods", "skid_icr", "umbmark", "--budget", "4", "--out", str(out), "--json"]
    assert main(argv) == 0
    summary = {row["method"]: row for row in json.loads(capsys.readouterr().out)["summary"]}
    assert set(summary) == {"skid_icr", "umbmark"}  # no oracle row
    for row in summary.values():
        assert row["failures"] == 0
        # Squares driven with the nominal track turn ~52° at a 90° corner: metres off.
        assert row["e_max_before_median_mm"] > 1000.0
        assert row["e_max_after_median_mm"] < 0.5 * row["e_max_before_median_mm"]
    results = json.loads((out / "results.json").read_text())
    rows = results["rows"] if isinstance(results, dict) else results
    icr = next(r for r in rows if r["method"] == "skid_icr")
    assert icr["est_E_b"] > 1.3  # the apparent track, not the wheels' spacing
    # A skid-steer population's rows carry the ICR offsets (0 for a classical method).
    assert icr["est_icr_x"] != 0.0 and icr["est_track_alpha"] == 0.0
    assert next(r for r in rows if r["method"] == "umbmark")["est_icr_x"] == 0.0
    # The report says why abs(ΔE_b) is large and the oracle column empty on such a robot.
    assert "On a skid-steer base, abs(ΔE_b) is the fitted E_b" in (out / "summary.md").read_text()


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["bench", "calibrators", "--base", "scout2", "--oracle"], "oracle row needs a robot"),
        (["bench", "skid", "--base", "scout2"], "--base is an option of `odomgym bench calib"),
    ],
)
def test_bench_options_for_skid_steer_populations_fail_in_one_line(
    argv: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    one_line_error(capsys, needle)
    assert not (tmp_path / "out").exists()


def test_the_arc_driver_counts_the_icr_step_in_its_path_length() -> None:
    """A circle driven by a calibration with y_ICR = 0.1 m: the body moves y_ICR·Δθ forward
    beyond the rims' mean travel, so the driver stops when the mean travel plus that step is
    the plan's length (2π m), not when the mean travel alone is."""
    cal = Calibration(wheelbase_scale=1.7, icr_y=0.1)
    (run,) = drive_arcs(
        ROBOT, FLOORS["smooth"], [circle_plan(1.0, "ccw")], calibration=cal, cruise_speed=0.3
    )
    travels, wheelbase = wheel_travels(run, ROBOT, cal)
    mean = float(travels.mean(axis=1).sum())
    turn = float((travels[:, 1] - travels[:, 0]).sum() / wheelbase)
    assert turn == pytest.approx(2.0 * math.pi, rel=0.02)
    assert mean + cal.icr_y * turn == pytest.approx(2.0 * math.pi, abs=0.02)
    assert mean < 2.0 * math.pi - 0.5  # the ICR step is 0.63 m of it


def test_classical_calibrators_and_clapper_refuse_an_icr_calibration() -> None:
    skid = Calibration(wheelbase_scale=1.7, icr_x=0.02)
    lab = SimLab(ROBOT, FLOORS["smooth"], rng=np.random.default_rng(0))
    for name in ("umbmark", "jung_chung", "lee", "ivanjko", "least_squares", "trajectory"):
        with pytest.raises(ValueError, match=f"^{name} models a differential-drive"):
            CALIBRATORS[name]().calibrate(lab, skid)
    assert lab.runs_used == 0  # refused before driving
    from odomgym.vehicle.paths import straight_path
    from odomgym.vehicle.spec import VEHICLES
    from odomgym.vehicle.trial import VehicleTrial

    with pytest.raises(ValueError, match="CLAPPER"):
        VehicleTrial(VEHICLES["clapper"], FLOORS["smooth"], straight_path(2.0), calibration=skid)


@pytest.mark.parametrize("method", ["skid_icr", "skid_curvature"])
def test_the_leaderboard_carries_a_calibrations_skid_terms_to_the_other_sessions(
    method: str,
) -> None:
    """``leaderboard --methods skid_icr`` (or ``skid_curvature``) on the shipped
    (differential-drive) square sessions: each calibration is judged on the other sessions with
    its skid-steer terms (ICR offsets, or the track's curve with α rescaled like E_b to the
    other session's nominal track), not only with the b, D_R, D_L the board tabulates."""
    from odomgym.baselines.leaderboard import evaluate, run_leaderboard
    from odomgym.data import sample_data
    from odomgym.data.optiodom import find_sessions, read_session

    root = sample_data()
    board = run_leaderboard(root, methods=[method], path_types=("square",))
    sessions = {s.name: s for s in (read_session(p) for p in find_sessions(root))}
    (source, target), *_ = [(s, t) for (_, s, t) in board.cross]
    cls = CALIBRATORS[method]
    held = Holdings(sessions[source].side, RecordedLab(sessions[source]).holdings())
    lab = RecordedLab(sessions[source])
    own = cls(**cls.session_options(held)).calibrate(lab, sessions[source].initial).calibration
    assert own.is_skid_steer
    params = own.parameters(sessions[source].robot)
    moved = Calibration.from_parameters(
        sessions[target].robot, params["wheelbase"], params["right_diameter"],
        params["left_diameter"],
    )  # fmt: skip
    ratio = sessions[source].robot.wheelbase / sessions[target].robot.wheelbase
    whole = Calibration(
        moved.c_left, moved.c_right, moved.wheelbase_scale, moved.distance_scale,
        icr_x=own.icr_x, icr_y=own.icr_y, track_alpha=own.track_alpha * ratio,
        track_beta=own.track_beta, track_power=own.track_power,
    )  # fmt: skip
    if own.has_track_curve:  # the same track in a spin, in metres, on either robot
        spin = whole.parameters(sessions[target].robot)["spin_wheelbase"]
        assert spin == pytest.approx(params["spin_wheelbase"], rel=1e-12)
    got = board.cross[(method, source, target)]
    assert got == evaluate(sessions[target].runs, sessions[target].robot, whole)
    assert got != evaluate(sessions[target].runs, sessions[target].robot, moved)


CURVE = Calibration(
    c_left=1.004, c_right=0.996, wheelbase_scale=1.25, distance_scale=1.01,
    track_alpha=0.42, track_beta=0.3, track_power=1.6,
)  # fmt: skip
"""A track that moves with the turn: 1.67 × nominal in a spin, 1.25 on a straight path."""


def test_the_odometry_applies_a_track_curve_as_the_curvature_model() -> None:
    """The compiled kernel and replay_odometry dead-reckon a calibration whose track moves
    with the turn as odomgym.odometry.icr's curvature model (χ_∞ = E_b) does, λ per period."""
    counts = _counts([0.0, 1.5, -0.7, 3.0, 0.2, 8.0])
    run = _truth(SkidModel("constant", B, chi_inf=1.0), counts, (1.0, 1.0))
    odometry = Odometry(ROBOT, CURVE)
    odometry.reset(run.true_pose[:1])
    poses = np.array([odometry.update(row[None, :], 0.05)[0].copy() for row in counts])
    model = calibration_model(CURVE, ROBOT)
    assert model.kind == "curvature"
    scale = CURVE.distance_scale * np.array([CURVE.c_left, CURVE.c_right])
    expected = skid_dead_reckon(model, np.diff(counts, axis=0) * TICK * scale, run.true_pose[0])
    np.testing.assert_allclose(poses, expected, rtol=0, atol=1e-11)
    np.testing.assert_allclose(replay_odometry(run, ROBOT, CURVE), expected, rtol=0, atol=1e-11)
    assert float(CURVE.track_factor(0.0)) == pytest.approx(1.67)
    assert CURVE.parameters(ROBOT)["spin_wheelbase"] == pytest.approx(1.67 * B)


def test_fit_skid_recovers_a_known_track_curve() -> None:
    """Ground truth from the curvature model (χ_∞ 1.3, α 0.4, β 0.35, p 1.5) driven by wheels
    travelling 1.01 and 0.99 times their nominal distance: the fit finds every parameter."""
    truth = SkidModel("curvature", B, chi_inf=1.3, alpha=0.4, beta=0.35, power=1.5)
    legs = ([0.0, 2.0, -2.0, 6.0], [0.5, -1.0, 0.25, 4.0, 12.0], [-0.3, 1.0, -8.0])
    runs = [_truth(truth, _counts(list(c)), (1.01, 0.99)) for c in legs]
    cal = fit_skid(runs, ROBOT, "curvature").calibration
    assert cal.c_left * cal.distance_scale == pytest.approx(1.01, abs=1e-6)
    assert cal.c_right * cal.distance_scale == pytest.approx(0.99, abs=1e-6)
    assert cal.wheelbase_scale == pytest.approx(1.3, abs=1e-5)
    assert cal.track_alpha == pytest.approx(0.4, abs=1e-5)
    assert cal.track_beta == pytest.approx(0.35, abs=1e-4)
    assert cal.track_power == pytest.approx(1.5, abs=1e-4)


def test_a_track_curve_in_files_composition_and_refusals(tmp_path: Path) -> None:
    path = tmp_path / "curve.toml"
    CURVE.save(path)
    assert load_calibration(path) == CURVE
    assert "icr_x" not in path.read_text() and "track_alpha" in path.read_text()
    assert "alpha = 0.420000" in CURVE.ros2_yaml()
    assert Calibration(wheelbase_scale=1.1).then(CURVE).track_alpha == pytest.approx(0.42 * 1.1)
    with pytest.raises(ValueError, match="do not compose"):
        CURVE.then(CURVE)
    path.write_text("[calibration]\ntrack_alpha = -0.1\n")
    with pytest.raises(SpecError, match="track_alpha must be >= 0") as info:
        load_calibration(path)
    assert info.value.field == "track_alpha"
    run = _truth(SkidModel("constant", B, chi_inf=1.0), _counts([1.0]), (1.0, 1.0))
    with pytest.raises(ValueError, match="track curve"):
        wheel_steps(run, ROBOT, CURVE)
    with pytest.raises(ValueError, match=r"^selfcal models a differential-drive"):
        CALIBRATORS["selfcal"]().calibrate(SimLab(ROBOT, FLOORS["smooth"]), CURVE)
    with pytest.raises(ValueError, match="none of"):
        calibration_model(dataclasses.replace(CURVE, icr_x=0.01), ROBOT)
    # Without a curve β and p act on nothing: equal calibrations stay equal through a file.
    assert Calibration(track_beta=3.0, track_power=2.0) == Calibration()


def test_the_arc_driver_turns_by_the_track_its_curve_gives() -> None:
    """A 1 m circle driven by a calibration whose track moves with the turn: the driver asks
    the rims for the track at the λ it makes (about 1.52 × nominal at λ ≈ 2.3), so the odometry
    turns once round in the circle's length; rims sized by the straight-path track (1.25) would
    turn it only about 0.8 times round."""
    (run,) = drive_arcs(
        ROBOT, FLOORS["smooth"], [circle_plan(1.0, "ccw")], calibration=CURVE, cruise_speed=0.3
    )
    odometry = replay_odometry(run, ROBOT, CURVE)
    assert odometry[-1, 2] - odometry[0, 2] == pytest.approx(2.0 * math.pi, rel=0.02)


def test_skid_curvature_is_registered_and_calibrates_the_worlds_scout() -> None:
    """On the World's Scout (`smooth`, seed 1) the curve's track is about 1.67 × nominal in a
    spin and falls toward wide arcs, as the World's steady turns do (docs/skid-steer.md)."""
    assert CALIBRATORS["skid_curvature"] is SkidCurvature
    assert SkidCurvature.skid_steer and SkidCurvature().experiments() == SkidIcr().experiments()
    lab = SimLab(PRESETS["scout2"], FLOORS["smooth"], rng=np.random.default_rng(1))
    result = SkidCurvature().calibrate(lab)
    assert 1.6 < result.estimates["factor_spin"] < 1.75
    assert result.estimates["factor_5m"] < result.estimates["factor_1m"] - 0.1
    assert not result.calibration.has_icr and result.calibration.has_track_curve


def test_a_recorded_sessions_report_gives_the_skid_steer_terms(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``calibrate skid_icr --data`` on a shipped square session: the parameter line gives
    y_L, y_R and x_ICR beside b, D_R, D_L (``skid_curvature``: the track in a spin)."""
    assert main(["calibrate", "skid_icr", "--data", "optiodom:square/230620202042"]) == 0
    assert "x_ICR = " in capsys.readouterr().out
    assert main(["calibrate", "skid_curvature", "--data", "optiodom:square/230620202042"]) == 0
    assert "b in a spin = " in capsys.readouterr().out

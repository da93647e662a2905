"""Confounds derived from the data (``odomgym.diagnose.confounds``), on logs with a known answer.

The expectations are analytic (``docs/diagnose.md``, "Confounds"):

* a ground-truth frame scaled by s is exactly a robot whose wheels and wheelbase are both
  scaled by s: every displacement scales, every heading stays (E_s and E_b change together);
* a wheel toe τ is exactly a frame yaw δ = −τ: both rotate every predicted path about its start
  (``docs/effects.md`` step 6);
* the catalogue's ``gt_sensor_offset`` (dx, dy) is exactly a tracked point (dx, dy);
* a translation or rotation of the whole frame is invisible: every replay starts at the first
  measured pose;
* a clock rate is nearly a distance scale (with a time offset) while the robot cruises at
  constant speed, and separable where it stops (the counts stop, a scale does not);
* closed squares measured at their end points do not see a common scale of the wheels and the
  wheelbase (Borenstein & Feng 1994's UMBmark squares: the corners see E_s/E_b only).

The data come from the independent generator (``tests/independent_robot.py``), 10 Hz logs with
1 mm / 2 mrad sensor noise.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from independent_robot import IndependentRobot, Manoeuvre, generate, rich_protocol

from odomgym.diagnose.confounds import RELATIVE_SINGULAR_VALUE, Confound, derive_confounds
from odomgym.diagnose.gate import model_effect
from odomgym.diagnose.generate import NOMINAL_ROBOT
from odomgym.diagnose.openloop import NuisanceOptions, OpenLoopData, OpenLoopFit, fit_open_loop
from odomgym.diagnose.sensitivity import GroundTruthError, JointJacobian, joint_jacobian
from odomgym.odometry.runs import Run

GEOMETRY = ("wheel_diameter_ratio", "wheelbase", "distance_scale")
SCALE = 1.005  # the frame's scale error
CENTRE = np.array([1.0, -0.5])  # the point it scales about [m]
TOE = 0.005  # [rad]


def fitted(
    runs: list[Run], effects: tuple[str, ...], options: NuisanceOptions | None = None
) -> tuple[OpenLoopData, OpenLoopFit, JointJacobian, list[Confound]]:
    data = OpenLoopData(runs, 0.25, NOMINAL_ROBOT.wheelbase)
    fit = fit_open_loop(data, NOMINAL_ROBOT, model_effect(effects, ()), options)
    jac = joint_jacobian(data, fit)
    return data, fit, jac, derive_confounds(data, fit, NOMINAL_ROBOT, jacobian=jac)


def largest_singular_value(jac: JointJacobian) -> float:
    seen = jac.norms > 0
    return float(np.linalg.svd(jac.matrix[:, seen] / jac.norms[seen], compute_uv=False)[0])


def residual_change(jac: JointJacobian, confound: Confound, across: bool = False) -> float:
    """How much the residuals change (exactly, not linearised) for a small move along the
    confound — or across it, every component but the largest reversed — relative to the
    largest change a move of that size in any direction makes (the largest singular value of
    the unit-column Jacobian): the relative singular value, measured."""
    by_name = {c.name: c for c in jac.columns}
    size = 0.1 / max(
        abs(c.per_unit) / by_name[c.name].parameter.scale  # type: ignore[union-attr]
        for c in confound.components
        if c.robot
    )  # the largest robot change a tenth of its parameter's scale
    top = max(confound.components, key=lambda c: abs(c.weight))
    step = {
        c.name: size * c.per_unit * (-1.0 if across and c is not top else 1.0)
        for c in confound.components
    }
    moved = jac.residuals(step) - jac.residuals({})
    return float(np.linalg.norm(moved)) / (size * largest_singular_value(jac))


def assert_a_confound(jac: JointJacobian, confound: Confound) -> None:
    """The reported direction leaves the residuals as they were (< 1e-3 relative) and the
    direction across it does not (> 0.1)."""
    along = residual_change(jac, confound)
    assert along < RELATIVE_SINGULAR_VALUE, (confound.direction(), along)
    assert residual_change(jac, confound, across=True) > 0.1, confound.direction()


def only(confounds: list[Confound], robot: set[str]) -> Confound:
    found = [c for c in confounds if set(c.robot) == robot]
    assert len(found) == 1, [c.direction() for c in confounds]
    return found[0]


def reading(confound: Confound, name: str) -> float:
    return dict(confound.robot_reading + confound.nuisance_reading)[name]


def per_unit(confound: Confound, name: str) -> float:
    return next(c.per_unit for c in confound.components if c.name == name)


@pytest.fixture(scope="module")
def clean_runs() -> list[Run]:
    return generate(IndependentRobot(), rich_protocol(), np.random.default_rng(5))


@pytest.fixture(scope="module")
def clean(clean_runs: list[Run]) -> tuple[OpenLoopData, OpenLoopFit, JointJacobian, list[Confound]]:
    return fitted(clean_runs, GEOMETRY)


def test_a_rigid_motion_of_the_whole_frame_is_invisible(
    clean: tuple[OpenLoopData, OpenLoopFit, JointJacobian, list[Confound]],
) -> None:
    _, _, jac, _ = clean
    assert set(jac.invisible) == {"gt.translation_x", "gt.translation_y", "gt.rotation"}
    for name in ("time_offset", "tracked_dx", "tracked_dy", "frame_yaw", "gt.scale"):
        assert name in jac.names
    assert "gt.clock_rate" in jac.names


def test_effect_free_data_move_along_no_confound(
    clean: tuple[OpenLoopData, OpenLoopFit, JointJacobian, list[Confound]],
) -> None:
    """E_d, E_b, E_s fitted to a robot without effects: the frame scale is a confound whether or
    not anything moved along it (the only one of the geometry), and the fit did not move."""
    _, _, jac, confounds = clean
    assert [set(c.robot) for c in confounds] == [{"wheelbase.e_b", "distance_scale.e_s"}]
    for confound in confounds:
        assert not confound.moved, confound.sentence()
        assert_a_confound(jac, confound)


def test_a_frame_scaled_by_half_a_percent_reads_as_wheels_and_wheelbase_half_a_percent_larger(
    clean_runs: list[Run],
) -> None:
    """Measured positions scaled by 1.005 about (1, −0.5) m, fitted with E_d, E_b, E_s: the fit
    moves E_s and E_b by +0.5 % together; the confound says so, reads it equally as the frame
    scaled by +0.5 %, and names the measurement check (no robot experiment separates them).
    Tolerance: three standard errors of the projection (about 1e-4 each), and 5e-5 between the
    two readings (first order: the columns are taken at the fitted, scaled model). The
    confound is within the 1e-3 rule, not exact: the open-loop error aligns each prediction on
    the measured poses of a run's first second, and a frame scaled about a point far
    from the run moves those poses by a little more than the scaled robot moves its
    prediction there."""
    scaled = []
    for run in clean_runs:
        pose = run.true_pose.copy()
        pose[:, :2] = CENTRE + SCALE * (pose[:, :2] - CENTRE)
        scaled.append(dataclasses.replace(run, true_pose=pose))
    _, _, jac, confounds = fitted(scaled, GEOMETRY)
    confound = only(confounds, {"wheelbase.e_b", "distance_scale.e_s"})
    assert confound.nuisances == ("gt.scale",)
    assert confound.relative_singular_value < RELATIVE_SINGULAR_VALUE
    # Analytically a common change: per unit of the direction, E_s, E_b and −scale alike.
    e_s, e_b = per_unit(confound, "distance_scale.e_s"), per_unit(confound, "wheelbase.e_b")
    assert e_b == pytest.approx(e_s, rel=1e-3)
    assert -per_unit(confound, "gt.scale") == pytest.approx(e_s, rel=1e-2)
    assert confound.moved
    tolerance = 3.0 * confound.move_stderr * abs(e_s)
    assert tolerance < 5e-4
    for name in ("distance_scale.e_s", "wheelbase.e_b", "gt.scale"):
        assert abs(reading(confound, name) - (SCALE - 1.0)) < tolerance, name
    assert abs(reading(confound, "gt.scale") - reading(confound, "distance_scale.e_s")) < 5e-5
    assert confound.experiment is None
    assert confound.check is not None and "known distance" in confound.check
    assert "+0.50" in confound.sentence()
    assert_a_confound(jac, confound)


def test_a_wheel_toe_on_one_session_is_a_frame_yaw() -> None:
    """A 5 mrad wheel toe fitted beside the geometry on one session: it trades against the
    frame yaw (which diagnose does not fit with one session) — exactly before the alignment on
    a run's first second, within the 1e-3 rule with it (the robot's column is taken on the
    measured runs, whose aligned start moves with their noise; the yaw's along the prediction);
    the fit moved along it, and the two readings are a toe τ and a yaw −τ."""
    runs = generate(
        IndependentRobot(effects={"wheel_toe": {"angle": TOE}}),
        rich_protocol(),
        np.random.default_rng(7),
    )
    _, _, jac, confounds = fitted(runs, (*GEOMETRY, "wheel_toe"))
    confound = only(confounds, {"wheel_toe.angle"})
    assert confound.nuisances == ("frame_yaw",)
    assert confound.relative_singular_value < RELATIVE_SINGULAR_VALUE
    assert confound.moved and not confound.fitted
    toe = reading(confound, "wheel_toe.angle")
    assert abs(toe - TOE) < 3.0 * confound.move_stderr * per_unit(confound, "wheel_toe.angle")
    # τ = −δ to first order (exactly before the alignment on the first second; 3e-5 with it).
    assert reading(confound, "frame_yaw") == pytest.approx(-toe, rel=1e-3)
    assert confound.experiment is None
    assert confound.check is not None and "markers" in confound.check
    assert_a_confound(jac, confound)


def test_the_ground_truth_sensor_offset_is_a_tracked_point() -> None:
    """``gt_sensor_offset`` (10, −5) mm fitted beside the geometry: each of dx, dy trades
    against the tracked point's (within the 1e-3 rule: see the toe), and the readings are the
    same offset."""
    runs = generate(
        IndependentRobot(effects={"gt_sensor_offset": {"dx": 0.01, "dy": -0.005}}),
        rich_protocol(),
        np.random.default_rng(8),
    )
    _, _, jac, confounds = fitted(runs, (*GEOMETRY, "gt_sensor_offset"))
    for axis, truth in (("dx", 0.01), ("dy", -0.005)):
        confound = only(confounds, {f"gt_sensor_offset.{axis}"})
        assert confound.nuisances == (f"tracked_{axis}",)
        assert confound.relative_singular_value < RELATIVE_SINGULAR_VALUE
        assert confound.moved
        value = reading(confound, f"gt_sensor_offset.{axis}")
        assert value == pytest.approx(truth, abs=1e-3)
        assert reading(confound, f"tracked_{axis}") == pytest.approx(value, rel=1e-6)
        assert_a_confound(jac, confound)


def test_closed_squares_at_their_end_points_cannot_tell_wheelbase_from_distance_scale() -> None:
    """UMBmark-style logs (squares, ground truth at the end points only) of a robot with
    E_b = 1.01, fitted with E_b and E_s: every corner sees E_s/E_b alone, so a common change of
    the two is a confound of the robot with itself — reported as such (no nuisance in it), the
    fit free along it, and a straight run named to separate them."""
    squares = [m for m in rich_protocol() if m.kind == "square"] * 3
    runs = generate(
        IndependentRobot(effects={"wheelbase": {"e_b": 1.01}}),
        squares,
        np.random.default_rng(9),
        endpoints_only=True,
    )
    _, fit, jac, confounds = fitted(runs, ("wheelbase", "distance_scale"))
    confound = only(confounds, {"wheelbase.e_b", "distance_scale.e_s"})
    assert confound.nuisances == ()
    assert confound.relative_singular_value < RELATIVE_SINGULAR_VALUE
    weights = [c.weight for c in confound.components]
    assert all(w > 0.5 for w in weights), weights  # a common change: E_s/E_b stays
    assert confound.fitted and not confound.moved
    assert confound.experiment is not None and confound.experiment.startswith("straight")
    assert "cannot be told apart" in confound.sentence()
    # What the data do determine: the ratio the corners see.
    ratio = fit.values["wheelbase.e_b"] / fit.values["distance_scale.e_s"]
    assert ratio == pytest.approx(1.01, abs=2e-3)
    assert_a_confound(jac, confound)


def cruising(run: Run, start: float, end: float) -> Run:
    """``run`` from ``start`` of its samples on (time and counts from there), its ground truth
    blanked after ``end``: a straight measured only while it cruises at constant speed. The
    counts run on to the stop, as a log's counts do beyond its last ground-truth sample."""
    first, last = int(len(run.time) * start), int(len(run.time) * end)
    pose = run.true_pose[first:].copy()
    pose[last - first :] = np.nan
    return dataclasses.replace(
        run,
        time=run.time[first:] - run.time[first],
        counts=run.counts[first:] - run.counts[first],
        true_pose=pose,
    )


def smallest_relative(jac: JointJacobian, names: tuple[str, ...]) -> float:
    index = [jac.names.index(n) for n in names]
    values = np.linalg.svd(jac.matrix[:, index] / jac.norms[index], compute_uv=False)
    return float(values[-1] / values[0])


def test_a_clock_rate_is_a_distance_scale_only_while_the_robot_cruises() -> None:
    """3 m straights at 0.3 m/s. Measured from start to stop, a clock rate ρ (the ground
    truth's stamps running fast) is told from a distance scale and a time offset: once the
    robot stops its counts stop, a scale's travel does not. Measured only while the robot
    cruises, ρ shifts the counts by ρ·v·(t − t₀), as a scale ε·v·(t − t₀) does: a confound
    (found at 4e-4, below the 1e-3 rule), reported beside the frame scale's, and an
    experiment that stops names what separates them."""
    straights = [Manoeuvre("straight", size=3.0, speed=0.3, label="straight_oneway")] * 4
    runs = generate(IndependentRobot(), straights, np.random.default_rng(4))
    columns = ("distance_scale.e_s", "time_offset", "gt.clock_rate")
    _, _, stopping, found = fitted(runs, ("distance_scale",))
    assert smallest_relative(stopping, columns) > 0.1
    assert all("gt.clock_rate" not in c.nuisances for c in found)
    cruise = [cruising(r, 0.2, 0.7) for r in runs]
    _, _, jac, confounds = fitted(cruise, ("distance_scale",))
    assert smallest_relative(jac, columns) < RELATIVE_SINGULAR_VALUE
    clock = [c for c in confounds if c.nuisances == ("gt.clock_rate",)]
    assert len(clock) == 1, [c.direction() for c in confounds]
    assert clock[0].robot == ("distance_scale.e_s",)
    # The same physical change: E_s + ε and a clock running ε fast (per unit of the direction).
    assert per_unit(clock[0], "gt.clock_rate") == pytest.approx(
        per_unit(clock[0], "distance_scale.e_s"), rel=0.05
    )
    assert clock[0].experiment is not None
    assert_a_confound(jac, clock[0])
    assert any(c.nuisances == ("gt.scale",) for c in confounds)


def test_two_sessions_with_their_frames_fitted_leave_the_toe_free() -> None:
    """Two sessions, their frames fitted (as diagnose does with several sessions) beside a
    wheel toe: the toe trades against every session's yaw at once, named per session, and the
    fit is free along it (its values there say nothing); the frame scale trades against both
    sessions' scales."""
    rng = np.random.default_rng(11)
    robot = IndependentRobot(effects={"wheel_toe": {"angle": 0.004}})
    runs = [
        dataclasses.replace(run, meta={**run.meta, "session": session})
        for session in ("A", "B")
        for run in generate(robot, rich_protocol()[:12], rng)
    ]
    _, _, jac, confounds = fitted(runs, (*GEOMETRY, "wheel_toe"), NuisanceOptions(frames=True))
    assert "gt.rotation[A]" in jac.invisible and "gt.rotation[B]" in jac.invisible
    confound = only(confounds, {"wheel_toe.angle"})
    assert set(confound.nuisances) == {"frame_yaw[A]", "frame_yaw[B]"}
    assert confound.fitted and not confound.moved
    assert "not determined" in confound.sentence()
    # The frame scale, in both sessions at once; nothing moved along it (the sessions' sandwich
    # alone, rank 1 with two sessions, would have said 19 standard errors).
    scale = only(confounds, {"wheelbase.e_b", "distance_scale.e_s"})
    assert set(scale.nuisances) == {"gt.scale[A]", "gt.scale[B]"}
    assert not scale.moved, scale.sentence()


def test_ground_truth_errors_are_removed_exactly() -> None:
    """:class:`GroundTruthError.remove` undoes :meth:`~GroundTruthError.apply`: poses to
    rounding, counts exactly where they are linear in time (a constant speed)."""
    time = np.linspace(0.0, 10.0, 101)
    counts = np.stack([100.0 * time, 120.0 * time], axis=1)
    pose = np.stack([0.1 * time, 0.02 * time**2, 0.3 * np.sin(time)], axis=1)
    run = Run("free", time, counts, pose, meta={"session_time": 5.0})
    error = GroundTruthError(0.3, -0.2, 0.4, 0.01, 2e-3)
    back = error.remove(error.apply(run))
    np.testing.assert_allclose(back.true_pose, pose, atol=1e-12)
    # The clock's times run ρ·(t − t_ref) past the log at both ends (t_ref 5 s before the run
    # starts), where the counts are held: compare inside.
    inside = (time > 0.05) & (time < 9.9)
    np.testing.assert_allclose(back.counts[inside], counts[inside], atol=1e-9)
    logged = error.apply(run)
    radius = np.hypot(*(pose[-1, :2] - pose[0, :2]))
    assert np.hypot(*(logged.true_pose[-1, :2] - logged.true_pose[0, :2])) == pytest.approx(
        1.01 * radius
    )


def test_confounds_are_deterministic_and_json_safe(
    clean_runs: list[Run], clean: tuple[OpenLoopData, OpenLoopFit, JointJacobian, list[Confound]]
) -> None:
    data, fit, _, confounds = clean
    again = derive_confounds(data, fit, NOMINAL_ROBOT)
    assert [c.as_dict() for c in again] == [c.as_dict() for c in confounds]
    text = json.dumps([c.as_dict() for c in confounds], allow_nan=False)
    assert "gt.scale" in text
    for confound in confounds:
        sentence = confound.sentence()
        assert "\n" not in sentence and sentence.endswith(".")
        assert math.isfinite(confound.relative_singular_value)

"""The CLAPPER's experiments as the paper ran them (Borenstein 1995, §6): seeded sets of runs on
the one stated floor, judged by the paper's own figures.

Tolerances come from the paper (±1.0°, 5 cm, "more than 20-fold", 0.3° average measured to
±0.25°) or from a stated model (each cable turns a truck by the rigid-cylinder geometry of
:func:`odomgym.sim.cables.bump_extra_rotation` and costs the crossing wheel half that in centre
travel), never from a measured value.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from odomgym.floor import FloorSpec, load_floor
from odomgym.sim.cables import bump_extra_rotation
from odomgym.vehicle.cable_layout import CableLayer, evenly
from odomgym.vehicle.ipec import ipec_estimator
from odomgym.vehicle.paper_runs import PAPER_CONDITIONS, run_clapper, summarize
from odomgym.vehicle.paths import straight_path
from odomgym.vehicle.spec import VEHICLES
from odomgym.vehicle.trial import CLAPPER_FLOOR, drive_vehicles

CLAPPER = VEHICLES["clapper"]
TRUCK = CLAPPER.truck_a
EXCESS = bump_extra_rotation(0.5 * TRUCK.true_right_diameter, 0.010)  # rim over ground [m]
PER_BUMP = EXCESS / TRUCK.true_wheelbase  # one crossing turns a truck by this [rad]


def _ipec(name: str = "recommended"):  # type: ignore[no-untyped-def]
    return ipec_estimator(name, CLAPPER.rotary_resolution)


@pytest.mark.slow
def test_straight_conditions_a_to_d() -> None:
    """§6.1, three runs per condition on the stated floor. b: ten cables turn each truck by ten
    crossings (the paper: −6° of its −7.7°, 0.6° each); d: "In all runs the return orientation
    error with IPEC was less than ±1.0°" — for the vehicle and for each truck. The follower
    holds its rotary encoder (§5.2), so the linkage never reaches its end stops and both
    trucks cross every cable."""
    runs = run_clapper(
        CLAPPER,
        load_floor(CLAPPER_FLOOR),
        "straight",
        conditions=PAPER_CONDITIONS["straight"],
        runs=3,
        seed=0,
        ipec=_ipec(),
    )
    assert len(runs) == 12 and all(r.outcome.finished[0] for r in runs)
    for run in runs:
        assert run.outcome.link_force[0] == 0.0, run.record()
        assert list(run.outcome.cable_crossings[0]) == [run.bumps, run.bumps], run.record()
    summary = summarize(runs)["conditions"]
    for truck in ("theta_truck_a", "theta_truck_b"):
        # Ten crossings' rotation, give or take what the floor alone leaves the same truck in
        # condition a (its mean absolute error plus two standard deviations).
        floor_alone = summary["a"][truck]["mean_abs"] + 2.0 * summary["a"][truck]["sd"]
        assert abs(summary["b"][truck]["mean_abs"] - 10 * PER_BUMP) < floor_alone, summary["b"]
    # The paper ran three runs per condition; over six, one run ends at 1.03° (docs/clapper.md,
    # "Missed, measured"), so this pins the paper's protocol, not a claim about every run.
    for key in ("theta_vehicle", "theta_truck_a", "theta_truck_b"):
        assert math.degrees(summary["d"][key]["worst"]) < 1.0, summary["d"]
    # The floor makes runs of one condition differ (distributions, not one run).
    assert summary["a"]["theta_truck_a"]["sd"] > 0.0


@pytest.mark.slow
def test_rectangle_ten_cw_and_ten_ccw() -> None:
    """§6.2: 10 cw + 10 ccw runs with ten cables (right wheels in half the runs, left in the
    other half), with and without IPEC. "None of the 20 runs produced a position error of more
    than 5 cm"; "a more than 20-fold reduction in orientation errors" (the vehicle's, as the
    paper measured it); the IPEC average 0.3°, measured to about ±0.25° (§6), so at most
    0.55° here. Each truck's own heading improves at least ten-fold."""
    runs = run_clapper(
        CLAPPER,
        load_floor(CLAPPER_FLOOR),
        "rectangle",
        conditions=PAPER_CONDITIONS["rectangle"],
        directions=("cw", "ccw"),
        sides=("right", "left"),
        runs=10,
        seed=0,
        ipec=_ipec(),
    )
    assert len(runs) == 40 and all(r.outcome.finished[0] for r in runs)
    assert all(list(r.outcome.cable_crossings[0]) == [10, 10] for r in runs)
    summary = summarize(runs)
    with_ipec = summary["conditions"]["with IPEC"]
    assert with_ipec["runs"] == 20 and with_ipec["position"]["worst"] < 0.05
    assert math.degrees(with_ipec["theta_vehicle"]["mean_abs"]) < 0.3 + 0.25
    assert summary["reduction"]["theta_vehicle"] > 20.0, summary["reduction"]
    assert summary["reduction"]["theta_truck_a"] > 10.0
    assert summary["reduction"]["theta_truck_b"] > 10.0
    assert all(r.outcome.link_force[0] == 0.0 for r in runs)


def _along(configuration: str, cables: int) -> float:
    """The return error along the path [m] (x) of one 36 m straight run on a smooth floor."""
    layer = CableLayer(evenly(cables)) if cables else None
    out = drive_vehicles(
        CLAPPER, FloorSpec(), straight_path(18.0), estimator=_ipec(configuration), cables=layer
    )
    return float(out.return_error[0, 0])


@pytest.mark.slow
def test_gated_eq_15_of_the_recommended_configuration_removes_the_cable_travel_loss() -> None:
    """Each crossing costs truck A's centre half the wheel's excess rim travel (1.70 mm), which
    its dead reckoning counts as progress: without Eq. 15 twenty cables leave 20 × 1.70 mm of
    travel uncorrected. The recommended configuration (corrections consistent with the 10-bit
    readings, Eq. 15 gated to one count in straight travel) takes at least half of it out and
    does not overshoot. The issue's literal gate (``gated``: one count, straight travel) and the
    printed Eq. 15 (``paper``) both overshoot — the follower holds ψ_A at a count boundary
    and every flip there fires Eq. 15 (docs/clapper.md)."""
    loss = 20 * 0.5 * EXCESS
    names = ("heading-only", "recommended", "gated", "paper")
    base = {name: _along(name, 0) for name in names}
    left = {name: _along(name, 20) - base[name] for name in names}
    assert left["heading-only"] == pytest.approx(loss, rel=0.1)
    assert abs(left["recommended"]) < 0.5 * loss, left
    assert left["recommended"] > -0.1 * loss, left  # no overshoot
    assert left["gated"] < -0.1 * loss and left["paper"] < -0.5 * loss, left


@pytest.mark.slow
def test_the_old_controller_lets_the_trucks_drift_apart() -> None:
    """Why the follower holds its encoder: steering each truck by its own dead reckoning
    (``steering="pose"``), the trucks drift apart without IPEC and the linkage hits its end stop
    on the smooth rectangle with cables (the inflated baseline of the earlier controller);
    holding ψ, it never does."""
    from odomgym.vehicle.cable_layout import rectangle_cable_positions
    from odomgym.vehicle.controller import VehicleDriver
    from odomgym.vehicle.paths import rectangle_path

    path = rectangle_path(direction="cw")
    forces = {}
    for steering in ("pose", "psi"):
        layer = CableLayer(rectangle_cable_positions(path, 10), leg=0, side="right")
        out = drive_vehicles(
            VEHICLES["clapper-uncalibrated"],
            FloorSpec(),
            path,
            cables=layer,
            driver=VehicleDriver(steering=steering),  # type: ignore[arg-type]
        )
        forces[steering] = float(out.link_force[0])
    assert forces["pose"] > 100.0 and forces["psi"] == 0.0, forces


def test_run_records_carry_force_crossings_and_trucks() -> None:
    runs = run_clapper(
        CLAPPER,
        FloorSpec(),
        "straight",
        conditions=PAPER_CONDITIONS["straight"][1:2],
        runs=1,
        ipec=_ipec(),
    )
    record = runs[0].record()
    assert record["condition"] == "b" and record["cable_crossings"] == {"A": 10, "B": 10}
    assert record["link_force_max_n"] == 0.0 and len(record["link_range_m"]) == 2
    assert set(record["trucks"]) == {"A", "B"}
    assert np.isfinite(record["corrections_rad"]["A"])


# ---------------------------------------------------------------------- the encoder trailer (§7)
def test_trailer_readings_come_from_one_rotary_encoder() -> None:
    """The trailer's rigid tongue fixes ψ_B at 0 and the length at the tongue's; only the hitch
    encoder (ψ_A) reads anything."""
    from odomgym.vehicle.spec import link_readings

    spec = VEHICLES["trailer"]
    poses = np.array([[[1.0, 0.0, 0.2], [0.0, 0.05, 0.1]]])
    reading = link_readings(spec, poses)
    assert reading.psi[0, 1] == 0.0 and reading.length[0] == spec.link_length
    assert reading.psi[0, 0] != 0.0


@pytest.mark.slow
def test_trailer_is_towed_and_its_free_wheels_count_the_arc_over_a_cable() -> None:
    """The towed trailer follows the robot out and back, and its free-rolling wheels, pulled
    over ten cables on the return leg, over-count like a driven wheel: its own dead reckoning
    turns by ten rigid-cylinder crossings of its 100 mm wheels on its 0.3 m track (7.9°,
    :func:`bump_extra_rotation`)."""
    from odomgym.vehicle.trial import VehicleTrial

    spec = VEHICLES["trailer"]
    trailer = spec.truck_b
    # Free-rolling: at steady speed on the flat the hitch passes next to no force (a wheel
    # that resisted rolling would show up here).
    trial = VehicleTrial(spec, FloorSpec(), straight_path(18.0, back=False))
    steady = []
    while not trial.done.all():
        trial.step()
        if abs(float(trial.driver.reference_speed[0]) - trial.driver.cruise_speed) < 1e-9:
            steady.append(float(trial.current_link_force()[0]))
    assert steady and max(steady) < 2.0, max(steady)
    out = drive_vehicles(spec, FloorSpec(), straight_path(18.0), cables=CableLayer(evenly(10)))
    assert out.finished[0]
    assert abs(float(out.link_range[0, 1]) - spec.link_length) < 0.01  # a rigid tongue
    per_cable = bump_extra_rotation(0.5 * trailer.true_left_diameter, 0.010)
    expected = 10 * per_cable / trailer.true_wheelbase
    assert abs(float(out.truck_errors[0, 1, 2])) == pytest.approx(expected, rel=0.05)
    assert list(out.cable_crossings[0]) == [10, 10]
    # With IPEC and a fine hitch encoder the trailer's heading is corrected.
    import dataclasses

    fine = dataclasses.replace(spec, rotary_bits=16)
    corrected = drive_vehicles(
        fine,
        FloorSpec(),
        straight_path(18.0),
        cables=CableLayer(evenly(10)),
        estimator=ipec_estimator("recommended", fine.rotary_resolution),
    )
    assert np.all(
        np.abs(np.degrees(corrected.truck_errors[0, :, 2])) < 0.1 * math.degrees(expected)
    )


# ---------------------------------------------------------------------- more error sources
@pytest.mark.slow
def test_a_compliant_tyre_feels_a_thinner_cable() -> None:
    """``tyre_compression`` δ: the wheel climbs only d − δ, so ten crossings turn a truck by
    ten rigid-cylinder crossings of a (d − δ) cable."""
    import dataclasses

    spec = dataclasses.replace(CLAPPER, tyre_compression=0.002)
    out = drive_vehicles(spec, FloorSpec(), straight_path(18.0), cables=CableLayer(evenly(10)))
    thinner = bump_extra_rotation(0.5 * TRUCK.true_right_diameter, 0.008) / TRUCK.true_wheelbase
    assert abs(float(out.truck_errors[0, 0, 2])) == pytest.approx(10 * thinner, rel=0.05)
    assert thinner < PER_BUMP


def test_the_sonar_measures_the_return_pose_within_its_accuracy() -> None:
    """``sonar=SONAR``: every reported return error is the true one plus at most ±2 mm and
    ±0.25° (Borenstein 1995, §6), drawn from its own stream: the runs themselves are the
    same as without it."""
    from odomgym.vehicle.paper_runs import SONAR

    plain, measured = (
        run_clapper(
            CLAPPER,
            FloorSpec(),
            "straight",
            conditions=PAPER_CONDITIONS["straight"][2:3],
            runs=2,
            ipec=_ipec(),
            sonar=sonar,
        )
        for sonar in (None, SONAR)
    )
    for a, b in zip(plain, measured, strict=True):
        np.testing.assert_array_equal(a.outcome.return_error, b.outcome.return_error)
        vehicle, trucks = b.measured()
        shift = vehicle - a.outcome.return_error[0]
        assert np.all(np.abs(shift[:2]) <= SONAR[0]) and abs(shift[2]) <= SONAR[1]
        assert np.any(shift != 0.0)
        np.testing.assert_allclose(trucks - a.outcome.truck_errors[0], shift[None, :].repeat(2, 0))
        assert b.record()["sonar_error"] is not None and a.record()["sonar_error"] is None

"""The CLAPPER driven in the World, with and without IPEC (Borenstein 1995, §§5–6): single
deterministic runs on a smooth floor, for the physics (per-bump error, §5.1 auto-calibration,
§5.2 encoder and link biases, the §3.3 growth rate). The paper's experiments as distributions
on the stated floor are in tests/test_clapper_paper.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from odomgym.floor import FloorSpec
from odomgym.sim.cables import bump_extra_rotation
from odomgym.vehicle.cable_layout import CableLayer, evenly, rectangle_cable_positions
from odomgym.vehicle.controller import VehicleDriver
from odomgym.vehicle.estimator import DeadReckoning, growth_rate
from odomgym.vehicle.ipec import estimate_wheel_diameter_ratio, ipec_configuration
from odomgym.vehicle.paths import circle_path, rectangle_path, straight_path
from odomgym.vehicle.spec import VEHICLES, VehicleSpec
from odomgym.vehicle.trial import VehicleTrial, drive_vehicles

CLAPPER = VEHICLES["clapper"]
TRUCK = CLAPPER.truck_a
# One crossing turns a truck by the cable's excess rim travel over its true wheelbase: 0.58°
# for a LabMate over a 10 mm cable (Borenstein 1995 measured "approximately 0.6°", §6.1).
PER_BUMP = bump_extra_rotation(0.5 * TRUCK.true_right_diameter, 0.010) / TRUCK.true_wheelbase
# The estimator of these physics tests: IPEC's "heading-only" configuration (midpoint dead
# reckoning, Eqs. 9-13 and 16 without the composite translational correction of Eqs. 14-15),
# so that each test sees only the effect it is about; the configurations are compared in
# tests/test_clapper_paper.py and docs/clapper.md.
CLAPPER_IPEC = ipec_configuration("heading-only")


@pytest.mark.slow
def test_straight_without_ipec_accumulates_every_bump() -> None:
    """§6.1: without IPEC, ten bumps under the right wheels on the return leg leave a return
    orientation error of ten per-bump errors (the paper: −6° of its −7.7°, the rest
    systematic). Out and back retraces the systematic arc, so here the bumps are nearly all."""
    layer = CableLayer(evenly(10))
    out = drive_vehicles(CLAPPER, FloorSpec(), straight_path(18.0), cables=layer)
    assert out.finished.all() and len(layer.laid) == 10
    heading = abs(float(out.return_error[0, 2]))
    assert heading == pytest.approx(10 * PER_BUMP, rel=0.05)
    assert np.all(out.link_force == 0.0)  # the bearing never reached its ends


@pytest.mark.slow
def test_straight_with_ipec_and_twenty_bumps_stays_within_one_degree() -> None:
    """§6.1: "In all runs the return orientation error with IPEC was less than ±1.0°" with 20
    bumps on the 36 m path."""
    layer = CableLayer(evenly(20))
    out = drive_vehicles(
        CLAPPER, FloorSpec(), straight_path(18.0), cables=layer, estimator=CLAPPER_IPEC
    )
    assert out.finished.all() and len(layer.laid) == 20
    assert abs(math.degrees(float(out.return_error[0, 2]))) < 1.0
    # Without IPEC the same 20 bumps would leave 20 per-bump errors (11.6°).
    assert abs(float(out.return_error[0, 2])) < 0.1 * 20 * PER_BUMP


@pytest.mark.slow
@pytest.mark.parametrize("direction", ["cw", "ccw"])
def test_rectangle_on_a_smooth_floor(direction: str) -> None:
    """§6.2's 7×4 m rectangle with smooth turns: the controller keeps the linkage inside its
    range (no end-stop force) and IPEC's return orientation error on a smooth floor stays below
    1° (the paper's smooth-floor IPEC runs were "almost indistinguishable" from its bumpy ones,
    0.3° on average)."""
    out = drive_vehicles(
        CLAPPER, FloorSpec(), rectangle_path(direction=direction), estimator=CLAPPER_IPEC
    )
    assert out.finished.all()
    assert np.all(out.link_force == 0.0)
    assert CLAPPER.link_min < out.link_range[0, 0] and out.link_range[0, 1] < CLAPPER.link_max
    assert abs(math.degrees(float(out.return_error[0, 2]))) < 1.0
    assert float(np.hypot(*out.return_error[0, :2])) < 0.05  # "None ... more than 5 cm"


@pytest.mark.slow
@pytest.mark.parametrize("direction", ["cw", "ccw"])
def test_rectangle_with_bumps_ipec_cuts_orientation_error_tenfold(direction: str) -> None:
    """§6.2: ten bumps per run, under the right-side wheels in half the runs and the left in the
    other half; IPEC "resulted in a more than 20-fold reduction in orientation errors" (the
    average absolute return orientation error). The issue asks for at least 10-fold here, in
    both directions; every IPEC run must also end within 5 cm ("None of the 20 runs produced a
    position error of more than 5 cm")."""
    path = rectangle_path(direction=direction)  # type: ignore[arg-type]
    errors: dict[str, list[float]] = {"dr": [], "ipec": []}
    for side in ("right", "left"):
        for name, estimator in (("dr", None), ("ipec", CLAPPER_IPEC)):
            layer = CableLayer(rectangle_cable_positions(path, 10), leg=0, side=side)  # type: ignore[arg-type]
            out = drive_vehicles(CLAPPER, FloorSpec(), path, estimator=estimator, cables=layer)
            assert out.finished.all() and len(layer.laid) == 10
            errors[name].append(abs(float(out.return_error[0, 2])))
            if name == "ipec":
                assert float(np.hypot(*out.return_error[0, :2])) < 0.05
    assert np.mean(errors["dr"]) >= 10.0 * np.mean(errors["ipec"])
    assert math.degrees(max(errors["ipec"])) < 1.0


IDEAL = TRUCK.ideal()


def _with(**changes: object) -> VehicleSpec:
    return dataclasses.replace(CLAPPER, **changes)  # type: ignore[arg-type]


@pytest.mark.slow
@pytest.mark.parametrize("direction", ["cw", "ccw"])
def test_ipec_corrects_unequal_wheel_diameters_on_a_smooth_floor(direction: str) -> None:
    """§5.1: IPEC compensates systematic errors that turn the trucks. Both trucks with
    E_d = 1.005 (0.84° per metre of dead-reckoned turn): the 7×4 m rectangle ends tens of degrees
    off without IPEC, within 1° with it."""
    truck = IDEAL.with_errors(1.005, 1.0)
    spec = _with(truck_a=truck, truck_b=truck)
    plain = drive_vehicles(spec, FloorSpec(), rectangle_path(direction=direction))
    ipec = drive_vehicles(
        spec, FloorSpec(), rectangle_path(direction=direction), estimator=CLAPPER_IPEC
    )
    assert abs(math.degrees(float(plain.return_error[0, 2]))) > 10.0
    assert abs(math.degrees(float(ipec.return_error[0, 2]))) < 1.0


@pytest.mark.slow
def test_auto_calibration_reads_e_d_from_ipecs_corrections() -> None:
    """§5.1: "unequal wheel-diameters ... are automatically calibrated by monitoring the
    corrective actions of the CLAPPER while traveling on smooth surfaces": 18 m straight with
    E_d = 1.005 trucks; the summed corrections give E_d within 5 % of E_d − 1 (the quantised
    readings' last step, ≤ 0.35°, is b·q/D = 1e-4 of it)."""
    truck = IDEAL.with_errors(1.005, 1.0)
    spec = _with(truck_a=truck, truck_b=truck)
    out = drive_vehicles(spec, FloorSpec(), straight_path(18.0, back=False), estimator=CLAPPER_IPEC)
    travelled = float(np.hypot(*out.estimated[0, 0, :2]))  # straight: |end − start|
    e_d = estimate_wheel_diameter_ratio(out.corrections[0], travelled, TRUCK.wheelbase)
    np.testing.assert_allclose(e_d - 1.0, 0.005, rtol=0.05)


@pytest.mark.slow
def test_ipec_cannot_see_a_rotary_encoder_bias() -> None:
    """§5.2: encoder A reading +β and B −β too much makes the controller, holding the readings
    straight, drive an arc of radius l/(2 sin β) "instead of straight", and IPEC's estimate stays
    straight. β = 0.25°, 18 m: the truth turns ~9°, the estimate not at all. (Measured: 10% more
    than the rigid-chord prediction, because truck B lags the arc; tolerance 15 %.)"""
    beta = math.radians(0.25)
    spec = _with(truck_a=IDEAL, truck_b=IDEAL, rotary_bias_a=beta, rotary_bias_b=-beta)
    out = drive_vehicles(spec, FloorSpec(), straight_path(18.0, back=False), estimator=CLAPPER_IPEC)
    predicted = 18.0 * 2.0 * math.sin(beta) / spec.link_length  # s / ρ [rad]
    assert abs(float(out.true_poses[0, 0, 2])) == pytest.approx(predicted, rel=0.15)
    assert abs(math.degrees(float(out.estimated[0, 0, 2]))) < 0.1  # IPEC sees a straight path
    assert abs(float(out.return_error[0, 2])) == pytest.approx(predicted, rel=0.15)


@pytest.mark.slow
def test_link_length_bias_costs_a_third_of_a_degree_per_mm_and_turn() -> None:
    """§5.2: "a constant bias of 1 mm in the measurement of the link-length l causes an
    orientation error of roughly 1° for every full 360° turn". odomgym gives the first-order
    law of the anchoring (Eq. 16): 2π·Δl/l = 0.36° per mm per turn, against a bias-free run,
    sign flipping with the turn direction; the paper's informal figure is ~2.8× larger
    (docs/clapper_design_notes.md §4 discusses why)."""
    spec = _with(truck_a=IDEAL, truck_b=IDEAL)
    per_mm = {}
    for direction in ("ccw", "cw"):
        heading = {}
        for bias in (0.0, 0.002):
            out = drive_vehicles(
                dataclasses.replace(spec, linear_bias=bias),
                FloorSpec(),
                circle_path(direction=direction),  # type: ignore[arg-type]
                estimator=CLAPPER_IPEC,
            )
            heading[bias] = float(out.return_error[0, 2])
        per_mm[direction] = math.degrees(heading[0.002] - heading[0.0]) / 2.0
    first_order = math.degrees(2.0 * math.pi * 1e-3 / spec.link_length)
    assert abs(per_mm["ccw"]) == pytest.approx(first_order, rel=0.10)
    assert per_mm["cw"] == pytest.approx(-per_mm["ccw"], rel=0.05)


@pytest.mark.slow
def test_growth_rate_concept_in_the_world() -> None:
    """§3.3: at 0.5 m/s and T_s = 40 ms a bump's orientation error α can only grow a lateral
    error of about U·α in the one interval before IPEC sees it (U = 20 mm; the paper: 0.15 mm
    for its α = 0.44°), and IPEC measures α itself within a few % (the paper: 2.3 %). One cable
    under truck A's right wheel; 24-bit rotary encoders, so that the concept is not hidden by
    the 0.35° counts (which bound the measurement to ±q/2 per reading instead)."""
    spec = _with(truck_a=IDEAL, truck_b=IDEAL, rotary_bits=24)
    trial = VehicleTrial(
        spec,
        FloorSpec(),
        straight_path(6.0, back=False),
        estimator=CLAPPER_IPEC,
        driver=VehicleDriver(cruise_speed=0.5),
        cables=CableLayer((3.0,), leg=0, lead=1.0),
    )
    plain = DeadReckoning(trial.wheelbase)
    plain.reset(trial.estimated.copy(), trial.reading)
    correction, lateral, heading = 0.0, [], []
    while not trial.done.all():
        before = trial.world.counts.copy()
        trial.step()
        travel = (trial.world.counts - before) * trial.odometry.travel_per_tick
        unseen = plain.update(travel.reshape(1, 2, 2), trial.reading)
        correction += float(trial.estimator.correction[0, 0])
        error = trial.truth[0, 0] - trial.estimated[0, 0]
        theta = float(trial.truth[0, 0, 2])
        lateral.append(-math.sin(theta) * error[0] + math.cos(theta) * error[1])
        heading.append(float(error[2]))
    alpha = float(trial.truth[0, 0, 2] - unseen[0, 0, 2])  # what dead reckoning missed
    assert abs(math.degrees(alpha)) == pytest.approx(0.57, rel=0.1)  # one crossing
    assert correction == pytest.approx(alpha, rel=0.03)
    assert max(abs(h) for h in heading) < 0.03 * abs(alpha)
    # Eq. 6 at 0.5 m/s and T_s = 40 ms (D_s = 20 mm): 0.19 mm for this α.
    u_alpha = growth_rate(abs(alpha), 0.5 * spec.sample_period, spec.link_length).lateral
    assert 0.5 * u_alpha < max(abs(v) for v in lateral) < 1.2 * u_alpha

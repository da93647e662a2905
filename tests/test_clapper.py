"""The CLAPPER driven in the World, with and without IPEC (Borenstein 1995, §6).

Work in progress for issue 9: the straight experiment of §6.1 and the smooth-floor rectangle of
§6.2; the rectangle with bumps, the envs and the command line are still to come.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from odomgym.baselines.ipec import IPEC
from odomgym.cables import bump_extra_rotation
from odomgym.clapper import (
    CableLayer,
    drive_vehicles,
    evenly,
    rectangle_cable_positions,
    rectangle_path,
    straight_path,
)
from odomgym.floor import FloorSpec
from odomgym.vehicle import VEHICLES

CLAPPER = VEHICLES["clapper"]
TRUCK = CLAPPER.truck_a
# One crossing turns a truck by the cable's excess rim travel over its true wheelbase: 0.58°
# for a LabMate over a 10 mm cable (Borenstein 1995 measured "approximately 0.6°", §6.1).
PER_BUMP = bump_extra_rotation(0.5 * TRUCK.true_right_diameter, 0.010) / TRUCK.true_wheelbase
# The estimator the CLAPPER runs here: IPEC with midpoint dead reckoning (Eq. 9 moves along the
# heading at the end of the interval, a first-order error on arcs that IPEC then reads as link
# motion: ±1.9° after a smooth-floor rectangle, against ±0.5° with the midpoint), without the
# composite translational correction (Eqs. 14-15): with 10-bit readings it fires at every
# count change of ψ_A, moving truck A back 1.04 mm each time, which through a rectangle's turns
# adds up to 6 cm; the paper found the correction had "only minimal effect" (§4.2).
CLAPPER_IPEC = functools.partial(IPEC, heading="midpoint", translation_correction=False)


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

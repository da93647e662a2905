"""The order in which ``diagnose`` reports the effects its rounds named
(:func:`odomgym.diagnose.workflow._in_order_added`). How a round's winner joins the model with
its partners is tested end to end in ``tests/test_skid_diagnose.py`` (the Husky in the field)."""

from __future__ import annotations

from odomgym.diagnose.fit import Model
from odomgym.diagnose.generate import NOMINAL_ROBOT
from odomgym.diagnose.likelihood import SensorNoise
from odomgym.diagnose.rounds import DiagnosisState
from odomgym.diagnose.workflow import _in_order_added
from odomgym.effects import EFFECTS


def _state(*named: str) -> DiagnosisState:
    model = Model(NOMINAL_ROBOT, SensorNoise(1e-3, 1e-3))
    return DiagnosisState(model, NOMINAL_ROBOT, named=list(named))


def test_an_effect_kept_beside_the_partner_it_extends_is_reported_in_its_place() -> None:
    """The skid track over ``wheelbase`` (its asymptote), floor bumps over the distance scale
    (their mean loss): where the rounds named the partner first and both were kept, the
    effect is reported first, the partner right after it; everything else keeps the order of
    the rounds."""
    state = _state("wheelbase", "gt_sensor_offset", "skid_track")
    kept = ["wheelbase", "gt_sensor_offset", "skid_track"]
    assert _in_order_added(state, kept, []) == ["skid_track", "wheelbase", "gt_sensor_offset"]
    # Named first already, or the partner not kept: the rounds' order.
    state = _state("skid_track", "backlash", "wheelbase")
    kept = ["wheelbase", "backlash", "skid_track"]
    assert _in_order_added(state, kept, []) == ["skid_track", "backlash", "wheelbase"]
    state = _state("wheelbase", "backlash")
    assert _in_order_added(state, ["wheelbase", "backlash"], []) == ["wheelbase", "backlash"]
    # A noise effect over its systematic partner.
    state = _state("backlash", "distance_scale", "floor_bumps")
    named = _in_order_added(state, ["backlash", "distance_scale"], ["floor_bumps"])
    assert named == ["backlash", "floor_bumps", "distance_scale"]
    # A partner the gate kept without the rounds naming it comes after its effect anyway.
    state = _state("skid_track")
    assert _in_order_added(state, ["skid_track", "wheelbase"], []) == ["skid_track", "wheelbase"]


def test_an_error_of_the_measurement_is_reported_after_the_robots_effects() -> None:
    """The tracked point's offset (``Effect.measurement``) follows the robot's own effects,
    whichever round named it: a marker 0.29 m ahead of a small robot's axle wins the first
    round (``benchmarks/skid_field.py``), and the report is read for the robot. Among the
    robot's effects the rounds' order and the partner rule stand."""
    assert EFFECTS["gt_sensor_offset"].measurement
    assert [n for n, e in EFFECTS.items() if e.measurement] == ["gt_sensor_offset"]
    kept = ["gt_sensor_offset", "skid_track", "wheelbase"]
    state = _state("gt_sensor_offset", "skid_track", "wheelbase")
    assert _in_order_added(state, kept, []) == ["skid_track", "wheelbase", "gt_sensor_offset"]
    state = _state("gt_sensor_offset", "wheelbase", "skid_track")
    assert _in_order_added(state, kept, []) == ["skid_track", "wheelbase", "gt_sensor_offset"]
    state = _state("gt_sensor_offset", "backlash", "floor_bumps")
    named = _in_order_added(state, ["gt_sensor_offset", "backlash"], ["floor_bumps"])
    assert named == ["backlash", "floor_bumps", "gt_sensor_offset"]
    only = _state("gt_sensor_offset")  # alone, it is still named
    assert _in_order_added(only, ["gt_sensor_offset"], []) == ["gt_sensor_offset"]

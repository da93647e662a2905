"""The order in which ``diagnose`` reports the effects its rounds named
(:func:`odomgym.diagnose.workflow._in_order_added`). How a round's winner joins the model with
its partners is tested end to end in ``tests/test_skid_diagnose.py`` (the Husky in the field)."""

from __future__ import annotations

from odomgym.diagnose.fit import Model
from odomgym.diagnose.generate import NOMINAL_ROBOT
from odomgym.diagnose.likelihood import SensorNoise
from odomgym.diagnose.rounds import DiagnosisState
from odomgym.diagnose.workflow import _in_order_added


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
    state = _state("skid_track", "gt_sensor_offset", "wheelbase")
    assert _in_order_added(state, kept, []) == ["skid_track", "gt_sensor_offset", "wheelbase"]
    state = _state("wheelbase", "backlash")
    assert _in_order_added(state, ["wheelbase", "backlash"], []) == ["wheelbase", "backlash"]
    # A noise effect over its systematic partner.
    state = _state("backlash", "distance_scale", "floor_bumps")
    named = _in_order_added(state, ["backlash", "distance_scale"], ["floor_bumps"])
    assert named == ["backlash", "floor_bumps", "distance_scale"]
    # A partner the gate kept without the rounds naming it comes after its effect anyway.
    state = _state("skid_track")
    assert _in_order_added(state, ["skid_track", "wheelbase"], []) == ["skid_track", "wheelbase"]

"""The effect catalogue: physical mechanisms that make a robot disagree with its odometry.

Each effect (``docs/effects.md``) is a physical extension of the simulator with a few named
parameters, nested at a value meaning "absent", saved in the robot TOML as
``[robot.effects.NAME]``. The catalogue is open: :func:`register_effect` adds one.

========================  =====================  ============================================
name                      parameters             what it is
========================  =====================  ============================================
``wheel_diameter_ratio``  ``e_d``                E_d = D_R/D_L ≠ 1 (mean diameter unchanged)
``wheelbase``             ``e_b``                effective wheelbase ≠ nominal
``distance_scale``        ``e_s``                mean wheel diameter ≠ nominal
``wheel_toe``             ``angle`` [rad]        crab at a constant angle while translating
``turn_skid``             ``gain`` [s²/m]        yaw under-rotation growing with |v·ω|
``backlash``              ``angle`` [rad]        dead band lost at every wheel reversal
``skid_track``            ``excess``,            skid-steer scrub: an apparent track wider in
                          ``lambda_half``        tight turns than on wide arcs
``skid_speed``            ``gain`` [s²/m]        skid-steer scrub relieved by speed: the track
                                                 narrows as v·ω grows
``floor_bumps``           ``rate`` [1/m],        sparse heading jumps from bumps
                          ``heading_jump`` [rad]
``floor_roughness``       ``k_left``,            Chong & Kleeman wheel noise
                          ``k_right`` [m^½]
``gt_sensor_offset``      ``dx``, ``dy`` [m]     tracked point offset from the axle midpoint (an
                                                 error of the measurement, not of the robot)
``discovered``            ``CHANNEL_MODULATOR``  terms of the error grammar found by sparse
                                                 regression (:mod:`odomgym.effects.discovered`)
========================  =====================  ============================================
"""

from __future__ import annotations

from odomgym.effects.discovered import TERMS, Discovered, DiscoveredTerms, Term
from odomgym.effects.geometry import DistanceScale, Wheelbase, WheelDiameterRatio
from odomgym.effects.motion import SkidSpeed, SkidTrack, TurnSkid, WheelToe
from odomgym.effects.noise import FloorBumps, FloorRoughness
from odomgym.effects.registry import (
    EFFECTS,
    Effect,
    Parameter,
    ReplayArrays,
    SpecView,
    WorldHook,
    WorldView,
    get_effect,
    register_effect,
)
from odomgym.effects.sensor import GroundTruthOffset, offset_point
from odomgym.effects.transmission import Backlash, play_operator

__all__ = [
    "EFFECTS",
    "TERMS",
    "Backlash",
    "Discovered",
    "DiscoveredTerms",
    "DistanceScale",
    "Effect",
    "FloorBumps",
    "FloorRoughness",
    "GroundTruthOffset",
    "Parameter",
    "ReplayArrays",
    "SkidSpeed",
    "SkidTrack",
    "SpecView",
    "Term",
    "TurnSkid",
    "WheelDiameterRatio",
    "WheelToe",
    "Wheelbase",
    "WorldHook",
    "WorldView",
    "catalogue",
    "get_effect",
    "offset_point",
    "play_operator",
    "register_effect",
]

for _effect in (
    WheelDiameterRatio(),
    Wheelbase(),
    DistanceScale(),
    WheelToe(),
    TurnSkid(),
    Backlash(),
    FloorBumps(),
    FloorRoughness(),
    GroundTruthOffset(),
    SkidTrack(),  # last: the differential-drive catalogue keeps its order (and its matrix seeds)
    SkidSpeed(),
    Discovered(),
):
    if _effect.name not in EFFECTS:
        register_effect(_effect)


def catalogue() -> list[str]:
    """The catalogue's effect names, in registry order: every registered effect except the
    grammar's ``discovered`` (which only the discovery pass fills). One catalogue for every
    robot class: ``diagnose`` proposes each effect to every robot, and the data decide."""
    return [name for name in EFFECTS if name != "discovered"]

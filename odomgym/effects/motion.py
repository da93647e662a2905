"""Contact-velocity effects: a toed-in wheel pair (crab) and yaw skid under lateral acceleration.

Both act on the no-slip velocities of the two wheel contacts (``World.ground_velocity``) before
the floor does; the chassis follows through the friction-limited pivot joints, exactly as it
follows the plain rolling velocities. Split each contact velocity into the common translation
v̄ = (g_L + g_R)/2 and the differential part g_w − v̄ (the rotation about the axle midpoint):

* ``wheel_toe`` rotates the translation by τ: the robot crabs at τ to its heading while
  translating; rotation in place is untouched, so the heading is unaffected;
* ``turn_skid`` scales the differential part by max(0, 1 − κ·|v·ω₀|): yaw under-rotation that
  grows with the lateral acceleration v·ω₀ and vanishes in in-place turns (v = 0).

The replay applies the same to one sampling interval (``docs/effects.md`` steps 4–5).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.effects.registry import Effect, Parameter, ReplayArrays, WorldHook, WorldView

__all__ = ["TurnSkid", "WheelToe"]

FloatArray = NDArray[np.float64]


class WheelToe(Effect):
    """A misaligned wheel pair: translation at a constant angle τ to the heading."""

    name = "wheel_toe"
    parameters = (
        Parameter("angle", "rad", 0.0, -0.2, 0.2, 1e-3, "direction of travel minus heading"),
    )
    summary = "misaligned wheels: the robot crabs sideways while translating, heading unaffected"
    reveals = (
        "one-way straight runs with ground truth along the track (cancels on closed loops and "
        "on out-and-back runs)"
    )
    confounded = (
        "a yaw misalignment of the ground-truth body frame (e.g. a motion-capture rigid body "
        "defined a little off the robot's axis) puts the same constant angle between the "
        "measured heading and the direction of travel; pose logs cannot tell the two apart, "
        "a check of the rigid-body alignment can"
    )

    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        return _ToeHook(values[:, 0].copy())

    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        if stage == "body":
            arrays.crab = arrays.crab + values["angle"]


class _ToeHook(WorldHook):
    has_shape = True

    def __init__(self, angle: FloatArray) -> None:
        self.cos = np.cos(angle)
        self.sin = np.sin(angle)

    def shape(self, world: WorldView, h: float) -> None:
        _rotate_translation(world.ground_velocity, self.cos, self.sin)


@kernel
def _rotate_translation(ground_v: FloatArray, cos_a: FloatArray, sin_a: FloatArray) -> None:
    for i in range(ground_v.shape[0]):
        mx = 0.5 * (ground_v[i, 0, 0] + ground_v[i, 1, 0])
        my = 0.5 * (ground_v[i, 0, 1] + ground_v[i, 1, 1])
        rx = cos_a[i] * mx - sin_a[i] * my
        ry = sin_a[i] * mx + cos_a[i] * my
        for w in range(2):
            ground_v[i, w, 0] += rx - mx
            ground_v[i, w, 1] += ry - my


class TurnSkid(Effect):
    """Yaw under-rotation growing with lateral acceleration: dθ = dθ₀·max(0, 1 − κ|v·ω₀|)."""

    name = "turn_skid"
    parameters = (
        Parameter("gain", "s²/m", 0.0, 0.0, 10.0, 0.05, "yaw lost per m/s² of lateral accel."),
    )
    summary = "the robot under-turns on fast arcs (yaw lost grows with v·ω)"
    reveals = "arcs at two speeds (the loss grows with speed); absent in in-place turns"

    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        return _SkidHook(values[:, 0].copy())

    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        if stage == "body":
            gain = values["gain"]
            accel = np.abs(arrays.ds * arrays.dtheta) / np.square(arrays.dt)
            arrays.dtheta = arrays.dtheta * np.maximum(0.0, 1.0 - gain * accel)


class _SkidHook(WorldHook):
    has_shape = True

    def __init__(self, gain: FloatArray) -> None:
        self.gain = gain

    def shape(self, world: WorldView, h: float) -> None:
        _scale_rotation(world.ground_velocity, world.rim_speed, world.half_track, self.gain)


@kernel
def _scale_rotation(
    ground_v: FloatArray, rim: FloatArray, half_track: FloatArray, gain: FloatArray
) -> None:
    for i in range(ground_v.shape[0]):
        v = 0.5 * (rim[i, 0] + rim[i, 1])
        omega = (rim[i, 1] - rim[i, 0]) / (2.0 * half_track[i])
        factor = max(0.0, 1.0 - gain[i] * math.fabs(v * omega))
        mx = 0.5 * (ground_v[i, 0, 0] + ground_v[i, 1, 0])
        my = 0.5 * (ground_v[i, 0, 1] + ground_v[i, 1, 1])
        for w in range(2):
            ground_v[i, w, 0] = mx + factor * (ground_v[i, w, 0] - mx)
            ground_v[i, w, 1] = my + factor * (ground_v[i, w, 1] - my)

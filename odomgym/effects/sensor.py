"""The ground-truth sensor's tracked point is offset from the axle midpoint.

A motion-capture rigid body is rarely defined exactly at the axle midpoint, the point odometry
describes. Tracking the point (dx, dy) of the body frame, the sensor reports
(x, y) + R(θ)·(dx, dy): invisible on straight runs, a circle of radius √(dx² + dy²) during an
in-place turn, and a displacement of 2·√(dx² + dy²) after a 180° spin.

On a skid-steer robot a constant longitudinal offset x_ICR of the sides' instantaneous centres of
rotation (Mandow et al. 2007) adds a sideways velocity −x_ICR·ω at the tracked point, which is
the motion of the point dx = −x_ICR ahead of a body without it: the two make the same logs, and
the catalogue has no separate ICR offset (the effect's ``confounded`` text says so whenever it is
named; with per-session frames the same holds for the tracked-point nuisance).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from odomgym.effects.registry import Effect, Parameter, ReplayArrays, WorldHook, WorldView

__all__ = ["GroundTruthOffset", "offset_point"]

FloatArray = NDArray[np.float64]


def offset_point(pose: FloatArray, dx: FloatArray | float, dy: FloatArray | float) -> FloatArray:
    """Poses (K, 3) of the point (dx, dy) [m] of the body frame of poses ``pose`` (K, 3)."""
    out = np.array(pose, dtype=np.float64, copy=True)
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    out[:, 0] += c * dx - s * dy
    out[:, 1] += s * dx + c * dy
    return out


class GroundTruthOffset(Effect):
    """The tracked point sits at (dx, dy) [m] in the body frame."""

    name = "gt_sensor_offset"
    parameters = (
        Parameter("dx", "m", 0.0, -1.0, 1.0, 2e-3, "tracked point ahead of the axle"),
        Parameter("dy", "m", 0.0, -1.0, 1.0, 2e-3, "tracked point left of the axle midpoint"),
    )
    summary = "the ground-truth system tracks a point offset from the axle midpoint"
    measurement = True
    reveals = "in-place turns (the tracked point circles the axle; 180° spins show 2·offset)"
    confounded = (
        "on a skid-steer robot, instantaneous centres of rotation of both sides sitting a constant "
        "x_ICR = −dx ahead of the tracked point (Mandow et al. 2007's x_ICR, e.g. from a centre "
        "of mass off the middle of the wheels) move the tracked point exactly as this offset "
        "does: pose logs cannot tell the two apart; measuring the rigid body's origin against "
        "the middle of the wheels can, and what is left of dx is then x_ICR"
    )

    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        return _OffsetHook(values[:, 0].copy(), values[:, 1].copy())

    stacked_replay = True  # pose by pose

    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        if stage == "measurement":
            arrays.tracked = offset_point(arrays.tracked, values["dx"], values["dy"])


class _OffsetHook(WorldHook):
    has_tracked = True

    def __init__(self, dx: FloatArray, dy: FloatArray) -> None:
        self.dx = dx
        self.dy = dy

    def tracked(self, pose: FloatArray) -> FloatArray:
        return offset_point(pose, self.dx, self.dy)

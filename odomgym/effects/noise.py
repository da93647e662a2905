"""Zero-mean floor effects carried by the robot's model: wheel roughness and sparse bumps.

* ``floor_roughness`` — Chong & Kleeman (1997, Eq. 4): each wheel's ground travel d gains white
  noise of variance k²·|d|, with its own k per wheel. The World adds it to the floor's own
  roughness (variances add).
* ``floor_bumps`` — each wheel meets bumps as a Poisson process of ``rate`` per metre of its
  travel; crossing one, it turns more than it advances (the rigid-wheel-over-cable
  over-count of :func:`odomgym.sim.cables.bump_extra_rotation`), by a·b so the heading jumps by
  ±a: +a under the left wheel, −a under the right. In the World the lost travel is spread over
  5 cm of the wheel's travel, as a real wheel climbs over a cable; the draws come from the
  robot's own stream.

Roughness does not move the mean of the disagreement; bumps do a little — their losses always
shorten a wheel's travel, by ``rate``·a·b per metre on average, which the replay applies. The
workflow's likelihood carries the rest as per-sample wheel variance and as sparse wheel-travel
losses (a Gaussian-sum filter), see :mod:`odomgym.diagnose.likelihood`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.effects.registry import (
    Effect,
    Parameter,
    ReplayArrays,
    WorldHook,
    WorldView,
    scale_columns,
)

__all__ = ["BUMP_SPREAD", "FloorBumps", "FloorRoughness"]

FloatArray = NDArray[np.float64]

BUMP_SPREAD = 0.05
"""Wheel travel over which one bump's lost travel is spread in the World [m]."""


class FloorRoughness(Effect):
    """Chong & Kleeman wheel noise k_L, k_R [m^½]."""

    name = "floor_roughness"
    noise = True
    parameters = (
        Parameter("k_left", "m^½", 0.0, 0.0, 0.1, 2e-4, "left wheel noise constant"),
        Parameter("k_right", "m^½", 0.0, 0.0, 0.1, 2e-4, "right wheel noise constant"),
    )
    summary = "wheel-travel noise growing with distance (variance k²·|d| per wheel)"
    reveals = "repeated runs with ground truth along the track; spread growing with distance"

    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        return _RoughnessHook(values.copy())

    def wheel_variance(self, values: Mapping[str, float], travel: FloatArray) -> FloatArray | None:
        return scale_columns(np.abs(travel), (values["k_left"] ** 2, values["k_right"] ** 2))


class _RoughnessHook(WorldHook):
    def __init__(self, k: FloatArray) -> None:
        self.k = k

    def configure(self, world: WorldView) -> None:
        world.wheel_roughness[:] = np.sqrt(np.square(world.wheel_roughness) + np.square(self.k))


class FloorBumps(Effect):
    """Sparse heading jumps ±a from wheels crossing bumps at ``rate`` per metre of travel."""

    name = "floor_bumps"
    noise = True
    with_systematic = True
    partners = ("distance_scale",)
    parameters = (
        Parameter("rate", "1/m", 0.0, 0.0, 10.0, 0.05, "bumps per metre of one wheel's travel"),
        Parameter("heading_jump", "rad", 0.0, 0.0, 0.2, 2e-3, "heading jump per bump"),
    )
    summary = "sparse discrete heading jumps (wheels crossing cables, thresholds)"
    reveals = "long runs with ground truth along the track: jumps, heavy-tailed heading errors"

    @classmethod
    def is_absent(cls, values: Mapping[str, float]) -> bool:
        return float(values.get("rate", 0.0)) == 0.0 or float(values.get("heading_jump", 0.0)) == 0

    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        return _BumpHook(values[:, 0].copy(), values[:, 1] * 2.0 * world.half_track)

    stacked_replay = True  # sample by sample

    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        # The losses always shorten a wheel's travel: on average by rate·e per metre, which is a
        # systematic shortening of the distance; the jumps scatter around it (noise face).
        if stage == "transmission" and not self.is_absent(values):
            loss = values["rate"] * values["heading_jump"] * arrays.wheelbase
            arrays.wheel = arrays.wheel * (1.0 - loss)

    def wheel_jumps(
        self, values: Mapping[str, float], travel: FloatArray, wheelbase: float
    ) -> tuple[FloatArray, float] | None:
        if self.is_absent(values):
            return None
        expected: FloatArray = values["rate"] * np.abs(travel)
        return expected, values["heading_jump"] * wheelbase


class _BumpHook(WorldHook):
    has_perturb = True
    needs_rng = True

    def __init__(self, rate: FloatArray, excess: FloatArray) -> None:
        self.rate = rate
        self.excess = excess  # travel lost per bump [m]
        n = rate.size
        self.travelled = np.zeros((n, 2))
        self.next = np.full((n, 2), np.inf)
        self.pending = np.zeros((n, 2))
        self.hit = np.zeros((n, 2), dtype=np.bool_)
        self.streams: list[np.random.Generator] = []

    def bind_rng(self, streams: Sequence[np.random.Generator]) -> None:
        self.streams = list(streams)
        for i in range(self.rate.size):
            self._draw(i, 0)
            self._draw(i, 1)

    def rebind_rng(self, index: int, stream: np.random.Generator) -> None:
        self.streams[index] = stream
        self._draw(index, 0)
        self._draw(index, 1)

    def _draw(self, i: int, w: int) -> None:
        rate = self.rate[i]
        self.next[i, w] = self.streams[i].exponential(1.0 / rate) if rate > 0 else math.inf

    def reset(self, indices: NDArray[np.intp]) -> None:
        self.pending[indices] = 0.0
        self.travelled[indices] = 0.0
        if self.streams:
            for i in indices:
                self._draw(int(i), 0)
                self._draw(int(i), 1)

    def perturb(self, world: WorldView, h: float) -> None:
        if _bump_step(
            world.rim_speed,
            world.pose,
            h,
            self.excess,
            BUMP_SPREAD,
            self.travelled,
            self.next,
            self.pending,
            self.hit,
            world.ground_velocity,
        ):
            for i, w in np.argwhere(self.hit):
                self._draw(int(i), int(w))


@kernel
def _bump_step(
    rim: FloatArray,
    pose: FloatArray,
    h: float,
    excess: FloatArray,
    spread: float,
    travelled: FloatArray,
    next_at: FloatArray,
    pending: FloatArray,
    hit: NDArray[np.bool_],
    ground_v: FloatArray,
) -> bool:
    """Advance each wheel's bump process by this substep's travel; remove lost travel."""
    any_hit = False
    for i in range(rim.shape[0]):
        cos_t = math.cos(pose[i, 2])
        sin_t = math.sin(pose[i, 2])
        for w in range(2):
            step = math.fabs(rim[i, w]) * h
            hit[i, w] = False
            travelled[i, w] += step
            if travelled[i, w] >= next_at[i, w]:
                travelled[i, w] -= next_at[i, w]
                pending[i, w] += excess[i]
                hit[i, w] = True
                any_hit = True
            if pending[i, w] > 0.0 and step > 0.0:
                lost = min(pending[i, w], step * min(0.5, excess[i] / spread))
                pending[i, w] -= lost
                sign = 1.0 if rim[i, w] >= 0.0 else -1.0
                ground_v[i, w, 0] -= sign * lost / h * cos_t
                ground_v[i, w, 1] -= sign * lost / h * sin_t
    return any_hit

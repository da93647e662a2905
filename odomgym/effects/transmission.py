"""Backlash: a dead band of wheel rotation lost at every reversal of a wheel's direction.

The encoder sits on the motor; between motor and wheel there is gear play of width β [rad of
wheel rotation]. The wheel angle follows the motor angle through the *play operator*
φ_w ← min(φ_m + β/2, max(φ_m − β/2, φ_w)): while the motor turns through the gap the wheel
stands still, so every reversal of a wheel's direction loses β of rotation the encoder counted.
At the start of a run the gear is engaged for forward motion (φ_w = φ_m − β/2).

The World applies it per physics substep to the continuous motor rotation; the replay applies the
same operator to the motor angles the logged counts give (``docs/effects.md`` step 1).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.effects.registry import (
    Effect,
    Parameter,
    ReplayArrays,
    WorldHook,
    WorldView,
    run_bounds,
)

__all__ = ["Backlash", "play_operator"]

FloatArray = NDArray[np.float64]


class Backlash(Effect):
    """Gear play between motor (encoder) and wheel, lost at every reversal."""

    name = "backlash"
    parameters = (Parameter("angle", "rad", 0.0, 0.0, 0.5, 2e-3, "dead band of wheel rotation"),)
    summary = "gear play: every reversal of a wheel loses a fixed rotation the encoder counted"
    reveals = (
        "in-place turns of several angles (a fixed loss per reversal, not proportional to the "
        "angle) and out-and-back runs"
    )

    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        return _BacklashHook(values[:, 0].copy())

    stacked_replay = True  # the play restarts engaged forward at every run's first interval

    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        if stage == "transmission":
            gap = np.full(2, 0.5 * values["angle"])
            arrays.wheel = play_operator(
                arrays.wheel, np.full(2, values["angle"]), gap, run_bounds(arrays)
            )


class _BacklashHook(WorldHook):
    has_transmission = True

    def __init__(self, angle: FloatArray) -> None:
        self.width = np.repeat(angle[:, None], 2, axis=1)  # (N, 2) [rad]
        self.gap = 0.5 * self.width  # φ_m − φ_w: engaged forward

    def reset(self, indices: NDArray[np.intp]) -> None:
        self.gap[indices] = 0.5 * self.width[indices]

    def transmission(self, motor_step: FloatArray) -> None:
        _play_step(motor_step, self.width, self.gap)


@kernel
def _play_step(step: FloatArray, width: FloatArray, gap: FloatArray) -> None:
    """One substep of the play operator for every robot and wheel, in place."""
    for i in range(step.shape[0]):
        for w in range(2):
            half = 0.5 * width[i, w]
            g = gap[i, w] + step[i, w]
            if g > half:
                step[i, w] = g - half
                gap[i, w] = half
            elif g < -half:
                step[i, w] = g + half
                gap[i, w] = -half
            else:
                step[i, w] = 0.0
                gap[i, w] = g


@kernel
def _play_runs(
    motor: FloatArray, width: FloatArray, gap0: FloatArray, bounds: NDArray[np.int64]
) -> FloatArray:
    out = np.empty_like(motor)
    for r in range(bounds.shape[0] - 1):
        for w in range(2):
            half = 0.5 * width[w]
            g = gap0[w]
            for k in range(bounds[r], bounds[r + 1]):
                g += motor[k, w]
                if g > half:
                    out[k, w] = g - half
                    g = half
                elif g < -half:
                    out[k, w] = g + half
                    g = -half
                else:
                    out[k, w] = 0.0
    return out


def play_operator(
    motor: FloatArray,
    width: FloatArray,
    gap: FloatArray,
    bounds: NDArray[np.int64] | None = None,
) -> FloatArray:
    """Wheel rotation increments (n, 2) [rad] from motor increments (n, 2) through gear play of
    ``width`` (2,) [rad], starting with φ_m − φ_w = ``gap`` (2,); ``bounds`` (R + 1,): rows of
    R runs stacked, each starting at ``gap`` again (default: one run)."""
    if bounds is None:
        bounds = np.array([0, len(motor)], dtype=np.int64)
    return np.asarray(
        _play_runs(
            np.ascontiguousarray(motor, dtype=np.float64),
            np.asarray(width, dtype=np.float64),
            np.asarray(gap, dtype=np.float64),
            np.asarray(bounds, dtype=np.int64),
        )
    )

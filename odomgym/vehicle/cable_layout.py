"""Cables laid across a two-truck vehicle's path, as the experimenter of Borenstein 1995, §6.1
did, and a free-rolling wheel's travel over them.

:class:`CableLayer` lays each cable as the vehicle comes (the floor changes between steps);
:func:`rectangle_cable_positions` and :func:`evenly` say where; :func:`free_wheel_rim` is the
rim travel of the encoder trailer's free-rolling wheels over a cable, and :func:`cable_arrays`
the cables as arrays for counting crossings. Units: metres, radians.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.floor import CableBump
from odomgym.sim.cables import rim_travel_for_advance
from odomgym.vehicle.paths import VehiclePath, point_at

__all__ = [
    "CableLayer",
    "cable_arrays",
    "crossings",
    "evenly",
    "free_wheel_rim",
    "rectangle_cable_positions",
    "wheel_sides",
]

FloatArray = NDArray[np.float64]


@dataclass
class CableLayer:
    """Lays 10 mm cables under one side's wheels as the vehicle comes, like the experimenter
    of Borenstein 1995, §6.1 ("only under the right side-wheels of the vehicle", on the return
    leg only).

    When the vehicle's leading truck is ``lead`` metres before the next position in ``at``
    (arc lengths along ``leg`` [m], increasing), a cable half a track long is laid across the
    path there (perpendicular to its tangent),
    centred on that truck's wheel track on the chosen side: both trucks' wheels on that side
    cross it and the other side's do not, as long as the trucks stay within a quarter track of
    that line.
    One vehicle per World: the floor is shared.
    """

    at: tuple[float, ...]
    leg: int = 1
    side: Literal["left", "right"] = "right"
    diameter: float = 0.010
    lead: float = 0.3
    laid: list[CableBump] = field(default_factory=list)
    _progress: list[float] = field(default_factory=lambda: [0.0, 0.0])

    def __call__(
        self, leg: int, path: VehiclePath, truth: FloatArray, tracks: tuple[float, float]
    ) -> tuple[CableBump, ...] | None:
        """Every cable laid so far if a new one is due (``truth``: true truck poses (2, 3);
        ``tracks``: the trucks' wheel tracks [m]), else None."""
        if leg != self.leg or len(self.laid) >= len(self.at):
            return None
        points = path.legs[leg].points
        arc = path.legs[leg].polyline.arc
        target = self.at[len(self.laid)]
        # How far along the leg each truck is: the arc length of its nearest path point within
        # a window just ahead of where it was (a closed path passes its start twice). The arc
        # lengths increase, so the window is a slice, found by bisection.
        reached = []
        for k in (0, 1):
            start = bisect.bisect_left(arc, self._progress[k] - 0.2)
            stop = bisect.bisect_right(arc, self._progress[k] + 1.0)
            if stop <= start:
                stop = len(arc)
            near = np.hypot(*(points[start:stop] - truth[k, :2]).T)
            nearest = start + int(np.argmin(near))
            self._progress[k] = max(self._progress[k], arc[nearest])
            reached.append(self._progress[k])
        if max(reached) < target - self.lead:
            return None
        x_t, y_t, tangent_heading, _ = point_at(path.legs[leg].polyline, target)
        at_point = np.array([x_t, y_t])
        along = np.array([math.cos(tangent_heading), math.sin(tangent_heading)])
        normal = np.array([-along[1], along[0]])
        # The leading truck's wheel track on the chosen side, extended along its heading to
        # the line across the path at ``target``: where that truck's wheels will cross.
        lead = 0 if reached[0] >= reached[1] else 1
        heading = truth[lead, 2]
        side = -1.0 if self.side == "right" else 1.0
        left_of_truck = np.array([-math.sin(heading), math.cos(heading)])
        track = tracks[lead]
        wheel = truth[lead, :2] + side * 0.5 * track * left_of_truck
        forwards = np.array([math.cos(heading), math.sin(heading)])
        if abs(float(forwards @ along)) < 0.7:
            return None  # the truck is turning: lay the cable when it heads across it
        reach = -float((wheel - at_point) @ along) / float(forwards @ along)
        x, y = wheel + reach * forwards
        self.laid.append(
            CableBump(
                x=float(x),
                y=float(y),
                angle=math.atan2(normal[1], normal[0]),
                diameter=self.diameter,
                length=0.5 * track,
            )
        )
        return tuple(self.laid)


def rectangle_cable_positions(
    path: VehiclePath, count: int, clearance: float = 0.8, trailing: float = 1.0
) -> tuple[float, ...]:
    """``count`` arc lengths evenly spread over the straight parts of a rectangle path, at
    least ``clearance`` [m] from its turns and its start, and ``clearance + trailing`` from its
    end: the rear truck stops ``trailing`` [m] (the link) behind the front one, and must cross
    every cable too (cables in turns would be crossed at a slant by trucks that are turning)."""
    leg = path.legs[0]
    arc = leg.arc_length
    heading = leg.headings
    straight = np.abs(np.diff(heading, prepend=heading[0])) < 1e-9
    turning = arc[:-1][~straight]
    candidates = np.linspace(clearance, arc[-1] - clearance - trailing, 2000)
    if turning.size:
        gap = np.min(np.abs(candidates[:, None] - turning[None, :]), axis=1)
        candidates = candidates[gap >= clearance]
    if count <= 0 or candidates.size == 0:
        return ()
    picks = np.linspace(0, candidates.size - 1, count).round().astype(int)
    return tuple(float(candidates[k]) for k in picks)


def evenly(count: int, length: float = 18.0, margin: float = 1.5) -> tuple[float, ...]:
    """``count`` positions evenly spaced between ``margin`` and ``length − margin`` [m]."""
    if count <= 0:
        return ()
    if count == 1:
        return (length / 2.0,)
    return tuple(float(x) for x in np.linspace(margin, length - margin, count))


def free_wheel_rim(
    cables: tuple[CableBump, ...],
    px: float,
    py: float,
    hx: float,
    hy: float,
    advance: float,
    radius: float,
) -> float:
    """Rim travel [m] of a free-rolling wheel whose contact point (px, py) advances by
    ``advance`` along its heading (hx, hy) in one interval: the advance itself on the flat,
    the arc over a cable where it crosses one (:func:`odomgym.sim.cables.rim_travel_for_advance`
    across the cable's axis; the first cable in reach)."""
    for cable in cables:
        ax, ay = math.cos(cable.angle), math.sin(cable.angle)
        rx, ry = px - cable.x, py - cable.y
        if abs(rx * ax + ry * ay) > 0.5 * cable.length:
            continue
        nx, ny = -ay, ax
        offset = rx * nx + ry * ny
        facing = hx * nx + hy * ny
        across = advance * facing
        reach = 2.0 * math.sqrt(radius * 0.5 * cable.diameter) + abs(across)
        if abs(offset) > reach or abs(facing) < 1e-3:
            continue
        rim_across = rim_travel_for_advance(offset, across, radius, 0.5 * cable.diameter)
        return advance + (rim_across - across) / facing
    return advance


def cable_arrays(cables: tuple[CableBump, ...]) -> tuple[FloatArray, ...]:
    """Centres, unit axes and half lengths (K,) of ``cables`` [m], for :func:`wheel_sides`."""
    return (
        np.array([c.x for c in cables]),
        np.array([c.y for c in cables]),
        np.array([math.cos(c.angle) for c in cables]),
        np.array([math.sin(c.angle) for c in cables]),
        np.array([0.5 * c.length for c in cables]),
    )


@kernel
def wheel_sides(
    poses: FloatArray,
    half_track: FloatArray,
    cx: FloatArray,
    cy: FloatArray,
    ax: FloatArray,
    ay: FloatArray,
    half: FloatArray,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """For the wheels of two trucks at ``poses`` (2, 3) [m, m, rad] — A left, A right, B left,
    B right, each ``half_track`` (2,) [m] to its side of the heading — and every cable of
    :func:`cable_arrays`: the side of the cable's axis the contact point is on (4, K) (±1, 0 on
    it) and whether it lies within the cable's length (4, K).

    Compiled because a CLAPPER run asks it every control step once cables lie on the floor,
    where numpy's dozen calls on (4, K) arrays were a sixth of the step; the same operations
    as those calls, element by element (sine and cosine as libm's, like numpy's; the sign
    written out as numpy's: +0.0 on the axis, where numba's ``np.sign`` keeps −0.0)."""
    count = cx.shape[0]
    side = np.empty((4, count))
    within = np.empty((4, count), dtype=np.bool_)
    for truck in range(2):
        heading = poses[truck, 2]
        left_x = -np.sin(heading) * half_track[truck]
        left_y = np.cos(heading) * half_track[truck]
        for wheel in range(2):
            if wheel == 0:
                wx, wy = poses[truck, 0] + left_x, poses[truck, 1] + left_y
            else:
                wx, wy = poses[truck, 0] - left_x, poses[truck, 1] - left_y
            row = 2 * truck + wheel
            for k in range(count):
                px = wx - cx[k]
                py = wy - cy[k]
                across = px * -ay[k] + py * ax[k]
                if across > 0.0:
                    side[row, k] = 1.0
                elif across < 0.0:
                    side[row, k] = -1.0
                elif across == 0.0:
                    side[row, k] = 0.0
                else:  # NaN, as it came
                    side[row, k] = across
                within[row, k] = abs(px * ax[k] + py * ay[k]) <= half[k]
    return side, within


@kernel
def crossings(side: FloatArray, before: FloatArray, within: NDArray[np.bool_]) -> tuple[int, int]:
    """How many wheels of truck A and of truck B (rows 0–1 and 2–3 of :func:`wheel_sides`'
    arrays) crossed a cable's axis since ``before``: on the other side now, not on the axis,
    and within the cable's length."""
    counts = [0, 0]
    for row in range(4):
        for k in range(side.shape[1]):
            if side[row, k] != before[row, k] and side[row, k] != 0.0 and within[row, k]:
                counts[row // 2] += 1
    return counts[0], counts[1]

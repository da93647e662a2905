"""The paths a two-truck vehicle drives (Borenstein 1995, §6) and the scalar look-ups along them.

A :class:`VehiclePath` is a sequence of legs, each a polyline driven forwards or backwards with a
stop at its end: the straight experiment of Borenstein 1995, §6.1 (18 m out, then 18 m back
*backwards*) and the 7×4 m rectangle with smooth 90° turns of §6.2.

The look-ups (:func:`point_at`, :func:`reference_at`, :func:`offset_at`, :func:`extended_at`)
work on a leg's cached :class:`Polyline` in Python floats, because the controller and the cable
layout call them every control step for one vehicle at a time, where numpy's per-call overhead
on scalars was three quarters of a CLAPPER run's time.

Units: metres, radians, seconds.
"""

from __future__ import annotations

import bisect
import functools
import itertools
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "Leg",
    "Polyline",
    "VehiclePath",
    "circle_path",
    "extended_at",
    "interp_float",
    "offset_at",
    "point_at",
    "rectangle_path",
    "reference_at",
    "straight_path",
    "wrap_float",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Leg:
    """A polyline ``points`` (M, 2) [m] driven ``direction`` +1 (forwards) or −1 (backwards,
    the trucks facing the way they came), ending at rest."""

    points: FloatArray
    direction: float = 1.0

    @property
    def length(self) -> float:
        return float(self.arc_length[-1])

    @property
    def headings(self) -> FloatArray:
        """Direction of each segment (M − 1,) [rad], unwrapped (continuous through turns)."""
        return np.asarray(np.unwrap(np.arctan2(*np.diff(self.points, axis=0).T[::-1])))

    @functools.cached_property
    def arc_length(self) -> FloatArray:
        """Cumulative length at each point (M,) [m] (computed once: the driver and the cable
        layer look it up every control step)."""
        steps = np.hypot(*np.diff(self.points, axis=0).T)
        arc = np.concatenate([[0.0], np.cumsum(steps)])
        arc.flags.writeable = False
        return arc

    @functools.cached_property
    def polyline(self) -> Polyline:
        """The points, arc lengths and segment headings as Python floats, for the per-step
        look-ups of :func:`point_at` (scalar arithmetic: numpy's per-call overhead on scalars
        was three quarters of a CLAPPER run's time)."""
        points = np.asarray(self.points, dtype=float)
        d = np.diff(points, axis=0)
        return Polyline(
            x=points[:, 0].tolist(),
            y=points[:, 1].tolist(),
            arc=self.arc_length.tolist(),
            heading=[math.atan2(dy, dx) for dx, dy in d.tolist()],
        )


@dataclass(frozen=True)
class Polyline:
    """A leg's polyline in Python floats: point coordinates (M,), cumulative arc length (M,)
    [m] and the heading of each segment (M − 1,) [rad]."""

    x: list[float]
    y: list[float]
    arc: list[float]
    heading: list[float]


@dataclass(frozen=True)
class VehiclePath:
    """Legs driven one after the other; ``name`` for reports."""

    legs: tuple[Leg, ...]
    name: str

    def start_poses(self, link_length: float) -> FloatArray:
        """Truck poses (2, 3) at the start: A at the first point facing along the first leg
        (for a backward leg: facing against it), B ``link_length`` behind A."""
        leg = self.legs[0]
        d = leg.points[1] - leg.points[0]
        heading = math.atan2(d[1], d[0]) + (0.0 if leg.direction > 0 else math.pi)
        a = np.array([*leg.points[0], heading])
        b = a - np.array([link_length * math.cos(heading), link_length * math.sin(heading), 0.0])
        return np.stack([a, b])


def straight_path(length: float = 18.0, spacing: float = 0.05, back: bool = True) -> VehiclePath:
    """Out ``length`` metres along +x, then (``back``) the same way *backwards* (Borenstein
    1995, §6.1: "traveled straight forward for 18 m, stopped, and returned straight-backward")."""
    count = max(2, round(length / spacing) + 1)
    out = np.stack([np.linspace(0.0, length, count), np.zeros(count)], axis=1)
    if not back:
        return VehiclePath((Leg(out, 1.0),), f"straight-{length:g}m-out")
    return VehiclePath((Leg(out, 1.0), Leg(out[::-1].copy(), -1.0)), f"straight-{length:g}m")


def rectangle_path(
    width: float = 7.0,
    height: float = 4.0,
    direction: Literal["cw", "ccw"] = "ccw",
    radius: float = 0.45,
    spacing: float = 0.02,
) -> VehiclePath:
    """The §6.2 rectangle: ``width`` × ``height`` [m] with 90° fillets of ``radius`` [m] (0.45 m
    passes each corner at r(√2 − 1) = 0.19 m, within the paper's 0.2 m), driven forwards once
    round, starting and ending in the middle of the first long side, ``ccw`` turning left."""
    if not 0.0 < 2.0 * radius < min(width, height):
        raise ValueError(f"radius must be below half the shorter side, got {radius}")
    sign = 1.0 if direction == "ccw" else -1.0
    corners = [(0.0, 0.0), (width, 0.0), (width, sign * height), (0.0, sign * height)]
    points: list[tuple[float, float]] = [(width / 2.0, 0.0)]
    for k in range(1, 5):
        corner = np.array(corners[k % 4])
        before = np.array(corners[k - 1])
        u_in = (corner - before) / np.linalg.norm(corner - before)
        start = corner - radius * u_in
        points.append((float(start[0]), float(start[1])))
        centre = start + radius * np.array([-u_in[1], u_in[0]]) * sign
        a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
        for t in np.linspace(0.0, 1.0, max(4, int(radius * math.pi / 2 / spacing)))[1:]:
            a = a0 + sign * t * math.pi / 2
            points.append((centre[0] + radius * math.cos(a), centre[1] + radius * math.sin(a)))
    points.append((width / 2.0, 0.0))
    dense = _densify(np.array(points), spacing)
    return VehiclePath((Leg(dense, 1.0),), f"rectangle-{width:g}x{height:g}m-{direction}")


def circle_path(
    radius: float = 2.0,
    turns: float = 1.0,
    direction: Literal["cw", "ccw"] = "ccw",
    spacing: float = 0.02,
) -> VehiclePath:
    """``turns`` full circles of ``radius`` [m], preceded by a 1.5 m straight run-in and
    followed by a 1.5 m run-out along the same line, so the vehicle ends heading as it started
    after turning ``turns`` × 360° (the link-length bias experiment of Borenstein 1995,
    §5.2)."""
    if not radius > 0.6:
        raise ValueError(f"radius must exceed 0.6 m (the trucks are 1 m apart), got {radius}")
    sign = 1.0 if direction == "ccw" else -1.0
    run = np.stack([np.linspace(0.0, 1.5, 76), np.zeros(76)], axis=1)
    count = max(8, math.ceil(2.0 * math.pi * radius * turns / spacing))
    angles = np.linspace(0.0, 2.0 * math.pi * turns, count + 1)[1:]
    arc = np.stack([1.5 + radius * np.sin(angles), sign * radius * (1.0 - np.cos(angles))], axis=1)
    out = np.stack([np.linspace(1.5, 3.0, 76)[1:], np.zeros(75)], axis=1)
    points = np.concatenate([run, arc, out])
    return VehiclePath((Leg(points, 1.0),), f"circle-{radius:g}m-{turns:g}x-{direction}")


def _densify(points: FloatArray, spacing: float) -> FloatArray:
    out = [points[0]]
    for p, q in itertools.pairwise(points):
        count = max(1, math.ceil(float(np.hypot(*(q - p))) / spacing))
        for t in np.linspace(0.0, 1.0, count + 1)[1:]:
            out.append(p + t * (q - p))
    return np.array(out)


def wrap_float(angle: float) -> float:
    """:func:`odomgym.odometry.calibration.wrap_angle` for one float (the same IEEE result: Python's
    ``%`` and ``np.mod`` both take the divisor's sign)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def reference_at(line: Polyline, s: float) -> tuple[float, float, float, float]:
    """:func:`point_at`, continued straight (zero curvature) beyond the polyline's ends."""
    if 0.0 <= s <= line.arc[-1]:
        return point_at(line, s)
    x, y = extended_at(line, s)
    heading = line.heading[0] if s < 0.0 else line.heading[-1]
    return x, y, heading, 0.0


def point_at(line: Polyline, s: float) -> tuple[float, float, float, float]:
    """Position, tangent heading and curvature of the polyline at arc length ``s``."""
    k, t = _locate(line, s)
    x = line.x[k] + t * (line.x[k + 1] - line.x[k])
    y = line.y[k] + t * (line.y[k + 1] - line.y[k])
    heading = line.heading[k]
    last = len(line.arc) - 2
    j = min(k + 1, last)
    if j > k:
        step = max(line.arc[j + 1] - line.arc[k], 1e-9) / 2.0
        curvature = wrap_float(line.heading[j] - heading) / step
    else:
        curvature = 0.0
    return x, y, heading, curvature


def _locate(line: Polyline, s: float) -> tuple[int, float]:
    """The segment ``k`` holding arc length ``s`` (the first or last one beyond the ends) and
    the fraction ``t`` of it at ``s``."""
    arc = line.arc
    k = min(max(bisect.bisect_right(arc, s) - 1, 0), len(arc) - 2)
    return k, (s - arc[k]) / max(arc[k + 1] - arc[k], 1e-12)


def interp_float(x: float, xp: list[float], fp: list[float]) -> float:
    """``float(np.interp(x, xp, fp))`` for one float on increasing ``xp`` (at least two
    points), in numpy's arithmetic (``numpy/_core/src/multiarray/compiled_base.c``,
    ``arr_interp``): the end values outside ``xp``, ``fp[j]`` at a knot, else
    slope·(x − xp[j]) + fp[j] (from the right knot if that is NaN). Why: the controller asks
    it every control step, where numpy's call on a scalar cost ~5 µs."""
    if x != x:  # NaN: numpy gives it back as it came
        return x
    if x < xp[0]:
        return fp[0]
    if x >= xp[-1]:
        return fp[-1]
    j = bisect.bisect_right(xp, x) - 1
    if xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    value = slope * (x - xp[j]) + fp[j]
    if value != value:
        value = slope * (x - xp[j + 1]) + fp[j + 1]
        if value != value and fp[j] == fp[j + 1]:
            value = fp[j]
    return value


def offset_at(
    line: Polyline,
    s: float,
    distance: float,
    side: float,
    start: tuple[float, float] | None = None,
) -> float:
    """Arc length of the path point at straight-line ``distance`` [m] from the point at ``s``:
    behind it (``side`` −1) or ahead of it (+1) along the polyline, on the straight extension
    of its first or last segment beyond the ends.

    Found by marching along the path by the chord's shortfall: a chord is never longer than
    its arc, so each step lands short of (or on) the point and the shortfall shrinks — one step
    on a straight, a few in a turn — to 1e-10 m; bisection takes over should a path fold back
    on itself so that the march stalls. ``start``: :func:`extended_at` at ``s``, if the caller
    has it (the controller has just looked up the point at ``s`` with :func:`point_at`, whose
    position is the same for 0 ≤ s ≤ the leg's length, not beyond its ends)."""
    ax, ay = extended_at(line, s) if start is None else start
    t = s
    x, y = ax, ay
    for _ in range(64):
        gap = distance - math.hypot(ax - x, ay - y)
        if gap <= 1e-10:
            return t
        t += side * gap
        x, y = extended_at(line, t)
    near, far = s, s + side * 3.0 * distance
    for _ in range(64):  # the chord grows monotonically from ``near`` to ``far``
        mid = 0.5 * (near + far)
        x, y = extended_at(line, mid)
        if math.hypot(ax - x, ay - y) < distance:
            near = mid
        else:
            far = mid
    return 0.5 * (near + far)


def extended_at(line: Polyline, s: float) -> tuple[float, float]:
    """The polyline point at arc length ``s``, continued straight beyond either end."""
    arc = line.arc
    if s < 0.0:
        scale = s / max(arc[1], 1e-12)
        return line.x[0] + scale * (line.x[1] - line.x[0]), line.y[0] + scale * (
            line.y[1] - line.y[0]
        )
    if s > arc[-1]:
        scale = (s - arc[-1]) / max(arc[-1] - arc[-2], 1e-12)
        return line.x[-1] + scale * (line.x[-1] - line.x[-2]), line.y[-1] + scale * (
            line.y[-1] - line.y[-2]
        )
    k, t = _locate(line, s)  # :func:`point_at`'s position, without its heading and curvature
    return line.x[k] + t * (line.x[k + 1] - line.x[k]), line.y[k] + t * (line.y[k + 1] - line.y[k])

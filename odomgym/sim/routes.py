"""Routes: the sequences of straight drives and in-place turns that odometry experiments use.

A :class:`Route` is a list of :class:`Segment` s. The robot follows it *by its own odometry*,
exactly as in UMBmark (Borenstein & Feng 1994, §6.3: "at the end of each leg the robot came to a
complete stop and rotated on-the-spot through 90°"). :class:`RouteProgress` tracks, for a batch
of robots, which segment each is on and expresses the odometry pose relative to it — the
quantities a driver needs and an env observes.

Frames: the route is laid out in the odometry frame, which coincides with the world frame at the
start (origin, heading +x). ``cw`` squares turn right (toward −y), ``ccw`` squares left (+y),
matching Borenstein & Feng 1994, Eqs. 6.3–6.18.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from odomgym._kernels import route_update
from odomgym.errors import SpecError
from odomgym.odometry.runs import MAX_RUN_LENGTH, MIN_RUN_LENGTH

__all__ = [
    "Route",
    "RouteProgress",
    "Segment",
    "spin_route",
    "square_route",
    "straight_route",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Segment:
    """One manoeuvre.

    Attributes:
        kind: ``"drive"`` (straight line from ``start`` to ``end`` holding ``heading``) or
            ``"turn"`` (rotate in place at ``start`` until the heading is ``heading``).
        start, end: points (x, y) [m] in the odometry frame.
        heading: heading to hold (drive) or reach (turn) [rad], unwrapped.
        reverse: drive backwards (the robot faces ``heading`` but moves the other way).
        turn: signed rotation of a turn [rad] (positive = ccw).
    """

    kind: Literal["drive", "turn"]
    start: tuple[float, float]
    end: tuple[float, float]
    heading: float
    reverse: bool = False
    turn: float = 0.0

    @property
    def length(self) -> float:
        """Distance of a drive [m], or |angle| of a turn [rad]."""
        if self.kind == "drive":
            return math.dist(self.start, self.end)
        return abs(self.turn)


@dataclass(frozen=True)
class Route:
    """A sequence of segments with a name, e.g. ``square-cw-4m``."""

    name: str
    segments: tuple[Segment, ...]

    def __post_init__(self) -> None:
        if not self.segments:
            raise ValueError(f"route {self.name!r} has no segments")

    def wheel_travel(self, wheelbase: float) -> float:
        """Path length in wheel metres: drives plus turns as wheel arcs (b/2)·|Δψ| [m]."""
        return sum(
            s.length if s.kind == "drive" else 0.5 * wheelbase * s.length for s in self.segments
        )


MAX_RUN_TURN = 20.0 * math.pi
"""The largest turn in place of one run [rad]: ten revolutions."""
MIN_RUN_TURN = 1e-3
"""The smallest turn in place of one run [rad] (0.057°)."""


def check_extent(field: str, given: float, total: float, turn: bool = False) -> None:
    """Refuse a run whose path (or turn, with ``turn``) ``total``, from ``field`` = ``given``,
    lies outside :data:`MIN_RUN_LENGTH`..:data:`MAX_RUN_LENGTH` [m] (or the turn limits [rad])."""
    low, high, unit, what = (
        (MIN_RUN_TURN, MAX_RUN_TURN, "rad", "turn")
        if turn
        else (MIN_RUN_LENGTH, MAX_RUN_LENGTH, "m", "path")
    )
    if not low <= total <= high:
        raise SpecError(
            f"{field} {given:g} makes a run's {what} {total:g} {unit}; one run may have "
            f"{low:g} to {high:g} {unit}",
            field=field,
        )


def square_route(side: float = 4.0, direction: Literal["cw", "ccw"] = "cw") -> Route:
    """The UMBmark square: four legs of ``side`` metres, a 90° turn in place after each (the
    fourth turn restores the starting heading, Borenstein & Feng 1994, §6.3)."""
    if not side > 0:
        raise ValueError(f"side must be > 0, got {side!r}")
    check_extent("side", side, 4.0 * side)
    if direction not in ("cw", "ccw"):
        raise ValueError(f"direction must be 'cw' or 'ccw', got {direction!r}")
    sign = -1.0 if direction == "cw" else 1.0
    segments: list[Segment] = []
    point = (0.0, 0.0)
    heading = 0.0
    for _ in range(4):
        end = (point[0] + side * math.cos(heading), point[1] + side * math.sin(heading))
        end = (round(end[0], 12), round(end[1], 12))
        segments.append(Segment("drive", point, end, heading))
        segments.append(
            Segment("turn", end, end, heading + sign * math.pi / 2, turn=sign * math.pi / 2)
        )
        point = end
        heading += sign * math.pi / 2
    return Route(f"square-{direction}-{side:g}m", tuple(segments))


def straight_route(distance: float = 10.0, return_trip: bool = False) -> Route:
    """Drive ``distance`` metres along +x; with ``return_trip``, stop and drive back to the
    start *backwards* (no turn), as the CLAPPER did (Borenstein 1995, §6.1: 18 m out and back)."""
    if not distance > 0:
        raise ValueError(f"distance must be > 0, got {distance!r}")
    check_extent("distance", distance, distance * (2 if return_trip else 1))
    out = Segment("drive", (0.0, 0.0), (distance, 0.0), 0.0)
    segments = [out]
    if return_trip:
        segments.append(Segment("drive", (distance, 0.0), (0.0, 0.0), 0.0, reverse=True))
    name = f"straight-{distance:g}m" + ("-return" if return_trip else "")
    return Route(name, tuple(segments))


def spin_route(angle: float = math.pi, direction: Literal["cw", "ccw"] = "ccw") -> Route:
    """Turn in place by ``angle`` radians (Ivanjko et al.'s ±180° spins)."""
    if not angle > 0:
        raise ValueError(f"angle must be > 0, got {angle!r}")
    check_extent("angle", angle, angle, turn=True)
    sign = -1.0 if direction == "cw" else 1.0
    turn = Segment("turn", (0.0, 0.0), (0.0, 0.0), sign * angle, turn=sign * angle)
    return Route(f"spin-{direction}-{math.degrees(angle):g}deg", (turn,))


class RouteProgress:
    """Which segment each of N robots is on, and where its odometry says it is relative to it.

    Args:
        routes: one route per robot (routes may differ but are padded to the longest).
        position_tolerance: a drive is done when less than this remains [m] ...
        heading_tolerance: ... a turn when the heading error is below this [rad] ...
        stop_speed: ... and both wheels are slower than this [m/s]. Each tolerance is a scalar
            or one value per robot; they must exceed the odometry's resolution (one encoder
            count), or a robot could never be "there".
    """

    def __init__(
        self,
        routes: list[Route],
        *,
        position_tolerance: float | FloatArray = 0.002,
        heading_tolerance: float | FloatArray = 0.0005,
        stop_speed: float | FloatArray = 0.005,
    ) -> None:
        self.n = len(routes)
        # (N, 3): position tolerance [m], heading tolerance [rad], stop speed [m/s] per robot.
        self._limits = np.empty((self.n, 3))
        self._limits[:, 0] = position_tolerance
        self._limits[:, 1] = heading_tolerance
        self._limits[:, 2] = stop_speed
        self.set_routes(routes)

    @property
    def position_tolerance(self) -> FloatArray:
        """A drive is done when less than this remains (N,) [m]."""
        return self._limits[:, 0]

    @property
    def heading_tolerance(self) -> FloatArray:
        """A turn is done when the heading error is below this (N,) [rad]."""
        return self._limits[:, 1]

    @property
    def stop_speed(self) -> FloatArray:
        """A segment is done only when both wheels are slower than this (N,) [m/s]."""
        return self._limits[:, 2]

    def set_routes(self, routes: list[Route], indices: NDArray[np.intp] | None = None) -> None:
        """Assign routes (all robots, or robots ``indices``) and restart their progress."""
        if indices is None:
            self.routes = list(routes)
            self.segment_count = max(len(r.segments) for r in routes)
            size = (self.n, self.segment_count)
            self._is_turn = np.zeros(size, dtype=bool)
            # Per segment: start x, y [m]; unit direction of motion of a drive x, y; length
            # [m or rad]; held heading [rad]; +1 a drive along its heading, −1 reversing. One
            # array, so a compiled step takes it as one argument (odomgym._kernels).
            self._segments = np.zeros((*size, 7))
            self._count = np.zeros(self.n, dtype=np.intp)
            self.state = np.zeros((self.n, 8))
            self._advanced = np.zeros(self.n, dtype=np.bool_)
            self.progress = np.zeros(self.n)
            self._cumulative = np.zeros((self.n, self.segment_count + 1))
            self.index = np.zeros(self.n, dtype=np.intp)
            indices = np.arange(self.n)
        if len(routes) not in (1, len(indices)):
            raise ValueError(
                f"need one route, or one per robot ({len(indices)}), got {len(routes)}"
            )
        for row, i in enumerate(np.asarray(indices)):
            route = routes[row] if len(routes) == len(indices) else routes[0]
            if len(route.segments) > self.segment_count:
                raise ValueError("a route is longer than the routes this tracker was built for")
            self.routes[i] = route
            self._count[i] = len(route.segments)
            total = 0.0
            for s, seg in enumerate(route.segments):
                self._is_turn[i, s] = seg.kind == "turn"
                unit_x = unit_y = 0.0
                direction = 1.0
                if seg.kind == "drive":
                    dx, dy = seg.end[0] - seg.start[0], seg.end[1] - seg.start[1]
                    norm = math.hypot(dx, dy)
                    unit_x, unit_y = dx / norm, dy / norm
                    # +1 when a drive moves along the heading it holds, −1 when reversing.
                    facing = (dx * math.cos(seg.heading) + dy * math.sin(seg.heading)) / norm
                    direction = 1.0 if facing >= 0.0 else -1.0
                self._segments[i, s] = (
                    seg.start[0],
                    seg.start[1],
                    unit_x,
                    unit_y,
                    seg.length,
                    seg.heading,
                    direction,
                )
                total += seg.length
                self._cumulative[i, s + 1] = total
            self._cumulative[i, len(route.segments) + 1 :] = total
            self.index[i] = 0

    @property
    def done(self) -> NDArray[np.bool_]:
        """Robots that completed every segment of their route."""
        return np.asarray(self.index >= self._count)

    def update(
        self,
        odom_pose: FloatArray,
        wheel_speed: FloatArray,
        max_speed: FloatArray,
        advance: bool = True,
    ) -> NDArray[np.bool_]:
        """Refresh the route state from the odometry; optionally move on to the next segment.

        A robot moves on when its current segment is reached (less than the position tolerance
        left on a drive, heading error below the heading tolerance on a turn) *and* both wheels
        are below the stop speed. Fills ``state`` (N, 8) in the observation layout of
        :mod:`odomgym.sim.trial` and ``progress`` (N,) — route length done, in segment units (m for
        drives, rad for turns) — and returns which robots moved on.
        """
        advanced = self._advanced
        route_update(
            odom_pose,
            wheel_speed,
            max_speed,
            self._count,
            self._is_turn,
            self._segments,
            self._cumulative,
            self._limits,
            advance,
            self.index,
            self.state,
            self.progress,
            advanced,
        )
        return advanced.copy()

    def step_arrays(
        self,
    ) -> tuple[
        NDArray[np.intp],
        NDArray[np.bool_],
        FloatArray,
        FloatArray,
        FloatArray,
        NDArray[np.intp],
        FloatArray,
        FloatArray,
        NDArray[np.bool_],
    ]:
        """The arrays :func:`odomgym._kernels.route_update` takes after ``max_speed``, in its
        order, without ``advance`` (for a caller that runs it inside a larger compiled step)."""
        return (
            self._count,
            self._is_turn,
            self._segments,
            self._cumulative,
            self._limits,
            self.index,
            self.state,
            self.progress,
            self._advanced,
        )

    @property
    def segment_counts(self) -> NDArray[np.intp]:
        """Number of segments of each robot's route (N,) (read it, do not write it)."""
        return self._count

    @property
    def total(self) -> FloatArray:
        """Route length of each robot, in segment units (m for drives, rad for turns)."""
        return np.asarray(self._cumulative[np.arange(self.n), self._count])

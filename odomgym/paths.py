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

from odomgym._jit import kernel

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


def square_route(side: float = 4.0, direction: Literal["cw", "ccw"] = "cw") -> Route:
    """The UMBmark square: four legs of ``side`` metres, a 90° turn in place after each (the
    fourth turn restores the starting heading, Borenstein & Feng 1994, §6.3)."""
    if not side > 0:
        raise ValueError(f"side must be > 0, got {side!r}")
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
        self.position_tolerance = np.broadcast_to(np.asarray(position_tolerance, float), (self.n,))
        self.heading_tolerance = np.broadcast_to(np.asarray(heading_tolerance, float), (self.n,))
        self.stop_speed = np.broadcast_to(np.asarray(stop_speed, float), (self.n,))
        self.set_routes(routes)

    def set_routes(self, routes: list[Route], indices: NDArray[np.intp] | None = None) -> None:
        """Assign routes (all robots, or robots ``indices``) and restart their progress."""
        if indices is None:
            self.routes = list(routes)
            self.segment_count = max(len(r.segments) for r in routes)
            size = (self.n, self.segment_count)
            self._is_turn = np.zeros(size, dtype=bool)
            self._start = np.zeros((*size, 2))
            self._unit = np.zeros((*size, 2))  # direction of motion of a drive
            self._length = np.zeros(size)
            self._heading = np.zeros(size)
            self._direction = np.ones(size)  # +1 a drive along its heading, −1 reversing
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
                self._start[i, s] = seg.start
                self._heading[i, s] = seg.heading
                self._length[i, s] = seg.length
                if seg.kind == "drive":
                    dx, dy = seg.end[0] - seg.start[0], seg.end[1] - seg.start[1]
                    norm = math.hypot(dx, dy)
                    self._unit[i, s] = (dx / norm, dy / norm)
                    # +1 when a drive moves along the heading it holds, −1 when reversing.
                    facing = (dx * math.cos(seg.heading) + dy * math.sin(seg.heading)) / norm
                    self._direction[i, s] = 1.0 if facing >= 0.0 else -1.0
                else:
                    self._direction[i, s] = 1.0
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
        :mod:`odomgym.trial` and ``progress`` (N,) — route length done, in segment units (m for
        drives, rad for turns) — and returns which robots moved on.
        """
        advanced = self._advanced
        _route_update(
            odom_pose,
            wheel_speed,
            max_speed,
            self._count,
            self._is_turn,
            self._start,
            self._unit,
            self._length,
            self._heading,
            self._direction,
            self._cumulative,
            self.position_tolerance,
            self.heading_tolerance,
            self.stop_speed,
            advance,
            self.index,
            self.state,
            self.progress,
            advanced,
        )
        return advanced.copy()

    @property
    def segment_counts(self) -> NDArray[np.intp]:
        """Number of segments of each robot's route (N,) (read it, do not write it)."""
        return self._count

    @property
    def total(self) -> FloatArray:
        """Route length of each robot, in segment units (m for drives, rad for turns)."""
        return np.asarray(self._cumulative[np.arange(self.n), self._count])


@kernel
def _route_update(
    pose: FloatArray,
    wheel_speed: FloatArray,
    max_speed: FloatArray,
    count: NDArray[np.intp],
    is_turn: NDArray[np.bool_],
    start: FloatArray,
    unit: FloatArray,
    length: FloatArray,
    heading: FloatArray,
    drive_direction: FloatArray,
    cumulative: FloatArray,
    position_tolerance: FloatArray,
    heading_tolerance: FloatArray,
    stop_speed: FloatArray,
    advance: bool,
    index: NDArray[np.intp],
    state: FloatArray,
    progress: FloatArray,
    advanced: NDArray[np.bool_],
) -> None:
    """Route features of each robot's current segment (see :meth:`RouteProgress.update`)."""
    two_pi = 2.0 * math.pi
    for i in range(pose.shape[0]):
        advanced[i] = False
        for _attempt in range(2):  # the second pass describes the segment just moved on to
            k = index[i]
            finished = k >= count[i]
            s = min(k, count[i] - 1)
            # A turn counts the rotation left unwrapped (a 360° spin must not look finished at
            # the start): that goes to ``remaining``; the heading error itself is wrapped.
            rotation_left = heading[i, s] - pose[i, 2]
            error = (rotation_left + math.pi) % two_pi - math.pi
            rel_x = pose[i, 0] - start[i, s, 0]
            rel_y = pose[i, 1] - start[i, s, 1]
            travelled = rel_x * unit[i, s, 0] + rel_y * unit[i, s, 1]
            cross = unit[i, s, 0] * rel_y - unit[i, s, 1] * rel_x
            turn = is_turn[i, s]
            direction = drive_direction[i, s]
            if turn:
                remaining = rotation_left
                done_part = length[i, s] - abs(rotation_left)
                cross = 0.0
            else:
                remaining = length[i, s] - travelled
                done_part = travelled
                cross = cross * direction
            if finished:
                remaining = 0.0
                cross = 0.0
                error = 0.0
                progress[i] = cumulative[i, count[i]]
            else:
                progress[i] = cumulative[i, s] + min(max(done_part, 0.0), length[i, s])
            state[i, 0] = remaining
            state[i, 1] = cross
            state[i, 2] = error
            state[i, 3] = wheel_speed[i, 0] / max_speed[i]
            state[i, 4] = wheel_speed[i, 1] / max_speed[i]
            state[i, 5] = 1.0 if turn else 0.0
            state[i, 6] = direction
            total = cumulative[i, count[i]]
            state[i, 7] = progress[i] / total if total > 0.0 else 1.0
            if not advance or finished or advanced[i]:
                break
            stopped = max(abs(wheel_speed[i, 0]), abs(wheel_speed[i, 1])) < stop_speed[i]
            if turn:
                reached = abs(remaining) < heading_tolerance[i]
            else:
                reached = remaining < position_tolerance[i]
            if not (reached and stopped):
                break
            index[i] = k + 1
            advanced[i] = True

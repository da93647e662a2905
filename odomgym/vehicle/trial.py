"""Driving a two-truck vehicle (the CLAPPER, Borenstein 1995) along a path, with or without
internal position error correction.

A :class:`VehiclePath` is a sequence of legs, each a polyline driven forwards or backwards with a
stop at its end: the straight experiment of Borenstein 1995, §6.1 (18 m out, then 18 m back
*backwards*) and the 7×4 m rectangle with smooth 90° turns of §6.2.

:class:`VehicleDriver` is the low-level controller. The paper does not give its control law; it
says the controller holds both rotary encoders at 0° when driving straight (§5.2) and that the
compliant linkage absorbs its momentary errors (§2). Here (``steering="psi"``, the default,
in both modes, with and without IPEC) the truck that leads in the direction of travel (A
forwards, B when reversing) tracks a moving reference point with Kanayama et al.'s (1990)
tracking law using its *estimated* pose (IPEC's or plain dead reckoning's), as the real vehicle
does, and the other truck holds its rotary encoder at the angle the path expects — 0° on a
straight, as §5.2 says — with its speed regulated by the linear encoder: it follows the leader
through the linkage, never by its own dead reckoning, so the two trucks cannot drift apart
whatever their odometry does. ``steering="pose"`` lets each truck track its own reference by
its own estimate (the earlier controller: without IPEC the trucks then drift apart until the
linkage's end stop drags them). The leader's reference moves along the path with a trapezoidal
speed profile; the follower's is the path point a straight-line distance l₀ behind A's (so
turns do not compress the link), and B's speed is corrected by the measured link length so the
linear bearing stays near the middle of its range.

:func:`drive_vehicles` runs N vehicles in one :class:`~odomgym.sim.world.World` (2N trucks, N
links), sampling the encoders every T_s and feeding the estimator, and returns each vehicle's
true and estimated poses at the end.

Units: metres, radians, seconds.
"""

from __future__ import annotations

import bisect
import dataclasses
import functools
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.floor import CableBump, FloorSpec
from odomgym.odometry.calibration import Calibration, Odometry, wrap_angle
from odomgym.sim.cables import rim_travel_for_advance
from odomgym.sim.world import World
from odomgym.vehicle.estimator import DeadReckoning, InternalEstimator, link_angles, link_length
from odomgym.vehicle.spec import VehicleSpec, link_readings

__all__ = [
    "CLAPPER_FLOOR",
    "CableLayer",
    "EstimatorFactory",
    "Leg",
    "VehicleDriver",
    "VehicleOutcome",
    "VehiclePath",
    "VehicleTrial",
    "circle_path",
    "drive_vehicles",
    "evenly",
    "rectangle_path",
    "straight_path",
    "vehicle_pose",
]

FloatArray = NDArray[np.float64]

CLAPPER_FLOOR = "concrete"
"""The one floor of the CLAPPER experiments — the CLI's, the envs' and the tests' default: the
paper ran on "fairly smooth concrete floors" (Borenstein 1995, §6), and the ``concrete``
floor's wheel noise is what makes runs of one condition differ (``odomgym.floor``)."""


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
    def polyline(self) -> _Polyline:
        """The points, arc lengths and segment headings as Python floats, for the per-step
        look-ups of :func:`_point` (scalar arithmetic: numpy's per-call overhead on scalars
        was three quarters of a CLAPPER run's time)."""
        points = np.asarray(self.points, dtype=float)
        d = np.diff(points, axis=0)
        return _Polyline(
            x=points[:, 0].tolist(),
            y=points[:, 1].tolist(),
            arc=self.arc_length.tolist(),
            heading=[math.atan2(dy, dx) for dx, dy in d.tolist()],
        )


@dataclass(frozen=True)
class _Polyline:
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
        arc = path.legs[leg].arc_length
        target = self.at[len(self.laid)]
        # How far along the leg each truck is: the arc length of its nearest path point within
        # a window just ahead of where it was (a closed path passes its start twice).
        reached = []
        for k in (0, 1):
            window = (arc >= self._progress[k] - 0.2) & (arc <= self._progress[k] + 1.0)
            if not window.any():
                window = arc >= self._progress[k] - 0.2
            near = np.flatnonzero(window)
            nearest = near[np.argmin(np.hypot(*(points[near] - truth[k, :2]).T))]
            self._progress[k] = max(self._progress[k], float(arc[nearest]))
            reached.append(self._progress[k])
        if max(reached) < target - self.lead:
            return None
        x_t, y_t, tangent_heading, _ = _point(path.legs[leg].polyline, target)
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


def vehicle_pose(poses: FloatArray) -> FloatArray:
    """The vehicle's pose (N, 3) from truck poses (N, 2, 3): the midpoint of the truck centres
    and the heading of the linkage (from B to A)."""
    mid = 0.5 * (poses[:, 0, :2] + poses[:, 1, :2])
    return np.column_stack([mid, link_angles(poses)[0]])


@dataclass
class VehicleDriver:
    """Kanayama tracking of moving references by both trucks (module docstring).

    Args:
        cruise_speed: reference speed on a leg [m/s] (Borenstein 1995, §6: just under 0.5).
        accel: reference acceleration and deceleration [m/s²].
        k_x, k_y, k_theta: Kanayama et al. 1990 gains (along-track [1/s], cross-track [1/m²],
            heading [1/m]).
        k_link: link-length feedback on truck B's speed [1/s].
        steering: ``"psi"`` (the follower holds its rotary encoder at the path's expected
            angle, §5.2) or ``"pose"`` (each truck tracks its own reference by its own
            estimate); see the module docstring.
        k_psi: the follower's turn rate per radian of rotary-encoder error, per metre per
            second of speed [1/m] (as Kanayama's heading gain).
        lateral_accel: the reference slows for curves to keep v²·κ below this [m/s²], so that
            the rear truck, whose reference sweeps faster than the front's through a turn,
            stays within its wheels' speed limit.
    """

    cruise_speed: float = 0.45
    accel: float = 0.4
    k_x: float = 1.5
    k_y: float = 4.0
    k_theta: float = 3.0
    k_link: float = 1.0
    lateral_accel: float = 0.1
    steering: Literal["psi", "pose"] = "psi"
    k_psi: float = 6.0

    def __post_init__(self) -> None:
        if self.steering not in ("psi", "pose"):
            raise ValueError(f"steering must be 'psi' or 'pose', got {self.steering!r}")
        if not (math.isfinite(self.k_psi) and self.k_psi > 0.0):
            raise ValueError(f"k_psi must be a positive number [1/m], got {self.k_psi!r}")

    def plan(self, path: VehiclePath, n: int) -> None:
        self._path = path
        self._leg = np.zeros(n, dtype=np.int64)
        self._s = np.zeros(n)
        self._v = np.zeros(n)
        self._s_b = np.full(n, np.nan)  # truck B's reference arc length at the last step
        self._arcs = [leg.arc_length for leg in path.legs]
        self._limits = [self._speed_limit(leg) for leg in path.legs]

    def _speed_limit(self, leg: Leg) -> FloatArray:
        """Largest reference speed at each point of ``leg`` [m/s]: the cruise speed, slowed for
        curvature and, braking at ``accel``, for the curves and the stop ahead."""
        arc = leg.arc_length
        heading = leg.headings
        curvature = np.zeros(len(arc))
        ds = np.diff(arc)
        curvature[1:-1] = np.abs(np.diff(heading)) / np.maximum(0.5 * (ds[1:] + ds[:-1]), 1e-9)
        limit = np.minimum(
            self.cruise_speed, np.sqrt(self.lateral_accel / np.maximum(curvature, 1e-9))
        )
        limit[-1] = 0.0
        for k in range(len(arc) - 2, -1, -1):  # brake in time for what lies ahead
            limit[k] = min(limit[k], math.sqrt(limit[k + 1] ** 2 + 2.0 * self.accel * ds[k]))
        return limit

    def done(self) -> NDArray[np.bool_]:
        """Vehicles that have driven every leg."""
        return np.asarray(self._leg >= len(self._path.legs))

    @property
    def leg_index(self) -> NDArray[np.int64]:
        """Index of the leg each vehicle is on (N,); the number of legs once it has finished
        (a copy)."""
        return self._leg.copy()

    @property
    def reference_arc(self) -> FloatArray:
        """Arc length of truck A's reference along its current leg (N,) [m] (a copy)."""
        return self._s.copy()

    @property
    def reference_speed(self) -> FloatArray:
        """Speed of truck A's reference (N,) [m/s] (a copy)."""
        return self._v.copy()

    @property
    def leg(self) -> int:
        """The leg every vehicle is on or has finished (vehicles wait at the end of a leg
        until all have arrived, so that the floor can change between legs)."""
        return int(self._leg.min())

    def act(
        self,
        estimate: FloatArray,
        link_length: FloatArray,
        l0: float,
        half_track: FloatArray,
        dt: float,
        speed: FloatArray | None = None,
        psi: FloatArray | None = None,
        towed: bool = False,
    ) -> FloatArray:
        """Wheel speeds (N, 2, 2) [m/s] for the trucks from the estimated poses (N, 2, 3) and
        the measured link lengths (N,). ``speed`` (N,), if given, asks for a reference speed
        as a fraction of the cruise speed (an env's action); the curve and stop limits and the
        acceleration limit still apply. ``psi`` (N, 2): the rotary encoders' readings [rad],
        which the ``"psi"`` steering needs (without them each truck tracks its own
        reference). ``towed``: truck B is an unpowered trailer (its row of the result is left
        at zero for the caller to fill): A tracks the path going forwards and, reversing,
        holds the hitch angle ψ_A at the path's expected angle, which keeps a pushed trailer
        from jack-knifing."""
        n = estimate.shape[0]
        out = np.zeros((n, 2, 2))
        for i in range(n):
            k = int(self._leg[i])
            if k >= len(self._path.legs) or k > self._leg.min():
                continue  # finished, or waiting for the others at the end of its leg
            leg, arc = self._path.legs[k], self._arcs[k]
            total = float(arc[-1])
            # Reference speed: accelerate to the cruise speed, slow for curves and the stop.
            v_max = float(np.interp(self._s[i], arc, self._limits[k]))
            if self._s[i] < total:
                v_max = max(v_max, 0.02)  # never stall short of the end
            wanted = v_max if speed is None else min(v_max, float(speed[i]) * self.cruise_speed)
            v = min(max(wanted, self._v[i] - self.accel * dt), self._v[i] + self.accel * dt)
            v = max(0.0, min(v, v_max))
            self._v[i] = v
            self._s[i] = min(total, self._s[i] + v * dt)
            if self._s[i] >= total and v < 1e-3:
                self._leg[i] = k + 1
                self._s[i] = 0.0
                self._v[i] = 0.0
                self._s_b[i] = np.nan
                continue
            # Truck A leads forwards and trails backwards: B's reference is l0 behind A's in
            # the direction the trucks face, i.e. ahead in the direction of travel when reversing.
            line = leg.polyline
            ref_a = _point(line, float(self._s[i]))
            s_b = _offset(line, float(self._s[i]), l0, -leg.direction)
            ref_b = _reference(line, s_b)
            # B's reference moves at its own rate (slower than A's where A turns away from it);
            # a link longer than l0 makes the trailing truck speed up, the leading one slow down.
            previous = self._s_b[i]
            v_b_ref = v if np.isnan(previous) else (s_b - previous) / dt
            self._s_b[i] = s_b
            v_b = v_b_ref + leg.direction * self.k_link * (float(link_length[i]) - l0)
            refs = ((0, ref_a, v), (1, ref_b, v_b))
            if towed and leg.direction > 0:
                out[i, 0] = self._track(
                    estimate[i, 0], ref_a, v, leg.direction, float(half_track[i, 0])
                )
                continue
            if towed or (self.steering == "psi" and psi is not None):
                # The leader in the direction of travel tracks its reference by its estimate;
                # the follower holds its rotary encoder at the angle the path expects.
                leader = 0 if leg.direction > 0 else 1
                truck, ref, v_lead = refs[leader]
                if not towed:
                    out[i, truck] = self._track(
                        estimate[i, truck], ref, v_lead, leg.direction, float(half_track[i, truck])
                    )
                follower = 1 - leader
                _, ref_f, v_f = refs[follower]  # towed, reversing: A at the reference speed
                if psi is None:
                    raise ValueError("a towed trailer needs the hitch encoder's reading (psi)")
                link = math.atan2(ref_a[1] - ref_b[1], ref_a[0] - ref_b[0])
                facing = ref_f[2] + (math.pi if leg.direction < 0 else 0.0)
                expected = _wrap(facing - link)
                error = _wrap(expected - float(psi[i, follower]))
                omega = v_f * ref_f[3] + abs(v_f) * self.k_psi * error
                ahead = v_f if leg.direction > 0 else -v_f
                h = float(half_track[i, follower])
                out[i, follower, 0] = ahead - omega * h
                out[i, follower, 1] = ahead + omega * h
                continue
            for truck, ref, v_truck in refs:
                out[i, truck] = self._track(
                    estimate[i, truck], ref, v_truck, leg.direction, float(half_track[i, truck])
                )
        return out

    def _track(
        self,
        pose: FloatArray,
        ref: tuple[float, float, float, float],
        v_ref: float,
        direction: float,
        half_track: float,
    ) -> FloatArray:
        x_r, y_r, heading_r, curvature = ref
        theta = pose[2] + (math.pi if direction < 0 else 0.0)
        c, s = math.cos(theta), math.sin(theta)
        dx, dy = x_r - pose[0], y_r - pose[1]
        e_x = c * dx + s * dy
        e_y = -s * dx + c * dy
        e_theta = _wrap(heading_r - theta)
        v = v_ref * math.cos(e_theta) + self.k_x * e_x
        omega = v_ref * curvature + v_ref * (self.k_y * e_y + self.k_theta * math.sin(e_theta))
        if direction < 0:
            v = -v
        return np.array([v - omega * half_track, v + omega * half_track])


def _wrap(angle: float) -> float:
    """:func:`odomgym.odometry.calibration.wrap_angle` for one float (the same IEEE result: Python's
    ``%`` and ``np.mod`` both take the divisor's sign)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def _reference(line: _Polyline, s: float) -> tuple[float, float, float, float]:
    """:func:`_point`, continued straight (zero curvature) beyond the polyline's ends."""
    if 0.0 <= s <= line.arc[-1]:
        return _point(line, s)
    x, y = _extended(line, s)
    heading = line.heading[0] if s < 0.0 else line.heading[-1]
    return x, y, heading, 0.0


def _point(line: _Polyline, s: float) -> tuple[float, float, float, float]:
    """Position, tangent heading and curvature of the polyline at arc length ``s``."""
    arc = line.arc
    last = len(arc) - 2
    k = min(max(bisect.bisect_right(arc, s) - 1, 0), last)
    t = (s - arc[k]) / max(arc[k + 1] - arc[k], 1e-12)
    x = line.x[k] + t * (line.x[k + 1] - line.x[k])
    y = line.y[k] + t * (line.y[k + 1] - line.y[k])
    heading = line.heading[k]
    j = min(k + 1, last)
    if j > k:
        step = max(arc[j + 1] - arc[k], 1e-9) / 2.0
        curvature = _wrap(line.heading[j] - heading) / step
    else:
        curvature = 0.0
    return x, y, heading, curvature


def _offset(line: _Polyline, s: float, distance: float, side: float) -> float:
    """Arc length of the path point at straight-line ``distance`` [m] from the point at ``s``:
    behind it (``side`` −1) or ahead of it (+1) along the polyline, on the straight extension
    of its first or last segment beyond the ends.

    Found by marching along the path by the chord's shortfall: a chord is never longer than
    its arc, so each step lands short of (or on) the point and the shortfall shrinks — one step
    on a straight, a few in a turn — to 1e-10 m; bisection takes over should a path fold back
    on itself so that the march stalls."""
    ax, ay = _extended(line, s)
    t = s
    for _ in range(64):
        x, y = _extended(line, t)
        gap = distance - math.hypot(ax - x, ay - y)
        if gap <= 1e-10:
            return t
        t += side * gap
    near, far = s, s + side * 3.0 * distance
    for _ in range(64):  # the chord grows monotonically from ``near`` to ``far``
        mid = 0.5 * (near + far)
        x, y = _extended(line, mid)
        if math.hypot(ax - x, ay - y) < distance:
            near = mid
        else:
            far = mid
    return 0.5 * (near + far)


def _extended(line: _Polyline, s: float) -> tuple[float, float]:
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
    x, y, _, _ = _point(line, s)
    return x, y


def _wheel_contacts(pose: FloatArray, half_track: FloatArray) -> FloatArray:
    """Contact points (M, 2, 2) [m] of the left and right wheels of bodies at ``pose`` (M, 3),
    ``half_track`` (M,) [m] to either side of the heading (left at +y in the body frame)."""
    left = np.stack([-np.sin(pose[:, 2]), np.cos(pose[:, 2])], axis=1) * half_track[:, None]
    return np.stack([pose[:, :2] + left, pose[:, :2] - left], axis=1)


def _free_wheel_rim(
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


def _cable_arrays(cables: tuple[CableBump, ...]) -> tuple[FloatArray, ...]:
    """Centres, unit axes and half lengths (K,) of ``cables`` [m], for crossing counts."""
    return (
        np.array([c.x for c in cables]),
        np.array([c.y for c in cables]),
        np.array([math.cos(c.angle) for c in cables]),
        np.array([math.sin(c.angle) for c in cables]),
        np.array([0.5 * c.length for c in cables]),
    )


EstimatorFactory = Callable[[FloatArray], InternalEstimator]
"""Builds an estimator from the odometry's wheelbases (N, 2) [m] (e.g. ``DeadReckoning`` or
``odomgym.vehicle.ipec.IPEC``)."""


@dataclass(frozen=True)
class VehicleOutcome:
    """The end of a run of N vehicles (arrays with a leading vehicle axis).

    ``true_poses``, ``estimated`` and ``odometry`` are truck poses (N, 2, 3): the truth, the
    estimator's, and each truck's own wheel odometry. ``return_error`` (N, 3) is the vehicle's
    true minus estimated pose (:func:`vehicle_pose`: midpoint of the truck centres, heading of
    the link; heading wrapped), ``truck_errors`` (N, 2, 3) the same per truck. ``link_range``
    (N, 2) the shortest and longest true centre distance seen [m], ``link_force`` (N,) the
    largest force the bearing's end stops passed [N], ``corrections`` (N, 2) the summed
    orientation corrections of the estimator [rad], ``time`` the simulated duration [s],
    ``finished`` (N,) whether each vehicle drove the whole path, ``cable_crossings`` (N, 2)
    how many times the wheels of truck A and of truck B passed over a laid cable.
    """

    true_poses: FloatArray
    estimated: FloatArray
    odometry: FloatArray
    return_error: FloatArray
    truck_errors: FloatArray
    link_range: FloatArray
    link_force: FloatArray
    corrections: FloatArray
    time: float
    finished: NDArray[np.bool_]
    cable_crossings: NDArray[np.int64] = field(
        default_factory=lambda: np.zeros((0, 2), dtype=np.int64)
    )


class VehicleTrial:
    """N copies of a vehicle driving ``path`` on ``floor`` in one World (they start at the same
    place and never touch), steered by ``estimator``'s poses (default: plain dead reckoning,
    i.e. without IPEC), one sampling interval T_s per :meth:`step`. ``cables`` lays cables as
    the vehicle comes (one vehicle only: the floor is shared); ``rng`` feeds a rough floor's
    wheel noise."""

    def __init__(
        self,
        spec: VehicleSpec,
        floor: FloorSpec,
        path: VehiclePath,
        n: int = 1,
        *,
        estimator: EstimatorFactory | None = None,
        calibration: Calibration | None = None,
        driver: VehicleDriver | None = None,
        cables: CableLayer | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        if cables is not None and n != 1:
            raise ValueError("cables are laid under one vehicle: use n=1")
        self.spec, self.floor, self.path, self.n, self.cables = spec, floor, path, n, cables
        trucks = [spec.truck_a, spec.truck_b] * n
        links = [(2 * k, 2 * k + 1, spec.link_min, spec.link_max) for k in range(n)]
        hitches = [(2 * k, 2 * k + 1, spec.link_length) for k in range(n)]
        self.dt = spec.sample_period
        self.world = World(
            trucks,
            floor,
            dt=self.dt,
            links=[] if spec.trailer else links,
            hitches=hitches if spec.trailer else [],
            rng=rng,
        )
        start = np.tile(path.start_poses(spec.link_length), (n, 1, 1))
        self.world.reset(start.reshape(2 * n, 3))
        self.odometry = Odometry(trucks, calibration)
        self.odometry.reset(start.reshape(2 * n, 3))
        self.wheelbase = self.odometry.effective_wheelbase.reshape(n, 2)
        self.estimator = (estimator or DeadReckoning)(self.wheelbase)
        # The internal encoders' jitter has its own stream, so that switching it on does not
        # change the floor's noise of the same seed.
        self._reading_rng = (
            np.random.default_rng(rng.bit_generator.seed_seq.spawn(1)[0])  # type: ignore[attr-defined]
            if rng is not None
            else np.random.default_rng(0)
        )
        self._previous_truth = self.world.pose.reshape(n, 2, 3).copy()
        self.reading = link_readings(spec, self._previous_truth, self._reading_rng)
        self.estimator.reset(start.copy(), self.reading)
        self.estimated = start.copy()
        self.driver = driver or VehicleDriver()
        self.driver.plan(path, n)
        self._rate_per_speed = 1.0 / self.world.nominal_radius[:, None]
        self._last_counts = self.world.counts.copy()
        length = link_length(start)
        self.link_range = np.stack([length, length], axis=1)
        self.link_force = np.zeros(n)
        self.corrections = np.zeros((n, 2))
        self.cable_crossings = np.zeros((n, 2), dtype=np.int64)
        self._cable_geometry: tuple[FloatArray, ...] | None = None
        self._cable_side: FloatArray | None = None
        self.steps = 0

    @property
    def time(self) -> float:
        """Simulated time [s]."""
        return self.steps * self.dt

    @property
    def done(self) -> NDArray[np.bool_]:
        """Vehicles that have driven the whole path."""
        return self.driver.done()

    @property
    def truth(self) -> FloatArray:
        """True truck poses (N, 2, 3) [m, m, rad]."""
        return self.world.pose.reshape(self.n, 2, 3)

    def step(self, speed: FloatArray | None = None) -> None:
        """One sampling interval: lay a cable if one is due, steer, move, read the encoders
        and update the estimate. ``speed``: see :meth:`VehicleDriver.act`."""
        world, n = self.world, self.n
        if self.cables is not None:
            laid = self.cables(
                self.driver.leg,
                self.path,
                world.pose[:2],
                (self.spec.truck_a.true_wheelbase, self.spec.truck_b.true_wheelbase),
            )
            if laid is not None:  # the floor as it was, plus the cables laid so far
                squeeze = self.spec.tyre_compression
                felt = tuple(  # a compliant tyre swallows part of the cable's height
                    dataclasses.replace(c, diameter=max(c.diameter - squeeze, 1e-4)) for c in laid
                )
                world.lay_floor(dataclasses.replace(self.floor, bumps=self.floor.bumps + felt))
                self._cable_geometry = _cable_arrays(laid)
                # Which side of every cable each wheel is on before this interval's motion,
                # so that a crossing in the interval a cable is laid counts too.
                self._cable_side = self._wheel_sides(self.truth)[0]
        speeds = self.driver.act(
            self.estimated,
            self.reading.length,
            self.spec.link_length,
            0.5 * self.wheelbase,
            self.dt,
            speed,
            self.reading.psi,
            towed=self.spec.trailer,
        )
        rates = speeds.reshape(2 * n, 2) * self._rate_per_speed
        if self.spec.trailer:
            rates[1::2] = self._free_rolling(speeds[:, 0])
        world.step(rates)
        counts = world.counts.copy()
        travel = ((counts - self._last_counts) * self.odometry.travel_per_tick).reshape(n, 2, 2)
        self._last_counts = counts
        self.odometry.update(counts, self.dt)
        truth = self.truth
        shown = truth
        if self.spec.read_skew > 0.0:  # the link encoders read read_skew before the wheels
            f = self.spec.read_skew / self.dt
            shown = truth + f * (self._previous_truth - truth)
            shown[:, :, 2] = truth[:, :, 2] + f * wrap_angle(
                self._previous_truth[:, :, 2] - truth[:, :, 2]
            )
        self._previous_truth = truth.copy()
        self.reading = link_readings(self.spec, shown, self._reading_rng)
        self.estimated = self.estimator.update(travel, self.reading)
        if self._cable_geometry is not None:
            self._count_crossings(truth)
        self.corrections += self.estimator.correction
        length = link_length(truth)
        self.link_range[:, 0] = np.minimum(self.link_range[:, 0], length)
        self.link_range[:, 1] = np.maximum(self.link_range[:, 1], length)
        self.link_force = np.maximum(self.link_force, self.current_link_force())
        self.steps += 1

    def current_link_force(self) -> FloatArray:
        """The force each vehicle's linkage passed in the last interval (N,) [N]: the end stops'
        for the CLAPPER (0 inside its range), the hitch's towing force for a trailer."""
        world = self.world
        return np.asarray(world.hitch_forces() if self.spec.trailer else world.link_forces())

    def _free_rolling(self, towing: FloatArray) -> FloatArray:
        """Wheel rates (N, 2) [rad/s] of the trailers' free-rolling wheels in the coming
        interval. The World drives every wheel at a commanded rate through a friction-limited
        contact, which resists any other speed along the wheel as well as across it; a wheel
        commanded to the speed the tow gives it passes (nearly) no force along itself. That
        speed is the trailer's kinematics under the hitch (robot A's centre) moving at the
        robot's commanded speed ``towing`` (N, 2) [m/s, left and right wheel] along its heading:
        the trailer moves along its own heading at v·cos φ and turns at v·sin φ / L about its
        axle, φ the hitch angle, L the tongue. A limitation, measured: the hitch passes ≈ 0 N
        on a straight at steady speed, but up to ~60 N in and after the rectangle's tight turns,
        where the commanded and the actual motion of the 40 ms interval differ and the
        velocity-controlled contacts (not truly free wheels) take up the difference."""
        world = self.world
        robot = world.pose[0::2]
        pose = world.pose[1::2]
        v = 0.5 * (towing[:, 0] + towing[:, 1])
        phi = robot[:, 2] - pose[:, 2]
        along = v * np.cos(phi)
        omega = v * np.sin(phi) / self.spec.link_length
        turn = omega * world.half_track[1::2]
        ground = np.stack([along - turn, along + turn], axis=1)
        cables = self.world.floor.bumps
        if cables:  # over a cable the rim turns through the arc, not the horizontal advance
            radius = world.true_radius[1::2]
            contacts = _wheel_contacts(pose, world.half_track[1::2])
            for k in range(len(pose)):
                c, s = math.cos(float(pose[k, 2])), math.sin(float(pose[k, 2]))
                for w in (0, 1):
                    px, py = (float(v) for v in contacts[k, w])
                    step = float(ground[k, w]) * self.dt
                    ground[k, w] = (
                        _free_wheel_rim(cables, px, py, c, s, step, float(radius[k, w])) / self.dt
                    )
        return np.asarray(ground / world.true_radius[1::2])

    def _count_crossings(self, truth: FloatArray) -> None:
        """Count each truck's wheels passing a laid cable this interval: a wheel's contact point
        changed sides of a cable's axis while within the cable's length."""
        side, within = self._wheel_sides(truth)
        if self._cable_side is not None:
            crossed = (side != self._cable_side) & (side != 0) & within
            per_wheel = crossed.sum(axis=1)
            self.cable_crossings[0, 0] += int(per_wheel[:2].sum())
            self.cable_crossings[0, 1] += int(per_wheel[2:].sum())
        self._cable_side = side

    def _wheel_sides(self, truth: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
        """For each wheel (A left, A right, B left, B right) and laid cable: the side of the
        cable's axis its contact point is on (±1) and whether it lies within the cable's
        length."""
        assert self._cable_geometry is not None
        cx, cy, ax, ay, half = self._cable_geometry
        points = _wheel_contacts(truth[0], self.world.half_track[:2]).reshape(4, 2)
        px = points[:, 0:1] - cx[None, :]
        py = points[:, 1:2] - cy[None, :]
        side = np.sign(px * -ay[None, :] + py * ax[None, :])
        within = np.abs(px * ax[None, :] + py * ay[None, :]) <= half[None, :]
        return side, within

    def errors(self) -> tuple[FloatArray, FloatArray]:
        """(vehicle error (N, 3), truck errors (N, 2, 3)): true minus estimated, headings
        wrapped; the vehicle's pose is :func:`vehicle_pose`."""
        truth = self.truth
        trucks = truth - self.estimated
        trucks[:, :, 2] = wrap_angle(trucks[:, :, 2])
        vehicle = vehicle_pose(truth) - vehicle_pose(self.estimated)
        vehicle[:, 2] = wrap_angle(vehicle[:, 2])
        return vehicle, trucks

    def outcome(self) -> VehicleOutcome:
        """The state now, as a :class:`VehicleOutcome`."""
        vehicle, trucks = self.errors()
        return VehicleOutcome(
            true_poses=self.truth.copy(),
            estimated=self.estimated.copy(),
            odometry=self.odometry.pose.reshape(self.n, 2, 3).copy(),
            return_error=vehicle,
            truck_errors=trucks,
            link_range=self.link_range.copy(),
            link_force=self.link_force.copy(),
            corrections=self.corrections.copy(),
            time=self.time,
            finished=self.done.copy(),
            cable_crossings=self.cable_crossings.copy(),
        )


def drive_vehicles(
    spec: VehicleSpec,
    floor: FloorSpec,
    path: VehiclePath,
    n: int = 1,
    *,
    estimator: EstimatorFactory | None = None,
    calibration: Calibration | None = None,
    driver: VehicleDriver | None = None,
    max_time: float | None = None,
    cables: CableLayer | None = None,
    rng: np.random.Generator | None = None,
) -> VehicleOutcome:
    """Drive a :class:`VehicleTrial` with the reference speed profile until every vehicle has
    driven the path (or ``max_time`` [s], default three times the nominal duration + 60 s)."""
    trial = VehicleTrial(
        spec,
        floor,
        path,
        n,
        estimator=estimator,
        calibration=calibration,
        driver=driver,
        cables=cables,
        rng=rng,
    )
    total = sum(leg.length for leg in path.legs)
    limit = max_time if max_time is not None else 3.0 * total / trial.driver.cruise_speed + 60.0
    while not trial.done.all() and trial.time < limit:
        trial.step()
    return trial.outcome()

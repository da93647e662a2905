"""The low-level controller of a two-truck vehicle (the CLAPPER, Borenstein 1995).

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

Units: metres, radians, seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.vehicle.paths import (
    Leg,
    VehiclePath,
    interp_float,
    offset_at,
    point_at,
    reference_at,
    wrap_float,
)

__all__ = ["VehicleDriver"]

FloatArray = NDArray[np.float64]


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
        self._first_leg = 0  # self._leg.min(), kept as it changes (asked every control step)
        self._s = np.zeros(n)
        self._v = np.zeros(n)
        self._s_b = np.full(n, np.nan)  # truck B's reference arc length at the last step
        self._arcs = [leg.polyline.arc for leg in path.legs]
        self._limits = [self._speed_limit(leg).tolist() for leg in path.legs]

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
        return self._first_leg

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
            if k >= len(self._path.legs) or k > self._first_leg:
                continue  # finished, or waiting for the others at the end of its leg
            leg, arc = self._path.legs[k], self._arcs[k]
            total = arc[-1]
            # Reference speed: accelerate to the cruise speed, slow for curves and the stop.
            s, v_last = float(self._s[i]), float(self._v[i])  # Python floats: cheaper here
            v_max = interp_float(s, arc, self._limits[k])
            if s < total:
                v_max = max(v_max, 0.02)  # never stall short of the end
            wanted = v_max if speed is None else min(v_max, float(speed[i]) * self.cruise_speed)
            v = min(max(wanted, v_last - self.accel * dt), v_last + self.accel * dt)
            v = max(0.0, min(v, v_max))
            self._v[i] = v
            s = min(total, s + v * dt)
            self._s[i] = s
            if s >= total and v < 1e-3:
                self._leg[i] = k + 1
                self._first_leg = int(self._leg.min())
                self._s[i] = 0.0
                self._v[i] = 0.0
                self._s_b[i] = np.nan
                continue
            # Truck A leads forwards and trails backwards: B's reference is l0 behind A's in
            # the direction the trucks face, i.e. ahead in the direction of travel when reversing.
            line = leg.polyline
            ref_a = point_at(line, s)
            s_b = offset_at(line, s, l0, -leg.direction, ref_a[:2])
            ref_b = reference_at(line, s_b)
            # B's reference moves at its own rate (slower than A's where A turns away from it);
            # a link longer than l0 makes the trailing truck speed up, the leading one slow down.
            previous = self._s_b[i]  # numpy's float: NaN, not an exception, should dt be 0
            v_b_ref = v if math.isnan(previous) else (s_b - previous) / dt
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
                expected = wrap_float(facing - link)
                error = wrap_float(expected - float(psi[i, follower]))
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
    ) -> tuple[float, float]:
        """Kanayama et al. 1990's tracking law: the (left, right) wheel speeds [m/s] that bring
        a truck at ``pose`` onto the moving reference ``ref`` (x, y, heading, curvature)."""
        x_r, y_r, heading_r, curvature = ref
        theta = pose[2] + (math.pi if direction < 0 else 0.0)
        c, s = math.cos(theta), math.sin(theta)
        dx, dy = x_r - pose[0], y_r - pose[1]
        e_x = c * dx + s * dy
        e_y = -s * dx + c * dy
        e_theta = wrap_float(heading_r - theta)
        v = v_ref * math.cos(e_theta) + self.k_x * e_x
        omega = v_ref * curvature + v_ref * (self.k_y * e_y + self.k_theta * math.sin(e_theta))
        if direction < 0:
            v = -v
        return v - omega * half_track, v + omega * half_track

"""An independent source of measured logs: a differential-drive robot that carries effects.

This module is the "robot from somewhere else" on which the discrepancy-diagnosis workflow is
tested. It is written from the written specification of the effects (``docs/effects.md``) only
and deliberately does **not** use odomgym's simulator (``odomgym.sim.world``,
``odomgym.lab.simulated``, ``odomgym.sim.trial``, ``odomgym.effects``, ``odomgym.diagnose`` are
never imported), so that a workflow that recovers the effects from these logs cannot be relying on
artefacts of odomgym's own integrator, log rate, speed profiles or noise model.

How it differs from odomgym's simulator on purpose:

* **Motion** is open-loop and continuous in time: every move is a smooth S-curve
  (raised-cosine acceleration ramps, continuous acceleration, no trapezoids) of the two motor
  angles, planned with the *nominal* wheel diameter and wheelbase; whatever the wheels then do is
  the path. Moves are separated by short random stops; a square is four drive + in-place-turn
  pairs with stops in between.
* **Integration** of the body pose uses exact constant-curvature (arc) steps at
  ``integration_hz`` on a grid that also contains every log time and every move boundary, so
  the motor angles are monotone within each step and the play operator of the backlash is exact.
* **Encoders** count the continuous motor angle, quantised with ``floor`` and a random initial
  encoder phase, logged cumulative from the run start.
* **Logging** at ``log_rate_hz`` (10 Hz by default), ground truth = the tracked point plus
  Gaussian sensor noise on every logged row; runs start at a random pose in the world frame.

The effects are applied to the continuous motion as ``docs/effects.md`` specifies them:
true diameters from ``e_d``/``e_s``, wheelbase ``e_b``, backlash as a play operator between the
motor (which the encoder counts) and the wheel, ``turn_skid`` scaling the yaw rate by
max(0, 1 − κ|v·ω₀|), ``skid_speed`` by 1 + g|v·ω₀| (ω₀ the no-slip yaw rate),
``skid_track`` dividing it by 1 + ε/(1 + (λ/λ½)²) with λ the step's ratio
of the wheels' summed to differenced ground travel, ``wheel_toe`` turning the velocity to
heading + τ, ``floor_roughness`` as per-wheel ground-travel noise of variance k²|d| per
integration step, ``floor_bumps`` as a Poisson process per wheel (rate per metre of the wheel's
travel), each bump removing ``heading_jump`` × true wheelbase of that wheel's ground travel
spread over :data:`BUMP_SPREAD` of its travel, and ``gt_sensor_offset`` moving the logged point.

Everything random is drawn from the ``rng`` passed to :func:`generate`; each run draws three
child seeds from it (motion, process noise, sensor noise), so switching an effect on or off does
not change the other random streams of the same seed.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.odometry.runs import Run

__all__ = [
    "BUMP_SPREAD",
    "EFFECT_PARAMETERS",
    "IndependentRobot",
    "Manoeuvre",
    "SCurve",
    "TurnDirection",
    "generate",
    "logged_run",
    "play_operator",
    "rich_protocol",
    "run_streams",
    "s_curve",
    "time_grid",
]

FloatArray = NDArray[np.float64]
TurnDirection = Literal["cw", "ccw"]
ManoeuvreKind = Literal["square", "straight", "spin", "arc"]

EFFECT_PARAMETERS: dict[str, dict[str, float]] = {
    "wheel_diameter_ratio": {"e_d": 1.0},
    "distance_scale": {"e_s": 1.0},
    "wheelbase": {"e_b": 1.0},
    "backlash": {"angle": 0.0},
    "turn_skid": {"gain": 0.0},
    "skid_speed": {"gain": 0.0},
    "skid_track": {"excess": 0.0, "lambda_half": 2.0},
    "wheel_toe": {"angle": 0.0},
    "gt_sensor_offset": {"dx": 0.0, "dy": 0.0},
    "floor_roughness": {"k_left": 0.0, "k_right": 0.0},
    "floor_bumps": {"rate": 0.0, "heading_jump": 0.0},
}
"""Every effect of ``docs/effects.md``: its parameters and their "absent" values."""

_POSITIVE = {
    ("wheel_diameter_ratio", "e_d"),
    ("distance_scale", "e_s"),
    ("wheelbase", "e_b"),
    ("skid_track", "lambda_half"),
}
_NON_NEGATIVE = {
    ("backlash", "angle"),
    ("turn_skid", "gain"),
    ("skid_speed", "gain"),
    ("skid_track", "excess"),
    ("floor_roughness", "k_left"),
    ("floor_roughness", "k_right"),
    ("floor_bumps", "rate"),
}

BUMP_SPREAD = 0.05
"""Wheel travel over which one bump's loss of ground travel is spread [m]."""

_DWELL = (0.3, 0.7)  # random stop between moves [s]
_START_BOX = 2.0  # start position uniform in [-_START_BOX, _START_BOX]² [m]
_TIME_DECIMALS = 9  # the time grid is rounded to 1 ns so coincident instants merge


@dataclass(frozen=True)
class IndependentRobot:
    """A differential-drive robot, its effects and its ground-truth sensor.

    Attributes:
        wheel_diameter: nominal wheel diameter D_n [m] (what the controller and odometry assume).
        wheelbase: nominal wheelbase b_n [m].
        ticks_per_rev: encoder counts per *wheel* revolution, counted on the motor side.
        effects: ``{effect name: {parameter: value}}`` with the names of ``docs/effects.md``;
            a missing parameter takes its "absent" value.
        sensor_position_std: ground-truth sensor noise per axis [m].
        sensor_heading_std: ground-truth sensor heading noise [rad].
    """

    wheel_diameter: float = 0.084
    wheelbase: float = 0.200
    ticks_per_rev: float = 2796.8
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    sensor_position_std: float = 0.001
    sensor_heading_std: float = 0.002

    def __post_init__(self) -> None:
        for name, value in (
            ("wheel_diameter", self.wheel_diameter),
            ("wheelbase", self.wheelbase),
            ("ticks_per_rev", self.ticks_per_rev),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be positive and finite, got {value}")
        for name, value in (
            ("sensor_position_std", self.sensor_position_std),
            ("sensor_heading_std", self.sensor_heading_std),
        ):
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be non-negative and finite, got {value}")
        for effect, params in self.effects.items():
            if effect not in EFFECT_PARAMETERS:
                raise ValueError(
                    f"unknown effect {effect!r}; known: {', '.join(sorted(EFFECT_PARAMETERS))}"
                )
            for param, value in params.items():
                if param not in EFFECT_PARAMETERS[effect]:
                    raise ValueError(
                        f"unknown parameter {param!r} of effect {effect!r}; "
                        f"known: {', '.join(EFFECT_PARAMETERS[effect])}"
                    )
                v = float(value)
                if not math.isfinite(v):
                    raise ValueError(f"{effect}.{param} must be finite, got {value}")
                if (effect, param) in _POSITIVE and v <= 0.0:
                    raise ValueError(f"{effect}.{param} must be positive, got {value}")
                if (effect, param) in _NON_NEGATIVE and v < 0.0:
                    raise ValueError(f"{effect}.{param} must be non-negative, got {value}")

    def param(self, effect: str, name: str) -> float:
        """The value of one effect parameter, or its absent value."""
        default = EFFECT_PARAMETERS[effect][name]
        return float(self.effects.get(effect, {}).get(name, default))

    @property
    def mean_diameter(self) -> float:
        """True mean diameter D̄ = E_s·D_n [m]."""
        return self.param("distance_scale", "e_s") * self.wheel_diameter

    @property
    def left_diameter(self) -> float:
        """True left diameter D_L = 2·D̄/(E_d + 1) [m]."""
        return 2.0 * self.mean_diameter / (self.param("wheel_diameter_ratio", "e_d") + 1.0)

    @property
    def right_diameter(self) -> float:
        """True right diameter D_R = 2·D̄/(1/E_d + 1) [m]."""
        return 2.0 * self.mean_diameter / (1.0 / self.param("wheel_diameter_ratio", "e_d") + 1.0)

    @property
    def true_wheelbase(self) -> float:
        """True wheelbase b = E_b·b_n [m]."""
        return self.param("wheelbase", "e_b") * self.wheelbase

    @property
    def metres_per_tick(self) -> float:
        """Nominal rim travel per encoder count [m]."""
        return math.pi * self.wheel_diameter / self.ticks_per_rev


@dataclass(frozen=True)
class Manoeuvre:
    """One run of a characterisation protocol.

    Attributes:
        kind: ``"square"`` (four sides, each followed by a 90° in-place turn),
            ``"straight"`` (optionally out, 180° in-place turn, back), ``"spin"`` (in-place
            turn) or ``"arc"`` (constant-curvature arc; logged as kind ``"free"``).
        direction: turning sense ``"cw"``/``"ccw"``; required for squares, spins and arcs; for
            a straight with ``return_trip`` the sense of the 180° turn (``"ccw"`` if ``None``).
        size: square side, straight length or arc radius [m] (unused for spins).
        angle: spin angle or arc sweep [rad] (unused for squares and straights).
        speed: peak speed [m/s]: of the axle midpoint for straights, square sides and arcs; of
            the wheel rims for spins.
        turn_speed: peak wheel-rim speed of the in-place turns inside squares and return trips
            [m/s].
        accel: peak acceleration of the profiled speed [m/s²] (sets the S-curve ramp time).
        return_trip: straights only: drive out, turn 180° in place, drive back.
        label: the experiment label (``meta["experiment"]``); generated if empty.
    """

    kind: ManoeuvreKind
    direction: TurnDirection | None = None
    size: float = 0.0
    angle: float = 0.0
    speed: float = 0.3
    turn_speed: float = 0.1
    accel: float = 0.5
    return_trip: bool = False
    label: str = ""

    def __post_init__(self) -> None:
        if self.kind not in ("square", "straight", "spin", "arc"):
            raise ValueError(f"unknown manoeuvre kind {self.kind!r}")
        if self.direction not in (None, "cw", "ccw"):
            raise ValueError(f"direction must be 'cw', 'ccw' or None, got {self.direction!r}")
        if self.kind in ("square", "spin", "arc") and self.direction is None:
            raise ValueError(f"a {self.kind} needs a direction ('cw' or 'ccw')")
        if self.kind in ("square", "straight", "arc") and not self.size > 0.0:
            raise ValueError(f"a {self.kind} needs a positive size, got {self.size}")
        if self.kind in ("spin", "arc") and not self.angle > 0.0:
            raise ValueError(f"a {self.kind} needs a positive angle, got {self.angle}")
        for name, value in (
            ("speed", self.speed),
            ("turn_speed", self.turn_speed),
            ("accel", self.accel),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be positive and finite, got {value}")
        if self.return_trip and self.kind != "straight":
            raise ValueError("return_trip applies to straights only")

    @property
    def experiment(self) -> str:
        """The experiment label: :attr:`label`, or one made from the manoeuvre."""
        if self.label:
            return self.label
        if self.kind == "straight":
            return "straight_return" if self.return_trip else "straight_oneway"
        if self.kind == "spin":
            return f"spin_{self.direction}_{round(math.degrees(self.angle))}"
        return f"{self.kind}_{self.direction}"


@dataclass(frozen=True)
class SCurve:
    """A rest-to-rest move with raised-cosine acceleration ramps.

    The speed rises as V·sin²(πt/(2T_r)) over the ramp time T_r, cruises at V for T_c and
    falls symmetrically; acceleration is continuous (zero at both ends of each ramp) and peaks at
    πV/(2T_r). Each ramp covers V·T_r/2, so ``distance`` = V·(T_r + T_c).
    """

    distance: float
    peak: float
    ramp: float
    cruise: float

    @property
    def duration(self) -> float:
        """Total time of the move [s]."""
        return 2.0 * self.ramp + self.cruise

    def _ramp_position(self, u: FloatArray) -> FloatArray:
        out: FloatArray = self.peak * (
            0.5 * u - self.ramp / (2.0 * math.pi) * np.sin(math.pi * u / self.ramp)
        )
        return out

    def position(self, t: FloatArray) -> FloatArray:
        """Distance covered at times ``t`` from the start of the move (clipped to the move)."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        up = self.ramp
        down = self.ramp + self.cruise
        out: FloatArray = np.where(
            t < up,
            self._ramp_position(np.minimum(t, up)),
            np.where(
                t <= down,
                0.5 * self.peak * self.ramp + self.peak * (t - up),
                self.distance - self._ramp_position(np.clip(self.duration - t, 0.0, up)),
            ),
        )
        return np.clip(out, 0.0, self.distance)

    def speed(self, t: FloatArray) -> FloatArray:
        """Speed at times ``t`` from the start of the move (zero outside it)."""
        t = np.asarray(t, dtype=float)
        rise = self.peak * np.sin(0.5 * math.pi * np.clip(t, 0.0, self.ramp) / self.ramp) ** 2
        fall_t = np.clip(self.duration - t, 0.0, self.ramp)
        fall = self.peak * np.sin(0.5 * math.pi * fall_t / self.ramp) ** 2
        out: FloatArray = np.where(
            t < self.ramp, rise, np.where(t <= self.ramp + self.cruise, self.peak, fall)
        )
        return np.where((t < 0.0) | (t > self.duration), 0.0, out)


def s_curve(distance: float, peak_speed: float, accel: float) -> SCurve:
    """The S-curve for ``distance`` at ``peak_speed`` with peak acceleration ``accel``.

    Ramp time T_r = πV/(2a); a move too short to reach V ramps only, at the lower peak
    V = √(2a·distance/π).
    """
    if not distance > 0.0:
        raise ValueError(f"a move needs a positive distance, got {distance}")
    peak = peak_speed
    ramp = math.pi * peak / (2.0 * accel)
    if distance < peak * ramp:
        peak = math.sqrt(2.0 * accel * distance / math.pi)
        ramp = math.pi * peak / (2.0 * accel)
    cruise = max(0.0, distance / peak - ramp)
    return SCurve(distance=distance, peak=peak, ramp=ramp, cruise=cruise)


@dataclass(frozen=True)
class _Segment:
    """A move of both motor angles (or a stop, ``profile is None``) on the run's timeline."""

    start: float
    duration: float
    motor_start: tuple[float, float]  # wheel-equivalent motor angles [rad], left/right
    motor_delta: tuple[float, float]
    profile: SCurve | None


def _moves(m: Manoeuvre, robot: IndependentRobot) -> list[tuple[float, float, SCurve]]:
    """The open-loop moves of a manoeuvre: (Δφ_m,L, Δφ_m,R, profile), planned nominally."""
    r_n = 0.5 * robot.wheel_diameter
    half_b = 0.5 * robot.wheelbase

    def straight(length: float) -> tuple[float, float, SCurve]:
        return (length / r_n, length / r_n, s_curve(length, m.speed, m.accel))

    def turn(angle: float, sense: TurnDirection, rim_speed: float) -> tuple[float, float, SCurve]:
        sign = 1.0 if sense == "ccw" else -1.0
        rim = angle * half_b
        return (-sign * rim / r_n, sign * rim / r_n, s_curve(rim, rim_speed, m.accel))

    if m.kind == "straight":
        out = [straight(m.size)]
        if m.return_trip:
            out.append(turn(math.pi, m.direction or "ccw", m.turn_speed))
            out.append(straight(m.size))
        return out
    assert m.direction is not None
    if m.kind == "square":
        out = []
        for _ in range(4):
            out.append(straight(m.size))
            out.append(turn(0.5 * math.pi, m.direction, m.turn_speed))
        return out
    if m.kind == "spin":
        return [turn(m.angle, m.direction, m.speed)]
    sign = 1.0 if m.direction == "ccw" else -1.0
    left = (m.size - sign * half_b) * m.angle
    right = (m.size + sign * half_b) * m.angle
    return [(left / r_n, right / r_n, s_curve(m.size * m.angle, m.speed, m.accel))]


def _timeline(m: Manoeuvre, robot: IndependentRobot, rng: np.random.Generator) -> list[_Segment]:
    """Moves separated by random stops, with a stop at the start and at the end."""
    segments: list[_Segment] = []
    t = 0.0
    angles = (0.0, 0.0)

    def stop() -> None:
        nonlocal t
        duration = float(rng.uniform(*_DWELL))
        segments.append(_Segment(t, duration, angles, (0.0, 0.0), None))
        t += duration

    stop()
    for d_left, d_right, profile in _moves(m, robot):
        segments.append(_Segment(t, profile.duration, angles, (d_left, d_right), profile))
        t += profile.duration
        angles = (angles[0] + d_left, angles[1] + d_right)
        stop()
    return segments


def _motor_angles(segments: Sequence[_Segment], t: FloatArray) -> FloatArray:
    """Wheel-equivalent motor angles (N, 2) at times ``t`` (continuous, piecewise monotone)."""
    starts = np.array([s.start for s in segments])
    which = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(segments) - 1)
    out = np.empty((len(t), 2))
    for i, seg in enumerate(segments):
        sel = which == i
        if not np.any(sel):
            continue
        if seg.profile is None:
            frac = np.zeros(int(np.count_nonzero(sel)))
        else:
            frac = seg.profile.position(t[sel] - seg.start) / seg.profile.distance
        for w in range(2):
            out[sel, w] = seg.motor_start[w] + seg.motor_delta[w] * frac
    return out


def play_operator(motor: FloatArray, width: float, start: float) -> FloatArray:
    """Wheel angle behind a play of ``width`` driven by the sampled motor angle ``motor``.

    φ_w ← min(φ_m + β/2, max(φ_m − β/2, φ_w)), exact when the motor angle is monotone between
    samples (within a monotone stretch the output is a running max/min, computed vectorised).
    """
    out = np.empty_like(motor)
    out[0] = start
    if len(motor) == 1:
        return out
    half = 0.5 * width
    sign = np.sign(np.diff(motor))
    moving = np.flatnonzero(sign)
    if len(moving) == 0:
        out[:] = start
        return out
    flips = moving[1:][sign[moving[1:]] != sign[moving[:-1]]]
    bounds = [0, *flips.tolist(), len(motor) - 1]
    current = start
    for a, b in itertools.pairwise(bounds):
        piece = motor[a : b + 1]
        direction = sign[moving[moving >= a][0]] if np.any(moving >= a) else 0.0
        if direction > 0:
            values = np.maximum(current, piece - half)
        elif direction < 0:
            values = np.minimum(current, piece + half)
        else:
            values = np.full_like(piece, current)
        out[a : b + 1] = values
        current = float(values[-1])
    return out


def _bump_loss(rim: FloatArray, rate: float, loss: float, rng: np.random.Generator) -> FloatArray:
    """Ground travel lost to bumps in each step (N,) [m], ≥ 0.

    Bumps sit at Poisson positions (``rate`` per metre) along the wheel's cumulative travel
    |rim|; each removes ``loss`` of ground travel uniformly over the next BUMP_SPREAD of travel.
    """
    travelled = np.concatenate([[0.0], np.cumsum(np.abs(rim))])
    total = float(travelled[-1])
    positions: list[float] = []
    at = 0.0
    while True:
        at += float(rng.exponential(1.0 / rate))
        if at >= total:
            break
        positions.append(at)
    cumulative = np.zeros_like(travelled)
    for p in positions:
        cumulative += loss * np.clip((travelled - p) / BUMP_SPREAD, 0.0, 1.0)
    lost: FloatArray = np.minimum(np.diff(cumulative), np.abs(rim))
    return lost


def _simulate_run(
    m: Manoeuvre,
    robot: IndependentRobot,
    rng: np.random.Generator,
    *,
    index: int,
    log_rate_hz: float,
    integration_hz: float,
    endpoints_only: bool,
) -> Run:
    motion_rng, process_rng, sensor_rng, start_pose, encoder_phase = run_streams(rng)
    segments = _timeline(m, robot, motion_rng)
    log_times, grid, log_index = time_grid(segments, log_rate_hz, integration_hz)
    n_log = len(log_times)

    # Motors, transmission, wheels.
    motor = _motor_angles(segments, grid)
    beta = robot.param("backlash", "angle")
    diameters = (robot.left_diameter, robot.right_diameter)
    k_wheel = (robot.param("floor_roughness", "k_left"), robot.param("floor_roughness", "k_right"))
    bump_rate = robot.param("floor_bumps", "rate")
    bump_loss = robot.param("floor_bumps", "heading_jump") * robot.true_wheelbase
    ground = np.empty((len(grid) - 1, 2))
    for w in range(2):
        wheel = (
            play_operator(motor[:, w], beta, motor[0, w] - 0.5 * beta)
            if beta > 0.0
            else motor[:, w]
        )
        rim = np.diff(wheel) * (0.5 * diameters[w])
        travel = rim.copy()
        if k_wheel[w] > 0.0:
            travel += k_wheel[w] * np.sqrt(np.abs(rim)) * process_rng.standard_normal(len(rim))
        if bump_rate > 0.0 and bump_loss != 0.0:
            travel -= np.sign(rim) * _bump_loss(rim, bump_rate, bump_loss, process_rng)
        ground[:, w] = travel

    # Body: exact constant-curvature steps.
    dt = np.diff(grid)
    ds = 0.5 * (ground[:, 0] + ground[:, 1])
    dtheta0 = (ground[:, 1] - ground[:, 0]) / robot.true_wheelbase
    gain = robot.param("turn_skid", "gain")
    relief = robot.param("skid_speed", "gain")
    lateral = np.abs((ds / dt) * (dtheta0 / dt))  # |v·ω₀| [m/s²] of each step
    dtheta = dtheta0
    if gain > 0.0:
        dtheta = dtheta * np.maximum(0.0, 1.0 - gain * lateral)
    if relief > 0.0:
        dtheta = dtheta * (1.0 + relief * lateral)
    excess = robot.param("skid_track", "excess")
    if excess > 0.0:
        # The apparent track E_b·(1 + ε/(1 + (λ/λ½)²)) at this step's path-curvature ratio
        # λ = (d_L + d_R)/(d_R − d_L) of the ground travels, written as ε·Δ²λ½²/(Δ²λ½² + Σ²)
        # so that a straight step (Δ = 0) gets no excess without dividing by zero.
        diff2 = ((ground[:, 1] - ground[:, 0]) * robot.param("skid_track", "lambda_half")) ** 2
        sum2 = (ground[:, 1] + ground[:, 0]) ** 2
        denominator = diff2 + sum2
        share = np.divide(diff2, denominator, out=np.zeros_like(diff2), where=denominator > 0.0)
        dtheta = dtheta / (1.0 + excess * share)
    toe = robot.param("wheel_toe", "angle")
    theta = start_pose[2] + np.concatenate([[0.0], np.cumsum(dtheta)])
    chord = ds * np.sinc(dtheta / (2.0 * math.pi))  # |chord| of an arc of length ds, angle dθ
    direction = theta[:-1] + 0.5 * dtheta + toe
    x = start_pose[0] + np.concatenate([[0.0], np.cumsum(chord * np.cos(direction))])
    y = start_pose[1] + np.concatenate([[0.0], np.cumsum(chord * np.sin(direction))])

    # Measurement: the tracked point, with sensor noise, at the log times.
    dx, dy = robot.param("gt_sensor_offset", "dx"), robot.param("gt_sensor_offset", "dy")
    th = theta[log_index]
    c, s = np.cos(th), np.sin(th)
    pose = np.stack([x[log_index] + c * dx - s * dy, y[log_index] + s * dx + c * dy, th], axis=1)
    pose[:, :2] += robot.sensor_position_std * sensor_rng.standard_normal((n_log, 2))
    pose[:, 2] += robot.sensor_heading_std * sensor_rng.standard_normal(n_log)
    if endpoints_only and n_log > 2:
        pose[1:-1] = np.nan
    return logged_run(
        m,
        index,
        "independent",
        log_times,
        pose,
        motor[log_index],
        encoder_phase,
        robot.ticks_per_rev,
    )


def run_streams(
    rng: np.random.Generator,
) -> tuple[np.random.Generator, np.random.Generator, np.random.Generator, FloatArray, FloatArray]:
    """A run's three child streams drawn from ``rng`` (motion, process noise, sensor noise: an
    effect switched on or off moves none of the others), and from the motion stream the start
    pose (x, y [m] uniform in the start box, θ [rad]) and the encoders' fractional counts at
    the start."""
    seeds = rng.integers(0, 2**63 - 1, size=3)
    motion_rng, process_rng, sensor_rng = (np.random.default_rng(int(s)) for s in seeds)
    start_pose = np.array(
        [
            motion_rng.uniform(-_START_BOX, _START_BOX),
            motion_rng.uniform(-_START_BOX, _START_BOX),
            motion_rng.uniform(-math.pi, math.pi),
        ]
    )
    encoder_phase = motion_rng.uniform(0.0, 1.0, size=2)
    return motion_rng, process_rng, sensor_rng, start_pose, encoder_phase


def time_grid(
    segments: Sequence[_Segment], log_rate_hz: float, integration_hz: float
) -> tuple[FloatArray, FloatArray, NDArray[np.intp]]:
    """The log times (cover the whole run; the last is during/after the final stop), the
    integration grid (every 1/``integration_hz``, every log time and every move boundary) and
    each log time's index in it."""
    end = segments[-1].start + segments[-1].duration
    n_log = math.ceil(end * log_rate_hz - 1e-9) + 1
    log_times = np.round(np.arange(n_log) / log_rate_hz, _TIME_DECIMALS)
    t_end = float(log_times[-1])
    n_int = math.ceil(t_end * integration_hz - 1e-9)
    grid = np.concatenate(
        [
            np.arange(n_int + 1) / integration_hz,
            log_times,
            [s.start for s in segments if s.start <= t_end],
        ]
    )
    grid = np.unique(np.round(np.clip(grid, 0.0, t_end), _TIME_DECIMALS))
    return log_times, grid, np.searchsorted(grid, log_times)


def logged_run(
    m: Manoeuvre,
    index: int,
    source: str,
    log_times: FloatArray,
    pose: FloatArray,
    motor: FloatArray,
    encoder_phase: FloatArray,
    ticks_per_rev: float,
) -> Run:
    """The run a logger writes: the measured ``pose`` (n, 3) at ``log_times`` and the encoder
    counts of the wheel-equivalent ``motor`` angles (n, 2) [rad], quantised with ``floor``
    from the random ``encoder_phase`` (fractional counts at the start)."""
    ticks = motor * (ticks_per_rev / (2.0 * math.pi)) + encoder_phase
    counts = (np.floor(ticks) - np.floor(encoder_phase)).astype(np.int64)
    return Run(
        kind="free" if m.kind == "arc" else m.kind,
        time=log_times.astype(float),
        counts=counts,
        true_pose=pose,
        direction=m.direction if m.kind in ("square", "spin") else None,
        side=m.size if m.kind in ("square", "straight") else 0.0,
        source=source,
        meta={"run": f"{index:03d}", "experiment": m.experiment},
    )


def generate(
    robot: IndependentRobot,
    protocol: Sequence[Manoeuvre],
    rng: np.random.Generator,
    *,
    log_rate_hz: float = 10.0,
    integration_hz: float = 500.0,
    endpoints_only: bool = False,
) -> list[Run]:
    """Drive ``robot`` through ``protocol`` and return the measured logs, one run per manoeuvre.

    Args:
        robot: the robot, its effects and its ground-truth sensor noise.
        protocol: the manoeuvres, in order.
        rng: the only source of randomness (start poses, encoder phases, stop durations,
            floor noise, sensor noise); the same seed gives identical runs.
        log_rate_hz: rate of the logged rows (time from 0).
        integration_hz: rate of the integration grid (log times and move boundaries are added).
        endpoints_only: keep the ground truth of the first and last rows only (others NaN), as
            in UMBmark-style logs; the counts are logged on every row.
    """
    if not (math.isfinite(log_rate_hz) and log_rate_hz > 0.0):
        raise ValueError(f"log_rate_hz must be positive, got {log_rate_hz}")
    if not (math.isfinite(integration_hz) and integration_hz > 0.0):
        raise ValueError(f"integration_hz must be positive, got {integration_hz}")
    return [
        _simulate_run(
            m,
            robot,
            rng,
            index=i,
            log_rate_hz=log_rate_hz,
            integration_hz=integration_hz,
            endpoints_only=endpoints_only,
        )
        for i, m in enumerate(protocol)
    ]


def rich_protocol() -> list[Manoeuvre]:
    """A characterisation protocol of 24 runs for a small robot (b ≈ 0.2 m).

    * squares, 2 m side at 0.3 m/s (corners at 0.1 m/s rim speed), 2 cw + 2 ccw
      (``square_cw``, ``square_ccw``);
    * 3 m straights at 0.3 m/s: 2 out and back (180° turn ccw, then cw;
      ``straight_return``) and 2 one-way (``straight_oneway``);
    * in-place turns of 90°, 180°, 360°, both ways, at 0.1 and 0.3 m/s rim speed
      (``spin_ccw_90_slow`` … ``spin_cw_360_fast``);
    * arcs of radius 1 m through 180°, both ways, at 0.15 and 0.4 m/s
      (``arc_ccw_slow`` … ``arc_cw_fast``).
    """
    protocol: list[Manoeuvre] = []
    senses: tuple[TurnDirection, TurnDirection] = ("cw", "ccw")
    for sense in senses:
        protocol += [Manoeuvre("square", sense, size=2.0, speed=0.3, label=f"square_{sense}")] * 2
    for sense in senses[::-1]:
        protocol.append(
            Manoeuvre(
                "straight", sense, size=3.0, speed=0.3, return_trip=True, label="straight_return"
            )
        )
    protocol += [Manoeuvre("straight", size=3.0, speed=0.3, label="straight_oneway")] * 2
    for pace, rim_speed in (("slow", 0.1), ("fast", 0.3)):
        for degrees in (90, 180, 360):
            for sense in senses:
                protocol.append(
                    Manoeuvre(
                        "spin",
                        sense,
                        angle=math.radians(degrees),
                        speed=rim_speed,
                        label=f"spin_{sense}_{degrees}_{pace}",
                    )
                )
    for pace, speed in (("slow", 0.15), ("fast", 0.4)):
        for sense in senses:
            protocol.append(
                Manoeuvre(
                    "arc", sense, size=1.0, angle=math.pi, speed=speed, label=f"arc_{sense}_{pace}"
                )
            )
    return protocol

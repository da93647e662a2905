"""A third source of measured logs: a robot whose effects nobody wrote into odomgym.

``tests/independent_robot.py`` checks that ``diagnose`` does not rely on odomgym's integrator; its
effects still follow the catalogue's own formulas. This generator checks what a user meets: a
robot whose mechanisms have **other functional forms** than the catalogue's, and mechanisms
**outside the catalogue**. It shares the motion planning of the independent generator (S-curve
moves, random stops, open-loop motor angles: that is the robot's controller, not its physics)
and nothing of the World, the replay or the catalogue's forms.

Catalogue effects in another form (the name the report should give, and how it differs):

=========================  =================================================================
``wheel_diameter_ratio``   only the right wheel is off: D_R = D(1 + ε), D_L = D (per wheel,
                           not E_d with the mean kept)
``wheelbase``              one tyre worn on its outer edge: the left contact sits ε·b further
                           out, the right one at −b/2 (wheelbase b(1 + ε), rotation centre off
                           the axle midpoint)
``distance_scale``         per-wheel, unequal: r_L(1 + ε), r_R(1 + 0.8ε)
``wheel_toe``              crab that saturates with speed: τ·tanh(|v|/0.05 m/s)
``turn_skid``              saturating: dθ = dθ₀/(1 + κ|v·ω₀|)
``backlash``               on the left gearbox only
``floor_bumps``            heading jumps of exponentially distributed size (mean a)
``floor_roughness``        time-correlated slip (AR(1) per wheel, 0.2 s) of variance k²|d|
=========================  =================================================================

Effects outside the catalogue (the grammar term that should be discovered):

=======================  ========================================  =======================
``speed_shrink``         r_w = r(1 − c|v_w|), both wheels          ``left|right_speed``
``out_of_round``         r_R(φ) = r(1 + a·sin(φ + φ₀))             ``right_sin1|cos1``
``sideslip``             crab = c·v·ω                              ``crab_lateral_signed``
``ratio_drift``          D_R/D_L = 1 + c·t (session time)          ``left|right_time``
``traction_slip``        ground = rim·(1 − c·d|v_w|/dt)            ``left|right_accel``
``spin_scrub``           dθ = dθ₀(1 − c|ω₀|)                       ``yaw_rate``
``reverse_scale``        left travel × (1 + c) when reversing      ``left_direction``
``three_lobes``          r_L(φ) = r(1 + a·sin 3φ)                  none: the grammar stops
                                                                   at twice per revolution
=======================  ========================================  =======================

Runs carry ``meta["session_time"]`` (their start since the session began; runs follow one
another with 20 s between them) and ``meta["wheel_angle0"]`` (each wheel's angle at the run's
start since the session began, as cumulative encoders give).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from independent_robot import (
    _TIME_DECIMALS,
    IndependentRobot,
    Manoeuvre,
    _motor_angles,
    _timeline,
    play_operator,
    rich_protocol,
    run_streams,
)
from numpy.typing import NDArray

from odomgym.odometry.runs import Run

__all__ = ["ALIEN_EFFECTS", "EXPECTED_TERMS", "draw_effect", "generate_session"]

FloatArray = NDArray[np.float64]

ALIEN_EFFECTS: dict[str, tuple[float, float]] = {
    # catalogue effects in other forms: magnitude range of their parameter
    "wheel_diameter_ratio": (0.004, 0.012),  # ε of the right wheel
    "wheelbase": (0.006, 0.02),  # ε
    "distance_scale": (0.005, 0.015),  # ε
    "wheel_toe": (0.004, 0.012),  # τ [rad]
    "turn_skid": (0.3, 1.0),  # κ [s²/m]
    "backlash": (0.01, 0.03),  # play of the left gearbox [rad]
    "floor_bumps": (0.01, 0.03),  # mean heading jump a [rad], 0.5 bumps/m
    "floor_roughness": (0.002, 0.005),  # k [m^½]
    # outside the catalogue
    "speed_shrink": (0.03, 0.08),  # c [1/(m/s)]
    "out_of_round": (0.006, 0.015),  # a
    "sideslip": (0.03, 0.08),  # c [rad/(m/s²)]
    "ratio_drift": (4e-6, 1e-5),  # c [1/s]
    "traction_slip": (0.15, 0.3),  # c [s²/m]
    "spin_scrub": (0.008, 0.02),  # c [s/rad]
    "reverse_scale": (0.008, 0.02),  # c
    # outside the catalogue *and* the grammar (three lobes per revolution): no term can name it
    "three_lobes": (0.006, 0.015),  # a
}
"""Every effect of this generator and the range its magnitude is drawn from."""

EXPECTED_TERMS: dict[str, tuple[str, ...]] = {
    "speed_shrink": ("left_speed", "right_speed"),
    "out_of_round": ("right_sin1", "right_cos1"),
    "sideslip": ("crab_lateral_signed",),
    "ratio_drift": ("left_time", "right_time"),
    "traction_slip": ("left_accel", "right_accel"),
    "spin_scrub": ("yaw_rate",),
    "reverse_scale": ("left_direction",),
}
"""For each out-of-catalogue effect, the grammar terms that describe it (any one is right)."""

_GAP = 20.0  # time between two runs of a session [s]
_SIGNED = {"wheel_diameter_ratio", "wheelbase", "distance_scale", "wheel_toe", "speed_shrink"}
_SIGNED |= {"sideslip", "ratio_drift", "reverse_scale"}


def draw_effect(name: str, rng: np.random.Generator) -> dict[str, float]:
    """A magnitude from :data:`ALIEN_EFFECTS` (random sign where the effect has one), and a
    phase for the out-of-round wheel."""
    low, high = ALIEN_EFFECTS[name]
    value = float(rng.uniform(low, high))
    if name in _SIGNED and rng.random() < 0.5:
        value = -value
    out = {"value": value}
    if name == "out_of_round":
        out["phase"] = float(rng.uniform(0.0, 2.0 * math.pi))
    return out


def _ar1(n: int, dt: FloatArray, tau: float, rng: np.random.Generator) -> FloatArray:
    """AR(1) samples with correlation time ``tau`` on steps ``dt``, scaled so that their sum
    over many steps has the variance of as many independent unit draws: the slip is correlated
    over ``tau`` but k keeps its meaning on long runs (variance k²|d|, Chong & Kleeman 1997)."""
    out = np.empty(n)
    x = float(rng.standard_normal())
    for i in range(n):
        rho = math.exp(-float(dt[i]) / tau)
        x = rho * x + math.sqrt(1.0 - rho * rho) * float(rng.standard_normal())
        out[i] = x * math.sqrt((1.0 - rho) / (1.0 + rho))
    return out


def _simulate(
    m: Manoeuvre,
    base: IndependentRobot,
    effects: Mapping[str, Mapping[str, float]],
    rng: np.random.Generator,
    *,
    index: int,
    session_time: float,
    wheel_angle0: FloatArray,
    log_rate_hz: float,
    integration_hz: float,
) -> tuple[Run, float, FloatArray]:
    motion_rng, process_rng, sensor_rng, start_pose, encoder_phase = run_streams(rng)
    segments = _timeline(m, base, motion_rng)
    end = segments[-1].start + segments[-1].duration
    n_log = math.ceil(end * log_rate_hz - 1e-9) + 1
    log_times = np.round(np.arange(n_log) / log_rate_hz, _TIME_DECIMALS)
    t_end = float(log_times[-1])
    n_int = math.ceil(t_end * integration_hz - 1e-9)
    grid = np.concatenate([np.arange(n_int + 1) / integration_hz, log_times])
    grid = np.unique(np.round(np.clip(grid, 0.0, t_end), _TIME_DECIMALS))
    log_index = np.searchsorted(grid, log_times)
    dt = np.diff(grid)
    t_mid = session_time + 0.5 * (grid[1:] + grid[:-1])

    def value(name: str) -> float:
        return float(effects[name]["value"]) if name in effects else 0.0

    motor = _motor_angles(segments, grid)  # wheel-equivalent motor angles since the run start
    wheel = motor.copy()
    if "backlash" in effects:
        beta = value("backlash")
        wheel[:, 0] = play_operator(motor[:, 0], beta, motor[0, 0] - 0.5 * beta)
    step = np.diff(wheel, axis=0)  # (n, 2) [rad]
    angle = wheel_angle0 + 0.5 * (wheel[1:] + wheel[:-1])  # since the session start
    r = 0.5 * base.wheel_diameter
    radius = np.full_like(step, r)
    if "wheel_diameter_ratio" in effects:
        radius[:, 1] *= 1.0 + value("wheel_diameter_ratio")
    if "distance_scale" in effects:
        e = value("distance_scale")
        radius[:, 0] *= 1.0 + e
        radius[:, 1] *= 1.0 + 0.8 * e
    rim_speed = step * r / dt[:, None]
    if "speed_shrink" in effects:
        radius *= 1.0 - value("speed_shrink") * np.abs(rim_speed)
    if "out_of_round" in effects:
        radius[:, 1] *= 1.0 + value("out_of_round") * np.sin(
            angle[:, 1] + effects["out_of_round"]["phase"]
        )
    if "three_lobes" in effects:
        radius[:, 0] *= 1.0 + value("three_lobes") * np.sin(3.0 * angle[:, 0])
    if "ratio_drift" in effects:
        radius[:, 1] *= 1.0 + value("ratio_drift") * t_mid
    ground = step * radius
    if "traction_slip" in effects:
        speed = np.abs(ground / dt[:, None])
        accel = np.gradient(speed, np.cumsum(dt), axis=0)
        ground *= 1.0 - value("traction_slip") * accel
    if "reverse_scale" in effects:
        ground[:, 0] = np.where(
            ground[:, 0] < 0, ground[:, 0] * (1 + value("reverse_scale")), ground[:, 0]
        )
    if "floor_roughness" in effects:
        k = value("floor_roughness")
        for w in range(2):
            ground[:, w] += k * np.sqrt(np.abs(ground[:, w])) * _ar1(len(dt), dt, 0.2, process_rng)
    left_arm, right_arm = 0.5 * base.wheelbase, 0.5 * base.wheelbase
    if "wheelbase" in effects:
        left_arm += value("wheelbase") * base.wheelbase
    if "floor_bumps" in effects:
        mean_jump = value("floor_bumps")
        for w in range(2):
            travelled = np.cumsum(np.abs(ground[:, w]))
            at = 0.0
            while True:
                at += float(process_rng.exponential(1.0 / 0.5))
                if at >= travelled[-1]:
                    break
                k = int(np.searchsorted(travelled, at))
                loss = float(process_rng.exponential(mean_jump)) * base.wheelbase
                ground[k, w] -= math.copysign(loss, ground[k, w])
    # Body motion about the axle midpoint with contacts at +left_arm and −right_arm.
    width = left_arm + right_arm
    dtheta0 = (ground[:, 1] - ground[:, 0]) / width
    # the midpoint of the nominal axle moves with the contact-weighted mean travel
    ds = (right_arm * ground[:, 0] + left_arm * ground[:, 1]) / width
    lateral = np.abs((ds / dt) * (dtheta0 / dt))
    dtheta = dtheta0
    if "turn_skid" in effects:
        dtheta = dtheta0 / (1.0 + value("turn_skid") * lateral)
    if "spin_scrub" in effects:
        dtheta = dtheta * (1.0 - value("spin_scrub") * np.abs(dtheta0 / dt))
    crab = np.zeros_like(ds)
    if "wheel_toe" in effects:
        crab += value("wheel_toe") * np.tanh(np.abs(ds / dt) / 0.05)
    if "sideslip" in effects:
        crab += value("sideslip") * (ds / dt) * (dtheta0 / dt)
    theta = start_pose[2] + np.concatenate([[0.0], np.cumsum(dtheta)])
    chord = ds * np.sinc(dtheta / (2.0 * math.pi))
    direction = theta[:-1] + 0.5 * dtheta + crab
    x = start_pose[0] + np.concatenate([[0.0], np.cumsum(chord * np.cos(direction))])
    y = start_pose[1] + np.concatenate([[0.0], np.cumsum(chord * np.sin(direction))])
    pose = np.stack([x[log_index], y[log_index], theta[log_index]], axis=1)
    pose[:, :2] += base.sensor_position_std * sensor_rng.standard_normal((n_log, 2))
    pose[:, 2] += base.sensor_heading_std * sensor_rng.standard_normal(n_log)
    ticks = motor[log_index] * (base.ticks_per_rev / (2.0 * math.pi)) + encoder_phase
    counts = (np.floor(ticks) - np.floor(encoder_phase)).astype(np.int64)
    kind = "free" if m.kind == "arc" else m.kind
    run = Run(
        kind=kind,
        time=log_times.astype(float),
        counts=counts,
        true_pose=pose,
        direction=m.direction if m.kind in ("square", "spin") else None,
        side=m.size if m.kind in ("square", "straight") else 0.0,
        source="alien",
        meta={
            "run": f"{index:03d}",
            "experiment": m.experiment,
            "session_time": session_time,
            "wheel_angle0": [float(wheel_angle0[0]), float(wheel_angle0[1])],
        },
    )
    return run, session_time + t_end + _GAP, wheel_angle0 + wheel[-1]


def generate_session(
    effects: Mapping[str, Mapping[str, float]],
    rng: np.random.Generator,
    *,
    protocol: Sequence[Manoeuvre] | None = None,
    base: IndependentRobot | None = None,
    log_rate_hz: float = 10.0,
    integration_hz: float = 400.0,
) -> list[Run]:
    """One session of runs of a robot carrying ``effects`` (names of :data:`ALIEN_EFFECTS`,
    each ``{"value": magnitude}``), driven through ``protocol`` (default: the independent
    generator's rich protocol) one run after the other."""
    for name in effects:
        if name not in ALIEN_EFFECTS:
            raise ValueError(f"unknown alien effect {name!r}; known: {', '.join(ALIEN_EFFECTS)}")
    plan = list(protocol) if protocol is not None else rich_protocol()
    robot = base if base is not None else IndependentRobot()
    runs: list[Run] = []
    clock = 0.0
    angle0 = rng.uniform(0.0, 2.0 * math.pi, size=2)
    for i, m in enumerate(plan):
        run, clock, angle0 = _simulate(
            m,
            robot,
            effects,
            rng,
            index=i,
            session_time=clock,
            wheel_angle0=angle0,
            log_rate_hz=log_rate_hz,
            integration_hz=integration_hz,
        )
        runs.append(run)
    return runs

"""Sanity tests of the independent log generator against analytic predictions.

Tolerances. Unless an effect adds noise, the ground truth of the generator is a deterministic
function of the continuous motor angles, so predictions about the *truth* are checked to float
precision (1e-9). Predictions about the *odometry* (dead-reckoned from the logged, floor-
quantised counts) carry the encoder quantisation: each cumulative count is within one tick of
the continuous motor angle, so the odometry heading is within 2·m_tick/b_n = 9.4e-4 rad of the
commanded one (m_tick = πD_n/ticks_per_rev = 94 µm), and the position error of a square is
bounded by that heading error times the 8 m path plus a tick: 7.6 mm. Statistical checks use
enough runs that the tolerance is ≥ 3.5 standard errors of the estimate.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest
from independent_robot import (
    BUMP_SPREAD,
    IndependentRobot,
    Manoeuvre,
    TurnDirection,
    generate,
    play_operator,
    rich_protocol,
    s_curve,
)
from module_imports import module_imports
from numpy.typing import NDArray

from odomgym.odometry.runs import Run

FloatArray = NDArray[np.float64]

EXACT = 1e-9


def quiet(**kwargs: object) -> IndependentRobot:
    """A robot with no ground-truth sensor noise."""
    effects = kwargs.pop("effects", {})
    assert isinstance(effects, Mapping)
    ticks = kwargs.pop("ticks_per_rev", 2796.8)
    assert isinstance(ticks, float)
    assert not kwargs
    return IndependentRobot(
        ticks_per_rev=ticks, effects=effects, sensor_position_std=0.0, sensor_heading_std=0.0
    )


def heading_bound(robot: IndependentRobot) -> float:
    """Largest odometry heading error from quantised counts: 2 ticks over the wheelbase."""
    return 2.0 * robot.metres_per_tick / robot.wheelbase


def odometry(run: Run, robot: IndependentRobot) -> FloatArray:
    """Midpoint dead reckoning of the logged counts with the nominal parameters (T, 3)."""
    travel = np.diff(run.counts, axis=0).astype(float) * robot.metres_per_tick
    ds = 0.5 * (travel[:, 0] + travel[:, 1])
    dtheta = (travel[:, 1] - travel[:, 0]) / robot.wheelbase
    x0, y0, th0 = run.true_pose[0]
    theta = th0 + np.concatenate([[0.0], np.cumsum(dtheta)])
    mid = theta[:-1] + 0.5 * dtheta
    return np.stack(
        [
            x0 + np.concatenate([[0.0], np.cumsum(ds * np.cos(mid))]),
            y0 + np.concatenate([[0.0], np.cumsum(ds * np.sin(mid))]),
            theta,
        ],
        axis=1,
    )


def in_start_frame(run: Run, pose: FloatArray) -> FloatArray:
    """Poses (K, 3) relative to the first logged pose."""
    x0, y0, th0 = run.true_pose[0]
    c, s = math.cos(th0), math.sin(th0)
    dx, dy = pose[:, 0] - x0, pose[:, 1] - y0
    return np.stack([c * dx + s * dy, -s * dx + c * dy, pose[:, 2] - th0], axis=1)


def rotation(run: Run) -> float:
    """Logged heading change over the run [rad] (unwrapped)."""
    return float(run.true_pose[-1, 2] - run.true_pose[0, 2])


def one(
    robot: IndependentRobot,
    m: Manoeuvre,
    seed: int = 0,
    *,
    log_rate_hz: float = 10.0,
    endpoints_only: bool = False,
) -> Run:
    """The single run of ``m``."""
    rng = np.random.default_rng(seed)
    return generate(robot, [m], rng, log_rate_hz=log_rate_hz, endpoints_only=endpoints_only)[0]


SQUARES = [
    Manoeuvre("square", "cw", size=2.0, speed=0.3),
    Manoeuvre("square", "ccw", size=2.0, speed=0.3),
]


def test_independent_of_odomgym_simulator() -> None:
    """The generator imports numpy, the standard library and odomgym.odometry.runs only."""
    modules = module_imports(Path(__file__).parent / "independent_robot.py")
    odomgym = {m for m in modules if m.split(".")[0] == "odomgym"}
    assert odomgym == {"odomgym.odometry.runs"}
    allowed = {"numpy", "numpy.typing", "odomgym.odometry.runs"}
    assert all(
        m in allowed or m.split(".")[0] not in {"odomgym", "scipy", "pymunk"} for m in modules
    )


def test_log_format_and_protocol() -> None:
    protocol = rich_protocol()
    labels = [m.experiment for m in protocol]
    assert len(protocol) == 24
    assert labels.count("square_cw") == labels.count("square_ccw") == 2
    assert labels.count("straight_return") == labels.count("straight_oneway") == 2
    assert {"spin_ccw_90_fast", "spin_cw_360_slow", "arc_cw_slow", "arc_ccw_fast"} <= set(labels)
    runs = generate(IndependentRobot(), protocol, np.random.default_rng(1))
    assert [r.meta["experiment"] for r in runs] == labels
    assert len({r.meta["run"] for r in runs}) == len(runs)
    for m, run in zip(protocol, runs, strict=True):
        assert run.kind == {"arc": "free"}.get(m.kind, m.kind)
        assert run.direction == (m.direction if m.kind in ("square", "spin") else None)
        assert run.counts.dtype == np.int64
        assert np.all(run.counts[0] == 0)
        np.testing.assert_allclose(run.time, np.arange(len(run.time)) / 10.0, atol=1e-9)
        assert np.all(np.isfinite(run.true_pose))
        # At rest at both ends (the runs start and end with a stop).
        assert np.all(run.counts[1] == run.counts[0]) and np.all(run.counts[-1] == run.counts[-2])
    starts = np.array([r.true_pose[0] for r in runs])
    assert np.ptp(starts[:, 0]) > 1.0 and np.ptp(starts[:, 2]) > 1.0  # random start poses

    sparse = one(IndependentRobot(), SQUARES[0], endpoints_only=True, log_rate_hz=20.0)
    assert np.all(np.isfinite(sparse.true_pose[[0, -1]]))
    assert np.all(np.isnan(sparse.true_pose[1:-1]))
    np.testing.assert_allclose(np.diff(sparse.time), 0.05, atol=1e-9)


def test_effect_names_are_checked() -> None:
    with pytest.raises(ValueError, match="unknown effect"):
        IndependentRobot(effects={"wheel_tow": {"angle": 0.01}})
    with pytest.raises(ValueError, match="unknown parameter"):
        IndependentRobot(effects={"backlash": {"beta": 0.01}})
    with pytest.raises(ValueError, match="positive"):
        IndependentRobot(effects={"wheelbase": {"e_b": 0.0}})
    with pytest.raises(ValueError, match="direction"):
        Manoeuvre("spin", angle=1.0)


def test_s_curve_and_play_operator() -> None:
    prof = s_curve(2.0, 0.3, 0.5)
    t = np.linspace(0.0, prof.duration, 20001)
    pos = prof.position(t)
    assert pos[0] == 0.0 and pos[-1] == pytest.approx(2.0, abs=EXACT)
    assert np.all(np.diff(pos) >= 0.0)
    speed = prof.speed(t)
    assert speed.max() == pytest.approx(0.3)
    assert np.trapezoid(speed, t) == pytest.approx(2.0, rel=1e-6)
    accel = np.diff(speed) / np.diff(t)
    assert np.abs(accel).max() == pytest.approx(0.5, rel=1e-3)  # smooth: no steps in speed
    short = s_curve(0.01, 0.3, 0.5)
    assert short.cruise == 0.0 and short.peak < 0.3

    motor = np.array([0.0, 1.0, 1.0, 0.5, 0.0, 0.2, 1.0])
    wheel = play_operator(motor, 0.4, -0.2)
    np.testing.assert_allclose(wheel, [-0.2, 0.8, 0.8, 0.7, 0.2, 0.2, 0.8])


@pytest.mark.parametrize(
    ("ticks", "heading_tol", "position_tol"),
    [
        (2796.8, 9.5e-4, 7.6e-3),  # quantisation bounds (module docstring)
        (1e9, 1e-6, 1e-6),  # negligible quantisation: kinematic consistency
    ],
)
def test_ideal_square_odometry_matches_truth(
    ticks: float, heading_tol: float, position_tol: float
) -> None:
    """No effects, no noise: the odometry of the counts is the logged pose, up to quantisation.

    The squares are pure straights and pure in-place turns separated by stops of ≥ 0.3 s, so
    no 0.1 s log interval mixes translation and rotation and midpoint integration is exact.
    """
    robot = quiet(ticks_per_rev=ticks)
    assert heading_bound(quiet()) < 9.5e-4
    for run in generate(robot, SQUARES, np.random.default_rng(2)):
        odom = odometry(run, robot)
        err = run.true_pose - odom
        assert np.abs(err[:, 2]).max() < heading_tol
        assert np.hypot(err[:, 0], err[:, 1]).max() < position_tol
        # The commanded square closes exactly in the truth.
        end = in_start_frame(run, run.true_pose[-1:])[0]
        sign = 1.0 if run.direction == "ccw" else -1.0
        np.testing.assert_allclose(end, [0.0, 0.0, sign * 2.0 * math.pi], atol=EXACT)


@pytest.mark.parametrize("e_d", [1.02, 0.97])
def test_wheel_diameter_ratio_straight(e_d: float) -> None:
    """Equal motor angles Φ = L/(D_n/2): Δθ = Φ(D_R − D_L)/(2b) = (D_R − D_L)/b · L/D̄.

    With D_R − D_L = 2D̄(E_d − 1)/(E_d + 1) this is 2(E_d − 1)/(E_d + 1) · L/b; the odometry
    (equal counts) sees no turn.
    """
    robot = quiet(effects={"wheel_diameter_ratio": {"e_d": e_d}})
    length = 3.0
    run = one(robot, Manoeuvre("straight", size=length))
    d_l, d_r = robot.left_diameter, robot.right_diameter
    assert (d_l + d_r) / 2 == pytest.approx(robot.wheel_diameter)
    predicted = (d_r - d_l) / robot.wheelbase * length / robot.wheel_diameter
    assert predicted == pytest.approx(2 * (e_d - 1) / (e_d + 1) * length / robot.wheelbase)
    assert rotation(run) == pytest.approx(predicted, abs=EXACT)
    assert abs(odometry(run, robot)[-1, 2] - run.true_pose[0, 2]) < heading_bound(robot)


def test_distance_scale_straight() -> None:
    robot = quiet(effects={"distance_scale": {"e_s": 1.03}})
    run = one(robot, Manoeuvre("straight", size=2.0))
    end = in_start_frame(run, run.true_pose[-1:])[0]
    np.testing.assert_allclose(end, [2.06, 0.0, 0.0], atol=EXACT)


@pytest.mark.parametrize("direction", ["cw", "ccw"])
def test_wheelbase_spin(direction: TurnDirection) -> None:
    """The counts are what the motors did, d_R − d_L = ±2π·b_n; the truth turns by
    (d_R − d_L)/b = ±2π/e_b, the odometry by ±2π: true − odometry = ±2π(1/e_b − 1)."""
    e_b = 1.05
    robot = quiet(effects={"wheelbase": {"e_b": e_b}})
    run = one(robot, Manoeuvre("spin", direction, angle=2 * math.pi, speed=0.2))
    sign = 1.0 if direction == "ccw" else -1.0
    assert rotation(run) == pytest.approx(sign * 2 * math.pi / e_b, abs=EXACT)
    odom_rotation = odometry(run, robot)[-1, 2] - run.true_pose[0, 2]
    difference = rotation(run) - odom_rotation
    assert difference == pytest.approx(sign * 2 * math.pi * (1 / e_b - 1), abs=heading_bound(robot))
    assert abs(difference) > 0.29


def test_wheel_toe_straight() -> None:
    """The body translates at τ to its heading: lateral = sin τ · path = tan τ · forward."""
    tau, length = 0.02, 3.0
    robot = quiet(effects={"wheel_toe": {"angle": tau}})
    run = one(robot, Manoeuvre("straight", size=length))
    forward, lateral, turned = in_start_frame(run, run.true_pose[-1:])[0]
    assert turned == pytest.approx(0.0, abs=EXACT)
    assert lateral == pytest.approx(length * math.sin(tau), abs=EXACT)
    assert lateral == pytest.approx(math.tan(tau) * forward, abs=EXACT)


def test_backlash() -> None:
    """Gear engaged forward at the start; each reversal of a wheel loses β of its rotation.

    An in-place turn after forward motion reverses the inner wheel: the truth turns
    ε = β·(D/2)/b less than commanded. Around a square each corner loses ε and the next side
    (the inner wheel reversing back to forward) regains it, so the end heading is short by ε:
    ccw 2π − ε, cw −2π + ε; the odometry (counts = motor) reports ±2π.
    """
    beta = 0.03
    robot = quiet(effects={"backlash": {"angle": beta}})
    eps = beta * 0.5 * robot.wheel_diameter / robot.wheelbase
    spin = one(robot, Manoeuvre("spin", "ccw", angle=math.pi / 2, speed=0.1))
    assert rotation(spin) == pytest.approx(math.pi / 2 - eps, abs=EXACT)
    spin = one(robot, Manoeuvre("spin", "cw", angle=math.pi / 2, speed=0.1))
    assert rotation(spin) == pytest.approx(-math.pi / 2 + eps, abs=EXACT)
    straight = one(robot, Manoeuvre("straight", size=1.0))  # forward from rest: no loss
    assert in_start_frame(straight, straight.true_pose[-1:])[0, 0] == pytest.approx(1.0, abs=EXACT)
    for run in generate(robot, SQUARES, np.random.default_rng(3)):
        sign = 1.0 if run.direction == "ccw" else -1.0
        assert rotation(run) == pytest.approx(sign * (2 * math.pi - eps), abs=EXACT)
        odom_rotation = odometry(run, robot)[-1, 2] - run.true_pose[0, 2]
        assert rotation(run) - odom_rotation == pytest.approx(-sign * eps, abs=heading_bound(robot))


@pytest.mark.parametrize(("direction", "speed"), [("ccw", 0.4), ("cw", 0.4), ("ccw", 0.15)])
def test_turn_skid(direction: TurnDirection, speed: float) -> None:
    """Yaw rate ω₀·max(0, 1 − κ|v·ω₀|): none on in-place turns (v = 0); on an arc of radius R
    (ω₀ = v/R) the yaw is α − κ/R²·∫v³dt, and for the S-curve (raised-cosine ramps of T_r,
    mean sin⁶ = 5/16 over a ramp) ∫v³dt = V³(T_c + 5T_r/8). Tolerance 1e-6 rad: the generator
    uses step-average v and ω₀ at 500 Hz (error O((aΔt)²))."""
    kappa, radius, alpha = 2.0, 1.0, math.pi
    robot = quiet(effects={"turn_skid": {"gain": kappa}})
    sign = 1.0 if direction == "ccw" else -1.0
    spin = one(robot, Manoeuvre("spin", direction, angle=math.pi / 2, speed=0.3))
    assert rotation(spin) == pytest.approx(sign * math.pi / 2, abs=EXACT)

    arc = Manoeuvre("arc", direction, size=radius, angle=alpha, speed=speed)
    run = one(robot, arc)
    prof = s_curve(radius * alpha, speed, arc.accel)
    assert kappa * prof.peak**2 / radius < 1.0  # the max(0, ·) does not bind
    integral_v3 = prof.peak**3 * (prof.cruise + 5.0 * prof.ramp / 8.0)
    predicted = sign * (alpha - kappa * integral_v3 / radius**2)
    assert rotation(run) == pytest.approx(predicted, abs=1e-6)
    assert abs(rotation(run) - sign * alpha) > 0.05  # the effect is large
    odom_rotation = odometry(run, robot)[-1, 2] - run.true_pose[0, 2]
    assert odom_rotation == pytest.approx(sign * alpha, abs=heading_bound(robot))


@pytest.mark.parametrize("direction", ["cw", "ccw"])
def test_skid_track(direction: TurnDirection) -> None:
    """The apparent track b·(1 + ε/(1 + (λ/λ½)²)) with λ = (d_L + d_R)/(d_R − d_L): a spin
    (λ = 0) turns by α/(1 + ε); an arc of radius R (λ = 2R/b at every step, the ramps
    included) by α/(1 + ε/(1 + (2R/(b·λ½))²)); a straight path (λ infinite) keeps its heading.
    The odometry, with the nominal track, reports the commanded α in both."""
    excess, half = 0.6, 3.0
    robot = quiet(effects={"skid_track": {"excess": excess, "lambda_half": half}})
    sign = 1.0 if direction == "ccw" else -1.0
    spin = one(robot, Manoeuvre("spin", direction, angle=math.pi, speed=0.3))
    assert rotation(spin) == pytest.approx(sign * math.pi / (1 + excess), abs=EXACT)
    radius, alpha = 0.5, math.pi
    arc = one(robot, Manoeuvre("arc", direction, size=radius, angle=alpha, speed=0.3))
    lam = 2 * radius / robot.wheelbase
    predicted = sign * alpha / (1 + excess / (1 + (lam / half) ** 2))
    assert rotation(arc) == pytest.approx(predicted, abs=EXACT)
    assert abs(rotation(arc) - sign * alpha) > 0.1  # the effect is large
    odom_rotation = odometry(arc, robot)[-1, 2] - arc.true_pose[0, 2]
    assert odom_rotation == pytest.approx(sign * alpha, abs=heading_bound(robot))
    straight = one(robot, Manoeuvre("straight", size=2.0))
    assert in_start_frame(straight, straight.true_pose[-1:])[0, 2] == pytest.approx(0.0, abs=EXACT)


def test_gt_sensor_offset() -> None:
    """A 180° in-place turn moves the tracked point by 2·|offset|; a straight does not."""
    dx, dy = 0.05, -0.03
    robot = quiet(effects={"gt_sensor_offset": {"dx": dx, "dy": dy}})
    run = one(robot, Manoeuvre("spin", "ccw", angle=math.pi, speed=0.2))
    moved = float(np.hypot(*(run.true_pose[-1, :2] - run.true_pose[0, :2])))
    assert moved == pytest.approx(2 * math.hypot(dx, dy), abs=EXACT)
    run = one(robot, Manoeuvre("straight", size=1.0))
    end = in_start_frame(run, run.true_pose[-1:])[0]
    np.testing.assert_allclose(end, [1.0, 0.0, 0.0], atol=EXACT)


def test_floor_roughness_spread() -> None:
    """Chong & Kleeman: per-wheel travel noise of variance k²|d| per step adds up along the
    path, so the end heading of a straight of length d has std √(k_L² + k_R²)·√d/b. 400 runs:
    the sample std has a 3.5 % standard error; tolerance 15 %."""
    k_left, k_right, length = 0.004, 0.006, 2.0
    robot = quiet(effects={"floor_roughness": {"k_left": k_left, "k_right": k_right}})
    runs = generate(
        robot,
        [Manoeuvre("straight", size=length, speed=0.4)] * 400,
        np.random.default_rng(4),
        integration_hz=200.0,
    )
    headings = np.array([rotation(r) for r in runs])
    predicted = math.hypot(k_left, k_right) * math.sqrt(length) / robot.wheelbase
    assert np.std(headings, ddof=1) == pytest.approx(predicted, rel=0.15)
    assert abs(np.mean(headings)) < 4 * predicted / math.sqrt(len(runs))


def test_floor_bumps() -> None:
    """Each bump costs its wheel a·b of ground travel, a heading jump of ±a: the end heading
    of a straight is a·(N_L − N_R) with N ~ Poisson(λd) per wheel (std a·√(2λd)), except for a
    bump still within its 5 cm at the end. 400 runs: tolerance 15 % on the std (3.5 % s.e.)."""
    rate, jump, length = 1.0, 0.02, 2.0
    robot = quiet(effects={"floor_bumps": {"rate": rate, "heading_jump": jump}})
    runs = generate(
        robot,
        [Manoeuvre("straight", size=length, speed=0.4)] * 400,
        np.random.default_rng(5),
        integration_hz=200.0,
    )
    headings = np.array([rotation(r) for r in runs])
    whole = np.abs(headings / jump - np.round(headings / jump)) < 1e-6
    # Jumps are whole multiples of a unless a bump lies in the last BUMP_SPREAD of a wheel's
    # travel: probability 1 − exp(−2λ·BUMP_SPREAD) ≈ 9.5 %, binomial s.e. 1.5 %.
    assert whole.mean() == pytest.approx(math.exp(-2 * rate * BUMP_SPREAD), abs=0.06)
    assert np.std(headings, ddof=1) == pytest.approx(jump * math.sqrt(2 * rate * length), rel=0.15)


def test_determinism_and_streams() -> None:
    robot = IndependentRobot(
        effects={
            "floor_roughness": {"k_left": 0.003, "k_right": 0.002},
            "floor_bumps": {"rate": 0.5, "heading_jump": 0.01},
            "backlash": {"angle": 0.01},
        }
    )
    protocol = [SQUARES[0], Manoeuvre("arc", "ccw", size=1.0, angle=math.pi, speed=0.3)]
    a = generate(robot, protocol, np.random.default_rng(6))
    b = generate(robot, protocol, np.random.default_rng(6))
    c = generate(robot, protocol, np.random.default_rng(7))
    for ra, rb, rc in zip(a, b, c, strict=True):
        np.testing.assert_array_equal(ra.time, rb.time)
        np.testing.assert_array_equal(ra.counts, rb.counts)
        np.testing.assert_array_equal(ra.true_pose, rb.true_pose)
        assert not np.array_equal(ra.true_pose[0], rc.true_pose[0])

    # Sensor noise is its own stream: the same seed without it gives the same motion, and
    # the difference (every row, the first included) is the sensor noise.
    clean = IndependentRobot(effects=robot.effects, sensor_position_std=0.0, sensor_heading_std=0.0)
    d = generate(clean, protocol, np.random.default_rng(6))
    noise = np.concatenate([ra.true_pose - rd.true_pose for ra, rd in zip(a, d, strict=True)])
    np.testing.assert_array_equal(a[0].counts, d[0].counts)
    assert np.all(noise[0] != 0.0)
    assert np.std(noise[:, :2]) == pytest.approx(robot.sensor_position_std, rel=0.1)
    assert np.std(noise[:, 2]) == pytest.approx(robot.sensor_heading_std, rel=0.1)

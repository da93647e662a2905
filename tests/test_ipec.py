"""IPEC, Borenstein 1995 (Eqs. 9–16, §3.3, §5), on exact kinematic drives of a two-truck vehicle.

No physics engine: the true poses are written down analytically (rigid rotations about a
fixed point) or integrated in 1 mm sub-steps from the wheels' true ground travel, with the
rigid-wheel-over-cable geometry of :mod:`odomgym.sim.cables` (Borenstein 1995, Fig. 4). The
estimators get the wheel travel the encoders report and link readings computed from the true
poses (:func:`odomgym.vehicle.estimator.link_angles`), optionally quantised like the CLAPPER's
10-bit rotary encoders (§2).
"""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np
import pytest
from numpy.typing import NDArray

from odomgym.odometry.calibration import Odometry, wrap_angle
from odomgym.robot import PRESETS
from odomgym.sim.cables import bump_extra_rotation, cable_advance, paper_bump_error
from odomgym.vehicle.estimator import (
    DeadReckoning,
    Heading,
    InternalEstimator,
    LinkReading,
    growth_rate,
    link_angles,
)
from odomgym.vehicle.ipec import IPEC, estimate_wheel_diameter_ratio

FloatArray = NDArray[np.float64]

LABMATE = PRESETS["labmate"]
WHEELBASE = 0.340  # truck wheelbase b [m] (Borenstein 1995, Table I)
WHEEL_RADIUS = 0.075  # R [m] (Table I)
CABLE = 0.010  # bump: a 10 mm cable (Table I, §6)
LINK = 1.0  # centre distance L of the trucks [m] (§3.3)
SPEED = 0.5  # V [m/s] (§3.1)
SAMPLE = 0.04  # T_s [s] (§3.1)
D_S = SPEED * SAMPLE  # travel per sampling interval [m] (§3.1: 20 mm)
Q = 2.0 * math.pi / 1024  # rotary encoder step [rad] (§2: 2^-10 × 360°)


# ---------------------------------------------------------------------- helpers
def quantise(psi: FloatArray) -> FloatArray:
    """A 10-bit absolute encoder, rounding to the nearest step."""
    return np.asarray(Q * np.round(psi / Q), dtype=np.float64)


def readings(
    truth: FloatArray, bias: tuple[float, float] = (0.0, 0.0), quantised: bool = False
) -> list[LinkReading]:
    """Link readings of true poses (K, N, 2, 3): exact length, ψ + bias, optionally quantised."""
    out = []
    for poses in truth:
        _, psi = link_angles(poses)
        psi = psi + np.asarray(bias)
        if quantised:
            psi = quantise(psi)
        length = np.hypot(poses[:, 0, 0] - poses[:, 1, 0], poses[:, 0, 1] - poses[:, 1, 1])
        out.append(LinkReading(length, psi))
    return out


def run(
    estimator: InternalEstimator, truth: FloatArray, travel: FloatArray, reads: list[LinkReading]
) -> tuple[FloatArray, FloatArray]:
    """Estimates (K, N, 2, 3) and corrections (K, N, 2) after each of the K intervals."""
    estimator.reset(truth[0], reads[0])
    estimates, corrections = [], []
    for k in range(travel.shape[0]):
        estimates.append(estimator.update(travel[k], reads[k + 1]))
        corrections.append(estimator.correction)
    return np.array(estimates), np.array(corrections)


def rigid_rotation(
    centre: FloatArray, start: FloatArray, dphi: float, intervals: int
) -> tuple[FloatArray, FloatArray]:
    """The vehicle turning rigidly about ``centre`` by ``dphi`` [rad] per interval.

    ``start`` (2, 3) holds the trucks' start poses; every truck's axle line must pass through
    ``centre`` (no side slip), its left wheel on the centre's side for dphi > 0 driving forwards.
    Returns true poses (K + 1, 1, 2, 3) and exact wheel travel (K, 1, 2, 2) [m].
    """
    radius = np.hypot(*(start[:, :2] - centre).T)  # centre radius of each truck [m]
    phi = dphi * np.arange(intervals + 1)
    c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
    rel = start[:, :2] - centre
    truth = np.empty((intervals + 1, 1, 2, 3))
    truth[:, 0, :, 0] = centre[0] + c * rel[:, 0] - s * rel[:, 1]
    truth[:, 0, :, 1] = centre[1] + s * rel[:, 0] + c * rel[:, 1]
    truth[:, 0, :, 2] = start[:, 2] + phi[:, None]
    wheels = np.stack([radius - 0.5 * WHEELBASE, radius + 0.5 * WHEELBASE], axis=-1) * dphi
    return truth, np.broadcast_to(wheels, (intervals, 1, 2, 2)).copy()


def cable_drive(
    x_cable: FloatArray, direction: float, intervals: int = 60, substeps: int = 20
) -> tuple[FloatArray, FloatArray]:
    """Both trucks roll open-loop with equal rim travel D_S per interval (forwards for
    ``direction`` = +1, backwards for −1), trucks on the x axis, A at x = 1 m, B at 0.

    A 10 mm cable across the path at x = ``x_cable[i]`` (one per vehicle) lies under truck A's
    right wheel only (truck B's run ends before it gets there). The wheel's horizontal advance
    is :func:`odomgym.sim.cables.cable_advance` of its rim travel, integrated in 1 mm sub-steps, so
    truck A truly turns by the deficit over b while its encoders report equal travel. The link
    transmits no force (Borenstein 1995, §2), so each truck moves as if alone. Returns true
    poses (K + 1, N, 2, 3) and reported wheel travel (K, N, 2, 2) [m].
    """
    n = x_cable.size
    step = direction * D_S / substeps  # rim travel of each sub-step [m]
    pose = np.zeros((n, 2, 3))
    pose[:, 0, 0] = LINK
    truth = [pose.copy()]
    for _ in range(intervals):
        for _ in range(substeps):
            theta = pose[:, 0, 2]
            contact_x = pose[:, 0, 0] + 0.5 * WHEELBASE * np.sin(theta)  # right wheel
            across = step * np.cos(theta)
            lost = across - cable_advance(contact_x - x_cable, across, WHEEL_RADIUS, 0.5 * CABLE)
            ds = step - 0.5 * lost
            dtheta = -lost / WHEELBASE
            mid = theta + 0.5 * dtheta
            pose[:, 0, 0] += ds * np.cos(mid)
            pose[:, 0, 1] += ds * np.sin(mid)
            pose[:, 0, 2] += dtheta
            pose[:, 1, 0] += step
        truth.append(pose.copy())
    travel = np.full((intervals, n, 2, 2), direction * D_S)
    return np.array(truth), travel


def along_track(error: FloatArray, theta: FloatArray) -> FloatArray:
    """Component of position errors (…, 2) along the headings θ (…) [m]."""
    return np.asarray(error[..., 0] * np.cos(theta) + error[..., 1] * np.sin(theta))


# ---------------------------------------------------------------------- Table I and §3.3
def test_table_1_bump_errors() -> None:
    """Table I: ΔD = 2.63 mm, α = 0.44°, e_lat(10 m) = 77 mm, from the package's Eqs. 1–5
    (:func:`odomgym.sim.cables.paper_bump_error`), matched to the digits printed (the paper rounds;
    nothing tighter can be asserted). The World's exact rigid-cylinder geometry
    (:func:`bump_extra_rotation`) gives 3.40 mm, 0.57°, within 5 % of the paper's measured
    ≈ 0.6° per bump (§6.1)."""
    table = paper_bump_error(WHEEL_RADIUS, CABLE, WHEELBASE, 10.0)
    assert round(table.overcount * 1e3, 2) == 2.63
    assert round(math.degrees(table.heading), 2) == 0.44
    assert round(table.lateral * 1e3) == 77
    exact = bump_extra_rotation(WHEEL_RADIUS, CABLE)
    assert round(exact * 1e3, 2) == 3.40
    assert round(math.degrees(exact / WHEELBASE), 2) == 0.57
    assert math.degrees(exact / WHEELBASE) == pytest.approx(0.6, rel=0.05)
    # The chord of Eq. 3 under-counts the exact arc: the two agree as the cable shrinks.
    small = paper_bump_error(WHEEL_RADIUS, 1e-4, WHEELBASE, 10.0)
    assert small.overcount == pytest.approx(bump_extra_rotation(WHEEL_RADIUS, 1e-4), rel=0.35)


def test_growth_rates_section_3_3() -> None:
    """Eqs. 6–8 (:func:`odomgym.vehicle.estimator.growth_rate`) with D_s = 20 mm, L = 1 m and Table
    I's α: 0.15 mm lateral error per interval, δ = 0.01°, θ_m = 0.43°, matched to the digits
    printed. The paper's 2.3 % and 4.5 % divide its *rounded* values (0.01/0.43, 0.02/0.44);
    unrounded they are 2.0 % and 4.0 %."""
    alpha = paper_bump_error(WHEEL_RADIUS, CABLE, WHEELBASE, 10.0).heading
    rate = growth_rate(alpha, D_S, LINK)
    assert round(rate.lateral * 1e3, 2) == 0.15
    assert round(math.degrees(rate.link), 2) == 0.01
    assert round(math.degrees(rate.measured), 2) == 0.43
    delta_2, theta_m_2, alpha_2 = (
        round(math.degrees(a), 2) for a in (rate.link, rate.measured, alpha)
    )
    assert round(100.0 * delta_2 / theta_m_2, 1) == 2.3
    assert round(100.0 * 2.0 * delta_2 / alpha_2, 1) == 4.5
    assert round(100.0 * rate.link / rate.measured, 1) == 2.0
    assert round(100.0 * 2.0 * rate.link / alpha, 1) == 4.0


# ---------------------------------------------------------------------- the equations
@pytest.mark.parametrize("heading", ["current", "midpoint"])
@pytest.mark.parametrize("translation_correction", [True, False])
def test_identities_after_update(heading: Heading, translation_correction: bool) -> None:
    """Eqs. 11–13 give θ'_X = θ_L + ψ_X,act, Eq. 16 puts B exactly l_meas behind A along θ_L,
    whatever the data (random poses, travel, readings; 1e-12: rounding of O(1) numbers)."""
    rng = np.random.default_rng(9)
    n = 6
    ipec = IPEC(
        rng.uniform(0.3, 0.4, (n, 2)),
        heading=heading,
        translation_correction=translation_correction,
    )
    poses = rng.uniform(-2.0, 2.0, (n, 2, 3))
    ipec.reset(poses, LinkReading(np.ones(n), np.zeros((n, 2))))
    for _ in range(20):
        reading = LinkReading(rng.uniform(0.9, 1.1, n), rng.uniform(-math.pi, math.pi, (n, 2)))
        out = ipec.update(rng.uniform(-0.03, 0.03, (n, 2, 2)), reading)
        theta_link = ipec.link_direction
        np.testing.assert_allclose(
            wrap_angle(out[:, :, 2] - theta_link[:, None] - reading.psi), 0.0, atol=1e-12
        )
        offset = out[:, 0, :2] - out[:, 1, :2]
        expected = reading.length[:, None] * np.stack(
            [np.cos(theta_link), np.sin(theta_link)], axis=1
        )
        np.testing.assert_allclose(offset, expected, atol=1e-12)


@pytest.mark.parametrize("dphi", [4e-3, -4e-3])
def test_exact_data_on_an_arc(dphi: float) -> None:
    """Both trucks on one 3 m circle, turning rigidly forwards and backwards (12 mm per interval),
    with exact wheel travel and readings. A wrong sign in Eqs. 10, 11, 12 or 16 fails this.

    ``heading="midpoint"`` moves each truck along the exact chord direction but by the arc
    length U, U·dφ²/24 more than the chord, and IPEC corrects the resulting phantom turn:
    Δ_A = Δ_B = dφ³/24 every interval (1e-14 rad: 2e-6 of it, the next term of the series);
    the poses stay within the summed chord excess (1.2 µm) and summed phantom turns (0.4 µrad).
    The paper's ``"current"`` moves along the end orientation, U·sin(dφ/2) to the side of the
    chord each interval; the headings stay within 2 µrad, the positions within that sideways
    error summed (3.6 mm, 3.4 mm seen)."""
    radius, intervals = 3.0, 150
    behind = 2.0 * math.asin(0.5 * LINK / radius)  # angle at the centre between B and A
    start = np.array(  # both trucks on the circle, tangent to it (ψ_A = −ψ_B = behind/2)
        [
            [radius, 0.0, 0.5 * math.pi],
            [radius * math.cos(behind), -radius * math.sin(behind), 0.5 * math.pi - behind],
        ]
    )
    truth, travel = rigid_rotation(np.zeros(2), start, dphi, intervals)
    step = radius * abs(dphi)  # U [m]
    ipec = IPEC(np.full((1, 2), WHEELBASE), heading="midpoint")
    estimates, corrections = run(ipec, truth, travel, readings(truth))
    np.testing.assert_allclose(corrections, dphi**3 / 24.0, rtol=0.0, atol=1e-14)
    position_error = np.abs(estimates[..., :2] - truth[1:, ..., :2]).max()
    assert position_error < intervals * step * dphi**2 / 24.0 + 1e-9
    heading_error = np.abs(estimates[..., 2] - truth[1:, ..., 2]).max()
    assert heading_error < intervals * abs(dphi) ** 3 / 24.0 + 1e-12

    ipec = IPEC(np.full((1, 2), WHEELBASE), heading="current")
    estimates, _ = run(ipec, truth, travel, readings(truth))
    assert np.abs(estimates[..., 2] - truth[1:, ..., 2]).max() < 2e-6
    position_error = np.hypot(*(estimates[..., :2] - truth[1:, ..., :2]).T).max()
    assert position_error < intervals * step * math.sin(0.5 * abs(dphi))


def test_eq_15_rotates_truck_a_about_the_non_slipping_wheel() -> None:
    """Eq. 15 as a rotation: truck A's corrected centre is its dead-reckoned centre turned by
    Δ_A about the contact point of the wheel that did not lag — the left one when s·Δ_A < 0
    (s the sign of its travel), the right one when s·Δ_A > 0 — and stays where it was when its
    wheels roll in opposite directions or stand still, or when the wheel that would have lagged
    reported no travel (it cannot have over-reported) (1e-12 m: rounding)."""
    rng = np.random.default_rng(15)
    n = 400
    wheelbase = np.full((n, 2), WHEELBASE)
    start = rng.uniform(-2.0, 2.0, (n, 2, 3))
    travel = rng.uniform(-0.03, 0.03, (n, 2, 2))
    travel[:20, 0] = 0.0  # standing still
    travel[20:60, 0, 0] = 0.0  # pivoting about the left wheel
    reading = LinkReading(rng.uniform(0.9, 1.1, n), rng.uniform(-0.2, 0.2, (n, 2)))
    ipec = IPEC(wheelbase)
    ipec.reset(start, reading)
    corrected = ipec.update(travel, reading)[:, 0]
    delta = ipec.correction[:, 0]
    plain = IPEC(wheelbase, translation_correction=False)
    plain.reset(start, reading)
    reckoned = plain.update(travel, reading)[:, 0]  # Eqs. 9–13 only: A's centre untouched
    theta = reckoned[:, 2] - delta  # the dead-reckoned (uncorrected) θ_A
    left, right = travel[:, 0, 0], travel[:, 0, 1]
    sign = np.sign(left + right)
    cases = {"left pivot": 0, "right pivot": 0, "none": 0}
    for i in range(n):
        side = 1.0 if sign[i] * delta[i] < 0.0 else -1.0  # +1: the right wheel lagged
        lagged = right[i] if side > 0 else left[i]
        if left[i] * right[i] < 0.0 or lagged == 0.0:
            expected = reckoned[i, :2]
            cases["none"] += 1
        else:
            cases["left pivot" if side > 0 else "right pivot"] += 1
            normal = np.array([-math.sin(theta[i]), math.cos(theta[i])])  # to the left
            pivot = reckoned[i, :2] + side * 0.5 * WHEELBASE * normal
            c, s = math.cos(delta[i]), math.sin(delta[i])
            rel = reckoned[i, :2] - pivot
            expected = pivot + np.array([c * rel[0] - s * rel[1], s * rel[0] + c * rel[1]])
        np.testing.assert_allclose(corrected[i, :2], expected, rtol=0.0, atol=1e-12)
    assert min(cases.values()) >= 20


def test_dead_reckoning_is_odomgym_odometry() -> None:
    """DeadReckoning integrates each truck as :class:`odomgym.odometry.calibration.Odometry` does
    (the same midpoint equations; 1e-12 m: rounding)."""
    rng = np.random.default_rng(3)
    odometry = Odometry([LABMATE] * 4)  # 2 vehicles × 2 trucks
    start = rng.uniform(-1.0, 1.0, (2, 2, 3))
    odometry.reset(start.reshape(4, 3))
    dead = DeadReckoning(odometry.effective_wheelbase.reshape(2, 2))
    dead.reset(start, LinkReading(np.ones(2), np.zeros((2, 2))))
    counts = np.zeros((4, 2), dtype=np.int64)
    for _ in range(50):
        step = rng.integers(-150, 150, (4, 2))
        counts = counts + step
        odometry.update(counts, SAMPLE)
        travel = (step * odometry.travel_per_tick).reshape(2, 2, 2)
        poses = dead.update(travel, LinkReading(np.ones(2), np.zeros((2, 2))))
    np.testing.assert_allclose(poses.reshape(4, 3), odometry.pose, atol=1e-12)
    assert not dead.correction.any()


def test_vehicles_in_a_batch_are_independent() -> None:
    """A vehicle's estimate is bit-identical whatever else shares its batch."""
    rng = np.random.default_rng(5)
    n, k = 4, 30
    wheelbase = rng.uniform(0.3, 0.4, (n, 2))
    start = rng.uniform(-1.0, 1.0, (n, 2, 3))
    travel = rng.uniform(-0.02, 0.03, (k, n, 2, 2))
    reads = [
        LinkReading(rng.uniform(0.9, 1.1, n), rng.uniform(-0.5, 0.5, (n, 2))) for _ in range(k + 1)
    ]
    batch = IPEC(wheelbase)
    alone = IPEC(wheelbase[2:3])
    batch.reset(start, reads[0])
    alone.reset(start[2:3], LinkReading(reads[0].length[2:3], reads[0].psi[2:3]))
    for j in range(k):
        together = batch.update(travel[j], reads[j + 1])
        single = alone.update(
            travel[j, 2:3], LinkReading(reads[j + 1].length[2:3], reads[j + 1].psi[2:3])
        )
        assert np.array_equal(together[2:3], single)


def test_invalid_arguments_are_named() -> None:
    with pytest.raises(ValueError, match="wheelbase"):
        IPEC(np.full(2, WHEELBASE))
    with pytest.raises(ValueError, match="heading"):
        IPEC(np.full((1, 2), WHEELBASE), heading=cast(Any, "end"))
    ipec = IPEC(np.full((1, 2), WHEELBASE))
    with pytest.raises(ValueError, match="wheel_travel"):
        ipec.update(np.zeros((1, 2)), LinkReading(np.ones(1), np.zeros((1, 2))))


# ---------------------------------------------------------------------- one cable (§3, §4)
PHASES = 1.5 + np.linspace(0.0, D_S, 5, endpoint=False)  # cable positions across one interval [m]


def _cable(direction: float) -> tuple[FloatArray, FloatArray]:
    x_cable = PHASES if direction > 0 else 2.0 * LINK - PHASES  # A meets it 0.5 m out
    return cable_drive(x_cable, direction)


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_dead_reckoning_takes_the_whole_bump(direction: float) -> None:
    """Without IPEC, truck A ends with the full heading error deficit/b = 0.57°: its encoders
    reported equal travel while the cable cost the right wheel 3.40 mm of horizontal advance
    (within 1e-5: the truck yaws during the crossing, so the rim's component across the cable
    differs from its travel by 1 − cos θ ≈ 1e-5). Truck B, on a clear floor, none."""
    truth, travel = _cable(direction)
    estimates, _ = run(
        DeadReckoning(np.full((PHASES.size, 2), WHEELBASE)), truth, travel, readings(truth)
    )
    error = estimates[-1, :, :, 2] - truth[-1, :, :, 2]
    expected = direction * bump_extra_rotation(WHEEL_RADIUS, CABLE) / WHEELBASE
    np.testing.assert_allclose(error[:, 0], expected, rtol=1e-5)
    np.testing.assert_allclose(error[:, 1], 0.0, atol=1e-12)
    assert math.degrees(abs(expected)) == pytest.approx(0.5726, abs=1e-4)


@pytest.mark.parametrize("direction", [1.0, -1.0])
@pytest.mark.parametrize("heading", ["current", "midpoint"])
def test_ipec_removes_the_bump(direction: float, heading: Heading) -> None:
    """With exact readings IPEC's heading error stays below Eq. 7's δ = 0.01° at every interval
    (the only error left is the link direction's, from the lateral error the bump causes
    within one interval), for every cable position across an interval."""
    truth, travel = _cable(direction)
    ipec = IPEC(np.full((PHASES.size, 2), WHEELBASE), heading=heading)
    estimates, _ = run(ipec, truth, travel, readings(truth))
    error = wrap_angle(estimates[..., 2] - truth[1:, ..., 2])
    assert np.degrees(np.abs(error)).max() < 0.01


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_ipec_with_10_bit_encoders(direction: float) -> None:
    """With 10-bit readings (q = 0.35°, rounded) each truck's heading error is exactly the link
    direction's error e_L plus the reading's rounding ε_X (≤ q/2) — Eq. 13 gives
    θ'_X = θ_L + ψ_X,act — so it is bounded by q/2 only as long as e_L stays small. It does not
    stay put: a rounded reading is a temporary encoder bias (§5.2), each truck then moves
    U·ε_X to the side of its true track, and the link turns by U·(ε_A − ε_B)/l per interval.
    Checked: e_L equals the exact-reading run's link error plus Σ U·(ε_A − ε_B)/l within
    1e-3° (the law is first order in ε ≤ 3 mrad; its largest value here is ≈ 0.05°). Over
    this 1.2 m run the heading errors reach 0.19° (A) and 0.22° (B), above q/2 = 0.176°."""
    truth, travel = _cable(direction)
    wheelbase = np.full((PHASES.size, 2), WHEELBASE)
    exact = IPEC(wheelbase)
    exact.reset(truth[0], readings(truth[:1])[0])
    rounded = IPEC(wheelbase)
    rounded.reset(truth[0], readings(truth[:1])[0])
    exact_reads = readings(truth)
    rounded_reads = readings(truth, quantised=True)
    drift = np.zeros(PHASES.size)  # Σ U·(ε_A − ε_B)/l [rad]
    worst = 0.0
    for k in range(travel.shape[0]):
        exact.update(travel[k], exact_reads[k + 1])
        estimate = rounded.update(travel[k], rounded_reads[k + 1])
        true_link, true_psi = link_angles(truth[k + 1])
        link_error = wrap_angle(rounded.link_direction - true_link)
        exact_link_error = wrap_angle(exact.link_direction - true_link)
        assert np.degrees(np.abs(link_error - exact_link_error - drift)).max() < 1e-3
        rounding = rounded_reads[k + 1].psi - true_psi
        assert np.abs(rounding).max() <= 0.5 * Q + 1e-12
        heading_error = wrap_angle(estimate[..., 2] - truth[k + 1, ..., 2])
        np.testing.assert_allclose(heading_error, link_error[:, None] + rounding, atol=1e-12)
        drift = drift + direction * D_S * (rounding[:, 0] - rounding[:, 1]) / LINK
        worst = max(worst, float(np.abs(heading_error).max()))
    assert worst > 0.5 * Q  # q/2 alone is no bound (see the docstring)


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_translation_correction_eq_15(direction: float) -> None:
    """Dead reckoning puts truck A half the wheel deficit (1.70 mm) ahead along its track
    (within 1 %: the remainder is the lateral part of the yaw); Eqs. 14–15, pivoting about the
    left wheel's contact point, bring that below 0.1 mm, driving forwards or backwards
    (exact readings)."""
    truth, travel = _cable(direction)
    along = {}
    for correct in (True, False):
        ipec = IPEC(np.full((PHASES.size, 2), WHEELBASE), translation_correction=correct)
        estimates, _ = run(ipec, truth, travel, readings(truth))
        error = estimates[-1, :, 0, :2] - truth[-1, :, 0, :2]
        along[correct] = direction * along_track(error, truth[-1, :, 0, 2])  # + = ahead
    half_deficit = 0.5 * bump_extra_rotation(WHEEL_RADIUS, CABLE)
    np.testing.assert_allclose(along[False], half_deficit, rtol=0.01)
    assert np.abs(along[True]).max() < 1e-4
    assert np.all(np.abs(along[True]) < np.abs(along[False]))


# ---------------------------------------------------------------------- §5 systematic errors
def test_rotary_encoder_bias_is_invisible() -> None:
    """§5.2: encoder B reads ψ_B + 1°. The trucks drive the motion that keeps the biased
    readings at their straight-line values (0, 0): truck A at 0° to the link, truck B truly at
    −1°. Without side slip the vehicle then turns rigidly about the intersection of the two axle
    lines, l·cot 1° = 57.3 m to the left of A; after 5 m (250 intervals of 20 mm at A) both
    trucks have turned by 5.0°. IPEC sees a constant link angle and reports a straight path:
    after its first interval (which reconciles the true start poses with the biased readings),
    the estimated headings change by < 1e-6 rad and truck A's estimated positions lie on a line
    within 1 µm. Its corrections add up to the true turn: IPEC takes it for dead-reckoning
    error, as it would unequal wheel diameters."""
    beta = math.radians(1.0)
    centre = np.array([LINK, LINK / math.tan(beta)])
    start = np.array([[LINK, 0.0, 0.0], [0.0, 0.0, -beta]])
    dphi = D_S / centre[1]
    truth, travel = rigid_rotation(centre, start, dphi, 250)
    reads = readings(truth, bias=(0.0, beta))
    np.testing.assert_allclose(np.array([r.psi for r in reads]), 0.0, atol=1e-12)
    true_turn = truth[-1, 0, :, 2] - truth[0, 0, :, 2]
    assert math.degrees(true_turn[0]) == pytest.approx(5.0, abs=0.01)
    ipec = IPEC(np.full((1, 2), WHEELBASE))
    estimates, corrections = run(ipec, truth, travel, reads)
    heading_change = estimates[-1, 0, :, 2] - estimates[0, 0, :, 2]
    assert np.abs(heading_change).max() < 1e-6
    path = estimates[:, 0, 0, :2] - estimates[0, 0, 0, :2]
    chord = path[-1] / np.linalg.norm(path[-1])
    assert np.abs(path[:, 0] * chord[1] - path[:, 1] * chord[0]).max() < 1e-6
    np.testing.assert_allclose(corrections[1:, 0, 0].sum(), -true_turn[0] + dphi, atol=1e-6)


def test_auto_calibration_of_wheel_diameters() -> None:
    """§5.1: three vehicles drive 18 m straight (900 intervals of 20 mm, as §6.1's legs) on a
    smooth floor, each truck a LabMate with its own E_d; the trucks hold 0.1° to the link, read
    as 0 by the 10-bit encoders. Wheel travel comes from rounded encoder counts. E_d from the
    summed corrections (intervals 2–900: the first reconciles the true start with the readings)
    must match, within 2e-5 (1 % of E_d − 1, covering one count of rounding in each wheel's
    sum, 1.3e-5, and the skipped interval, 2e-6) *after* removing the link drift the docstring
    predicts for trucks with different E_d: b·Σ U(Δθ_A − Δθ_B)/(l·D), 6e-5 here."""
    e_d = np.array([[1.002, 1.002], [1.002, 0.999], [0.998, 1.0005]])
    n, intervals = e_d.shape[0], 900
    crab = math.radians(0.1)
    specs = [[LABMATE.with_errors(e_d=e, e_b=1.0, e_s=1.0) for e in row] for row in e_d]
    true_per_count = np.array(
        [[[s.true_left_diameter, s.true_right_diameter] for s in row] for row in specs]
    ) * (math.pi / LABMATE.ticks_per_rev)

    def truth_at(k: int) -> FloatArray:
        poses = np.zeros((n, 2, 3))
        poses[:, :, 0] = k * D_S * math.cos(crab)
        poses[:, 0, 0] += LINK
        poses[:, :, 1] = k * D_S * math.sin(crab)
        poses[:, :, 2] = crab
        return poses

    ipec = IPEC(np.full((n, 2), LABMATE.wheelbase))
    ipec.reset(truth_at(0), readings(truth_at(0)[None], quantised=True)[0])
    counts = np.zeros((n, 2, 2))
    correction_sum = np.zeros((n, 2))
    distance = np.zeros((n, 2))
    for k in range(1, intervals + 1):
        new_counts = np.round(k * D_S / true_per_count)
        travel = (new_counts - counts) * LABMATE.metres_per_tick
        counts = new_counts
        ipec.update(travel, readings(truth_at(k)[None], quantised=True)[0])
        if k > 1:
            correction_sum += np.sign(ipec.travel) * ipec.correction
            distance += np.abs(ipec.travel)
    estimate = estimate_wheel_diameter_ratio(correction_sum, distance, LABMATE.wheelbase)
    # Link drift, heading "current": Δθ_X = −U·(E_d − 1)/b per interval to first order.
    dtheta = -D_S * (e_d - 1.0) / LABMATE.wheelbase
    drift = intervals * D_S * (dtheta[:, 0] - dtheta[:, 1]) / LINK
    predicted = e_d + LABMATE.wheelbase * drift[:, None] / distance
    np.testing.assert_allclose(estimate, predicted, atol=2e-5)
    # Equal wheels in both trucks: no drift, and the plain estimate is already within 1 %.
    np.testing.assert_allclose(estimate[0], e_d[0], atol=2e-5)

"""The compiled and scalar pieces of a CLAPPER control step against the numpy expressions they
replaced, bit for bit: the encoder readings, the wheels' sides of laid cables and the crossing
count, the controller's speed-limit interpolation, and the follower's reference (``offset_at``)
given the point the controller has just looked up. Why bit for bit: a run
of the vehicle is chaotic enough (IPEC's corrections are rounded to encoder counts) that a last-
bit difference in one step would change the run."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from odomgym.floor import CableBump
from odomgym.odometry.calibration import wrap_angle
from odomgym.robot import PRESETS
from odomgym.vehicle.cable_layout import cable_arrays, crossings, wheel_sides
from odomgym.vehicle.paths import (
    Polyline,
    VehiclePath,
    circle_path,
    extended_at,
    interp_float,
    offset_at,
    point_at,
    rectangle_path,
    straight_path,
)
from odomgym.vehicle.spec import VehicleSpec, link_readings


def _numpy_readings(
    spec: VehicleSpec, poses: np.ndarray, jitter: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """The readings as numpy arrays compute them (the reference of the compiled kernel)."""
    dx = poses[:, 0, 0] - poses[:, 1, 0]
    dy = poses[:, 0, 1] - poses[:, 1, 1]
    theta = np.arctan2(dy, dx)
    psi = wrap_angle(poses[:, :, 2] - theta[:, None])
    shown = psi + np.array([spec.rotary_bias_a, spec.rotary_bias_b])
    if jitter is not None:
        shown = shown + jitter
    q = spec.rotary_resolution
    psi_read = q * np.round(shown / q)
    if spec.trailer:
        psi_read[:, 1] = 0.0
        return np.full(len(psi), spec.link_length), psi_read
    length = np.hypot(dx, dy) + spec.linear_bias
    if spec.linear_eccentricity:
        length = length - spec.linear_eccentricity * np.sin(psi[:, 1])
    r = spec.linear_resolution
    return r * np.round(length / r), psi_read


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"rotary_bias_a": 0.003, "rotary_bias_b": -0.002, "linear_bias": 0.002},
        {"linear_eccentricity": 0.002, "rotary_jitter": 0.004},
        {"trailer": True},
    ],
)
def test_encoder_readings_are_numpys_to_the_bit(changes: dict[str, object]) -> None:
    spec = dataclasses.replace(
        VehicleSpec(PRESETS["labmate"], PRESETS["labmate"]),
        **changes,  # type: ignore[arg-type]
    )
    rng = np.random.default_rng(11)
    poses = np.zeros((4000, 2, 3))
    poses[:, 0, :2] = rng.uniform(-20.0, 20.0, (4000, 2))
    angle = rng.uniform(-math.pi, math.pi, 4000)
    poses[:, 1, 0] = poses[:, 0, 0] - np.cos(angle) * rng.uniform(0.9, 1.1, 4000)
    poses[:, 1, 1] = poses[:, 0, 1] - np.sin(angle) * rng.uniform(0.9, 1.1, 4000)
    poses[:, :, 2] = rng.uniform(-4.0, 4.0, (4000, 2))
    poses[:5, :, 2] = np.arctan2(  # on the link exactly: ψ = 0, where -0.0 could appear
        poses[:5, 0, 1] - poses[:5, 1, 1], poses[:5, 0, 0] - poses[:5, 1, 0]
    )[:, None]
    draws = np.random.default_rng(5)
    reading = link_readings(spec, poses, np.random.default_rng(5))
    jitter = spec.rotary_jitter * draws.standard_normal((4000, 2)) if spec.rotary_jitter else None
    length, psi = _numpy_readings(spec, poses, jitter)
    assert reading.psi.tobytes() == psi.tobytes()
    assert reading.length.tobytes() == length.tobytes()


def _numpy_sides(
    poses: np.ndarray, half_track: np.ndarray, geometry: tuple[np.ndarray, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """The wheels' sides and reach of each cable as numpy arrays compute them (the reference)."""
    cx, cy, ax, ay, half = geometry
    left = np.stack([-np.sin(poses[:, 2]), np.cos(poses[:, 2])], axis=1) * half_track[:, None]
    points = np.stack([poses[:, :2] + left, poses[:, :2] - left], axis=1).reshape(4, 2)
    px = points[:, 0:1] - cx[None, :]
    py = points[:, 1:2] - cy[None, :]
    side = np.sign(px * -ay[None, :] + py * ax[None, :])
    return side, np.abs(px * ax[None, :] + py * ay[None, :]) <= half[None, :]


def test_wheel_sides_and_crossings_are_numpys() -> None:
    rng = np.random.default_rng(2)
    cables = tuple(
        CableBump(x=x, y=y, angle=a, diameter=0.01, length=0.3)
        for x, y, a in rng.uniform((-1.0, -1.0, -math.pi), (1.0, 1.0, math.pi), (25, 3))
    )
    geometry = cable_arrays(cables)
    half_track = np.array([0.28, 0.31])
    before = None
    total = [0, 0]
    for _ in range(300):
        poses = np.column_stack([rng.uniform(-1.0, 1.0, (2, 2)), rng.uniform(-4.0, 4.0, 2)])
        side, within = wheel_sides(poses, half_track, *geometry)
        want_side, want_within = _numpy_sides(poses, half_track, geometry)
        assert side.tobytes() == want_side.tobytes()
        assert np.array_equal(within, want_within)
        if before is not None:
            crossed = ((side != before) & (side != 0) & within).sum(axis=1)
            counted = crossings(side, before, within)
            assert counted == (int(crossed[:2].sum()), int(crossed[2:].sum()))
            total[0] += counted[0]
            total[1] += counted[1]
        before = side
    assert min(total) > 0  # the random poses do cross cables: the count is exercised


def test_a_wheel_on_a_cable_axis_is_on_neither_side_as_numpy_says() -> None:
    """Cables centred exactly on each wheel, their axes at 2 rad (cos < 0 < sin): the side's
    sum is −0.0, whose sign numpy gives as +0.0 (numba's ``np.sign`` would keep −0.0)."""
    poses = np.array([[0.3, -0.2, 0.4], [-0.7, 0.1, 0.5]])
    half_track = np.array([0.28, 0.31])
    left = np.stack([-np.sin(poses[:, 2]), np.cos(poses[:, 2])], axis=1) * half_track[:, None]
    points = np.stack([poses[:, :2] + left, poses[:, :2] - left], axis=1).reshape(4, 2)
    cables = tuple(CableBump(x=x, y=y, angle=2.0, diameter=0.01, length=0.3) for x, y in points)
    geometry = cable_arrays(cables)
    side, _ = wheel_sides(poses, half_track, *geometry)
    want, _ = _numpy_sides(poses, half_track, geometry)
    assert np.all(np.diag(want) == 0.0)
    assert side.tobytes() == want.tobytes()


def test_interp_float_is_numpys_interp() -> None:
    rng = np.random.default_rng(4)
    for trial in range(400):
        xp = np.sort(rng.uniform(-5.0, 5.0, rng.integers(2, 30)))
        if trial % 3 == 0:
            xp = np.sort(np.round(xp))  # repeated knots
        fp = rng.uniform(-2.0, 2.0, len(xp))
        if trial % 4 == 0:
            fp = np.round(fp)  # flat stretches
        xs = np.concatenate([rng.uniform(-6.0, 6.0, 40), xp, np.nextafter(xp, np.inf), [np.nan]])
        for x in xs:
            want = np.float64(np.interp(x, xp, fp)).tobytes()
            assert np.float64(interp_float(float(x), xp.tolist(), fp.tolist())).tobytes() == want


def _march(line: Polyline, s: float, distance: float, side: float) -> float:
    """:func:`offset_at`'s march as it was before it took ``start`` (the reference; on these
    paths it never stalls, so its bisection fallback is not needed)."""
    ax, ay = extended_at(line, s)
    t = s
    for _ in range(64):
        x, y = extended_at(line, t)
        gap = distance - math.hypot(ax - x, ay - y)
        if gap <= 1e-10:
            return t
        t += side * gap
    raise AssertionError(f"the march stalled at s = {s}")


@pytest.mark.parametrize(
    "path",
    [rectangle_path(), circle_path(2.0), straight_path(18.0)],
    ids=["rectangle", "circle", "straight"],
)
def test_offset_at_is_the_march_it_was_given_the_controllers_start(path: VehiclePath) -> None:
    """The controller passes the position :func:`point_at` has just given it; on the leg (its
    arc lengths 0 … length) the result is the old march's, bit for bit."""
    line = path.legs[-1].polyline
    for s in [*np.linspace(0.0, line.arc[-1], 400).tolist(), line.arc[-1]]:
        for side in (-1.0, 1.0):
            want = _march(line, s, 1.0, side)
            assert offset_at(line, s, 1.0, side) == want
            assert offset_at(line, s, 1.0, side, point_at(line, s)[:2]) == want

"""The compiled and scalar pieces of a CLAPPER control step against the numpy expressions they
replaced, bit for bit: the encoder readings, the wheels' sides of laid cables and the crossing
count, the controller's speed-limit interpolation and the path look-ups. Why bit for bit: a run
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
    circle_path,
    extended_at,
    interp_float,
    offset_at,
    rectangle_path,
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


def test_wheel_sides_and_crossings_are_numpys() -> None:
    rng = np.random.default_rng(2)
    cables = tuple(
        CableBump(x=x, y=y, angle=a, diameter=0.01, length=0.3)
        for x, y, a in rng.uniform((-1.0, -1.0, -math.pi), (1.0, 1.0, math.pi), (25, 3))
    )
    cx, cy, ax, ay, half = geometry = cable_arrays(cables)
    half_track = np.array([0.28, 0.31])
    before = None
    total = [0, 0]
    for _ in range(300):
        poses = np.column_stack([rng.uniform(-1.0, 1.0, (2, 2)), rng.uniform(-4.0, 4.0, 2)])
        side, within = wheel_sides(poses, half_track, *geometry)
        left = np.stack([-np.sin(poses[:, 2]), np.cos(poses[:, 2])], axis=1) * half_track[:, None]
        points = np.stack([poses[:, :2] + left, poses[:, :2] - left], axis=1).reshape(4, 2)
        px = points[:, 0:1] - cx[None, :]
        py = points[:, 1:2] - cy[None, :]
        assert side.tobytes() == np.sign(px * -ay[None, :] + py * ax[None, :]).tobytes()
        assert np.array_equal(within, np.abs(px * ax[None, :] + py * ay[None, :]) <= half[None, :])
        if before is not None:
            crossed = ((side != before) & (side != 0) & within).sum(axis=1)
            counted = crossings(side, before, within)
            assert counted == (int(crossed[:2].sum()), int(crossed[2:].sum()))
            total[0] += counted[0]
            total[1] += counted[1]
        before = side
    assert min(total) > 0  # the random poses do cross cables: the count is exercised


def test_interp_float_is_numpys_interp() -> None:
    rng = np.random.default_rng(4)
    for trial in range(400):
        xp = np.unique(rng.uniform(-5.0, 5.0, rng.integers(2, 30)))
        if len(xp) < 2:
            continue
        fp = rng.uniform(-2.0, 2.0, len(xp))
        if trial % 4 == 0:
            fp = np.round(fp)  # flat stretches
        xs = np.concatenate([rng.uniform(-6.0, 6.0, 40), xp, np.nextafter(xp, np.inf), [np.nan]])
        for x in xs:
            want = np.float64(np.interp(x, xp, fp)).tobytes()
            assert np.float64(interp_float(float(x), xp.tolist(), fp.tolist())).tobytes() == want


@pytest.mark.parametrize("path", [rectangle_path(), circle_path(2.0)], ids=["rectangle", "circle"])
def test_offset_at_given_its_start_is_the_same(path: object) -> None:
    """The controller passes the point it has just looked up; the march is the same."""
    line = path.legs[0].polyline  # type: ignore[attr-defined]
    for s in np.linspace(0.0, line.arc[-1], 400).tolist():
        for side in (-1.0, 1.0):
            alone = offset_at(line, s, 1.0, side)
            assert offset_at(line, s, 1.0, side, extended_at(line, s)) == alone

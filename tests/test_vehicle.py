"""The two-truck vehicle spec, its internal encoders and the compliant linkage in the World
(Borenstein 1995, §2)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from odomgym.errors import SpecError
from odomgym.floor import FLOORS
from odomgym.robot import PRESETS
from odomgym.sim.world import World
from odomgym.vehicle.estimator import link_angles
from odomgym.vehicle.spec import (
    PAPER_ERRORS,
    VEHICLES,
    VehicleSpec,
    calibrated,
    link_readings,
    load_vehicle,
)

CLAPPER = VEHICLES["clapper"]


def test_clapper_preset_has_the_papers_encoders() -> None:
    # Borenstein 1995, §2: 10-bit absolute encoders (0.35°), 0.1 mm linear encoder; §4.1: 40 ms.
    assert math.degrees(CLAPPER.rotary_resolution) == pytest.approx(0.3515625)
    assert CLAPPER.linear_resolution == 1e-4
    assert CLAPPER.sample_period == 0.04
    assert CLAPPER.link_length == 1.0
    # The paper's vehicle was "well calibrated" (§6): LabMates with their odometry calibrated.
    assert CLAPPER.truck_a == calibrated(PRESETS["labmate"]) == CLAPPER.truck_b
    truck = CLAPPER.truck_a
    assert truck.wheelbase == truck.true_wheelbase == PRESETS["labmate"].true_wheelbase
    assert truck.true_left_diameter == truck.true_right_diameter == truck.wheel_diameter
    assert VEHICLES["clapper-uncalibrated"].truck_a == PRESETS["labmate"]


def test_toml_round_trip_and_file_relative_truck(tmp_path: Path) -> None:
    truck = PRESETS["labmate"].with_errors(1.002, 1.01)
    truck_path = tmp_path / "trucks" / "b.toml"
    truck_path.parent.mkdir()
    truck.save(truck_path)
    path = tmp_path / "vehicle.toml"
    path.write_text(
        '[vehicle]\nname = "mine"\ntruck_a = "labmate"\ntruck_b = "trucks/b.toml"\n'
        "link_length = 1.2\nlink_min = 1.0\nlink_max = 1.4\nrotary_bias_b = 0.01\n",
        encoding="utf-8",
    )
    spec = load_vehicle(path)
    assert spec.truck_b.e_d == pytest.approx(1.002)
    assert spec.link_length == 1.2 and spec.rotary_bias_b == 0.01
    again = tmp_path / "again.toml"
    spec.save(again)
    assert load_vehicle(again) == spec


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("link_length = 1.5\n", r"vehicle\.toml:2: link_length must lie strictly between"),
        ("rotary_bits = 0\n", r"rotary_bits must be a whole number in \[1, 32\]"),
        ("wheel_size = 1\n", r"vehicle\.toml:2: unknown vehicle field 'wheel_size'"),
        ("linear_bias = nan\n", r"vehicle\.toml:2: linear_bias must be finite"),
    ],
)
def test_bad_vehicle_files_name_field_and_line(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "vehicle.toml"
    path.write_text("[vehicle]\n" + text, encoding="utf-8")
    with pytest.raises(SpecError, match=message):
        load_vehicle(path)


def test_readings_are_quantised_and_biased() -> None:
    spec = VehicleSpec(PRESETS["labmate"], PRESETS["labmate"], rotary_bias_b=math.radians(1.0))
    rng = np.random.default_rng(3)
    poses = np.zeros((50, 2, 3))
    poses[:, 0, :2] = rng.uniform(-0.05, 0.05, (50, 2)) + np.array([1.0, 0.0])
    poses[:, :, 2] = rng.uniform(-0.3, 0.3, (50, 2))
    reading = link_readings(spec, poses)
    q, r = spec.rotary_resolution, spec.linear_resolution
    np.testing.assert_allclose(reading.psi / q, np.round(reading.psi / q), atol=1e-9)
    np.testing.assert_allclose(reading.length / r, np.round(reading.length / r), atol=1e-6)
    _, psi = link_angles(poses)
    assert np.all(np.abs(reading.psi[:, 0] - psi[:, 0]) <= q / 2 + 1e-12)
    # The bias of encoder B shifts its readings by 1° (within one count).
    assert np.all(np.abs(reading.psi[:, 1] - psi[:, 1] - math.radians(1.0)) <= q / 2 + 1e-12)
    true_length = np.hypot(*(poses[:, 0, :2] - poses[:, 1, :2]).T)
    assert np.all(np.abs(reading.length - true_length) <= r / 2 + 1e-12)


def test_error_sources_in_the_readings() -> None:
    """Eccentricity shifts the length by −e·sin ψ_B; jitter moves the counts (and needs a
    generator: every random draw flows from one); the paper's magnitudes load as spec
    fields, and out-of-range values are refused with the field's name."""
    poses = np.zeros((1, 2, 3))
    poses[0, 0, :2] = (1.0, 0.0)
    poses[0, 1, 2] = 0.3  # ψ_B = 0.3 rad
    plain = VehicleSpec(PRESETS["labmate"], PRESETS["labmate"], linear_resolution=1e-6)
    eccentric = dataclasses.replace(plain, linear_eccentricity=0.002)
    shift = link_readings(eccentric, poses).length - link_readings(plain, poses).length
    assert shift[0] == pytest.approx(-0.002 * math.sin(0.3), abs=2e-6)
    jittery = dataclasses.replace(plain, rotary_jitter=math.radians(0.5))
    with pytest.raises(ValueError, match="rng"):
        link_readings(jittery, poses)
    draws = {
        float(link_readings(jittery, poses, np.random.default_rng(k)).psi[0, 1]) for k in range(20)
    }
    assert len(draws) > 1  # the count moves with the jitter
    same = [link_readings(jittery, poses, np.random.default_rng(7)).psi for _ in range(2)]
    np.testing.assert_array_equal(*same)
    with_errors = dataclasses.replace(CLAPPER, **PAPER_ERRORS)  # type: ignore[arg-type]
    assert with_errors.linear_bias == 0.002 and with_errors.read_skew < with_errors.sample_period
    for field, value in (("rotary_jitter", -0.1), ("read_skew", 0.05)):
        with pytest.raises(SpecError, match=field):
            dataclasses.replace(CLAPPER, **{field: value})  # type: ignore[arg-type]


def test_read_skew_shows_the_trucks_where_they_were() -> None:
    """Link encoders read ``read_skew`` before the wheels: a truck turning at a steady rate
    shows ψ behind the truth by rate × skew (to within a count)."""
    from odomgym.vehicle.paths import circle_path
    from odomgym.vehicle.trial import VehicleTrial

    spec = dataclasses.replace(CLAPPER, rotary_bits=24, read_skew=0.02)
    trial = VehicleTrial(spec, FLOORS["smooth"], circle_path(direction="ccw"))
    for _ in range(200):
        before = trial.truth.copy()
        trial.step()
    f = 0.02 / spec.sample_period
    where = trial.truth + f * (before - trial.truth)  # positions and headings, 20 ms ago
    _, expected = link_angles(where)
    np.testing.assert_allclose(trial.reading.psi, expected, atol=spec.rotary_resolution)
    _, now = link_angles(trial.truth)
    assert np.all(np.abs(trial.reading.psi - now) > 100 * spec.rotary_resolution)


def _two_trucks(rates_a: float, rates_b: float, steps: int) -> tuple[World, list[float]]:
    robot = PRESETS["labmate"].ideal()
    world = World([robot, robot], FLOORS["smooth"], dt=0.04, links=[(0, 1, 0.9, 1.1)])
    world.reset(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    distances = []
    for _ in range(steps):
        world.step(np.array([[rates_a, rates_a], [rates_b, rates_b]]))
        distances.append(float(np.hypot(*(world.pose[0, :2] - world.pose[1, :2]))))
    return world, distances


def test_linkage_is_force_free_inside_its_range() -> None:
    # Both trucks at the same speed: the centre distance stays 1 m and the link passes nothing.
    world, distances = _two_trucks(4.0, 4.0, 100)
    assert max(abs(d - 1.0) for d in distances) < 1e-9
    assert np.all(world.link_forces() == 0.0)


def test_linkage_stops_the_trucks_at_the_end_of_its_range() -> None:
    # Truck A drives away from a truck B that is told to stand still: the bearing's end stop
    # catches it at 1.1 m and A drags B, whose braked wheels slide. Chipmunk sees the violation
    # one step late, so the stop may overshoot by one step of travel (0.3 m/s × 40 ms) before
    # it pulls back.
    world, distances = _two_trucks(4.0, 0.0, 150)
    assert distances[10] < 1.1  # free at first
    assert max(distances) < 1.1 + 0.3 * 0.04
    assert distances[-1] == pytest.approx(1.1, abs=1e-4)
    # Steady drag: the link carries exactly B's sliding friction, μ·m·g·(drive load fraction).
    truck = PRESETS["labmate"]
    friction = FLOORS["smooth"].friction * truck.mass * 9.81 * truck.drive_load_fraction
    assert world.link_forces()[0] == pytest.approx(friction, rel=0.01)


def test_links_are_checked() -> None:
    robot = PRESETS["labmate"]
    with pytest.raises(ValueError, match="two different robots"):
        World([robot, robot], links=[(0, 0, 0.9, 1.1)])
    with pytest.raises(ValueError, match="min < max"):
        World([robot, robot], links=[(0, 1, 1.1, 0.9)])


def test_errors_inside_an_inline_truck_name_the_truck_and_its_line(tmp_path: Path) -> None:
    path = tmp_path / "vehicle.toml"
    path.write_text(
        '[vehicle]\nname = "x"\ntruck_a = "labmate"\n\n[vehicle.truck_b]\nwheel_diameter = 0.15\n'
        "wheelbase = -0.34\nticks_per_rev = 2048\n",
        encoding="utf-8",
    )
    with pytest.raises(
        SpecError, match=r"vehicle\.toml:7: truck_b\.wheelbase must lie in \[0\.02, 5\.0\]"
    ):
        load_vehicle(path)
    path.write_text('[vehicle]\ntruck_b = "labmat"\n', encoding="utf-8")
    with pytest.raises(SpecError, match=r"vehicle\.toml:2: truck_b: unknown robot preset 'labmat'"):
        load_vehicle(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("sample_period = 1e-9\n", r"sample_period must lie in \[0.001, 1.0\]"),
        ("rotary_bias_a = 5.0\n", r"rotary_bias_a must lie in \[-0.5, 0.5\]"),  # degrees?
        ("linear_bias = -2.0\n", r"linear_bias must lie in \[-0.1, 0.1\]"),  # millimetres?
    ],
)
def test_values_outside_what_a_vehicle_can_be_are_refused(
    tmp_path: Path, text: str, message: str
) -> None:
    path = tmp_path / "vehicle.toml"
    path.write_text("[vehicle]\n" + text, encoding="utf-8")
    with pytest.raises(SpecError, match=message):
        load_vehicle(path)


def test_a_vehicle_key_that_is_not_a_table_is_one_error(tmp_path: Path) -> None:
    path = tmp_path / "vehicle.toml"
    path.write_text('vehicle = "clapper"\n', encoding="utf-8")
    with pytest.raises(SpecError, match=r"vehicle must be a table"):
        load_vehicle(path)

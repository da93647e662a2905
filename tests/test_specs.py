"""Issue #2 must-pass 6 (specs): bad input gives a clear error naming the field, file and line."""

from __future__ import annotations

import dataclasses
import math
import typing
from pathlib import Path

import pytest

from odomgym.errors import SpecError
from odomgym.floor import FloorSpec, load_floor
from odomgym.odometry.calibration import Calibration, load_calibration
from odomgym.robot import PRESETS, RobotSpec, load_robot


def test_minimal_robot_toml_loads(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    path.write_text("wheel_diameter = 0.084\nwheelbase = 0.2\nticks_per_rev = 2796.8\n")
    robot = load_robot(path)
    assert robot.wheel_diameter == 0.084
    assert robot.e_d == 1.0 and robot.e_b == 1.0 and robot.e_s == 1.0


@pytest.mark.parametrize(
    ("kind", "load", "inside"),
    [
        ("robot", load_robot, "wheel_diameter = 0.33\nwheelbase = 0.583\nticks_per_rev = 4096\n"),
        ("floor", load_floor, "friction = 0.8\n"),
        ("calibration", load_calibration, "c_left = 1.0\nc_right = 1.0\n"),
    ],
)
def test_keys_above_the_table_header_are_refused_not_ignored(
    kind: str, load: typing.Any, inside: str, tmp_path: Path
) -> None:
    """A skid-steer robot's ``axle_spacing`` written above ``[robot]`` was ignored (the page
    said so), and the robot became a differential-drive one without a word: keys outside the
    table are now an error naming the first and its line; other tables stay allowed."""
    path = tmp_path / f"{kind}.toml"
    path.write_text(f"# a {kind}\naxle_spacing = 0.498\nlabel = 'x'\n[{kind}]\n{inside}")
    with pytest.raises(SpecError) as caught:
        load(path)
    message = str(caught.value)
    assert message.startswith(f"{path}:2: key(s) 'axle_spacing', 'label' sit outside the [{kind}]")
    assert caught.value.field == "axle_spacing"
    path.write_text(f"[notes]\nlabel = 'x'\n[[runs]]\nn = 1\n[{kind}]\n{inside}")
    load(path)  # other tables (and arrays of tables) beside it are the file's own business


def test_a_robots_effects_table_outside_robot_is_refused_and_a_bom_is_read(
    tmp_path: Path,
) -> None:
    """``[effects.backlash]`` beside ``[robot]`` (meant as ``[robot.effects.backlash]``) was
    ignored without a word, even with a negative angle; a byte-order mark, which Windows
    editors write and the CSV readers accept, was "malformed TOML: Invalid statement"."""
    robot = "[robot]\nwheel_diameter = 0.1\nwheelbase = 0.3\nticks_per_rev = 500\n"
    path = tmp_path / "robot.toml"
    path.write_text(robot + "\n[effects.backlash]\nangle = -1.0\n")
    with pytest.raises(SpecError) as caught:
        load_robot(path)
    assert str(caught.value).startswith(f"{path}:6: the table [effects…] sits outside [robot]")
    assert caught.value.field == "effects"
    path.write_bytes(b"\xef\xbb\xbf" + robot.encode())
    assert load_robot(path).wheelbase == 0.3


def test_robot_toml_round_trip(tmp_path: Path) -> None:
    robot = PRESETS["labmate"].with_errors(1.003, 0.98, 1.01)
    path = tmp_path / "lm.toml"
    robot.save(path)
    again = load_robot(path)
    assert again == robot
    assert again.e_d == pytest.approx(1.003) and again.e_b == pytest.approx(0.98)


def test_with_errors_follows_eqs_6_31_6_32() -> None:
    robot = PRESETS["navbot"].with_errors(1.01, 1.0, 1.02)
    mean = 1.02 * robot.wheel_diameter
    assert robot.true_left_diameter == pytest.approx(2 / (1.01 + 1) * mean)
    assert robot.true_right_diameter == pytest.approx(2 / (1 / 1.01 + 1) * mean)
    assert robot.e_s == pytest.approx(1.02)


@pytest.mark.parametrize(
    ("text", "field", "line"),
    [
        ("wheel_diameter = 0.1\nwheelbase = -0.3\nticks_per_rev = 100\n", "wheelbase", 2),
        ("wheel_diameter = 0.1\nwheelbase = 0.3\nticks_per_rev = nan\n", "ticks_per_rev", 3),
        ("wheel_diameter = 0.1\nwheelbase = 0.3\nticks_per_rev = 100\nmass = 0\n", "mass", 4),
        ("wheel_diameter = 0.1\nwheelbase = 0.3\nticks_per_rev = 100\nwheels = 3\n", "wheels", 4),
        ("wheel_diameter = 0.1\nwheelbase = 0.3\nticks_per_rev = 100\ne_d = -1\n", "e_d", 4),
    ],
)
def test_bad_robot_field_names_field_file_and_line(
    tmp_path: Path, text: str, field: str, line: int
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SpecError) as info:
        load_robot(path)
    assert info.value.field == field
    assert f"{path}:{line}" in str(info.value)
    assert field in str(info.value)


def test_missing_required_field(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("wheel_diameter = 0.1\nwheelbase = 0.3\n")
    with pytest.raises(SpecError, match="ticks_per_rev"):
        load_robot(path)


def test_malformed_toml_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text("wheel_diameter = 0.1\nwheelbase = = 0.3\n")
    with pytest.raises(SpecError) as info:
        load_robot(path)
    assert str(path) in str(info.value)
    assert "line 2" in str(info.value)


def test_unknown_preset() -> None:
    with pytest.raises(SpecError, match=r"unknown robot preset 'lab-mate'.*labmate"):
        load_robot("lab-mate")
    with pytest.raises(SpecError, match="unknown floor"):
        load_floor("icy")


DERIVED = ("true_left_diameter", "true_right_diameter", "true_wheelbase", "mass")
DERIVED += ("chassis_length", "chassis_width")


def test_robot_optional_parameters_are_honestly_typed_and_resolved() -> None:
    """The true parameters and the chassis are ``float | None`` arguments (None: derive from
    the nominal ones) but always floats once the spec exists, in attributes and TOML."""
    arguments = typing.get_type_hints(RobotSpec.__init__)
    fields = {f.name: f.type for f in dataclasses.fields(RobotSpec)}
    for name in DERIVED:
        assert arguments[name] == float | None, name
        assert fields[name] == "float", name
    robot = RobotSpec(wheel_diameter=0.1, wheelbase=0.3, ticks_per_rev=100, true_wheelbase=None)
    assert (robot.true_left_diameter, robot.true_right_diameter, robot.true_wheelbase) == (
        0.1,
        0.1,
        0.3,
    )
    assert robot.chassis_length == robot.chassis_width == pytest.approx(1.3 * 0.3)
    assert robot.mass == pytest.approx(60.0 * (1.3 * 0.3) ** 2)
    assert all(isinstance(robot.to_dict()[name], float) for name in DERIVED)
    assert RobotSpec.from_dict(robot.to_dict()) == robot
    widened = dataclasses.replace(robot, true_wheelbase=0.31)
    assert widened.true_wheelbase == 0.31 and widened.e_b == pytest.approx(0.31 / 0.3)


@pytest.mark.parametrize("value", [0.0, -1.0, math.nan, math.inf])
def test_non_positive_or_nan_parameters_raise(value: float) -> None:
    with pytest.raises(SpecError, match="wheelbase"):
        RobotSpec(wheel_diameter=0.1, wheelbase=value, ticks_per_rev=100)
    with pytest.raises(SpecError, match="friction"):
        FloorSpec(friction=value)
    with pytest.raises(SpecError, match="c_left"):
        Calibration(c_left=value)


def test_floor_toml_with_bumps(tmp_path: Path) -> None:
    path = tmp_path / "floor.toml"
    path.write_text(
        "[floor]\nfriction = 0.6\n\n[[floor.bumps]]\nx = 1.0\ny = -0.17\ndiameter = 0.01\n"
        "\n[[floor.bumps]]\nx = 2.0\ny = 0.0\ndiameter = -0.01\n"
    )
    with pytest.raises(SpecError) as info:
        load_floor(path)
    assert "bumps[1]" in str(info.value) and "diameter" in str(info.value)
    assert f"{path}:" in str(info.value)
    path.write_text("[floor]\nfriction = 0.6\n\n[[floor.bumps]]\nx = 1.0\ny = -0.17\n")
    floor = load_floor(path)
    assert floor.friction == 0.6 and floor.bumps[0].x == 1.0
    floor.save(tmp_path / "again.toml")
    assert load_floor(tmp_path / "again.toml") == floor


def test_calibration_toml_and_ros2_mapping(tmp_path: Path) -> None:
    calibration = Calibration.from_errors(e_d=1.002, e_b=0.99, e_s=1.01)
    path = tmp_path / "calib.toml"
    calibration.save(path)
    assert load_calibration(path) == calibration
    ros = calibration.ros2_parameters()
    assert ros["wheel_separation_multiplier"] == pytest.approx(0.99)
    assert ros["right_wheel_radius_multiplier"] / ros["left_wheel_radius_multiplier"] == (
        pytest.approx(1.002)
    )
    path.write_text("[calibration]\nc_left = 1.0\nc_right = -2\n")
    with pytest.raises(SpecError) as info:
        load_calibration(path)
    assert f"{path}:3" in str(info.value)


@pytest.mark.parametrize(
    ("argv", "field"),
    [
        (["run", "square", "--side", "1e9"], "side"),
        (["run", "straight", "--distance", "1e7"], "distance"),
    ],
)
def test_a_run_longer_than_a_kilometre_is_refused_in_one_line(
    argv: list[str], field: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``run square --side 1e9`` asked numpy for 87 TiB to record the run (ArrayMemoryError
    traceback); one run now drives at most MAX_RUN_LENGTH = 1 km (and turns at most 10
    revolutions), checked where routes and experiments are made."""
    from odomgym.cli import main
    from odomgym.lab.experiment import Experiment
    from odomgym.sim.routes import MAX_RUN_LENGTH, spin_route, square_route

    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"odomgym: error: {field} "), err
    square_route(MAX_RUN_LENGTH / 4)  # the limit itself is allowed
    with pytest.raises(SpecError, match=r"0\.001 to 62\.8319 rad"):
        spin_route(100.0)
    with pytest.raises(SpecError) as caught:
        Experiment("circular", "ccw", runs=1, size=200.0, laps=1.0)  # 1257 m around
    assert caught.value.field == "size"

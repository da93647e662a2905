"""Property-based tests (hypothesis): whatever a user feeds odomgym — spec files, command-line
numbers, env actions, measured logs — it either works, with finite results inside the declared
spaces, or raises odomgym's own one-line error naming the field (and, for files, the file):
never a traceback from numpy, pymunk, numba, tomllib, csv, rosbags or SQLite.

Profiles: ``ci`` (the default, 1000 examples per property) and ``soak`` (set
``ODOMGYM_FUZZ_EXAMPLES``; ``python benchmarks/bench_fuzz.py`` runs it and prints the counts).
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import tomli_w

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, event, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import odomgym  # noqa: E402
from odomgym.errors import SpecError  # noqa: E402

EXAMPLES = int(os.environ.get("ODOMGYM_FUZZ_EXAMPLES", "1000"))
settings.register_profile(
    "fuzz",
    max_examples=EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    # CI runs the same examples every time; a larger profile draws new ones on every run.
    derandomize="ODOMGYM_FUZZ_EXAMPLES" not in os.environ,
)
settings.load_profile("fuzz")

SCRATCH = Path(tempfile.mkdtemp(prefix="odomgym-fuzz-"))

# Values a spec field may be given by mistake (or on purpose).
ODD_FLOATS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, 1e300, -1.0, 1.0, 2.0**53]),
)
VALUES = st.one_of(
    ODD_FLOATS,
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.booleans(),
    st.text(max_size=12),
    st.lists(st.floats(allow_nan=False, width=32), max_size=3),
)


def _write(name: str, data: dict[str, Any] | bytes) -> Path:
    path = SCRATCH / name
    if isinstance(data, bytes):
        path.write_bytes(data)
    else:
        path.write_text(tomli_w.dumps(data), encoding="utf-8")
    return path


def _one_line(exc: SpecError, path: Path | None = None) -> None:
    message = str(exc)
    assert message and "\n" not in message.strip(), message
    if path is not None:
        assert str(path) in message or path.name in message, message


def _finite(values: dict[str, Any]) -> None:
    for key, value in values.items():
        if isinstance(value, float):
            assert math.isfinite(value), (key, value)


def _mutated(base: dict[str, Any], keys: list[str]) -> st.SearchStrategy[dict[str, Any]]:
    """``base`` with some of ``keys`` given odd values, some removed, maybe an unknown key."""
    return st.builds(
        lambda changes, removed, extra: {
            **{k: v for k, v in base.items() if k not in removed},
            **changes,
            **extra,
        },
        st.dictionaries(st.sampled_from(keys), VALUES, max_size=4),
        st.sets(st.sampled_from(keys), max_size=2),
        st.dictionaries(st.sampled_from(["colour", "wheel_diam", "b"]), VALUES, max_size=1),
    )


ROBOT = odomgym.PRESETS["labmate"].to_dict()
ROBOT_KEYS = [k for k in ROBOT if k not in ("name", "source", "effects")]


@given(_mutated(ROBOT, ROBOT_KEYS))
def test_robot_specs(fields: dict[str, Any]) -> None:
    path = _write("robot.toml", {"robot": fields})
    try:
        robot = odomgym.load_robot(path)
    except SpecError as exc:
        _one_line(exc, path)
        return
    _finite(robot.to_dict())


FLOOR = {"friction": 0.8, "roughness": 0.0004, "name": "f"}


@given(
    _mutated(FLOOR, ["friction", "roughness"]),
    st.lists(
        st.fixed_dictionaries(
            {"x": ODD_FLOATS, "y": ODD_FLOATS, "angle": ODD_FLOATS},
            optional={"diameter": VALUES, "length": VALUES},
        ),
        max_size=2,
    ),
)
def test_floor_specs(fields: dict[str, Any], bumps: list[dict[str, Any]]) -> None:
    data = {"floor": {**fields, **({"bumps": bumps} if bumps else {})}}
    try:
        path = _write("floor.toml", data)
    except (ValueError, TypeError):  # tomli_w cannot write it: not a TOML a user can have
        return
    try:
        odomgym.load_floor(str(path))
    except SpecError as exc:
        _one_line(exc, path)


CALIBRATION = {"c_left": 1.0, "c_right": 1.0, "wheelbase_scale": 1.0, "distance_scale": 1.0}


@given(_mutated(CALIBRATION, list(CALIBRATION)))
def test_calibration_specs(fields: dict[str, Any]) -> None:
    path = _write("calibration.toml", {"calibration": fields})
    try:
        calibration = odomgym.load_calibration(path)
    except SpecError as exc:
        _one_line(exc, path)
        return
    _finite(calibration.to_dict())


VEHICLE = {"trucks": ["labmate", "labmate"], "link_length": 1.0}


@given(
    _mutated(
        VEHICLE,
        ["link_length", "link_min", "link_max", "sample_period", "linear_bias", "trucks"],
    )
)
def test_vehicle_specs(fields: dict[str, Any]) -> None:
    from odomgym.vehicle.spec import load_vehicle

    try:
        path = _write("vehicle.toml", {"vehicle": fields})
    except (ValueError, TypeError):
        return
    try:
        load_vehicle(str(path))
    except SpecError as exc:
        _one_line(exc, path)


@given(st.binary(max_size=200))
def test_spec_files_of_garbage(data: bytes) -> None:
    path = _write("garbage.toml", data)
    for load in (odomgym.load_robot, odomgym.load_calibration, odomgym.load_floor):
        try:
            load(str(path))
        except SpecError as exc:
            _one_line(exc, path)


@given(st.text(max_size=20))
def test_command_line_numbers(text: str) -> None:
    from odomgym.cli import _count, _positive, _seed

    for parse in (_count, _positive, _seed):
        try:
            value = parse(text)
        except argparse.ArgumentTypeError as exc:
            assert str(exc) and "\n" not in str(exc)
            continue
        assert math.isfinite(value)
        assert value > 0 or (parse is _seed and value >= 0)


ENV = gym.make("UMBmarkSquare-v0", robot="labmate", floor="concrete")
ENV.reset(seed=0)

ACTIONS = st.one_of(
    st.lists(ODD_FLOATS, min_size=2, max_size=2).map(np.array),
    st.lists(ODD_FLOATS, min_size=0, max_size=4).map(np.array),
    st.lists(st.integers(-5, 5), min_size=2, max_size=2).map(np.array),
    st.just(np.zeros((2, 2))),
    st.sampled_from([None, "go", 1.0, [0.5, "x"]]),
)


@given(ACTIONS)
def test_env_actions(action: Any) -> None:
    try:
        obs, reward, terminated, truncated, _ = ENV.step(action)
    except (ValueError, TypeError) as exc:
        assert str(exc) and "\n" not in str(exc).strip(), exc
        return
    assert ENV.observation_space.contains(obs)
    assert math.isfinite(reward)
    if terminated or truncated:
        ENV.reset(seed=1)


@given(st.one_of(VALUES, st.just(np.array(3)), st.just(np.array([1, 2])), st.none()))
def test_selfcal_actions(action: Any) -> None:
    from odomgym.envs.selfcal import menu_index

    try:
        index = menu_index(action)
    except SpecError as exc:
        assert exc.field == "action"
        _one_line(exc)
        return
    assert 0 <= index < 10


CSV = (SCRATCH / "base.csv").as_posix()


def _base_csv() -> list[str]:
    if not Path(CSV).exists():
        from odomgym.data.native import write_native
        from odomgym.floor import FLOORS
        from odomgym.sim.route_runs import simulate_runs
        from odomgym.sim.routes import square_route

        runs, _ = simulate_runs(
            odomgym.PRESETS["labmate"], FLOORS["smooth"], square_route(0.5, "cw")
        )
        write_native(Path(CSV), runs)
    return Path(CSV).read_text(encoding="utf-8").splitlines()


def _mutate_csv(lines: list[str], edits: list[tuple[int, int, str]]) -> str:
    out = list(lines)
    for kind, where, text in edits:
        if not out:
            break
        k = where % len(out)
        if kind == 0:  # truncate the file here
            out = out[:k]
        elif kind == 1:  # drop a line
            del out[k]
        elif kind == 2:  # replace one cell
            cells = out[k].split(",")
            cells[where % len(cells)] = text
            out[k] = ",".join(cells)
        elif kind == 3:  # drop a column everywhere
            out = [
                ",".join(c for i, c in enumerate(line.split(",")) if i != where % 8) for line in out
            ]
        elif kind == 4:  # an extra column
            out = [line + "," + text for line in out]
        elif kind == 5:  # repeat a line (repeated time)
            out.insert(k, out[k])
        elif kind == 6:  # swap two lines (time going backwards)
            j = (k + 1) % len(out)
            out[k], out[j] = out[j], out[k]
    return "\n".join(out) + "\n"


CELLS = st.sampled_from(["", "nan", "inf", "-1", "1e999", "abc", "0.5", "99999999999999999999"])


@given(
    st.lists(st.tuples(st.integers(0, 6), st.integers(0, 10_000), CELLS), max_size=4),
    st.sampled_from(["utf-8", "latin-1", "utf-16"]),
    st.binary(max_size=8),
)
def test_measured_logs(edits: list[tuple[int, int, str]], encoding: str, junk: bytes) -> None:
    from odomgym.data.native import read_native

    text = _mutate_csv(_base_csv(), edits)
    path = SCRATCH / "log.csv"
    path.write_bytes(text.encode(encoding, errors="replace") + junk)
    try:
        runs = read_native(path, robot=odomgym.PRESETS["labmate"])
    except SpecError as exc:
        _one_line(exc, path)
        return
    for run in runs:
        assert np.all(np.isfinite(run.time)) and np.all(np.diff(run.time) > 0)


def test_regression_a_spec_file_that_is_not_utf8(tmp_path: Path) -> None:
    """Found by test_spec_files_of_garbage: a byte 0x80 raised UnicodeDecodeError from
    pathlib; now a one-line SpecError naming the file and the line."""
    path = tmp_path / "robot.toml"
    path.write_bytes(b'[robot]\nname = "caf\xe9"\n')
    with pytest.raises(SpecError) as caught:
        odomgym.load_robot(path)
    message = str(caught.value)
    assert str(path) in message and "line 2: not UTF-8 text (byte 0xe9)" in message


REQUIRED = ("wheel_diameter", "wheelbase", "ticks_per_rev")  # Python's own TypeError if absent


@given(
    _mutated(ROBOT, ROBOT_KEYS).map(
        lambda d: (
            {k: d.get(k, ROBOT[k]) for k in REQUIRED} | {k: v for k, v in d.items() if k in ROBOT}
        )
    )
)
def test_robot_constructor(fields: dict[str, Any]) -> None:
    from odomgym.robot import RobotSpec

    try:
        robot = RobotSpec(**fields)
    except SpecError as exc:
        assert exc.field is not None
        _one_line(exc)
        return
    _finite(robot.to_dict())


@given(
    _mutated(CALIBRATION, list(CALIBRATION)).map(
        lambda d: {k: v for k, v in d.items() if k in CALIBRATION}
    ),
    _mutated(FLOOR, ["friction", "roughness"]).map(
        lambda d: {k: v for k, v in d.items() if k in ("friction", "roughness")}
    ),
)
def test_calibration_and_floor_constructors(cal: dict[str, Any], floor: dict[str, Any]) -> None:
    from odomgym.floor import FloorSpec
    from odomgym.odometry.calibration import Calibration

    for build, fields in ((Calibration, cal), (FloorSpec, floor)):
        try:
            build(**fields)
        except SpecError as exc:
            assert exc.field is not None
            _one_line(exc)


def _session_copy() -> Path:
    """A scratch copy of a shipped OptiOdom session (square, 6 runs)."""
    import shutil

    from odomgym.data import resolve_data

    target = SCRATCH / "optiodom" / "square" / "230620202042"
    if not target.exists():
        shutil.copytree(resolve_data("optiodom:square/230620202042", session=True), target)
    return target


@given(
    st.lists(st.tuples(st.integers(0, 6), st.integers(0, 10_000), CELLS), max_size=3),
    st.lists(st.tuples(st.integers(0, 6), st.integers(0, 10_000), CELLS), max_size=3),
    st.sampled_from(["utf-8", "latin-1", "utf-16"]),
)
@pytest.mark.slow
def test_optiodom_sessions(
    meta_edits: list[tuple[int, int, str]], run_edits: list[tuple[int, int, str]], encoding: str
) -> None:
    """The OptiOdom reader on a session whose metadata and first run file are mutated."""
    from odomgym.data import read_session

    folder = _session_copy()
    meta = folder / "230620202042_metadata.csv"
    run = folder / "230620202042_run-01.csv"
    originals = {path: path.read_bytes() for path in (meta, run)}
    try:
        for path, edits in ((meta, meta_edits), (run, run_edits)):
            lines = originals[path].decode("utf-8").splitlines()
            path.write_bytes(_mutate_csv(lines, edits).encode(encoding, errors="replace"))
        try:
            session = read_session(folder)
        except SpecError as exc:
            _one_line(exc)
            assert folder.name in str(exc), exc
            return
        for one in session.runs:
            assert np.all(np.isfinite(one.time)) and np.all(np.diff(one.time) > 0)
    finally:
        for path, data in originals.items():
            path.write_bytes(data)


def test_regression_a_huge_wheelbase_is_named_not_overflowed() -> None:
    """Found by test_robot_constructor: RobotSpec(wheelbase=1e154) overflowed computing the
    default mass (OverflowError); now the wheelbase is named."""
    from odomgym.robot import RobotSpec

    with pytest.raises(SpecError) as caught:
        RobotSpec(wheel_diameter=0.15, wheelbase=1e154, ticks_per_rev=2048)
    assert caught.value.field == "wheelbase"


NUMBERS = st.one_of(
    st.sampled_from(["0", "-1", "nan", "inf", "-inf", "1e309", "1e-320", "abc", "", "3", "0.4"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
)


@given(NUMBERS, NUMBERS, NUMBERS, NUMBERS, st.sampled_from(["1", "0", "-5", "10", "x"]))
@pytest.mark.slow
def test_command_line_end_to_end(
    left: str, right: str, wheelbase: str, k: str, partitions: str
) -> None:
    """``odomgym covariance`` (the Chong & Kleeman closed forms) with arbitrary numbers: it
    prints its result (exit 0) or one error line (exit 2), never a traceback."""
    import contextlib
    import io

    from odomgym.cli import main

    out, err = io.StringIO(), io.StringIO()
    argv = [
        "covariance",
        "--left",
        left,
        "--right",
        right,
        "--wheelbase",
        wheelbase,
        "--kl",
        k,
        "--kr",
        k,
        "--partitions",
        partitions,
        "--json",
    ]
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse: an option's type refused the text
            code = int(exc.code or 0)
    if code == 0:
        assert "nan" not in out.getvalue().lower().replace("nan_", ""), out.getvalue()
    else:
        assert code == 2, (argv, err.getvalue())
        lines = [line for line in err.getvalue().splitlines() if line.strip()]
        assert lines and "Traceback" not in err.getvalue(), err.getvalue()
        assert lines[-1].startswith(("odomgym: error:", "odomgym covariance: error:")), lines


def test_regression_covariance_with_huge_numbers_is_one_line(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Found by test_command_line_end_to_end: ``covariance --right 1.34e154`` raised
    OverflowError; now exit 2 and one line."""
    from odomgym.cli import main

    argv = [
        "covariance",
        "--left",
        "0",
        "--right",
        "1.3407807929942597e+154",
        "--wheelbase",
        "3",
        "--kl",
        "0",
        "--kr",
        "0",
        "--partitions",
        "1",
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "too large for the closed forms" in err[0]
    # A turn that overflows (1e300 m over a 1e-10 m wheelbase) was "math domain error".
    argv = ["covariance", "--left=1e300", "--right=-1e300", "--wheelbase=1e-10", "--kl=0"]
    assert main([*argv, "--kr=0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "overflows a float: too large for the closed forms" in err[0], err


# ------------------------------------------------------------------------------- ROS 2 bags
# Bags are written with ``rosbags`` itself (as tests/test_data_rosbag2.py does), so every bag
# below is one a ROS 2 recorder could have produced, except where its bytes are damaged on
# purpose.
needs_rosbags = pytest.mark.skipif(
    importlib.util.find_spec("rosbags") is None, reason="needs rosbags: pip install odomgym[ros]"
)
JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
INT32S = "std_msgs/msg/Int32MultiArray"
INT64S = "std_msgs/msg/Int64MultiArray"
BAG_EPOCH = 1_700_000_000 * 10**9  # [ns]
BAG_STEP = 10_000_000  # one stamp step: 10 ms [ns]
BAG_ROBOT = odomgym.RobotSpec(wheel_diameter=0.1, wheelbase=0.3, ticks_per_rev=1000)
WHEELS = ("left_wheel_joint", "right_wheel_joint")
JOINT_NAMES = st.sampled_from(
    [WHEELS, WHEELS[::-1], (*WHEELS, "caster"), WHEELS[:1], ("arm",), ()]
)  # both wheels, swapped, with another joint, one wheel missing, another group, no names
BAG_FLOATS = st.one_of(
    st.floats(-10.0, 10.0),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -1.7e308, 1.7e308, 1e17, 0.0]),
    st.floats(),
)
COUNTS = st.one_of(
    st.integers(-1000, 1000),
    st.sampled_from([2**31 - 1, -(2**31), 2**62 - 1, 2**62, -(2**62), 2**63 - 1, -(2**63)]),
    st.integers(-(2**63), 2**63 - 1),
)
STAMPS = st.one_of(st.integers(0, 12), st.none())  # None: a zero stamp (the receive time counts)
BAG_EDITS = st.lists(
    st.tuples(
        st.sampled_from([0, 0, 1, 1, 2, 3, 4, 5, 6, 6, 7, 8, 9]),  # odd values (0, 1, 6) twice
        st.integers(0, 10_000),
        BAG_FLOATS,
        COUNTS,
        JOINT_NAMES,
        STAMPS,
    ),
    max_size=3,
)
BAG_LAYOUTS = st.sampled_from(
    ["ok"] * 8
    + ["no poses", "no wheels", "empty bag", "wheels are poses", "poses are joints"]
    + ["pose topic is the wheel topic", "read as the other kind"]
)


def _bag_streams(
    wheel_type: str, edits: list[tuple[Any, ...]]
) -> tuple[list[list[Any]], list[list[Any]]]:
    """Wheel messages [stamp, names, positions, counts] (6, in 10-ms steps 1, 3, … 11) and
    pose messages [stamp, x, y, qz, qw] (7, steps 0, 2, … 12) of a short drive, with ``edits``:
    (kind, where, odd float, odd count, joint names, stamp) as in :func:`_mutate_csv`."""
    wheels: list[list[Any]] = [
        [2 * k + 1, WHEELS, [0.3 * k, 0.35 * k], [2**31 - 250 + 100 * k, -5 + 120 * k]]
        for k in range(6)
    ]  # the left counter passes 2**31 (an Int32MultiArray wraps there)
    poses: list[list[Any]] = [
        [2 * j, 0.02 * j, -0.04 * j, math.sin(0.1 * j), math.cos(0.1 * j)] for j in range(7)
    ]  # every wheel sample lies between two poses: its pose is interpolated
    for kind, where, value, count, names, stamp in edits:
        stream = poses if kind in (1, 3, 9) else wheels
        if not stream:
            continue
        message = stream[where % len(stream)]
        if kind == 0 and message[2]:  # an odd joint position
            message[2] = list(message[2])
            message[2][where // 7 % len(message[2])] = value
        elif kind == 1:  # an odd x, y or quaternion
            message[1 + where // 13 % 4] = value
        elif kind in (2, 3):  # a repeated, backwards or zero stamp
            message[0] = stamp
        elif kind == 4:  # other joint names
            message[1] = names
        elif kind == 5:  # one position more than names
            message[2] = [*message[2], 0.0]
        elif kind == 6 and message[3]:  # an odd count
            message[3] = list(message[3])
            message[3][where // 7 % len(message[3])] = count
        elif kind == 7:  # too few or too many counts
            message[3] = [*message[3], count][: where // 7 % 4]
        elif kind in (8, 9):  # only 0, 1 or 2 messages
            del stream[where % 3 :]
    if wheel_type == INT32S:  # what an Int32MultiArray can hold
        for message in wheels:
            message[3] = [(v + 2**31) % 2**32 - 2**31 for v in message[3]]
    return wheels, poses


@functools.cache
def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _bag_header(types: Any, ns: int) -> Any:
    sec, nanosec = divmod(ns, 10**9)
    stamp = types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id="world")


def _bag_message(types: Any, msgtype: str, ns: int, values: tuple[Any, ...]) -> Any:
    """A ``msgtype`` message stamped ``ns`` from ``values``: (names, positions) for a
    JointState, counts for an Int*MultiArray, (x, y, qz, qw) for a pose."""
    if msgtype == JOINT_STATE:
        names, positions = values
        return types[msgtype](
            header=_bag_header(types, ns),
            name=list(names),
            position=np.asarray(positions, dtype=np.float64),
            velocity=np.zeros(0),
            effort=np.zeros(0),
        )
    if msgtype in (INT32S, INT64S):
        layout = types["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
        data = np.asarray(values, dtype=np.int32 if msgtype == INT32S else np.int64)
        return types[msgtype](layout=layout, data=data)
    x, y, z, w = values
    pose = types["geometry_msgs/msg/Pose"](
        position=types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
        orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=z, w=w),
    )
    if msgtype == POSE_STAMPED:
        return types[msgtype](header=_bag_header(types, ns), pose=pose)
    covariance = np.zeros(36)
    zero = types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return types[msgtype](
        header=_bag_header(types, ns),
        child_frame_id="base",
        pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=covariance),
        twist=types["geometry_msgs/msg/TwistWithCovariance"](
            twist=types["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
            covariance=covariance,
        ),
    )


def _write_bag(
    path: Path, topics: dict[str, tuple[str, list[tuple[int, Any]]]], storage: str
) -> Path:
    """Write ``{topic: (msgtype, [(receive ns, message), …])}`` as one bag folder at ``path``."""
    import shutil

    from bag_writer import write_bag
    from rosbags.rosbag2 import StoragePlugin

    if path.exists():
        shutil.rmtree(path)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    return write_bag(path, topics, plugin, _typestore())


def _stamp_ns(step: int | None) -> int:
    return 0 if step is None else BAG_EPOCH + step * BAG_STEP


def _received_ns(stream: int, k: int, step: int | None) -> int:
    """Receive time of message ``k`` of stream 0 (wheels) or 1 (poses) stamped ``step``: its
    stamp (the time of a message without header), or after every stamp for a zero stamp."""
    return _stamp_ns(step) or BAG_EPOCH + 10**9 * (1 + stream) + k * BAG_STEP


def _expected_wheels(
    wheel_type: str, messages: list[list[Any]]
) -> tuple[list[int], list[tuple[int, int]]]:
    """Wheel sample times [ns] and counts relative to the first as the reader documents them,
    in exact integers (what a correct reader returns; it may instead refuse the bag)."""
    rows: list[tuple[int, int, int]] = []
    for k, (step, names, positions, data) in enumerate(messages):
        ns = _received_ns(0, k, step)
        if wheel_type == JOINT_STATE:
            if not set(WHEELS) <= set(names):
                continue
            scale = BAG_ROBOT.ticks_per_rev / (2.0 * math.pi)
            left, right = (int(np.rint(positions[names.index(n)] * scale)) for n in WHEELS)
            rows.append((ns, left, right))
        else:
            rows.append((ns, data[0], data[1]))
    rows.sort(key=lambda row: row[0])
    if wheel_type == INT32S:  # a 32-bit counter that wraps is unwrapped
        unwrapped = rows[:1]
        for (ns, left, right), (_, l0, r0) in zip(rows[1:], rows, strict=False):
            steps = [(a - b + 2**31) % 2**32 - 2**31 for a, b in ((left, l0), (right, r0))]
            unwrapped.append((ns, unwrapped[-1][1] + steps[0], unwrapped[-1][2] + steps[1]))
        rows = unwrapped
    first = rows[0]
    return [r[0] for r in rows], [(r[1] - first[1], r[2] - first[2]) for r in rows]


def _message_values(msgtype: str, message: list[Any]) -> tuple[Any, ...]:
    """What a :func:`_bag_streams` message holds as a ``msgtype`` message; a stream written as
    another type (a wrong topic type) holds that type's plain message."""
    wheel = len(message) == 4
    if msgtype == JOINT_STATE:
        return (message[1], message[2]) if wheel else (WHEELS, [0.0, 0.0])
    if msgtype in (INT32S, INT64S):
        return tuple(message[3]) if wheel else (0, 0)
    return (0.0, 0.0, 0.0, 1.0) if wheel else tuple(message[1:])


def _write_streams(
    path: Path, streams: dict[str, tuple[str, list[list[Any]], int]], storage: str
) -> Path:
    """Write :func:`_bag_streams` messages as one bag: ``{topic: (msgtype, messages, stream)}``
    with stream 0 (wheels) or 1 (poses) for the receive times."""
    types = _typestore().types
    topics = {
        topic: (
            msgtype,
            [
                (
                    _received_ns(number, k, m[0]),
                    _bag_message(types, msgtype, _stamp_ns(m[0]), _message_values(msgtype, m)),
                )
                for k, m in enumerate(messages)
            ],
        )
        for topic, (msgtype, messages, number) in streams.items()
    }
    return _write_bag(path, topics, storage)


def _bag_of(
    wheel_type: str,
    edits: list[tuple[Any, ...]],
    storage: str = "mcap",
    path: Path = SCRATCH / "bags" / "square_cw",
) -> Path:
    """The bag at ``path`` of :func:`_bag_streams` (``wheel_type`` on /wheels, PoseStamped on
    /pose)."""
    wheels, poses = _bag_streams(wheel_type, edits)
    streams = {"/wheels": (wheel_type, wheels, 0), "/pose": (POSE_STAMPED, poses, 1)}
    return _write_streams(path, streams, storage)


# A bag write and read takes ~55 ms (rosbags builds its message decoders on every read_rosbag
# call), so 1000 bags would take a minute: a fifth of the examples, each a different bag.
@needs_rosbags
@settings(max_examples=max(EXAMPLES // 5, 1))
@given(
    st.sampled_from([JOINT_STATE, JOINT_STATE, INT32S, INT64S]),
    st.sampled_from([POSE_STAMPED, ODOMETRY]),
    BAG_EDITS,
    BAG_LAYOUTS,
    st.sampled_from(["mcap", "sqlite3"]),
)
@pytest.mark.slow
def test_rosbag_messages(
    wheel_type: str, pose_type: str, edits: list[tuple[Any, ...]], layout: str, storage: str
) -> None:
    """``read_rosbag`` on small bags with odd messages: NaN/inf/huge joint positions, counts and
    poses, repeated, backwards and zero stamps, missing joint names, 0-2 messages on a topic;
    and odd bags: a topic missing or of the wrong type, an empty bag."""
    from odomgym.data.rosbag2 import read_rosbag

    wheels, poses = _bag_streams(wheel_type, edits)
    streams = {
        "/wheels": (POSE_STAMPED if layout == "wheels are poses" else wheel_type, wheels, 0),
        "/pose": (JOINT_STATE if layout == "poses are joints" else pose_type, poses, 1),
    }
    missing = {"no poses": ["/pose"], "no wheels": ["/wheels"], "empty bag": list(streams)}
    for topic in missing.get(layout, []):
        del streams[topic]
    bag = _write_streams(SCRATCH / "bags" / "square_cw", streams, storage)
    joints = (wheel_type == JOINT_STATE) != (layout == "read as the other kind")
    options = {
        "pose_topic": "/wheels" if layout == "pose topic is the wheel topic" else "/pose",
        "joint_topic" if joints else "encoder_topic": "/wheels",
    }
    try:
        (run,) = read_rosbag(bag, robot=BAG_ROBOT, **options)
    except SpecError as exc:
        _one_line(exc, bag)
        event(f"refused: {str(exc).split(': ')[1][:25]}")
        return
    event("read")
    times, counts = _expected_wheels(wheel_type, wheels)
    assert run.time.dtype == np.float64 and run.counts.dtype == np.int64
    np.testing.assert_allclose(run.time, [(t - times[0]) * 1e-9 for t in times], atol=1e-12)
    assert np.all(np.diff(run.time) > 0)
    assert run.counts.tolist() == [list(c) for c in counts]
    pose_times = [_received_ns(1, k, m[0]) for k, m in enumerate(poses)]
    inside = np.array([min(pose_times) <= t <= max(pose_times) for t in times])
    # Wheel samples outside the pose stream (before it too: a tracker started late) are gaps.
    assert np.all(np.isfinite(run.true_pose[inside])), run.true_pose
    assert np.all(np.isnan(run.true_pose[~inside]))


@needs_rosbags
def test_regression_a_huge_joint_angle_is_refused_not_wrapped() -> None:
    """Found by test_rosbag_messages: a JointState position of 1e300 rad (1.6e302 counts) was
    cast to int64 unchecked, so the run's counts were -9223372036854775760 (only a numpy
    RuntimeWarning); now a one-line SpecError naming the wheel and the message's time."""
    from odomgym.data.rosbag2 import read_rosbag

    bag = _bag_of(JOINT_STATE, [(0, 1, 1e300, 0, WHEELS, 0)])  # message 1, left wheel
    with pytest.raises(SpecError, match=r"left wheel's count 1\.59155e\+302 in the mess") as caught:
        read_rosbag(bag, pose_topic="/pose", joint_topic="/wheels", robot=BAG_ROBOT)
    assert caught.value.field == "position"
    _one_line(caught.value, bag)


@needs_rosbags
def test_regression_int64_counts_beyond_2_to_the_62_are_refused() -> None:
    """Found by test_rosbag_messages in the soak profile (ODOMGYM_FUZZ_EXAMPLES=10000; CI's
    fixed examples miss it): an Int64MultiArray whose first message counts -2**63 on the left
    wheel wrapped around in ``counts - counts[0]`` (the next relative count was
    -9223372034707292310 instead of +9223372039002259306); now a SpecError, as the native
    reader's ``|counts| < 2**62`` rule."""
    from odomgym.data.rosbag2 import read_rosbag

    bag = _bag_of(INT64S, [(6, 0, 0.0, -(2**63), WHEELS, 0)])  # message 0, left count
    with pytest.raises(SpecError, match=r"left wheel's count -9\.22337e\+18 in the message at"):
        read_rosbag(bag, pose_topic="/pose", encoder_topic="/wheels", robot=BAG_ROBOT)


@needs_rosbags
def test_regression_an_interpolated_pose_that_overflows_is_refused() -> None:
    """Found by test_rosbag_messages: a PoseStamped x of -1.7e308 m next to 0.02 m made the
    interpolated pose of the first wheel sample x = -inf (np.interp's slope overflows), a
    non-finite start pose inside the pose stream; now a one-line SpecError naming the
    topic."""
    from odomgym.data.rosbag2 import read_rosbag

    bag = _bag_of(JOINT_STATE, [(1, 0, -1.7e308, 0, WHEELS, 0)])  # pose 0's x
    with pytest.raises(SpecError, match=r"/pose pose interpolated at 1700000000\.010000000 s"):
        read_rosbag(bag, pose_topic="/pose", joint_topic="/wheels", robot=BAG_ROBOT)


def _base_bag(storage: str) -> Path:
    """A valid bag (JointState wheels, PoseStamped poses) of ``storage``, written once."""
    folder = SCRATCH / "base-bags" / storage / "square_cw"
    if not folder.exists():
        _bag_of(JOINT_STATE, [], storage, folder)
    return folder


def _damaged_bag(
    storage: str, data_file: bool, kind: int, where: int, junk: bytes, text: str
) -> tuple[Path, Path]:
    """A copy of the valid ``storage`` bag whose storage file (``data_file``) or metadata.yaml
    is damaged: ``kind`` 0 truncated at ``where``, 1 ``junk`` written over it there, 2 emptied,
    3 ``junk`` inserted there (storage) or one YAML line's value replaced by ``text``, 4
    deleted. Returns the bag folder and its storage file."""
    import shutil

    bag = SCRATCH / "damaged" / "square_cw"
    if bag.exists():
        shutil.rmtree(bag)
    shutil.copytree(_base_bag(storage), bag)
    (stored,) = (p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
    target = stored if data_file else bag / "metadata.yaml"
    data = target.read_bytes()
    k = where % (len(data) + 1)
    if kind == 0:  # truncated
        target.write_bytes(data[:k])
    elif kind == 1:  # random bytes written over
        target.write_bytes(data[:k] + junk + data[k + len(junk) :])
    elif kind == 2:  # emptied
        target.write_bytes(b"")
    elif kind == 3 and data_file:  # bytes inserted
        target.write_bytes(data[:k] + junk + data[k:])
    elif kind == 3:  # one YAML line's value replaced
        lines = data.split(b"\n")
        n = where % len(lines)
        lines[n] = lines[n].split(b":")[0] + b": " + text.encode()
        target.write_bytes(b"\n".join(lines))
    else:  # deleted
        target.unlink()
    return bag, stored


YAML_VALUES = st.sampled_from(
    ["", "-1", "nan", "abc", "[]", "{", "99999999999999999999", "null", "'", "- x", "*a", "~"]
)


@needs_rosbags
@given(
    st.sampled_from(["mcap", "sqlite3"]),
    st.booleans(),  # damage the storage file (else metadata.yaml)
    st.integers(0, 4),
    st.integers(0, 2**31),
    st.binary(min_size=1, max_size=16),
    YAML_VALUES,
    st.booleans(),  # read the bare storage file (else the bag folder)
)
@pytest.mark.slow
def test_rosbag_damaged_files(
    storage: str, data_file: bool, kind: int, where: int, junk: bytes, text: str, bare: bool
) -> None:
    """``read_rosbag`` on a copy of a valid bag whose .mcap/.db3 file or metadata.yaml is
    truncated, overwritten with random bytes, emptied, garbled or deleted."""
    from odomgym.data.rosbag2 import read_rosbag

    bag, stored = _damaged_bag(storage, data_file, kind, where, junk, text)
    path = stored if bare else bag
    try:
        (run,) = read_rosbag(path, pose_topic="/pose", joint_topic="/wheels", robot=BAG_ROBOT)
    except SpecError as exc:
        _one_line(exc, path)
        event(f"refused: {str(exc).split(': ')[1][:25]}")
        return
    event("read")
    assert np.all(np.isfinite(run.time)) and np.all(np.diff(run.time) > 0)
    assert np.all(np.isfinite(run.true_pose[0]))


@needs_rosbags
@pytest.mark.parametrize(
    ("damage", "raised"),
    [
        (("sqlite3", True, 0, 253965, b"", ""), "apsw.CorruptError"),  # .db3 truncated
        (("mcap", True, 3, 9, b"\0\0\0\0", ""), "MemoryError"),  # 4 bytes inserted at 9
        (("mcap", True, 1, 9, b"\xff" * 8, ""), "OverflowError"),  # 8 bytes overwritten
        (("mcap", False, 3, 5, b"", ""), "TypeError"),  # a metadata.yaml value emptied
        (("mcap", False, 3, 5, b"", "{"), "a SpecError of 7 lines"),  # YAML syntax error
    ],
)
def test_regression_a_damaged_bag_is_one_line(damage: tuple[Any, ...], raised: str) -> None:
    """Found by test_rosbag_damaged_files: these damaged bags raised ``raised`` from rosbags,
    apsw or the MCAP parser (the reader caught only ReaderError, OSError, ValueError and
    KeyError), and a YAML syntax error's message kept ruamel's line breaks; now every one is
    a one-line SpecError naming the bag ("cannot read bag: …")."""
    from odomgym.data.rosbag2 import read_rosbag

    bag, _ = _damaged_bag(*damage)
    with pytest.raises(SpecError, match="cannot read bag") as caught:
        read_rosbag(bag, pose_topic="/pose", joint_topic="/wheels", robot=BAG_ROBOT)
    _one_line(caught.value, bag)


# ------------------------------------------------------------------------ any measured log
HEADER = "run,experiment,t,ticks_left,ticks_right,x,y,theta\n"
LOG_BYTES = st.one_of(
    st.binary(max_size=200),
    st.just(b""),
    st.sampled_from(["utf-8", "utf-8-sig", "utf-16", "utf-32", "latin-1", "cp500"]).map(
        HEADER.encode
    ),  # a header only, in some encoding
    st.binary(max_size=40).map(lambda junk: HEADER.encode() + junk),
    st.binary(max_size=40).map(lambda junk: b"Type,diff,,,,,\nngear," + junk),  # OptiOdom-ish
)


@given(
    st.sampled_from(["file", "empty folder", "bag folder", "session folder", "nested session"]),
    st.sampled_from([".csv", ".CSV", ".mcap", ".db3", ".txt", "", ".yaml"]),
    LOG_BYTES,
    st.sampled_from([None, None, None, "native", "optiodom", "rosbag"]),
)
def test_read_log_garbage(layout: str, suffix: str, data: bytes, log_format: str | None) -> None:
    """``read_log`` (format detection, then the native, OptiOdom or ROS 2 bag reader) on random
    bytes, empty files, header-only files in odd encodings, empty folders and folders that look
    like a bag or an OptiOdom session but hold garbage."""
    import shutil

    from odomgym.data.logs import read_log

    root = SCRATCH / "logs"
    if root.exists():
        shutil.rmtree(root)
    root.mkdir()
    if layout == "file":
        path = root / f"log{suffix}"
        path.write_bytes(data)
    else:
        path = root / "square" / "230620202042"  # an OptiOdom session's place
        path.mkdir(parents=True)
        if layout == "bag folder":
            (path / "metadata.yaml").write_bytes(data)
            (path / f"230620202042_0{suffix}").write_bytes(data[::-1])
        elif layout == "session folder":
            (path / "230620202042_metadata.csv").write_bytes(data)
            (path / f"230620202042_run-01{suffix}").write_bytes(data[::-1])
        elif layout == "nested session":
            (path / "x_metadata.csv").write_bytes(data)
            path = root
    try:
        runs, _ = read_log(
            path,
            robot=odomgym.PRESETS["labmate"],
            format=log_format,  # type: ignore[arg-type]
            pose_topic="/pose",
            joint_topic="/wheels",
        )
    except SpecError as exc:
        _one_line(exc, path)
        event(f"refused: {str(exc).split(': ')[1][:20]}")
        return
    event("read")
    for run in runs:
        assert np.all(np.isfinite(run.time)) and np.all(np.diff(run.time) > 0)


# ----------------------------------------------------------------------- vehicle constructor
VEHICLE_FIELDS = {  # the CLAPPER's (odomgym.vehicle.spec.VEHICLES["clapper"]), trucks aside
    "link_length": 1.0,
    "link_min": 0.9,
    "link_max": 1.1,
    "sample_period": 0.04,
    "rotary_bits": 10,
    "rotary_bias_a": 0.0,
    "rotary_bias_b": 0.0,
    "linear_resolution": 1e-4,
    "linear_bias": 0.0,
}
TRUCKS = st.one_of(
    st.sampled_from([odomgym.PRESETS["labmate"], odomgym.PRESETS["navbot"]]),
    st.sampled_from(["labmate", None, 5, {"wheelbase": 0.5}]),
)


@given(
    _mutated(VEHICLE_FIELDS, list(VEHICLE_FIELDS)).map(
        lambda d: {k: v for k, v in d.items() if k in VEHICLE_FIELDS}
    ),
    st.dictionaries(st.sampled_from(["truck_a", "truck_b"]), TRUCKS, max_size=2),
)
def test_vehicle_constructor(fields: dict[str, Any], trucks: dict[str, Any]) -> None:
    """``VehicleSpec(...)`` itself (not its TOML loader) with odd link, encoder and truck
    values."""
    from odomgym.robot import RobotSpec
    from odomgym.vehicle.spec import VehicleSpec

    try:
        vehicle = VehicleSpec(
            **(
                {"truck_a": odomgym.PRESETS["labmate"], "truck_b": odomgym.PRESETS["labmate"]}
                | fields
                | trucks
            )
        )
    except SpecError as exc:
        assert exc.field is not None
        _one_line(exc)
        return
    _finite(vehicle.to_dict())
    assert all(isinstance(truck, RobotSpec) for truck in vehicle.trucks), vehicle.trucks
    assert vehicle.link_min < vehicle.link_length < vehicle.link_max


def test_regression_a_vehicle_truck_must_be_a_robot_spec() -> None:
    """Found by test_vehicle_constructor: VehicleSpec(truck_a="labmate") was accepted, and
    ClapperStraight-v0's reset() then raised AttributeError ('str' object has no attribute
    'true_left_diameter') in odomgym.sim.world; now a SpecError naming truck_a."""
    from odomgym.vehicle.spec import VehicleSpec

    with pytest.raises(SpecError, match=r"truck_a must be a RobotSpec .* got str 'labmate'") as e:
        VehicleSpec(truck_a="labmate", truck_b=odomgym.PRESETS["labmate"])  # type: ignore[arg-type]
    assert e.value.field == "truck_a"


# ------------------------------------------------------------------- actions of every env
DTYPES: list[Any] = [np.float16, np.float32, np.int8, np.uint64, np.bool_, np.complex64]
DTYPES += [np.str_, np.bytes_, object]
HUGE_INTS = st.one_of(st.integers(), st.sampled_from([2**1024, -(2**1100)]))  # beyond a float
_ENVS: dict[str, Any] = {}


def _env(env_id: str) -> Any:
    """One env per id for every example (``vector``: the native vector env of 3 squares)."""
    if env_id not in _ENVS:
        env: Any
        if env_id == "vector":
            env = gym.make_vec(
                "UMBmarkSquare-v0", num_envs=3, vectorization_mode="vector_entry_point"
            )
        else:
            env = gym.make(env_id)
        env.reset(seed=0)
        _ENVS[env_id] = env
    return _ENVS[env_id]


def _actions(shape: tuple[int, ...]) -> st.SearchStrategy[Any]:
    """Actions for a Box of ``shape``: odd floats, ints and dtypes of the right shape, wrong
    shapes, huge integers, None, text and other objects."""
    size = math.prod(shape)

    def shaped(values: list[Any]) -> Any:
        return np.array(values).reshape(shape)

    return st.one_of(
        st.lists(ODD_FLOATS, min_size=size, max_size=size).map(shaped),
        st.lists(ODD_FLOATS, min_size=0, max_size=size + 2).map(np.array),
        st.lists(st.integers(-5, 5), min_size=size, max_size=size).map(shaped),
        st.lists(HUGE_INTS, min_size=size, max_size=size),
        st.sampled_from(DTYPES).map(lambda dtype: np.full(shape, 1, dtype=dtype)),
        st.sampled_from([np.zeros((*shape, 2)), np.zeros((2, 2)), np.zeros(())]),
        st.sampled_from([None, "go", "0.5", b"1", 1.0, 2**1100, [0.5, "x"], {"a": 1}, object()]),
    )


def _must_refuse(action: Any, shape: tuple[int, ...]) -> bool:
    """True for an action no Box of ``shape`` holds: not real numbers (None, text, bytes,
    complex, other objects), NaN, infinite or beyond a float, or the wrong number of them."""
    if action is None or isinstance(action, str | bytes):
        return True
    try:
        raw = np.asarray(action)
    except ValueError:  # ragged
        return True
    numbers = (bool, int, float, np.bool_, np.integer, np.floating)
    if raw.dtype.kind not in "biufO" or not all(isinstance(v, numbers) for v in raw.flat):
        return True
    try:
        values = raw.astype(np.float64)
    except OverflowError:
        return True
    return values.size != math.prod(shape) or not np.all(np.isfinite(values))


@pytest.mark.parametrize(
    ("env_id", "shape"),
    [("StraightLine-v0", (2,)), ("ClapperStraight-v0", (1,)), ("vector", (3, 2))],
)
@given(data=st.data())
def test_env_actions_of_every_env(env_id: str, shape: tuple[int, ...], data: Any) -> None:
    """``step`` of the other Box-action envs (UMBmarkSquare-v0: :func:`test_env_actions`) and
    of the native vector env: a valid action gives an observation in the space and a finite
    reward; anything else is a one-line ValueError/TypeError, never numpy's or pymunk's."""
    env = _env(env_id)
    action = data.draw(_actions(shape), label="action")
    try:
        obs, reward, terminated, truncated, _ = env.step(action)
    except (ValueError, TypeError) as exc:
        assert str(exc) and "\n" not in str(exc).strip(), exc
        assert type(exc).__module__ == "builtins" or isinstance(exc, SpecError), repr(exc)
        return
    assert not _must_refuse(action, shape), f"accepted {action!r}"
    assert env.observation_space.contains(obs), obs
    assert np.all(np.isfinite(reward))
    if env_id != "vector" and (terminated or truncated):  # the vector env resets itself
        env.reset(seed=1)


@pytest.mark.parametrize("env_id", ["UMBmarkSquare-v0", "StraightLine-v0", "vector"])
def test_regression_an_integer_beyond_a_float_is_a_value_error(env_id: str) -> None:
    """Found by test_env_actions_of_every_env: an action holding a Python int beyond float
    range ([0, 0, 0, 0, 0, 2**1024] for the vector env, 2**1100 for ClapperStraight-v0)
    raised OverflowError from numpy's float conversion; now a one-line ValueError."""
    env = _env(env_id)
    action = [[0, 2**1024]] * 3 if env_id == "vector" else [0, 2**1024]
    with pytest.raises(ValueError, match="action must be finite, got") as caught:
        env.step(action)
    assert "\n" not in str(caught.value)
    with pytest.raises(ValueError, match="action must be finite"):
        _env("ClapperStraight-v0").step(2**1100)


@pytest.mark.parametrize(
    ("env_id", "action"),
    [
        ("StraightLine-v0", np.full(2, 1, dtype=np.complex64)),
        ("StraightLine-v0", np.array(["0.5", "0.5"])),
        ("vector", np.full((3, 2), b"1")),
        ("ClapperStraight-v0", np.array([1 + 0j])),
        ("ClapperStraight-v0", "0.5"),
    ],
)
def test_regression_complex_and_text_actions_are_refused(env_id: str, action: Any) -> None:
    """Found by test_env_actions_of_every_env: complex actions were accepted (StraightLine-v0
    took np.full(2, 1, complex64), ClapperStraight-v0 np.array([1+0j]): numpy dropped the
    imaginary part with a ComplexWarning), and so was text ("0.5", numpy parsed it); now a
    one-line ValueError, as for None."""
    with pytest.raises(ValueError, match=r"action must be .* got") as caught:
        _env(env_id).step(action)
    assert "\n" not in str(caught.value)


def test_regression_a_clapper_action_error_is_one_line() -> None:
    """Found by test_env_actions_of_every_env: ClapperStraight-v0.step(np.zeros((2, 2)))
    raised a ValueError whose message held the array's two-line repr; now one line."""
    with pytest.raises(ValueError) as caught:
        _env("ClapperStraight-v0").step(np.zeros((2, 2)))
    assert str(caught.value) == (
        "action must be one finite number in [0, 1], got array([[0., 0.], [0., 0.]])"
    )


SELFCAL_ACTIONS = st.one_of(
    st.integers(0, 9),  # valid: one run of a menu item (0 stops)
    st.integers(max_value=-1) | st.integers(min_value=10),
    VALUES,
    st.sampled_from([np.int64(3), np.uint8(2), np.array(4), np.int8(-1), np.uint64(2**63)]),
    st.sampled_from([np.array([1]), np.zeros((2, 2), int), np.float64(2), np.array(2.0), None]),
    st.sampled_from(["3", b"3", 3.0, True, 1 + 0j, [3], (3,), {"a": 3}]),
)


# A valid step drives a whole run (a physics batch, ~0.1 s): a quarter of the examples, most
# of them invalid actions (each refused in microseconds).
@settings(max_examples=max(EXAMPLES // 4, 1))
@given(SELFCAL_ACTIONS)
def test_selfcal_env_steps(action: Any) -> None:
    """``SelfCalibration-v1``'s ``step`` (not only :func:`menu_index`) with menu indices and
    everything else."""
    env = _env("SelfCalibration-v1")
    value = action.item() if isinstance(action, np.ndarray) and action.shape == () else action
    valid = isinstance(value, int | np.integer) and not isinstance(value, bool)
    valid = valid and 0 <= int(value) < 10
    event("a menu index" if valid else "not a menu index")
    try:
        obs, reward, terminated, truncated, _ = env.step(action)
    except (ValueError, TypeError) as exc:
        assert not valid, f"refused {action!r}: {exc}"
        assert str(exc) and "\n" not in str(exc).strip(), exc
        return
    assert valid, f"accepted {action!r}"
    assert env.observation_space.contains(obs), obs
    assert math.isfinite(reward)
    if terminated or truncated:
        env.reset(seed=int(value) + 1)


def test_regression_a_selfcal_action_error_is_one_line() -> None:
    """Found by test_selfcal_env_steps: SelfCalibration-v0.step(np.zeros((2, 2), int)) raised
    a SpecError whose message held the array's two-line repr; now one line."""
    with pytest.raises(SpecError) as caught:
        _env("SelfCalibration-v1").step(np.zeros((2, 2), int))
    assert caught.value.field == "action"
    assert str(caught.value).endswith("got array([[0, 0], [0, 0]])")


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["run", "square", "--runs", "99999999999999999999"], "must be at most 1000000000"),
        (["calibrate", "umbmark", "--side", "1e-308"], "one run may have 0.001 to 1000 m"),
        (["run", "clapper-straight", "--bumps", "99999999999999999999"], "at most 1000"),
        (["train", "selfcal", "--envs", "99999999999999999999"], "at most 1024"),
        (["diagnose", "x", "--jobs", "99999999999999999999"], "at most 1024"),
        (["train", "selfcal", "--seed", "-1"], "must be >= 0"),
        (["train", "selfcal", "--eval-sessions", "0"], "must be >= 1"),
        (["train", "selfcal", "--seed", "4294967296"], "at most 2**32 - 1"),
    ],
)
def test_regression_absurd_command_line_numbers_are_one_line(
    argv: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """Found by benchmarks/fuzz_cli.py: ``--runs 1e20`` raised OverflowError (an index-sized
    integer), ``--side 1e-308`` ZeroDivisionError, ``--bumps 1e20`` and ``--envs 1e20`` numpy's
    "Maximum allowed size exceeded", ``diagnose --jobs 1e20`` OverflowError (a C int),
    ``train selfcal --seed -1`` SB3's ValueError. Now seeds for training are 0..2**32 - 1,
    counts are at most 10^9, processes and sessions 1024, cables 1000, a run's path 1 mm to
    1 km: exit 2 and one line."""
    from odomgym.cli import main

    try:
        code = main(argv)
    except SystemExit as exc:  # argparse refused the text
        code = int(exc.code or 0)
    assert code == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert err[-1].startswith("odomgym") and says in err[-1], err


def test_regression_a_clapper_env_with_absurd_cables_is_one_line() -> None:
    """Found with the above: ``ClapperStraight-v0`` with ``bumps=10**20`` raised numpy's
    "Maximum allowed size exceeded" at reset; now a ValueError naming bumps when made."""
    with pytest.raises(ValueError, match="bumps must be at most 1000"):
        gym.make("ClapperStraight-v0", bumps=10**20)


# ------------------------------------------------------------ diagnose on logs with gaps
GAP_KINDS = ("samples", "dropouts", "held", "headings", "all", "none")
"""How a run's ground truth goes missing: single samples at random, long contiguous dropouts,
a tracker repeating its last pose, a position-only stretch (headings empty), the whole run
(the tracker never saw it), or not at all."""


@functools.cache
def _gappy_protocol() -> tuple[Any, ...]:
    """Six short runs of the independent generator (tests/independent_robot.py), one of each
    kind a diagnosis reads, with a wheel-diameter ratio to find; and the model's TOML."""
    from independent_robot import IndependentRobot, Manoeuvre, generate

    from odomgym.robot import RobotSpec

    protocol = [
        Manoeuvre("square", "cw", size=0.5, speed=0.3),
        Manoeuvre("square", "ccw", size=0.5, speed=0.3),
        Manoeuvre("straight", size=1.0, speed=0.3),
        Manoeuvre("spin", "ccw", angle=math.pi, speed=0.2),
        Manoeuvre("arc", "cw", size=0.5, angle=math.pi, speed=0.3),
        Manoeuvre("straight", size=1.0, speed=0.3),
    ]
    robot = IndependentRobot(effects={"wheel_diameter_ratio": {"e_d": 1.004}})
    runs = generate(robot, protocol, np.random.default_rng(42))
    model = SCRATCH / "gappy-robot.toml"
    RobotSpec(wheel_diameter=0.084, wheelbase=0.2, ticks_per_rev=2796.8).save(model)
    return tuple(runs), model


def _with_gaps(pose: np.ndarray, kind: str, share: float, rng: np.random.Generator) -> np.ndarray:
    """``pose`` (T, 3) with about ``share`` of its rows' ground truth lost the ``kind`` way."""
    out = pose.copy()
    n = len(out)
    if kind == "samples":
        out[rng.random(n) < share] = np.nan
    elif kind == "all":
        out[:] = np.nan
    elif kind != "none":
        lost = np.zeros(n, dtype=bool)
        for _ in range(int(rng.integers(1, 4))):  # one to three stretches
            length = int(share * n / 2) + 1
            start = int(rng.integers(0, n))
            lost[start : start + length] = True
        if kind == "held":  # the tracker writes the pose it had before each stretch
            for k in np.flatnonzero(lost):
                out[k] = out[k - 1] if k else out[k]
        elif kind == "headings":
            out[lost, 2] = np.nan
        else:
            out[lost] = np.nan
    return out


@settings(max_examples=max(EXAMPLES // 200, 2))
@given(
    st.lists(
        st.tuples(st.sampled_from(GAP_KINDS), st.floats(0.0, 0.6), st.integers(0, 2**32 - 1)),
        min_size=3,
        max_size=6,
    )
)
@pytest.mark.slow
def test_diagnose_takes_logs_with_gaps(gaps: list[tuple[str, float, int]]) -> None:
    """``odomgym diagnose`` (native CSV, the baseline on) on logs of three to six runs whose
    ground truth has 0–60 % gaps — random samples, long dropouts, held poses, position-only
    stretches, whole runs of gaps: it finishes (exit 0, finite held-out position errors for
    every model) or refuses in one error line (exit 2); never an internal error or a
    traceback. One round, catalogue only, two candidates: the point is the plumbing, not the
    verdict."""
    import contextlib
    import dataclasses
    import io
    import json
    import shutil

    from odomgym.cli import main
    from odomgym.data.native import write_native

    runs, model = _gappy_protocol()
    gappy = [
        dataclasses.replace(
            run, true_pose=_with_gaps(run.true_pose, kind, share, np.random.default_rng(seed))
        )
        for run, (kind, share, seed) in zip(runs, gaps, strict=False)
    ]
    data, out = SCRATCH / "gappy.csv", SCRATCH / "gappy-diagnose"
    write_native(data, gappy)
    shutil.rmtree(out, ignore_errors=True)
    argv = [
        *("diagnose", str(data), "--robot", str(model), "--out", str(out), "--json"),
        *("--no-discover", "--max-rounds", "1", "--jobs", "1"),
        *("--candidates", "wheel_diameter_ratio", "wheelbase"),
    ]
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(argv)
    lines = stderr.getvalue().splitlines()
    assert "Traceback" not in stderr.getvalue() and "internal error" not in stderr.getvalue()
    assert all(line.startswith(("odomgym: ", "wrote: ")) for line in lines), lines
    errors = [line for line in lines if line.startswith("odomgym: error: ")]
    if code == 2:
        assert len(errors) == 1 and not out.exists(), lines
        event(f"refused: {errors[0].split(': ')[2][:30]}")
        return
    assert code == 0 and not errors, (code, lines)
    report = json.loads(stdout.getvalue())
    for label, figures in report["held_out_open_loop"]["models"].items():
        assert math.isfinite(figures["position_rms_mm"]), (label, figures)
    assert {s["run"] for s in report["skipped_runs"]} == {
        line.split()[3] for line in lines if line.startswith("odomgym: skipped run ")
    }
    event(f"diagnosed, {len(report['skipped_runs'])} runs set aside")

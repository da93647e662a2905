"""Property-based tests (hypothesis): whatever a user feeds odomgym — spec files, command-line
numbers, env actions, measured logs — it either works, with finite results inside the declared
spaces, or raises odomgym's own one-line error naming the field (and, for files, the file):
never a traceback from numpy, pymunk, numba, tomllib or csv.

Profiles: ``ci`` (the default, 1000 examples per property) and ``soak`` (set
``ODOMGYM_FUZZ_EXAMPLES``; ``python benchmarks/bench_fuzz.py`` runs it and prints the counts).
"""

from __future__ import annotations

import argparse
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
from hypothesis import HealthCheck, given, settings  # noqa: E402
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
    from odomgym.vehicle import load_vehicle

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
        from odomgym.lab import simulate_runs
        from odomgym.routes import square_route

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
    from odomgym.odometry import Calibration

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

"""The native measured-log CSV (:mod:`odomgym.data.native`): exact round trips, and bad input
refused with the file, line and column named."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from odomgym.data.native import COLUMNS, experiment_kind, read_native, write_native
from odomgym.errors import SpecError
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

HEADER = ",".join(COLUMNS)
NAN = math.nan
# 0.1 m wheels, 1000 counts/rev: 0.314 mm per count; at 0.5 m/s a 0.1 s row allows
# 1.5 · 0.5 · 0.1 / 3.1416e-4 + 2 = 240.7 counts.
ROBOT = RobotSpec(wheel_diameter=0.1, wheelbase=0.3, ticks_per_rev=1000, max_wheel_speed=0.5)


def _write(tmp_path: Path, *lines: str, name: str = "log.csv") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _runs() -> list[Run]:
    """Three runs: dense full poses, an UMBmark-style sparse log, position-only rows."""
    rng = np.random.default_rng(7)
    t = 3.0 + np.cumsum(rng.uniform(0.01, 0.1, 40))  # does not start at 0
    dense = Run(
        kind="square",
        time=t,
        counts=np.cumsum(rng.integers(-5, 60, (40, 2)), axis=0) + 17,  # does not start at 0
        true_pose=np.column_stack(
            [rng.normal(size=40), rng.normal(size=40), np.linspace(0, -7, 40)]
        ),
        direction="cw",
        meta={"run": "a,1", "experiment": "square_cw"},
    )
    sparse_pose = np.full((5, 3), NAN)
    sparse_pose[0] = (0.1, -0.2, 0.3)
    sparse_pose[-1] = (1.0 / 3.0, 2e-17, -0.5)
    sparse = Run(
        kind="straight",
        time=np.array([0.0, 0.5, 1.0, 1.5, 2.25]),
        counts=np.array([[0, 0], [10, 11], [20, 22], [30, 33], [41, 45]]),
        true_pose=sparse_pose,
    )
    partial = Run(
        kind="spin",
        time=np.array([0.0, 0.1, 0.2, 0.3]),
        counts=np.array([[0, 0], [-3, 3], [-6, 6], [-9, 9]]),
        true_pose=np.array(
            [[0.0, 0.0, 0.0], [0.001, 0.0, NAN], [NAN, NAN, NAN], [0.0, 0.002, 0.5]]
        ),
        direction="ccw",
        meta={"run": 7},
    )
    return [dense, sparse, partial]


# ---------------------------------------------------------------------------------- round trip
def test_round_trip_is_exact(tmp_path: Path) -> None:
    runs = _runs()
    path = tmp_path / "out" / "log.csv"
    write_native(path, runs)
    back = read_native(path)
    assert len(back) == len(runs)
    for original, read in zip(runs, back, strict=True):
        np.testing.assert_array_equal(read.time, original.time - original.time[0])
        np.testing.assert_array_equal(read.counts, original.counts - original.counts[0])
        np.testing.assert_array_equal(read.true_pose, original.true_pose)  # NaN where NaN
        assert read.time.dtype == np.float64 and read.counts.dtype == np.int64
        assert (read.kind, read.direction) == (original.kind, original.direction)
        assert read.meta["format"] == "native"
    assert [r.meta["run"] for r in back] == ["a,1", "2", "7"]
    assert [r.meta["experiment"] for r in back] == ["square_cw", "straight", "spin_ccw"]
    assert back[0].source == f"{path}:2" and back[1].source == f"{path}:42"
    assert back[1].meta["lines"] == (42, 46)
    # Nothing but the target is left in the folder.
    assert [p.name for p in path.parent.iterdir()] == ["log.csv"]


def test_written_cells(tmp_path: Path) -> None:
    path = tmp_path / "log.csv"
    write_native(path, _runs()[1:], experiments=["straight_1m", "spin cw"])
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[0] == HEADER
    assert lines[1] == "1,straight_1m,0.0,0,0,0.1,-0.2,0.3"
    assert lines[2] == "1,straight_1m,0.5,10,11,,,"
    assert lines[5] == "1,straight_1m,2.25,41,45,0.3333333333333333,2e-17,-0.5"
    assert lines[7] == "7,spin cw,0.1,-3,3,0.001,0.0,"
    back = read_native(path)
    assert (back[1].kind, back[1].direction) == ("spin", "cw")  # the label wins over the run


def test_reads_a_hand_written_log(tmp_path: Path) -> None:
    """Columns in any order, a BOM, CRLF, blank lines; heading unwrapped on measured rows."""
    text = (
        "\ufefftheta,x,y,t,ticks_right,ticks_left,experiment,run\r\n"
        "3.0,1,2,10.0,100,200,Spin-CCW-180,r1\r\n"
        "\r\n"
        ",,,10.5,110,190,Spin-CCW-180,r1\r\n"
        "-3.0,1,2,11.0,120,180,Spin-CCW-180,r1\r\n"
        "1.0,0,0,0,5,5,UMBmark,r2\r\n"
        "1.5,0,0,0.25,6,6,UMBmark,r2\r\n"
    )
    path = tmp_path / "hand.csv"
    path.write_bytes(text.encode("utf-8"))
    spin, free = read_native(path)
    np.testing.assert_array_equal(spin.time, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(spin.counts, [[0, 0], [-10, 10], [-20, 20]])
    assert np.isnan(spin.true_pose[1]).all()
    assert spin.true_pose[2, 2] == pytest.approx(2 * math.pi - 3.0)  # unwrapped past π
    assert (spin.kind, spin.direction, spin.source) == ("spin", "ccw", f"{path}:2")
    assert spin.meta == {
        "run": "r1",
        "experiment": "Spin-CCW-180",
        "format": "native",
        "lines": (2, 5),
    }
    assert (free.kind, free.direction, free.source) == ("free", None, f"{path}:6")


def test_gaps_are_read_as_logged(tmp_path: Path) -> None:
    """Empty pose cells are gaps wherever they are: on a run's first rows (a tracker that
    found the marker late: the rows stay, counts and time from the run's first row), or on
    every row of a run (the tracker never saw it). Deciding what a diagnosis can use is the
    screening's (odomgym.diagnose.screen), not the reader's."""
    path = _write(
        tmp_path,
        HEADER,
        _row(th=""),
        _row(t=0.5, left=3, right=4, x="", y="", th=""),
        _row(t=1, left=9, right=10, x=0.1),
        _row(run="r2", x="", y="", th=""),
        _row(run="r2", t=1, left=5, right=5, x="", y="", th=""),
    )
    late, blind = read_native(path)
    assert np.isnan(late.true_pose[0, 2]) and not np.isnan(late.true_pose[0, :2]).any()
    assert np.isnan(late.true_pose[1]).all()
    np.testing.assert_array_equal(late.true_pose[2], [0.1, 0.0, 0.0])
    np.testing.assert_array_equal(late.counts, [[0, 0], [3, 4], [9, 10]])
    assert np.isnan(blind.true_pose).all() and blind.meta["lines"] == (5, 6)
    again = tmp_path / "again.csv"
    write_native(again, [late, blind])  # what is read writes back, gaps included
    for read, written in zip(read_native(again), (late, blind), strict=True):
        np.testing.assert_array_equal(read.true_pose, written.true_pose)


@pytest.mark.parametrize(
    ("label", "kind", "direction"),
    [
        ("square_cw", "square", "cw"),
        ("square-ccw-2m", "square", "ccw"),
        ("spin_ccw_90", "spin", "ccw"),
        ("straight", "straight", None),
        ("straight_back cw", "straight", "cw"),
        ("squarecw", "square", None),  # "cw" is a token, not a substring
        ("figure8_cw", "free", "cw"),
        ("spin_cw_ccw", "spin", None),  # both: undecided
        ("", "free", None),
    ],
)
def test_experiment_kind(label: str, kind: str, direction: str | None) -> None:
    assert experiment_kind(label) == (kind, direction)


# ---------------------------------------------------------------------------------- bad input
def _row(
    t: object = 0.0,
    left: object = 0,
    right: object = 0,
    x: object = 0.0,
    y: object = 0.0,
    th: object = 0.0,
    run: str = "r1",
    label: str = "square_cw",
) -> str:
    return f"{run},{label},{t},{left},{right},{x},{y},{th}"


BAD: dict[str, tuple[list[str], str, int, str | None]] = {
    # case: (lines, message pattern, line, field)
    "header only": ([HEADER], "no data rows", 1, None),
    "missing columns": (
        ["run,experiment,t,ticks_left,ticks_right,x", _row()],
        "missing column.*'y', 'theta'",
        1,
        "y",
    ),
    "extra column": ([HEADER + ",z,", _row() + ",1,"], "unknown column.*'z', ''", 1, "z"),
    "repeated column": ([HEADER + ",x", _row() + ",1"], "'x' appears twice", 1, "x"),
    "cell count": ([HEADER, _row(), _row(t=1) + ",9"], "expected 8 cells.*got 9", 3, None),
    "malformed quote": ([HEADER, _row(), 'r1,"square_cw,1,0,0,,,'], "malformed CSV", 3, None),
    "empty run id": ([HEADER, _row(run=" ")], "'run' is empty", 2, "run"),
    "non-numeric t": ([HEADER, _row(), _row(t="1.0s")], "'t' is not a number: '1.0s'", 3, "t"),
    "empty t": ([HEADER, _row(), _row(t="")], "'t' is empty", 3, "t"),
    "nan text": ([HEADER, _row(), _row(t=1, x="nan")], "'x' is not finite: 'nan'.*empty", 3, "x"),
    "inf text": ([HEADER, _row(), _row(t=1, th="-inf")], "'theta' is not finite", 3, "theta"),
    "fractional count": (
        [HEADER, _row(), _row(t=1, right="2.5")],
        "'ticks_right' must hold a whole number.*'2.5'",
        3,
        "ticks_right",
    ),
    "text count": (
        [HEADER, _row(), _row(t=1, left="n/a")],
        "'ticks_left' is not a number",
        3,
        "ticks_left",
    ),
    "empty count": ([HEADER, _row(), _row(t=1, left="")], "'ticks_left' is empty", 3, "ticks_left"),
    "time repeats": (
        [HEADER, _row(t=0.5), _row(t=0.75), _row(t=0.75)],
        r"t = 0\.75 s follows t = 0\.75 s on line 3",
        4,
        "t",
    ),
    "time goes back": (
        [HEADER, _row(t=0.5), _row(t=0.25)],
        r"t = 0\.25 s follows t = 0\.5 s on line 2",
        3,
        "t",
    ),
    "non-contiguous": (
        [HEADER, _row(), _row(t=1), _row(run="r2"), _row(run="r2", t=1), _row(t=2)],
        "run 'r1' appears again after run 'r2'.*lines 2–3",
        6,
        "run",
    ),
    "label changes": (
        [HEADER, _row(), _row(t=1, label="square_ccw")],
        "from 'square_cw'.*to 'square_ccw'",
        3,
        "experiment",
    ),
    "only x": ([HEADER, _row(), _row(t=1, y="")], "'x' is given but 'y' is empty", 3, "y"),
    "only y": ([HEADER, _row(), _row(t=1, x="")], "'y' is given but 'x' is empty", 3, "x"),
    "theta alone": ([HEADER, _row(), _row(t=1, x="", y="")], "'theta' is given but", 3, "x"),
    "one row": (
        [HEADER, _row(), _row(t=1), _row(run="r2")],
        "run 'r2' has only one row \\(line 4\\)",
        4,
        "run",
    ),
    # A header nearly right gets the usual slip named (a user's logs: each listed every column
    # as missing or an unknown column '' without a word on why).
    "semicolons": (
        [HEADER.replace(",", ";"), _row().replace(",", ";")],
        "the header holds no comma: columns are separated by commas",
        1,
        "run",
    ),
    "upper case": ([HEADER.upper(), _row()], r"\(column names are lower case\)", 1, "run"),
    "trailing comma": (
        [HEADER + ",", _row() + ","],
        r"unknown column\(s\) ''.*a trailing or doubled comma\?",
        1,
        "",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_log_names_file_line_and_column(tmp_path: Path, case: str) -> None:
    lines, pattern, line, column = BAD[case]
    path = _write(tmp_path, *lines, name="bad-log.csv")
    with pytest.raises(SpecError, match=pattern) as info:
        read_native(path)
    message = str(info.value)
    assert f"bad-log.csv:{line}:" in message, message
    assert info.value.field == column
    if column is not None:
        assert f"'{column}'" in message or column in message


def test_unreadable_and_non_text_files(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="cannot read native log") as info:
        read_native(tmp_path / "missing.csv")
    assert "missing.csv" in str(info.value)
    with pytest.raises(SpecError, match="cannot read native log"):
        read_native(tmp_path)  # a folder
    latin = tmp_path / "latin.csv"
    latin.write_bytes(f"{HEADER}\n{_row()}\nr1,caf\xe9,1,0,0,,,\n".encode("latin-1"))
    with pytest.raises(SpecError, match=r"latin\.csv:3: not UTF-8"):
        read_native(latin)
    binary = tmp_path / "blob.csv"
    binary.write_bytes(b"run,experiment\x00\x01\x02garbage")
    with pytest.raises(SpecError, match=r"blob\.csv:1: binary data"):
        read_native(binary)
    random = tmp_path / "random.csv"
    random.write_bytes(np.random.default_rng(1).bytes(4096))
    with pytest.raises(SpecError, match=r"random\.csv:\d+: (not UTF-8|binary data)"):
        read_native(random)
    for text in ("", "\n\n  \n"):
        empty = _write(tmp_path, text, name="empty.csv")
        with pytest.raises(SpecError, match=r"empty\.csv: empty file: expected a header row"):
            read_native(empty)


def test_count_jumps_are_checked_against_the_robot(tmp_path: Path) -> None:
    ok = _write(tmp_path, HEADER, _row(), _row(t=0.1, left=240, right=-240), name="ok.csv")
    assert read_native(ok, robot=ROBOT)[0].counts[-1].tolist() == [240, -240]
    jump = _write(
        tmp_path,
        HEADER,
        _row(),
        _row(t=0.1, left=240),
        _row(t=0.2, left=240, right=241),
        name="jump.csv",
    )
    assert read_native(jump)[0].counts[-1].tolist() == [240, 241]  # no robot: no check
    with pytest.raises(
        SpecError, match=r"ticks_right jumps by \+241 counts in 0\.1 s .*240\.7"
    ) as info:
        read_native(jump, robot=ROBOT)
    assert "jump.csv:4:" in str(info.value) and info.value.field == "ticks_right"
    assert str(info.value).endswith(
        "(a robot that drives faster needs its max_wheel_speed in the robot file; a "
        "ticks_per_rev too small or a wheel_diameter too large gives the same)"
    )


# ---------------------------------------------------------------------------------- writing
@pytest.mark.parametrize(
    ("change", "pattern"),
    [
        ("inf", "theta of sample 2 is infinite"),
        ("half", "sample 1 has only one of x and y"),
        ("lone theta", "sample 1 has theta without x and y"),
        ("time", "time must increase"),
        ("nan time", "time of sample 3 is nan"),
        ("duplicate id", "same id as run 1"),
    ],
)
def test_write_refuses_runs_it_could_not_read_back(
    tmp_path: Path, change: str, pattern: str
) -> None:
    runs = _runs()
    pose, time = runs[0].true_pose, runs[0].time
    if change == "inf":
        pose[2, 2] = math.inf
    elif change == "half":
        pose[1, 0] = NAN
    elif change == "lone theta":
        pose[1, :2] = NAN
    elif change == "time":
        time[5] = time[4]
    elif change == "nan time":
        time[3] = NAN
    else:
        runs[2].meta["run"] = "a,1"
    path = tmp_path / "log.csv"
    with pytest.raises(SpecError, match=pattern):
        write_native(path, runs)
    assert list(tmp_path.iterdir()) == []


def test_write_argument_errors(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="2 labels for 3 runs"):
        write_native(tmp_path / "a.csv", _runs(), experiments=["x", "y"])
    with pytest.raises(SpecError, match="line break"):
        write_native(tmp_path / "a.csv", _runs()[:1], experiments=["square\ncw"])
    with pytest.raises(SpecError, match="no runs"):
        write_native(tmp_path / "a.csv", [])
    assert list(tmp_path.iterdir()) == []


def test_failed_write_leaves_nothing_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("x", encoding="utf-8")
    with pytest.raises(OSError):
        write_native(blocker / "sub" / "log.csv", _runs())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["not-a-folder"]

    path = tmp_path / "log.csv"
    path.write_text("previous content", encoding="utf-8")

    def fail(src: object, dst: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("odomgym.io.os.replace", fail)
    with pytest.raises(OSError, match="No space"):
        write_native(path, _runs())
    assert path.read_text(encoding="utf-8") == "previous content"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.csv", "not-a-folder"]


def test_a_folder_of_two_formats_is_refused_not_read_as_one(tmp_path: Path) -> None:
    """Native logs beside an OptiOdom session: read as OptiOdom, the CSV logs and the folder's
    robot.toml were dropped without a word; now one line naming both, with --format as the
    way out. A CSV file that is no native log (an OptiOdom folder's results table) is no
    second format."""
    from odomgym.data.logs import detect_format

    session = tmp_path / "square" / "230620202042"
    session.mkdir(parents=True)
    (session / "230620202042_metadata.csv").write_text("a,b\n1,2\n", encoding="utf-8")
    (tmp_path / "published_results.csv").write_text("method,e_b\numbmark,1.0\n")
    assert detect_format(tmp_path) == "optiodom"
    write_native(tmp_path / "a.csv", _runs()[:1])
    with pytest.raises(SpecError) as caught:
        detect_format(tmp_path)
    assert caught.value.field == "format"
    assert "holds logs of 2 formats: OptiOdom sessions (square/230620202042/) and native CSV " \
        "logs (a.csv)" in str(caught.value)  # fmt: skip


def test_a_folder_of_native_logs_is_one_robots_sessions(tmp_path: Path) -> None:
    """A folder of native CSV files — directly, or one sub-folder per period, as a robot's
    folder of ``odomgym fleet`` — reads as that robot's sessions (a file alone has no session
    column, so ``diagnose --loso`` could not run on such a robot), with the folder's
    ``robot.toml`` as its nominal robot."""
    from odomgym.data.logs import detect_format, native_sessions, read_log

    runs = _runs()
    write_native(tmp_path / "s1.csv", runs[:2])
    (tmp_path / "2026-11").mkdir()
    write_native(tmp_path / "2026-11" / "s2.csv", runs[2:])
    (tmp_path / ".hidden.csv").write_text("junk", encoding="utf-8")
    (tmp_path / "notes.txt").write_text("not a log", encoding="utf-8")
    assert [s for s, _ in native_sessions(tmp_path)] == ["2026-11/s2", "s1"]
    assert detect_format(tmp_path) == "native"
    read, nominal = read_log(tmp_path)
    assert nominal is None  # no robot.toml
    assert [(r.meta["session"], r.meta["period"]) for r in read] == [
        ("2026-11/s2", "2026-11"),
        ("s1", ""),
        ("s1", ""),
    ]
    fast = RobotSpec(wheel_diameter=0.1, wheelbase=0.3, ticks_per_rev=1000, max_wheel_speed=5.0)
    fast.save(tmp_path / "robot.toml")  # its count-jump check passes the random runs above
    _, nominal = read_log(tmp_path)
    assert nominal == fast
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(SpecError, match="cannot tell the log format"):
        read_log(empty)
    with pytest.raises(SpecError, match=r"no native log \(\.csv\) in this folder"):
        read_log(empty, format="native")


def test_fleet_and_diagnose_name_a_robots_sessions_alike(tmp_path: Path) -> None:
    """One robot's folder of native logs in period sub-folders reads with the same sessions
    and periods whether ``odomgym fleet`` reads it as a robot of its fleet or ``diagnose``
    as a folder of logs (one walk, :func:`odomgym.data.logs.period_logs`); a hidden folder's
    files are no session of either."""
    from odomgym.data.logs import read_log
    from odomgym.diagnose.fleet import find_fleet, read_robot_runs

    runs = _runs()
    folder = tmp_path / "fleet" / "r1"
    for period, name, part in (("2026-10", "a", runs[:1]), ("2026-11", "b", runs[1:])):
        (folder / period).mkdir(parents=True)
        write_native(folder / period / f"{name}.csv", part)
    (folder / ".trash").mkdir()
    write_native(folder / ".trash" / "old.csv", runs)
    fast = RobotSpec(wheel_diameter=0.1, wheelbase=0.3, ticks_per_rev=1000, max_wheel_speed=5.0)
    fast.save(folder / "robot.toml")
    [robot] = find_fleet(tmp_path / "fleet")
    by_fleet = [(r.meta["session"], r.meta["period"]) for r in read_robot_runs(robot)]
    by_diagnose = [(r.meta["session"], r.meta["period"]) for r in read_log(folder)[0]]
    assert (
        by_fleet
        == by_diagnose
        == [
            ("2026-10/a", "2026-10"),
            ("2026-11/b", "2026-11"),
            ("2026-11/b", "2026-11"),
        ]
    )

"""odomgym's native measured-log format: one CSV of encoder counts and ground-truth poses.

Why a format of its own: every robot logs differently, but a calibration needs only the time,
the two cumulative encoder counts and whatever the tracker measured. One flat CSV with one row
per sample is what a user can produce from any logger with a short script, read in a
spreadsheet, and check by eye. Both :func:`read_native` and
:func:`odomgym.data.rosbag2.read_rosbag` produce the same :class:`odomgym.odometry.runs.Run`
records.

The file has a header row with exactly these columns, in any order::

    run,experiment,t,ticks_left,ticks_right,x,y,theta

* ``run`` — an id (any text); the rows of one run are contiguous and in time order.
* ``experiment`` — a free label (``square_cw``, ``straight``, ``spin_ccw_90`` …). Its prefix
  gives the run's kind (``square``/``straight``/``spin``, else ``free``) and a ``cw`` or ``ccw``
  token (split on ``_``, ``-`` and spaces) its direction; see :func:`experiment_kind`.
* ``t`` — time [s] from the run's start (the reader subtracts the first row's time anyway).
* ``ticks_left``, ``ticks_right`` — cumulative encoder counts since the run's start (whole
  numbers; the reader subtracts the first row's counts).
* ``x``, ``y`` [m], ``theta`` [rad] — the tracked body's ground-truth pose in a fixed world
  frame. A cell is EMPTY where nothing was measured (an UMBmark-style log measures only the
  first and last rows of a run); ``nan`` written as text is an error, so a logging bug cannot
  pass for a gap. ``x`` and ``y`` come together; ``theta`` may be missing where they are given
  (a position-only tracker). Any row may be empty, the first ones too (a tracker that found the
  marker only after the logger started): odometry is replayed from a run's first FULL pose, so
  ``odomgym diagnose`` starts the run there (:func:`odomgym.diagnose.screen.screen_runs`, which
  also sets aside a run with too little ground truth, one without any included).

Headings are unwrapped over a run's measured rows (``np.unwrap`` on the non-empty thetas
only): rows more than π apart in heading with nothing measured between them are taken to be
the nearer way round, whatever the file wrote (an unwrapped heading is wrapped again). A log
measured sparsely thus tells a heading only modulo 2π between its measured rows; what reads
it takes the turn between them as the one nearest the odometry's (the diagnosis' residuals
wrap a heading difference, and :func:`odomgym.diagnose.screen.scale_ratios` does the same).

Every defect raises :class:`odomgym.errors.SpecError` naming the file, the line and the column.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from odomgym.errors import SpecError
from odomgym.io import atomic_write_text
from odomgym.odometry.runs import Direction, Run
from odomgym.robot import RobotSpec

__all__ = ["COLUMNS", "experiment_kind", "read_native", "write_native"]

FloatArray = NDArray[np.float64]
COLUMNS = ("run", "experiment", "t", "ticks_left", "ticks_right", "x", "y", "theta")
_POSE = ("x", "y", "theta")
_KINDS = ("square", "straight", "spin")
_MAX_COUNT = 2**62  # |counts| beyond this cannot be a wheel's travel (and would overflow int64)
_JUMP_SPEED_MARGIN = 1.5  # a wheel may exceed the commanded max_wheel_speed by 50 % …
_JUMP_SLACK = 2  # … plus two counts of quantisation / sampling jitter


def experiment_kind(label: str) -> tuple[str, Direction | None]:
    """The run kind and direction an experiment label names.

    Kind: ``"square"``, ``"straight"`` or ``"spin"`` if the label starts with that word, else
    ``"free"``. Direction: ``"cw"`` or ``"ccw"`` if that token occurs (tokens split on ``_``,
    ``-`` and spaces), else ``None`` (also when both occur). Case is ignored.
    """
    lowered = label.strip().lower()
    kind = next((k for k in _KINDS if lowered.startswith(k)), "free")
    tokens = set(re.split(r"[_\- ]+", lowered))
    direction: Direction | None = None
    if "cw" in tokens and "ccw" not in tokens:
        direction = "cw"
    elif "ccw" in tokens and "cw" not in tokens:
        direction = "ccw"
    return kind, direction


# ---------------------------------------------------------------------------------- reading
@dataclass
class _Row:
    line: int
    t: float
    left: int
    right: int
    pose: tuple[float, float, float]  # NaN where not measured


@dataclass
class _Group:
    run: str
    experiment: str
    rows: list[_Row] = field(default_factory=list)

    @property
    def lines(self) -> str:
        return f"lines {self.rows[0].line}–{self.rows[-1].line}"


def read_native(path: str | Path, *, robot: RobotSpec | None = None) -> list[Run]:
    """Read a native measured-log CSV into one :class:`Run` per run, in file order.

    Args:
        path: the CSV file.
        robot: if given, refuse encoder counts that jump between consecutive rows by more than
            ``1.5 · max_wheel_speed · dt / metres_per_tick + 2`` counts (a wheel cannot turn
            that far; the log dropped rows or the counter overflowed).

    Returns:
        Runs as logged (rows before the first measured pose included) with ``time`` from 0
        [s], ``counts`` from (0, 0), ``true_pose`` NaN where not measured and heading
        unwrapped over the measured rows, ``kind`` and ``direction`` from
        the experiment label, ``source`` ``"<file>:<first line>"`` and ``meta`` holding
        ``run``, ``experiment``, ``format`` (``"native"``) and ``lines`` (first, last).

    Raises:
        SpecError: naming file, line and column: an unreadable, non-UTF-8 or binary file; an
            empty file or one without data rows; missing, unknown or repeated columns; a row
            with the wrong number of cells; an empty ``run``, ``t`` or count cell; a
            non-numeric or non-finite cell; non-whole counts; time not increasing within a
            run; a run whose rows are not contiguous or whose label changes; a count jump
            beyond what a wheel can turn (with ``robot``); only one of ``x``, ``y``, or
            ``theta`` without them; a run with fewer than two rows. (Too little ground truth in
            a run is no defect of the file: empty pose cells are gaps.)
    """
    file = Path(path)
    return _parse(_read_text(file), str(file), robot)


def _read_text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise SpecError(f"cannot read native log: {reason}", source=str(path)) from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise SpecError(
            f"not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}): a native log "
            "is a CSV text file",
            source=f"{path}:{line}",
        ) from None
    nul = text.find("\x00")
    if nul >= 0:
        line = text.count("\n", 0, nul) + 1
        raise SpecError("binary data (a NUL byte), not a CSV text file", source=f"{path}:{line}")
    return text


def _cells(line: str, where: str) -> list[str]:
    try:
        return next(csv.reader([line], strict=True))
    except csv.Error as exc:
        raise SpecError(f"malformed CSV: {exc}", source=where) from None


def _parse(text: str, source: str, robot: RobotSpec | None) -> list[Run]:
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    numbered = [(n, line) for n, line in enumerate(lines, start=1) if line.strip()]
    expected = ",".join(COLUMNS)
    if not numbered:
        raise SpecError(f"empty file: expected a header row {expected}", source=source)
    header_line, header_text = numbered[0]
    index = _header(_cells(header_text, f"{source}:{header_line}"), f"{source}:{header_line}")
    if len(numbered) == 1:
        raise SpecError("no data rows after the header", source=f"{source}:{header_line}")

    runs: list[Run] = []
    finished: dict[str, str] = {}  # run id → its line range, to catch non-contiguous runs
    group: _Group | None = None
    for number, line in numbered[1:]:
        where = f"{source}:{number}"
        cells = _cells(line, where)
        if len(cells) != len(index):
            raise SpecError(
                f"expected {len(index)} cells ({', '.join(COLUMNS)}), got {len(cells)}",
                source=where,
            )
        run_id = cells[index["run"]].strip()
        label = cells[index["experiment"]].strip()
        if not run_id:
            raise SpecError(
                "column 'run' is empty: every row needs a run id", field="run", source=where
            )
        row = _parse_row(cells, index, number, where)
        if group is None or run_id != group.run:
            if group is not None:
                runs.append(_finish(group, source))
                finished[group.run] = group.lines
            if run_id in finished:
                other = group.run if group is not None else "?"
                raise SpecError(
                    f"run {run_id!r} appears again after run {other!r} (its rows were "
                    f"{finished[run_id]}): the rows of one run must be contiguous",
                    field="run",
                    source=where,
                )
            group = _Group(run_id, label)
        else:
            _check_step(group, row, label, robot, where)
        group.rows.append(row)
    assert group is not None
    runs.append(_finish(group, source))
    return runs


def _header(cells: list[str], where: str) -> dict[str, int]:
    names = [c.strip() for c in cells]
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise SpecError(
                f"column {name!r} appears twice in the header", field=name, source=where
            )
        seen.add(name)
    missing = [c for c in COLUMNS if c not in seen]
    if missing:
        raise SpecError(
            f"missing column(s) {', '.join(repr(c) for c in missing)}; a native log has the "
            f"columns {','.join(COLUMNS)}{_header_hint(names)}",
            field=missing[0],
            source=where,
        )
    extra = [n for n in names if n not in COLUMNS]
    if extra:
        raise SpecError(
            f"unknown column(s) {', '.join(repr(c) for c in extra)}; a native log has exactly "
            f"the columns {','.join(COLUMNS)}{_header_hint(names)}",
            field=extra[0],
            source=where,
        )
    return {name: position for position, name in enumerate(names)}


def _header_hint(names: list[str]) -> str:
    """A hint for a header that is nearly right: the usual slips behind a refused header."""
    if len(names) == 1 and any(mark in names[0] for mark in (";", "\t")):
        return " (the header holds no comma: columns are separated by commas)"
    if "" in names:
        return " (an empty column name: a trailing or doubled comma?)"
    if {n.lower() for n in names} >= set(COLUMNS) and not set(names) >= set(COLUMNS):
        return " (column names are lower case)"
    return ""


def _parse_row(cells: list[str], index: dict[str, int], number: int, where: str) -> _Row:
    t = _number(cells[index["t"]], "t", where)
    if t is None:
        raise SpecError("column 't' is empty: every row needs a time", field="t", source=where)
    left = _count(cells[index["ticks_left"]], "ticks_left", where)
    right = _count(cells[index["ticks_right"]], "ticks_right", where)
    x, y, theta = (_number(cells[index[c]], c, where) for c in _POSE)
    if (x is None) != (y is None):
        given, empty = ("x", "y") if y is None else ("y", "x")
        raise SpecError(
            f"column {given!r} is given but {empty!r} is empty: a position needs both "
            "(leave both empty where it was not measured)",
            field=empty,
            source=where,
        )
    if theta is not None and x is None:
        raise SpecError(
            "column 'theta' is given but 'x' and 'y' are empty: a measured heading needs its "
            "position",
            field="x",
            source=where,
        )
    nan = math.nan
    pose = (
        nan if x is None else x,
        nan if y is None else y,
        nan if theta is None else theta,
    )
    return _Row(number, t, left, right, pose)


def _number(cell: str, column: str, where: str) -> float | None:
    text = cell.strip()
    if not text:
        return None
    try:
        value = float(text)
    except ValueError:
        raise SpecError(
            f"column {column!r} is not a number: {text!r}", field=column, source=where
        ) from None
    if not math.isfinite(value):
        raise SpecError(
            f"column {column!r} is not finite: {text!r} (leave the cell empty where nothing "
            "was measured)",
            field=column,
            source=where,
        )
    return value


def _count(cell: str, column: str, where: str) -> int:
    text = cell.strip()
    if not text:
        raise SpecError(
            f"column {column!r} is empty: every row needs both encoder counts",
            field=column,
            source=where,
        )
    try:
        value = int(text)
    except ValueError:
        number = _number(text, column, where)
        assert number is not None
        if not number.is_integer():
            raise SpecError(
                f"column {column!r} must hold a whole number of encoder counts, got {text!r}",
                field=column,
                source=where,
            ) from None
        value = int(number)
    if abs(value) >= _MAX_COUNT:
        raise SpecError(f"column {column!r} is out of range: {text!r}", field=column, source=where)
    return value


def _check_step(group: _Group, row: _Row, label: str, robot: RobotSpec | None, where: str) -> None:
    previous = group.rows[-1]
    if label != group.experiment:
        raise SpecError(
            f"run {group.run!r} changes its experiment label from {group.experiment!r} (line "
            f"{group.rows[0].line}) to {label!r}: one run has one label",
            field="experiment",
            source=where,
        )
    if row.t <= previous.t:
        raise SpecError(
            f"time must increase within run {group.run!r}, but t = {row.t!r} s follows "
            f"t = {previous.t!r} s on line {previous.line}",
            field="t",
            source=where,
        )
    if robot is None:
        return
    dt = row.t - previous.t
    limit = _JUMP_SPEED_MARGIN * robot.max_wheel_speed * dt / robot.metres_per_tick + _JUMP_SLACK
    for column, now, before in (
        ("ticks_left", row.left, previous.left),
        ("ticks_right", row.right, previous.right),
    ):
        jump = now - before
        if abs(jump) > limit:
            raise SpecError(
                f"{column} jumps by {jump:+d} counts in {dt:.6g} s (from line {previous.line}), "
                f"more than the {limit:.1f} counts a wheel can turn (1.5 × max_wheel_speed "
                f"{robot.max_wheel_speed:g} m/s · dt / {robot.metres_per_tick:.6g} m per count "
                "+ 2): dropped rows or a counter overflow? (a robot that drives faster needs "
                "its max_wheel_speed in the robot file; a ticks_per_rev too small or a "
                "wheel_diameter too large gives the same)",
                field=column,
                source=where,
            )


def _finish(group: _Group, source: str) -> Run:
    rows = group.rows
    first = rows[0]
    where = f"{source}:{first.line}"
    if len(rows) < 2:
        raise SpecError(
            f"run {group.run!r} has only one row (line {first.line}): a run needs at least two "
            "samples",
            field="run",
            source=where,
        )
    pose = np.array([r.pose for r in rows], dtype=np.float64)
    measured = ~np.isnan(pose[:, 2])
    pose[measured, 2] = np.unwrap(pose[measured, 2])
    time = np.array([r.t for r in rows], dtype=np.float64)
    counts = np.array([(r.left, r.right) for r in rows], dtype=np.int64)
    kind, direction = experiment_kind(group.experiment)
    return Run(
        kind=kind,
        time=time - time[0],
        counts=counts - counts[0],
        true_pose=pose,
        direction=direction,
        source=where,
        meta={
            "run": group.run,
            "experiment": group.experiment,
            "format": "native",
            "lines": (first.line, rows[-1].line),
        },
    )


# ---------------------------------------------------------------------------------- writing
def write_native(
    path: str | Path, runs: Sequence[Run], *, experiments: Sequence[str] | None = None
) -> None:
    """Write ``runs`` as a native measured-log CSV, atomically (temp file, then rename).

    Run ids come from ``run.meta["run"]`` (else the 1-based position); experiment labels from
    ``experiments`` (one per run), else ``run.meta["experiment"]``, else the kind and direction
    (``square_cw``, ``straight``). Time and counts are written relative to each run's first
    sample, floats with ``repr`` precision (a write → :func:`read_native` round trip is exact),
    NaN pose cells empty.

    Raises:
        SpecError: nothing is written if ``experiments`` has the wrong length, two runs share an
            id, an id or label is empty or holds a line break, or a run could not be read back:
            non-finite time or counts, infinite pose, time not increasing, only one of x/y,
            or theta without x/y.
        OSError: the file cannot be written (nothing is left behind).
    """
    target = Path(path)
    if experiments is not None and len(experiments) != len(runs):
        raise SpecError(
            f"experiments= has {len(experiments)} labels for {len(runs)} runs",
            field="experiments",
        )
    if not runs:
        raise SpecError("no runs to write", source=str(target))
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(COLUMNS)
    seen: dict[str, int] = {}
    for position, run in enumerate(runs, start=1):
        run_id = str(run.meta.get("run", position)).strip()
        label = _label(run, None if experiments is None else experiments[position - 1])
        what = f"run {position} (id {run_id!r})"
        for name, value in (("run id", run_id), ("experiment label", label)):
            if "\n" in value or "\r" in value:
                raise SpecError(f"{what}: the {name} holds a line break", field="run")
        if not run_id:
            raise SpecError(f"run {position} has an empty id (meta['run'])", field="run")
        if run_id in seen:
            raise SpecError(
                f"{what} has the same id as run {seen[run_id]}: ids must be unique",
                field="run",
            )
        seen[run_id] = position
        _check_writable(run, what)
        time = np.asarray(run.time, dtype=np.float64)
        counts = np.asarray(run.counts, dtype=np.int64)
        time = time - time[0]
        counts = counts - counts[0]
        for i in range(len(time)):
            writer.writerow(
                [
                    run_id,
                    label,
                    repr(float(time[i])),
                    str(int(counts[i, 0])),
                    str(int(counts[i, 1])),
                    *(_cell(float(v)) for v in run.true_pose[i]),
                ]
            )
    text = buffer.getvalue()
    _parse(text, f"{target} (refused, not written)", None)  # whatever is written reads back
    atomic_write_text(target, text)


def _label(run: Run, given: str | None) -> str:
    if given is not None:
        return str(given).strip()
    label = run.meta.get("experiment")
    if label is not None:
        return str(label).strip()
    return run.kind if run.direction is None else f"{run.kind}_{run.direction}"


def _cell(value: float) -> str:
    return "" if math.isnan(value) else repr(value)


def _check_writable(run: Run, what: str) -> None:
    time = np.asarray(run.time, dtype=np.float64)
    pose = np.asarray(run.true_pose, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise SpecError(f"{what}: time of sample {bad[0]} is {float(time[bad[0]])!r}", field="t")
    steps = np.flatnonzero(np.diff(time) <= 0.0)
    if steps.size:
        i = int(steps[0]) + 1
        raise SpecError(
            f"{what}: time must increase, but sample {i} (t = {time[i]!r} s) follows "
            f"t = {time[i - 1]!r} s",
            field="t",
        )
    if np.any(np.isinf(pose)):
        i, j = (int(v) for v in np.argwhere(np.isinf(pose))[0])
        raise SpecError(f"{what}: {_POSE[j]} of sample {i} is infinite", field=_POSE[j])
    nan = np.isnan(pose)
    half = np.flatnonzero(nan[:, 0] != nan[:, 1])
    if half.size:
        raise SpecError(f"{what}: sample {half[0]} has only one of x and y", field="x")
    lone = np.flatnonzero(nan[:, 0] & ~nan[:, 2])
    if lone.size:
        raise SpecError(f"{what}: sample {lone[0]} has theta without x and y", field="x")

"""Reader of the OptiOdom data format (its sessions are served to calibrators by
:class:`odomgym.lab.recorded.RecordedLab`).

The OptiOdom data (R. B. Sousa, M. R. Petry, A. P. Moreira, P. Costa, *OptiOdom: a Generic
Approach for Odometry Calibration of Wheeled Mobile Robots*, J. Intell. Robot. Syst. 105:39,
2022; MIT licence; code and data at github.com/sousarbarb/optiodom) hold runs of a real
differential-drive robot with OptiTrack ground truth. One *session* is a folder::

    <path-type>/<session>/<session>_metadata.csv
    <path-type>/<session>/<session>_run-01.csv … _run-NN.csv

**Run files** have no header and six columns: time [s], x_gt [m], y_gt [m], θ_gt [rad], then the
encoder counts of *this sampling cycle* for the **right** wheel, then the **left** wheel (the
authors' ``loadData.m`` takes columns 5:end as ``Odo``, and ``simulateRobot_diff.m`` pairs them
with ``D = [D_R, D_L]``). Samples are 50 ms apart.

**Metadata** rows are ``key, value, value, …``: ``type`` (``diff``), ``ngear`` (gear ratio),
``encRes`` (counts per motor revolution), ``Li`` (wheelbase [m]), ``Di`` (D_R, D_L [m]), ``Thi``
(unused for ``diff``), ``N`` (runs), ``L`` (square side [m], empty for other paths),
``imarkers`` (OptiTrack marker ids) and the per-run synchronisation windows ``gt_ti``,
``gt_tf``, ``odo_ti``, ``odo_tf`` [s].

Conventions taken from the authors' code (``src/diff/umbmark/main.m``, ``loadData.m``,
``src/sousa-et-al/simulateRobot_diff.m``, ``src/synchonization/processOptiTrackData.m``):

* The synchronisation windows were applied *when the run files were written*
  (``processOptiTrackData.m`` cuts both streams to them and resamples the ground truth onto the
  odometry clock); the calibration code (``loadData.m``) reads the run file whole and never looks
  at them again. So does this reader; it only checks that each run file lasts
  ``odo_tf − odo_ti`` (a truncated file fails loudly instead of giving a wrong return error).
* The ground truth was already moved to the run's start frame (first pose (0, 0, 0)) and its
  heading unwrapped by the synchronisation; the reader unwraps again, which is idempotent.
* Odometry starts at the first ground-truth pose and integrates row i's increment between
  samples i−1 and i, so the first row's increment is never used. Cumulative counts here
  therefore start at 0 and leave the first row's increment out.
* Squares (``main.m``, the README of ``src/diff/umbmark``): the first N/2 runs are cw, the last
  N/2 ccw. Ivanjko paths (``src/diff/ivanjko-et-al/main.m``): the first N/3 runs are straight
  lines, then N/3 cw and N/3 ccw on-the-spot turns of 180°. The reader checks these positions
  against the turning direction the ground truth shows and refuses a session where they
  disagree.
* The nominal robot is the one in the session's own metadata. (The authors' scripts read the
  robot from one fixed metadata file per method; their OptiOdom and Ivanjko rows in
  ``published_results.csv`` use b = 0.2 m, D = 0.084 m for every session, their UMBmark and
  Jung & Chung rows the session's own values.) Pass another robot to
  :class:`~odomgym.lab.recorded.RecordedLab` to reproduce the former.
"""

from __future__ import annotations

import csv
import datetime
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.errors import SpecError, require_positive
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import MAX_RUN_LENGTH, MIN_RUN_LENGTH, Direction, Run
from odomgym.robot import ROBOT_RANGES, RobotSpec

__all__ = [
    "PATH_TYPES",
    "PathType",
    "Session",
    "SyncWindow",
    "find_sessions",
    "read_session",
    "session_time",
]

FloatArray = NDArray[np.float64]
PathType = Literal["square", "circular", "ivanjko", "free"]
PATH_TYPES: tuple[PathType, ...] = ("square", "circular", "ivanjko", "free")

RUN_COLUMNS = ("time", "x_gt", "y_gt", "theta_gt", "odoR", "odoL")
SPIN_ANGLE = math.pi  # Ivanjko's path: on-the-spot turns of 180° [rad]
_REQUIRED_FIELDS = ("type", "ngear", "encRes", "Li", "Di", "N")
_WINDOW_FIELDS = ("gt_ti", "gt_tf", "odo_ti", "odo_tf")


@dataclass(frozen=True)
class SyncWindow:
    """The time windows the authors cut one run to when synchronising it [s].

    Attributes:
        gt_start, gt_end: window on the OptiTrack clock (``gt_ti``, ``gt_tf``).
        odo_start, odo_end: window on the odometry clock (``odo_ti``, ``odo_tf``).
    """

    gt_start: float
    gt_end: float
    odo_start: float
    odo_end: float

    @property
    def duration(self) -> float:
        """Length of the odometry window, which the run file spans [s]."""
        return self.odo_end - self.odo_start


@dataclass(frozen=True)
class Session:
    """One recorded session: the nominal robot, its initial calibration and its runs.

    Attributes:
        name: the session id (the file-name prefix, e.g. ``"230620202042"``).
        directory: the session folder.
        path_type: ``"square"``, ``"circular"``, ``"ivanjko"`` or ``"free"``.
        robot: nominal robot from the metadata: ``wheelbase`` = Li [m], ``wheel_diameter`` =
            mean of Di [m], ``ticks_per_rev`` = ngear · encRes [counts/wheel revolution].
        initial: the calibration equivalent to the metadata's (Li, D_R, D_L) on ``robot``
            (the identity unless D_R ≠ D_L).
        side: square side L [m] (0 when the metadata gives none).
        runs: the runs in file order.
        windows: the synchronisation window of each run, or ``None`` if the metadata has none.
        markers: OptiTrack marker ids (``imarkers``), for provenance.
    """

    name: str
    directory: Path
    path_type: PathType
    robot: RobotSpec
    initial: Calibration
    side: float
    runs: tuple[Run, ...]
    windows: tuple[SyncWindow, ...] | None = None
    markers: tuple[int, ...] = ()

    @property
    def n_runs(self) -> int:
        """Number of runs."""
        return len(self.runs)

    def select(self, kind: str, direction: Direction | None = None) -> list[Run]:
        """The runs of ``kind`` (and ``direction``, unless ``None``), in file order."""
        return [
            r
            for r in self.runs
            if r.kind == kind and (direction is None or r.direction == direction)
        ]

    def holdings(self) -> dict[str, int]:
        """How many runs of each kind and direction the session holds, e.g. ``{"square cw": 3}``."""
        counts: dict[str, int] = {}
        for run in self.runs:
            key = run.kind if run.direction is None else f"{run.kind} {run.direction}"
            counts[key] = counts.get(key, 0) + 1
        return counts


def find_sessions(root: str | Path) -> list[Path]:
    """All session folders below ``root`` (folders holding one ``*_metadata.csv``), sorted."""
    return sorted({p.parent for p in Path(root).rglob("*_metadata.csv")})


def session_time(name: str) -> datetime.datetime | None:
    """When a session was recorded, from its name, or None if the name is not a timestamp.

    The OptiOdom recordings name each session by its start as ``DDMMYYYYhhmm`` (Sousa et al.
    2022's data set: ``230620202042`` is 23 June 2020, 20:42; the 14 June sessions run from
    23 to 25 June 2020). ``odomgym fleet`` groups a robot's sessions into periods by it."""
    if len(name) != 12 or not name.isdigit():
        return None
    try:
        return datetime.datetime.strptime(name, "%d%m%Y%H%M")
    except ValueError:  # 12 digits that are no date (month 13, day 32, …)
        return None


def read_session(
    directory: str | Path,
    *,
    path_type: PathType | None = None,
    check_windows: bool = True,
) -> Session:
    """Read an OptiOdom session folder into a :class:`Session`.

    Args:
        directory: the session folder (``…/<path-type>/<session>``).
        path_type: override the path type; default: the parent folder's name.
        check_windows: check that each run file lasts as long as its odometry window
            (``odo_tf − odo_ti``, to half a sample) when the metadata gives windows.

    Raises:
        SpecError: for anything malformed, naming the file and, where there is one, the line:
            a missing folder, metadata file or run file; a missing or non-numeric metadata
            field; a robot value in other units (``Li`` or ``Di`` outside the wheelbase or
            wheel-diameter range of :data:`~odomgym.robot.ROBOT_RANGES`, in millimetres say;
            ``ngear × encRes`` outside its ``ticks_per_rev``) or a side ``L`` whose run is
            longer than a lab drives, each at its metadata line and under its metadata key;
            an empty session; missing or extra columns, non-numeric or non-finite values,
            non-integer counts or non-increasing time in a run file; an odd number of square
            runs; a run whose turning direction contradicts its position in the session.
    """
    folder = Path(directory)
    if folder.is_file():
        raise SpecError(
            "is a file: an OptiOdom session is a folder (its *_metadata.csv and run files); "
            "`odomgym diagnose` reads logs of other formats",
            source=str(folder),
        )
    if not folder.is_dir():
        raise SpecError("session folder does not exist", source=str(folder))
    metas = sorted(folder.glob("*_metadata.csv"))
    if not metas:
        raise SpecError("no <session>_metadata.csv in the session folder", source=str(folder))
    if len(metas) > 1:
        names = ", ".join(p.name for p in metas)
        raise SpecError(f"more than one metadata file: {names}", source=str(folder))
    meta_path = metas[0]
    name = meta_path.name[: -len("_metadata.csv")]
    kind = _path_type(folder, path_type)
    meta = _Metadata.read(meta_path)

    robot_type = meta.text("type")
    if robot_type != "diff":
        raise SpecError(
            f"only differential-drive sessions (type 'diff') are supported, got {robot_type!r}",
            field="type",
            source=meta.where("type"),
        )
    ngear = meta.positive("ngear")
    enc_res = meta.positive("encRes")
    meta.check_ticks(ngear, enc_res)
    wheelbase = meta.within("Li", meta.positive("Li"), "wheelbase", "the wheelbase in metres")
    right_diameter, left_diameter = (
        meta.within("Di", d, "wheel_diameter", "the wheel diameters D_R, D_L in metres")
        for d in meta.positives("Di", 2)
    )
    n_runs = meta.count("N")
    side = meta.optional_positive("L")
    if kind == "square" and side is None:
        raise SpecError(
            "a square session needs the square side L", field="L", source=meta.where("L")
        )
    if side is not None:
        meta.check_side(side, legs=4 if kind == "square" else 1)
    windows = meta.windows(n_runs)
    markers = tuple(int(v) for v in meta.optional_numbers("imarkers"))

    robot = RobotSpec(
        wheel_diameter=0.5 * (right_diameter + left_diameter),
        wheelbase=wheelbase,
        ticks_per_rev=ngear * enc_res,
        name=f"optiodom-{name}",
        source=str(meta_path),
    )
    initial = Calibration.from_parameters(robot, wheelbase, right_diameter, left_diameter)

    files = _run_files(folder, name, n_runs, meta)
    layout = _layout(kind, n_runs, meta)
    runs: list[Run] = []
    for index, (path, (run_kind, direction)) in enumerate(zip(files, layout, strict=True)):
        data = _read_run_file(path)
        if windows is not None and check_windows:
            _check_window(path, data, windows[index], meta, index)
        runs.append(_make_run(data, path, run_kind, direction, kind, side, name, index, windows))
    return Session(
        name=name,
        directory=folder,
        path_type=kind,
        robot=robot,
        initial=initial,
        side=side if side is not None else 0.0,
        runs=tuple(runs),
        windows=windows,
        markers=markers,
    )


def _path_type(folder: Path, override: PathType | None) -> PathType:
    if override is not None:
        if override not in PATH_TYPES:
            raise SpecError(
                f"unknown path type {override!r}; known: {', '.join(PATH_TYPES)}",
                field="path_type",
            )
        return override
    parent = folder.resolve().parent.name
    for known in PATH_TYPES:
        if parent == known:
            return known
    raise SpecError(
        f"cannot tell the path type from the parent folder {parent!r} (expected one of "
        f"{', '.join(PATH_TYPES)}): put the session folder in a folder named after its path "
        "type, as the OptiOdom data set lays them out (square/230620202042/); in Python "
        "path_type=",
        source=str(folder),
    )


class _Metadata:
    """The metadata rows by key, with the line each came from (for error messages)."""

    def __init__(self, path: Path, rows: dict[str, tuple[int, list[str]]]) -> None:
        self.path = path
        self.rows = rows

    @classmethod
    def read(cls, path: Path) -> _Metadata:
        try:
            text = path.read_text(encoding="utf-8-sig")
        except OSError as exc:
            raise SpecError(f"cannot read metadata: {exc.strerror}", source=str(path)) from None
        except UnicodeDecodeError:
            raise SpecError("metadata is not UTF-8 text", source=str(path)) from None
        rows: dict[str, tuple[int, list[str]]] = {}
        for number, cells in enumerate(csv.reader(text.splitlines()), start=1):
            cells = [c.strip() for c in cells]
            if not any(cells):
                continue
            values = cells[1:]
            while values and values[-1] == "":
                values.pop()  # MATLAB's writecell pads every row to the widest one
            key = cells[0]
            if key in rows:
                raise SpecError(
                    f"field {key!r} given twice (first on line {rows[key][0]})",
                    field=key,
                    source=f"{path}:{number}",
                )
            rows[key] = (number, values)
        for key in _REQUIRED_FIELDS:
            if key not in rows:
                raise SpecError(f"missing metadata field {key!r}", field=key, source=str(path))
        return cls(path, rows)

    def where(self, key: str) -> str:
        row = self.rows.get(key)
        return f"{self.path}:{row[0]}" if row else str(self.path)

    def values(self, key: str) -> list[str]:
        row = self.rows.get(key)
        return row[1] if row else []

    def text(self, key: str) -> str:
        values = self.values(key)
        if not values:
            raise SpecError(f"metadata field {key!r} is empty", field=key, source=self.where(key))
        return values[0]

    def _number(self, key: str, value: str) -> float:
        try:
            number = float(value)
        except ValueError:
            raise SpecError(
                f"metadata field {key!r} must be a number, got {value!r}",
                field=key,
                source=self.where(key),
            ) from None
        if not math.isfinite(number):
            raise SpecError(
                f"metadata field {key!r} must be finite, got {value!r}",
                field=key,
                source=self.where(key),
            )
        return number

    def positive(self, key: str) -> float:
        return require_positive(key, self._number(key, self.text(key)), source=self.where(key))

    def positives(self, key: str, count: int) -> list[float]:
        values = self.values(key)
        if len(values) < count:
            raise SpecError(
                f"metadata field {key!r} needs {count} values, got {len(values)}",
                field=key,
                source=self.where(key),
            )
        return [
            require_positive(key, self._number(key, v), source=self.where(key))
            for v in values[:count]
        ]

    def within(self, key: str, value: float, robot_field: str, meaning: str) -> float:
        """``value`` of ``key`` if it lies in the range :data:`~odomgym.robot.ROBOT_RANGES`
        allows the robot field it becomes, else a :class:`SpecError` at the key's line.

        Why here and not left to :class:`~odomgym.robot.RobotSpec`: the robot would refuse the
        value too, but under its own field name (``wheelbase``) and without the file, so a
        session written in millimetres (``Li,200``) told the user nothing about where to look.
        """
        low, high = ROBOT_RANGES[robot_field]
        if not low <= value <= high:
            raise SpecError(
                f"{key} must lie in [{low}, {high}] m ({meaning}), got {value!r}",
                field=key,
                source=self.where(key),
            )
        return value

    def check_ticks(self, ngear: float, enc_res: float) -> None:
        """Refuse counts per wheel revolution (``ngear`` · ``encRes``) the robot cannot have
        (:data:`~odomgym.robot.ROBOT_RANGES` ``ticks_per_rev``), at the line of the factor
        that is the likelier culprit: the larger one when the product is too large, the
        smaller one when it is too small (a gear ratio and an encoder resolution are both
        usually > 1, so the odd one out is the one that broke the product)."""
        low, high = ROBOT_RANGES["ticks_per_rev"]
        ticks = ngear * enc_res
        if low <= ticks <= high:
            return
        blamed = "encRes" if (enc_res >= ngear) == (ticks > high) else "ngear"
        other = "ngear" if blamed == "encRes" else "encRes"
        raise SpecError(
            f"ngear × encRes (counts per wheel revolution) must lie in [{low:g}, {high:g}], "
            f"got {ngear:g} × {enc_res:g} = {ticks:g}: is {blamed} (or {other}, line "
            f"{self.rows[other][0]}) in other units?",
            field=blamed,
            source=self.where(blamed),
        )

    def check_side(self, side: float, *, legs: int) -> None:
        """Refuse a side ``L`` [m] whose run (``legs`` sides: 4 on a square, 1 on a straight
        line) a lab may not drive (:data:`~odomgym.odometry.runs.MIN_RUN_LENGTH` ..
        :data:`~odomgym.odometry.runs.MAX_RUN_LENGTH`): the calibrator would otherwise refuse it
        later as a bare ``size``, without the metadata file (``L,750``: millimetres)."""
        low, high = MIN_RUN_LENGTH / legs, MAX_RUN_LENGTH / legs
        if not low <= side <= high:
            raise SpecError(
                f"L must lie in [{low:g}, {high:g}] m (the side in metres; a run drives "
                f"{legs} × L, at most {MAX_RUN_LENGTH:g} m), got {side!r}",
                field="L",
                source=self.where("L"),
            )

    def optional_positive(self, key: str) -> float | None:
        return self.positive(key) if self.values(key) else None

    def optional_numbers(self, key: str) -> list[float]:
        return [self._number(key, v) for v in self.values(key)]

    def count(self, key: str) -> int:
        number = self._number(key, self.text(key))
        if number != int(number) or number < 1:
            raise SpecError(
                f"metadata field {key!r} must be a whole number of runs >= 1 (an empty "
                f"session cannot be calibrated on), got {self.text(key)!r}",
                field=key,
                source=self.where(key),
            )
        return int(number)

    def windows(self, n_runs: int) -> tuple[SyncWindow, ...] | None:
        present = [k for k in _WINDOW_FIELDS if self.values(k)]
        if not present:
            return None
        for key in _WINDOW_FIELDS:
            if len(self.values(key)) != n_runs:
                raise SpecError(
                    f"synchronisation window {key!r} needs one value per run ({n_runs}), "
                    f"got {len(self.values(key))}",
                    field=key,
                    source=self.where(key),
                )
        columns = [self.optional_numbers(k) for k in _WINDOW_FIELDS]
        windows = tuple(SyncWindow(*row) for row in zip(*columns, strict=True))
        for i, w in enumerate(windows):
            if w.gt_end <= w.gt_start or w.odo_end <= w.odo_start:
                raise SpecError(
                    f"synchronisation window of run {i + 1} ends before it starts: "
                    f"gt [{w.gt_start}, {w.gt_end}], odo [{w.odo_start}, {w.odo_end}]",
                    field="odo_tf",
                    source=self.where("odo_tf"),
                )
        return windows


def _run_files(folder: Path, name: str, n_runs: int, meta: _Metadata) -> list[Path]:
    pattern = re.compile(rf"^{re.escape(name)}_run-(\d+)\.csv$")
    numbers = sorted(
        int(m.group(1)) for p in folder.iterdir() if (m := pattern.match(p.name)) is not None
    )
    expected = list(range(1, n_runs + 1))
    if numbers != expected:
        missing = sorted(set(expected) - set(numbers))
        extra = sorted(set(numbers) - set(expected))
        detail = []
        if missing:
            detail.append("missing run " + ", ".join(f"{n:02d}" for n in missing))
        if extra:
            detail.append("unexpected run " + ", ".join(f"{n:02d}" for n in extra))
        raise SpecError(
            f"metadata says N = {n_runs} runs but the folder {folder} holds "
            f"{len(numbers)} run file{'' if len(numbers) == 1 else 's'} ({'; '.join(detail)})",
            field="N",
            source=meta.where("N"),
        )
    return [folder / f"{name}_run-{n:02d}.csv" for n in expected]


def _layout(kind: PathType, n_runs: int, meta: _Metadata) -> list[tuple[str, Direction | None]]:
    """(kind, direction) of each run from its position, as the authors' scripts assume."""
    if kind == "square":
        if n_runs % 2:
            raise SpecError(
                f"a square session needs as many cw as ccw runs (first N/2 cw, last N/2 ccw), "
                f"but N = {n_runs} is odd",
                field="N",
                source=meta.where("N"),
            )
        half = n_runs // 2
        cw: tuple[str, Direction | None] = ("square", "cw")
        ccw: tuple[str, Direction | None] = ("square", "ccw")
        return [cw] * half + [ccw] * half
    if kind == "ivanjko":
        if n_runs % 3:
            raise SpecError(
                f"an Ivanjko session needs N/3 straight, N/3 cw and N/3 ccw runs, "
                f"but N = {n_runs} is not a multiple of 3",
                field="N",
                source=meta.where("N"),
            )
        third = n_runs // 3
        straight: tuple[str, Direction | None] = ("straight", None)
        spin_cw: tuple[str, Direction | None] = ("spin", "cw")
        spin_ccw: tuple[str, Direction | None] = ("spin", "ccw")
        return [straight] * third + [spin_cw] * third + [spin_ccw] * third
    return [("free", None)] * n_runs


def _read_run_file(path: Path) -> FloatArray:
    """Parse one run file into a (T, 6) array, naming the file and line of any defect."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise SpecError(f"cannot read run file: {exc.strerror}", source=str(path)) from None
    except UnicodeDecodeError:
        raise SpecError("run file is not UTF-8 text", source=str(path)) from None
    rows: list[list[float]] = []
    width = len(RUN_COLUMNS)
    previous_time = -math.inf
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        where = f"{path}:{number}"
        cells = line.split(",")
        if len(cells) != width:
            raise SpecError(
                f"expected {width} columns ({', '.join(RUN_COLUMNS)}), got {len(cells)}",
                source=where,
            )
        row: list[float] = []
        for column, cell in zip(RUN_COLUMNS, cells, strict=True):
            try:
                value = float(cell)
            except ValueError:
                raise SpecError(
                    f"column {column!r} is not a number: {cell.strip()!r}", source=where
                ) from None
            if not math.isfinite(value):
                raise SpecError(f"column {column!r} is not finite: {cell.strip()!r}", source=where)
            row.append(value)
        for column, value in zip(RUN_COLUMNS[4:], row[4:], strict=True):
            if value != round(value):
                raise SpecError(
                    f"column {column!r} must hold whole encoder counts, got {value!r}",
                    source=where,
                )
        if row[0] <= previous_time:
            raise SpecError(
                f"time must increase, but {row[0]!r} follows {previous_time!r}", source=where
            )
        previous_time = row[0]
        rows.append(row)
    if len(rows) < 2:
        raise SpecError(f"a run needs at least two samples, got {len(rows)}", source=str(path))
    return np.asarray(rows, dtype=np.float64)


def _check_window(
    path: Path, data: FloatArray, window: SyncWindow, meta: _Metadata, index: int
) -> None:
    duration = float(data[-1, 0] - data[0, 0])
    period = float(np.median(np.diff(data[:, 0])))
    if abs(duration - window.duration) > 0.5 * period + 1e-6:
        raise SpecError(
            f"run {index + 1} ({path.name}) lasts {duration:.3f} s, but its odometry window "
            f"odo_tf − odo_ti is {window.duration:.3f} s: truncated or wrong run file? "
            "(pass check_windows=False to read it anyway)",
            field="odo_tf",
            source=meta.where("odo_tf"),
        )


def _make_run(
    data: FloatArray,
    path: Path,
    kind: str,
    direction: Direction | None,
    path_type: PathType,
    side: float | None,
    session: str,
    index: int,
    windows: tuple[SyncWindow, ...] | None,
) -> Run:
    increments = data[:, [5, 4]].astype(np.int64)  # file order is right, left
    first_increment = increments[0].copy()
    increments[0] = 0  # never used by the authors' odometry (it starts at sample 1)
    counts = np.cumsum(increments, axis=0)
    true_pose = data[:, 1:4].copy()
    true_pose[:, 2] = np.unwrap(true_pose[:, 2])
    net_turn = float(true_pose[-1, 2] - true_pose[0, 2])
    measured: Direction = "ccw" if net_turn > 0.0 else "cw"
    if direction is not None and measured != direction:
        position = "first" if direction == "cw" else "last"
        raise SpecError(
            f"run {index + 1} is in the {position} part of the session, which the authors' "
            f"convention makes {direction} {kind} runs, but its ground truth turned "
            f"{net_turn:+.3f} rad ({measured}): the run order does not follow the convention",
            source=str(path),
        )
    meta: dict[str, object] = {
        "session": session,
        "index": index + 1,
        "path_type": path_type,
        "turn": measured,
        "net_turn": net_turn,
    }
    if first_increment.any():
        meta["dropped_first_increment"] = (int(first_increment[0]), int(first_increment[1]))
    if windows is not None:
        meta["window"] = windows[index]
    if kind == "spin":
        meta["angle"] = SPIN_ANGLE
    run_side = side if side is not None and kind in ("square", "straight") else 0.0
    return Run(
        kind=kind,
        time=data[:, 0].copy(),
        counts=counts,
        true_pose=true_pose,
        direction=direction,
        side=run_side,
        source=str(path),
        meta=meta,
    )

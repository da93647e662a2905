"""One entry point for measured logs in any supported format: :func:`read_log`.

Formats: ``native`` (odomgym's CSV, :mod:`odomgym.data.native`), ``optiodom`` (a session folder
or a folder of sessions, :mod:`odomgym.data.optiodom`) and ``rosbag`` (ROS 2 bags,
:mod:`odomgym.data.rosbag2`). Without ``format`` the layout decides: a ``.csv`` file is native,
a folder holding ``*_metadata.csv`` files is OptiOdom, a bag folder (``metadata.yaml``) or an
``.mcap``/``.db3`` file is a ROS 2 bag, and any other folder holding ``.csv`` files is a folder
of native logs (:func:`native_sessions`): each file one session, directly in the folder or in
one sub-folder per period — the layout of one robot's folder of ``odomgym fleet``, whose
``robot.toml``, when there, is the folder's nominal robot. A folder holding logs of two formats
(native logs, whose header names the native columns, beside OptiOdom sessions or bags) is
refused in one line: read as one, the other's logs were dropped without a word.

Every format's runs come out the same way: poses a tracker held while the wheels turned are made
gaps (:func:`odomgym.data.gaps.mark_held_poses`; how many, per run, in ``meta["held_poses"]``),
and a run is returned as it was logged otherwise — rows before its first full pose, or a run
without one, included (:func:`odomgym.diagnose.screen.screen_runs` decides what can be used).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Literal

from odomgym.data.gaps import mark_held_poses
from odomgym.errors import SpecError
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "FORMATS",
    "LogFormat",
    "detect_format",
    "native_sessions",
    "period_logs",
    "read_log",
    "session_name",
]

LogFormat = Literal["native", "optiodom", "rosbag"]
FORMATS: tuple[LogFormat, ...] = ("native", "optiodom", "rosbag")


def detect_format(path: Path) -> LogFormat:
    """The format of ``path`` from its layout (see the module docstring)."""
    if not path.exists():
        raise SpecError("no such file or folder", field="DATA", source=str(path))
    if path.is_file():
        if path.suffix.lower() == ".csv":
            return "native"
        if path.suffix.lower() in (".mcap", ".db3"):
            return "rosbag"
    else:
        found: dict[LogFormat, str] = {}
        optiodom = next(path.rglob("*_metadata.csv"), None)
        if optiodom is not None:
            found["optiodom"] = f"OptiOdom sessions ({optiodom.parent.relative_to(path)}/)"
        bag = next(
            (p for pattern in ("metadata.yaml", "*.mcap", "*.db3") for p in path.rglob(pattern)),
            None,
        )
        if bag is not None:
            found["rosbag"] = f"ROS 2 bags ({bag.relative_to(path)})"
        csv_logs = [log for _, log in native_sessions(path)]
        native = [log for log in csv_logs if _looks_native(log)]
        if native:
            found["native"] = f"native CSV logs ({native[0].relative_to(path)})"
        elif csv_logs and not found:
            return "native"  # CSV files that are no native logs: the reader says why
        if len(found) > 1:
            # Read as the first format found, the others were dropped without a word (a
            # folder's CSV logs and its robot.toml beside an OptiOdom session).
            raise SpecError(
                f"holds logs of {len(found)} formats: {' and '.join(found.values())}; "
                "diagnose reads one at a time: move the others apart, or name the one to "
                "read with --format",
                field="format",
                source=str(path),
            )
        if found:
            return next(iter(found))
    raise SpecError(
        "cannot tell the log format (a .csv file or a folder of them, an OptiOdom folder or a "
        "ROS 2 bag); "
        "give --format native|optiodom|rosbag",
        field="format",
        source=str(path),
    )


def read_log(
    path: str | Path,
    *,
    robot: RobotSpec | None = None,
    format: LogFormat | None = None,
    pose_topic: str | None = None,
    joint_topic: str | None = None,
    encoder_topic: str | None = None,
    left_joint: str = "left_wheel_joint",
    right_joint: str = "right_wheel_joint",
) -> tuple[list[Run], RobotSpec | None]:
    """Read every run of ``path``; returns the runs, their held poses made gaps (module
    docstring), and the nominal robot: for OptiOdom data its (first) session's metadata's, for
    a folder of native logs its ``robot.toml`` when there and ``robot`` is not given, else
    ``None``."""
    runs, nominal = _read(
        Path(path),
        robot,
        format,
        pose_topic,
        joint_topic,
        encoder_topic,
        left_joint,
        right_joint,
    )
    return [mark_held_poses(run)[0] for run in runs], nominal


def _read(
    where: Path,
    robot: RobotSpec | None,
    format: LogFormat | None,
    pose_topic: str | None,
    joint_topic: str | None,
    encoder_topic: str | None,
    left_joint: str,
    right_joint: str,
) -> tuple[list[Run], RobotSpec | None]:
    """:func:`read_log` as the format's reader gives the runs."""
    kind = format if format is not None else detect_format(where)
    if kind not in FORMATS:
        raise SpecError(f"unknown format {kind!r}; formats: {', '.join(FORMATS)}", field="format")
    if kind == "native":
        from odomgym.data.native import read_native

        if not where.is_dir():
            return read_native(where, robot=robot), None
        return _read_native_folder(where, robot)
    if kind == "rosbag":
        from odomgym.data.rosbag2 import read_rosbag

        if robot is None:
            raise SpecError("reading ROS 2 bags needs --robot (ticks per rev)", field="robot")
        if pose_topic is None:
            raise SpecError("reading ROS 2 bags needs --pose-topic", field="pose_topic")
        bag_runs = read_rosbag(
            where,
            pose_topic=pose_topic,
            joint_topic=joint_topic,
            encoder_topic=encoder_topic,
            left=left_joint,
            right=right_joint,
            robot=robot,
        )
        return bag_runs, None
    from odomgym.data.optiodom import find_sessions, read_session

    folders = [where] if (where / f"{where.name}_metadata.csv").exists() else find_sessions(where)
    if not folders:
        raise SpecError("no OptiOdom session below this folder", source=str(where))
    runs: list[Run] = []
    nominal: RobotSpec | None = None
    for folder in folders:
        session = read_session(folder)
        nominal = nominal or session.robot
        for run in session.runs:
            label = run.kind if run.direction is None else f"{run.kind}_{run.direction}"
            if run.kind == "free":
                label = session.path_type
            run.meta.update(
                run=f"{session.name}-{run.meta['index']:02d}", experiment=label, format="optiodom"
            )
            runs.append(run)
    return runs, nominal


def period_logs(folder: Path, is_log: Callable[[Path], bool]) -> list[tuple[str, Path]]:
    """The logs of one robot's ``folder`` as (period, path), sorted by path: each entry that
    ``is_log`` accepts directly in it (period ``""``), or in a sub-folder of it (the period,
    that sub-folder's name). Hidden folders are passed over (``is_log`` judges the files). One
    walk for ``odomgym fleet``'s robot folders and ``diagnose``'s folder of native logs, so
    both name a robot's sessions alike (:func:`session_name`)."""
    found: list[tuple[str, Path]] = []
    for child in sorted(folder.iterdir()):
        if is_log(child):
            found.append(("", child))
        elif child.is_dir() and not child.name.startswith("."):
            found += [(child.name, p) for p in sorted(child.iterdir()) if is_log(p)]
    return found


def session_name(period: str, path: Path) -> str:
    """A log's session: its path from the robot's folder without its suffix (``s1``,
    ``2026-11/s2``)."""
    return f"{period}/{path.stem}" if period else path.stem


def _looks_native(path: Path) -> bool:
    """Whether the first line of the CSV file ``path`` names every native column
    (:data:`odomgym.data.native.COLUMNS`, any case, quoted or not): a native log, not another
    table that lies beside logs of another format (an OptiOdom folder's results table)."""
    from odomgym.data.native import COLUMNS

    try:
        with path.open(encoding="utf-8-sig", errors="replace") as handle:
            first = handle.readline(4096)
    except OSError:
        return False
    names = {cell.strip().strip('"').strip().lower() for cell in first.split(",")}
    return all(column in names for column in COLUMNS)


def _is_native(path: Path) -> bool:
    """A native log: a visible ``.csv`` file."""
    return path.is_file() and path.suffix.lower() == ".csv" and not path.name.startswith(".")


def native_sessions(folder: Path) -> list[tuple[str, Path]]:
    """The native logs of ``folder`` as (session, file): each ``.csv`` file directly in it, or
    in a sub-folder of it (a period), sorted by path (:func:`period_logs`); the session is
    :func:`session_name`'s (``s1``, ``2026-11/s2``), what ``odomgym fleet`` calls a robot's
    sessions. Hidden files and folders are left out."""
    return [(session_name(period, path), path) for period, path in period_logs(folder, _is_native)]


def _read_native_folder(
    folder: Path, robot: RobotSpec | None
) -> tuple[list[Run], RobotSpec | None]:
    """Every native log of ``folder`` (:func:`native_sessions`), each run's ``meta["session"]``
    its file's session and ``meta["period"]`` its sub-folder (``""`` for none); the nominal
    robot is the folder's ``robot.toml`` when there and ``robot`` is None. Why: a fleet's
    robot folder, or any folder of one robot's logs, is diagnosed (and ``--loso``'s sessions
    told apart) as ``odomgym fleet`` diagnoses it; a native file alone has no session
    column."""
    from odomgym.data.native import read_native
    from odomgym.robot import load_robot

    sessions = native_sessions(folder)
    if not sessions:
        raise SpecError("no native log (.csv) in this folder", field="DATA", source=str(folder))
    # The folder's robot only when none is given: a broken one must not block --robot.
    toml = folder / "robot.toml"
    nominal = load_robot(toml) if robot is None and toml.is_file() else None
    runs: list[Run] = []
    for session, path in sessions:
        for run in read_native(path, robot=robot or nominal):
            run.meta["session"] = session
            run.meta["period"] = session.rpartition("/")[0]
            runs.append(run)
    return runs, nominal

"""Reader of ROS 2 bags (rosbag2: sqlite3 or MCAP) into :class:`odomgym.odometry.runs.Run` records.

Why: a ROS robot already logs what a calibration needs — wheel joint positions or raw encoder
counts, and a motion-capture or other ground-truth pose — so recording a bag during the
experiments is the least effort. The bag is read with the pure-Python ``rosbags`` package (no
ROS installation), imported only when a bag is read: ``pip install odomgym[ros]``.

What is read:

* The time base is the wheel stream: ``sensor_msgs/msg/JointState`` (``position`` [rad] of the
  two named wheel joints; counts = round(position · ticks_per_rev / 2π), relative to the first
  message) or ``std_msgs/msg/Int32MultiArray`` / ``Int64MultiArray`` (``data`` = [left, right]
  cumulative counts; a 32-bit counter that wraps around is unwrapped).
* The ground truth is ``geometry_msgs/msg/PoseStamped``, ``PoseWithCovarianceStamped`` or
  ``nav_msgs/msg/Odometry``: x, y [m] and yaw = atan2(2(wz + xy), 1 − 2(y² + z²)) [rad]. It is
  linearly interpolated (x, y and unwrapped yaw) onto each wheel sample's time; wheel samples
  outside the pose stream's time span get a NaN pose (a tracker started late or stopped early:
  a replay starts from the first measured pose, :func:`odomgym.diagnose.screen.screen_runs`).
  Interpolation bridges the pose stream's ordinary spacing and a dropped message or two, not a
  gap: a wheel sample between two poses more than :data:`BRIDGE_PERIODS` of the stream's median
  spacing apart gets a NaN pose too (the tracker lost the marker there, and a straight line
  across the gap would be a path nobody measured), as an empty cell of a CSV log does.
* Times are header stamps [ns], or the bag's receive time where a message has no header or a
  zero stamp. Both streams must share a clock.

One bag (a folder with ``metadata.yaml``, or a bare ``.mcap``/``.db3`` file) gives one run; a
folder of bags gives one run per bag, sorted by name.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.data.native import experiment_kind
from odomgym.errors import SpecError
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = ["ENCODER_TYPES", "JOINT_TYPE", "POSE_TYPES", "read_rosbag"]

FloatArray = NDArray[np.float64]
JOINT_TYPE = "sensor_msgs/msg/JointState"
ENCODER_TYPES = ("std_msgs/msg/Int32MultiArray", "std_msgs/msg/Int64MultiArray")
POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
)
_STORAGE_SUFFIXES = (".mcap", ".db3")
_MAX_COUNT = 2**62  # |counts| from here on cannot be a wheel's travel (native.py's bound)
_INSTALL = "reading ROS 2 bags needs the 'rosbags' package: pip install odomgym[ros]"


@dataclass
class _Stream:
    """One topic's samples: times [ns] (sorted, strictly increasing) and values (N, k)."""

    topic: str
    times: NDArray[np.int64]
    values: NDArray[Any]


def read_rosbag(
    path: str | Path,
    *,
    pose_topic: str,
    joint_topic: str | None = None,
    encoder_topic: str | None = None,
    left: str = "left_wheel_joint",
    right: str = "right_wheel_joint",
    robot: RobotSpec,
    experiment: str | None = None,
) -> list[Run]:
    """Read one ROS 2 bag, or a folder of bags, into one :class:`Run` per bag.

    Args:
        path: a bag folder (with ``metadata.yaml``), a bare ``.mcap``/``.db3`` file, or a folder
            holding several of those (read in name order).
        pose_topic: the ground-truth pose topic (PoseStamped, PoseWithCovarianceStamped or
            Odometry).
        joint_topic: a JointState topic with the wheel joints' positions [rad]; or
        encoder_topic: an Int32MultiArray/Int64MultiArray topic with [left, right] counts.
            Exactly one of the two.
        left, right: the wheel joint names in the JointState.
        robot: gives ``ticks_per_rev`` to turn joint angles into counts.
        experiment: the experiment label of every run (``square_cw`` …), which sets ``kind``
            and ``direction``; default: the bag's name.

    Returns:
        Runs with ``time`` from 0 [s] on the wheel stream's clock, ``counts`` from (0, 0),
        ``true_pose`` interpolated onto those times (NaN outside the pose stream),
        ``source`` the bag path and ``meta`` holding ``run`` (the bag name), ``experiment``,
        ``format`` (``"rosbag2"``), ``start_ns`` and the topics.

    Raises:
        SpecError: naming the bag and topic: not both or neither of ``joint_topic`` and
            ``encoder_topic``; no bag at ``path``; an unreadable bag; a missing topic (listing
            the bag's topics); a wrong message type; a topic without messages; wheel joints
            absent from the JointState (listing those present); a malformed message; counts of
            ±2⁶² or more; repeated time stamps; fewer than two wheel samples; poses too large
            to interpolate; the ``rosbags`` package not installed.
    """
    if (joint_topic is None) == (encoder_topic is None):
        raise SpecError(
            "give exactly one of the wheel topics: --joint-topic (sensor_msgs/msg/JointState) "
            "or --encoder-topic (std_msgs/msg/Int32MultiArray or Int64MultiArray); in Python "
            "joint_topic= or encoder_topic=",
            field="joint_topic" if joint_topic is None else "encoder_topic",
        )
    if joint_topic is not None and left == right:
        raise SpecError(f"left and right name the same joint {left!r}", field="right")
    api = _Rosbags.load(Path(path))
    runs: list[Run] = []
    for bag in _find_bags(Path(path)):
        label = experiment if experiment is not None else _bag_name(bag)
        runs.append(
            _read_bag(bag, api, pose_topic, joint_topic, encoder_topic, left, right, robot, label)
        )
    return runs


class _Rosbags:
    """The parts of ``rosbags`` used here, imported on first use."""

    def __init__(self, reader: Any, reader_error: type[Exception], typestore: Any) -> None:
        self.reader = reader
        self.reader_error = reader_error
        self.typestore = typestore

    @classmethod
    def load(cls, path: Path) -> _Rosbags:
        """The ``rosbags`` API, or a one-line :class:`SpecError` naming the bag ``path`` it
        was needed for (the extra that installs it)."""
        try:
            from rosbags.rosbag2 import Reader, ReaderError
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise SpecError(_INSTALL, field="rosbags", source=str(path)) from None
        return cls(Reader, ReaderError, get_typestore(Stores.ROS2_HUMBLE))


def _is_bag(path: Path) -> bool:
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.is_file() and path.suffix in _STORAGE_SUFFIXES


def _bag_name(bag: Path) -> str:
    return bag.name if bag.is_dir() else bag.stem


def _find_bags(path: Path) -> list[Path]:
    if not path.exists():
        raise SpecError("bag path does not exist", source=str(path))
    if _is_bag(path):
        return [path]
    if not path.is_dir():
        raise SpecError(
            "not a ROS 2 bag: expected a bag folder with metadata.yaml, an .mcap or .db3 file, "
            "or a folder of bags",
            source=str(path),
        )
    bags = sorted((p for p in path.iterdir() if _is_bag(p)), key=lambda p: p.name)
    if not bags:
        raise SpecError(
            "no ROS 2 bag in this folder (no sub-folder with metadata.yaml, no .mcap or .db3 file)",
            source=str(path),
        )
    return bags


def _read_bag(
    bag: Path,
    api: _Rosbags,
    pose_topic: str,
    joint_topic: str | None,
    encoder_topic: str | None,
    left: str,
    right: str,
    robot: RobotSpec,
    label: str,
) -> Run:
    wheel_topic = joint_topic if joint_topic is not None else encoder_topic
    assert wheel_topic is not None
    source = str(bag)
    try:
        with api.reader(bag) as reader:
            topics: dict[str, Any] = reader.topics
            wheel_types = (JOINT_TYPE,) if joint_topic is not None else ENCODER_TYPES
            wheel_type = _check_topic(topics, wheel_topic, wheel_types, source)
            pose_type = _check_topic(topics, pose_topic, POSE_TYPES, source)
            raw: dict[str, list[tuple[int, Any]]] = {wheel_topic: [], pose_topic: []}
            connections = [*topics[wheel_topic].connections]
            if pose_topic != wheel_topic:
                connections += topics[pose_topic].connections
            for connection, received, data in reader.messages(connections=connections):
                raw[connection.topic].append((received, data))
    except SpecError:
        raise
    except Exception as exc:  # a damaged file may fail anywhere in rosbags, YAML, SQLite or MCAP
        detail = " ".join(str(exc).split())  # one line: YAML errors span several
        if not isinstance(exc, api.reader_error | OSError):
            detail = f"{type(exc).__name__}: {detail}" if detail else type(exc).__name__
        raise SpecError(f"cannot read bag: {detail}", source=source) from None

    if joint_topic is not None:
        wheels = _decode(
            raw[wheel_topic], wheel_type, api, wheel_topic, source, _joint_reader(left, right)
        )
        keep = ~np.isnan(wheels.values[:, 0])  # other joint groups' messages are skipped
        if not keep.any():
            seen = ", ".join(_joint_names_seen(raw[wheel_topic], api)) or "none"
            raise SpecError(
                f"no message on {wheel_topic} names the wheel joints {left!r} and {right!r}; "
                f"joints present: {seen} (name them with --left-joint and --right-joint; in "
                "Python left= and right=)",
                field="left",
                source=f"{source} {wheel_topic}",
            )
        wheel_times = wheels.times[keep]
        with np.errstate(over="ignore"):  # a huge angle: inf counts, refused just below
            ticks = np.rint(wheels.values[keep] * (robot.ticks_per_rev / (2.0 * math.pi)))
        _check_counts(ticks, wheel_times, wheel_topic, source)
        counts = ticks.astype(np.int64)
    else:
        wheels = _decode(raw[wheel_topic], wheel_type, api, wheel_topic, source, _encoder_values)
        wheel_times = wheels.times
        _check_counts(wheels.values, wheel_times, wheel_topic, source)
        counts = wheels.values.astype(np.int64)
        if wheel_type == ENCODER_TYPES[0]:  # a 32-bit counter wraps around at ±2³¹
            steps = np.diff(counts, axis=0)
            steps = (steps + 2**31) % 2**32 - 2**31
            counts = np.concatenate([counts[:1], counts[:1] + np.cumsum(steps, axis=0)])
    _check_distinct(wheel_times, wheel_topic, source)
    if len(wheel_times) < 2:
        raise SpecError(
            f"{wheel_topic} has {len(wheel_times)} usable message(s): a run needs at least two",
            field="joint_topic" if joint_topic is not None else "encoder_topic",
            source=source,
        )
    poses = _decode(raw[pose_topic], pose_type, api, pose_topic, source, _pose_values)
    _check_distinct(poses.times, pose_topic, source)
    true_pose = _interpolate(poses, wheel_times, source)

    start = int(wheel_times[0])
    kind, direction = experiment_kind(label)
    return Run(
        kind=kind,
        time=(wheel_times - start).astype(np.float64) * 1e-9,
        counts=counts - counts[0],
        true_pose=true_pose,
        direction=direction,
        source=source,
        meta={
            "run": _bag_name(bag),
            "experiment": label,
            "format": "rosbag2",
            "start_ns": start,
            "pose_topic": pose_topic,
            "wheel_topic": wheel_topic,
        },
    )


def _check_topic(topics: dict[str, Any], topic: str, allowed: tuple[str, ...], source: str) -> str:
    if topic not in topics:
        present = ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(topics.items()))
        raise SpecError(
            f"topic {topic} is not in the bag; its topics: {present or 'none'}",
            field=topic,
            source=source,
        )
    info = topics[topic]
    msgtype = info.msgtype
    if msgtype not in allowed:
        found = msgtype or ", ".join(sorted({c.msgtype for c in info.connections}))
        raise SpecError(
            f"topic {topic} carries {found}, expected {' or '.join(allowed)}",
            field=topic,
            source=source,
        )
    if info.msgcount == 0:
        raise SpecError(f"topic {topic} has no messages", field=topic, source=source)
    return str(msgtype)


def _stamp(message: Any, received: int) -> int:
    header = getattr(message, "header", None)
    if header is None:
        return received
    stamp = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
    return stamp if stamp != 0 else received


def _decode(
    messages: list[tuple[int, Any]],
    msgtype: str,
    api: _Rosbags,
    topic: str,
    source: str,
    values: Callable[[Any, str], list[float]],
) -> _Stream:
    """Deserialise ``messages`` and return their times and ``values(message, where)``."""
    where = f"{source} {topic}"
    if not messages:
        raise SpecError(f"topic {topic} has no messages", field=topic, source=source)
    times: list[int] = []
    rows: list[list[float]] = []
    for received, data in messages:
        try:
            message = api.typestore.deserialize_cdr(data, msgtype)
        except Exception as exc:  # a corrupt message may fail anywhere in the decoder
            raise SpecError(
                f"cannot decode a {msgtype} message received at {received} ns: {exc!r}",
                field=topic,
                source=where,
            ) from None
        times.append(_stamp(message, received))
        rows.append(values(message, f"{where} message at {received} ns"))
    order = np.argsort(np.asarray(times, dtype=np.int64), kind="stable")
    dtype = np.int64 if msgtype == ENCODER_TYPES[1] else np.float64  # int64 counts stay exact
    array = np.asarray(rows, dtype=dtype)
    return _Stream(topic, np.asarray(times, dtype=np.int64)[order], array[order])


def _check_distinct(times: NDArray[np.int64], topic: str, source: str) -> None:
    repeated = np.flatnonzero(np.diff(times) == 0)
    if repeated.size:
        stamp = int(times[repeated[0]])
        raise SpecError(
            f"two messages on {topic} have the same time stamp {stamp} ns "
            f"({_seconds(stamp)} s): times must be distinct",
            field=topic,
            source=source,
        )


def _check_counts(counts: NDArray[Any], times: NDArray[np.int64], topic: str, source: str) -> None:
    """Refuse counts of ±2⁶² or more, as the native reader does: not a wheel's travel, and
    counts relative to the first would overflow int64."""
    inside = (counts > -_MAX_COUNT) & (counts < _MAX_COUNT)  # also False for inf counts
    if not inside.all():
        row, column = np.argwhere(~inside)[0]
        stamp = int(times[row])
        raise SpecError(
            f"the {('left', 'right')[column]} wheel's count {float(counts[row, column]):.6g} in "
            f"the message at {_seconds(stamp)} s is out of range (beyond ±2^62 counts)",
            field="position" if counts.dtype.kind == "f" else "data",
            source=f"{source} {topic}",
        )


def _joint_reader(left: str, right: str) -> Callable[[Any, str], list[float]]:
    def read(message: Any, where: str) -> list[float]:
        names = list(message.name)
        have = [n in names for n in (left, right)]
        if not any(have):
            return [math.nan, math.nan]  # another joint group's message on the same topic
        if not all(have):
            missing = right if have[0] else left
            raise SpecError(
                f"JointState names {left if have[0] else right!r} but not {missing!r}; "
                f"joints present: {', '.join(names)}",
                field=missing,
                source=where,
            )
        position = np.asarray(message.position, dtype=np.float64)
        if len(position) != len(names):
            raise SpecError(
                f"JointState has {len(names)} names but {len(position)} positions",
                field="position",
                source=where,
            )
        values = [float(position[names.index(left)]), float(position[names.index(right)])]
        if not all(math.isfinite(v) for v in values):
            raise SpecError(
                f"wheel joint position is not finite: {values}", field="position", source=where
            )
        return values

    return read


def _joint_names_seen(messages: list[tuple[int, Any]], api: _Rosbags) -> list[str]:
    seen: dict[str, None] = {}
    for _, data in messages:
        for name in api.typestore.deserialize_cdr(data, JOINT_TYPE).name:
            seen[str(name)] = None
    return list(seen)


def _encoder_values(message: Any, where: str) -> list[float]:
    data: list[float] = [int(v) for v in message.data]
    if len(data) != 2:
        raise SpecError(
            f"encoder message holds {len(data)} values, expected 2: [left, right] counts",
            field="data",
            source=where,
        )
    return data  # ints, kept exact: Int64MultiArray values go into an int64 array


def _pose_values(message: Any, where: str) -> list[float]:
    pose = message.pose
    if not hasattr(pose, "position"):  # PoseWithCovariance (also inside Odometry)
        pose = pose.pose
    p, q = pose.position, pose.orientation
    w, x, y, z = float(q.w), float(q.x), float(q.y), float(q.z)
    norm = w * w + x * x + y * y + z * z
    if not norm > 1e-12:  # also NaN
        raise SpecError(
            f"orientation quaternion is not a rotation: (x, y, z, w) = {(x, y, z, w)}",
            field="orientation",
            source=where,
        )
    # atan2(2(wz + xy), 1 − 2(y² + z²)) for a unit quaternion; norm − 2(y² + z²) keeps it exact
    # for one that is not quite normalised.
    yaw = math.atan2(2.0 * (w * z + x * y), norm - 2.0 * (y * y + z * z))
    values = [float(p.x), float(p.y), yaw]
    if not all(math.isfinite(v) for v in values):
        raise SpecError(f"pose is not finite: {values}", field="pose", source=where)
    return values


def _seconds(ns: int) -> str:
    """A time stamp [ns] as exact decimal seconds (a float would round it)."""
    sign = "-" if ns < 0 else ""
    whole, fraction = divmod(abs(ns), 1_000_000_000)
    return f"{sign}{whole}.{fraction:09d}"


BRIDGE_PERIODS = 5.0
"""The widest space between two pose messages that interpolation bridges, in the pose
stream's median spacing [-]: 50 ms for a 100 Hz tracker. Why 5: a dropped message or two and
ordinary jitter are bridged; a tracker that lost the marker for longer leaves a gap (NaN), which
every step of ``odomgym diagnose`` takes as it comes. Until 0.3.x every gap was bridged: 4 s of
a lost marker became a straight line, and a diagnosis of such bags found nothing."""


def _interpolate(poses: _Stream, times: NDArray[np.int64], source: str) -> FloatArray:
    """Pose (x, y, unwrapped yaw) at each of ``times`` [ns], NaN outside the pose stream and
    inside its gaps (:data:`BRIDGE_PERIODS`)."""
    start = int(times[0])
    first, last = int(poses.times[0]), int(poses.times[-1])
    at = (times - start).astype(np.float64) * 1e-9
    pose_at = (poses.times - start).astype(np.float64) * 1e-9
    values = np.asarray(poses.values, dtype=np.float64)
    yaw = np.unwrap(values[:, 2])
    result = np.empty((len(times), 3), dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):  # refused just below
        for column, series in enumerate((values[:, 0], values[:, 1], yaw)):
            result[:, column] = np.interp(at, pose_at, series, left=np.nan, right=np.nan)
    inside = (times >= first) & (times <= last)
    if len(poses.times) > 2:
        spacing = np.diff(poses.times)
        widest = BRIDGE_PERIODS * float(np.median(spacing))
        # The pose message at or after each time, and the one before it: a time that falls
        # strictly inside a wider space than ``widest`` is in a gap.
        after = np.searchsorted(poses.times, times, side="left")
        between = inside & (after > 0) & (after < len(poses.times))
        between &= poses.times[np.minimum(after, len(poses.times) - 1)] != times
        gap = np.zeros(len(times), dtype=bool)
        gap[between] = spacing[after[between] - 1] > widest
        result[gap] = np.nan
        inside &= ~gap
    overflowed = np.flatnonzero(inside & ~np.isfinite(result).all(axis=1))
    if overflowed.size:
        stamp = int(times[overflowed[0]])
        raise SpecError(
            f"the {poses.topic} pose interpolated at {_seconds(stamp)} s is not finite: the "
            "positions around it are too large (near 1e308 m)",
            field=poses.topic,
            source=source,
        )
    return result

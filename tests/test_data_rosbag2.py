"""The ROS 2 bag reader (:mod:`odomgym.data.rosbag2`) on bags written here with ``rosbags``.

The robot drives a known path: 1 m straight at 0.2 m/s, then a 90° counter-clockwise turn on
the spot, starting at a heading near π so the yaw wraps. Wheel joint angles come from exact
kinematics at 50 Hz; the motion capture runs at 125 Hz, starts before the wheels and stops
before them. Both paths are piecewise linear in time with the kink on a motion-capture sample,
so the interpolated pose must equal the true pose to rounding.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

pytest.importorskip("rosbags")

from bag_writer import write_bag as shared_write_bag
from rosbags.rosbag2 import StoragePlugin
from rosbags.typesys import Stores, get_typestore

from odomgym.data.rosbag2 import read_rosbag
from odomgym.errors import SpecError
from odomgym.robot import RobotSpec

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
ROBOT = RobotSpec(wheel_diameter=0.1, wheelbase=0.3, ticks_per_rev=1000)
RADIUS = 0.05
K = ROBOT.ticks_per_rev / (2 * math.pi)  # counts per radian of wheel
EPOCH = 1_700_000_000 * 10**9  # a realistic stamp [ns]: far beyond float64's exact integers
START = (0.5, -0.2, 2.8)  # world pose at t = 0 [m, m, rad]
SPEED, STRAIGHT = 0.2, 5.0  # 1 m in 5 s
TURN_SPEED = 0.1  # wheel rim speed in the turn [m/s]
TURN = (ROBOT.wheelbase / 2) * (math.pi / 2) / TURN_SPEED  # 90° takes 2.356 s
PHI0 = (1.234, -0.5)  # wheel joint angles at t = 0 [rad]
MS = 1_000_000


def true_pose(t: float) -> tuple[float, float, float]:
    x0, y0, th0 = START
    if t <= STRAIGHT:
        d = SPEED * t
        return x0 + d * math.cos(th0), y0 + d * math.sin(th0), th0
    d = SPEED * STRAIGHT
    turned = min(t - STRAIGHT, TURN) * TURN_SPEED / (ROBOT.wheelbase / 2)
    return x0 + d * math.cos(th0), y0 + d * math.sin(th0), th0 + turned


def wheel_angles(t: float) -> tuple[float, float]:
    straight = SPEED * min(t, STRAIGHT) / RADIUS
    turn = TURN_SPEED * min(max(t - STRAIGHT, 0.0), TURN) / RADIUS  # then it stands still
    return PHI0[0] + straight - turn, PHI0[1] + straight + turn


def _stamp(ns: int) -> Any:
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
        frame_id="world",
    )


def _pose_msg(msgtype: str, ns: int, x: float, y: float, yaw: float) -> Any:
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
        orientation=T["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
        ),
    )
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return T[msgtype](header=_stamp(ns), pose=pose)
    with_cov = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36))
    if msgtype == "geometry_msgs/msg/PoseWithCovarianceStamped":
        return T[msgtype](header=_stamp(ns), pose=with_cov)
    zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    twist = T["geometry_msgs/msg/TwistWithCovariance"](
        twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
    )
    return T[msgtype](header=_stamp(ns), child_frame_id="base", pose=with_cov, twist=twist)


def _joint_msg(ns: int, names: Sequence[str], positions: Sequence[float]) -> Any:
    return T["sensor_msgs/msg/JointState"](
        header=_stamp(ns),
        name=list(names),
        position=np.asarray(positions, dtype=np.float64),
        velocity=np.zeros(0),
        effort=np.zeros(0),
    )


def _array_msg(msgtype: str, values: Sequence[int]) -> Any:
    dtype = np.int32 if "Int32" in msgtype else np.int64
    layout = T["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
    return T[msgtype](layout=layout, data=np.asarray(values, dtype=dtype))


def write_bag(
    path: Path,
    topics: dict[str, tuple[str, list[tuple[int, object]]]],
    storage: StoragePlugin = StoragePlugin.MCAP,
) -> Path:
    """Write ``{topic: (msgtype, [(receive ns, message), …])}`` as one bag at ``path``."""
    return shared_write_bag(path, topics, storage, TS)


def joint_times() -> list[int]:
    """Wheel sample stamps [ns]: 50 Hz from 3 ms to past the end of the turn."""
    return [EPOCH + 3 * MS + 20 * MS * k for k in range(int((STRAIGHT + TURN + 0.5) / 0.02))]


def mocap_times(stop: float = STRAIGHT + TURN) -> list[int]:
    """Motion-capture stamps [ns]: 125 Hz from 0 to ``stop`` (a sample falls on t = 5 s)."""
    return [EPOCH + 8 * MS * k for k in range(int(stop / 0.008) + 1)]


def pose_stream(
    msgtype: str = "geometry_msgs/msg/PoseStamped", times: Sequence[int] | None = None
) -> tuple[str, list[tuple[int, object]]]:
    stamps = mocap_times() if times is None else times
    messages = [
        (ns + 2 * MS, _pose_msg(msgtype, ns, *true_pose((ns - EPOCH) * 1e-9))) for ns in stamps
    ]
    return msgtype, messages


def joint_stream(
    names: Sequence[str] = ("front_caster", "left_wheel_joint", "right_wheel_joint"),
) -> tuple[str, list[tuple[int, object]]]:
    messages: list[tuple[int, object]] = []
    for ns in joint_times():
        left, right = wheel_angles((ns - EPOCH) * 1e-9)
        by_name = {"left_wheel_joint": left, "right_wheel_joint": right}
        positions = [by_name.get(n, 0.7) for n in names]
        messages.append((ns + 5 * MS, _joint_msg(ns, names, positions)))  # 5 ms latency
    return "sensor_msgs/msg/JointState", messages


def expected_counts(times: Sequence[int]) -> NDArray[np.int64]:
    ticks: NDArray[np.int64] = np.array(
        [[round(a * K) for a in wheel_angles((ns - EPOCH) * 1e-9)] for ns in times],
        dtype=np.int64,
    )
    relative: NDArray[np.int64] = ticks - ticks[0]
    return relative


def expected_poses(times: Sequence[int], last_pose: float) -> NDArray[np.float64]:
    poses = np.array([true_pose((ns - EPOCH) * 1e-9) for ns in times])
    late = np.array([(ns - EPOCH) * 1e-9 > last_pose for ns in times])
    poses[late] = np.nan
    return poses


@pytest.fixture(scope="module")
def joint_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("bags") / "square_ccw_demo"
    return write_bag(folder, {"/joint_states": joint_stream(), "/mocap/pose": pose_stream()})


# ---------------------------------------------------------------------------------- reading
def test_joint_state_bag(joint_bag: Path) -> None:
    (run,) = read_rosbag(
        joint_bag, pose_topic="/mocap/pose", joint_topic="/joint_states", robot=ROBOT
    )
    times = joint_times()
    np.testing.assert_allclose(run.time, [(ns - times[0]) * 1e-9 for ns in times], atol=1e-12)
    assert run.time[0] == 0.0 and run.time.dtype == np.float64
    np.testing.assert_array_equal(run.counts, expected_counts(times))
    # 1 m straight: 1 / (π · 0.1) · 1000 = 3183 counts on each wheel, then ∓ 750 for 90°; the
    # first sample comes 3 ms in, after 0.6 mm (1.9 counts).
    assert run.counts[-1].tolist() == pytest.approx([3183 - 750 - 2, 3183 + 750 - 2], abs=1)
    last_mocap = mocap_times()[-1]
    expected = expected_poses(times, (last_mocap - EPOCH) * 1e-9)
    np.testing.assert_allclose(run.true_pose, expected, atol=1e-9)
    measured = ~np.isnan(run.true_pose[:, 0])
    assert measured.sum() == sum(ns <= last_mocap for ns in times) < len(times)
    assert np.isnan(run.true_pose[~measured]).all()
    assert run.true_pose[measured][-1, 2] > math.pi  # unwrapped: the heading passed π
    assert (run.kind, run.direction, run.source) == ("square", "ccw", str(joint_bag))
    assert run.meta["run"] == "square_ccw_demo" and run.meta["format"] == "rosbag2"
    assert run.meta["experiment"] == "square_ccw_demo"
    assert run.meta["start_ns"] == times[0]


@pytest.mark.parametrize(
    "pose_type", ["geometry_msgs/msg/PoseWithCovarianceStamped", "nav_msgs/msg/Odometry"]
)
@pytest.mark.parametrize(
    "encoder_type", ["std_msgs/msg/Int32MultiArray", "std_msgs/msg/Int64MultiArray"]
)
def test_encoder_bag_sqlite(tmp_path: Path, pose_type: str, encoder_type: str) -> None:
    """Raw counts without header (receive time), a 32-bit counter that wraps, a .db3 bag."""
    times = joint_times()
    counts = expected_counts(times)
    offset = np.array([2**31 - 1000, -5])  # the left counter passes +2³¹ during the run
    raw = counts + offset
    if "Int32" in encoder_type:
        raw = (raw + 2**31) % 2**32 - 2**31
        assert (raw[:, 0] < 0).any()
    messages: list[tuple[int, object]] = [
        (ns, _array_msg(encoder_type, row.tolist())) for ns, row in zip(times, raw, strict=True)
    ]
    bag = write_bag(
        tmp_path / "straight",
        {"/ticks": (encoder_type, messages), "/odom_gt": pose_stream(pose_type)},
        storage=StoragePlugin.SQLITE3,
    )
    (run,) = read_rosbag(
        bag, pose_topic="/odom_gt", encoder_topic="/ticks", robot=ROBOT, experiment="spin_cw"
    )
    np.testing.assert_array_equal(run.counts, counts)
    expected = expected_poses(times, (mocap_times()[-1] - EPOCH) * 1e-9)
    np.testing.assert_allclose(run.true_pose, expected, atol=1e-9)
    assert (run.kind, run.direction, run.meta["experiment"]) == ("spin", "cw", "spin_cw")
    # The bare storage file reads as well.
    (again,) = read_rosbag(
        next(bag.glob("*.db3")), pose_topic="/odom_gt", encoder_topic="/ticks", robot=ROBOT
    )
    np.testing.assert_array_equal(again.counts, counts)


def test_folder_of_bags_and_receive_time_fallback(tmp_path: Path) -> None:
    """One run per bag in name order; zero header stamps fall back to the receive time."""
    mocap = [ns for ns in mocap_times() if ns <= EPOCH + 2 * 10**9]
    zero_stamped = [
        (ns, _pose_msg("geometry_msgs/msg/PoseStamped", 0, *true_pose((ns - EPOCH) * 1e-9)))
        for ns in mocap
    ]
    write_bag(
        tmp_path / "straight",
        {
            "/joint_states": joint_stream(("right_wheel_joint", "left_wheel_joint")),
            "/pose": ("geometry_msgs/msg/PoseStamped", zero_stamped),
        },
    )
    write_bag(tmp_path / "spin_cw", {"/joint_states": joint_stream(), "/pose": pose_stream()})
    (tmp_path / "notes.txt").write_text("not a bag", encoding="utf-8")
    runs = read_rosbag(tmp_path, pose_topic="/pose", joint_topic="/joint_states", robot=ROBOT)
    assert [(r.meta["run"], r.kind, r.direction) for r in runs] == [
        ("spin_cw", "spin", "cw"),
        ("straight", "straight", None),
    ]
    times = joint_times()
    np.testing.assert_array_equal(runs[1].counts, expected_counts(times))
    expected = expected_poses(times, 2.0)
    np.testing.assert_allclose(runs[1].true_pose, expected, atol=1e-9)
    assert np.isnan(runs[1].true_pose[:, 0]).sum() == sum(ns > EPOCH + 2 * 10**9 for ns in times)


def test_joint_state_messages_of_other_joints_are_skipped(tmp_path: Path) -> None:
    _, wheel = joint_stream()
    arm = [(ns + 7 * MS, _joint_msg(ns, ["shoulder", "elbow"], [0.1, 0.2])) for ns in mocap_times()]
    bag = write_bag(
        tmp_path / "bag",
        {"/joint_states": ("sensor_msgs/msg/JointState", wheel + arm), "/pose": pose_stream()},
    )
    (run,) = read_rosbag(bag, pose_topic="/pose", joint_topic="/joint_states", robot=ROBOT)
    np.testing.assert_array_equal(run.counts, expected_counts(joint_times()))


# ---------------------------------------------------------------------------------- errors
def _read(bag: Path, **kwargs: Any) -> None:
    options: dict[str, Any] = {"pose_topic": "/mocap/pose", "joint_topic": "/joint_states"}
    options.update(kwargs)
    read_rosbag(bag, robot=ROBOT, **options)


@pytest.mark.parametrize(
    ("options", "pattern"),
    [
        ({"joint_topic": None}, "exactly one of the wheel topics: --joint-topic"),
        ({"encoder_topic": "/ticks"}, "exactly one of the wheel topics: --joint-topic"),
        (
            {"pose_topic": "/tf"},
            r"topic /tf is not in the bag; its topics: /joint_states "
            r"\(sensor_msgs/msg/JointState\), /mocap/pose \(geometry_msgs/msg/PoseStamped\)",
        ),
        ({"pose_topic": "/joint_states"}, "carries sensor_msgs/msg/JointState, expected"),
        (
            {"joint_topic": None, "encoder_topic": "/mocap/pose"},
            "carries geometry_msgs/msg/PoseStamped, expected std_msgs/msg/Int32MultiArray or",
        ),
        (
            {"left": "wheel_l", "right": "wheel_r"},
            "names the wheel joints 'wheel_l' and 'wheel_r'; joints present: front_caster, "
            "left_wheel_joint, right_wheel_joint",
        ),
        ({"right": "wheel_r"}, "names 'left_wheel_joint' but not 'wheel_r'; joints present"),
        ({"left": "x", "right": "x"}, "the same joint"),
    ],
)
def test_bad_arguments_and_topics(joint_bag: Path, options: dict[str, Any], pattern: str) -> None:
    with pytest.raises(SpecError, match=pattern) as info:
        _read(joint_bag, **options)
    if "exactly one" not in pattern and "same joint" not in pattern:
        assert str(joint_bag) in str(info.value)


def test_wheel_samples_before_the_first_pose_are_gaps(tmp_path: Path) -> None:
    """A tracker that starts half a second after the wheel log: the wheel samples before its
    first pose have none (NaN, a gap at the run's start: diagnose's screening starts the run at
    its first pose), the others are interpolated as ever."""
    late = [ns + 500 * MS for ns in mocap_times()]
    bag = write_bag(
        tmp_path / "late", {"/joint_states": joint_stream(), "/mocap/pose": pose_stream(times=late)}
    )
    (run,) = read_rosbag(bag, robot=ROBOT, pose_topic="/mocap/pose", joint_topic="/joint_states")
    stamps = np.array(joint_times())
    before = stamps < late[0]
    assert before.sum() == 25  # 3, 23, …, 483 ms
    assert np.isnan(run.true_pose[before]).all()
    assert np.isfinite(run.true_pose[~before & (stamps <= late[-1])]).all()


def test_a_tracker_gap_is_a_gap_not_a_straight_line(tmp_path: Path) -> None:
    """A tracker that lost the marker from 1 s to 2 s (125 Hz: 124 messages missing) and
    dropped one message at 3 s: the wheel samples inside the lost second get no pose (NaN, as
    an empty CSV cell), those beside the one dropped message are interpolated as ever
    (rosbag2.BRIDGE_PERIODS). Until 0.3.x the second was bridged by a straight line, which a
    diagnosis read as the robot's path."""
    from odomgym.data.rosbag2 import BRIDGE_PERIODS

    lost_from, lost_to, dropped = EPOCH + 1000 * MS, EPOCH + 2000 * MS, EPOCH + 3000 * MS
    kept = [ns for ns in mocap_times() if not (lost_from < ns < lost_to) and ns != dropped]
    bag = write_bag(
        tmp_path / "gap", {"/joint_states": joint_stream(), "/mocap/pose": pose_stream(times=kept)}
    )
    (run,) = read_rosbag(bag, robot=ROBOT, pose_topic="/mocap/pose", joint_topic="/joint_states")
    stamps = np.array(joint_times())
    inside = (stamps > lost_from) & (stamps < lost_to)
    assert inside.sum() == 50 and np.isnan(run.true_pose[inside]).all()
    seen = stamps <= kept[-1]
    assert np.isfinite(run.true_pose[~inside & seen]).all()  # 2.99-3.01 s bridged
    assert 2 * 8 < BRIDGE_PERIODS * 8 < 1000  # one dropped message bridged, a second not


def test_read_log_takes_poses_the_tracker_held_as_gaps(tmp_path: Path) -> None:
    """A motion-capture stream that repeats the pose of t = 1 s until t = 2 s while the robot
    drives on: the wheel samples whose interpolated pose is that held one are gaps
    (odomgym.data.gaps.mark_held_poses, which read_log applies to every format), the first
    wheel sample at that pose stays, and the run says how many it lost."""
    from odomgym.data.logs import read_log

    msgtype = "geometry_msgs/msg/PoseStamped"
    held = EPOCH + 1000 * MS
    messages = [
        (ns + 2 * MS, _pose_msg(msgtype, ns, *true_pose((min(ns, held) - EPOCH) * 1e-9)))
        if ns <= EPOCH + 2000 * MS
        else (ns + 2 * MS, _pose_msg(msgtype, ns, *true_pose((ns - EPOCH) * 1e-9)))
        for ns in mocap_times()
    ]
    bag = write_bag(
        tmp_path / "held", {"/joint_states": joint_stream(), "/mocap/pose": (msgtype, messages)}
    )
    (run,), _ = read_log(
        bag, robot=ROBOT, format="rosbag", pose_topic="/mocap/pose", joint_topic="/joint_states"
    )
    stamps = np.array(joint_times())
    # Wheel samples in [1.0, 2.0] s interpolate between two held messages: 1.003 s (the first
    # at the held pose) is kept, 1.023 … 1.983 s are gaps; 2.003 s is past the last held one.
    lost = (stamps > held + 3 * MS) & (stamps < EPOCH + 2000 * MS)
    assert run.meta["held_poses"] == lost.sum() == 49
    assert np.isnan(run.true_pose[lost]).all()
    seen = stamps <= mocap_times()[-1]  # the wheel log runs on past the tracker's
    assert np.isfinite(run.true_pose[~lost & seen]).all()


def test_empty_topic_duplicates_and_bad_messages(tmp_path: Path) -> None:
    empty = write_bag(
        tmp_path / "empty",
        {"/joint_states": joint_stream(), "/mocap/pose": ("geometry_msgs/msg/PoseStamped", [])},
    )
    with pytest.raises(SpecError, match=r"empty: topic /mocap/pose has no messages"):
        _read(empty)

    msgtype, messages = joint_stream()
    doubled = write_bag(
        tmp_path / "doubled",
        {"/joint_states": (msgtype, [*messages, messages[10]]), "/mocap/pose": pose_stream()},
    )
    with pytest.raises(SpecError, match=r"doubled: two messages on /joint_states have the same"):
        _read(doubled)

    _, poses = pose_stream()
    poses[3] = (poses[3][0], _pose_msg("geometry_msgs/msg/PoseStamped", EPOCH + 24 * MS, 0, 0, 0))
    poses[3][1].pose.orientation.w = 0.0  # type: ignore[attr-defined]
    zero = write_bag(
        tmp_path / "zero",
        {"/joint_states": joint_stream(), "/mocap/pose": ("geometry_msgs/msg/PoseStamped", poses)},
    )
    with pytest.raises(SpecError, match=r"zero /mocap/pose message at \d+ ns: orientation quat"):
        _read(zero)

    kind = "std_msgs/msg/Int64MultiArray"
    three = write_bag(
        tmp_path / "three",
        {
            "/ticks": (kind, [(EPOCH + 9 * MS, _array_msg(kind, [1, 2, 3]))]),
            "/mocap/pose": pose_stream(),
        },
    )
    with pytest.raises(SpecError, match=r"three /ticks message at \d+ ns: encoder message holds 3"):
        _read(three, joint_topic=None, encoder_topic="/ticks")

    one = write_bag(
        tmp_path / "one",
        {
            "/ticks": (kind, [(EPOCH + 9 * MS, _array_msg(kind, [1, 2]))]),
            "/mocap/pose": pose_stream(),
        },
    )
    with pytest.raises(SpecError, match=r"/ticks has 1 usable message\(s\)"):
        _read(one, joint_topic=None, encoder_topic="/ticks")


def test_not_a_bag(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="does not exist"):
        _read(tmp_path / "missing")
    with pytest.raises(SpecError, match="no ROS 2 bag in this folder"):
        _read(tmp_path)
    text = tmp_path / "notes.txt"
    text.write_text("x", encoding="utf-8")
    with pytest.raises(SpecError, match="not a ROS 2 bag"):
        _read(text)
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x00garbage" * 20)
    with pytest.raises(SpecError, match=r"junk\.mcap: cannot read bag"):
        _read(junk)


def test_missing_rosbags_names_the_extra(joint_bag: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "rosbags.rosbag2", None)
    with pytest.raises(SpecError, match=r"pip install odomgym\[ros\]"):
        _read(joint_bag)

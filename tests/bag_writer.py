"""Writing a ROS 2 bag with ``rosbags`` (no ROS install), shared by the bag reader's tests and
its fuzz tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def write_bag(
    path: Path,
    topics: dict[str, tuple[str, list[tuple[int, Any]]]],
    storage: Any,
    typestore: Any,
) -> Path:
    """Write ``{topic: (msgtype, [(receive ns, message), …])}`` as one bag folder at ``path``
    (``storage``: a ``rosbags.rosbag2.StoragePlugin``), messages in receive-time order."""
    from rosbags.rosbag2 import Writer

    with Writer(path, version=9, storage_plugin=storage) as writer:
        connections = {
            topic: writer.add_connection(topic, msgtype, typestore=typestore)
            for topic, (msgtype, _) in topics.items()
        }
        queue = [
            (received, topic, msgtype, message)
            for topic, (msgtype, messages) in topics.items()
            for received, message in messages
        ]
        for received, topic, msgtype, message in sorted(queue, key=lambda q: (q[0], q[1])):
            writer.write(connections[topic], received, typestore.serialize_cdr(message, msgtype))
    return path

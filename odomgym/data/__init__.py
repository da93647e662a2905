"""Recorded data of real robots, read into :class:`odomgym.runs.Run` records.

Formats: odomgym's native CSV (:mod:`odomgym.data.native`), the OptiOdom sessions (Sousa et al.,
J. Intell. Robot. Syst. 105:39, 2022; :func:`read_session`, served to calibrators by
:class:`RecordedLab`) and ROS 2 bags (:mod:`odomgym.data.rosbag2`, with the ``rosbags`` package).
:func:`read_log` reads any of them, detecting the format.
"""

from odomgym.data.lab import ExperimentNotRecorded, RecordedLab
from odomgym.data.logs import FORMATS, detect_format, read_log
from odomgym.data.native import read_native, write_native
from odomgym.data.optiodom import Session, SyncWindow, find_sessions, read_session

__all__ = [
    "FORMATS",
    "ExperimentNotRecorded",
    "RecordedLab",
    "Session",
    "SyncWindow",
    "detect_format",
    "find_sessions",
    "read_log",
    "read_native",
    "read_session",
    "write_native",
]

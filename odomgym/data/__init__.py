"""Recorded data of real robots, read into :class:`odomgym.odometry.runs.Run` records.

Formats: odomgym's native CSV (:mod:`odomgym.data.native`), the OptiOdom sessions (Sousa et al.,
J. Intell. Robot. Syst. 105:39, 2022; :func:`read_session`, served to calibrators by
:class:`odomgym.lab.recorded.RecordedLab`) and ROS 2 bags (:mod:`odomgym.data.rosbag2`, with the
``rosbags`` package). :func:`read_log` reads any of them, detecting the format. Six OptiOdom
sessions ship with the package (:mod:`odomgym.data.samples`): :func:`sample_session`,
:func:`sample_sessions`, and :func:`resolve_data` for the ``optiodom:<kind>/<session>`` names every
data option accepts.
"""

from odomgym.data.logs import FORMATS, detect_format, read_log
from odomgym.data.native import read_native, write_native
from odomgym.data.optiodom import Session, SyncWindow, find_sessions, read_session
from odomgym.data.samples import resolve_data, sample_data, sample_session, sample_sessions

__all__ = [
    "FORMATS",
    "Session",
    "SyncWindow",
    "detect_format",
    "find_sessions",
    "read_log",
    "read_native",
    "read_session",
    "resolve_data",
    "sample_data",
    "sample_session",
    "sample_sessions",
    "write_native",
]

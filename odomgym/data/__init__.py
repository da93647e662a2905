"""Recorded data of real robots, read into :class:`odomgym.runs.Run` records.

Only the OptiOdom format (Sousa et al., J. Intell. Robot. Syst. 105:39, 2022) is supported so
far: :func:`read_session` reads one session folder into a :class:`Session`, and
:class:`RecordedLab` serves its runs to any calibrator through the
:class:`odomgym.experiments.Lab` protocol.
"""

from odomgym.data.lab import ExperimentNotRecorded, RecordedLab
from odomgym.data.optiodom import Session, SyncWindow, find_sessions, read_session

__all__ = [
    "ExperimentNotRecorded",
    "RecordedLab",
    "Session",
    "SyncWindow",
    "find_sessions",
    "read_session",
]

"""Ground-truth gaps in measured logs: held poses found and made gaps, and where a run's
measured poses begin and end.

A tracker loses sight of the robot now and then (a marker hidden by the robot itself, a person
in the way, the edge of the tracked volume). A log shows it in one of two ways:

* **empty pose cells** (NaN in :attr:`odomgym.odometry.runs.Run.true_pose`): nothing was
  measured there. Every step of ``odomgym diagnose`` takes them as they come: a replay is
  compared with the measured rows only.
* **a held pose**: the tracker, or the logger behind it, keeps writing the last pose it had.
  The OptiTrack logs that brought this module in held 45 % of their samples (their logger
  wrote them as empty cells; another writes the repeated pose); the shipped OptiOdom sessions
  hold a handful (5 of 58 845 rows). A held
  pose says "the robot stood still" while its wheels turned: a fit would read it as slip, a
  time offset or a scale error. :func:`mark_held_poses` finds them and makes them gaps.

**The held-pose rule.** Row k is held when (1) it has a measured pose, (2) the previous row
with a measured pose carries *exactly* the same values — x, y and θ bit for bit, empty in the
same columns — and (3) either wheel's cumulative count at row k differs from its count at the
first row of that run of identical values, where the value was first reported. That first row
is kept (it is the measurement being held); the rows after it are made gaps (all three
columns) once a wheel has turned.

Why exact equality, and why only while the wheels turn: a tracker's noise changes the last
digits of every fresh pose (millimetre noise written with ~15 significant digits), so two fresh
poses are never bit-identical; and a robot at rest legitimately reports the same place over and
over — which is why rows whose wheels have not turned since the value was first reported are
never marked. What can still be marked wrongly: a noise-free ground truth (a simulator without
sensor noise) while the wheels turn and the body does not move (a wheel spinning on the spot, a
lifted robot), or poses written with so few decimals that a slow creep does not change them.
Both cost one measured sample each; a held pose kept costs a false standstill in every fit.

The readers apply :func:`mark_held_poses` (:func:`odomgym.data.logs.read_log`, every format)
and so does :func:`odomgym.diagnose.screen.screen_runs` for runs given through the Python API
(the rule is idempotent: a marked run has no held rows left).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from odomgym.odometry.runs import Run

__all__ = [
    "END_SLACK_COUNTS",
    "first_full_pose",
    "held_poses",
    "mark_held_poses",
    "measured_end",
]

END_SLACK_COUNTS = 2
"""Encoder counts a wheel may move after a run's last measured pose for that pose still to be
the run's end (:func:`measured_end`): the quantisation and jitter of a wheel at rest (the native
reader's count-jump check allows the same two counts of slack)."""


def mark_held_poses(run: Run) -> tuple[Run, int]:
    """``run`` with its held poses (module docstring: the held-pose rule) made gaps, and how
    many rows were marked.

    Returns the run itself when nothing is held; otherwise a copy whose marked rows have NaN in
    x, y and θ and whose ``meta["held_poses"]`` adds the count (so a log read, then screened,
    reports each held row once)."""
    pose = np.asarray(run.true_pose, dtype=np.float64)
    rows = np.flatnonzero(~np.isnan(pose).all(axis=1))
    if len(rows) < 2:
        return run, 0
    measured = pose[rows]
    both_empty = np.isnan(measured[1:]) & np.isnan(measured[:-1])
    repeated = np.all((measured[1:] == measured[:-1]) | both_empty, axis=1)
    fresh = np.concatenate([[True], ~repeated])
    # Each measured row's streak start: the row at which its value was first reported.
    first = np.maximum.accumulate(np.where(fresh, np.arange(len(rows)), 0))
    counts = np.asarray(run.counts)
    turned = np.any(counts[rows] != counts[rows[first]], axis=1)
    held = rows[~fresh & turned]
    if not len(held):
        return run, 0
    marked = pose.copy()
    marked[held] = np.nan
    meta = {**run.meta, "held_poses": held_poses(run) + len(held)}
    return dataclasses.replace(run, true_pose=marked, meta=meta), len(held)


def held_poses(run: Run) -> int:
    """How many of ``run``'s rows :func:`mark_held_poses` has made gaps (``meta["held_poses"]``,
    0 if none)."""
    count = run.meta.get("held_poses", 0)
    return count if isinstance(count, int) else 0


def first_full_pose(run: Run) -> int | None:
    """The first row with a full measured pose (x, y and θ), where a replay can start; None if
    no row has one."""
    full = np.flatnonzero(np.isfinite(run.true_pose).all(axis=1))
    return int(full[0]) if len(full) else None


def measured_end(run: Run, slack: int = END_SLACK_COUNTS) -> int | None:
    """The row of ``run``'s last measured position if it is the run's end pose — neither wheel
    turned more than ``slack`` counts after it — else None (the tracker lost the robot before
    it stopped, so the run's final disagreement, or a square's return error, was not measured).
    """
    rows = np.flatnonzero(np.isfinite(run.true_pose[:, :2]).all(axis=1))
    if not len(rows):
        return None
    last = int(rows[-1])
    counts: NDArray[np.float64] = np.asarray(run.counts, dtype=np.float64)
    after = np.abs(counts[last:] - counts[last]).max(initial=0.0)
    return last if after <= slack else None

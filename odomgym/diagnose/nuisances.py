"""Measurement nuisances of a session: the clock and the frame through which the ground truth saw
the robot.

A session's logs carry three properties of the *recording*, not of the robot, and a robot effect
must not pass for them — nor they for a robot effect:

* **time offset** τ [s] between the encoder log and the ground truth: the wheel motion stamped
  t happened at t − τ (τ > 0: the encoder log lags the tracker). Two clocks, two pipelines and
  a resampling step leave such an offset; it is what temporal calibration estimates
  (Furgale, Rehder & Siegwart 2013, who fit it jointly with the spatial calibration, as here).
  Uncorrected, it shows as an along-track error proportional to speed and a disagreement
  during every acceleration — the signature of a traction-slip term.
* **tracked point** (dx, dy) [m]: where, in the robot's frame (x forward, y left, origin at the
  axle midpoint), the ground truth's rigid body has its origin.
* **yaw misalignment** δ [rad]: measured heading − robot heading. A motion-capture rigid body
  can sit at any yaw on the robot (one OptiOdom-like marker body sits 17° off the axis), so δ
  has no bound.

A motion-capture rigid body defined on markers that were rearranged between sessions tracks a
different point at a different yaw each time (the OptiOdom sessions used different marker sets,
Sousa et al. 2022, metadata field ``imarkers``), so all three are per session.
:func:`correct_run` removes them from a run: the cumulative counts are resampled at t + τ
(linear interpolation, held at the ends, where a run starts and stops at rest), the measured
poses are moved into the robot's frame (heading θ − δ, axle point p − R(θ − δ)·(dx, dy)). They
are fitted by :mod:`odomgym.diagnose.openloop` on the open-loop pose error, jointly with the
robot's parameters.

A yaw misalignment δ and a wheel toe τ = −δ produce identical pose logs (the replay starts at
the measured heading); so do a per-session offset and the catalogue's ``gt_sensor_offset``:
where the frames are fitted, those two catalogue effects are not candidates
(:data:`SESSION_EFFECTS`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.odometry.runs import Run

__all__ = [
    "OFFSET_SIGNIFICANCE",
    "SESSION_EFFECTS",
    "SessionNuisance",
    "correct_run",
    "correct_runs",
    "offset_is_significant",
    "sessions_of",
    "with_clock",
]

FloatArray = NDArray[np.float64]
SESSION_EFFECTS = ("gt_sensor_offset", "wheel_toe")
"""Catalogue effects that per-session frames make unidentifiable (left out of the candidates)."""
OFFSET_SIGNIFICANCE = 3.0
"""A session's fitted time offset is applied only beyond this many (run-clustered) standard
errors from zero: resampling the counts at a spurious offset adds the acceleration-correlated
disagreement the filter is most sensitive to."""


@dataclass(frozen=True)
class SessionNuisance:
    """One session's measurement nuisances (module docstring), with run-clustered standard
    errors (NaN when not fitted).

    Attributes:
        session: the session label (``Run.meta["session"]``; ``""`` for unlabelled runs).
        runs: how many runs of the session the values were fitted on.
        time_offset: τ [s] (positive: the encoder log lags the ground truth).
        dx, dy: tracked point in the robot frame [m].
        yaw: δ, measured heading − robot heading [rad].
        frame: whether (dx, dy, δ) were fitted (else they are 0).
        time_offset_se, dx_se, dy_se, yaw_se: standard errors [s], [m], [m], [rad].
        held_out: a session the diagnosis held out: its nuisances were fitted on its own runs
            with the diagnosed model fixed (they never inform the robot's parameters).
    """

    session: str
    runs: int = 0
    time_offset: float = 0.0
    dx: float = 0.0
    dy: float = 0.0
    yaw: float = 0.0
    frame: bool = False
    time_offset_se: float = math.nan
    dx_se: float = math.nan
    dy_se: float = math.nan
    yaw_se: float = math.nan
    held_out: bool = False

    @property
    def values(self) -> FloatArray:
        """(τ, dx, dy, δ) [s, m, m, rad]."""
        return np.array([self.time_offset, self.dx, self.dy, self.yaw])

    def with_values(
        self,
        values: Sequence[float] | FloatArray,
        stderr: Sequence[float] | FloatArray | None = None,
    ) -> SessionNuisance:
        """A copy with (τ, dx, dy, δ) = ``values`` (and their standard errors)."""
        se = list(stderr) if stderr is not None else [math.nan] * 4
        return dataclasses.replace(
            self,
            time_offset=float(values[0]),
            dx=float(values[1]),
            dy=float(values[2]),
            yaw=float(values[3]),
            time_offset_se=float(se[0]),
            dx_se=float(se[1]),
            dy_se=float(se[2]),
            yaw_se=float(se[3]),
        )

    def as_dict(self) -> dict[str, Any]:
        """The report's entry, in ms, mm and degrees."""
        return {
            "session": self.session,
            "runs": self.runs,
            "time_offset_ms": 1e3 * self.time_offset,
            "time_offset_se_ms": 1e3 * self.time_offset_se,
            "frame_fitted": self.frame,
            "dx_mm": 1e3 * self.dx,
            "dy_mm": 1e3 * self.dy,
            "yaw_deg": math.degrees(self.yaw),
            "dx_se_mm": 1e3 * self.dx_se,
            "dy_se_mm": 1e3 * self.dy_se,
            "yaw_se_deg": math.degrees(self.yaw_se),
            "held_out": self.held_out,
        }


def offset_is_significant(nuisance: SessionNuisance) -> bool:
    """Whether ``nuisance``'s time offset is at least :data:`OFFSET_SIGNIFICANCE` standard
    errors from zero (False when its standard error is unknown)."""
    se = nuisance.time_offset_se
    return math.isfinite(se) and abs(nuisance.time_offset) >= OFFSET_SIGNIFICANCE * se


def sessions_of(runs: Sequence[Run]) -> list[str]:
    """Each run's session (``meta["session"]``, else one session for all)."""
    return [str(r.meta.get("session", "")) for r in runs]


def shifted_counts(run: Run, time_offset: float) -> FloatArray:
    """The cumulative counts at the ground truth's sample times when the encoder log lags it by
    ``time_offset`` [s]: the logged counts interpolated at t + τ, held at the first and last
    values beyond the log."""
    counts = run.counts.astype(np.float64)
    if time_offset == 0.0:
        return counts
    at = run.time + time_offset
    out = np.empty_like(counts)
    for wheel in range(2):
        out[:, wheel] = np.interp(at, run.time, counts[:, wheel])
    return out


def corrected_poses(pose: FloatArray, dx: float, dy: float, yaw: float) -> FloatArray:
    """Measured poses (T, 3) of a tracked body moved into the robot's frame (module
    docstring): heading θ − δ, axle point p − R(θ − δ)·(dx, dy). Rows without a heading keep
    their position as measured (the offset cannot be turned into the world frame there)."""
    out = np.array(pose, dtype=np.float64, copy=True)
    if dx == 0.0 and dy == 0.0 and yaw == 0.0:
        return out
    theta = out[:, 2] - yaw
    known = np.isfinite(theta)
    c, s = np.where(known, np.cos(theta), 0.0), np.where(known, np.sin(theta), 0.0)
    out[:, 0] -= c * dx - s * dy
    out[:, 1] -= s * dx + c * dy
    out[:, 2] = theta
    return out


def correct_run(run: Run, nuisance: SessionNuisance | None) -> Run:
    """``run`` with ``nuisance`` removed (module docstring); the run itself if ``None``. The
    corrected run records what was removed in ``meta["nuisance"]``."""
    if nuisance is None:
        return run
    return dataclasses.replace(
        run,
        counts=shifted_counts(run, nuisance.time_offset),
        true_pose=corrected_poses(run.true_pose, nuisance.dx, nuisance.dy, nuisance.yaw),
        meta={**run.meta, "nuisance": nuisance.as_dict()},
    )


def correct_runs(runs: Sequence[Run], nuisances: Mapping[str, SessionNuisance]) -> list[Run]:
    """Every run with its session's nuisances removed (runs of other sessions unchanged)."""
    return [
        correct_run(run, nuisances.get(session))
        for run, session in zip(runs, sessions_of(runs), strict=True)
    ]


def with_clock(
    nuisances: Mapping[str, SessionNuisance], clock: Mapping[str, SessionNuisance]
) -> dict[str, SessionNuisance]:
    """``nuisances`` (frames, fitted on runs whose clocks were already corrected) with each
    session's time offset from ``clock`` put back."""
    out = {}
    for session, n in nuisances.items():
        c = clock.get(session)
        out[session] = (
            dataclasses.replace(n, time_offset=c.time_offset, time_offset_se=c.time_offset_se)
            if c is not None
            else n
        )
    return out

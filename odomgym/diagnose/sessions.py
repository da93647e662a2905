"""Per-session nuisances of multi-session data: where the tracking system put the robot's frame.

A motion-capture system reports the pose of a *rigid body* defined on a set of markers. When the
markers are rearranged between sessions (the OptiOdom sessions used different marker sets,
Sousa et al. 2022, metadata field ``imarkers``), each session tracks a different point of the
robot, at a different yaw to its axle: a tracked-point offset (dx, dy) [m] in the body frame and
a yaw misalignment δ [rad] of the measured heading, *per session*. They are properties of the
measurement, not of the robot, and a robot effect must not pass for them — nor they for a robot
effect.

:func:`fit_session_frames` fits the three per session by generalised least squares on the
whitened innovations, jointly with the three geometric errors E_d, E_b, E_s (which would
otherwise leak into them: a wheel-diameter ratio curves straight runs, as a misalignment tilts
them); only the session frames are kept. :func:`correct_runs` moves every run's measured poses
into the robot's own frame (heading θ − δ, the axle point p − R(θ − δ)·(dx, dy)), so the workflow
then fits robot effects on data free of them. A yaw misalignment δ and a wheel toe τ = −δ produce
identical pose logs (the replay starts at the measured heading); so do a per-session offset and
the catalogue's ``gt_sensor_offset``: with session frames on, those two catalogue effects are
not candidates, and the report gives the part all sessions share (a toe, or a marker body
misaligned the same way every time: pose logs cannot tell).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from odomgym.diagnose.fit import Dataset, _whitened_stack
from odomgym.diagnose.likelihood import SensorNoise
from odomgym.effects import EFFECTS
from odomgym.robot import RobotSpec
from odomgym.runs import Run

__all__ = ["SESSION_EFFECTS", "SessionFrame", "correct_runs", "fit_session_frames", "sessions_of"]

FloatArray = NDArray[np.float64]
SESSION_EFFECTS = ("gt_sensor_offset", "wheel_toe")
"""Catalogue effects that per-session frames make unidentifiable (left out of the candidates)."""
_SCALE = np.array([2e-3, 2e-3, 1e-3])  # dx, dy [m], δ [rad]: the fit's units
_GEOMETRY_SCALE = 1e-3


@dataclass(frozen=True)
class SessionFrame:
    """One session's tracked-point offset and yaw misalignment, with standard errors."""

    session: str
    runs: int
    dx: float
    dy: float
    yaw: float
    dx_se: float
    dy_se: float
    yaw_se: float

    def as_dict(self) -> dict[str, Any]:
        return {
            "session": self.session,
            "runs": self.runs,
            "dx_mm": 1e3 * self.dx,
            "dy_mm": 1e3 * self.dy,
            "yaw_deg": math.degrees(self.yaw),
            "dx_se_mm": 1e3 * self.dx_se,
            "dy_se_mm": 1e3 * self.dy_se,
            "yaw_se_deg": math.degrees(self.yaw_se),
        }


def sessions_of(runs: Sequence[Run]) -> list[str]:
    """Each run's session (``meta["session"]``, else one session for all)."""
    return [str(r.meta.get("session", "")) for r in runs]


def _spec_for(spec: RobotSpec, geometry: FloatArray, frame: FloatArray) -> RobotSpec:
    e_d, e_b, e_s = 1.0 + _GEOMETRY_SCALE * geometry
    out = spec.with_errors(spec.e_d * e_d, spec.e_b * e_b, spec.e_s * e_s)
    dx, dy, delta = frame * _SCALE
    out = EFFECTS["gt_sensor_offset"].write(out, {"dx": dx, "dy": dy})
    # A misalignment δ of the measured heading is a crab of −δ in the replay.
    return EFFECTS["wheel_toe"].write(out, {"angle": -delta})


def fit_session_frames(data: Dataset, spec: RobotSpec, sensor: SensorNoise) -> list[SessionFrame]:
    """Per-session (dx, dy, δ) fitted jointly with E_d, E_b, E_s on ``data`` (module docstring).

    Returns the frames, one per session, in order of first appearance.
    """
    labels = sessions_of(data.runs)
    order = list(dict.fromkeys(labels))
    members = {s: [j for j, lab in enumerate(labels) if lab == s] for s in order}
    subsets = [data.subset(members[s]) for s in order]
    n_geo = 3

    # A session's innovations depend on the geometry and its own frame only, so a derivative
    # column of one session's frame changes that session's part alone: the others are looked up
    # by the exact bits of their inputs (bit-identical to computing them again), which makes
    # the finite-difference Jacobian cost ~6 evaluations of all runs instead of 3 + 3·sessions.
    # Enough entries to keep every session's current point while the geometry columns and a
    # few trial steps pass through.
    @functools.lru_cache(maxsize=8 * len(order))
    def session_part(k: int, geometry: bytes, frame: bytes) -> FloatArray:
        at = _spec_for(spec, np.frombuffer(geometry), np.frombuffer(frame))
        return _whitened_stack(subsets[k], at, sensor)[0]

    def residual(x: FloatArray) -> FloatArray:
        geometry = x[:n_geo].tobytes()
        return np.concatenate(
            [
                session_part(k, geometry, x[n_geo + 3 * k : n_geo + 3 * k + 3].tobytes())
                for k in range(len(order))
            ]
        )

    x0 = np.zeros(n_geo + 3 * len(order))
    result = least_squares(residual, x0, diff_step=1e-2, x_scale=1.0, max_nfev=20)
    jac = result.jac
    try:
        cov = np.linalg.inv(jac.T @ jac)
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        se = np.full(len(x0), math.inf)
    frames = []
    for k, s in enumerate(order):
        v = result.x[n_geo + 3 * k : n_geo + 3 * k + 3] * _SCALE
        e = se[n_geo + 3 * k : n_geo + 3 * k + 3] * _SCALE
        frames.append(
            SessionFrame(
                s,
                len(members[s]),
                float(v[0]),
                float(v[1]),
                float(v[2]),
                float(e[0]),
                float(e[1]),
                float(e[2]),
            )
        )
    return frames


def correct_runs(runs: Sequence[Run], frames: Sequence[SessionFrame]) -> list[Run]:
    """``runs`` with every measured pose moved into the robot's frame (module docstring)."""
    by_session = {f.session: f for f in frames}
    out = []
    for run, session in zip(runs, sessions_of(runs), strict=True):
        frame = by_session.get(session)
        if frame is None:
            out.append(run)
            continue
        pose = np.array(run.true_pose, dtype=float, copy=True)
        theta = pose[:, 2] - frame.yaw
        known = np.isfinite(theta)  # rows without a heading keep their position as measured
        c, s = np.where(known, np.cos(theta), 0.0), np.where(known, np.sin(theta), 0.0)
        pose[:, 0] -= c * frame.dx - s * frame.dy
        pose[:, 1] -= s * frame.dx + c * frame.dy
        pose[:, 2] = theta
        meta = {**run.meta, "session_frame": frame.as_dict()}
        out.append(dataclasses.replace(run, true_pose=pose, meta=meta))
    return out

"""The joint sensitivity of the open-loop residuals to the robot and to the measurement.

What a fit can say about a robot depends on what else could have made the same logs. This
module lays the two side by side: the derivatives of the weighted open-loop residuals that
:func:`odomgym.diagnose.openloop.fit_open_loop` minimises (every run stacked) with respect to

* the robot's parameters as the fit parametrises them (catalogue effects, grammar terms: the
  fit's :class:`~odomgym.effects.Effect` or :class:`~odomgym.diagnose.fit.Joint`), per unit of
  each parameter — the fit's own Jacobian block, reused;
* per session, the measurement nuisances diagnose fits (:mod:`odomgym.diagnose.nuisances`): the
  time offset τ [s], the tracked point dx, dy [m], the frame yaw δ [rad] — also where the fit
  does not fit them (one session), since a confound exists whether or not it is fitted; where
  the fit has them, its Jacobian block is reused;
* per session, errors of the ground-truth system itself (:class:`GroundTruthError`): a rigid
  motion of its frame (translation [m], rotation [rad]), a scale of its frame [-] and a clock
  rate [-].

A nuisance is an error *of the recording*: the logs were made with it, and the residuals are
computed after removing it (:func:`remove_nuisances`; the convention of
:func:`odomgym.diagnose.nuisances.correct_run`). The columns the fit lacks are central
differences along the fitted model's own prediction — the logs with every measured pose
replaced by the pose the fitted model predicts there — so they are the model's structural
sensitivities: identifiability as a property of the model and the experiment, not of the noise
(Bellman & Åström 1970, "On structural identifiability", Mathematical Biosciences 7). On the
measured poses themselves a rotation of the whole frame would turn the residual vectors by 90°
and show a column the size of the noise; along the prediction it is zero, as it should be. Each
costs two residual evaluations of every run (all sessions at once, as the fit's own Jacobian).

**Invisible nuisances.** A nuisance whose change of the residuals is below :data:`INVISIBLE` of
its change of the logs — of the measured poses, or of the prediction through the counts — is
one the replay absorbs: every replay starts at the first measured pose, so a rigid motion of the
whole frame moves prediction and measurement alike. It is listed as invisible
(:attr:`JointJacobian.invisible`) and left out of the columns, never reported as a confound.
:mod:`odomgym.diagnose.confounds` finds the directions in which the visible columns cancel.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym.diagnose.fit import Joint
from odomgym.diagnose.nuisances import SessionNuisance, correct_run
from odomgym.diagnose.openloop import _NUISANCE_SCALE, OpenLoopData, OpenLoopFit, _residual
from odomgym.effects import Parameter
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "INVISIBLE",
    "NUISANCE_KINDS",
    "Column",
    "GroundTruthError",
    "JointJacobian",
    "NuisanceKind",
    "joint_jacobian",
    "remove_nuisances",
    "robot_parameters",
]

FloatArray = NDArray[np.float64]
INVISIBLE = 1e-6
"""A nuisance whose change of the residuals is below this fraction of its change of the logs is
invisible: numerically zero (finite differences leave ~1e-11), far below any real sensitivity."""


@dataclass(frozen=True)
class NuisanceKind:
    """One kind of measurement error, per session.

    Attributes:
        name: the column's name (``"gt.scale"``; ``"gt.scale[SESSION]"`` with several sessions).
        unit: its SI unit.
        step: the central-difference step of its column [unit].
        reading: how a value reads, a format with ``{value}`` in ``display`` units.
        display: the factor from ``unit`` to the display unit (1e3 for s → ms).
        check: the measurement that determines it, independently of the robot.
    """

    name: str
    unit: str
    step: float
    reading: str
    display: float
    check: str


_MARKERS = "measure the rigid body's markers against the axle (its origin and forward axis)"
NUISANCE_KINDS: tuple[NuisanceKind, ...] = (
    NuisanceKind(
        "time_offset",
        "s",
        1e-4,  # the fit's own step (1e-2 of its 10 ms unit): well inside a 50–100 ms sample
        "the encoder log lagging the ground truth by {value:+.1f} ms",
        1e3,
        "timestamp a common event (a sharp start of motion) on both clocks",
    ),
    NuisanceKind(
        "tracked_dx",
        "m",
        1e-4,
        "the tracked point {value:+.2f} mm ahead of the axle",
        1e3,
        _MARKERS + "; on a skid-steer robot what is left of it is the sides' ICRs lying that "
        "far behind the tracked point (Mandow et al. 2007's x_ICR = −dx), which no pose log "
        "separates from it",
    ),
    NuisanceKind(
        "tracked_dy", "m", 1e-4, "the tracked point {value:+.2f} mm left of the axle", 1e3, _MARKERS
    ),
    NuisanceKind(
        "frame_yaw",
        "rad",
        1e-4,
        "the tracked body's frame yawed {value:+.3f}° from the robot's axis",
        math.degrees(1.0),
        _MARKERS,
    ),
    NuisanceKind(
        "gt.translation_x",
        "m",
        1e-4,
        "the ground-truth frame moved {value:+.2f} mm along x",
        1e3,
        "none needed: a translation of the frame does not change the logs' replay",
    ),
    NuisanceKind(
        "gt.translation_y",
        "m",
        1e-4,
        "the ground-truth frame moved {value:+.2f} mm along y",
        1e3,
        "none needed: a translation of the frame does not change the logs' replay",
    ),
    NuisanceKind(
        "gt.rotation",
        "rad",
        1e-4,
        "the ground-truth frame rotated {value:+.3f}°",
        math.degrees(1.0),
        "none needed: a rotation of the whole frame does not change the logs' replay",
    ),
    NuisanceKind(
        "gt.scale",
        "-",
        1e-4,
        "the ground-truth frame scaled by {value:+.3f} %",
        100.0,
        "measure a known distance (a calibrated bar, a tape between two markers) with the "
        "ground-truth system",
    ),
    NuisanceKind(
        "gt.clock_rate",
        "-",
        1e-5,
        "the ground truth's clock running {value:+.0f} ppm fast",
        1e6,
        "timestamp a common event on both clocks at the start and at the end of a long session",
    ),
)
"""Every nuisance of the joint Jacobian, in the order of :func:`remove_nuisances`' values: the
session's (τ, dx, dy, δ) of :class:`~odomgym.diagnose.nuisances.SessionNuisance`, then the
fields of :class:`GroundTruthError`."""
_SESSION_KINDS = 4  # the first four are SessionNuisance's values


@dataclass(frozen=True)
class GroundTruthError:
    """Errors of the ground-truth system of one session, as perturbations of what it logs.

    A true tracked pose (p, θ) in the ground truth's ideal frame is logged as
    ((1 + scale)·R(rotation)·p + (translation_x, translation_y), θ + rotation): the frame's
    scale and rotation are about its origin. Because every replay starts at the first measured
    pose, the point they are about does not matter to the residuals (a translation of the whole
    frame is invisible, :data:`INVISIBLE`).

    ``clock_rate`` ρ: the ground truth's clock runs fast by ρ relative to the encoders': an event
    at encoder time t is stamped t_ref + (1 + ρ)·(t − t_ref), t_ref the session's start (where
    the run records it, ``Run.meta["session_time"]`` at its first sample) or else the run's
    first sample. A constant offset between the clocks is the time offset τ of
    :class:`~odomgym.diagnose.nuisances.SessionNuisance`.

    Attributes:
        translation_x, translation_y: [m]. rotation: [rad]. scale, clock_rate: [-].
    """

    translation_x: float = 0.0
    translation_y: float = 0.0
    rotation: float = 0.0
    scale: float = 0.0
    clock_rate: float = 0.0

    def apply(self, run: Run) -> Run:
        """``run`` (the truth) as the ground-truth system with these errors would log it."""
        return self._map(run, inverse=False)

    def remove(self, run: Run) -> Run:
        """``run`` (as logged) with these errors removed: the exact inverse of :meth:`apply`
        (to the linear interpolation of the counts for the clock rate)."""
        return self._map(run, inverse=True)

    def _map(self, run: Run, inverse: bool) -> Run:
        if self == GroundTruthError():
            return run
        pose = np.array(run.true_pose, dtype=np.float64, copy=True)
        c, s = math.cos(self.rotation), math.sin(self.rotation)
        x, y = pose[:, 0].copy(), pose[:, 1].copy()
        if inverse:
            x, y = x - self.translation_x, y - self.translation_y
            k = 1.0 / (1.0 + self.scale)
            pose[:, 0] = k * (c * x + s * y)
            pose[:, 1] = k * (-s * x + c * y)
            pose[:, 2] -= self.rotation
        else:
            k = 1.0 + self.scale
            pose[:, 0] = k * (c * x - s * y) + self.translation_x
            pose[:, 1] = k * (s * x + c * y) + self.translation_y
            pose[:, 2] += self.rotation
        counts = run.counts
        if self.clock_rate != 0.0:
            start = float(run.time[0]) - float(run.meta.get("session_time", 0.0))  # type: ignore[arg-type]
            rate = 1.0 / (1.0 + self.clock_rate) if inverse else 1.0 + self.clock_rate
            at = start + rate * (run.time - start)
            raw = run.counts.astype(np.float64)
            counts = np.stack([np.interp(at, run.time, raw[:, w]) for w in range(2)], axis=1)
        return dataclasses.replace(run, counts=counts, true_pose=pose)


def remove_nuisances(run: Run, values: Sequence[float] | FloatArray, session: str = "") -> Run:
    """``run`` with the nuisances ``values`` (one per :data:`NUISANCE_KINDS`) removed: the
    ground-truth system's errors first (they act on what it logged), then the session's time
    offset, tracked point and yaw (:func:`~odomgym.diagnose.nuisances.correct_run`)."""
    v = np.asarray(values, dtype=np.float64)
    error = GroundTruthError(*(float(a) for a in v[_SESSION_KINDS:]))
    own = SessionNuisance(session, frame=True).with_values(v[:_SESSION_KINDS])
    return correct_run(error.remove(run), own)


@dataclass(frozen=True)
class Column:
    """One column of the joint Jacobian.

    Attributes:
        name: ``EFFECT.PARAMETER`` for a robot parameter; the nuisance's
            :attr:`NuisanceKind.name`, with ``[SESSION]`` when there are several sessions.
        parameter: the robot parameter, or None for a nuisance.
        kind: the nuisance's index in :data:`NUISANCE_KINDS` (−1 for a robot parameter).
        session: the nuisance's session (``""`` for a robot parameter).
    """

    name: str
    parameter: Parameter | None
    kind: int
    session: str

    @property
    def unit(self) -> str:
        """The SI unit of the column's quantity."""
        if self.parameter is not None:
            return self.parameter.unit
        return NUISANCE_KINDS[self.kind].unit


@dataclass(frozen=True, eq=False)
class JointJacobian:
    """The joint Jacobian of a fit's open-loop residuals (module docstring); frozen, with the
    fit and the data it was computed for.

    Attributes:
        names: every visible column: the robot's parameters, then each session's nuisances.
        robot: how many of them are the robot's.
        matrix: the columns (rows: every run's weighted residuals stacked), per unit of each
            column's quantity (a parameter's own unit; :attr:`NuisanceKind.unit`).
        norms: each column's norm (zero for a robot parameter the data do not see).
        invisible: the nuisances the replay absorbs (left out of ``names``).
        columns: what each column is (:class:`Column`), in the order of ``names``.
        fit, data: what it was computed for (:meth:`residuals` evaluates them exactly).
    """

    names: tuple[str, ...]
    robot: int
    matrix: FloatArray
    norms: FloatArray
    invisible: tuple[str, ...]
    columns: tuple[Column, ...]
    fit: OpenLoopFit
    data: OpenLoopData

    def residuals(self, step: Mapping[str, float]) -> FloatArray:
        """The stacked weighted residuals with the named columns changed by ``step`` (in their
        units) from the fit, evaluated exactly on the data (not linearised): what a confound's
        direction must leave unchanged."""
        fit, data = self.fit, self.data
        problem = fit.problem
        by_name = {c.name: c for c in self.columns}
        du = np.zeros(problem.size)
        values = {s: np.zeros(len(NUISANCE_KINDS)) for s in problem.sessions}
        for s in problem.sessions:
            values[s][:_SESSION_KINDS] = problem.nuisance(fit.x, s).values
        for name, amount in step.items():
            column = by_name[name]
            if column.parameter is not None:
                du[self.names.index(name)] = amount / column.parameter.scale
            else:
                values[column.session][column.kind] += amount
        spec = problem.build(fit.x[: problem.size] + du)
        return _stacked(data, spec, values, data.runs)


def _column_name(kind: NuisanceKind, session: str, several: bool) -> str:
    return f"{kind.name}[{session}]" if several else kind.name


def robot_parameters(fit: OpenLoopFit) -> list[tuple[str, Parameter]]:
    """The fit's robot parameters, named as the fit's values are (``EFFECT.PARAMETER``)."""
    effect = fit.effect
    if effect is None:
        return []
    if isinstance(effect, Joint):
        return [(p.name, p) for p in effect.parameters]
    return [(f"{effect.name}.{p.name}", p) for p in effect.parameters]


def _stacked(
    data: OpenLoopData,
    spec: RobotSpec,
    values: Mapping[str, FloatArray],
    runs: Sequence[Run],
) -> FloatArray:
    """Every run's weighted residuals (:func:`odomgym.diagnose.openloop._residual`, as the fit
    computes them) with its session's nuisances ``values`` removed from ``runs``, stacked."""
    view = copy.copy(data)
    view.inputs = [{} for _ in runs]  # the replay inputs depend on the runs' counts
    view.corrected = [{} for _ in runs]  # so do the corrected runs and the stacks
    view.stacks = {}
    view.fixed_arrays = None
    view.runs = [
        GroundTruthError(*values[s][_SESSION_KINDS:]).remove(r)
        for r, s in zip(runs, data.sessions, strict=True)
    ]
    parts = []
    for j, session in enumerate(data.sessions):
        own = SessionNuisance(session, frame=True).with_values(values[session][:_SESSION_KINDS])
        parts.append(_residual(view, j, spec, own))
    return np.concatenate(parts) if parts else np.zeros(0)


def _measured(
    data: OpenLoopData, runs: Sequence[Run], values: Mapping[str, FloatArray]
) -> FloatArray:
    """The measured part of the residuals alone (the corrected poses, weighted and masked as
    the residuals; heading × the fit's length), stacked: what a nuisance does to the logs."""
    parts = []
    for j, (run, session) in enumerate(zip(runs, data.sessions, strict=True)):
        pose = remove_nuisances(run, values[session], session).true_pose.copy()
        pose[:, 2] *= data.length
        parts.append(pose[data.masks[j]] * data.weights[j])
    return np.concatenate(parts) if parts else np.zeros(0)


def _uncorrected(pose: FloatArray, measured: FloatArray, nuisance: SessionNuisance) -> FloatArray:
    """The raw poses whose :func:`~odomgym.diagnose.nuisances.correct_run` is ``pose``: heading
    θ + δ, position p + R(θ)·(dx, dy) — where the measured row has a heading (a row without one
    keeps its position, as the correction does); NaN where ``measured`` is."""
    out = np.array(pose, dtype=np.float64, copy=True)
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    has = np.isfinite(measured[:, 2])
    out[:, 0] += np.where(has, c * nuisance.dx - s * nuisance.dy, 0.0)
    out[:, 1] += np.where(has, s * nuisance.dx + c * nuisance.dy, 0.0)
    out[:, 2] += nuisance.yaw
    out[~np.isfinite(measured)] = np.nan
    return out


def _shifted(values: Mapping[str, FloatArray], kind: int, step: float) -> dict[str, FloatArray]:
    """Every session's nuisances with nuisance ``kind`` moved by ``step`` (all sessions at once:
    a session's nuisances touch only its runs)."""
    out = {s: v.copy() for s, v in values.items()}
    for v in out.values():
        v[kind] += step
    return out


def joint_jacobian(data: OpenLoopData, fit: OpenLoopFit) -> JointJacobian:
    """The joint Jacobian of ``fit``'s open-loop residuals on ``data`` (module docstring): the
    fit's own blocks where it has them, and for every other nuisance kind a central difference
    along the fitted model's prediction (two evaluations of every run, all sessions at once)."""
    problem = fit.problem
    if len(problem.data) != len(data):
        raise ValueError("the fit was made on other data")
    robot_blocks, own_blocks, _ = fit.blocks
    sessions = list(problem.sessions)
    several = len(sessions) >= 2
    rows = [len(b) for b in fit.blocks[2]]
    which = np.concatenate(
        [np.full(n, sessions.index(s)) for n, s in zip(rows, data.sessions, strict=True)]
    ).astype(int)
    robot = robot_parameters(fit)
    names: list[str] = [n for n, _ in robot]
    columns: list[Column] = [Column(n, p, -1, "") for n, p in robot]
    blocks: list[FloatArray] = []
    if robot:
        stacked = np.concatenate(robot_blocks)
        blocks.extend(stacked[:, k] / p.scale for k, (_, p) in enumerate(robot))
    fitted = {s: np.zeros(len(NUISANCE_KINDS)) for s in sessions}
    for s in sessions:
        fitted[s][:_SESSION_KINDS] = problem.nuisance(fit.x, s).values
    # The fitted model's own logs: every measured pose replaced by its prediction.
    own = {s: problem.nuisance(fit.x, s) for s in sessions}
    clean: list[Run] = []
    for j, run in enumerate(data.runs):
        nuisance = own[data.sessions[j]]
        _, replayed = data.replay(j, fit.spec, nuisance)
        pose = _uncorrected(replayed.tracked, run.true_pose, nuisance)
        clean.append(dataclasses.replace(run, true_pose=pose))
    data_measured = _measured(data, data.runs, fitted)
    invisible: list[str] = []
    active = list(problem.active)
    for k, kind in enumerate(NUISANCE_KINDS):
        plus, minus = _shifted(fitted, k, kind.step), _shifted(fitted, k, -kind.step)
        if k in active:  # the fit's own column, per unit of the nuisance
            i = active.index(k)
            change = np.concatenate(own_blocks)[:, i] / _NUISANCE_SCALE[k]
            logs = (_measured(data, data.runs, plus) - data_measured) / kind.step
        else:
            # Central differences: the counts are interpolated linearly between samples, so a
            # time shift has a kink at every whole sample — at τ = 0 among them — where a
            # one-sided difference would take one side's slope.
            change = (
                _stacked(data, fit.spec, plus, clean) - _stacked(data, fit.spec, minus, clean)
            ) / (2.0 * kind.step)
            logs = (_measured(data, clean, plus) - _measured(data, clean, minus)) / (
                2.0 * kind.step
            )
        for index, session in enumerate(sessions):
            mine = which == index
            column = np.where(mine, change, 0.0)
            size = float(np.linalg.norm(column))
            seen = max(
                float(np.linalg.norm(logs[mine])), float(np.linalg.norm((logs - change)[mine]))
            )
            name = _column_name(kind, session, several)
            if not (size > INVISIBLE * seen) or not math.isfinite(size):
                invisible.append(name)
                continue
            names.append(name)
            columns.append(Column(name, None, k, session))
            blocks.append(column)
    matrix = np.stack(blocks, axis=1) if blocks else np.zeros((int(sum(rows)), 0))
    return JointJacobian(
        names=tuple(names),
        robot=len(robot),
        matrix=matrix,
        norms=np.linalg.norm(matrix, axis=0),
        invisible=tuple(invisible),
        columns=tuple(columns),
        fit=fit,
        data=data,
    )

"""The open-loop prediction of a robot model, in plain units: what a diagnosed model is judged by.

A model is better than another only if it predicts the robot's poses better *from the wheel
motions alone*, on runs — on a real robot, on sessions — it was not fitted on. That is what a
roboticist uses a model for (dead reckoning, or a simulator that behaves like the robot), and it
cannot be gamed by a noise model that merely widens the predicted spread, as a whitened gap can.

**Error.** A run's logged counts are replayed through the model (:func:`odomgym.diagnose.replay.
replay_run`) after its session's measurement nuisances are removed
(:mod:`odomgym.diagnose.nuisances`), and the prediction is placed where the measured poses of the
run's first :data:`ALIGN_WINDOW` seconds put it (:func:`aligned_prediction`: one sample would
carry its tracker noise into every later prediction); the error at every measured sample after
that window is measured − predicted: position [m], heading [rad]. The *combined* error of a
sample is |Δp|² + (L·Δθ)², L = the model's nominal wheelbase [m/rad] (a heading error weighs as
the displacement it makes at the wheels); a run's mean square error is its mean over the
samples, one per ``interval`` seconds; runs weigh equally. The reports give position and heading
RMS separately, over every measured sample after the window.

**Fit.** Least squares on those errors (:func:`fit_open_loop`, :func:`scipy.optimize.least_squares`,
trust-region reflective): a model's systematic parameters jointly with each session's nuisances
(Furgale, Rehder & Siegwart 2013 fit the time offset jointly with the rest, as here), by finite
differences over a block-sparse Jacobian (a session's nuisances touch only its runs). The
nuisances start from a coarse search: the time offset on a grid, the yaw misalignment in closed
form for each (it rotates the predicted path about its start: a Procrustes rotation), so any yaw
and offsets up to ``max_time_offset`` are found. Errors along a run are strongly correlated, so
model-based standard errors would be far too small: they are cluster-robust, by run and by
session (Liang & Zeger 1986).

**Cross-validation.** :func:`open_loop_folds` leaves whole sessions out (or, with one session,
per experiment family a contiguous block of runs in time); a fold's parameters are one
Gauss–Newton step from the full fit without the fold's rows (exact for the linear part), and a
left-out session's nuisances are then fitted on its own runs with the robot fixed — they belong
to that recording, and every model compared gets the same treatment
(:func:`cross_validate_open_loop`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.data.gaps import measured_end
from odomgym.diagnose.fit import (
    JACOBIAN_STEP,
    build_within,
    gauss_newton_step,
    strata,
    systematic_vector,
)
from odomgym.diagnose.likelihood import measurement_mask
from odomgym.diagnose.nuisances import (
    SessionNuisance,
    correct_run,
    offset_is_significant,
    sessions_of,
)
from odomgym.diagnose.replay import (
    Replay,
    RunInputs,
    RunStack,
    _cos_sin,
    replay_run,
    replay_stacked,
    stackable,
)
from odomgym.diagnose.stats import clustered_covariance
from odomgym.effects import Effect
from odomgym.errors import SpecError
from odomgym.odometry.runs import Run, rotate_into
from odomgym.odometry.umbmark_measures import e_max_syst
from odomgym.robot import RobotSpec

__all__ = [
    "ModelErrors",
    "NuisanceOptions",
    "OpenLoopData",
    "OpenLoopFit",
    "aligned_prediction",
    "alignment_samples",
    "cross_validate_open_loop",
    "evaluate_open_loop",
    "fit_open_loop",
    "open_loop_folds",
    "pose_errors",
    "predicted_path",
    "rms_over_runs",
    "run_errors",
    "variance_inflation",
]

FloatArray = NDArray[np.float64]
_NUISANCE_SCALE = np.array([0.01, 1e-3, 1e-3, 1e-2])  # τ [s], dx, dy [m], δ [rad]: fit units
_NUISANCE_BOUND = np.array([math.inf, 1.0, 1.0, math.inf])  # |dx|, |dy| < 1 m
_GRID_STEP = 0.05  # [s]: the time-offset grid of the starting search
_KEPT_INPUTS = 4  # replay inputs kept per run (OpenLoopData.replay)


@dataclass(frozen=True)
class NuisanceOptions:
    """Which measurement nuisances are fitted per session.

    Attributes:
        time_offset: fit the time offset τ of the encoder log against the ground truth.
        frames: fit the tracked point (dx, dy) and the yaw misalignment δ (on when the runs
            come from two or more sessions: with one session they are the catalogue's
            ``gt_sensor_offset`` and ``wheel_toe``).
        max_time_offset: the largest |τ| searched and allowed [s].
    """

    time_offset: bool = True
    frames: bool = False
    max_time_offset: float = 1.0

    @property
    def active(self) -> tuple[int, ...]:
        """Indices of the fitted nuisances in (τ, dx, dy, δ)."""
        return ((0,) if self.time_offset else ()) + ((1, 2, 3) if self.frames else ())


class OpenLoopData:
    """Runs with the samples whose open-loop error counts (:func:`measurement_mask`: measured
    components, one sample per ``interval``, never the first) and each run's weight, and the
    replay inputs kept for its runs (:meth:`replay`; a subset shares them)."""

    def __init__(self, runs: Sequence[Run], interval: float, length: float) -> None:
        self.runs = list(runs)
        self.interval = interval
        self.length = length
        self.masks = [open_loop_mask(r, interval) for r in self.runs]
        self.sessions = sessions_of(self.runs)
        # Runs weigh equally: each run's residuals are divided by √(its measured samples).
        self.weights = [1.0 / math.sqrt(max(int(m.any(axis=1).sum()), 1)) for m in self.masks]
        self.inputs: list[dict[tuple[float, float], RunInputs]] = [{} for _ in self.runs]
        self.corrected: list[dict[tuple[float, ...] | None, Run]] = [{} for _ in self.runs]
        self.stacks: dict[tuple[object, ...], RunStack] = {}
        self.fixed_arrays: _StackedRuns | None = None

    def replay(
        self, j: int, spec: RobotSpec, nuisance: SessionNuisance | None
    ) -> tuple[Run, Replay]:
        """Run ``j`` with ``nuisance`` removed, and its replay through ``spec``.

        What the replay takes from the run alone (:class:`~odomgym.diagnose.replay.RunInputs`)
        is kept per time offset and encoder resolution (the only parts of a nuisance and a model
        it depends on): a fit replays every run hundreds of times, mostly at one time offset,
        and building them took a third of each replay. A few are kept per run (the offset moves
        while it is fitted), and so are the corrected runs (:meth:`_corrected`, shared with
        :meth:`stacked_residuals`); the replay is the one :func:`replay_run` makes without
        them."""
        fixed = self._corrected(j, nuisance)
        return fixed, replay_run(fixed, spec, self._inputs(j, fixed, nuisance, spec))

    def _inputs(
        self, j: int, fixed: Run, nuisance: SessionNuisance | None, spec: RobotSpec
    ) -> RunInputs:
        offset = nuisance.time_offset if nuisance is not None else 0.0
        key = (offset, float(spec.ticks_per_rev))
        held = self.inputs[j]
        inputs = held.get(key)
        if inputs is None:
            if len(held) >= _KEPT_INPUTS:
                held.clear()
            inputs = held[key] = RunInputs.of(fixed, spec.ticks_per_rev)
        return inputs

    def _corrected(self, j: int, nuisance: SessionNuisance | None) -> Run:
        """Run ``j`` with ``nuisance`` removed (:func:`correct_run`), a few kept per run (a
        fit's Jacobian moves the robot's parameters with the nuisances where they were)."""
        key = None if nuisance is None else tuple(float(v) for v in nuisance.values)
        held = self.corrected[j]
        fixed = held.get(key)
        if fixed is None:
            if len(held) >= _KEPT_INPUTS:
                held.clear()
            fixed = held[key] = correct_run(self.runs[j], nuisance)
        return fixed

    def stacked_residuals(
        self, spec: RobotSpec, nuisances: Sequence[SessionNuisance | None]
    ) -> list[FloatArray] | None:
        """Every run's :func:`_residual` (run j with ``nuisances[j]`` removed), from one
        stacked replay (:func:`~odomgym.diagnose.replay.replay_stacked`) and two compiled
        passes for the alignment and the weighting (:func:`_stacked_open_loop_residuals`): the
        same bytes as run by run. None where a replay of ``spec`` does not stack (fewer than
        two runs, or an effect that replays one run at a time).

        Why: an open-loop fit evaluates every run at every step and Jacobian column, and the
        Python around each run's replay, alignment and residual (~100 µs) was most of it."""
        if len(self.runs) < 2 or not stackable(spec):
            return None
        ticks = float(spec.ticks_per_rev)
        keys = tuple(None if n is None else tuple(float(v) for v in n.values) for n in nuisances)
        stack = self.stacks.get((ticks, keys))
        if stack is None:
            fixed = [self._corrected(j, n) for j, n in enumerate(nuisances)]
            inputs = [
                self._inputs(j, f, n, spec)
                for j, (f, n) in enumerate(zip(fixed, nuisances, strict=True))
            ]
            if len(self.stacks) >= _KEPT_INPUTS:
                self.stacks.clear()
            stack = self.stacks[(ticks, keys)] = RunStack.of(fixed, inputs)
        if self.fixed_arrays is None:
            self.fixed_arrays = _StackedRuns.of(self)
        arrays = self.fixed_arrays
        replay = replay_stacked(stack, spec)
        out = _stacked_open_loop_residuals(
            stack.measured, replay.tracked, arrays, replay.samples(), float(self.length)
        )
        rows = arrays.rows.tolist()
        return [out[rows[j] : rows[j + 1]] for j in range(len(self.runs))]

    def subset(self, index: Sequence[int]) -> OpenLoopData:
        out = OpenLoopData.__new__(OpenLoopData)
        out.runs = [self.runs[j] for j in index]
        out.interval, out.length = self.interval, self.length
        out.masks = [self.masks[j] for j in index]
        out.sessions = [self.sessions[j] for j in index]
        out.weights = [self.weights[j] for j in index]
        out.inputs = [self.inputs[j] for j in index]
        out.corrected = [self.corrected[j] for j in index]
        out.stacks = {}
        out.fixed_arrays = None
        return out

    def __len__(self) -> int:
        return len(self.runs)


@dataclass(frozen=True)
class _StackedRuns:
    """What :meth:`OpenLoopData.stacked_residuals` takes from the runs alone, stacked: the
    sample times (ΣT,) [s], the masks (ΣT, 3), each run's weight (R,) and where each run's
    residuals start in the stacked residual vector (R + 1,)."""

    time: FloatArray
    mask: NDArray[np.bool_]
    weights: FloatArray
    rows: NDArray[np.int64]

    @classmethod
    def of(cls, data: OpenLoopData) -> _StackedRuns:
        rows = np.zeros(len(data.runs) + 1, dtype=np.int64)
        np.cumsum([int(m.sum()) for m in data.masks], out=rows[1:])
        return cls(
            np.ascontiguousarray(np.concatenate([r.time for r in data.runs]), dtype=np.float64),
            np.ascontiguousarray(np.concatenate(data.masks), dtype=np.bool_),
            np.array(data.weights, dtype=np.float64),
            rows,
        )


def _wrap(angle: FloatArray) -> FloatArray:
    wrapped: FloatArray = np.mod(angle + math.pi, 2.0 * math.pi) - math.pi
    return wrapped


def pose_errors(run: Run, spec: RobotSpec, nuisance: SessionNuisance | None) -> FloatArray:
    """Measured − predicted poses (T, 3) [m, m, rad] of ``run`` replayed open loop through
    ``spec`` with ``nuisance`` removed; heading wrapped to [−π, π); NaN where not measured."""
    fixed = correct_run(run, nuisance)
    return _measured_minus(fixed, replay_run(fixed, spec))


ALIGN_WINDOW = 1.0
"""How long after a run's first sample the measured poses fix where the prediction starts [s]
(:func:`aligned_prediction`); their errors are not counted. A second: 20 poses of a 20 Hz
tracker, the first 30 cm of a straight at 0.3 m/s, in which no effect of the catalogue moves
the heading by more than a few µrad (a 0.5 s window left a third of the small-effect trials of
the hidden-effect matrix to the tracker's start noise)."""


ALIGN_TURN = 0.02
"""The most the prediction may have turned since the start at a sample the alignment uses
[rad]: where the robot has turned, effects that act through turning (a wheelbase, backlash at
the first reversal of a spin) have begun to act, and an alignment there would take their signal
for the tracker's noise."""


def _in_window(run: Run) -> NDArray[np.bool_]:
    """The samples within :data:`ALIGN_WINDOW` of ``run``'s first (whose errors are not
    counted)."""
    inside: NDArray[np.bool_] = np.asarray(run.time - run.time[0] <= ALIGN_WINDOW + 1e-9)
    return inside


def aligned_prediction(fixed: Run, replayed: Replay) -> FloatArray:
    """``replayed``'s tracked poses (T, 3) moved rigidly onto ``fixed``'s measured poses of its
    first :data:`ALIGN_WINDOW` seconds, before the prediction has turned by
    :data:`ALIGN_TURN`: turned about the start by the mean heading difference there, then
    shifted by the mean position difference.

    Why: the replay starts at the first measured pose, so that one sample's tracker noise moves
    every later prediction — a 2 mrad heading error is 6 mm after 3 m — and on a robot with a
    1 mm / 0.11° tracker it decided more comparisons of small effects than the effects did.
    Aligning a prediction on several measured poses is the practice of trajectory evaluation
    (Zhang & Scaramuzza 2018, trajectory alignment); aligning only on the first second
    keeps it open loop, and takes from an effect only what it does in that second before any
    turn (a straight's first 30 cm; in a spin, the samples before the wheels move). A log
    measured at its end points (UMBmark) has one pose there: the alignment is then the
    anchor."""
    predicted = np.array(replayed.tracked, dtype=np.float64)
    measured = fixed.true_pose
    inside = alignment_samples(fixed, predicted)
    heading = measured[inside, 2] - predicted[inside, 2]
    heading = heading[np.isfinite(heading)]
    cosines, sines = _cos_sin(np.ascontiguousarray(heading, dtype=np.float64))
    turn = float(np.arctan2(np.mean(sines), np.mean(cosines))) if heading.size else 0.0
    if turn != 0.0:
        c, s = math.cos(turn), math.sin(turn)
        start = predicted[0, :2].copy()
        rel = predicted[:, :2] - start
        predicted[:, 0] = start[0] + c * rel[:, 0] - s * rel[:, 1]
        predicted[:, 1] = start[1] + s * rel[:, 0] + c * rel[:, 1]
        predicted[:, 2] += turn
    shift = measured[inside, :2] - predicted[inside, :2]
    shift = shift[np.isfinite(shift).all(axis=1)]
    if shift.size:
        predicted[:, :2] += np.mean(shift, axis=0)
    return predicted


def alignment_samples(fixed: Run, predicted: FloatArray) -> NDArray[np.bool_]:
    """The samples :func:`aligned_prediction` aligns on: those within :data:`ALIGN_WINDOW` of
    the start up to the first at which the robot has turned by more than :data:`ALIGN_TURN`
    from its first heading — as measured, where the heading is (the set is then the data's,
    the same for every model fitted to it, and a least-squares fit sees a smooth error), else
    as ``predicted`` (T, 3)."""
    heading = np.where(np.isfinite(fixed.true_pose[:, 2]), fixed.true_pose[:, 2], predicted[:, 2])
    turn = np.abs(np.mod(heading - heading[0] + math.pi, 2.0 * math.pi) - math.pi)
    before: NDArray[np.bool_] = np.logical_and.accumulate(turn <= ALIGN_TURN)
    return _in_window(fixed) & before


def _measured_minus(fixed: Run, replayed: Replay) -> FloatArray:
    """``fixed``'s measured poses minus ``replayed``'s tracked ones aligned on the start
    (:func:`aligned_prediction`), heading wrapped; NaN within the alignment window."""
    error = fixed.true_pose - aligned_prediction(fixed, replayed)
    error[:, 2] = _wrap(error[:, 2])
    error[_in_window(fixed)] = np.nan
    return error


@kernel
def _block_sum(values: FloatArray, start: int, n: int) -> float:
    """numpy's pairwise sum of a block of at most 128 values (:func:`_pairwise_sum`)."""
    if n < 8:
        total: float = -0.0
        for i in range(n):
            total += values[start + i]
        return total
    r0 = values[start]
    r1 = values[start + 1]
    r2 = values[start + 2]
    r3 = values[start + 3]
    r4 = values[start + 4]
    r5 = values[start + 5]
    r6 = values[start + 6]
    r7 = values[start + 7]
    i = 8
    end = n - n % 8
    while i < end:
        r0 += values[start + i]
        r1 += values[start + i + 1]
        r2 += values[start + i + 2]
        r3 += values[start + i + 3]
        r4 += values[start + i + 4]
        r5 += values[start + i + 5]
        r6 += values[start + i + 6]
        r7 += values[start + i + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        total += values[start + i]
        i += 1
    return total


@kernel
def _pairwise_sum(values: FloatArray, start: int, n: int) -> float:
    """numpy's sum of ``values[start:start + n]`` (a contiguous float64 vector): its pairwise
    summation (eight partial sums in blocks of up to 128; above, the two halves summed apart,
    the first a multiple of 8 long, then added), the same operations in the same order, so the
    same bytes (``tests/test_diagnose_speed.py`` holds it to ``numpy.sum``). numpy recurses;
    this walks the same tree with a stack of its own, as numba's on-disk cache cannot reload a
    recursive kernel (it crashed the process that loaded it, numba 0.68)."""
    if n <= 128:
        return _block_sum(values, start, n)
    starts = np.empty(256, dtype=np.int64)
    sizes = np.empty(256, dtype=np.int64)
    joins = np.zeros(256, dtype=np.bool_)
    partial = np.empty(256)
    top = 0
    done = 0
    starts[0] = start
    sizes[0] = n
    top = 1
    while top > 0:
        top -= 1
        s = starts[top]
        m = sizes[top]
        if joins[top]:  # both halves summed: first + second
            joins[top] = False
            second = partial[done - 1]
            first = partial[done - 2]
            done -= 2
            partial[done] = first + second
            done += 1
        elif m <= 128:
            partial[done] = _block_sum(values, s, m)
            done += 1
        else:
            half = m // 2
            half -= half % 8
            joins[top] = True  # this entry again, after both halves
            top += 1
            starts[top] = s + half
            sizes[top] = m - half
            joins[top] = False
            top += 1
            starts[top] = s
            sizes[top] = half
            joins[top] = False
            top += 1
    return float(partial[0])


@kernel
def _interval_rates(
    index: NDArray[np.int64],
    gained: FloatArray,
    cross: FloatArray,
    classes: NDArray[np.int64],
    ds: FloatArray,
    dtheta: FloatArray,
    reversal: NDArray[np.bool_],
    kind: NDArray[np.int64],
    heading: FloatArray,
    off_track: FloatArray,
    per_reversal: FloatArray,
    reversed_: NDArray[np.bool_],
) -> None:
    """The manoeuvre view of :func:`odomgym.diagnose.where.localise` for one run, interval
    by interval between consecutive measured samples ``index[p]``, ``index[p + 1]``:
    ``kind[p]`` the manoeuvre the interval is counted for (1 straight, 2 in-place turn, 3 arc;
    0 none: stops, too short, or more than one manoeuvre), ``heading[p]`` the heading
    disagreement gained per metre (1) or per radian (2, 3), ``off_track[p]`` the cross-track
    one per metre (1), ``per_reversal[p]`` the heading gained per wheel reversal where
    ``reversed_[p]`` (a wheel reversed in it).

    Why compiled: a loop of small numpy calls per interval took 0.8 s of the 14 June OptiOdom
    sessions (102 runs). The same numbers: the class is the most frequent one (the first of
    equals, as ``bincount().argmax()``), and the distances and angles are numpy's pairwise sums
    of the absolute values (:func:`_pairwise_sum`). It lives here, beside the sum it calls, not
    in :mod:`odomgym.diagnose.where`: numba's on-disk cache does not see edits to a kernel
    called from another module (:mod:`odomgym._jit`)."""
    longest = 0
    for p in range(index.shape[0] - 1):
        longest = max(longest, index[p + 1] - index[p])
    absolute = np.empty(longest)
    for p in range(index.shape[0] - 1):
        a = index[p]
        b = index[p + 1]
        kind[p] = 0
        heading[p] = np.nan
        off_track[p] = np.nan
        per_reversal[p] = np.nan
        reversed_[p] = False
        first = 0
        mixed = False
        counts = np.zeros(4, dtype=np.int64)
        flips = 0
        for i in range(a, b):
            c = classes[i]
            counts[c] += 1
            if c != 0:
                if first == 0:
                    first = c
                elif c != first:
                    mixed = True
            if reversal[i]:
                flips += 1
        if mixed:
            continue
        cls = 0
        for c in range(1, 4):
            if counts[c] > counts[cls]:
                cls = c
        dh = gained[b] - gained[a]
        dc = cross[b] - cross[a]
        if cls == 1:
            for i in range(a, b):
                absolute[i - a] = abs(ds[i])
            dist = _pairwise_sum(absolute, 0, b - a)
            if dist > 0.02:
                kind[p] = 1
                heading[p] = dh / dist
                off_track[p] = dc / dist
        elif cls == 2 or cls == 3:
            for i in range(a, b):
                absolute[i - a] = abs(dtheta[i])
            ang = _pairwise_sum(absolute, 0, b - a)
            if ang > 0.05:
                kind[p] = cls
                heading[p] = dh / ang
        if flips > 0:
            reversed_[p] = True
            per_reversal[p] = dh / float(flips)


@kernel
def _numpy_mod(x: float, period: float) -> float:
    """``numpy.mod(x, period)`` for a positive ``period``: fmod, plus the period where that is
    non-zero and negative, +0.0 where it is zero (numpy's float remainder)."""
    mod = float(np.fmod(x, period))
    if mod != 0.0:  # NaN included, as numpy's ``if (mod)``
        if mod < 0.0:
            mod += period
    else:
        mod = 0.0
    return mod


@kernel
def _stacked_alignment(
    measured: FloatArray,
    tracked: FloatArray,
    time: FloatArray,
    samples: NDArray[np.int64],
    window: float,
    align_turn: float,
    inside: NDArray[np.bool_],
    mean_sin: FloatArray,
    mean_cos: FloatArray,
    counts: NDArray[np.int64],
) -> None:
    """First pass of :func:`_stacked_open_loop_residuals`, run by run (samples rows
    ``samples[r]:samples[r + 1]``): :func:`alignment_samples` into ``inside`` (ΣT,), and the
    means of the sines and cosines of the heading differences there into ``mean_sin``,
    ``mean_cos`` (R,), over ``counts`` (R,) finite differences (numpy's pairwise sums)."""
    two_pi = 2.0 * math.pi
    for r in range(samples.shape[0] - 1):
        a = samples[r]
        b = samples[r + 1]
        n = b - a
        # the window before the robot has turned, by the measured heading where there is one,
        # else the predicted
        h0 = measured[a, 2] if np.isfinite(measured[a, 2]) else tracked[a, 2]
        before = True
        for k in range(a, b):
            hk = measured[k, 2] if np.isfinite(measured[k, 2]) else tracked[k, 2]
            turn = abs(_numpy_mod(hk - h0 + math.pi, two_pi) - math.pi)
            before = before and turn <= align_turn
            inside[k] = (time[k] - time[a] <= window) and before
        sines = np.empty(n)
        cosines = np.empty(n)
        m = 0
        for k in range(a, b):
            if inside[k]:
                d = measured[k, 2] - tracked[k, 2]
                if np.isfinite(d):
                    sines[m] = math.sin(d)
                    cosines[m] = math.cos(d)
                    m += 1
        counts[r] = m
        mean_sin[r] = _pairwise_sum(sines, 0, m) / m if m > 0 else 0.0
        mean_cos[r] = _pairwise_sum(cosines, 0, m) / m if m > 0 else 0.0


@kernel
def _stacked_open_loop(
    measured: FloatArray,
    tracked: FloatArray,
    inside: NDArray[np.bool_],
    turns: FloatArray,
    mask: NDArray[np.bool_],
    samples: NDArray[np.int64],
    weights: FloatArray,
    length: float,
    rows: NDArray[np.int64],
    out: FloatArray,
) -> None:
    """Second pass of :func:`_stacked_open_loop_residuals`: each run's prediction turned by
    ``turns[r]`` about its start and shifted by the mean position difference over ``inside``
    (:func:`aligned_prediction`; numpy's axis-0 mean: row by row), then
    :func:`_measured_minus` and :func:`_residual`'s masked, weighted errors into
    ``out[rows[r]:rows[r + 1]]``."""
    two_pi = 2.0 * math.pi
    for r in range(samples.shape[0] - 1):
        a = samples[r]
        b = samples[r + 1]
        n = b - a
        predicted = tracked[a:b].copy()
        turn = turns[r]
        if turn != 0.0:
            c = math.cos(turn)
            s = math.sin(turn)
            x0 = predicted[0, 0]
            y0 = predicted[0, 1]
            for k in range(n):
                rx = predicted[k, 0] - x0
                ry = predicted[k, 1] - y0
                predicted[k, 0] = x0 + c * rx - s * ry
                predicted[k, 1] = y0 + s * rx + c * ry
                predicted[k, 2] += turn
        sx = 0.0
        sy = 0.0
        count = 0
        for k in range(n):
            if inside[a + k]:
                ex = measured[a + k, 0] - predicted[k, 0]
                ey = measured[a + k, 1] - predicted[k, 1]
                if np.isfinite(ex) and np.isfinite(ey):
                    if count == 0:
                        sx = ex
                        sy = ey
                    else:
                        sx += ex
                        sy += ey
                    count += 1
        if count > 0:
            mx = sx / count
            my = sy / count
            for k in range(n):
                predicted[k, 0] += mx
                predicted[k, 1] += my
        # the alignment window's rows are never in the mask
        j = rows[r]
        w = weights[r]
        for k in range(n):
            for axis in range(3):
                if mask[a + k, axis]:
                    error = measured[a + k, axis] - predicted[k, axis]
                    if axis == 2:
                        error = (_numpy_mod(error + math.pi, two_pi) - math.pi) * length
                    out[j] = error * w
                    j += 1


def _stacked_open_loop_residuals(
    measured: FloatArray,
    tracked: FloatArray,
    arrays: _StackedRuns,
    samples: NDArray[np.int64],
    length: float,
) -> FloatArray:
    """:func:`_residual` of every run of stacked arrays, stacked (run r's residuals are
    ``arrays.rows[r]:arrays.rows[r + 1]``): :func:`aligned_prediction` (with
    :func:`alignment_samples`), :func:`_measured_minus` and the weighting, numpy's operations
    written out in numpy's order (its pairwise sums, the position shift's mean row by row, its
    float remainder), so the same bytes. Two compiled passes with numpy's ``arctan2`` of the
    mean sines and cosines between them: libm's ``atan2`` differs from numpy's in the last
    bit for about one pair in 20 000 (it moved a leave-one-session-out fold's gate rows in
    their eleventh digit)."""
    runs = len(samples) - 1
    inside = np.zeros(len(measured), dtype=np.bool_)
    mean_sin = np.zeros(runs)
    mean_cos = np.zeros(runs)
    counts = np.zeros(runs, dtype=np.int64)
    _stacked_alignment(
        measured,
        tracked,
        arrays.time,
        samples,
        ALIGN_WINDOW + 1e-9,
        ALIGN_TURN,
        inside,
        mean_sin,
        mean_cos,
        counts,
    )
    turns = np.where(counts > 0, np.arctan2(mean_sin, mean_cos), 0.0)
    out = np.empty(arrays.rows[-1])
    _stacked_open_loop(
        measured,
        tracked,
        inside,
        turns,
        arrays.mask,
        samples,
        arrays.weights,
        length,
        arrays.rows,
        out,
    )
    return out


def open_loop_mask(run: Run, interval: float) -> NDArray[np.bool_]:
    """The samples (T, 3) whose open-loop error counts: :func:`measurement_mask`'s, after the
    alignment window."""
    mask = measurement_mask(run, interval)
    mask[_in_window(run)] = False
    return mask


def predicted_path(run: Run, spec: RobotSpec, nuisance: SessionNuisance | None) -> FloatArray:
    """Where ``spec`` predicts the tracked point of ``run`` (T, 2) [m], open loop, in the ground
    truth's own frame: the replay (nuisances removed) with the tracked-point offset put back."""
    fixed = correct_run(run, nuisance)
    tracked = aligned_prediction(fixed, replay_run(fixed, spec))
    dx, dy = (nuisance.dx, nuisance.dy) if nuisance is not None else (0.0, 0.0)
    c, s = np.cos(tracked[:, 2]), np.sin(tracked[:, 2])
    out: FloatArray = np.stack(
        [tracked[:, 0] + c * dx - s * dy, tracked[:, 1] + s * dx + c * dy], 1
    )
    return out


def _errors(
    data: OpenLoopData, j: int, spec: RobotSpec, nuisance: SessionNuisance | None
) -> FloatArray:
    """:func:`pose_errors` of run ``j`` of ``data``, with the inputs it keeps."""
    return _measured_minus(*data.replay(j, spec, nuisance))


def _residual(
    data: OpenLoopData,
    j: int,
    spec: RobotSpec,
    nuisance: SessionNuisance | None,
    error: FloatArray | None = None,
) -> FloatArray:
    """Run ``j``'s weighted combined-error residuals; ``error``: its :func:`_errors` if the
    caller has them (they are not changed)."""
    error = _errors(data, j, spec, nuisance) if error is None else error.copy()
    error[:, 2] *= data.length
    out: FloatArray = error[data.masks[j]] * data.weights[j]
    return out


def _speeds(run: Run, spec: RobotSpec) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Interval midpoints [s], the encoders' body speed [m/s] and turn rate [rad/s] there (the
    nominal geometry), and the interval lengths [s]."""
    dt = np.diff(run.time)
    safe = np.where(dt > 0, dt, np.inf)
    travel = np.diff(run.counts.astype(np.float64), axis=0) * (
        math.pi * spec.wheel_diameter / spec.ticks_per_rev
    )
    v = 0.5 * (travel[:, 0] + travel[:, 1]) / safe
    omega = (travel[:, 1] - travel[:, 0]) / (spec.wheelbase * safe)
    return 0.5 * (run.time[1:] + run.time[:-1]), v, omega, dt


def _offset_from_speeds(
    data: OpenLoopData, members: Sequence[int], spec: RobotSpec, limit: float
) -> float:
    """A time offset τ to start from [s]: the lag that best matches the ground truth's body
    speed and turn rate (by differences of consecutive measured poses) to the encoders'
    (v_enc(t + τ) ≈ v_gt(t)), on a 5 ms grid over ±``limit``, refined by a parabola through the
    best three. No replay is needed, and a scale or wheelbase error does not move the lag. 0
    where the ground truth is too sparse to give speeds (an UMBmark end-point log)."""
    taus = np.arange(-limit, limit + 1e-12, 0.005)
    cost = np.zeros(len(taus))
    used = 0
    for j in members:
        run = data.runs[j]
        mid, v_enc, w_enc, dt = _speeds(run, spec)
        pose = run.true_pose
        step = np.diff(pose, axis=0)
        ok = np.isfinite(step).all(axis=1) & (dt > 0)
        if ok.sum() < 10:
            continue
        heading = pose[:-1, 2] + 0.5 * step[:, 2]
        v_gt = (step[:, 0] * np.cos(heading) + step[:, 1] * np.sin(heading)) / np.where(
            ok, dt, np.inf
        )
        w_gt = step[:, 2] / np.where(ok, dt, np.inf)
        at = mid[ok][None, :] + taus[:, None]
        dv = np.interp(at, mid, v_enc) - v_gt[ok][None, :]
        dw = (np.interp(at, mid, w_enc) - w_gt[ok][None, :]) * data.length
        cost += data.weights[j] ** 2 * np.sum(dv * dv + dw * dw, axis=1)
        used += 1
    if not used:
        return 0.0
    k = int(np.argmin(cost))
    if 0 < k < len(taus) - 1:
        c0, c1, c2 = cost[k - 1], cost[k], cost[k + 1]
        curvature = c0 - 2.0 * c1 + c2
        if curvature > 0:
            return float(taus[k] + 0.5 * 0.005 * (c0 - c2) / curvature)
    return float(taus[k])


def _procrustes_yaw(
    data: OpenLoopData, members: Sequence[int], spec: RobotSpec, time_offset: float
) -> float:
    """The yaw misalignment δ that best aligns the predicted paths of ``members`` (one
    session) with the measured ones at time offset τ, in closed form.

    δ rotates every predicted path about its start by −δ and leaves the heading errors as
    they are, so −δ is the Procrustes rotation of the predicted displacements a onto the
    measured b: atan2(Σ a×b, Σ a·b) (weighted as the fit weighs the runs)."""
    cross = dot = 0.0
    guess = SessionNuisance("", time_offset=time_offset)
    for j in members:
        fixed, replayed = data.replay(j, spec, guess)
        predicted = replayed.tracked
        rows = data.masks[j][:, 0] & data.masks[j][:, 1]
        w2 = data.weights[j] ** 2
        a = predicted[rows, :2] - fixed.true_pose[0, :2]
        b = fixed.true_pose[rows, :2] - fixed.true_pose[0, :2]
        cross += w2 * float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
        dot += w2 * float(np.sum(a * b))
    return -math.atan2(cross, dot)


def _start_nuisances(
    data: OpenLoopData, members: Sequence[int], spec: RobotSpec, options: NuisanceOptions
) -> FloatArray:
    """(τ, dx, dy, δ) to start one session's fit from: τ from the speeds
    (:func:`_offset_from_speeds`), δ in closed form at that τ (:func:`_procrustes_yaw`), the
    offsets 0 — so any yaw and any time offset within the limit is found."""
    out = np.zeros(4)
    if options.time_offset:
        out[0] = _offset_from_speeds(data, members, spec, options.max_time_offset)
    if options.frames:
        out[3] = _procrustes_yaw(data, members, spec, out[0])
    return out


class _Fixed:
    """The builder of a fit without robot parameters: ``spec`` whatever u (a class, not a
    closure, so that the fit pickles; :class:`~odomgym.diagnose.fit.SpecBuilder`)."""

    def __init__(self, spec: RobotSpec) -> None:
        self.spec = spec

    def __call__(self, u: FloatArray) -> RobotSpec:
        del u
        return self.spec


@dataclass
class _Problem:
    """The least-squares problem of :func:`fit_open_loop` in fit units: x = (the robot's
    parameters relative to the start, in units of their scale; then each session's active
    nuisances in units of ``_NUISANCE_SCALE``)."""

    data: OpenLoopData
    build: Callable[[FloatArray], RobotSpec]
    size: int  # robot parameters
    active: list[int]
    sessions: list[str]
    members: dict[str, list[int]]
    frames: bool
    low: FloatArray
    high: FloatArray

    def column(self, session: str) -> int:
        """The first nuisance column of ``session``."""
        return self.size + self.sessions.index(session) * len(self.active)

    def nuisance(self, x: FloatArray, session: str) -> SessionNuisance:
        values = np.zeros(4)
        if self.active:
            k = self.column(session)
            values[self.active] = x[k : k + len(self.active)] * _NUISANCE_SCALE[self.active]
        return SessionNuisance(session, len(self.members[session]), frame=self.frames).with_values(
            values
        )

    def residuals(self, x: FloatArray) -> list[FloatArray]:
        model = self.build(x[: self.size])
        cache = {s: self.nuisance(x, s) for s in self.sessions}
        stacked = self.data.stacked_residuals(
            model, [cache[self.data.sessions[j]] for j in range(len(self.data))]
        )
        if stacked is not None:
            return stacked
        return [
            _residual(self.data, j, model, cache[self.data.sessions[j]])
            for j in range(len(self.data))
        ]

    def jacobian(
        self, x: FloatArray, base: list[FloatArray], step: float = JACOBIAN_STEP
    ) -> tuple[list[FloatArray], list[FloatArray]]:
        """Forward differences: per run, d r_j / d robot (n_j, P) and d r_j / d its session's
        nuisances (n_j, k). A session's nuisances touch only its runs, so each nuisance
        column is perturbed in every session at once: P + k evaluations in all."""
        n = len(self.data)
        robot = [np.empty((len(base[j]), self.size)) for j in range(n)]
        own = [np.empty((len(base[j]), len(self.active))) for j in range(n)]
        for a in range(self.size):
            moved = x.copy()
            moved[a] += step
            try:
                shifted = self.residuals(moved)
                h = step
            except SpecError:  # at the edge of a valid robot: the backward difference
                moved[a] -= 2.0 * step
                shifted = self.residuals(moved)
                h = -step
            for j, r in enumerate(shifted):
                robot[j][:, a] = (r - base[j]) / h
        for i in range(len(self.active)):
            moved = x.copy()
            for s in self.sessions:
                moved[self.column(s) + i] += step
            for j, r in enumerate(self.residuals(moved)):
                own[j][:, i] = (r - base[j]) / step
        return robot, own

    def normal(
        self,
        robot: list[FloatArray],
        own: list[FloatArray],
        res: list[FloatArray],
        runs: Sequence[int],
    ) -> tuple[FloatArray, FloatArray]:
        """JᵀJ and Jᵀr over ``runs`` (full parameter space)."""
        size = self.size + len(self.sessions) * len(self.active)
        a = np.zeros((size, size))
        g = np.zeros(size)
        p, k = self.size, len(self.active)
        for j in runs:
            c = self.column(self.data.sessions[j])
            ju, jn, r = robot[j], own[j], res[j]
            a[:p, :p] += ju.T @ ju
            g[:p] += ju.T @ r
            if k:
                a[:p, c : c + k] += ju.T @ jn
                a[c : c + k, :p] += jn.T @ ju
                a[c : c + k, c : c + k] += jn.T @ jn
                g[c : c + k] += jn.T @ r
        return a, g

    def score(
        self, robot: list[FloatArray], own: list[FloatArray], res: list[FloatArray], j: int
    ) -> FloatArray:
        """Run ``j``'s score Jᵀr (full parameter space)."""
        size = self.size + len(self.sessions) * len(self.active)
        out = np.zeros(size)
        out[: self.size] = robot[j].T @ res[j]
        k = len(self.active)
        if k:
            c = self.column(self.data.sessions[j])
            out[c : c + k] = own[j].T @ res[j]
        return out


def _cost(res: list[FloatArray]) -> float:
    return float(sum(float(r @ r) for r in res))


def _levenberg_marquardt(
    problem: _Problem, x0: FloatArray, max_iterations: int = 30
) -> tuple[FloatArray, list[FloatArray], list[FloatArray], list[FloatArray]]:
    """Minimise the summed squares of ``problem``'s residuals from ``x0`` (Levenberg 1944;
    Marquardt 1963; the damping update of Nielsen 1999), steps projected onto the bounds.
    The normal equations are small (robot + session nuisances) and assembled from the runs'
    blocks. Returns x, the residuals and the two Jacobian blocks there."""
    x = np.clip(x0, problem.low, problem.high)
    res = problem.residuals(x)
    cost = _cost(res)
    robot, own = problem.jacobian(x, res)
    everything = range(len(problem.data))
    a, g = problem.normal(robot, own, res, everything)
    damping = 1e-3 * max(float(np.max(np.diag(a))) if len(a) else 1.0, 1e-12)
    grow = 2.0
    for _ in range(max_iterations):
        if len(x) == 0:
            break
        diag = np.maximum(np.diag(a), 1e-12)
        try:
            delta = -np.linalg.solve(a + damping * np.diag(diag), g)
        except np.linalg.LinAlgError:
            delta = -np.linalg.lstsq(a + damping * np.diag(diag), g, rcond=None)[0]
        trial = np.clip(x + delta, problem.low, problem.high)
        step = trial - x
        try:
            trial_res = problem.residuals(trial)
        except SpecError:  # beyond the range a robot may have: a failed step
            trial_res, trial_cost = res, math.inf
        else:
            trial_cost = _cost(trial_res)
        predicted = -(step @ g) - 0.5 * step @ a @ step
        gain = (cost - trial_cost) / predicted if predicted > 0 else -1.0
        if trial_cost < cost:
            x, res = trial, trial_res
            done = cost - trial_cost <= 1e-10 * cost or float(np.max(np.abs(step))) < 1e-6
            cost = trial_cost
            robot, own = problem.jacobian(x, res)
            a, g = problem.normal(robot, own, res, everything)
            damping *= max(1.0 / 3.0, 1.0 - float(2.0 * gain - 1.0) ** 3)
            grow = 2.0
            if done:
                break
        else:
            damping *= grow
            grow *= 2.0
            if float(np.max(np.abs(step))) < 1e-9:
                break
    return x, res, robot, own


@dataclass
class OpenLoopFit:
    """A model fitted by least squares on the open-loop error (module docstring).

    Attributes:
        spec: the fitted robot.
        effect: the effect whose parameters were fitted (a :class:`~odomgym.diagnose.fit.Joint`
            of several), or None (nuisances only, the robot fixed).
        values: its fitted parameters.
        stderr_runs, stderr_sessions: their run- and session-clustered standard errors (NaN
            with fewer than two clusters).
        nuisances: each session's fitted nuisances.
        options: which nuisances were fitted.
        run_error: each run's mean square combined error at the fit [m²].
        inflation: every parameter's variance inflation factor (:func:`variance_inflation`),
            by the other parameters and the sessions' nuisances together.
        robot_inflation: every robot parameter's variance inflation factor by the other robot
            parameters alone, the nuisances held known: whether the data can tell the robot's
            effects apart (an effect that is exactly a measurement nuisance is a confound the
            report states, :mod:`odomgym.diagnose.confounds`, not a robot effect the fit cannot
            identify).
    """

    spec: RobotSpec
    effect: Effect | None
    values: dict[str, float]
    stderr_runs: dict[str, float]
    stderr_sessions: dict[str, float]
    nuisances: dict[str, SessionNuisance]
    options: NuisanceOptions
    run_error: FloatArray
    problem: _Problem = field(repr=False)
    x: FloatArray = field(repr=False)
    blocks: tuple[list[FloatArray], list[FloatArray], list[FloatArray]] = field(repr=False)
    inflation: dict[str, float] = field(default_factory=dict)
    robot_inflation: dict[str, float] = field(default_factory=dict)

    @property
    def error(self) -> float:
        """Mean square combined error over the runs (runs weigh equally) [m²]."""
        return float(np.mean(self.run_error))


def fit_open_loop(
    data: OpenLoopData,
    spec: RobotSpec,
    effect: Effect | None = None,
    options: NuisanceOptions | None = None,
    start: Mapping[str, SessionNuisance] | None = None,
) -> OpenLoopFit:
    """Fit ``effect``'s parameters (none: the robot stays as ``spec``) and every session's
    nuisances (``options``) to the open-loop errors of ``data`` (module docstring).

    ``start``: sessions' nuisances to start from (a warm start; the others start from the
    coarse search)."""
    opts = options if options is not None else NuisanceOptions()
    active = list(opts.active)
    order = list(dict.fromkeys(data.sessions))
    members = {s: [j for j, lab in enumerate(data.sessions) if lab == s] for s in order}
    build: Callable[[FloatArray], RobotSpec]
    if effect is not None:
        u0, low_u, high_u, build = systematic_vector(spec, effect)
    else:
        u0, low_u, high_u = np.zeros(0), np.zeros(0), np.zeros(0)
        build = _Fixed(spec)

    scale = _NUISANCE_SCALE[active]
    bound = _NUISANCE_BOUND[active].copy()
    if 0 in active:
        bound[0] = opts.max_time_offset
    x0, low, high = [u0], [low_u], [high_u]
    for s in order:
        given = start.get(s) if start is not None else None
        begin = (
            given.values if given is not None else _start_nuisances(data, members[s], spec, opts)
        )
        x0.append(begin[active] / scale)
        low.append(-bound / scale)
        high.append(bound / scale)
    problem = _Problem(
        data,
        build,
        len(u0),
        active,
        order,
        members,
        opts.frames,
        np.concatenate(low),
        np.concatenate(high),
    )
    x, res, robot, own = _levenberg_marquardt(problem, np.concatenate(x0))
    fitted = build(x[: problem.size])
    se_runs, se_sessions, vif, robot_vif = _clustered_errors(problem, robot, own, res)
    values = effect.read(fitted) if effect is not None else {}
    stderr_runs: dict[str, float] = {}
    stderr_sessions: dict[str, float] = {}
    inflation: dict[str, float] = {}
    robot_inflation: dict[str, float] = {}
    if effect is not None:
        for k, p in enumerate(effect.parameters):
            stderr_runs[p.name] = float(se_runs[k] * p.scale)
            stderr_sessions[p.name] = float(se_sessions[k] * p.scale)
            inflation[p.name] = float(vif[k])
            robot_inflation[p.name] = float(robot_vif[k])
    nuisances = {}
    for s in order:
        se = np.full(4, math.nan)
        if active:
            c = problem.column(s)
            se[active] = se_runs[c : c + len(active)] * scale
        nuisances[s] = problem.nuisance(x, s).with_values(problem.nuisance(x, s).values, se)
    return OpenLoopFit(
        spec=fitted,
        effect=effect,
        values=values,
        stderr_runs=stderr_runs,
        stderr_sessions=stderr_sessions,
        nuisances=nuisances,
        options=opts,
        run_error=np.array([float(r @ r) for r in res]),
        problem=problem,
        x=x,
        blocks=(robot, own, res),
        inflation=inflation,
        robot_inflation=robot_inflation,
    )


def _clustered_errors(
    problem: _Problem, robot: list[FloatArray], own: list[FloatArray], res: list[FloatArray]
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Run- and session-clustered standard errors of every fitted parameter (fit units), every
    parameter's variance inflation factor (:func:`variance_inflation`), and the robot
    parameters' by each other alone (the leading block of the normal matrix)."""
    a, _ = problem.normal(robot, own, res, range(len(res)))
    if len(a) == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0)
    size = problem.size
    block = a[:size, :size]
    try:
        robot_vif = variance_inflation(block, np.asarray(np.linalg.inv(block), dtype=np.float64))
    except np.linalg.LinAlgError:
        robot_vif = np.full(size, math.inf)
    try:
        cov: FloatArray = np.asarray(np.linalg.inv(a), dtype=np.float64)
    except np.linalg.LinAlgError:
        nan = np.full(len(a), math.nan)
        return nan, nan, np.full(len(a), math.inf), robot_vif
    scores = np.array([problem.score(robot, own, res, j) for j in range(len(res))])
    by_run = clustered_covariance(cov, scores, list(range(len(res))))
    by_session = clustered_covariance(cov, scores, list(problem.data.sessions))
    return (
        np.sqrt(np.maximum(np.diag(by_run), 0.0)),
        np.sqrt(np.maximum(np.diag(by_session), 0.0)),
        variance_inflation(a, cov),
        robot_vif,
    )


def variance_inflation(normal: FloatArray, inverse: FloatArray) -> FloatArray:
    """Variance inflation factor of every parameter of a least-squares fit with normal matrix
    ``normal`` (JᵀJ, the sessions' nuisance columns included) and its ``inverse``:
    VIF_k = (JᵀJ)⁻¹_kk · (JᵀJ)_kk, the factor by which the other columns inflate parameter k's
    variance over a fit of k alone (Kutner, Nachtsheim, Neter & Li 2005, §10.5; invariant to
    the columns' scales; ≥ 1 in exact arithmetic). ∞ where a parameter's column has no length
    or the matrix is singular in it (numerically: a VIF below 1 or beyond 1e12).

    Why: a grammar term can be a combination of the fitted geometry and the sessions' nuisances
    — a constant crab angle is a frame yaw with the opposite tracked-heading offset, so with
    the sessions' frames fitted it only moves them; its least-squares value is then arbitrary
    and the geometry's standard errors explode (on June OptiOdom sessions: E_s and E_b 1.00 ±
    2.4). The open-loop gate refuses such a term (:data:`odomgym.diagnose.gate.MAX_INFLATION`)."""
    diagonal = np.diag(normal)
    vif = np.diag(inverse) * diagonal
    valid = (diagonal > 0.0) & np.isfinite(vif) & (vif >= 1.0 - 1e-9) & (vif < 1e12)
    out: FloatArray = np.where(valid, vif, math.inf)
    return out


def _session_time(run: Run, index: int) -> tuple[float, int]:
    return float(run.meta.get("session_time", 0.0)), index  # type: ignore[arg-type]


def open_loop_folds(runs: Sequence[Run], blocks: int = 5) -> list[list[int]]:
    """Cross-validation folds of run indices: one per session when the runs come from two or
    more; else ``blocks`` folds, each taking, of every experiment family
    (:func:`odomgym.diagnose.fit.strata`), a contiguous block of its runs in time order
    (``meta["session_time"]``, then the runs' order)."""
    labels = sessions_of(runs)
    distinct = list(dict.fromkeys(labels))
    if len(distinct) >= 2:
        return [[j for j, s in enumerate(labels) if s == name] for name in distinct]
    count = max(2, min(blocks, len(runs)))
    folds: list[list[int]] = [[] for _ in range(count)]
    for members in strata(runs).values():
        ordered = sorted(members, key=lambda j: _session_time(runs[j], j))
        n = len(ordered)
        for k in range(count):
            folds[k].extend(ordered[n * k // count : n * (k + 1) // count])
    return [sorted(f) for f in folds if f]


def _fold_step(fit: OpenLoopFit, train: Sequence[int]) -> tuple[FloatArray, RobotSpec]:
    """The fit-unit parameters without the runs outside ``train`` — one Gauss–Newton step from
    the full fit on the training runs (:func:`odomgym.diagnose.fit.gauss_newton_step`; columns no
    training run touches stay put) — and the robot there (the step halved until it is a valid
    robot: :func:`odomgym.diagnose.fit.build_within`)."""
    problem = fit.problem
    robot, own, res = fit.blocks
    a, g = problem.normal(robot, own, res, train)
    used = np.flatnonzero(np.diag(a) > 0)
    x = fit.x.copy()
    if len(used) == 0:
        return x, problem.build(x[: problem.size])
    delta = gauss_newton_step(a[np.ix_(used, used)], g[used])
    x[used] = np.clip(x[used] + delta, problem.low[used], problem.high[used])
    size = problem.size
    spec = build_within(problem.build, fit.x[:size], x[:size] - fit.x[:size])
    return x, spec


def cross_validate_open_loop(
    data: OpenLoopData, fit: OpenLoopFit, folds: Sequence[Sequence[int]]
) -> FloatArray:
    """Each run's held-out mean square combined error [m²] under ``fit`` refitted without its
    fold (module docstring). A session left out whole keeps the nuisances the full fit gave it:
    they are properties of its recording, not of the model (the fold step leaves columns no
    training run touches where they are)."""
    problem = fit.problem
    out = np.empty(len(data))
    for fold in folds:
        held = set(fold)
        x, spec = _fold_step(fit, [j for j in range(len(data)) if j not in held])
        for j in fold:
            nuisance = problem.nuisance(x, data.sessions[j])
            out[j] = float(np.sum(_residual(data, j, spec, nuisance) ** 2))
    return out


def run_errors(data: OpenLoopData, spec: RobotSpec) -> FloatArray:
    """Each run's mean square combined error [m²] under ``spec``, the runs taken as they are
    (their nuisances already removed)."""
    return np.array([float(np.sum(_residual(data, j, spec, None) ** 2)) for j in range(len(data))])


def rms_over_runs(values: FloatArray) -> float:
    """Root mean square of per-run RMS errors, runs weighing equally, over the runs that
    measured the quantity: a run of a position-only tracker has no heading error (NaN), and
    counts in the position RMS only. NaN when no run measured it."""
    finite = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(finite**2))) if len(finite) else math.nan


@dataclass
class ModelErrors:
    """One model's open-loop errors on a set of runs, in plain units.

    Attributes:
        label: which model (``"as given"``, ``"diagnosed"``, ``"baseline"``).
        runs: the runs' ids; sessions: their sessions.
        position, heading: each run's RMS position [m] and heading [rad] error over its
            measured samples after the alignment window (:data:`ALIGN_WINDOW`; NaN for a run
            that measured no heading after it: a position-only tracker).
        combined: each run's mean square combined error at the fit's samples [m²].
        nuisances: the nuisances used per session (fitted with this model).
        e_max_syst: per session with squares both ways, Borenstein & Feng's E_max,syst [m]
            of the predicted return positions (1994, Eq. 3.3), of the squares whose return
            was measured (:func:`odomgym.data.gaps.measured_end`: not those whose ground truth
            stops before their wheels do).
        paths: for the runs asked for, the predicted positions of the tracked point (T, 2) [m]
            in the ground truth's own frame (what a plot shows beside the measured path).
    """

    label: str
    runs: list[str]
    sessions: list[str]
    position: FloatArray
    heading: FloatArray
    combined: FloatArray
    nuisances: dict[str, SessionNuisance]
    e_max_syst: dict[str, float]
    paths: dict[str, FloatArray] = field(default_factory=dict)

    @property
    def position_rms(self) -> float:
        """RMS position error over the runs (runs weigh equally) [m]."""
        return rms_over_runs(self.position)

    @property
    def heading_rms(self) -> float:
        """RMS heading error over the runs with a measured heading (runs weigh equally) [rad]."""
        return rms_over_runs(self.heading)

    def summary(self) -> dict[str, Any]:
        """The report's entry, in mm and degrees."""
        return {
            "position_rms_mm": 1e3 * self.position_rms,
            "heading_rms_deg": math.degrees(self.heading_rms),
            "combined_rms_mm": 1e3 * float(np.sqrt(np.mean(self.combined))),
            "e_max_syst_mm": {s: 1e3 * v for s, v in self.e_max_syst.items()},
        }


def _rms_rows(squares: FloatArray) -> float:
    """The root of the mean of ``squares`` [m², rad²]; NaN for no rows."""
    return math.sqrt(float(np.mean(squares))) if len(squares) else math.nan


def evaluate_open_loop(
    label: str,
    runs: Sequence[Run],
    spec: RobotSpec,
    nuisances: Mapping[str, SessionNuisance],
    options: NuisanceOptions,
    interval: float,
    length: float,
    paths: Sequence[int] = (),
) -> ModelErrors:
    """``spec``'s open-loop errors on ``runs`` (:class:`ModelErrors`). Sessions without
    nuisances in ``nuisances`` get theirs fitted on their own runs with the robot fixed.
    ``paths``: indices of the runs whose predicted paths to keep."""
    data = OpenLoopData(runs, interval, length)
    known = dict(nuisances)
    for session in dict.fromkeys(data.sessions):
        if session in known or not options.active:
            continue
        own = data.subset([j for j, s in enumerate(data.sessions) if s == session])
        fitted = fit_open_loop(own, spec, None, options).nuisances[session]
        if options.time_offset and not offset_is_significant(fitted):
            # The fit sessions' rule: no offset where the data show none (its s.e. reported).
            frames_only = dataclasses.replace(options, time_offset=False)
            refit = (
                fit_open_loop(own, spec, None, frames_only).nuisances[session]
                if frames_only.active
                else SessionNuisance(session, fitted.runs)
            )
            fitted = dataclasses.replace(refit, time_offset_se=fitted.time_offset_se)
        known[session] = fitted
    position = np.empty(len(data))
    heading = np.empty(len(data))
    combined = np.empty(len(data))
    ends: dict[str, dict[str, list[FloatArray]]] = {}
    for j, run in enumerate(data.runs):
        nuisance = known.get(data.sessions[j])
        error = _errors(data, j, spec, nuisance)
        # After the start (row 0, where the replay begins), each component where measured.
        later = np.arange(len(error)) > 0
        placed = later & np.isfinite(error[:, :2]).all(axis=1)
        headed = later & np.isfinite(error[:, 2])
        position[j] = _rms_rows(np.sum(error[placed, :2] ** 2, axis=1))
        heading[j] = _rms_rows(error[headed, 2] ** 2)
        combined[j] = float(np.sum(_residual(data, j, spec, nuisance, error) ** 2))
        last = measured_end(run)
        if run.kind == "square" and run.direction in ("cw", "ccw") and last is not None:
            theta0 = float(correct_run(run, nuisance).true_pose[0, 2])
            in_start = rotate_into(error[last : last + 1, 0], error[last : last + 1, 1], theta0)
            ends.setdefault(data.sessions[j], {}).setdefault(run.direction, []).append(in_start[0])
    kept_paths = {
        str(data.runs[j].meta.get("run", j + 1)): predicted_path(
            data.runs[j], spec, known.get(data.sessions[j])
        )
        for j in paths
    }
    e_max = {
        s: e_max_syst(np.array(d["cw"]), np.array(d["ccw"]))
        for s, d in ends.items()
        if d.get("cw") and d.get("ccw")
    }
    return ModelErrors(
        label=label,
        runs=[str(r.meta.get("run", j + 1)) for j, r in enumerate(data.runs)],
        sessions=data.sessions,
        position=position,
        heading=heading,
        combined=combined,
        nuisances=known,
        e_max_syst=e_max,
        paths=kept_paths,
    )

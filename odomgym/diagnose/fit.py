"""Fitting candidate effects to logged runs, and scoring them on runs they did not see.

**Fit.** A model is a :class:`~odomgym.robot.RobotSpec` (its effects) plus the ground-truth
sensor's noise. A systematic effect's parameters are fitted by generalised least squares — the
whitened innovations of :func:`odomgym.diagnose.likelihood.run_likelihood` (heading jumps as their
variance) — with :func:`scipy.optimize.least_squares`; noise parameters (the sensor's σ and a
noise effect's parameters) by maximum likelihood. The two alternate twice, because an effect that
explains the mean lowers the noise the data need.

**Score.** Whole runs are held out in K folds (stratified by experiment label). A systematic
candidate's fold fits are one Gauss–Newton step from the full fit on the whitened system (exact
for the linear part; effects are small), so a run's held-out log-likelihood is its score at the
full fit corrected by the quadratic change; a noise candidate is refitted per fold. The base
model's noise is fitted on all runs. The log-likelihood of a held-out run is a proper scoring
rule, so the per-run differences to the base model compare candidates honestly.

**Test.** The best candidate's improvement is tested against the family of all candidates with
a max-T sign-flip test over runs (Westfall & Young 1993): the sign of every run's improvements is
flipped together, which keeps the dependence between candidates, and the largest studentised mean
over candidates forms the null distribution. The tests themselves are in
:mod:`odomgym.diagnose.stats` (numbers in, p-values out); this module fits and scores. It
imports neither the workflow nor anything above it: workflow → fit → stats.

**Run.** :class:`FitJob` is one candidate's fit and cross-validation, a deterministic function of
its fields; :func:`run_fit_jobs` runs several, side by side in forked worker processes or one
after the other.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import multiprocessing as mp
import os
import pickle
import re
from collections.abc import Callable, Iterable, Mapping, Sequence, Sized
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares, lsq_linear, minimize

from odomgym.diagnose.likelihood import (
    FilterInputs,
    SensorNoise,
    StackedInputs,
    filter_inputs,
    filter_runs,
    measurement_mask,
    process_noise,
    replay_gains,
    run_residual,
    run_scores,
    score_stacked,
    stacked_process_noise,
)
from odomgym.diagnose.replay import (
    Replay,
    RunInputs,
    RunStack,
    StackedReplay,
    replay_run,
    replay_stacked,
    stackable,
)
from odomgym.diagnose.stats import clustered_covariance
from odomgym.distributed import ray_started, run_ray_tasks
from odomgym.effects import EFFECTS, Effect
from odomgym.effects.registry import Spec, SpecView
from odomgym.errors import SpecError
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec
from odomgym.workers import Handler, WorkerDeath, run_tasks

__all__ = [
    "CandidateFit",
    "Dataset",
    "FitJob",
    "Joint",
    "Model",
    "bounded_gauss_newton_step",
    "build_within",
    "close_thread_pool",
    "evaluate",
    "fit_candidate",
    "fit_noise",
    "fit_noise_model",
    "folds_for",
    "forks",
    "gauss_newton_step",
    "noise_curvature",
    "noise_stderr",
    "run_fit_jobs",
    "run_forked",
    "strata",
    "systematic_vector",
    "whitened_stack",
]

FloatArray = NDArray[np.float64]
_MIN_SIGMA = 1e-5  # [m] / [rad]: floor of the sensor σ a fit may reach


@dataclass(frozen=True)
class Model:
    """A model as the workflow fits it: the robot and the sensor that measured it.

    The two travel together (every fit, test and replay of the workflow needs both), so they
    are one value rather than two parallel arguments that could be mixed up between rounds.

    Attributes:
        spec: the robot model, its effects included (geometry in m, angles in rad).
        sensor: the ground-truth sensor's white noise, position σ [m] and heading σ [rad].
    """

    spec: RobotSpec
    sensor: SensorNoise


@dataclass
class Dataset:
    """Runs with the pose components that enter the likelihood.

    Two caches, not data (pickles — worker jobs, journal keys — leave them out and are the same
    bytes as without them): ``inputs`` keeps each run's
    :class:`~odomgym.diagnose.replay.RunInputs` (by encoder resolution) once a replay has made
    them, shared with every subset (a fit replays each run hundreds of times); ``noise_fits``
    keeps the results of :func:`fit_noise` on these runs by their exact inputs (a round asks
    for the same noise fit of the same model up to three times)."""

    runs: list[Run]
    masks: list[NDArray[np.bool_]]
    inputs: list[dict[float, RunInputs]] = field(default_factory=list)
    noise_fits: dict[object, tuple[RobotSpec, SensorNoise, float]] = field(default_factory=dict)
    stacks: dict[tuple[float, int, int], RunStack] = field(default_factory=dict)
    mask_stacks: dict[tuple[int, int], NDArray[np.bool_]] = field(default_factory=dict)
    share_cuts: dict[int, list[range]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.inputs:
            self.inputs = [{} for _ in self.runs]

    @classmethod
    def of(cls, runs: Sequence[Run], min_interval: float) -> Dataset:
        return cls(list(runs), [measurement_mask(r, min_interval) for r in runs])

    def wheel_travel(self, spec: RobotSpec) -> list[FloatArray]:
        """Each run's wheel travel per logged interval (n − 1, 2) [m] by ``spec``'s encoders:
        what :meth:`~odomgym.effects.Effect.shape_identified` judges a fitted shape against."""
        return [np.diff(run.counts, axis=0) * spec.metres_per_tick for run in self.runs]

    def subset(self, index: Sequence[int]) -> Dataset:
        return Dataset(
            [self.runs[i] for i in index],
            [self.masks[i] for i in index],
            [self.inputs[i] for i in index],
        )

    def replay(self, j: int, spec: RobotSpec) -> Replay:
        """Run ``j`` replayed through ``spec`` (:func:`~odomgym.diagnose.replay.replay_run`)
        with its kept inputs."""
        return replay_run(self.runs[j], spec, self._inputs(j, spec.ticks_per_rev))

    def replays(self, spec: RobotSpec, index: range | None = None) -> list[Replay]:
        """The runs of ``index`` (default: all) replayed through ``spec``: in one pass over
        them stacked (:func:`~odomgym.diagnose.replay.replay_stacked`; the stack kept per
        encoder resolution and range) where every effect of ``spec`` replays stacked, else run
        by run (:meth:`replay`); the same numbers either way."""
        if index is None:
            index = range(len(self.runs))
        stacked = self.stacked_replay(spec, index)
        if stacked is None:
            return [self.replay(j, spec) for j in index]
        return stacked.split()

    def stacked_replay(self, spec: RobotSpec, index: range) -> StackedReplay | None:
        """The runs of ``index`` replayed through ``spec`` in one pass
        (:func:`~odomgym.diagnose.replay.replay_stacked`), or None where that does not apply
        (fewer than two runs, or an effect of ``spec`` that replays one run at a time)."""
        if len(index) < 2 or index.step != 1 or not stackable(spec):
            return None
        return replay_stacked(self.stack(spec.ticks_per_rev, index), spec)

    def stack(self, ticks: float, index: range) -> RunStack:
        """The :class:`~odomgym.diagnose.replay.RunStack` of the runs of ``index`` (a
        contiguous range) at ``ticks`` counts/rev, kept."""
        key = (ticks, index.start, index.stop)
        stack = self.stacks.get(key)
        if stack is None:
            inputs = [self._inputs(j, ticks) for j in index]
            stack = self.stacks[key] = RunStack.of([self.runs[j] for j in index], inputs)
        return stack

    def shares(self, count: int) -> list[range]:
        """The runs cut into ``count`` threads' shares of nearly equal samples
        (:func:`balanced_shares` of the masks), kept: every evaluation asks again."""
        held = self.share_cuts.get(count)
        if held is None:
            held = self.share_cuts[count] = balanced_shares(self.masks, count)
        return held

    def stacked_mask(self, index: range) -> NDArray[np.bool_]:
        """The masks of the runs of ``index`` stacked (ΣT, 3), kept."""
        key = (index.start, index.stop)
        held = self.mask_stacks.get(key)
        if held is None:
            held = np.ascontiguousarray(np.concatenate([self.masks[j] for j in index]))
            held.flags.writeable = False
            self.mask_stacks[key] = held
        return held

    def _inputs(self, j: int, ticks: float) -> RunInputs:
        held = self.inputs[j]
        if ticks not in held:
            held[ticks] = RunInputs.of(self.runs[j], ticks)
        return held[ticks]

    def __len__(self) -> int:
        return len(self.runs)

    def __getstate__(self) -> dict[str, object]:
        return {"runs": self.runs, "masks": self.masks}

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self.inputs = [{} for _ in self.runs]
        self.noise_fits = {}
        self.stacks = {}
        self.mask_stacks = {}
        self.share_cuts = {}


_Share = tuple[list[Replay | StackedReplay], list[tuple[float, FloatArray | None]]]
"""What :func:`evaluate` makes of a thread's share of the runs: its replays (one stacked
replay, or each run's) and each run's log-likelihood and whitened innovations."""


@dataclass
class Evaluation:
    """Per-run log-likelihoods (mixture) and whitened innovations (Gaussian jumps), and the
    replays they came from: ``sources`` holds each run's :class:`Replay`, or the
    :class:`StackedReplay` of a share of consecutive runs replayed together."""

    loglik: FloatArray
    whitened: list[FloatArray]
    sources: Sequence[Replay | StackedReplay]

    @functools.cached_property
    def replays(self) -> list[Replay]:
        """Each run's replay, in run order; a stacked share's are views of its arrays, made
        here. Why not made by :func:`evaluate`: no fit reads them, and splitting every stacked
        evaluation into a hundred views cost about 1 % of a diagnosis (the 14 June OptiOdom
        sessions). Made once; the views share the stacked replay's memory."""
        out: list[Replay] = []
        for source in self.sources:
            out.extend(source.split() if isinstance(source, StackedReplay) else [source])
        return out


@dataclass(frozen=True)
class FixedReplays:
    """Every run's replay through one spec and what the filter takes from it, kept for a fit
    that varies only noise parameters (see :func:`_fixed_replays`).

    Attributes:
        replays: each run's replay.
        inputs: each run's :func:`~odomgym.diagnose.likelihood.filter_inputs`.
        travel: every run's wheel travel stacked (ΣN, 2) [m], for
            :func:`~odomgym.diagnose.likelihood.stacked_process_noise`.
        rows: run j's rows of ``travel``.
        stacked: the replays, their filter inputs and the masks stacked, for
            :func:`~odomgym.diagnose.likelihood.filter_runs`.
    """

    replays: list[Replay]
    inputs: list[FilterInputs]
    travel: FloatArray
    rows: list[slice]
    stacked: StackedInputs

    @classmethod
    def of(
        cls,
        replays: list[Replay],
        inputs: list[FilterInputs],
        masks: list[NDArray[np.bool_]],
    ) -> FixedReplays:
        ends = np.cumsum([len(r.travel) for r in replays]).tolist()
        starts = [0, *ends[:-1]]
        rows = [slice(a, b) for a, b in zip(starts, ends, strict=True)]
        travel = np.concatenate([r.travel for r in replays]) if replays else np.zeros((0, 2))
        return cls(replays, inputs, travel, rows, StackedInputs.of(replays, inputs, masks))


def evaluate(
    data: Dataset,
    spec: RobotSpec,
    sensor: SensorNoise,
    *,
    whitened: bool = True,
    fixed: FixedReplays | None = None,
    gains: Sequence[FloatArray] | None = None,
    loglik: bool = True,
    kept: KeptReplays | None = None,
) -> Evaluation:
    """Replay every run through ``spec`` and filter it; ``fixed``: each run's replay through
    ``spec`` and its filter inputs, if the caller keeps them (a noise fit, see
    :func:`_fixed_replays`: then the process noise of all runs is computed in one call).
    ``gains``: each run's wheel-noise gains (:func:`~odomgym.diagnose.likelihood.replay_gains`)
    held at a replay of another spec instead of this one's (:func:`_least_squares`; not with
    ``fixed``, which keeps its own). ``loglik`` False (with ``whitened``): the whitened
    innovations are all the caller reads (a least-squares residual), and a run where a wheel
    jump is expected gets NaN for its log-likelihood instead of a filter of its jump mixture
    (:func:`~odomgym.diagnose.likelihood.run_scores`); the whitened innovations are the same
    bytes either way. ``kept``: a noise fit's :class:`KeptReplays`, which replays a share of
    the runs again only when a parameter that moves the replay has moved.

    The runs are independent, and the filter (compiled, releasing the GIL) takes most of the
    time, so they are shared among :func:`_threads` threads; each run's numbers do not depend on
    which thread computed them, and they are gathered in run order (bit-identical results).
    With ``fixed`` and without ``whitened`` each thread's share of the runs is one compiled
    call (:func:`~odomgym.diagnose.likelihood.filter_runs`, the same bytes)."""
    if not whitened and not loglik:
        raise ValueError("evaluate: loglik=False needs whitened=True (nothing else to compute)")
    if fixed is not None and not whitened:
        return _evaluate_fixed(data, spec, sensor, fixed)
    noise = stacked_process_noise(spec, fixed.travel, fixed.rows) if fixed is not None else []

    def one(j: int, rep: Replay) -> tuple[Replay, float, FloatArray | None]:
        run, mask = data.runs[j], data.masks[j]
        if fixed is None:
            held = None if gains is None else FilterInputs(run_residual(run, rep, mask), gains[j])
            value, white = run_scores(
                run, rep, spec, sensor, mask, whitened=whitened, kept=held, loglik=loglik
            )
        else:
            inputs, own = fixed.inputs[j], noise[j]
            value, white = run_scores(
                run,
                rep,
                spec,
                sensor,
                mask,
                whitened=whitened,
                kept=inputs,
                noise=own,
                loglik=loglik,
            )
        return rep, value, white

    def listed(scored: list[tuple[Replay, float, FloatArray | None]]) -> _Share:
        return [r[0] for r in scored], [(r[1], r[2]) for r in scored]

    def chunk(index: range) -> _Share:
        # A thread replays its share of the runs stacked and scores them in one compiled call
        # (score_stacked): numpy's calls on the stacked arrays and the compiled functions
        # release the GIL, so the threads' shares overlap. A stacked replay stays whole: its
        # runs' views are made only if a caller asks for them (Evaluation.replays).
        if fixed is not None:
            reps = fixed.replays[index.start : index.stop]
            return listed([one(j, rep) for j, rep in zip(index, reps, strict=True)])
        stacked = (
            data.stacked_replay(spec, index) if kept is None else kept.stacked(data, spec, index)
        )
        if stacked is None:
            return listed([one(j, data.replay(j, spec)) for j in index])
        stack = data.stack(spec.ticks_per_rev, index)
        logs, white = score_stacked(
            stacked,
            stack.measured,
            data.stacked_mask(index),
            spec,
            sensor,
            whitened=whitened,
            gains=None if gains is None else _stacked_gains(gains, index),
            loglik=loglik,
        )
        rows = (3 * stacked.samples()).tolist()
        return [stacked], [
            (float(logs[r]), white[rows[r] : rows[r + 1]] if whitened else None)
            for r in range(len(index))
        ]

    pool = _pool()
    n = len(data)
    if pool is None or n < 2:
        parts = [chunk(range(n))]
    else:  # one contiguous share per thread: few hand-overs of the GIL
        parts = list(pool.map(chunk, data.shares(_pool_size())))
    results = [r for part in parts for r in part[1]]
    logs = np.array([r[0] for r in results], dtype=float)
    white = [r[1] for r in results if r[1] is not None]
    return Evaluation(logs, white, [source for part in parts for source in part[0]])


def _evaluate_fixed(
    data: Dataset, spec: RobotSpec, sensor: SensorNoise, fixed: FixedReplays
) -> Evaluation:
    """:func:`evaluate` of kept replays without whitened innovations: the process noise of all
    runs in one call, then one compiled filter call per thread's contiguous share."""
    noise = process_noise(spec, fixed.travel)
    n = len(data)
    logs = np.empty(n)
    pool = _pool()
    if pool is None or n < 2:
        filter_runs(fixed.stacked, noise, sensor, range(n), logs)
    else:
        shares = data.shares(_pool_size())
        list(pool.map(lambda share: filter_runs(fixed.stacked, noise, sensor, share, logs), shares))
    return Evaluation(logs, [], fixed.replays)


def balanced_shares(rows: Sequence[Sized], count: int) -> list[range]:
    """``len(rows)`` runs cut into ``min(count, len(rows))`` contiguous shares (at least one
    share, empty for no rows) of nearly equal work, a run's work its sample count
    ``len(rows[j])``: each cut at the run boundary closest to its equal fraction of the samples
    that leaves every share at least one run, so no share holds more than ``total/count`` plus
    the longest run.

    Why: the threads of :func:`evaluate` wait for the slowest share, and a run's replay and
    filter cost in proportion to its samples. Equal counts of runs were unequal work wherever
    run lengths differ (the 102 June OptiOdom runs, 223–3 015 samples: 74 278 against 59 113
    samples for two threads; cut here, 66 851 against 66 540). Which thread computes a run
    does not change its numbers (each run is replayed and filtered on its own rows and the
    results are gathered in run order; a share of one run is replayed and scored run by run,
    the same bytes as stacked, ``tests/test_diagnose_stacked.py``), so the results are the
    same bytes for any cut."""
    n = len(rows)
    count = max(1, min(count, n))
    total = 0
    ends = []  # ends[i]: samples in runs 0 … i
    for one in rows:
        total += len(one)
        ends.append(total)
    cuts = [0]
    for k in range(1, count):
        target = total * k / count
        # The boundary after run i − 1 closest to the target, leaving a run for every share.
        low, high = cuts[-1] + 1, n - (count - k)
        best = min(range(low, high + 1), key=lambda i: (abs(ends[i - 1] - target), i))
        cuts.append(best)
    cuts.append(n)
    return [range(a, b) for a, b in itertools.pairwise(cuts)]


def _threads() -> int:
    """Threads per process for :func:`evaluate`: ``ODOMGYM_THREADS`` if set, else the CPU count.

    Why threads inside the worker processes of the candidate pool: the candidates of a round
    take very different times (a wheel-jump fit ~10× a systematic one), so the last of them
    runs alone on one core while the other idles; threads let it use both. When every worker
    is busy the threads merely share the cores."""
    raw = os.environ.get("ODOMGYM_THREADS", "")
    if not raw:
        try:
            return max(1, len(os.sched_getaffinity(0)))  # the CPUs this process may use
        except AttributeError:  # not on every platform
            return max(1, os.cpu_count() or 1)
    try:
        count = int(raw)
    except ValueError:
        count = 0
    if count < 1:
        raise SpecError(f"ODOMGYM_THREADS must be a whole number >= 1, got {raw!r}")
    return count


_POOL: tuple[int, ThreadPoolExecutor | None, int] | None = None


def close_thread_pool() -> None:
    """Stop this process's evaluation threads (before a fork: a child must not inherit threads
    that may hold a lock); the next :func:`evaluate` starts new ones."""
    global _POOL
    if _POOL is not None and _POOL[1] is not None:
        _POOL[1].shutdown(wait=True)
    _POOL = None


def _pool() -> ThreadPoolExecutor | None:
    """This process's thread pool for :func:`evaluate` (``None``: one thread); created on first
    use, so a forked worker makes its own rather than inheriting its parent's threads."""
    global _POOL
    pid = os.getpid()
    if _POOL is None or _POOL[0] != pid:
        count = _threads()
        pool = ThreadPoolExecutor(count, thread_name_prefix="odomgym-eval") if count > 1 else None
        _POOL = (pid, pool, count)
    return _POOL[1]


def _pool_size() -> int:
    """Threads of this process's evaluation pool (1 without one)."""
    return _POOL[2] if _POOL is not None and _POOL[1] is not None else 1


def _noise_vector(
    spec: RobotSpec, sensor: SensorNoise, effects: Sequence[Effect], *, at_current: bool = False
) -> tuple[
    FloatArray, FloatArray, FloatArray, Callable[[FloatArray], tuple[RobotSpec, SensorNoise]]
]:
    """Log-parametrisation of the sensor σ and the noise effects' parameters (floors at a tenth
    of their scale, so 'absent' is approached continuously; ceilings at the parameters' own
    upper limits); returns start, lower and upper bounds and the map back to (spec, sensor).

    The start is each parameter's current value, raised to its scale when below it (a fresh
    fit: a value near the floor is a flat place to start from) unless ``at_current``: then the
    current value itself (within the bounds), i.e. the point of an existing fit — for a warm
    restart and for derivatives taken at the fit."""
    start = [math.log(max(sensor.position, _MIN_SIGMA)), math.log(max(sensor.heading, _MIN_SIGMA))]
    low = [math.log(_MIN_SIGMA)] * 2
    high = [0.0, 0.0]  # σ < 1 m, 1 rad
    for effect in effects:
        current = effect.read(spec)
        for p in effect.parameters:
            value = current[p.name]
            floor = 0.1 * p.scale if at_current else p.scale
            start.append(math.log(min(p.high, max(value, floor))))
            low.append(math.log(0.1 * p.scale))
            high.append(math.log(p.high))

    def build(x: FloatArray) -> tuple[RobotSpec, SensorNoise]:
        noise = SensorNoise(
            max(math.exp(float(x[0])), _MIN_SIGMA), max(math.exp(float(x[1])), _MIN_SIGMA)
        )
        out = spec
        k = 2
        for effect in effects:
            values = {}
            for p in effect.parameters:
                values[p.name] = min(p.high, max(p.low, math.exp(float(x[k]))))
                k += 1
            out = effect.write(out, values)
        return out, noise

    return np.array(start), np.array(low), np.array(high), build


def fit_noise_model(
    data: Dataset, model: Model, *effects: Effect | None, warm: bool = False
) -> Model:
    """:func:`fit_noise` on a :class:`Model`, returning the refitted model (the workflow never
    needs the log-likelihood it also returns)."""
    spec, sensor, _ = fit_noise(data, model.spec, model.sensor, *effects, warm=warm)
    return Model(spec, sensor)


def _moves_mean(effects: Sequence[Effect]) -> bool:
    """True if some effect's parameters change the replay (then replays cannot be cached)."""
    return any(type(e).replay is not Effect.replay for e in effects)


def fit_noise(
    data: Dataset,
    spec: RobotSpec,
    sensor: SensorNoise,
    *effects: Effect | None,
    warm: bool = False,
) -> tuple[RobotSpec, SensorNoise, float]:
    """Maximum-likelihood sensor σ (and the noise parameters of ``effects``); returns the spec,
    the sensor noise and the total log-likelihood.

    ``warm``: ``spec`` and ``sensor`` already hold a fit of the same effects to nearly the same
    model (the joint refits of :func:`fit_candidate`): start exactly there, without the
    multi-start of a fresh fit.

    A deterministic function of its inputs, so a repeated call on the same ``data`` returns the
    first one's result (``Dataset.noise_fits``; the spec and sensor noise keyed by their pickled
    bytes: the exact bits of every value, −0.0 apart from 0.0)."""
    chosen = [e for e in effects if e is not None]
    key = (
        pickle.dumps((spec, sensor), protocol=5),
        tuple((type(e), e.name, e.parameters) for e in chosen),
        warm,
    )
    if key not in data.noise_fits:
        data.noise_fits[key] = _fit_noise(data, spec, sensor, chosen, warm)
    return data.noise_fits[key]


def _fixed_replays(
    data: Dataset, spec: RobotSpec, effects: Sequence[Effect]
) -> FixedReplays | None:
    """Every run's replay through ``spec`` and its filter inputs (residual, wheel gains), kept
    for a fit that varies only ``effects``' noise parameters and the sensor σ; None if one of
    the effects moves the replay.

    Why: the noise parameters change the filter's covariances, never its mean, so a noise
    fit's hundreds of evaluations replay the same runs, subtract the same poses and linearise
    about the same path; kept, the filter's own update is all that is left of each (the same
    functions on the same inputs: the same bytes)."""
    if _moves_mean(effects):
        return None
    reps = data.replays(spec)
    triples = zip(data.runs, reps, data.masks, strict=True)
    inputs = [filter_inputs(run, rep, mask) for run, rep, mask in triples]
    return FixedReplays.of(reps, inputs, data.masks)


class KeptReplays:
    """The latest stacked replay of each share of the runs in a noise fit whose effects move
    the replay (floor bumps: their mean loss of travel), kept while the parameters that move
    it stay put — those of the ``moving`` effects; the sensor σ and a noise effect without a
    replay of its own (wheel noise) never enter it.

    Why: such a fit cannot keep one replay for all its evaluations (:func:`_fixed_replays`),
    but four of the seven evaluations of each finite-difference gradient of a bump field's
    fit (σ_xy, σ_θ, k_L, k_R beside its rate and jump) replay the spec of its base point;
    kept, they only filter again. A replay is a deterministic function of the spec, so the
    same bytes. Only for noise effects (:func:`_fit_noise`): their ``build`` changes nothing
    else of the spec."""

    KEPT = 3
    """Replays kept per share: the gradient's base point and its two steps that move the
    replay (the bumps' rate and jump, which come before k_L and k_R in the noise vector)."""

    def __init__(self, moving: Sequence[Effect]) -> None:
        self.moving = list(moving)
        self.held: dict[tuple[int, int], dict[object, StackedReplay | None]] = {}

    def stacked(self, data: Dataset, spec: RobotSpec, index: range) -> StackedReplay | None:
        """``data.stacked_replay(spec, index)``, or a kept one if the moving effects'
        values are those it was replayed with (the latest :attr:`KEPT` per share)."""
        key = tuple(tuple(e.read(spec).items()) for e in self.moving)
        # One share per thread: no two threads write the same share's entry.
        held = self.held.setdefault((index.start, index.stop), {})
        if key in held:
            held[key] = held.pop(key)  # the most recent last
            return held[key]
        stacked = held[key] = data.stacked_replay(spec, index)
        if len(held) > self.KEPT:
            del held[next(iter(held))]  # the least recently used
        return stacked


def _fit_noise(
    data: Dataset, spec: RobotSpec, sensor: SensorNoise, chosen: list[Effect], warm: bool
) -> tuple[RobotSpec, SensorNoise, float]:
    """:func:`fit_noise` itself (without its memo)."""
    fixed = _fixed_replays(data, spec, chosen)
    x0, low, high, build = _noise_vector(spec, sensor, chosen, at_current=warm)
    kept = None
    if fixed is None and all(e.noise for e in chosen):
        kept = KeptReplays([e for e in chosen if _moves_mean([e])])

    def objective(x: FloatArray) -> float:
        s, n = build(x)
        ev = evaluate(data, s, n, whitened=False, fixed=fixed, kept=kept)
        return -float(ev.loglik.sum())

    start = np.clip(x0, low, high)
    if not warm:
        start = _best_start(objective, start, low, high, spec, chosen)
    result = minimize(
        objective,
        start,
        method="L-BFGS-B",
        bounds=list(zip(low, high, strict=True)),
        options={"eps": 1e-4, "ftol": 1e-7, "maxfun": 60 * len(x0)},
    )
    best_spec, best_sensor = build(result.x)
    return best_spec, best_sensor, -float(result.fun)


_START_FACTORS = (1.0, 10.0, 100.0)


def _best_start(
    objective: Callable[[FloatArray], float],
    x0: FloatArray,
    low: FloatArray,
    high: FloatArray,
    spec: RobotSpec,
    effects: Sequence[Effect],
) -> FloatArray:
    """The best of a few starting points: a noise effect absent from ``spec`` starts at its
    parameters' scale, where the likelihood of sparse jumps is nearly flat (a 2 mrad jump is
    lost in the sensor noise), so its parameters are also tried at 10 and 100 × their scale.

    Each of those is also tried with the noise effects ``spec`` already carries at the floor
    of their range: fitted beside wheel noise that already carries a bump field's variance, a
    fresh bump model gains nothing at any start where that noise stays, and L-BFGS-B stays at
    the start — the local optimum in which wheel noise explains the jumps (seen on the
    independent generator's bumps of 3 mm at 0.5 per metre, named wheel noise)."""
    fresh: list[range] = []
    present: list[int] = []
    k = 2
    for effect in effects:
        size = len(effect.parameters)
        if effect.is_absent(effect.read(spec)):
            fresh.append(range(k, k + size))
        else:
            present.extend(range(k, k + size))
        k += size
    if not fresh:
        return x0
    bases = [x0]
    if present:
        cleared = x0.copy()
        cleared[present] = low[present]
        bases.append(cleared)
    best, best_value = x0, objective(x0)
    for base in bases:
        for factors in itertools.product(_START_FACTORS, repeat=len(fresh)):
            if base is x0 and all(f == 1.0 for f in factors):
                continue
            x = base.copy()
            for idx, f in zip(fresh, factors, strict=True):
                for i in idx:
                    x[i] = min(high[i], max(low[i], x0[i] + math.log(f)))
            value = objective(x)
            if value < best_value:
                best, best_value = x, value
    return best


def noise_curvature(
    data: Dataset, spec: RobotSpec, sensor: SensorNoise, effects: Sequence[Effect]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per-run log-likelihood (J,), gradient (J, P) and Hessian (J, P, P) in the
    log-parameters of :func:`fit_noise` (central differences), for one-step fold refits."""
    fixed = _fixed_replays(data, spec, effects)
    x0, _, _, build = _noise_vector(spec, sensor, effects, at_current=True)
    step = 0.05

    def per_run(x: FloatArray) -> FloatArray:
        s, n = build(x)
        return evaluate(data, s, n, whitened=False, fixed=fixed).loglik

    p = len(x0)
    f0 = per_run(x0)
    grad = np.zeros((len(data), p))
    hess = np.zeros((len(data), p, p))
    plus: list[FloatArray] = []
    minus: list[FloatArray] = []
    for a in range(p):
        e = np.zeros(p)
        e[a] = step
        plus.append(per_run(x0 + e))
        minus.append(per_run(x0 - e))
        grad[:, a] = (plus[a] - minus[a]) / (2 * step)
        hess[:, a, a] = (plus[a] - 2 * f0 + minus[a]) / step**2
    for a in range(p):
        for b in range(a + 1, p):
            e = np.zeros(p)
            e[a] = step
            e[b] = step
            both = per_run(x0 + e)
            value = (both - plus[a] - plus[b] + f0) / step**2
            hess[:, a, b] = value
            hess[:, b, a] = value
    return f0, grad, hess


def noise_stderr(
    data: Dataset, spec: RobotSpec, sensor: SensorNoise, effects: Sequence[Effect]
) -> dict[str, dict[str, dict[str, float]]]:
    """Standard errors of the noise ``effects``' parameters at a maximum-likelihood fit
    (``spec``, ``sensor``): model-based (the inverse observed information) and run-clustered
    (the sandwich over runs; Liang & Zeger 1986), from :func:`noise_curvature` in the fit's
    log-parameters, mapped back by the delta method (se(p) = p · se(log p)). Keyed
    ``{effect: {parameter: {"stderr", "stderr_runs"}}}``; NaN where the information is
    singular (a parameter at the floor of its range)."""
    if not effects:
        return {}
    _, grad, hess = noise_curvature(data, spec, sensor, effects)
    information = -np.sum(hess, axis=0)
    try:
        cov = np.linalg.inv(information)
    except np.linalg.LinAlgError:
        cov = np.full_like(information, math.nan)
    runs = clustered_covariance(cov, grad, list(range(len(grad))))
    out: dict[str, dict[str, dict[str, float]]] = {}
    k = 2  # after the sensor's two log-sigmas
    for effect in effects:
        values = effect.read(spec)
        for p in effect.parameters:
            model = math.sqrt(cov[k, k]) if cov[k, k] > 0 else math.nan
            robust = math.sqrt(runs[k, k]) if runs[k, k] > 0 else math.nan
            out.setdefault(effect.name, {})[p.name] = {
                "stderr": values[p.name] * model,
                "stderr_runs": values[p.name] * robust,
            }
            k += 1
    return out


def systematic_vector(
    spec: RobotSpec, effect: Effect
) -> tuple[FloatArray, FloatArray, FloatArray, Callable[[FloatArray], RobotSpec]]:
    """Parameters in units of their scale, relative to the current values, with bounds."""
    build = SpecBuilder.of(spec, effect)
    return (
        np.zeros(len(build.origin)),
        (build.low - build.origin) / build.scale,
        (build.high - build.origin) / build.scale,
        build,
    )


@dataclass(frozen=True, eq=False)
class SpecBuilder:
    """The spec at fit units u of :func:`systematic_vector`: ``effect`` written into ``spec``
    at origin + u·scale, clipped to [low, high].

    A class, not a closure, so that a fit holding it (an
    :class:`~odomgym.diagnose.openloop.OpenLoopFit`) can come back from a worker process
    (:meth:`odomgym.diagnose.gate._Elimination.each`)."""

    spec: RobotSpec
    effect: Effect
    origin: FloatArray
    scale: FloatArray
    low: FloatArray
    high: FloatArray

    @classmethod
    def of(cls, spec: RobotSpec, effect: Effect) -> SpecBuilder:
        current = effect.read(spec)
        params = effect.parameters
        return cls(
            spec,
            effect,
            np.array([current[p.name] for p in params]),
            np.array([p.scale for p in params]),
            np.array([p.low for p in params]),
            np.array([p.high for p in params]),
        )

    def __call__(self, u: FloatArray) -> RobotSpec:
        values = np.clip(self.origin + u * self.scale, self.low, self.high)
        params = self.effect.parameters
        return self.effect.write(
            self.spec, {p.name: float(v) for p, v in zip(params, values, strict=True)}
        )


def gauss_newton_step(a: FloatArray, b: FloatArray, rcond: float = 1e-9) -> FloatArray:
    """The step −A⁺b of normal equations A·δ = −b, A⁺ the pseudo-inverse that drops directions
    whose eigenvalue is below ``rcond`` × the largest: a fold that leaves out the only runs
    determining a parameter keeps that parameter where the full fit put it instead of sending it
    to infinity."""
    values, vectors = np.linalg.eigh(0.5 * (a + a.T))
    top = float(np.max(values)) if len(values) else 0.0
    keep = values > rcond * top if top > 0 else np.zeros(len(values), dtype=bool)
    inverse = np.where(keep, 1.0 / np.where(keep, values, 1.0), 0.0)
    step: FloatArray = -(vectors @ (inverse * (vectors.T @ b)))
    return step


def bounded_gauss_newton_step(
    a: FloatArray, b: FloatArray, low: FloatArray, high: FloatArray, rcond: float = 1e-9
) -> FloatArray:
    """The minimiser of the Gauss–Newton model ½·δᵀAδ + bᵀδ inside the box low ≤ δ ≤ high:
    the step of a *bounded* refit, where :func:`gauss_newton_step` is the unbounded one.

    Why not the unbounded step clipped to the box: where two parameters are correlated,
    clipping one leaves the other where it only belonged beside the first's unclipped value,
    and the clipped point can be worse than no step at all. The box problem is solved exactly
    as a bounded linear least-squares problem (Stark & Parker 1995, BVLS) on A's square root;
    directions A does not determine (eigenvalue below ``rcond`` × the largest) are held at 0
    by a ridge of that size, as :func:`gauss_newton_step` drops them. Where the unbounded step
    (:func:`gauss_newton_step`) stays inside the box it is the minimum, and it is returned as
    it is, without the ridge's rounding."""
    free = gauss_newton_step(a, b, rcond)
    if np.all(free >= low) and np.all(free <= high):
        return free
    values, vectors = np.linalg.eigh(0.5 * (a + a.T))
    top = float(np.max(values)) if len(values) else 0.0
    if top <= 0.0:
        return np.zeros(len(b))
    keep = values > rcond * top
    root = np.sqrt(values[keep])[:, None] * vectors[:, keep].T  # rootᵀroot = A on its range
    target = -(vectors[:, keep].T @ b) / np.sqrt(values[keep])
    ridge = math.sqrt(rcond * top) * np.eye(len(b))
    lo = np.minimum(low, 0.0)
    hi = np.maximum(high, 0.0)
    if np.all(lo == hi):
        return np.zeros(len(b))
    solved = lsq_linear(
        np.vstack([root, ridge]),
        np.concatenate([target, np.zeros(len(b))]),
        bounds=(np.where(lo == hi, lo - 1e-12, lo), np.where(lo == hi, hi + 1e-12, hi)),
        method="bvls",
    )
    step: FloatArray = np.clip(np.asarray(solved.x, dtype=float), lo, hi)
    return step


def build_within(
    build: Callable[[FloatArray], RobotSpec], start: FloatArray, step: FloatArray
) -> RobotSpec:
    """``build(start + step)``, the step halved until the robot it makes is valid (a linearised
    step can leave the range a robot may have, e.g. a wheel twice nominal); ``build(start)`` if
    none is."""
    for _ in range(20):
        try:
            return build(start + step)
        except SpecError:
            step = 0.5 * step
    return build(start)


def whitened_stack(
    data: Dataset,
    spec: RobotSpec,
    sensor: SensorNoise,
    gains: Sequence[FloatArray] | None = None,
) -> tuple[FloatArray, list[FloatArray]]:
    """The whitened innovations of every run under ``spec``, concatenated and per run;
    ``gains``: the wheel-noise gains held (:func:`evaluate`). No log-likelihood: with a wheel
    jump expected, the jump mixture's filter is left out (``evaluate``'s ``loglik``)."""
    ev = evaluate(data, spec, sensor, gains=gains, loglik=False)
    return np.concatenate(ev.whitened), ev.whitened


# What the forked workers of :func:`whitened_stacks` read: set in the parent just before the
# fork, so every worker inherits the runs and their kept inputs instead of receiving them.
_SHARED_STACKS: tuple[Dataset, SensorNoise] | None = None


def _stack_task(spec: RobotSpec, attempt: int) -> list[FloatArray]:
    """One spec's per-run whitened innovations in a worker of :func:`whitened_stacks`."""
    del attempt
    assert _SHARED_STACKS is not None, "a whitened_stacks task outside its forked worker"
    data, sensor = _SHARED_STACKS
    return whitened_stack(data, spec, sensor)[1]


def whitened_stacks(
    data: Dataset,
    specs: Sequence[RobotSpec],
    sensor: SensorNoise,
    use: Callable[[int, list[FloatArray]], None],
    processes: int = 1,
    labels: Sequence[str] | None = None,
) -> None:
    """The per-run whitened innovations of :func:`whitened_stack` for every spec of ``specs``,
    handed to ``use(index, stack)`` as each is ready (so a caller can reduce them as they come
    and never hold them all: 73 stacks of ~2 MB for a 40-run library).

    With ``processes`` > 1, two or more specs, the ``fork`` start method and not inside a
    worker process already, the specs are shared among forked worker processes
    (:func:`odomgym.workers.run_tasks`), which inherit ``data``, and ``use`` sees them in the
    order they finish; else they are evaluated here, in order. Each spec's numbers are those
    one process computes (bit-identical). Why processes: a replay is mostly Python, so the
    evaluation threads of :func:`evaluate` share one core for it; a finite-difference library
    (two evaluations per term) is many independent evaluations. ``labels``: what to call each
    spec if its worker dies (default: its number).

    A spec whose evaluation raises in a worker surfaces as :class:`odomgym.workers.TaskFailed`
    (as a candidate fit's does in :func:`run_fit_jobs`)."""
    global _SHARED_STACKS
    if not forks(processes, len(specs)):
        for k, spec in enumerate(specs):
            use(k, whitened_stack(data, spec, sensor)[1])
        return
    names = list(labels) if labels is not None else [f"model {k + 1}" for k in range(len(specs))]
    _SHARED_STACKS = (data, sensor)
    try:
        run_forked(
            _stack_task,
            enumerate(specs),
            processes,
            use,
            lambda k: f"evaluating {names[k]} ({k + 1} of {len(specs)})",
        )
    finally:
        _SHARED_STACKS = None


def forks(processes: int, tasks: int) -> bool:
    """Whether :func:`whitened_stacks`, :func:`run_fit_jobs` and the open-loop gate's trials
    (:meth:`odomgym.diagnose.gate._Elimination.each`) share ``tasks`` among ``processes``
    forked workers: more than one of each, the ``fork`` start method available,
    and not inside a worker process already (a daemon process may not start its own)."""
    return (
        processes > 1
        and tasks > 1
        and not mp.current_process().daemon
        and "fork" in mp.get_all_start_methods()
    )


def run_forked(
    task: Handler,
    items: Iterable[tuple[int, object]],
    processes: int,
    finished: Callable[[int, Any], None],
    doing: Callable[[int], str],
) -> None:
    """``task`` on every ``(key, item)`` of ``items`` in forked workers
    (:func:`odomgym.workers.run_tasks`), each result handed to ``finished(key, result)`` as it
    comes; a worker that dies stops everything with a RuntimeError saying what it was
    ``doing(key)``. The evaluation pool's threads are closed first: no thread may be alive
    across a fork (a child inherits the lock state, not the threads)."""
    close_thread_pool()

    def died(death: WorkerDeath[int]) -> bool:
        raise RuntimeError(
            f"a diagnose worker died (exit code {death.exitcode}) while {doing(death.key)}"
        )

    run_tasks(task, items, processes=processes, finished=finished, died=died, start_method="fork")


@dataclass
class CandidateFit:
    """One candidate effect fitted to the fit runs."""

    name: str
    spec: RobotSpec
    sensor: SensorNoise
    values: dict[str, float]
    loglik: FloatArray  # per run, at the full fit
    cv_loglik: FloatArray = field(default_factory=lambda: np.zeros(0))  # per run, held out
    stderr: dict[str, float] = field(default_factory=dict)
    stderr_runs: dict[str, float] = field(default_factory=dict)  # run-clustered (sandwich)
    stderr_sessions: dict[str, float] = field(default_factory=dict)  # session-clustered
    jacobian: list[FloatArray] = field(default_factory=list)  # per run (m, p), whitened
    whitened: list[FloatArray] = field(default_factory=list)  # per run (m,)

    def entry(self, name: str, value: float) -> dict[str, float]:
        """The report's entry of parameter ``name`` at ``value``: the value and its three
        standard errors (model-based, run- and session-clustered; NaN when not computed)."""
        return {
            "value": value,
            "stderr": self.stderr.get(name, math.nan),
            "stderr_runs": self.stderr_runs.get(name, math.nan),
            "stderr_sessions": self.stderr_sessions.get(name, math.nan),
        }

    def entries(self) -> dict[str, dict[str, float]]:
        """The report's entry (:meth:`entry`) of each of the fit's own parameters at its value."""
        return {key: self.entry(key, value) for key, value in self.values.items()}


def _least_squares_step(
    data: Dataset, spec: RobotSpec, sensor: SensorNoise, effect: Effect, hold: bool = False
) -> RobotSpec:
    """``effect``'s parameters fitted by generalised least squares at fixed noise; ``hold``:
    with the wheel-noise gains held (:func:`_least_squares`)."""
    return _least_squares(data, spec, sensor, effect, hold=hold)[0]


class HeldGains(list[FloatArray]):
    """Each run's wheel-noise gains (:func:`_held_gains`), with their stacks per contiguous
    range of runs kept (:func:`_stacked_gains`): a fit that holds them evaluates hundreds of
    times."""

    def __init__(self, gains: Sequence[FloatArray]) -> None:
        super().__init__(gains)
        self.stacks: dict[tuple[int, int], FloatArray] = {}


def _stacked_gains(gains: Sequence[FloatArray], index: range) -> FloatArray:
    """The gains of the runs of ``index`` stacked (N, 2, 3); kept if ``gains`` is a
    :class:`HeldGains`."""
    key = (index.start, index.stop)
    kept = gains.stacks if isinstance(gains, HeldGains) else {}
    held = kept.get(key)
    if held is None:
        held = kept[key] = np.ascontiguousarray(np.concatenate([gains[j] for j in index]))
    return held


def _held_gains(data: Dataset, spec: RobotSpec) -> HeldGains:
    """Each run's wheel-noise gains under ``spec`` (:func:`~odomgym.diagnose.likelihood.
    replay_gains`): how the wheels' noise reaches the pose, which a least-squares fit may hold
    (:func:`_least_squares`)."""
    return HeldGains([replay_gains(rep) for rep in data.replays(spec)])


def _least_squares(
    data: Dataset,
    spec: RobotSpec,
    sensor: SensorNoise,
    effect: Effect,
    max_nfev: int = 30,
    hold: bool = False,
) -> tuple[RobotSpec, float]:
    """:func:`_least_squares_step` with at most ``max_nfev`` steps, and the fitted spec's
    cost: the sum of its squared whitened innovations. The Jacobian is
    :func:`forward_jacobian`'s, at steps of :data:`JACOBIAN_STEP` of each parameter's scale.

    The noise parameters are fixed; how the noise reaches the pose moves with the replay (the
    wheel-noise gains: the heading's is 1/(E_b·b), the position's turns with the replayed
    heading), unless ``hold``, which keeps the gains of ``spec`` for every step of the fit.
    Neither sum of squares is the likelihood, which also weighs the covariance's
    log-determinant; :func:`fit_candidate` keeps whichever fit the likelihood prefers where
    they part (beside a partner)."""
    u0, low, high, build = systematic_vector(spec, effect)
    held = _held_gains(data, spec) if hold else None
    last: list[tuple[bytes, FloatArray]] = []

    def residual(u: FloatArray) -> FloatArray:
        key = u.tobytes()
        if last and last[0][0] == key:
            return last[0][1]
        r = whitened_stack(data, build(u), sensor, held)[0]
        last[:] = [(key, r)]
        return r

    def jacobian(u: FloatArray) -> FloatArray:
        return forward_jacobian(residual, u, residual(u), high)

    try:
        result = least_squares(
            residual,
            u0,
            jac=jacobian,
            bounds=(low, high),
            x_scale=1.0,
            ftol=LEAST_SQUARES_FTOL,
            max_nfev=max_nfev,
        )
    except ValueError as exc:
        if str(exc) != _TRUST_REGION_FAILURE:
            raise
        # scipy's trust-region reflective step could not be taken from this start: a
        # one-sided parameter at its bound (moved 1e-10 inside), whose gradient points out,
        # beside one without any gradient (a skid track's half-point at no excess), left a
        # trust radius of the order of 1e-5 that rounding put the step outside. Seen once, in
        # a skid track's fit beside `wheelbase` on a differential-drive robot carrying
        # `skid_speed`, with that effect offered to every robot (the blind matrix's independent
        # generator at 5 ×, seed 1001002; docs/skid-steer.md). The fit keeps its start: the
        # data give the parameters no direction to leave it by.
        start = residual(u0)
        return spec, float(start @ start)
    return build(result.x), 2.0 * float(result.cost)


_TRUST_REGION_FAILURE = "`x` is not within the trust region."
"""scipy's message when ``least_squares``' trust-region reflective step cannot be taken
(``scipy.optimize._lsq.common.intersect_trust_region``): the one numerical failure of a start
:func:`_least_squares` answers by keeping the start."""


LEAST_SQUARES_FTOL = 1e-7
"""A systematic fit stops once a step lowers the cost ½Σw² by less than this share of it
(scipy's ``ftol``; its default is 1e-8). The cost of whitened innovations is about half the
number of measured values, so 1e-7 is 0.004 nats on the 14 June OptiOdom sessions (80 000
values) and less on smaller logs: below the 0.1 to which the reports give a likelihood ratio.

Why not the default: the last iterations it asked for moved the likelihood by thousandths of
a nat and cost a Jacobian each (one replay and filter of every run per parameter); with 1e-7
the June sessions' diagnosis took 79–83 s instead of 94 s, its effects, verdict and held-out
table the same, the kept values equal to four significant digits or more (``docs/diagnose.md``,
"Landed on stop 63")."""


JACOBIAN_STEP = 1e-2
"""The finite-difference step of a systematic fit's Jacobian, in units of each parameter's
scale (:class:`~odomgym.effects.Parameter`): the step the open-loop fit takes too
(:mod:`odomgym.diagnose.openloop`)."""


def forward_jacobian(
    residual: Callable[[FloatArray], FloatArray],
    u: FloatArray,
    base: FloatArray,
    high: FloatArray,
    step: float = JACOBIAN_STEP,
) -> FloatArray:
    """Forward differences of ``residual`` at ``u`` (``base`` its value there) with an
    absolute ``step`` per parameter, backward where the forward one would pass ``high``.

    Why absolute: scipy's ``diff_step`` is relative to |u|, and the parameters are offsets from
    the spec's current values, so a fit starts at u = 0. A one-sided effect starts at its bound,
    where ``least_squares`` moves u to 1e-10 inside: a relative step of 1e-12 there, a Jacobian
    of rounding noise, and the fit stayed at the bound whatever the data (a robot over-turning
    in fast turns with ``skid_speed`` g = 0.095 s²/m: fitted 1e-12 from the bound, 0.093 from
    1e-6; the gradient's sign was wrong: +2.6 against −14.3 at every step from 1e-10 to 1e-2 of
    the scale)."""
    jac = np.empty((len(base), len(u)))
    for k in range(len(u)):
        h = step if u[k] + step <= high[k] else -step
        moved = u.copy()
        moved[k] += h
        jac[:, k] = (residual(moved) - base) / h
    return jac


def fit_candidate(
    data: Dataset,
    spec: RobotSpec,
    sensor: SensorNoise,
    effect: Effect,
    nuisance: Effect | None = None,
) -> CandidateFit:
    """Fit ``effect`` added to (or freed in) ``spec``; the sensor noise (and, for a systematic
    effect, the ``nuisance`` noise effect's parameters) are refitted alongside. A systematic
    effect's :attr:`~odomgym.effects.Effect.partners` are fitted jointly with it (``skid_track``
    beside ``wheelbase``: the excess of a spin's track over the asymptote E_b), from the
    partners' own fit; the fit's values and standard errors are the effect's own, the partners'
    refit is in its spec."""
    if effect.noise:
        return _fit_noise_candidate(data, spec, sensor, effect, nuisance)
    partners = [EFFECTS[name] for name in effect.partners if not EFFECTS[name].noise]
    start = spec
    if partners:
        # The partners alone first, then the effect beside them from there: started where the
        # model as given is far off (a skid-steer robot's E_b of 1.3-1.8 against a nominal 1),
        # the joint least squares of a few steps ended up the ridge along which the skid
        # track's excess and E_b trade, beyond the logged turns, where the shape rule refuses
        # it and `wheelbase` was named first (an elastic-tyred robot written apart from
        # odomgym, tests/independent_skid.py: the first round's fit at λ½ = 44.6, E_b 0.5).
        start = _least_squares_step(data, spec, sensor, _joint(partners))
    current_spec, current_sensor = _fit_mean(data, start, sensor, effect, partners, nuisance)
    loglik = evaluate(data, current_spec, current_sensor, whitened=False).loglik
    if partners:
        # Fitted again with the wheel-noise gains held (_least_squares), the better likelihood
        # kept. Why: beside its partner an effect can keep the mean while the partner moves the
        # noise. A skid track's excess keeps the spins' mean while E_b, whose 1/(E_b·b) carries
        # the wheels' noise to the heading, widens the covariance, which the sum of squares
        # rewards and the likelihood does not: a differential-drive robot carrying a skid track
        # of ε 0.6 %, λ½ 2 (the blind matrix's World cell at 14 ×) was fitted at E_b 0.50,
        # ε 1.01, λ½ 61, 14 % less sum of squares than the truth and 30 nats less likelihood,
        # refused by the shape rule, and `backlash` was named first. With the gains held:
        # E_b 1.0001, ε 0.0052, λ½ 1.99. Held for every effect instead, they cost likelihood
        # elsewhere: the first round's E_d on one real OptiOdom session (230620202042) had a
        # likelihood ratio of 54.7 fitted with moving gains and 9.3 with held ones, and the 14
        # June sessions lost E_d (held-out heading 0.70° → 1.12°).
        held_spec, held_sensor = _fit_mean(
            data, start, sensor, effect, partners, nuisance, hold=True
        )
        held = evaluate(data, held_spec, held_sensor, whitened=False).loglik
        if float(np.sum(held)) > float(np.sum(loglik)):
            current_spec, current_sensor, loglik = held_spec, held_sensor, held
    if partners and at_nothing(effect, effect.read(current_spec)):
        # Back at nothing: from its bound the excess of a skid track has no gradient in its
        # half-point, and the fit may not have left it (the elastic-tyred robot: `wheelbase`
        # named first in 2 of 10). Fitted again from the best of a profile over the half-point,
        # kept if its likelihood is higher. Only then: a profile from every fit's start also
        # walked fits that had left the bound up the ridge along which the excess and E_b
        # trade, beyond the logged turns (the blind matrix's skid_track cells, 6 of 10 → 1).
        profiled = _profiled_start(data, start, sensor, effect, partners)
        if profiled is not start:
            again_spec, again_sensor = _fit_mean(data, profiled, sensor, effect, partners, nuisance)
            again = evaluate(data, again_spec, again_sensor, whitened=False).loglik
            if float(np.sum(again)) > float(np.sum(loglik)):
                current_spec, current_sensor, loglik = again_spec, again_sensor, again
    fit = CandidateFit(effect.name, current_spec, current_sensor, effect.read(current_spec), loglik)
    _linearise(data, fit, effect)
    return fit


def at_nothing(effect: Effect, values: Mapping[str, float]) -> bool:
    """Whether fitted ``values`` leave ``effect`` absent: each within a millionth of its
    parameter's scale of its absent value counts as there (a bounded least squares starts
    strictly inside its bounds, so an excess fitted to its bound of 0 comes back as 1e-12)."""
    snapped = {
        p.name: p.absent
        if abs(float(values.get(p.name, p.absent)) - p.absent) <= 1e-6 * p.scale
        else float(values[p.name])
        for p in effect.parameters
    }
    return effect.is_absent(snapped)


def _profiled_start(
    data: Dataset,
    spec: RobotSpec,
    sensor: SensorNoise,
    effect: Effect,
    partners: Sequence[Effect],
) -> RobotSpec:
    """Where ``effect``'s second fit starts (:func:`fit_candidate`, a first fit back at
    nothing): ``spec``, or the best by generalised least squares of the starts of its
    :meth:`~odomgym.effects.Effect.profile`, each with the profiled parameter held while the
    effect's others and its ``partners`` are fitted. A start that does not lower the cost of
    ``spec`` is not taken (``spec`` itself comes back, and no second fit is made)."""
    profile = effect.profile(effect.read(spec), data.wheel_travel(spec))
    if profile is None:
        return spec
    held, starts = profile
    free = _Holding([effect, *partners], f"{effect.name}.{held}")
    whitened = whitened_stack(data, spec, sensor)[0]
    best, best_cost = spec, float(whitened @ whitened)
    for values in starts:
        fitted, cost = _least_squares(
            data, effect.write(spec, values), sensor, free, max_nfev=PROFILE_NFEV
        )
        if cost < best_cost:
            best, best_cost = fitted, cost
    return best


PROFILE_NFEV = 10
"""The least-squares steps of each start of a profile (:func:`_profiled_start`): with the
profiled parameter held, the rest is nearly linear in the residuals, and a start only has to
rank, not to finish (the fit from the best one follows)."""


def _fit_mean(
    data: Dataset,
    spec: RobotSpec,
    sensor: SensorNoise,
    effect: Effect,
    partners: Sequence[Effect],
    nuisance: Effect | None,
    hold: bool = False,
) -> tuple[RobotSpec, SensorNoise]:
    """A systematic candidate's fit (:func:`fit_candidate`): ``effect`` and its ``partners`` by
    least squares at the noise (``hold``: with the wheel-noise gains held), then the noise,
    twice."""
    fitted = _joint([effect, *partners])
    for _ in range(2):
        spec = _least_squares_step(data, spec, sensor, fitted, hold)
        spec, sensor, _ = fit_noise(data, spec, sensor, nuisance)
    return spec, sensor


def _joint(effects: Sequence[Effect]) -> Effect:
    """``effects`` fitted as one: the effect itself if it is alone."""
    return effects[0] if len(effects) == 1 else Joint(effects)


def _fit_noise_candidate(
    data: Dataset,
    spec: RobotSpec,
    sensor: SensorNoise,
    effect: Effect,
    nuisance: Effect | None,
) -> CandidateFit:
    """A noise effect fitted (:func:`fit_candidate`), jointly with its systematic partners.

    The partners' mean parameters are fitted by least squares at the noise fit, then the noise
    again (twice), so the noise effect carries no systematic part. Where the model already
    carries a partner (the distance scale a round named for the travel bumps lose), the fit
    also starts from the partner as given and keeps the better of the two: from the partner
    that took the bumps' mean, every start of the bumps adds a second mean loss, and the noise
    fit stays where wheel noise explains the jumps (seen on the independent generator's bumps
    of 3 mm at 0.5 per metre)."""
    partners = [EFFECTS[name] for name in effect.partners]
    starts = [spec]
    if any(not p.is_absent(p.read(spec)) for p in partners):
        plain = spec
        for partner in partners:
            plain = partner.write(plain, partner.absent_values())
        starts.append(plain)
    best: CandidateFit | None = None
    for begin in starts:
        current_spec, current_sensor, _ = fit_noise(data, begin, sensor, effect, nuisance)
        for partner in partners:
            for _ in range(2):
                before = partner.read(current_spec)
                current_spec = _least_squares_step(data, current_spec, current_sensor, partner)
                after = partner.read(current_spec)
                if all(
                    abs(after[q.name] - before[q.name]) < 0.01 * q.scale for q in partner.parameters
                ):
                    break  # converged: the partner stayed put, so would the noise fit
                current_spec, current_sensor, _ = fit_noise(
                    data, current_spec, current_sensor, effect, nuisance, warm=True
                )
        ev = evaluate(data, current_spec, current_sensor, whitened=False)
        fit = CandidateFit(
            effect.name, current_spec, current_sensor, effect.read(current_spec), ev.loglik
        )
        if best is None or float(fit.loglik.sum()) > float(best.loglik.sum()):
            best = fit
    assert best is not None
    return best


def _linearise(data: Dataset, fit: CandidateFit, effect: Effect) -> None:
    """Per-run whitened residuals and Jacobians at the fit (central differences), and the
    parameters' standard errors: from the Gauss–Newton curvature (``stderr``: right when the
    whitened innovations are independent, as the noise model says) and run-clustered
    (``stderr_runs``: the sandwich I⁻¹·(Σ_runs g·gᵀ)·I⁻¹·G/(G−1) with g = Jᵀw each run's score,
    Liang & Zeger 1986), which stays right when samples within a run are correlated by
    something the model lacks — on real data the honest one to compare two data sets by — and
    session-clustered (``stderr_sessions``, the same with each session's runs summed into one
    score; NaN with fewer than two sessions), which also holds when the robot itself changed
    between sessions (tyre wear, load, floor)."""
    u0, _, _, build = systematic_vector(fit.spec, effect)
    _, base = whitened_stack(data, fit.spec, fit.sensor)
    columns: list[list[FloatArray]] = [[] for _ in data.runs]
    step = 0.05
    for k in range(len(u0)):
        du = np.zeros_like(u0)
        du[k] = step
        _, plus = whitened_stack(data, build(u0 + du), fit.sensor)
        _, minus = whitened_stack(data, build(u0 - du), fit.sensor)
        for j in range(len(data.runs)):
            columns[j].append((plus[j] - minus[j]) / (2.0 * step))
    fit.whitened = base
    fit.jacobian = [np.stack(c, axis=1) for c in columns]
    info = sum(j.T @ j for j in fit.jacobian)
    try:
        cov: FloatArray = np.asarray(np.linalg.inv(info), dtype=float)
    except np.linalg.LinAlgError:
        cov = np.full((len(u0), len(u0)), np.inf)
    scores = np.array([j.T @ w for j, w in zip(fit.jacobian, base, strict=True)])
    by_run = clustered_covariance(cov, scores, list(range(len(scores))))
    labels = [str(r.meta.get("session", "")) for r in data.runs]
    by_session = clustered_covariance(cov, scores, labels)
    for k, p in enumerate(effect.parameters):
        fit.stderr[p.name] = float(math.sqrt(max(cov[k, k], 0.0)) * p.scale)
        fit.stderr_runs[p.name] = float(math.sqrt(max(by_run[k, k], 0.0)) * p.scale)
        fit.stderr_sessions[p.name] = float(math.sqrt(max(by_session[k, k], 0.0)) * p.scale)


def strata(runs: Sequence[Run]) -> dict[str, list[int]]:
    """Run indices grouped by experiment *family* — the experiment label's first word
    (``spin`` for ``spin_cw_90_fast``), so that a protocol of many one-run labels is still split
    across its kinds of manoeuvre — each group ordered by label."""
    groups: dict[str, list[tuple[str, int]]] = {}
    for j, run in enumerate(runs):
        label = str(run.meta.get("experiment", run.kind))
        family = re.split(r"[_\-\s]", label, maxsplit=1)[0] or label
        groups.setdefault(family, []).append((label, j))
    return {family: [j for _, j in sorted(items)] for family, items in sorted(groups.items())}


def folds_for(runs: Sequence[Run], count: int, rng: np.random.Generator) -> list[list[int]]:
    """``count`` folds of run indices, stratified by experiment family (round-robin)."""
    labels = strata(runs)
    folds: list[list[int]] = [[] for _ in range(count)]
    position = 0
    for label in labels:
        members = labels[label]
        for j in rng.permutation(len(members)):
            folds[position % count].append(members[int(j)])
            position += 1
    return [sorted(f) for f in folds if f]


def cross_validate(
    data: Dataset,
    fit: CandidateFit,
    effect: Effect | None,
    folds: Sequence[Sequence[int]],
    nuisance: Effect | None = None,
) -> FloatArray:
    """Held-out log-likelihood of every run under ``fit`` refitted without its fold."""
    out = np.empty(len(data))
    if effect is None:  # the base model: nothing to refit but what all models share
        out[:] = fit.loglik
        return out
    if effect.noise:
        # One Newton step from the full fit per fold, on the per-run log-likelihood's
        # quadratic expansion in the log noise parameters (sensor σ and the effect's own),
        # limited to a factor e^±1; the held-out runs are then evaluated exactly there.
        chosen = [effect] + ([nuisance] if nuisance is not None and nuisance is not effect else [])
        _, grad, hess = noise_curvature(data, fit.spec, fit.sensor, chosen)
        x0, _, _, build = _noise_vector(fit.spec, fit.sensor, chosen, at_current=True)
        for fold in folds:
            held = set(fold)
            train = [j for j in range(len(data)) if j not in held]
            g = grad[train].sum(axis=0)
            h = hess[train].sum(axis=0)
            try:
                delta = -np.linalg.solve(h, g)
            except np.linalg.LinAlgError:
                delta = np.zeros(len(g))
            if not np.all(np.isfinite(delta)) or np.linalg.eigvalsh(h).max() >= 0:
                delta = np.zeros(len(g))  # not a maximum: keep the full fit
            spec, sensor = build(x0 + np.clip(delta, -1.0, 1.0))
            held_data = data.subset(list(fold))
            out[list(fold)] = evaluate(held_data, spec, sensor, whitened=False).loglik
        return out
    # One Gauss–Newton step from the full fit per fold, inside the parameters' bounds: the
    # fold's refit is a bounded fit like the full one. Unbounded, a fold that leaves out the runs
    # carrying a parameter's information has almost no curvature in it and the step ran far
    # past its bound (the World's Scout 2.0 carrying `skid_speed`, seed 505001, first round: a
    # one-sided gain at its lower bound 0 sent to −4.9 s²/m, the held-out fold then scored
    # −3 460 nats; bounded, it stays at 0 and the fold scores about what the full fit does).
    _, low, high, _ = systematic_vector(fit.spec, effect)
    for fold in folds:
        held = set(fold)
        train = [j for j in range(len(data)) if j not in held]
        a: FloatArray = np.sum([fit.jacobian[j].T @ fit.jacobian[j] for j in train], axis=0)
        b: FloatArray = np.sum([fit.jacobian[j].T @ fit.whitened[j] for j in train], axis=0)
        delta = bounded_gauss_newton_step(a, b, low, high)
        for j in fold:
            moved = fit.whitened[j] + fit.jacobian[j] @ delta
            out[j] = fit.loglik[j] - 0.5 * (moved @ moved - fit.whitened[j] @ fit.whitened[j])
    return out


@dataclass(frozen=True)
class FitJob:
    """One candidate's fit and cross-validation: a unit of work for a worker process, and the
    key of a finished fit in a journal (the fit is a deterministic function of these fields).

    Attributes:
        data: the fit runs.
        model: the current model the candidate is added to (its noise already fitted with the
            nuisance beside it).
        effect: the candidate's registry name (:data:`odomgym.effects.EFFECTS`); a name, not
            the object, so that a job pickles small and a forked worker finds the same effect
            (user-registered ones included) in its inherited registry.
        nuisance: the registry name of the noise effect fitted beside a systematic candidate,
            or None.
        folds: the cross-validation folds, run indices into ``data``.
    """

    data: Dataset
    model: Model
    effect: str
    nuisance: str | None
    folds: Sequence[Sequence[int]]

    def key_parts(self) -> tuple[object, ...]:
        """The job as the flat tuple a journal key is the hash of (the same tuple the jobs were
        before they were a class, so that fits journalled then are still found)."""
        return (
            self.data,
            self.model.spec,
            self.model.sensor,
            self.effect,
            self.nuisance,
            self.folds,
        )

    def run(self) -> CandidateFit:
        """Fit the candidate and cross-validate it."""
        effect = EFFECTS[self.effect]
        nuisance = EFFECTS[self.nuisance] if self.nuisance else None
        fit = fit_candidate(self.data, self.model.spec, self.model.sensor, effect, nuisance)
        fit.cv_loglik = cross_validate(self.data, fit, effect, self.folds, nuisance)
        return fit


def _run_job(job: FitJob, attempt: int) -> CandidateFit:
    """:meth:`FitJob.run` as a module-level task handler of :func:`odomgym.workers.run_tasks`
    (every attempt gives the same fit)."""
    del attempt
    return job.run()


def run_fit_jobs(
    jobs: Mapping[int, FitJob],
    processes: int,
    finished: Callable[[int, CandidateFit], None],
) -> None:
    """Run every job of ``jobs`` (keyed by the caller's index) and hand each fit to
    ``finished(index, fit)`` as soon as it is done, in whatever order they finish.

    Inside :func:`odomgym.distributed.on_ray` (``diagnose --backend ray``), more than one job:
    as Ray tasks of one CPU each. Else, with ``processes`` > 1, more than one job and the
    ``fork`` start method: in odomgym's
    worker pool (:func:`odomgym.workers.run_tasks`) of forked processes (they share the effect
    registry, user effects included, and the compiled kernels). Otherwise one after the other
    in this process, in the mapping's order. Results do not depend on which: each fit is a
    deterministic function of its job.

    Interruption: if ``finished`` raises, or anything else does while waiting (Ctrl-C, a
    SIGTERM turned into an exception), every worker is terminated at once and the exception
    propagates; a fit that raised in its worker is a :class:`odomgym.workers.TaskFailed`. A
    worker that dies (killed, out of memory) stops the diagnosis with a RuntimeError naming
    the candidate; the fits already finished (journalled by ``finished``) stay for a resume.
    """
    todo = list(jobs)
    started = ray_started()
    forked = forks(processes, len(todo))
    if started is not None or forked:
        todo = sorted(todo, key=lambda k: -_expected_cost(jobs[k].effect))
    if started is not None and len(todo) > 1:  # inside distributed.on_ray: Ray tasks
        run_ray_tasks(_run_job, ((k, (jobs[k], 0)) for k in todo), finished, started=started)
    elif forked:
        run_forked(
            _run_job,
            ((k, jobs[k]) for k in todo),
            processes,
            finished,
            lambda k: f"fitting {jobs[k].effect}",
        )
    else:
        for k in todo:
            finished(k, _run_job(jobs[k], 0))


def _expected_cost(name: str) -> int:
    """How many fits a candidate's job makes, roughly (the order :func:`run_fit_jobs` hands
    jobs out in, the dearest first): an effect fitted beside partners makes two or three
    (:func:`fit_candidate`: the partners alone, then jointly, then with the gains held or from
    a profile), every other effect one.

    Why: the workers take jobs first come, first served, and the round waits for its last
    fit. In registry order the dearest came late (on the 14 June OptiOdom sessions
    ``floor_bumps`` and ``skid_track``, 8 and 4 s against 0.5 s for the others), so one
    worker ran it alone while the other had finished; handed out first, it runs beside the
    rest (Graham 1969, longest processing time first). Each fit is a function of its job
    alone, so the order changes no result."""
    effect = EFFECTS.get(name)
    return 1 + len(effect.partners) if effect is not None else 1


def candidate_effects(exclude: Sequence[str] = ()) -> list[Effect]:
    """Every registered effect, in registry order, less ``exclude``."""
    return [e for name, e in EFFECTS.items() if name not in exclude]


class Joint(Effect):
    """Several systematic effects fitted as one (their parameters side by side, each named
    ``EFFECT.PARAMETER``): the refit of every named effect after another one joined, so that
    an effect fitted first is not left where it stood before the others explained their part.
    Not registered; only the fit uses it."""

    name = "(joint)"

    def __init__(self, effects: Sequence[Effect]) -> None:
        self.effects = list(effects)
        self.parameters = tuple(  # type: ignore[misc]
            dataclasses.replace(p, name=f"{e.name}.{p.name}")
            for e in self.effects
            for p in e.parameters
        )

    def read(self, spec: SpecView) -> dict[str, float]:
        out: dict[str, float] = {}
        for e in self.effects:
            out.update({f"{e.name}.{k}": v for k, v in e.read(spec).items()})
        return out

    def write(self, spec: Spec, values: Mapping[str, float]) -> Spec:
        out = spec
        for e in self.effects:
            prefix = f"{e.name}."
            own = {k[len(prefix) :]: v for k, v in values.items() if k.startswith(prefix)}
            if own:
                out = e.write(out, {**e.read(out), **own})
        return out

    def split(self, values: Mapping[str, float]) -> dict[str, dict[str, float]]:
        """``{effect: {parameter: value}}`` of joint values."""
        out: dict[str, dict[str, float]] = {}
        for key, value in values.items():
            effect, parameter = key.split(".", 1)
            out.setdefault(effect, {})[parameter] = value
        return out


class _Holding(Joint):
    """Several effects fitted as one (:class:`Joint`) with one parameter held where the spec
    has it (``EFFECT.PARAMETER``): the fits of a profile (:func:`_profiled_start`)."""

    def __init__(self, effects: Sequence[Effect], held: str) -> None:
        super().__init__(effects)
        self.parameters = tuple(p for p in self.parameters if p.name != held)  # type: ignore[misc]

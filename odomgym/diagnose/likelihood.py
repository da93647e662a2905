"""The likelihood of a logged run under a model: a Kalman filter on the disagreement.

State: δ = (true − predicted) axle pose (x, y [m], θ [rad]) in the world frame. The prediction
is the replay (:mod:`odomgym.diagnose.replay`); the disagreement grows through

* **wheel noise** — each wheel's travel d carries variance k²·|d| per sample (Chong & Kleeman
  1997, Eq. 4) and whatever noise effects add; linearised through the midpoint odometry
  equations, δ ← F·δ + G·w with F the displacement coupling (a heading error δθ moves later
  positions by δθ × displacement) and G = ∂(x, y, θ)/∂(d_L, d_R), exactly the propagation of
  Chong & Kleeman's Eq. 23 applied sample by sample;
* **wheel jumps** (``floor_bumps``): a Poisson number of sudden losses of e metres of one
  wheel's travel between two measurements (a bump: the pose moves −e/2 along the track and
  turns ±e/b); the innovation is a Gaussian mixture over the jump count (0–3), each jump's
  effect propagated to the measurement like the wheel noise, collapsed to one Gaussian after
  each update (a first-order generalised pseudo-Bayesian filter). With ``gaussian_jumps`` the
  jumps enter as their variance instead (for least-squares fits);
* **the sensor** — every measured pose component has white noise (σ_xy, σ_xy, σ_θ); the first
  measured pose starts the replay, so its noise is the initial covariance.

The log-likelihood (prediction-error decomposition) is a proper scoring rule for a held-out run;
the whitened innovations turn a fit of the mean model into generalised least squares.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import inlined_kernel, kernel
from odomgym.diagnose.replay import Replay, StackedReplay
from odomgym.effects import EFFECTS
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "FilterInputs",
    "ProcessNoise",
    "RunLikelihood",
    "RunPredictive",
    "SensorNoise",
    "StackedInputs",
    "filter_inputs",
    "filter_runs",
    "measurement_mask",
    "replay_gains",
    "run_likelihood",
    "run_predictive",
    "run_residual",
    "run_scores",
    "score_stacked",
    "stacked_process_noise",
]

FloatArray = NDArray[np.float64]
_MAX_JUMPS = 3


@dataclass(frozen=True)
class SensorNoise:
    """White noise of the ground-truth sensor: position σ [m] (each axis), heading σ [rad]."""

    position: float
    heading: float


@dataclass(frozen=True)
class RunLikelihood:
    """Log-likelihood of one run, its whitened innovations and how many values entered."""

    loglik: float
    whitened: FloatArray
    count: int


def measurement_mask(run: Run, min_interval: float) -> NDArray[np.bool_]:
    """Which pose components (T, 3) enter the filter: measured ones, at most one sample every
    ``min_interval`` seconds (the last measured sample always), never the first (it starts the
    replay)."""
    measured = np.isfinite(run.true_pose)
    rows = np.flatnonzero(measured[:, :2].all(axis=1) | measured[:, 2])
    keep = np.zeros(len(run.time), dtype=bool)
    last = -math.inf
    for k in rows[1:]:
        if run.time[k] - last >= min_interval - 1e-9:
            keep[k] = True
            last = run.time[k]
    if len(rows) > 1:
        keep[rows[-1]] = True
    return measured & keep[:, None]


ProcessNoise = tuple[FloatArray, FloatArray, float]
"""What :func:`process_noise` returns: wheel variance (n, 2) [m²], expected jumps (n, 2) and
the travel one jump loses [m]."""


def process_noise(spec: RobotSpec, travel: FloatArray) -> ProcessNoise:
    """Per-sample wheel variance (n, 2) [m²], expected wheel jumps (n, 2) and the travel each
    jump loses [m], from the spec's noise effects.

    Every noise effect's variance and jump rate is a function of each sample's travel alone
    (element by element), so ``travel`` may be several runs' travel stacked: each run's rows
    of the result are the bytes :func:`process_noise` gives for that run alone."""
    variance = np.zeros(travel.shape)  # not zeros_like: a Python function, ~6 µs a call
    jumps = np.zeros(travel.shape)
    size = 0.0
    for name, values in spec.effect_dict().items():
        effect = EFFECTS.get(name)
        if effect is None or not effect.noise:
            continue
        extra = effect.wheel_variance(values, travel)
        if extra is not None:
            variance += extra
        jumping = effect.wheel_jumps(values, travel, float(spec.true_wheelbase))
        if jumping is not None:
            rate, jump = jumping
            if size and jump != size:
                raise ValueError("only one wheel-jump effect is supported at a time")
            jumps += rate
            size = jump
    return variance, jumps, size


def run_likelihood(
    run: Run,
    replay: Replay,
    spec: RobotSpec,
    sensor: SensorNoise,
    mask: NDArray[np.bool_],
    *,
    gaussian_jumps: bool = False,
) -> RunLikelihood:
    """Filter ``run``'s disagreement with ``replay`` under ``spec``'s noise and ``sensor``."""
    loglik, whitened, count = _filter(
        *_model_arrays(replay, spec, sensor),
        run_residual(run, replay, mask),
        mask,
        gaussian_jumps,
        True,
        np.zeros((0, 2)),
    )
    return RunLikelihood(float(loglik), whitened, int(count))


LEVEL_DRAWS = 8000
"""Standard-normal draws (fixed, seeded) on which :func:`run_predictive` estimates the
coverage level of a jump mixture's predictive region. The draws are shared by every sample, so
their error does not average out: near a level q it is √(q(1 − q)/8000), 0.6 % at 50 % and
0.24 % at 95 % — small beside the 40–60 % and 90–98 % windows of
:mod:`odomgym.diagnose.spread`."""

_DRAWS = np.random.default_rng(20261128).standard_normal((LEVEL_DRAWS, 3))


@dataclass(frozen=True)
class RunPredictive:
    """A run's open-loop errors scored by the model's predictive distribution.

    Attributes:
        loglik: log predictive density of the whole sequence of disagreements at the measured
            samples [nats] — the prediction-error decomposition, i.e. the joint density of the
            run's open-loop errors (Schweppe 1965), the jump mixture included.
        levels: for each measured sample (in time order), the probability the one-step
            predictive distribution gives its smallest covariance ellipsoid that holds the
            observed error: the sample lies inside the model's q-region exactly when its
            level is ≤ q.
    """

    loglik: float
    levels: FloatArray


def run_predictive(
    run: Run, replay: Replay, spec: RobotSpec, sensor: SensorNoise, mask: NDArray[np.bool_]
) -> RunPredictive:
    """``run``'s disagreement with ``replay`` scored under ``spec``'s noise effects and
    ``sensor``: the filter of :func:`run_likelihood` (the jump mixture exact to its three
    jumps per interval), and where each measured error falls in its predictive distribution
    (:class:`RunPredictive`)."""
    levels = np.full(len(run.time), np.nan)
    loglik, _, _ = _filter(
        *_model_arrays(replay, spec, sensor),
        run_residual(run, replay, mask),
        mask,
        False,
        True,
        np.zeros((0, 2)),
        True,
        levels,
        _DRAWS,
    )
    measured: NDArray[np.bool_] = np.array(np.asarray(mask, dtype=bool).any(axis=1))
    measured[0] = False
    return RunPredictive(float(loglik), levels[measured])


def run_scores(
    run: Run,
    replay: Replay,
    spec: RobotSpec,
    sensor: SensorNoise,
    mask: NDArray[np.bool_],
    *,
    whitened: bool,
    kept: FilterInputs | None = None,
    noise: ProcessNoise | None = None,
    loglik: bool = True,
) -> tuple[float, FloatArray | None]:
    """``run``'s log-likelihood with the jump mixture and, if ``whitened``, its whitened
    innovations with the jumps as their variance: :func:`run_likelihood`'s ``loglik`` without
    and ``whitened`` with ``gaussian_jumps``, which is what a fit needs of every run.
    ``loglik`` False (with ``whitened``): the caller needs the whitened innovations only, and
    the log-likelihood of a run where a wheel jump is expected is not computed (NaN).

    Why one function: the two filters differ only at samples where a wheel jump is expected
    (``gaussian_jumps`` is read nowhere else), so without any — every model but one carrying
    ``floor_bumps`` — one pass gives both, bit-identical to two; the process noise and the
    residual are computed once either way. ``kept``: :func:`filter_inputs` of this run,
    replay and mask if the caller keeps them (a noise fit replays nothing, so they stay put
    over the fit's hundreds of evaluations). ``noise``: :func:`process_noise` of ``spec`` and
    this replay's travel if the caller computed it (for all runs at once, see
    :func:`stacked_process_noise`)."""
    if kept is None:
        kept = filter_inputs(run, replay, mask)
    arrays = _model_arrays(replay, spec, sensor, kept.gains, noise)
    residual = kept.residual
    no_expected = np.zeros((0, 2))
    jumping = whitened and bool(np.any(arrays[4] > 0.0))
    if jumping and not loglik:
        _, white, _ = _filter(*arrays, residual, mask, True, True, no_expected)
        return math.nan, white
    value, white, _ = _filter(*arrays, residual, mask, False, True, no_expected)
    if not whitened:
        return float(value), None
    if jumping:
        _, white, _ = _filter(*arrays, residual, mask, True, True, no_expected)
    return float(value), white


def score_stacked(
    replay: StackedReplay,
    measured: FloatArray,
    mask: NDArray[np.bool_],
    spec: RobotSpec,
    sensor: SensorNoise,
    *,
    whitened: bool,
    gains: FloatArray | None = None,
    loglik: bool = True,
) -> tuple[FloatArray, FloatArray]:
    """:func:`run_scores` of every run of a stacked replay, in one compiled call: each run's
    log-likelihood (R,) and, if ``whitened``, the runs' whitened innovations stacked (3·(N + R),;
    run r's are entries ``3·samples[r]:3·samples[r + 1]``, :meth:`StackedReplay.samples`),
    else an empty array. ``measured`` and ``mask`` are the runs' measured poses and masks
    stacked as the replay's poses (N + R, 3); ``gains``: the wheel gains held (N, 2, 3), as
    ``kept`` holds them in :func:`run_scores` (default: the replay's own); ``loglik``: as in
    :func:`run_scores` (False: NaN for a run where a wheel jump is expected).

    The same bytes as :func:`run_scores` on each run: the residual, the wheel gains and the
    filter are the same compiled functions on each run's rows, and the process noise of the
    stacked travel is, row by row, each run's (:func:`process_noise`). Why: the Python around
    each run's filter (its inputs gathered, the process noise looked up, the call dispatched)
    held the GIL for a third of a systematic evaluation, so the evaluation threads queued for
    it; one call per thread's share releases it for the whole share."""
    samples = replay.samples()
    if not (measured.shape == mask.shape == replay.pose.shape):
        raise ValueError(
            f"score_stacked: measured {measured.shape}, mask {mask.shape} and replayed poses "
            f"{replay.pose.shape} must have the same shape"
        )
    if gains is not None and gains.shape != (len(replay.ds), 2, 3):
        raise ValueError(f"score_stacked: held gains {gains.shape} for {len(replay.ds)} intervals")
    variance, jumps, size = process_noise(spec, replay.travel)
    runs = len(samples) - 1
    logs = np.empty(runs)
    white = np.empty(3 * len(replay.pose) if whitened else 0)
    _score_runs(
        np.ascontiguousarray(measured, dtype=np.float64),
        replay.pose,
        replay.tracked,
        replay.ds,
        replay.dtheta,
        float(replay.wheelbase),
        variance,
        jumps,
        size,
        np.array([sensor.position, sensor.position, sensor.heading]),
        np.ascontiguousarray(mask, dtype=np.bool_),
        samples,
        np.asarray(replay.bounds, dtype=np.int64),
        np.zeros((0, 2, 3)) if gains is None else np.ascontiguousarray(gains, dtype=np.float64),
        gains is not None,
        replay.cos_mid,
        replay.sin_mid,
        whitened,
        whitened and not loglik,
        logs,
        white,
    )
    return logs, white


@kernel
def _score_runs(
    measured: FloatArray,
    pose: FloatArray,
    tracked: FloatArray,
    ds: FloatArray,
    dtheta: FloatArray,
    wheelbase: float,
    variance: FloatArray,
    jumps: FloatArray,
    size: float,
    sigma: FloatArray,
    mask: NDArray[np.bool_],
    samples: NDArray[np.int64],
    intervals: NDArray[np.int64],
    held: FloatArray,
    use_held: bool,
    cos_mid: FloatArray,
    sin_mid: FloatArray,
    whitened: bool,
    white_only: bool,
    logs: FloatArray,
    white: FloatArray,
) -> None:
    """:func:`run_scores` of every run of stacked arrays (:func:`score_stacked`); the wheel
    gains from the replay's cosines and sines of the middle headings where it kept them.
    ``white_only``: the whitened innovations only — a run where a wheel jump is expected gets
    NaN for its log-likelihood and skips the jump mixture's filter (which a least-squares
    residual never reads: four Kalman updates a sample, about 3/4 of such a run's time)."""
    shared = cos_mid.shape[0] == ds.shape[0]
    no_expected = np.zeros((0, 2))
    for j in range(samples.shape[0] - 1):
        a = samples[j]
        b = samples[j + 1]
        c = intervals[j]
        d = intervals[j + 1]
        residual = _pose_residual(measured[a:b], tracked[a:b], mask[a:b])
        if use_held:
            gains = held[c:d].copy()
        elif shared:
            gains = _wheel_gains_of(
                pose[a:b], ds[c:d], dtheta[c:d], wheelbase, cos_mid[c:d], sin_mid[c:d]
            )
        else:
            gains = _wheel_gains(pose[a:b], ds[c:d], dtheta[c:d], wheelbase)
        jumping = False
        if whitened:
            for k in range(c, d):
                for w in range(2):
                    if jumps[k, w] > 0.0:
                        jumping = True
        if jumping and white_only:
            logs[j] = math.nan
        else:
            loglik, own, _ = _filter(
                pose[a:b],
                tracked[a:b],
                gains,
                variance[c:d],
                jumps[c:d],
                size,
                sigma,
                residual,
                mask[a:b],
                False,
                True,
                no_expected,
            )
            logs[j] = loglik
            if not whitened:
                continue
        if jumping:
            _, own, _ = _filter(
                pose[a:b],
                tracked[a:b],
                gains,
                variance[c:d],
                jumps[c:d],
                size,
                sigma,
                residual,
                mask[a:b],
                True,
                True,
                no_expected,
            )
        for k in range(3 * (b - a)):
            white[3 * a + k] = own[k]


def stacked_process_noise(
    spec: RobotSpec, travel: FloatArray, rows: list[slice]
) -> list[ProcessNoise]:
    """:func:`process_noise` of every run whose travel is ``travel[rows[j]]``, from one call on
    the stacked travel (ΣN, 2) [m]; each run's arrays are views of the stacked result.

    Why: a noise fit evaluates the same replays hundreds of times with new noise parameters,
    and the Python around each run's :func:`process_noise` (the effects' lookup, a dozen
    small numpy calls) cost about a tenth of the filter's own time per run; once per
    evaluation it is paid once for all runs. Element by element the same operations, so the
    same bytes (``tests/test_diagnose_speed.py``)."""
    variance, jumps, size = process_noise(spec, travel)
    return [(variance[r], jumps[r], size) for r in rows]


def filter_runs(
    stacked: StackedInputs,
    noise: ProcessNoise,
    sensor: SensorNoise,
    runs: range,
    out: FloatArray,
) -> None:
    """The log-likelihood of each run of ``runs`` (indices into ``stacked``) into ``out[j]``,
    from every run's inputs stacked (:class:`StackedInputs`) and their process noise stacked
    alike (:func:`process_noise` of the stacked travel): what :func:`run_scores` gives each
    run without ``whitened``, the same bytes (``tests/test_diagnose_speed.py``).

    Why: a noise fit evaluates the same replays hundreds of times; one compiled call for a
    share of the runs leaves out the Python around each run's filter (~20 µs a run: the
    arrays gathered, the call dispatched), a third of a short run's evaluation. It releases
    the GIL, so two shares run on two threads."""
    variance, jumps, size = noise
    # The kernel checks no bounds: a share outside the runs would read and write past them.
    total = len(stacked.samples) - 1
    if (
        runs.step != 1
        or not 0 <= runs.start <= runs.stop <= total
        or len(out) != total
        or len(variance) != len(stacked.gains)
    ):
        raise ValueError(
            f"filter_runs: a contiguous share of the {total} stacked runs, one out entry a "
            f"run and their stacked noise, got runs {runs}, {len(out)} out entries and "
            f"{len(variance)} noise rows for {len(stacked.gains)} intervals"
        )
    sigma = np.array([sensor.position, sensor.position, sensor.heading])
    _filter_runs(
        stacked.pose,
        stacked.tracked,
        stacked.gains,
        variance,
        jumps,
        size,
        sigma,
        stacked.residual,
        stacked.mask,
        stacked.samples,
        stacked.intervals,
        runs.start,
        runs.stop,
        out,
    )


@kernel
def _filter_runs(
    pose: FloatArray,
    tracked: FloatArray,
    gains: FloatArray,
    variance: FloatArray,
    jumps: FloatArray,
    size: float,
    sigma: FloatArray,
    residual: FloatArray,
    mask: NDArray[np.bool_],
    samples: NDArray[np.int64],
    intervals: NDArray[np.int64],
    first: int,
    last: int,
    out: FloatArray,
) -> None:
    """:func:`_filter` on runs ``first`` … ``last − 1`` of stacked arrays (run j's samples are
    rows ``samples[j]:samples[j + 1]``, its intervals ``intervals[j]:intervals[j + 1]``), the
    log-likelihood of each into ``out[j]`` (:func:`filter_runs`)."""
    no_expected = np.zeros((0, 2))
    for j in range(first, last):
        a = samples[j]
        b = samples[j + 1]
        c = intervals[j]
        d = intervals[j + 1]
        loglik, _, _ = _filter(
            pose[a:b],
            tracked[a:b],
            gains[c:d],
            variance[c:d],
            jumps[c:d],
            size,
            sigma,
            residual[a:b],
            mask[a:b],
            False,
            True,
            no_expected,
        )
        out[j] = loglik


@dataclass(frozen=True)
class StackedInputs:
    """Every run's replay and :class:`FilterInputs` stacked, for :func:`filter_runs`.

    Attributes:
        pose, tracked: the replays' axle and tracked poses (ΣT, 3).
        gains: the wheel gains (Σn, 2, 3).
        residual: the residuals (ΣT, 3).
        mask: the measured components (ΣT, 3).
        samples: run j's samples are rows ``samples[j]:samples[j + 1]`` (J + 1,).
        intervals: run j's intervals are rows ``intervals[j]:intervals[j + 1]`` (J + 1,).
    """

    pose: FloatArray
    tracked: FloatArray
    gains: FloatArray
    residual: FloatArray
    mask: NDArray[np.bool_]
    samples: NDArray[np.int64]
    intervals: NDArray[np.int64]

    @classmethod
    def of(
        cls,
        replays: list[Replay],
        inputs: list[FilterInputs],
        masks: list[NDArray[np.bool_]],
    ) -> StackedInputs:
        def offsets(lengths: list[int]) -> NDArray[np.int64]:
            return np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)

        def stack(parts: list[FloatArray], shape: tuple[int, ...]) -> FloatArray:
            return np.ascontiguousarray(np.concatenate(parts)) if parts else np.zeros(shape)

        return cls(
            stack([r.pose for r in replays], (0, 3)),
            stack([r.tracked for r in replays], (0, 3)),
            stack([i.gains for i in inputs], (0, 2, 3)),
            stack([i.residual for i in inputs], (0, 3)),
            np.ascontiguousarray(np.concatenate(masks)) if masks else np.zeros((0, 3), bool),
            offsets([len(r.pose) for r in replays]),
            offsets([len(i.gains) for i in inputs]),
        )


@dataclass(frozen=True)
class FilterInputs:
    """What the filter takes from a run and its replay alone, whatever the noise model.

    Attributes:
        residual: :func:`run_residual` (T, 3).
        gains: each wheel's travel mapped to the pose, G = ∂(x, y, θ)/∂(d_L, d_R) (n, 2, 3)
            [m/m, m/m, rad/m], linearised through the midpoint equations at every interval.
    """

    residual: FloatArray
    gains: FloatArray


def filter_inputs(run: Run, replay: Replay, mask: NDArray[np.bool_]) -> FilterInputs:
    """:class:`FilterInputs` of ``run`` replayed as ``replay``, measured where ``mask`` holds."""
    return FilterInputs(run_residual(run, replay, mask), replay_gains(replay))


def replay_gains(replay: Replay) -> FloatArray:
    """How each wheel's travel noise reaches the pose at every sample of ``replay``: G (n, 2,
    3), position [m/m] and heading [rad/m] per metre of a wheel's travel, from the replay's
    axle poses, increments and wheelbase (the ``gains`` of :class:`FilterInputs`)."""
    return _wheel_gains(replay.pose, replay.ds, replay.dtheta, replay.wheelbase)


@inlined_kernel
def _put_gains(gains: FloatArray, m: int, c: float, s: float, ds: float, wheelbase: float) -> None:
    """Interval ``m``'s rows of the wheel gains G (:func:`_wheel_gains`): the midpoint odometry
    equations' derivatives in each wheel's travel, given the cosine ``c`` and sine ``s`` of the
    middle heading, the interval's travel ``ds`` [m] and the wheelbase [m]."""
    half = ds / (2.0 * wheelbase)
    for w in range(2):
        sign = 1.0 if w == 0 else -1.0
        gains[m, w, 0] = 0.5 * c + sign * half * s
        gains[m, w, 1] = 0.5 * s - sign * half * c
        gains[m, w, 2] = -sign / wheelbase


@kernel
def _wheel_gains(
    pose: FloatArray, ds: FloatArray, dtheta: FloatArray, wheelbase: float
) -> FloatArray:
    """G (n, 2, 3) of :class:`FilterInputs` from the axle poses (T, 3), the increments ds [m]
    and dθ [rad] (n,) and the wheelbase [m]: what the filter computed at every sample before
    (a cosine and a sine each), kept once per replay (the same operations, the same bytes)."""
    n = ds.shape[0]
    gains = np.empty((n, 2, 3))
    for m in range(n):
        mid = pose[m, 2] + 0.5 * dtheta[m]
        c = math.cos(mid)
        s = math.sin(mid)
        _put_gains(gains, m, c, s, ds[m], wheelbase)
    return gains


@kernel
def _wheel_gains_of(
    pose: FloatArray,
    ds: FloatArray,
    dtheta: FloatArray,
    wheelbase: float,
    cos_mid: FloatArray,
    sin_mid: FloatArray,
) -> FloatArray:
    """:func:`_wheel_gains` with the cosine and sine of each middle heading given (the
    replay's, :class:`~odomgym.diagnose.replay.StackedReplay`): the same bytes, the cosine
    and sine computed once instead of twice per interval. At a middle heading of zero the
    replay's direction θ + dθ/2 + 0.0 is +0.0 where θ + dθ/2 may be −0.0, whose sine keeps the
    sign: recomputed there."""
    n = ds.shape[0]
    gains = np.empty((n, 2, 3))
    for m in range(n):
        mid = pose[m, 2] + 0.5 * dtheta[m]
        c = cos_mid[m]
        s = sin_mid[m]
        if mid == 0.0:
            c = math.cos(mid)
            s = math.sin(mid)
        _put_gains(gains, m, c, s, ds[m], wheelbase)
    return gains


def run_residual(run: Run, replay: Replay, mask: NDArray[np.bool_]) -> FloatArray:
    """Measured minus predicted tracked pose (T, 3) where ``mask`` holds, else 0; the heading
    difference wrapped to [−π, π) [rad]."""
    measured = np.asarray(run.true_pose, dtype=np.float64)
    predicted = np.asarray(replay.tracked, dtype=np.float64)
    kept = np.asarray(mask, dtype=np.bool_)
    if not (measured.shape == predicted.shape == kept.shape and measured.shape[1:] == (3,)):
        # the compiled pass checks no bounds (numpy's where raised on a mismatch)
        raise ValueError(
            f"run_residual: poses {measured.shape}, replay {predicted.shape} and mask "
            f"{kept.shape} must all be (T, 3)"
        )
    return _pose_residual(measured, predicted, kept)


_TWO_PI = 2.0 * math.pi


@kernel
def _pose_residual(
    measured: FloatArray, predicted: FloatArray, mask: NDArray[np.bool_]
) -> FloatArray:
    """:func:`run_residual` on arrays: numpy's ``np.where(mask, measured − predicted, 0)`` and
    ``np.mod(θ + π, 2π) − π`` written out, element by element the same operations (numpy's
    float remainder: ``fmod``, plus 2π when it is non-zero and negative, +0.0 when it is
    zero). Compiled because a systematic fit computes it for every run at every evaluation, and
    numpy's five passes over the (T, 3) array cost a third of a replay."""
    n = measured.shape[0]
    out = np.empty((n, 3))
    for k in range(n):
        for c in range(3):
            out[k, c] = measured[k, c] - predicted[k, c] if mask[k, c] else 0.0
        mod = np.fmod(out[k, 2] + math.pi, _TWO_PI)
        if mod != 0.0:  # NaN included, as numpy's ``if (mod)``
            if mod < 0.0:
                mod += _TWO_PI
        else:
            mod = 0.0
        out[k, 2] = mod - math.pi
    return out


def _model_arrays(
    replay: Replay,
    spec: RobotSpec,
    sensor: SensorNoise,
    gains: FloatArray | None = None,
    noise: ProcessNoise | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, float, FloatArray]:
    """The replay's motion, ``spec``'s process noise and ``sensor``'s sigmas in the order the
    compiled ``_filter`` takes them (it accepts arrays and scalars only); ``gains`` and
    ``noise``: the replay's :class:`FilterInputs` gains and :func:`process_noise` if the caller
    has them."""
    variance, jumps, size = process_noise(spec, replay.travel) if noise is None else noise
    return (
        replay.pose,
        replay.tracked,
        replay_gains(replay) if gains is None else gains,
        variance,
        jumps,
        size,
        np.array([sensor.position, sensor.position, sensor.heading]),
    )


def expected_square_gap(
    run: Run, replay: Replay, spec: RobotSpec, sensor: SensorNoise, mask: NDArray[np.bool_]
) -> FloatArray:
    """E|measured − predicted position|² [m²] and E(heading disagreement)² [rad²] at every
    sample (T, 2) (NaN where not in ``mask``) if the model were right: what noise alone leaves
    (the sensor, wheel noise, heading jumps as their variance), propagated open loop from the
    start."""
    expected = np.full((len(run.time), 2), np.nan)
    _filter(
        *_model_arrays(replay, spec, sensor),
        np.zeros((len(run.time), 3)),
        mask,
        True,
        False,
        expected,
    )
    return expected


@inlined_kernel
def _propagate(mat: FloatArray, ux: float, uy: float) -> None:
    """mat ← F·mat·Fᵀ in place for F = I + u·e_θᵀ, u = (ux, uy, 0): a heading error moves later
    positions by δθ × displacement. Scalar code: this runs once per logged sample."""
    p20 = mat[2, 0]
    p21 = mat[2, 1]
    p22 = mat[2, 2]
    mat[0, 0] += 2.0 * ux * p20 + ux * ux * p22
    mat[1, 1] += 2.0 * uy * p21 + uy * uy * p22
    mat[0, 1] += ux * p21 + uy * p20 + ux * uy * p22
    mat[1, 0] = mat[0, 1]
    mat[0, 2] += ux * p22
    mat[2, 0] = mat[0, 2]
    mat[1, 2] += uy * p22
    mat[2, 1] = mat[1, 2]


@inlined_kernel
def _add_outer(mat: FloatArray, weight: float, gx: float, gy: float, gt: float) -> None:
    """mat += weight·g·gᵀ in place, g = (gx, gy, gt)."""
    mat[0, 0] += weight * gx * gx
    mat[1, 1] += weight * gy * gy
    mat[2, 2] += weight * gt * gt
    mat[0, 1] += weight * gx * gy
    mat[1, 0] = mat[0, 1]
    mat[0, 2] += weight * gx * gt
    mat[2, 0] = mat[0, 2]
    mat[1, 2] += weight * gy * gt
    mat[2, 1] = mat[1, 2]


@inlined_kernel
def _small_cholesky(mat: FloatArray, dim: int, out: FloatArray) -> None:
    """Lower Cholesky factor of the leading ``dim`` × ``dim`` block of ``mat`` into ``out``
    (dim ≤ 3; a non-positive pivot is floored at 1e-300): the factor of :func:`_gauss_update`
    and :func:`_mixture_level`."""
    for a in range(dim):
        for b in range(a + 1):
            acc = mat[a, b]
            for c in range(b):
                acc -= out[a, c] * out[b, c]
            if a == b:
                out[a, a] = math.sqrt(max(acc, 1e-300))
            else:
                out[a, b] = acc / out[b, b]


@inlined_kernel
def _gauss_update(
    prior: FloatArray,
    mean: FloatArray,
    h: FloatArray,
    nu: FloatArray,
    rdiag: FloatArray,
    dim: int,
    work: FloatArray,
    sol: FloatArray,
    s_nu: FloatArray,
    out_mean: FloatArray,
    out_cov: FloatArray,
) -> float:
    """One Kalman update with the first ``dim`` rows of ``h`` (measurement noise ``rdiag``,
    innovation ``nu``), written out for at most three rows without temporaries; returns the
    innovation's log density, leaves the whitened innovation L⁻¹ν in ``sol`` and the posterior
    in ``out_mean``, ``out_cov``. ``work`` (4, 3, 3) and ``s_nu`` (3,) are scratch space."""
    hp = work[0]  # H·P (dim × 3)
    s_mat = work[1]  # H·P·Hᵀ + R
    chol = work[2]  # its Cholesky factor
    x = work[3]  # S⁻¹·H·P
    for a in range(dim):
        for b in range(3):
            hp[a, b] = h[a, 0] * prior[0, b] + h[a, 1] * prior[1, b] + h[a, 2] * prior[2, b]
    for a in range(dim):
        for b in range(dim):
            s_mat[a, b] = hp[a, 0] * h[b, 0] + hp[a, 1] * h[b, 1] + hp[a, 2] * h[b, 2]
        s_mat[a, a] += rdiag[a]
    _small_cholesky(s_mat, dim, chol)
    logdet = 0.0
    for a in range(dim):
        logdet += 2.0 * math.log(chol[a, a])
    quad = 0.0
    for a in range(dim):  # forward substitution: L·sol = ν
        acc = nu[a]
        for c in range(a):
            acc -= chol[a, c] * sol[c]
        sol[a] = acc / chol[a, a]
        quad += sol[a] * sol[a]
    for b in range(3):  # X = S⁻¹·(H·P), column by column: L·y = hp, Lᵀ·x = y
        for a in range(dim):
            acc = hp[a, b]
            for c in range(a):
                acc -= chol[a, c] * x[c, b]
            x[a, b] = acc / chol[a, a]
        for a in range(dim - 1, -1, -1):
            acc = x[a, b]
            for c in range(a + 1, dim):
                acc -= chol[c, a] * x[c, b]
            x[a, b] = acc / chol[a, a]
    # Gain K = (H·P)ᵀ·S⁻¹: posterior mean + (H·P)ᵀ·S⁻¹ν, covariance P − (H·P)ᵀ·S⁻¹·(H·P).
    for a in range(dim - 1, -1, -1):  # S⁻¹ν: back substitution Lᵀ·s_nu = sol
        acc = sol[a]
        for c in range(a + 1, dim):
            acc -= chol[c, a] * s_nu[c]
        s_nu[a] = acc / chol[a, a]
    for a in range(3):
        out_mean[a] = mean[a]
        for c in range(dim):
            out_mean[a] += hp[c, a] * s_nu[c]
        for b in range(3):
            acc = prior[a, b]
            for c in range(dim):
                acc -= hp[c, a] * x[c, b]
            out_cov[a, b] = acc
    return -0.5 * (dim * math.log(2.0 * math.pi) + logdet + quad)


@inlined_kernel
def _forward3(
    b0: float, b1: float, b2: float,
    l00: float, l10: float, l11: float, l20: float, l21: float, l22: float,
) -> tuple[float, float, float]:  # fmt: skip
    """L⁻¹·b for the lower-triangular 3×3 factor L (forward substitution, in
    :func:`_gauss_update`'s order of operations)."""
    y0 = b0 / l00
    y1 = (b1 - l10 * y0) / l11
    y2 = (b2 - l20 * y0 - l21 * y1) / l22
    return y0, y1, y2


@inlined_kernel
def _back3(
    y0: float, y1: float, y2: float,
    l00: float, l10: float, l11: float, l20: float, l21: float, l22: float,
) -> tuple[float, float, float]:  # fmt: skip
    """L⁻ᵀ·y (back substitution, in :func:`_gauss_update`'s order of operations)."""
    x2 = y2 / l22
    x1 = (y1 - l21 * x2) / l11
    x0 = (y0 - l10 * x1 - l20 * x2) / l00
    return x0, x1, x2


# What _update3 returns: the innovation's log density, the whitened innovation (3), the
# posterior mean (3) and the posterior covariance row by row (9).
_Update3 = tuple[
    float, float, float, float, float, float, float, float,
    float, float, float, float, float, float, float, float,
]  # fmt: skip


@inlined_kernel
def _update3(
    p00: float, p01: float, p02: float,
    p10: float, p11: float, p12: float,
    p20: float, p21: float, p22: float,
    m0: float, m1: float, m2: float,
    ox: float, oy: float,
    r0: float, r1: float, r2: float,
    z0: float, z1: float, z2: float,
) -> _Update3:  # fmt: skip
    """:func:`_gauss_update` for all three pose components measured, on scalars: prior P
    (p00…p22), mean m, the tracked point's offset (ox, oy) [m] from the axle, measurement
    variances r [m², m², rad²] and the measured residual z.

    Why a second copy: held in scalars, the state stays in registers, where the array version
    goes through memory at every step because the compiler must assume the arrays alias
    (~2.5× less filter time). Bit-identical to :func:`_gauss_update` with ``dim`` 3: the same
    operations in the same order, the products with H's zeros and ones included (they decide
    the sign of a zero and carry a NaN), which ``tests/test_diagnose_speed.py`` checks on
    random and degenerate priors and through the whole filter."""
    h02 = -oy
    h12 = ox
    n0 = z0 - (1.0 * m0 + 0.0 * m1 + h02 * m2)
    n1 = z1 - (0.0 * m0 + 1.0 * m1 + h12 * m2)
    n2 = z2 - (0.0 * m0 + 0.0 * m1 + 1.0 * m2)
    # H·P
    a00 = 1.0 * p00 + 0.0 * p10 + h02 * p20
    a01 = 1.0 * p01 + 0.0 * p11 + h02 * p21
    a02 = 1.0 * p02 + 0.0 * p12 + h02 * p22
    a10 = 0.0 * p00 + 1.0 * p10 + h12 * p20
    a11 = 0.0 * p01 + 1.0 * p11 + h12 * p21
    a12 = 0.0 * p02 + 1.0 * p12 + h12 * p22
    a20 = 0.0 * p00 + 0.0 * p10 + 1.0 * p20
    a21 = 0.0 * p01 + 0.0 * p11 + 1.0 * p21
    a22 = 0.0 * p02 + 0.0 * p12 + 1.0 * p22
    # S = H·P·Hᵀ + R (lower triangle)
    s00 = a00 * 1.0 + a01 * 0.0 + a02 * h02
    s00 += r0
    s10 = a10 * 1.0 + a11 * 0.0 + a12 * h02
    s11 = a10 * 0.0 + a11 * 1.0 + a12 * h12
    s11 += r1
    s20 = a20 * 1.0 + a21 * 0.0 + a22 * h02
    s21 = a20 * 0.0 + a21 * 1.0 + a22 * h12
    s22 = a20 * 0.0 + a21 * 0.0 + a22 * 1.0
    s22 += r2
    l00 = math.sqrt(max(s00, 1e-300))
    logdet = 0.0 + 2.0 * math.log(l00)
    l10 = s10 / l00
    l11 = math.sqrt(max(s11 - l10 * l10, 1e-300))
    logdet += 2.0 * math.log(l11)
    l20 = s20 / l00
    l21 = (s21 - l20 * l10) / l11
    l22 = math.sqrt(max(s22 - l20 * l20 - l21 * l21, 1e-300))
    logdet += 2.0 * math.log(l22)
    w0, w1, w2 = _forward3(n0, n1, n2, l00, l10, l11, l20, l21, l22)  # the whitened innovation L⁻¹ν
    quad = 0.0 + w0 * w0
    quad += w1 * w1
    quad += w2 * w2
    # X = S⁻¹·(H·P), column by column; S⁻¹ν = L⁻ᵀ·(L⁻¹ν).
    y0, y1, y2 = _forward3(a00, a10, a20, l00, l10, l11, l20, l21, l22)
    x00, x10, x20 = _back3(y0, y1, y2, l00, l10, l11, l20, l21, l22)
    y0, y1, y2 = _forward3(a01, a11, a21, l00, l10, l11, l20, l21, l22)
    x01, x11, x21 = _back3(y0, y1, y2, l00, l10, l11, l20, l21, l22)
    y0, y1, y2 = _forward3(a02, a12, a22, l00, l10, l11, l20, l21, l22)
    x02, x12, x22 = _back3(y0, y1, y2, l00, l10, l11, l20, l21, l22)
    t0, t1, t2 = _back3(w0, w1, w2, l00, l10, l11, l20, l21, l22)
    # Posterior mean m + (H·P)ᵀ·S⁻¹ν and covariance P − (H·P)ᵀ·X, in _gauss_update's order.
    q0 = m0 + a00 * t0 + a10 * t1 + a20 * t2
    q1 = m1 + a01 * t0 + a11 * t1 + a21 * t2
    q2 = m2 + a02 * t0 + a12 * t1 + a22 * t2
    c00 = p00 - a00 * x00 - a10 * x10 - a20 * x20
    c01 = p01 - a00 * x01 - a10 * x11 - a20 * x21
    c02 = p02 - a00 * x02 - a10 * x12 - a20 * x22
    c10 = p10 - a01 * x00 - a11 * x10 - a21 * x20
    c11 = p11 - a01 * x01 - a11 * x11 - a21 * x21
    c12 = p12 - a01 * x02 - a11 * x12 - a21 * x22
    c20 = p20 - a02 * x00 - a12 * x10 - a22 * x20
    c21 = p21 - a02 * x01 - a12 * x11 - a22 * x21
    c22 = p22 - a02 * x02 - a12 * x12 - a22 * x22
    fit = -0.5 * (3 * math.log(2.0 * math.pi) + logdet + quad)
    return (fit, w0, w1, w2, q0, q1, q2, c00, c01, c02, c10, c11, c12, c20, c21, c22)


@inlined_kernel
def _component_update(
    c00: float, c01: float, c02: float,
    c10: float, c11: float, c12: float,
    c20: float, c21: float, c22: float,
    v1: FloatArray, jumps: int,
    m0: float, m1: float, m2: float,
    ox: float, oy: float,
    r0: float, r1: float, r2: float,
    residual: FloatArray, k: int,
) -> _Update3:  # fmt: skip
    """:func:`_update3` of the jump mixture's component with ``jumps`` jumps since the last
    update at sample ``k``: prior c + jumps·v1 as the array path forms it (for no jump
    c + 0·v1, which is c but for the sign of a zero)."""
    return _update3(
        c00 + jumps * v1[0, 0], c01 + jumps * v1[0, 1], c02 + jumps * v1[0, 2],
        c10 + jumps * v1[1, 0], c11 + jumps * v1[1, 1], c12 + jumps * v1[1, 2],
        c20 + jumps * v1[2, 0], c21 + jumps * v1[2, 1], c22 + jumps * v1[2, 2],
        m0, m1, m2, ox, oy, r0, r1, r2,
        residual[k, 0], residual[k, 1], residual[k, 2],
    )  # fmt: skip


_Entries = tuple[float, float, float, float, float, float, float, float, float]


@inlined_kernel
def _entries(mat: FloatArray) -> _Entries:
    """A 3×3 matrix's nine entries, row by row (to hold it in scalars)."""
    return (
        mat[0, 0], mat[0, 1], mat[0, 2],
        mat[1, 0], mat[1, 1], mat[1, 2],
        mat[2, 0], mat[2, 1], mat[2, 2],
    )  # fmt: skip


_SQRT2 = math.sqrt(2.0)
_SQRT_2_OVER_PI = math.sqrt(2.0 / math.pi)


@inlined_kernel
def _chi2_cdf(q: float, dim: int) -> float:
    """P(χ²_dim ≤ q) for dim = 1, 2, 3, in closed form (Abramowitz & Stegun 1964, 26.4.4–5:
    erf for one degree of freedom, the exponential for two, erf less a Gaussian term for three):
    the probability a Gaussian predictive distribution gives its ellipsoid through a point whose
    squared Mahalanobis distance is ``q``."""
    if math.isnan(q):
        return math.nan
    if not q > 0.0:
        return 0.0
    r = math.sqrt(q)
    if dim == 1:
        return math.erf(r / _SQRT2)
    if dim == 2:
        return 1.0 - math.exp(-0.5 * q)
    return math.erf(r / _SQRT2) - _SQRT_2_OVER_PI * r * math.exp(-0.5 * q)


@inlined_kernel
def _solve_lower(chol: FloatArray, dim: int, b: FloatArray, out: FloatArray) -> float:
    """out = L⁻¹·b (forward substitution over ``dim`` rows); returns |out|²."""
    total = 0.0
    for a in range(dim):
        acc = b[a]
        for c in range(a):
            acc -= chol[a, c] * out[c]
        out[a] = acc / chol[a, a]
        total += out[a] * out[a]
    return total


@inlined_kernel
def _mixture_level(
    prior: FloatArray,
    v1: FloatArray,
    h: FloatArray,
    rdiag: FloatArray,
    nu: FloatArray,
    dim: int,
    weights: FloatArray,
    n_comp: int,
    draws: FloatArray,
    work: FloatArray,
) -> float:
    """The probability the jump mixture's predictive distribution gives the ellipsoid of its
    moment-matched covariance through the innovation ``nu``: Σ_j w_j · P(x_jᵀ S̄⁻¹ x_j ≤
    νᵀ S̄⁻¹ ν), x_j ~ N(0, S_j), S_j = H (P + j·V₁) Hᵀ + R, S̄ = Σ_j w_j S_j. Each component's
    probability is the share of the fixed standard-normal ``draws`` (M, 3) mapped through its
    Cholesky factor that fall inside (a Poisson scale mixture has no closed form); a Gaussian
    predictive (no jump expected) takes :func:`_chi2_cdf` instead. ``work`` (6, 3, 3) is
    scratch space."""
    base = work[0]  # H·P·Hᵀ + R
    step = work[1]  # H·V₁·Hᵀ
    mean_cov = work[2]  # S̄
    chol_mean = work[3]
    chol_j = work[4]
    vec = work[5]  # rows 0 and 1: two scratch vectors
    for a in range(dim):
        for b in range(dim):
            acc_p = 0.0
            acc_v = 0.0
            for c in range(3):
                for d in range(3):
                    acc_p += h[a, c] * prior[c, d] * h[b, d]
                    acc_v += h[a, c] * v1[c, d] * h[b, d]
            base[a, b] = acc_p + (rdiag[a] if a == b else 0.0)
            step[a, b] = acc_v
    expected_jumps = 0.0
    for j in range(n_comp):
        expected_jumps += weights[j] * j
    for a in range(dim):
        for b in range(dim):
            mean_cov[a, b] = base[a, b] + expected_jumps * step[a, b]
    _small_cholesky(mean_cov, dim, chol_mean)
    observed = _solve_lower(chol_mean, dim, nu, vec[0])
    if math.isnan(observed):
        return math.nan
    level = 0.0
    count = draws.shape[0]
    for j in range(n_comp):
        for a in range(dim):
            for b in range(dim):
                mean_cov[a, b] = base[a, b] + j * step[a, b]
        _small_cholesky(mean_cov, dim, chol_j)
        inside = 0
        for m in range(count):
            for a in range(dim):
                acc = 0.0
                for c in range(a + 1):
                    acc += chol_j[a, c] * draws[m, c]
                vec[1, a] = acc
            if _solve_lower(chol_mean, dim, vec[1], vec[0]) <= observed:
                inside += 1
        level += weights[j] * inside / count
    return level


@kernel
def _filter(
    pose: FloatArray,
    tracked: FloatArray,
    gains: FloatArray,
    variance: FloatArray,
    jumps: FloatArray,
    size: float,
    sigma: FloatArray,
    residual: FloatArray,
    mask: NDArray[np.bool_],
    gaussian_jumps: bool,
    update: bool,
    expected: FloatArray,
    scalar: bool = True,
    levels: FloatArray | None = None,
    draws: FloatArray | None = None,
) -> tuple[float, FloatArray, int]:
    """The filter of the module docstring over one run: log-likelihood (``update``), whitened
    innovations (3T,) and the count of measured values; with ``update`` False, the open-loop
    expected squared gap into ``expected`` instead. ``gains``: the replay's wheel gains G
    (n, 2, 3) of :class:`FilterInputs`; ``variance``, ``jumps``, ``size``: the process noise
    of :func:`process_noise`; ``sigma``: the sensor's σ (x, y [m], θ [rad]).

    The state (covariance, mean) is held in scalars between samples, and a sample with all
    three components measured and no jump mixture takes the scalar update :func:`_update3`
    and a one-component collapse written out (exp(0) = 1, log(1) = 0 exactly, so skipping
    them changes no bit). ``scalar`` False takes the array path of :func:`_gauss_update`
    everywhere instead: the reference the tests hold the fast one to, bit for bit.

    ``levels`` (T,) and ``draws`` (M, 3), given together (:func:`run_predictive`): at every
    measured sample, ``levels`` receives the probability the one-step predictive distribution
    gives the smallest ellipsoid of its covariance that holds the observed innovation — a
    region's coverage level, uniform on [0, 1] when the model is right (Rosenblatt 1952); the
    jump mixture's is estimated on the standard-normal ``draws`` (:func:`_mixture_level`). Left
    out, the function compiles without that code (numba prunes branches on an absent argument).

    One piece, not split into a propagation and an update kernel: the state lives in scalars
    across both (see above), and a call boundary between them would cost it its registers."""
    n_samples = pose.shape[0]
    if levels is not None:
        level_work = np.zeros((6, 3, 3))
    else:
        level_work = np.zeros((0, 3, 3))
    whitened = np.zeros(3 * n_samples)
    count = 0
    loglik = 0.0
    # Initial covariance: the first measured pose's noise, mapped from the tracked point to the
    # axle (δ_axle = H⁻¹·δ_tracked with H the offset coupling below).
    ox = tracked[0, 0] - pose[0, 0]
    oy = tracked[0, 1] - pose[0, 1]
    hinv = np.eye(3)
    hinv[0, 2] = oy
    hinv[1, 2] = -ox
    r0 = np.diag(sigma**2)
    cov = hinv @ r0 @ hinv.T
    # The state: covariance c (row by row) and mean m, in scalars (see the docstring); ``cov``
    # and ``mean`` hold them only while the array path runs.
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = _entries(cov)
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    mean = np.zeros(3)
    a0 = 0.0  # expected jumps since the last update
    vacc = np.zeros((3, 3))  # Σ μ·(Φg)(Φg)ᵀ of those jumps, propagated to the current sample
    rows = np.zeros(3, dtype=np.int64)
    h = np.zeros((3, 3))
    nu = np.zeros(3)
    rdiag = np.zeros(3)
    v1 = np.zeros((3, 3))
    prior = np.zeros((3, 3))
    work = np.zeros((4, 3, 3))
    sol = np.zeros(3)
    s_nu = np.zeros(3)
    weights = np.zeros(_MAX_JUMPS + 1)
    logs = np.zeros(_MAX_JUMPS + 1)
    shares = np.zeros(_MAX_JUMPS + 1)
    means = np.zeros((_MAX_JUMPS + 1, 3))
    covs = np.zeros((_MAX_JUMPS + 1, 3, 3))
    r_x = sigma[0] ** 2
    r_y = sigma[1] ** 2
    r_t = sigma[2] ** 2
    k = 0
    while k < n_samples - 1:
        k += 1
        # Sample after sample up to the next measured one (or the last), in a loop of its own:
        # there the compiler keeps more of the state in registers than in the loop with the
        # update (48 against 57 µs for a 2 455-sample run propagated without updates).
        while True:
            m = k - 1
            # δ ← F·δ, P ← F·P·Fᵀ + G·Q·Gᵀ with F = I + u·e_θᵀ, u = (−Δy, Δx, 0): the operations of
            # _propagate and _add_outer on the scalar state (this loop runs once per logged sample).
            ux = -(pose[k, 1] - pose[m, 1])
            uy = pose[k, 0] - pose[m, 0]
            m0 += ux * m2
            m1 += uy * m2
            p20 = c20
            p21 = c21
            p22 = c22
            c00 += 2.0 * ux * p20 + ux * ux * p22
            c11 += 2.0 * uy * p21 + uy * uy * p22
            c01 += ux * p21 + uy * p20 + ux * uy * p22
            c10 = c01
            c02 += ux * p22
            c20 = c02
            c12 += uy * p22
            c21 = c12
            if a0 > 0.0:
                _propagate(vacc, ux, uy)
            for w in range(2):
                var = variance[m, w]
                mu = jumps[m, w]
                if mu > 0.0 and gaussian_jumps:
                    var += mu * size * size
                if var == 0.0 and mu == 0.0:
                    continue
                gx = gains[m, w, 0]
                gy = gains[m, w, 1]
                gt = gains[m, w, 2]
                if var > 0.0:
                    c00 += var * gx * gx
                    c11 += var * gy * gy
                    c22 += var * gt * gt
                    c01 += var * gx * gy
                    c10 = c01
                    c02 += var * gx * gt
                    c20 = c02
                    c12 += var * gy * gt
                    c21 = c12
                if mu > 0.0 and not gaussian_jumps:
                    a0 += mu
                    _add_outer(vacc, mu * size * size, gx, gy, gt)
            if mask[k, 0] or mask[k, 1] or mask[k, 2] or k == n_samples - 1:
                break
            k += 1
        if not (mask[k, 0] or mask[k, 1] or mask[k, 2]):
            continue  # the last sample, not measured: the loop ends
        ox = tracked[k, 0] - pose[k, 0]
        oy = tracked[k, 1] - pose[k, 1]
        if not update:
            # Open loop: the expected squared position disagreement (tracked point) from
            # noise alone, E|z_xy|² = tr(H P Hᵀ)_xy + 2σ², jumps as their variance.
            vx = c00 - 2.0 * oy * c02 + oy * oy * c22
            vy = c11 + 2.0 * ox * c12 + ox * ox * c22
            expected[k, 0] = vx + vy + sigma[0] ** 2 + sigma[1] ** 2
            expected[k, 1] = c22 + sigma[2] ** 2
            continue
        mixture = a0 > 0.0 and not gaussian_jumps
        if scalar and mask[k, 0] and mask[k, 1] and mask[k, 2] and not mixture:
            # The usual case (all three components measured, no jump expected): one update
            # and the collapse of a one-component mixture, its weight exactly 1 when the
            # log density is finite (else the general expressions, which carry the NaN).
            (fit, w0, w1, w2, q0, q1, q2, d00, d01, d02, d10, d11, d12, d20, d21, d22) = (
                _component_update(
                    c00, c01, c02, c10, c11, c12, c20, c21, c22, v1, 0,
                    m0, m1, m2, ox, oy, r_x, r_y, r_t, residual, k,
                )
            )  # fmt: skip
            logs0 = math.log(1.0) + fit
            if levels is not None:
                levels[k] = _chi2_cdf(w0 * w0 + w1 * w1 + w2 * w2, 3)
            whitened[3 * k] = w0
            whitened[3 * k + 1] = w1
            whitened[3 * k + 2] = w2
            if math.isfinite(logs0):
                loglik += logs0 + 0.0
                weight = 1.0
            else:
                top = max(-math.inf, logs0)
                total = 0.0 + math.exp(logs0 - top)
                loglik += top + math.log(total)
                weight = math.exp(logs0 - top) / total
            m0 = 0.0 + weight * q0
            m1 = 0.0 + weight * q1
            m2 = 0.0 + weight * q2
            e0 = q0 - m0
            e1 = q1 - m1
            e2 = q2 - m2
            c00 = 0.0 + weight * (d00 + e0 * (q0 - m0))
            c01 = 0.0 + weight * (d01 + e0 * (q1 - m1))
            c02 = 0.0 + weight * (d02 + e0 * (q2 - m2))
            c10 = 0.0 + weight * (d10 + e1 * (q0 - m0))
            c11 = 0.0 + weight * (d11 + e1 * (q1 - m1))
            c12 = 0.0 + weight * (d12 + e1 * (q2 - m2))
            c20 = 0.0 + weight * (d20 + e2 * (q0 - m0))
            c21 = 0.0 + weight * (d21 + e2 * (q1 - m1))
            c22 = 0.0 + weight * (d22 + e2 * (q2 - m2))
            sym = 0.5 * (c01 + c10)
            c01 = sym
            c10 = sym
            sym = 0.5 * (c02 + c20)
            c02 = sym
            c20 = sym
            sym = 0.5 * (c12 + c21)
            c12 = sym
            c21 = sym
            count += 3
            continue
        # Otherwise the array path: measured rows, the jump mixture, the general collapse.
        # Work arrays are preallocated (this runs once per measured sample).
        cov[0, 0] = c00
        cov[0, 1] = c01
        cov[0, 2] = c02
        cov[1, 0] = c10
        cov[1, 1] = c11
        cov[1, 2] = c12
        cov[2, 0] = c20
        cov[2, 1] = c21
        cov[2, 2] = c22
        mean[0] = m0
        mean[1] = m1
        mean[2] = m2
        dim = 0
        for j in range(3):
            if mask[k, j]:
                rows[dim] = j
                dim += 1
        for a in range(dim):
            j = rows[a]
            for b in range(3):
                h[a, b] = 0.0
            h[a, j] = 1.0
            if j == 0:
                h[a, 2] = -oy
            elif j == 1:
                h[a, 2] = ox
            nu[a] = residual[k, j] - (h[a, 0] * mean[0] + h[a, 1] * mean[1] + h[a, 2] * mean[2])
            rdiag[a] = sigma[j] ** 2
        n_comp = 1
        weights[0] = 1.0
        if mixture:
            # Jump mixture: v1 = the covariance one jump since the last update adds.
            n_comp = _MAX_JUMPS + 1
            total = 0.0
            term = math.exp(-a0)
            for j in range(n_comp):
                weights[j] = term
                total += term
                term = term * a0 / (j + 1)
            for j in range(n_comp):
                weights[j] /= total
            for a in range(3):
                for b in range(3):
                    v1[a, b] = vacc[a, b] / a0
            a0 = 0.0
            vacc[:, :] = 0.0
        top = -math.inf
        for j in range(n_comp):
            post_mean, post_cov = means[j], covs[j]
            if dim == 3 and scalar:
                (
                    fit,
                    sol[0],
                    sol[1],
                    sol[2],
                    means[j, 0],
                    means[j, 1],
                    means[j, 2],
                    covs[j, 0, 0],
                    covs[j, 0, 1],
                    covs[j, 0, 2],
                    covs[j, 1, 0],
                    covs[j, 1, 1],
                    covs[j, 1, 2],
                    covs[j, 2, 0],
                    covs[j, 2, 1],
                    covs[j, 2, 2],
                ) = _component_update(
                    c00, c01, c02, c10, c11, c12, c20, c21, c22, v1, j,
                    m0, m1, m2, ox, oy, r_x, r_y, r_t, residual, k,
                )  # fmt: skip
            else:
                for a in range(3):
                    for b in range(3):
                        prior[a, b] = cov[a, b] + j * v1[a, b]
                fit = _gauss_update(
                    prior, mean, h, nu, rdiag, dim, work, sol, s_nu, post_mean, post_cov
                )
            logs[j] = math.log(weights[j]) + fit
            if j == 0:
                for a in range(dim):
                    whitened[3 * k + rows[a]] = sol[a]
            top = max(top, logs[j])
        if levels is not None:
            if not mixture:
                quad = 0.0
                for a in range(dim):
                    quad += sol[a] * sol[a]
                levels[k] = _chi2_cdf(quad, dim)
            elif draws is not None:
                levels[k] = _mixture_level(
                    cov, v1, h, rdiag, nu, dim, weights, n_comp, draws, level_work
                )
        total = 0.0
        for j in range(n_comp):
            shares[j] = math.exp(logs[j] - top)  # once: each is read three times
            total += shares[j]
        loglik += top + math.log(total)
        for a in range(3):
            mean[a] = 0.0
            for b in range(3):
                cov[a, b] = 0.0
        for j in range(n_comp):
            weight = shares[j] / total
            for a in range(3):
                mean[a] += weight * means[j, a]
        for j in range(n_comp):
            weight = shares[j] / total
            for a in range(3):
                da = means[j, a] - mean[a]
                for b in range(3):
                    cov[a, b] += weight * (covs[j, a, b] + da * (means[j, b] - mean[b]))
        for a in range(3):
            for b in range(a + 1, 3):
                sym = 0.5 * (cov[a, b] + cov[b, a])
                cov[a, b] = sym
                cov[b, a] = sym
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = _entries(cov)
        m0 = mean[0]
        m1 = mean[1]
        m2 = mean[2]
        count += dim
    return loglik, whitened, count

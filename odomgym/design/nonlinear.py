"""The replay behind the linear model: nonlinear measurements and a relinearised estimate.

The linear model of :mod:`~odomgym.design.model` is exact for its own data. A robot
at the prior's upper sizes moves its measured poses far from J·θ (a turn skid of 0.75 s²/m
puts a 0.5 m circle's poses 0.2 m off the linear prediction, against a 1 mm sensor), so real
runs need the replay itself: :class:`ReplayModel` measures a robot through
:func:`odomgym.diagnose.replay.replay_run` (plus the same noise R), and
:func:`relinearised_estimate` is Gauss–Newton on the subset posterior — the model relinearised
around the last estimate, y − f(θ̂) + J(θ̂)·θ̂ ≈ J(θ̂)·θ + e, a few times (the iterated
extended Kalman filter's measurement update for a constant state, Bell & Cathey 1993).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from odomgym.design.menu import item_run
from odomgym.design.model import EVERY, FD_STEPS, LinearModel, sample_rows
from odomgym.design.posterior import SubsetPrior, subset_posteriors
from odomgym.design.prior import (
    ALWAYS,
    DEFAULT_PRIOR,
    PARAMETERS,
    DesignPrior,
    columns_of,
    spec_of,
)
from odomgym.diagnose.generate import NOMINAL_ROBOT
from odomgym.diagnose.replay import RunInputs, replay_run
from odomgym.odometry.runs import Run
from odomgym.selfcal.estimators import CLIP_PRIORS

__all__ = ["ReplayModel", "laplace_estimate", "relinearised_estimate"]

FloatArray = NDArray[np.float64]
ONE_SIDED = np.array([one for _, one in FD_STEPS])


def clip_to_catalogue(theta: FloatArray, prior: DesignPrior = DEFAULT_PRIOR) -> FloatArray:
    """θ with the one-sided parameters (turn-skid gain, backlash width) kept ≥ 0 and every
    parameter within :data:`CLIP_PRIORS` times the prior's largest size [unit] — as the
    self-calibration estimators keep theirs (:data:`odomgym.selfcal.estimators.CLIP_PRIORS`):
    a Gauss–Newton step from a schedule that hardly sees a parameter can otherwise leave the
    robots a spec can describe (E_d ≤ 0 was seen)."""
    bound = np.zeros(len(PARAMETERS))
    for j, g in zip(ALWAYS, prior.geometry, strict=True):
        bound[j] = g.half_range
    for e in prior.effects:
        bound[list(columns_of(e.effect))] = e.high
    out: FloatArray = np.clip(
        np.array(theta, dtype=float), -CLIP_PRIORS * bound, CLIP_PRIORS * bound
    )
    out[ONE_SIDED] = np.maximum(out[ONE_SIDED], 0.0)
    return out


class ReplayModel:
    """Every menu item's run, replayed: the measured poses of any robot θ and their Jacobian.

    Args:
        model: the linear model (its items, in order, and their noise R).
        every: samples between measured poses (as the linear model's).
    """

    def __init__(self, model: LinearModel, every: int = EVERY) -> None:
        self.model = model
        self._runs: list[tuple[Run, RunInputs, NDArray[np.intp]]] = []
        for m in model.items:
            run = item_run(m.item.experiment)
            inputs = RunInputs.of(run, NOMINAL_ROBOT.ticks_per_rev)
            self._runs.append((run, inputs, sample_rows(run, every)))
        self._nominal = [self.poses(i, np.zeros(len(PARAMETERS))) for i in range(len(self._runs))]

    def poses(self, item: int, theta: FloatArray) -> FloatArray:
        """The tracked poses (m,) of item ``item`` driven by the robot θ (noise-free)."""
        run, inputs, rows = self._runs[item]
        out: FloatArray = replay_run(run, spec_of(theta), inputs).tracked[rows].reshape(-1)
        return out

    def predict(self, item: int, theta: FloatArray) -> FloatArray:
        """f(θ) − f(0) (m,): what the linear model approximates by J·θ."""
        out: FloatArray = self.poses(item, theta) - self._nominal[item]
        return out

    def jacobian(self, item: int, theta: FloatArray) -> FloatArray:
        """d f/dθ at θ (m, 8): central differences of the linear model's steps; a one-sided
        parameter is differenced upward from max(θ_j, 0)."""
        base = clip_to_catalogue(theta, self.model.prior)
        columns = []
        for j, (h, one_sided) in enumerate(FD_STEPS):
            up, down = base.copy(), base.copy()
            if one_sided:
                up[j] = base[j] + 2.0 * h
            else:
                up[j], down[j] = base[j] + h, base[j] - h
            columns.append((self.poses(item, up) - self.poses(item, down)) / (2.0 * h))
        return np.array(columns).T

    def measure(self, item: int, theta: FloatArray, rng: np.random.Generator) -> FloatArray:
        """A measurement (m,) of the robot θ: f(θ) − f(0) plus noise from the item's R (the
        same standard normals as :meth:`ItemModel.measure` draws)."""
        m = self.model.items[item]
        noise: FloatArray = m.chol @ rng.standard_normal(m.size)
        return self.predict(item, theta) + noise


def _objective(
    replay: ReplayModel,
    taken: list[int],
    measurements: list[FloatArray],
    theta: FloatArray,
    columns: NDArray[np.intp],
    mean: FloatArray,
    var: FloatArray,
) -> float:
    """The negative log posterior of θ up to a constant: the whitened misfit of the replayed
    runs plus the Gaussian prior of the parameters in ``columns``."""
    misfit = 0.0
    predicted: dict[int, FloatArray] = {}
    for item, y in zip(taken, measurements, strict=True):
        if item not in predicted:
            predicted[item] = replay.predict(item, theta)
        r = replay.model.items[item].whiten @ (y - predicted[item])
        misfit += float(r @ r)
    d = theta[columns] - mean[columns]
    return misfit + float(d @ (d / var[columns]))


def _subset_map(
    replay: ReplayModel,
    prior: SubsetPrior,
    taken: list[int],
    measurements: list[FloatArray],
    subset: int,
    iterations: int,
) -> tuple[FloatArray, float]:
    """Subset ``subset``'s posterior mode by damped Gauss–Newton, and its log weight
    ln π(S) + ln p(y | S) in the model linearised there (Laplace's approximation), up to the
    constant common to every subset."""
    model = replay.model
    mean, var = model.prior.gaussian()
    columns = model.prior.subset_columns(subset)
    theta = np.zeros(len(PARAMETERS))
    best = _objective(replay, taken, measurements, theta, columns, mean, var)
    log_weight = -np.inf
    for k in range(iterations + 1):
        info, data, quad = _normal_equations(replay, taken, measurements, theta, nominal=k == 0)
        stats = subset_posteriors(prior, info, data)
        target = clip_to_catalogue(stats.mean[0, subset], model.prior)
        step = _damped_step(replay, taken, measurements, theta, target, best, (columns, mean, var))
        if step is None:
            break
        theta, best = step
        log_weight = float(stats.log_weight[0, subset]) - 0.5 * quad
    return theta, log_weight


def _normal_equations(
    replay: ReplayModel,
    taken: list[int],
    measurements: list[FloatArray],
    theta: FloatArray,
    *,
    nominal: bool,
) -> tuple[FloatArray, FloatArray, float]:
    """The whitened normal equations HᵀH (8, 8) and Hᵀr (8,) of the runs ``taken``, and rᵀr,
    linearised at ``theta`` through the replay — or, when ``nominal``, the linear model's own
    (at θ = 0). Each item is relinearised once, however often it was driven."""
    model = replay.model
    info = np.zeros((len(PARAMETERS), len(PARAMETERS)))
    data = np.zeros(len(PARAMETERS))
    quad = 0.0
    cache: dict[int, tuple[FloatArray, FloatArray]] = {}
    for item, y in zip(taken, measurements, strict=True):
        m = model.items[item]
        if nominal:
            h, shifted = m.whitened, y
        else:
            if item not in cache:
                jac = replay.jacobian(item, theta)
                cache[item] = (m.whiten @ jac, replay.predict(item, theta) - jac @ theta)
            h, offset = cache[item]
            shifted = y - offset
        r = m.whiten @ shifted
        info += h.T @ h
        data += h.T @ r
        quad += float(r @ r)
    return info, data, quad


def _damped_step(
    replay: ReplayModel,
    taken: list[int],
    measurements: list[FloatArray],
    theta: FloatArray,
    target: FloatArray,
    best: float,
    prior: tuple[NDArray[np.intp], FloatArray, FloatArray],
) -> tuple[FloatArray, float] | None:
    """Gauss–Newton's step from ``theta`` towards ``target`` with step halving (Nocedal & Wright
    2006, Ch. 10): the first of ``target`` and up to six points halfway back whose negative log
    posterior (:func:`_objective`, ``prior`` its columns, mean and variance) is below ``best``,
    with that value; None when none is."""
    columns, mean, var = prior
    for _ in range(7):
        value = _objective(replay, taken, measurements, target, columns, mean, var)
        if value < best:
            return target, value
        target = clip_to_catalogue(0.5 * (theta + target), replay.model.prior)
    return None


def laplace_estimate(
    replay: ReplayModel,
    prior: SubsetPrior,
    taken: list[int],
    measurements: list[FloatArray],
    subset: int | None = None,
    iterations: int = 3,
) -> tuple[FloatArray, FloatArray]:
    """Every subset relinearised around its own posterior mode (damped Gauss–Newton,
    :func:`_subset_map`) and weighted by its Laplace evidence: the Bayes model average (8,)
    and the subsets' probabilities; given ``subset``, only that subset's mode (the oracle's)
    and a probability 1 on it."""
    n = replay.model.prior.subsets
    if subset is not None:
        theta, _ = _subset_map(replay, prior, taken, measurements, subset, iterations)
        return theta, np.eye(n)[subset]
    modes, weights = [], []
    for s in range(n):
        theta, w = _subset_map(replay, prior, taken, measurements, s, iterations)
        modes.append(theta)
        weights.append(w)
    logw = np.array(weights)
    p = np.exp(logw - logw.max())
    p /= p.sum()
    out: FloatArray = p @ np.array(modes)
    return out, p


def relinearised_estimate(
    replay: ReplayModel,
    prior: SubsetPrior,
    taken: list[int],
    measurements: list[FloatArray],
    subset: int | None = None,
    iterations: int = 3,
) -> tuple[FloatArray, FloatArray]:
    """The estimate (8,) after ``iterations`` relinearisations of the subset posterior around
    the previous one (the first: the linear model at nominal) — the Bayes model average, or,
    given ``subset``, that subset's posterior mean (the oracle's) — and the last
    linearisation's subset probabilities (subsets,).

    Each step is damped (Gauss–Newton with step halving; Nocedal & Wright 2006, Ch. 10): a new
    estimate that raises the negative log posterior — the replayed runs' whitened misfit plus
    the prior of the always-present errors (of the subset's parameters, given ``subset``) —
    is moved halfway back, up to six times, and the iteration stops if none lowers it."""
    model = replay.model
    mean, var = model.prior.gaussian()
    columns = (
        np.array(ALWAYS, dtype=np.intp) if subset is None else model.prior.subset_columns(subset)
    )
    theta = np.zeros(len(PARAMETERS))
    best = _objective(replay, taken, measurements, theta, columns, mean, var)
    probability = np.zeros(model.prior.subsets)
    for k in range(iterations + 1):
        info, data, _ = _normal_equations(replay, taken, measurements, theta, nominal=k == 0)
        stats = subset_posteriors(prior, info, data)
        probability = stats.probability[0]
        target = clip_to_catalogue(
            stats.average()[0] if subset is None else stats.mean[0, subset], model.prior
        )
        step = _damped_step(replay, taken, measurements, theta, target, best, (columns, mean, var))
        if step is None:
            break
        theta, best = step
    return theta, probability

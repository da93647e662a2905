"""Schedules within a travel budget: the best fixed one, the oracle's, and the greedy
expected-information-gain policy.

A *schedule* is a multiset of menu items, held as item counts (items,); it fits the budget when
Σ counts·travel ≤ budget [m]. In the linear-Gaussian model the posterior covariance of a
subset's parameters depends on the schedule alone, not on the data (Pukelsheim 2006, Ch. 1),
which is what makes the three searches cheap:

* **the oracle** knows the robot's subset S and fits only θ_S: its expected quadratic
  validation loss is exactly tr(W·P_S(schedule)), so its schedule is the one that minimises
  that trace for S (:func:`oracle_schedules`);
* **the best fixed schedule** is one schedule for every robot, estimated with the Bayes model
  average: its expected loss has no closed form (the model weights depend on the data), so it
  is estimated by Monte Carlo over robots drawn from the prior with common random numbers
  (:class:`DesignRobots`, :func:`bma_risk`) and minimised (:func:`best_fixed_schedule`);
* **greedy expected information gain** (Chaloner & Verdinelli 1995: a design's expected
  utility, here minus the Bayes risk of the terminal estimate) picks, after every run, the
  affordable item whose expected fall of the posterior expected loss per metre of travel is
  largest, the expectation over the posterior predictive by Monte Carlo
  (:func:`greedy_session`).

Where the budget admits at most :data:`ENUMERATE_LIMIT` schedules, both minimisations rank
every one of them (:func:`enumerate_schedules`). Otherwise they are greedy fills followed by
exchanges (add, remove, or swap one run while the loss falls) in the manner of Fedorov's
exchange algorithm (Fedorov 1972), restarted from every subset's own schedule: not a
proof of optimality, but every result is a local minimum over those moves, and the oracle's
search is started from, and never returns worse than, the fixed schedule.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym.design.model import LinearModel
from odomgym.design.nonlinear import ReplayModel
from odomgym.design.posterior import ModelPosterior, SubsetPrior, subset_posteriors
from odomgym.design.prior import PARAMETERS
from odomgym.errors import SpecError

__all__ = [
    "DesignRobots",
    "SessionRobot",
    "best_fixed_schedule",
    "bma_risk",
    "check_budget",
    "enumerate_schedules",
    "greedy_session",
    "oracle_loss",
    "oracle_schedules",
    "run_schedule",
    "schedule_information",
    "search",
]

FloatArray = NDArray[np.float64]
Counts = NDArray[np.int64]

ENUMERATE_LIMIT = 4000
"""Largest number of schedules ranked exhaustively (above it: greedy fill and exchanges)."""


def enumerate_schedules(
    costs: FloatArray, budget_m: float, limit: int = ENUMERATE_LIMIT
) -> NDArray[np.int64] | None:
    """Every non-empty schedule of travel ≤ ``budget_m`` as counts (schedules, items), or
    None if there are more than ``limit``."""
    out: list[list[int]] = []
    counts = [0] * len(costs)

    def walk(i: int, left: float) -> bool:
        if i == len(costs):
            if any(counts):
                out.append(list(counts))
            return len(out) <= limit
        k = 0
        while k * costs[i] <= left + 1e-9:
            counts[i] = k
            if not walk(i + 1, left - k * costs[i]):
                counts[i] = 0
                return False
            k += 1
        counts[i] = 0
        return True

    if not walk(0, budget_m):
        return None
    return np.array(out, dtype=np.int64)


def check_budget(budget_m: float, model: LinearModel) -> None:
    """A budget that affords no item is a one-line :class:`SpecError` naming ``budget``."""
    if not np.isfinite(budget_m) or budget_m < float(model.costs.min()):
        raise SpecError(
            f"budget must be at least the cheapest item's travel ({model.costs.min():.2f} m), "
            f"got {budget_m}",
            field="budget",
        )


def schedule_information(model: LinearModel, counts: Counts) -> FloatArray:
    """Σ counts·A (8, 8): the information of a schedule's runs."""
    infos = np.array([m.information for m in model.items])
    out: FloatArray = np.einsum("i,ijk->jk", counts.astype(float), infos)
    return out


def oracle_loss(model: LinearModel, prior: SubsetPrior, subset: int, counts: Counts) -> float:
    """tr(W·P_S) [m²]: the expected quadratic validation loss of subset ``subset``'s posterior
    mean after the schedule ``counts``, for a robot of that subset (exact in the model)."""
    stats = subset_posteriors(prior, schedule_information(model, counts), np.zeros((1, 8)))
    return float(np.einsum("jk,kj->", model.weight, stats.cov[subset]))


def search(
    loss: Callable[[Counts], float],
    costs: FloatArray,
    budget_m: float,
    start: Counts | None = None,
    max_rounds: int = 200,
) -> Counts:
    """A schedule of travel ≤ ``budget_m`` that no single add, remove or swap improves:
    from ``start`` (default empty), a greedy fill by loss fallen per metre, then exchanges."""
    counts = np.zeros(len(costs), dtype=np.int64) if start is None else start.copy()
    slack = 1e-9

    def fits(c: Counts) -> bool:
        return bool(c @ costs <= budget_m + slack)

    current = loss(counts)
    while True:  # greedy fill
        best, best_gain = -1, 0.0
        for i in range(len(costs)):
            trial = counts.copy()
            trial[i] += 1
            if not fits(trial):
                continue
            gain = (current - loss(trial)) / costs[i]
            if gain > best_gain:
                best, best_gain = i, gain
        if best < 0:
            break
        counts[best] += 1
        current = loss(counts)
    for _ in range(max_rounds):  # exchanges
        moves: list[Counts] = []
        for i in range(len(costs)):
            add = counts.copy()
            add[i] += 1
            moves.append(add)
            if counts[i] > 0:
                drop = counts.copy()
                drop[i] -= 1
                moves.append(drop)
                for j in range(len(costs)):
                    if j != i:
                        swap = drop.copy()
                        swap[j] += 1
                        moves.append(swap)
        scored = [(loss(m), k) for k, m in enumerate(moves) if fits(m) and m.any()]
        if not scored:
            break
        value, k = min(scored)
        if value >= current * (1.0 - 1e-9):
            break
        counts, current = moves[k], value
    return counts


@dataclass(frozen=True)
class DesignRobots:
    """Robots drawn from the prior, with the noise of every run they could drive drawn in
    advance (common random numbers: every schedule is judged on the same robots and noise).

    Attributes:
        subset: each robot's subset (R,).
        theta: each robot's θ (R, 8).
        noise: cumulative whitened noise Σ_{k<c} H_iᵀ·z_k per robot, item and count c
            (R, items, max count + 1, 8).
    """

    subset: NDArray[np.int64]
    theta: FloatArray
    noise: FloatArray

    @classmethod
    def draw(
        cls, model: LinearModel, robots: int, budget_m: float, rng: np.random.Generator
    ) -> DesignRobots:
        """``robots`` robots and the noise of every run a schedule of ``budget_m`` can hold."""
        subsets, thetas = zip(*(model.prior.draw(rng) for _ in range(robots)), strict=True)
        most = int(budget_m // float(model.costs.min()))
        noise = np.zeros((robots, len(model.items), most + 1, len(PARAMETERS)))
        for i, m in enumerate(model.items):
            reps = int(budget_m // m.item.travel_m)
            z = rng.standard_normal((robots, reps, m.size))
            noise[:, i, 1 : reps + 1] = np.cumsum(z @ m.whitened, axis=1)
        return cls(np.array(subsets, dtype=np.int64), np.array(thetas), noise)


def bma_risk(model: LinearModel, prior: SubsetPrior, robots: DesignRobots, counts: Counts) -> float:
    """Mean quadratic validation loss of the Bayes model average after ``counts`` over
    ``robots`` [m²] (Monte Carlo estimate of the fixed schedule's Bayes risk)."""
    info = schedule_information(model, counts)
    data = robots.theta @ info
    idx = np.arange(len(model.items))
    data = data + robots.noise[:, idx, counts].sum(axis=1)
    estimate = subset_posteriors(prior, info, data).average()
    miss = estimate - robots.theta
    return float(np.einsum("rj,jk,rk->r", miss, model.weight, miss).mean())


def best_fixed_schedule(
    model: LinearModel,
    prior: SubsetPrior,
    budget_m: float,
    robots: DesignRobots,
) -> Counts:
    """The fixed schedule of travel ≤ ``budget_m`` with the least Bayes risk of the model
    average on ``robots`` (a greedy fill on the prior-weighted oracle loss, then exchanges on
    the Monte Carlo risk)."""
    check_budget(budget_m, model)
    weights = np.exp(model.prior.log_subset_prior())

    def bound(c: Counts) -> float:
        info = schedule_information(model, c)
        stats = subset_posteriors(prior, info, np.zeros((1, 8)))
        return float(weights @ np.einsum("jk,skj->s", model.weight, stats.cov))

    def risk(c: Counts) -> float:
        return bma_risk(model, prior, robots, c)

    every = enumerate_schedules(model.costs, budget_m)
    if every is not None:
        return min(every, key=risk)
    # several starts against local minima: the prior-weighted bound's greedy fill, and each
    # subset's oracle schedule (distinct ones)
    starts = [search(bound, model.costs, budget_m)]
    for s in range(model.prior.subsets):

        def own(c: Counts, s: int = s) -> float:
            return oracle_loss(model, prior, s, c)

        candidate = search(own, model.costs, budget_m)
        if not any(np.array_equal(candidate, c) for c in starts):
            starts.append(candidate)
    found = [search(risk, model.costs, budget_m, start) for start in starts]
    return min(found, key=risk)


def oracle_schedules(
    model: LinearModel, prior: SubsetPrior, budget_m: float, fixed: Counts
) -> list[Counts]:
    """Per subset, the schedule of travel ≤ ``budget_m`` minimising tr(W·P_S): the better of
    a search from empty and one from ``fixed`` (so never worse than ``fixed`` for S)."""
    check_budget(budget_m, model)
    every = enumerate_schedules(model.costs, budget_m)
    if every is not None:
        every = np.concatenate([every, fixed[None, :]])
        traces = np.array(
            [
                np.einsum(
                    "jk,skj->s",
                    model.weight,
                    subset_posteriors(prior, schedule_information(model, c), np.zeros((1, 8))).cov,
                )
                for c in every
            ]
        )
        return [every[int(np.argmin(traces[:, s]))] for s in range(model.prior.subsets)]
    out = []
    for s in range(model.prior.subsets):

        def loss(c: Counts, s: int = s) -> float:
            return oracle_loss(model, prior, s, c)

        candidates = [
            search(loss, model.costs, budget_m),
            search(loss, model.costs, budget_m, fixed),
        ]
        out.append(min(candidates, key=loss))
    # a second pass started from every subset's first-pass schedule (against local minima)
    first = list(out)
    for s in range(model.prior.subsets):

        def again(c: Counts, s: int = s) -> float:
            return oracle_loss(model, prior, s, c)

        found = [search(again, model.costs, budget_m, start) for start in first]
        out[s] = min([out[s], *found], key=again)
    return out


class SessionRobot:
    """A robot of the evaluation: θ and one noise stream per menu item, so the k-th run of an
    item measures the same noise whichever method drove it (paired comparisons).

    Args:
        model: the linear model.
        theta: the robot's parameters (8,).
        seed: the entropy of its streams (one more key per item).
        replay: if given, measure through the replay (nonlinear) instead of J·θ.
    """

    def __init__(
        self,
        model: LinearModel,
        theta: FloatArray,
        seed: tuple[int, ...],
        replay: ReplayModel | None = None,
    ) -> None:
        self.model = model
        self.theta = theta
        self.replay = replay
        self.taken: list[int] = []
        self.measurements: list[FloatArray] = []
        self._streams = [
            np.random.default_rng(np.random.SeedSequence([*seed, i]))
            for i in range(len(model.items))
        ]

    def measure(self, item: int) -> FloatArray:
        """The next run of ``item``: its measurement (m,), also kept in :attr:`measurements`."""
        if self.replay is None:
            y = self.model.items[item].measure(self.theta, self._streams[item])
        else:
            y = self.replay.measure(item, self.theta, self._streams[item])
        self.taken.append(item)
        self.measurements.append(y)
        return y


def run_schedule(
    model: LinearModel, prior: SubsetPrior, robot: SessionRobot, counts: Counts
) -> ModelPosterior:
    """Drive a fixed schedule (items in menu order) and return the posterior."""
    post = ModelPosterior(model, prior)
    for i, c in enumerate(counts):
        for _ in range(int(c)):
            post.update(i, robot.measure(i))
    return post


def _preposterior_loss(
    post: ModelPosterior, item: int, draws: int, rng: np.random.Generator
) -> float:
    """E[posterior expected loss after one run of ``item``] over the posterior predictive
    (``draws`` draws per subset of non-negligible weight, weighted by its probability)."""
    model, prior = post.model, post.prior
    m = model.items[item]
    stats = post.stats
    prob = stats.probability[0]
    info = post.information + m.information
    data_sets, weights = [], []
    for s in np.flatnonzero(prob > 1e-4):
        cols = prior.columns[s]
        chol = np.linalg.cholesky(stats.cov[s][np.ix_(cols, cols)])
        theta = np.zeros((draws, len(PARAMETERS)))
        theta[:, cols] = stats.mean[0, s, cols] + rng.standard_normal((draws, len(cols))) @ chol.T
        noise = rng.standard_normal((draws, m.size)) @ m.whitened
        data_sets.append(post.data + theta @ m.information + noise)
        weights.append(np.full(draws, prob[s] / draws))
    after = subset_posteriors(prior, info, np.concatenate(data_sets))
    return float(np.concatenate(weights) @ after.expected_loss(model.weight))


def greedy_session(
    model: LinearModel,
    prior: SubsetPrior,
    robot: SessionRobot,
    budget_m: float,
    rng: np.random.Generator,
    draws: int = 8,
    per_metre: bool = True,
) -> ModelPosterior:
    """Greedy expected information gain: after every run, the affordable item with the largest
    expected fall of the posterior expected validation loss per metre of travel (``per_metre``;
    else the largest fall, whatever the item costs); stops when no item fits the budget left
    or none is expected to lower the loss."""
    check_budget(budget_m, model)
    post = ModelPosterior(model, prior)
    costs = model.costs
    while True:
        left = budget_m - post.travel_m
        now = post.expected_loss()
        best, best_rate = -1, 0.0
        for i in np.flatnonzero(costs <= left + 1e-9):
            fall = now - _preposterior_loss(post, int(i), draws, rng)
            rate = fall / costs[i] if per_metre else fall
            if rate > best_rate:
                best, best_rate = int(i), rate
        if best < 0:
            return post
        post.update(best, robot.measure(best))

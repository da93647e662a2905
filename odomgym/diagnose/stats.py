"""The statistical tests of the diagnose workflow, on plain numbers and arrays.

Kept apart from the fitting (:mod:`odomgym.diagnose.fit`) and the workflow
(:mod:`odomgym.diagnose.workflow`, :mod:`odomgym.diagnose.rounds`,
:mod:`odomgym.diagnose.verdict`) so that each test can be checked against known numbers on its
own (tests/test_diagnose_stats.py), and so that the dependency runs one way: workflow → fit →
stats. This module imports numpy and scipy only.

* :func:`likelihood_ratio`, :func:`lr_test`, :func:`bonferroni`, :func:`combine_bonferroni` —
  the selection test of a candidate (χ², Bonferroni over the candidates) and the combination of
  two tests into one verdict;
* :func:`wald_p` — a term's two-sided Wald test, Bonferroni over a library;
* :func:`whiteness_p` — the consistency check: do whitened innovations look like white noise?
* :func:`bootstrap_ci`, :func:`rms`, :func:`reducible_fraction` — the gap report's intervals;
* :func:`studentised`, :func:`sign_matrix`, :func:`max_t_test`, :func:`sign_flip_p` — sign-flip
  tests over runs or blocks;
* :func:`clustered_covariance` — cluster-robust (sandwich) covariance;
* :func:`mean_t_test`, :func:`holm` — the t-tests of the "where" table and Holm's adjustment.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy import stats

__all__ = [
    "bonferroni",
    "bootstrap_ci",
    "clustered_covariance",
    "combine_bonferroni",
    "holm",
    "likelihood_ratio",
    "lr_test",
    "max_t_test",
    "mean_t_test",
    "reducible_fraction",
    "rms",
    "sign_flip_p",
    "sign_matrix",
    "studentised",
    "wald_p",
    "whiteness_p",
]

FloatArray = NDArray[np.float64]

EXACT_FLIPS = 12
"""Up to this many units (runs, blocks) a sign-flip test enumerates all 2^n sign patterns
(4096); beyond, it draws random ones."""


# ------------------------------------------------------------------ likelihood-ratio tests
def likelihood_ratio(loglik_gain: float) -> float:
    """The likelihood-ratio statistic 2·Δℓ of a larger model over a nested smaller one, given
    the log-likelihood gain Δℓ [nats]; floored at 0 because a nested fit that ends below its
    base (an optimiser stopping early) is no evidence against the base."""
    return max(0.0, 2.0 * loglik_gain)


def bonferroni(p: float, tests: int) -> float:
    """A p-value corrected for ``tests`` tests of a family (Bonferroni: ``tests``·p, at most 1),
    so that the chance of any false alarm in the family stays below the level."""
    return min(1.0, tests * p)


def lr_test(lr: float, dof: int, tests: int) -> float:
    """The χ² p-value of the likelihood-ratio statistic ``lr`` with ``dof`` degrees of freedom
    (Wilks), Bonferroni-corrected over ``tests`` candidates. Conservative for noise parameters
    on the boundary of their range, where the null distribution is a χ² mixture."""
    return bonferroni(float(stats.chi2.sf(lr, dof)), tests)


def combine_bonferroni(*p: float) -> float:
    """One p-value for the question "does any of these tests reject?": the smallest p-value
    times the number of tests (Bonferroni; valid whatever the dependence between them)."""
    return min(1.0, len(p) * min(p))


def wald_p(z: float, tests: int) -> float:
    """The two-sided p-value of a Wald statistic ``z`` (estimate over its standard error),
    Bonferroni-corrected over ``tests`` terms."""
    return bonferroni(2.0 * float(stats.norm.sf(abs(z))), tests)


# ------------------------------------------------------------------ the consistency check
def whiteness_p(whitened: Sequence[FloatArray], masks: Sequence[NDArray[np.bool_]]) -> float:
    """p-value that whitened innovations are white noise (the workflow's consistency check).

    ``whitened``: per run, the innovations (3·T,) in row order time, then component (x, y, θ);
    ``masks``: per run, which of the (T, 3) components were measured. Each measured component
    series of a run (at least two values) contributes its mean — Σ²/n is χ²₁ under white unit
    noise, summed over series (χ² with one degree of freedom per series) — and its lag-1
    products, pooled into one standard-normal statistic Σ w_k·w_{k−1}/√N. The two p-values are
    Bonferroni-combined: a model that misses an effect shows either a run-wise offset or a
    slowly varying (correlated) residual. 1 when no series has two values.
    """
    chi2 = 0.0
    dof = 0
    lag_num = 0.0
    lag_n = 0
    for w, mask in zip(whitened, masks, strict=True):
        per = w.reshape(-1, 3)
        for c in range(3):
            series = per[mask[:, c], c]
            if len(series) >= 2:
                chi2 += float(series.sum()) ** 2 / len(series)
                dof += 1
                lag_num += float(np.sum(series[1:] * series[:-1]))
                lag_n += len(series) - 1
    p_mean = float(stats.chi2.sf(chi2, dof)) if dof else 1.0
    p_lag = float(2 * stats.norm.sf(abs(lag_num / math.sqrt(max(lag_n, 1))))) if lag_n else 1.0
    return combine_bonferroni(p_mean, p_lag)


# ------------------------------------------------------------------ the gap report
def bootstrap_ci(
    values: Sequence[FloatArray],
    statistic: Callable[..., float],
    rng: np.random.Generator,
    draws: int = 2000,
) -> list[float]:
    """The 95 % percentile-bootstrap interval [low, high] of ``statistic(*values)``.

    ``values`` are paired samples (one array per argument, the same length n, e.g. each
    held-out run's gap before and after): every draw resamples the same n indices with
    replacement for all of them, keeping the pairing. Draws whose statistic is not finite are
    left out; [nan, nan] when more than half are (a statistic undefined on these data).
    """
    n = len(values[0])
    out = []
    for _ in range(draws):
        pick = rng.integers(0, n, n)
        out.append(statistic(*(v[pick] for v in values)))
    finite = np.array(out)[np.isfinite(out)]
    if len(finite) < 0.5 * draws:
        return [math.nan, math.nan]
    low, high = np.percentile(finite, [2.5, 97.5])
    return [float(low), float(high)]


def rms(mean_squares: FloatArray) -> float:
    """Root of the mean of per-run mean squares (runs weighted equally)."""
    return float(math.sqrt(np.mean(mean_squares)))


def reducible_fraction(before: FloatArray, after: FloatArray, floor: FloatArray) -> float:
    """The fraction of the reducible gap closed, (MS_before − MS_after)/(MS_before − MS_floor),
    from per-run mean squares; NaN when there is no gap above the floor to close (the fraction
    would divide by zero or a negative)."""
    reducible = float(np.mean(before) - np.mean(floor))
    if reducible <= 0:
        return math.nan
    return float((np.mean(before) - np.mean(after)) / reducible)


# ------------------------------------------------------------------ sign-flip tests
def studentised(d: FloatArray) -> FloatArray:
    """Studentised means over the last axis, mean/(sd/√n) with the n−1 standard deviation; a
    spread of 0 gives +inf for a positive mean (every unit agrees) and 0 otherwise."""
    n = d.shape[-1]
    mean = d.mean(axis=-1)
    sd = d.std(axis=-1, ddof=1) if n > 1 else np.zeros_like(mean)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(sd > 0, mean / (sd / math.sqrt(n)), np.where(mean > 0, np.inf, 0.0))
    return np.asarray(t)


def sign_matrix(n: int, rng: np.random.Generator, draws: int) -> FloatArray:
    """Sign patterns (rows) for ``n`` units: all 2^n when n ≤ :data:`EXACT_FLIPS` (an exact
    test; ``rng`` untouched), else ``draws`` random ones whose first is the identity (the
    observed statistic belongs to its own null distribution, so a p-value is never 0)."""
    if n <= EXACT_FLIPS:
        return np.array(list(itertools.product((1.0, -1.0), repeat=n)))
    signs = rng.choice([1.0, -1.0], size=(draws, n))
    signs[0] = 1.0
    return signs


def max_t_test(
    improvements: FloatArray, rng: np.random.Generator, draws: int = 4000
) -> tuple[FloatArray, FloatArray]:
    """Studentised mean improvement of each candidate and its family-wise p-value.

    ``improvements`` (C, n): candidate × run. Single-step max-T (Westfall & Young 1993): the
    signs of whole runs are flipped together for all candidates, which keeps the dependence
    between candidates, and the largest studentised mean over candidates forms the null
    distribution (exact when n ≤ :data:`EXACT_FLIPS`, else ``draws`` random flips).
    Returns t (C,) and p (C,).
    """
    d = np.asarray(improvements, dtype=float)
    t_obs = studentised(d)
    signs = sign_matrix(d.shape[1], rng, draws)
    null_max = _null_max(d, signs)
    p = np.array([(np.sum(null_max >= t - 1e-12)) / len(null_max) for t in t_obs])
    return t_obs, p


_FLIP_CHUNK = 256  # sign patterns studentised at once by _null_max (a few MB)


def _null_max(d: FloatArray, signs: FloatArray) -> FloatArray:
    """The largest studentised mean over candidates of ``d`` (C, n) under each sign pattern
    of ``signs`` (draws, n): ``studentised(d * s).max()`` for every row s, computed for a block
    of patterns at once. The same numbers: each mean and standard deviation is the same
    reduction over a run axis of the same length (``tests/test_diagnose_speed.py`` compares
    the bytes); one pattern at a time took ~0.1 s a candidate round."""
    d = np.ascontiguousarray(d)  # the run axis contiguous, as in each row of the loop
    blocks = [
        studentised(d[None, :, :] * signs[k : k + _FLIP_CHUNK, None, :]).max(axis=1)
        for k in range(0, len(signs), _FLIP_CHUNK)
    ]
    return np.concatenate(blocks) if blocks else np.zeros(0)


def sign_flip_p(
    parts: FloatArray, basis: FloatArray, observed: float, rng: np.random.Generator, draws: int
) -> float:
    """p-value of ‖basisᵀ·Σ ±parts‖² ≥ ``observed`` under random signs of the parts.

    ``parts`` (n, K): each unit's score vector (a block's or a run's Jᵀr); ``basis`` (K, r)
    whitens the score. Under no dependence each unit's score is symmetric about 0, so its sign
    is a fair coin whatever the shape of the noise."""
    units = parts.shape[0]
    if units <= EXACT_FLIPS or draws * units <= _SIGN_CHUNK:
        score = sign_matrix(units, rng, draws) @ parts
    else:
        # The same patterns drawn a block of rows at a time (one draw of the whole matrix
        # consumes the stream row after row, so the blocks are its rows) and each block's
        # scores computed at once: the pattern matrix of the block sign-flip test is 4 000 ×
        # ~4 400 on the 14 June OptiOdom sessions, 140 MB, and writing it fresh cost 0.25–0.7 s
        # a test in the diagnosing process (page faults), 0.14 s in blocks. BLAS may sum a
        # block's products in another order than the whole matrix's (as it may for another
        # thread count): the null statistics can differ in their last bits, and a p-value
        # moves only if a pattern's statistic lies within rounding of the cut-off
        # observed·(1 − 1e-12), whose tolerance keeps the identity pattern counted.
        score = np.empty((draws, parts.shape[1]))
        rows = max(1, _SIGN_CHUNK // units)
        for k in range(0, draws, rows):
            signs = rng.choice([1.0, -1.0], size=(min(rows, draws - k), units))
            if k == 0:
                signs[0] = 1.0
            score[k : k + len(signs)] = signs @ parts
    null = np.sum((score @ basis) ** 2, axis=1)
    return float(np.mean(null >= observed * (1 - 1e-12)))


_SIGN_CHUNK = 1 << 22
"""Sign-pattern entries :func:`sign_flip_p` draws at once (4 M, 32 MB)."""


# ------------------------------------------------------------------ standard errors
def clustered_covariance(
    cov: FloatArray, scores: FloatArray, labels: Sequence[object]
) -> FloatArray:
    """Cluster-robust covariance cov·(Σ_c s_c·s_cᵀ)·cov·G/(G−1), s_c the summed scores of a
    cluster (Liang & Zeger 1986): right even when the units within a cluster are correlated.
    NaN with fewer than two clusters or a non-finite model covariance."""
    groups: dict[object, FloatArray] = {}
    for label, score in zip(labels, scores, strict=True):
        groups[label] = groups.get(label, 0.0) + score
    count = len(groups)
    if count < 2 or not np.all(np.isfinite(cov)):
        return np.full_like(cov, math.nan)
    summed = np.array(list(groups.values()))
    out: FloatArray = cov @ (summed.T @ summed) @ cov * (count / (count - 1))
    return out


# ------------------------------------------------------------------ the "where" table
def mean_t_test(values: FloatArray) -> tuple[float, float, float, float]:
    """One-sample t-test of the finite ``values`` against 0: (mean, 95 % interval low, high,
    two-sided p). With fewer than two values or no spread the interval is NaN and p is 1 (no
    evidence either way)."""
    v = values[np.isfinite(values)]
    n = len(v)
    mean = float(v.mean()) if n else math.nan
    if n < 2 or float(v.std(ddof=1)) == 0.0:
        return mean, math.nan, math.nan, 1.0
    se = float(v.std(ddof=1)) / math.sqrt(n)
    q = float(stats.t.ppf(0.975, n - 1))
    p = float(2 * stats.t.sf(abs(mean / se), n - 1))
    return mean, mean - q * se, mean + q * se, p


def holm(p: FloatArray) -> FloatArray:
    """Holm's step-down adjustment of p-values: the k-th smallest times (m − k + 1), made
    monotone, at most 1; controls the family-wise error like Bonferroni, with more power."""
    order = np.argsort(p)
    m = len(p)
    adjusted = np.empty(m)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        adjusted[i] = running
    return adjusted

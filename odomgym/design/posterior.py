"""The posterior over effect subsets and parameters: exact in the linear-Gaussian model.

Each subset S of the optional effects (2⁴ = 16) is one model: θ_S (the always-present E_s,
E_d, E_b and S's parameters) has the Gaussian prior N(μ₀, P₀) of
:meth:`~odomgym.design.prior.DesignPrior.gaussian`, the other entries of θ are absent
(0), and every measured item adds y = J·θ + e, e ~ N(0, R) (:mod:`~odomgym.design.
model`). In information form (a Kalman filter of a constant state, per subset — the issue's
"particle set over effect subsets with a Kalman update per particle", here with the 16 subsets
enumerated rather than sampled), after the whitened measurements r = L⁻¹·y:

    Λ_S = P₀⁻¹ + Σ H_Sᵀ·H_S,   η_S = P₀⁻¹·μ₀ + Σ H_Sᵀ·r,   μ_S = Λ_S⁻¹·η_S,

and the marginal likelihood (evidence) of all data under S is, completing the square,

    ln p(y | S) = −½·(Σ rᵀr − η_Sᵀ·Λ_S⁻¹·η_S + μ₀ᵀ·P₀⁻¹·μ₀) − ½·ln det Λ_S + ½·ln det P₀⁻¹
                  − (n/2)·ln 2π − ½·Σ ln det R,

the closed form of N(y; J·μ₀, J·P₀·Jᵀ + R) (Bishop 2006, Eq. 3.86). The model posterior is
p(S | y) ∝ π(S)·p(y | S). Only the first three sums depend on the data, and they are all the
posterior keeps: Σ A = Σ HᵀH (8, 8), Σ Hᵀr (8,), Σ rᵀr — so an update costs one triangular
solve of the item's measurements and 16 solves of at most 8 × 8 (measured: docs).

The estimate handed to the robot is the Bayes model average θ̂ = Σ_S p(S | y)·μ_S (absent
parameters 0), which minimises the posterior expected quadratic validation loss
E[(θ̂ − θ)ᵀ·W·(θ̂ − θ)] over all estimates; that loss itself is
Σ_S p(S | y)·[tr(W·P_S) + (μ_S − θ̂)ᵀ·W·(μ_S − θ̂)].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym.design.model import LinearModel
from odomgym.design.prior import PARAMETERS

__all__ = ["ModelPosterior", "SubsetPrior", "SubsetStats", "subset_posteriors"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SubsetPrior:
    """What every subset's posterior starts from (computed once per model).

    Attributes:
        columns: the entries of θ each subset estimates.
        precision: P₀⁻¹ restricted to them, per subset.
        shift: P₀⁻¹·μ₀ restricted to them, per subset.
        constant: −½·μ₀ᵀ·P₀⁻¹·μ₀ + ½·ln det P₀⁻¹ + ln π(S), per subset.
    """

    columns: tuple[NDArray[np.intp], ...]
    precision: tuple[FloatArray, ...]
    shift: tuple[FloatArray, ...]
    constant: FloatArray

    @classmethod
    def of(cls, model: LinearModel) -> SubsetPrior:
        """The subsets' priors of ``model``'s prior."""
        prior = model.prior
        mean, var = prior.gaussian()
        log_pi = prior.log_subset_prior()
        columns, precision, shift, constant = [], [], [], []
        for s in range(prior.subsets):
            cols = prior.subset_columns(s)
            lam = np.diag(1.0 / var[cols])
            columns.append(cols)
            precision.append(lam)
            shift.append(lam @ mean[cols])
            constant.append(
                -0.5 * float(mean[cols] @ lam @ mean[cols])
                + 0.5 * float(np.log(np.diag(lam)).sum())
                + float(log_pi[s])
            )
        return cls(tuple(columns), tuple(precision), tuple(shift), np.array(constant))


@dataclass(frozen=True)
class SubsetStats:
    """Every subset's posterior, for R sets of data at once.

    Attributes:
        log_weight: ln π(S) + ln p(y | S) up to a constant common to all subsets (R, S).
        mean: μ_S with absent entries 0 (R, S, 8).
        cov: P_S with absent rows and columns 0 (S, 8, 8); the same for every data set,
            because it depends only on which items were measured.
    """

    log_weight: FloatArray
    mean: FloatArray
    cov: FloatArray

    @property
    def probability(self) -> FloatArray:
        """p(S | y) (R, S)."""
        w = self.log_weight - self.log_weight.max(axis=1, keepdims=True)
        p = np.exp(w)
        out: FloatArray = p / p.sum(axis=1, keepdims=True)
        return out

    def average(self) -> FloatArray:
        """The Bayes model average θ̂ (R, 8)."""
        out: FloatArray = np.einsum("rs,rsj->rj", self.probability, self.mean)
        return out

    def expected_loss(self, weight: FloatArray) -> FloatArray:
        """Posterior expected quadratic loss of θ̂ (R,) [m²] (module docstring)."""
        p = self.probability
        spread = np.einsum("jk,skj->s", weight, self.cov)
        d = self.mean - self.average()[:, None, :]
        bias = np.einsum("rsj,jk,rsk->rs", d, weight, d)
        out: FloatArray = (p * (spread[None, :] + bias)).sum(axis=1)
        return out


def subset_posteriors(prior: SubsetPrior, information: FloatArray, data: FloatArray) -> SubsetStats:
    """Every subset's posterior from the sufficient statistics Σ HᵀH (8, 8) and Σ Hᵀr (R, 8)
    of R data sets measured with the same items."""
    data = np.atleast_2d(data)
    n_sets, n_sub = data.shape[0], len(prior.columns)
    log_weight = np.empty((n_sets, n_sub))
    mean = np.zeros((n_sets, n_sub, len(PARAMETERS)))
    cov = np.zeros((n_sub, len(PARAMETERS), len(PARAMETERS)))
    for s, cols in enumerate(prior.columns):
        lam = prior.precision[s] + information[np.ix_(cols, cols)]
        chol = np.linalg.cholesky(lam)  # fails loudly if Λ_S is not positive definite
        p = np.linalg.inv(lam)
        eta = prior.shift[s][None, :] + data[:, cols]
        mu = eta @ p
        cov[s][np.ix_(cols, cols)] = p
        mean[:, s, cols] = mu
        log_weight[:, s] = (
            0.5 * np.einsum("rj,rj->r", eta, mu)
            - float(np.log(np.diag(chol)).sum())
            + prior.constant[s]
        )
    return SubsetStats(log_weight, mean, cov)


class ModelPosterior:
    """The posterior of one calibration session, updated one measured item at a time.

    Args:
        model: the menu's linear model (items, prior, validation weight).
        subset_prior: the subsets' priors (computed from ``model`` when not given; pass one to
            share it between sessions).
    """

    def __init__(self, model: LinearModel, subset_prior: SubsetPrior | None = None) -> None:
        self.model = model
        self.prior = subset_prior if subset_prior is not None else SubsetPrior.of(model)
        dim = len(PARAMETERS)
        self.information = np.zeros((dim, dim))
        self.data = np.zeros(dim)
        self.quad = 0.0
        self.count = 0
        self.logdet = 0.0
        self.taken: list[int] = []
        self.travel_m = 0.0
        self.time_s = 0.0
        self._stats: SubsetStats | None = None

    def update(self, item: int, measurement: FloatArray) -> None:
        """Take in one run of item ``item`` (index into the model's items) whose measurement
        (measured poses minus the nominal replay's, (m,)) is ``measurement``."""
        m = self.model.items[item]
        r = m.whiten @ np.asarray(measurement, dtype=float)
        self.information = self.information + m.information
        self.data = self.data + m.whitened.T @ r
        self.quad += float(r @ r)
        self.count += m.size
        self.logdet += m.logdet
        self.taken.append(item)
        self.travel_m += m.item.travel_m
        self.time_s += m.item.time_s
        self._stats = None

    @property
    def stats(self) -> SubsetStats:
        """Every subset's posterior (one data set)."""
        if self._stats is None:
            self._stats = subset_posteriors(self.prior, self.information, self.data)
        return self._stats

    def probability(self) -> FloatArray:
        """p(S | data) of every subset (S,)."""
        out: FloatArray = self.stats.probability[0]
        return out

    def effect_probability(self) -> FloatArray:
        """p(effect present | data) of every optional effect (4,)."""
        p = self.probability()
        bits = np.array([[s >> k & 1 for k in range(4)] for s in range(len(p))], dtype=float)
        out: FloatArray = p @ bits
        return out

    def estimate(self) -> FloatArray:
        """The Bayes model average θ̂ (8,)."""
        out: FloatArray = self.stats.average()[0]
        return out

    def subset_mean(self, subset: int) -> FloatArray:
        """μ_S of one subset (8,), absent entries 0."""
        out: FloatArray = self.stats.mean[0, subset]
        return out

    def expected_loss(self) -> float:
        """The posterior expected quadratic validation loss of :meth:`estimate` [m²]."""
        return float(self.stats.expected_loss(self.model.weight)[0])

    def log_evidence(self) -> FloatArray:
        """ln p(y | S) of every subset (S,), every constant included (module docstring)."""
        log_pi = self.model.prior.log_subset_prior()
        partial = self.stats.log_weight[0] - log_pi
        out: FloatArray = (
            partial
            - 0.5 * self.quad
            - 0.5 * self.count * math.log(2.0 * math.pi)
            - 0.5 * self.logdet
        )
        return out

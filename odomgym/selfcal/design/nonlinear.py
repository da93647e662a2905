"""The replay behind the linear model: nonlinear measurements and a relinearised estimate.

The linear model of :mod:`~odomgym.selfcal.design.model` is exact for its own data. A robot
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

from odomgym.diagnose.generate import NOMINAL_ROBOT
from odomgym.diagnose.replay import RunInputs, replay_run
from odomgym.odometry.runs import Run
from odomgym.selfcal.design.menu import item_run
from odomgym.selfcal.design.model import EVERY, FD_STEPS, LinearModel, sample_rows
from odomgym.selfcal.design.posterior import SubsetPrior, subset_posteriors
from odomgym.selfcal.design.prior import PARAMETERS, spec_of

__all__ = ["ReplayModel", "relinearised_estimate"]

FloatArray = NDArray[np.float64]
ONE_SIDED = np.array([one for _, one in FD_STEPS])


def clip_to_catalogue(theta: FloatArray) -> FloatArray:
    """θ with the one-sided parameters (turn-skid gain, backlash width) kept ≥ 0 [unit]."""
    out = np.array(theta, dtype=float)
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
        base = clip_to_catalogue(theta)
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
    linearisation's subset probabilities (subsets,)."""
    model = replay.model
    theta = np.zeros(len(PARAMETERS))
    for k in range(iterations + 1):
        info = np.zeros((len(PARAMETERS), len(PARAMETERS)))
        data = np.zeros(len(PARAMETERS))
        cache: dict[int, tuple[FloatArray, FloatArray]] = {}
        for item, y in zip(taken, measurements, strict=True):
            m = model.items[item]
            if k == 0:
                h, shifted = m.whitened, y
            else:
                if item not in cache:
                    jac = replay.jacobian(item, theta)
                    cache[item] = (m.whiten @ jac, replay.predict(item, theta) - jac @ theta)
                h, offset = cache[item]
                shifted = y - offset
            info += h.T @ h
            data += h.T @ (m.whiten @ shifted)
        stats = subset_posteriors(prior, info, data)
        theta = clip_to_catalogue(stats.average()[0] if subset is None else stats.mean[0, subset])
    return theta, stats.probability[0]

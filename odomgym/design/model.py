"""The linear-Gaussian measurement model of every menu item, computed once and cached.

For an item, the measurement is the logged ground truth — the tracked pose (x, y, θ) every
``every`` samples (1 s at 20 Hz) and at the run's end — and the model is

    y = J·θ + e,   e ~ N(0, R),

with J the Jacobian of those poses with respect to θ (:data:`~odomgym.design.prior.
PARAMETERS`) at the nominal robot, by finite differences through the replay
(:func:`odomgym.diagnose.replay.replay_run`): central for the two-sided parameters; for the
one-sided ones (turn-skid gain, backlash width, which the catalogue keeps ≥ 0) central about
one step above zero, i.e. forward from the absent value — the replay is linear in both there
(``docs/effects.md`` steps 1 and 4: a fixed loss β per reversal; dθ₀·(1 − κ·|v·ω₀|)).

R is the ground-truth sensor's independent noise (σ = 1 mm and 2 mrad per pose, the
generator's and the detection-limit table's sensor) plus the floor's wheel noise carried along
the run: each wheel's travel over a 50 ms interval gets the variance k²·|d| (Chong & Kleeman
1997, Eq. 4) with k = 0.0004 m^½ (the benchmark's ``concrete`` floor, docs/selfcal.md), and
the linearised dead reckoning carries it into every later pose. The wheel noise is why a long
run is not worth its length in information: its errors are correlated along the run.

Everything the posterior needs of an item is whitened once: H = L⁻¹·J with R = L·Lᵀ, and
A = HᵀH, its information matrix.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_triangular

from odomgym.design.menu import DESIGN_MENU, VALIDATION, DesignItem, item_run
from odomgym.design.prior import DEFAULT_PRIOR, PARAMETERS, DesignPrior, spec_of
from odomgym.diagnose.generate import NOMINAL_ROBOT
from odomgym.diagnose.replay import RunInputs, replay_run
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "FD_STEPS",
    "SENSOR",
    "WHEEL_NOISE_K",
    "ItemModel",
    "LinearModel",
    "ValidationError",
    "build_model",
    "item_model",
    "sample_rows",
    "validation_errors",
    "validation_runs",
]

FloatArray = NDArray[np.float64]

SENSOR: tuple[float, float] = (0.001, 0.002)
"""Ground-truth sensor σ: position [m], heading [rad] (docs/effects.md, detection limits)."""
WHEEL_NOISE_K = 0.0004
"""Chong & Kleeman wheel-noise constant of the benchmark's ``concrete`` floor [m^½]."""
EVERY = 20
"""Samples between measured poses (1 s at 20 Hz)."""
#: Finite-difference step of each parameter of θ and whether it is one-sided (≥ 0).
FD_STEPS: tuple[tuple[float, bool], ...] = (
    (1e-4, False),
    (1e-4, False),
    (1e-4, False),
    (1e-4, False),
    (0.05, True),
    (2e-3, True),
    (1e-3, False),
    (1e-3, False),
)


@dataclass(frozen=True)
class ItemModel:
    """One menu item's linear-Gaussian model.

    Attributes:
        item: the menu item (name, costs).
        jacobian: J (m, 8): measured poses' derivative in θ [m or rad per unit of θ].
        chol: L (m, m), R = L·Lᵀ, the measurement covariance's Cholesky factor.
        whiten: L⁻¹ (m, m) (a product is cheaper per update than a triangular solve).
        whitened: H = L⁻¹·J (m, 8).
        information: A = HᵀH (8, 8).
        logdet: ln det R.
    """

    item: DesignItem
    jacobian: FloatArray
    chol: FloatArray
    whiten: FloatArray
    whitened: FloatArray
    information: FloatArray
    logdet: float

    @property
    def size(self) -> int:
        """Number of scalar measurements m."""
        return int(self.jacobian.shape[0])

    def measure(self, theta: FloatArray, rng: np.random.Generator) -> FloatArray:
        """A measurement y (m,) of a robot with parameters θ: J·θ plus noise drawn from R —
        the linear model's own data (measured poses minus the nominal replay's)."""
        noise: FloatArray = self.chol @ rng.standard_normal(self.size)
        out: FloatArray = self.jacobian @ np.asarray(theta, dtype=float) + noise
        return out


def sample_rows(run: Run, every: int) -> NDArray[np.intp]:
    """The rows of ``run`` measured: every ``every``-th sample after the start, and the last."""
    rows = list(range(every, len(run.time), every))
    if rows[-1] != len(run.time) - 1:
        rows.append(len(run.time) - 1)
    return np.array(rows, dtype=np.intp)


def _poses(run: Run, theta: FloatArray, inputs: RunInputs, rows: NDArray[np.intp]) -> FloatArray:
    replay = replay_run(run, spec_of(theta), inputs)
    out: FloatArray = replay.tracked[rows].reshape(-1)
    return out


def jacobian(run: Run, rows: NDArray[np.intp], robot: RobotSpec = NOMINAL_ROBOT) -> FloatArray:
    """d(tracked poses at ``rows``)/dθ at θ = 0 (len(rows)·3, 8), by finite differences of
    :data:`FD_STEPS` through the replay."""
    inputs = RunInputs.of(run, robot.ticks_per_rev)
    return _differences(lambda theta: _poses(run, theta, inputs, rows))


def _differences(observe: Callable[[FloatArray], FloatArray]) -> FloatArray:
    """(m, 8): the derivative of ``observe`` (θ → (m,)) at θ = 0 by the finite differences of
    :data:`FD_STEPS`: central over ±h, or forward over 2h where a parameter is one-sided."""
    zero = np.zeros(len(PARAMETERS))
    columns = []
    for j, (h, one_sided) in enumerate(FD_STEPS):
        up, down = zero.copy(), zero.copy()
        if one_sided:
            up[j] = 2.0 * h
        else:
            up[j], down[j] = h, -h
        columns.append((observe(up) - observe(down)) / (2 * h))
    out: FloatArray = np.array(columns).T
    return out


def wheel_noise_covariance(
    run: Run, rows: NDArray[np.intp], k: float, robot: RobotSpec
) -> FloatArray:
    """Covariance (3·len(rows), 3·len(rows)) of the poses at ``rows`` from the wheel noise of
    constant ``k`` [m^½] (Chong & Kleeman 1997, Eq. 4), carried by the dead reckoning
    linearised about the nominal path (midpoint integration, docs/effects.md steps 2–5)."""
    replay = replay_run(run, robot)
    pose, travel, ds = replay.pose, replay.travel, replay.ds
    b = replay.wheelbase
    n = len(ds)
    phi = pose[:-1, 2] + 0.5 * replay.dtheta
    c, s = np.cos(phi), np.sin(phi)
    interval = np.arange(n)
    g = np.zeros((len(rows), 3, n, 2))
    for r, t in enumerate(rows):
        before = interval < t
        dx = pose[t, 0] - pose[1:, 0]  # x_t − x_{i+1}
        dy = pose[t, 1] - pose[1:, 1]
        for w, sign in ((0, -1.0), (1, 1.0)):  # left: dθ −= δ/b, right: dθ += δ/b
            g[r, 0, :, w] = np.where(before, 0.5 * c - sign * (ds * s / (2 * b) + dy / b), 0.0)
            g[r, 1, :, w] = np.where(before, 0.5 * s + sign * (ds * c / (2 * b) + dx / b), 0.0)
            g[r, 2, :, w] = np.where(before, sign / b, 0.0)
    flat = g.reshape(3 * len(rows), 2 * n)
    variance = (k**2 * np.abs(travel)).reshape(2 * n)
    cov: FloatArray = (flat * variance) @ flat.T
    return cov


def item_model(
    item: DesignItem,
    *,
    sensor: tuple[float, float] = SENSOR,
    wheel_noise_k: float = WHEEL_NOISE_K,
    every: int = EVERY,
    robot: RobotSpec = NOMINAL_ROBOT,
) -> ItemModel:
    """``item``'s :class:`ItemModel` (module docstring)."""
    run = item_run(item.experiment, robot)
    rows = sample_rows(run, every)
    jac = jacobian(run, rows, robot)
    cov = np.diag(np.tile([sensor[0] ** 2, sensor[0] ** 2, sensor[1] ** 2], len(rows)))
    if wheel_noise_k > 0:
        cov = cov + wheel_noise_covariance(run, rows, wheel_noise_k, robot)
    chol = np.linalg.cholesky(cov)
    whiten = solve_triangular(chol, np.eye(len(chol)), lower=True)
    white = whiten @ jac
    logdet = 2.0 * float(np.log(np.diag(chol)).sum())
    return ItemModel(item, jac, chol, whiten, white, white.T @ white, logdet)


def _displacement(pose: FloatArray) -> FloatArray:
    """Axle positions (T, 2) relative to the start [m]: a validation run starts at the axle
    (the replay starts from the tracked point, which a ground-truth offset moves)."""
    out: FloatArray = pose[:, :2] - pose[0, :2]
    return out


def validation_jacobians(robot: RobotSpec = NOMINAL_ROBOT, every: int = EVERY) -> list[FloatArray]:
    """The axle positions' Jacobians of the validation runs (:data:`VALIDATION`): the two
    squares' end positions (2, 8) and the free path's positions every ``every`` samples
    (2·T, 8), by the same finite differences."""
    out = []
    for experiment in VALIDATION:
        run = item_run(experiment, robot)
        rows = (
            np.array([len(run.time) - 1])
            if "square" in experiment.name
            else sample_rows(run, every)
        )
        inputs = RunInputs.of(run, robot.ticks_per_rev)

        def observe(
            theta: FloatArray,
            run: Run = run,
            inputs: RunInputs = inputs,
            rows: NDArray[np.intp] = rows,
        ) -> FloatArray:
            moved: FloatArray = _displacement(replay_run(run, spec_of(theta), inputs).pose)
            return moved[rows].reshape(-1)

        out.append(_differences(observe))
    return out


@dataclass(frozen=True)
class LinearModel:
    """The menu's item models, the prior and the validation weight.

    Attributes:
        items: one :class:`ItemModel` per menu item.
        prior: the prior over robots.
        weight: W (8, 8): the quadratic validation loss of an estimate off by δ is δᵀ·W·δ
            [m²] — the two squares' squared end-position misses plus the free path's mean
            squared position miss, linearised (:func:`validation_jacobians`).
    """

    items: tuple[ItemModel, ...]
    prior: DesignPrior
    weight: FloatArray

    @property
    def costs(self) -> FloatArray:
        """Travel cost of each item [m]."""
        return np.array([m.item.travel_m for m in self.items])

    @property
    def names(self) -> tuple[str, ...]:
        """The items' names."""
        return tuple(m.item.name for m in self.items)


def build_model(
    menu: tuple[DesignItem, ...] = DESIGN_MENU,
    prior: DesignPrior = DEFAULT_PRIOR,
    *,
    sensor: tuple[float, float] = SENSOR,
    wheel_noise_k: float = WHEEL_NOISE_K,
    every: int = EVERY,
) -> LinearModel:
    """The :class:`LinearModel` of ``menu`` (each item's Jacobian computed once: ~20 replays)."""
    items = tuple(
        item_model(i, sensor=sensor, wheel_noise_k=wheel_noise_k, every=every) for i in menu
    )
    jacs = validation_jacobians(every=every)
    free = jacs[2]
    weight = jacs[0].T @ jacs[0] + jacs[1].T @ jacs[1] + free.T @ free / (len(free) // 2)
    return LinearModel(items, prior, weight)


@dataclass(frozen=True)
class ValidationError:
    """How far an estimate's odometry misses on the validation runs (noiseless replay).

    Attributes:
        e_max_syst: the larger of the two 2 m squares' end-position misses [m] (Borenstein &
            Feng 1994, Eq. 3.3, here exact: no floor noise, so the centroid is the run).
        free_rms: the RMS position miss along the free path [m].
    """

    e_max_syst: float
    free_rms: float

    @property
    def combined(self) -> float:
        """The room's figure: the mean of the two [m] (fixed before the room was measured)."""
        return 0.5 * (self.e_max_syst + self.free_rms)


def validation_runs(robot: RobotSpec = NOMINAL_ROBOT) -> list[tuple[Run, RunInputs]]:
    """The validation runs' counts and replay inputs (made once, shared)."""
    out = []
    for experiment in VALIDATION:
        run = item_run(experiment, robot)
        out.append((run, RunInputs.of(run, robot.ticks_per_rev)))
    return out


def validation_errors(
    estimate: FloatArray,
    truth: FloatArray,
    runs: list[tuple[Run, RunInputs]],
) -> ValidationError:
    """The validation runs replayed through the robot of θ = ``estimate`` (what the
    calibrated odometry believes) and through the true robot: their axle positions' misses."""
    ends = []
    free = math.nan
    for run, inputs in runs:
        believed = _displacement(replay_run(run, spec_of(estimate), inputs).pose)
        actual = _displacement(replay_run(run, spec_of(truth), inputs).pose)
        miss = np.hypot(*(believed - actual).T)
        if str(run.meta.get("experiment", "")).startswith("validate-square"):
            ends.append(float(miss[-1]))
        else:
            free = float(np.sqrt(np.mean(miss**2)))
    return ValidationError(max(ends), free)

"""Noise effects judged by the spread they predict (``odomgym.diagnose.spread``).

The yardstick of a noise effect is a proper scoring rule on held-out open-loop errors, the log
predictive density of every held-out run's errors (the filter's prediction-error
decomposition), with the coverage of the model's 50 % and 95 % predictive regions. What these
tests pin:

* the coverage levels the filter reports are those of its predictive distribution: the χ²
  closed forms against scipy, and for the bumps' Poisson mixture against a Monte Carlo of the
  mixture itself;
* on logs of the independent generator (no odomgym simulator code), the right wheel noise
  covers 40–60 % and 90–98 %, beats the model without it, and is confirmed; the same noise
  **merely widened** (k × 3) still beats a model without any noise but is refused, because its
  regions hold too much; too narrow (k / 3), refused the other way;
* bumps are told from wheel noise of the same variance by their tails, and a bump model's mean
  part (the travel the bumps lose) belongs to it: the workflow names the bumps first and keeps
  E_s at its true value, where the distance scale used to be named first for that mean.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from independent_robot import IndependentRobot, generate, rich_protocol
from scipy import stats

from odomgym.diagnose.fit import Dataset, Model
from odomgym.diagnose.generate import NOMINAL_ROBOT
from odomgym.diagnose.likelihood import (
    SensorNoise,
    _chi2_cdf,
    _mixture_level,
    measurement_mask,
    run_predictive,
)
from odomgym.diagnose.replay import replay_run
from odomgym.diagnose.spread import REGIONS, judge_spread, model_without, score_runs
from odomgym.diagnose.workflow import DiagnoseConfig, diagnose
from odomgym.effects import EFFECTS

SENSOR = SensorNoise(0.001, 0.002)
K = 1.5e-3  # [m^½]: wheel noise well above the sensor's, 12 × the detection limit


def _rough(k: float) -> Model:
    return Model(
        EFFECTS["floor_roughness"].write(NOMINAL_ROBOT, {"k_left": k, "k_right": k}), SENSOR
    )


@pytest.fixture(scope="module")
def rough_logs() -> tuple[list, list]:  # type: ignore[type-arg]
    """Fit and held-out runs of a robot on a floor of wheel noise k = :data:`K` (two
    independent draws of the rich protocol)."""
    robot = IndependentRobot(effects={"floor_roughness": {"k_left": K, "k_right": K}})
    fit = generate(robot, rich_protocol(), np.random.default_rng(11))
    held = generate(robot, rich_protocol(), np.random.default_rng(12))
    return fit, held


def test_chi2_closed_forms_are_scipys() -> None:
    """The coverage level of a Gaussian predictive is P(χ²_dim ≤ d²) (Abramowitz & Stegun
    1964, 26.4.4–5): the closed forms match scipy to 1e-12 for one, two and three measured
    components."""
    for dim in (1, 2, 3):
        for q in (0.0, 1e-6, 0.3, 1.0, 2.37, 7.8, 30.0):
            assert _chi2_cdf(q, dim) == pytest.approx(stats.chi2.cdf(q, dim), abs=1e-12)


def test_mixture_level_is_the_mixtures_own_probability() -> None:
    """For a Poisson scale mixture of Gaussians (the bumps' predictive), the level of a point is
    the mixture's probability inside the ellipsoid of its moment-matched covariance through
    that point: checked against 200 000 draws of the mixture itself."""
    rng = np.random.default_rng(3)
    prior = np.diag([4e-6, 3e-6, 2e-5])
    prior[0, 2] = prior[2, 0] = 1e-6
    v1 = np.outer([0.5e-3, 0.2e-3, 8e-3], [0.5e-3, 0.2e-3, 8e-3])
    h = np.eye(3)
    rdiag = np.array([1e-6, 1e-6, 4e-6])
    weights = np.array([0.6, 0.3, 0.08, 0.02])
    draws = np.random.default_rng(20261128).standard_normal((2000, 3))
    work = np.zeros((6, 3, 3))
    covs = [h @ (prior + j * v1) @ h.T + np.diag(rdiag) for j in range(4)]
    mean_cov = sum(w * c for w, c in zip(weights, covs, strict=True))
    inverse = np.linalg.inv(mean_cov)
    count = rng.choice(4, size=200_000, p=weights)
    sample = np.empty((200_000, 3))
    for j in range(4):
        rows = count == j
        sample[rows] = rng.multivariate_normal(np.zeros(3), covs[j], size=int(rows.sum()))
    d2 = np.einsum("ij,jk,ik->i", sample, inverse, sample)
    for nu in ([0.0, 0.0, 0.0], [1e-3, -1e-3, 2e-3], [2e-3, 1e-3, -2e-2], [0.0, 0.0, 0.05]):
        point = np.array(nu)
        level = _mixture_level(prior, v1, h, rdiag, point, 3, weights, 4, draws, work)
        expected = float(np.mean(d2 <= point @ inverse @ point))
        assert level == pytest.approx(expected, abs=0.025)


def test_the_right_wheel_noise_covers_its_regions(rough_logs: tuple[list, list]) -> None:  # type: ignore[type-arg]
    """On held-out logs of the independent generator, the one-step predictive regions of the
    true noise model hold 40–60 % and 90–98 % of the errors (Rosenblatt 1952: the levels are
    uniform when the model is right)."""
    _, held = rough_logs
    levels = score_runs(held, _rough(K), 0.25).levels
    assert levels.size > 500
    for q, low, high in REGIONS:
        assert low <= float(np.mean(levels <= q)) <= high


def test_a_merely_widened_covariance_is_refused(rough_logs: tuple[list, list]) -> None:  # type: ignore[type-arg]
    """The right wheel noise is confirmed against the model without it; the same noise widened
    three-fold (or narrowed three-fold) beats a model without any wheel noise by its score but
    is refused — its regions hold too much (or too little) of the held-out errors."""
    fit, held = rough_logs
    data = Dataset.of(fit, 0.25)
    right = _rough(K)
    without = model_without(data, right, "floor_roughness", ["floor_roughness"])
    assert EFFECTS["floor_roughness"].is_absent(EFFECTS["floor_roughness"].read(without.spec))
    check = judge_spread("floor_roughness", held, right, without, 0.25)
    assert check.confirmed, check.reason
    wide = judge_spread("floor_roughness", held, _rough(3 * K), without, 0.25)
    assert wide.better and not wide.calibrated and not wide.confirmed
    assert wide.coverage["50"] > 0.6 and "too wide" in wide.reason
    narrow = judge_spread("floor_roughness", held, _rough(K / 3), without, 0.25)
    assert not narrow.confirmed and "too narrow" in narrow.reason
    # A widened model also scores worse than the right one: the log score is proper.
    assert wide.score_with < check.score_with and narrow.score_with < check.score_with


def test_run_predictive_is_the_filters_likelihood(rough_logs: tuple[list, list]) -> None:  # type: ignore[type-arg]
    """The log predictive density of a run's open-loop errors is the filter's log-likelihood
    (the same prediction-error decomposition), and there is one level per measured sample."""
    from odomgym.diagnose.likelihood import run_likelihood

    run = rough_logs[1][0]
    model = _rough(K)
    rep = replay_run(run, model.spec)
    mask = measurement_mask(run, 0.25)
    scored = run_predictive(run, rep, model.spec, model.sensor, mask)
    assert scored.loglik == run_likelihood(run, rep, model.spec, model.sensor, mask).loglik
    assert scored.levels.size == int(mask[1:].any(axis=1).sum())
    assert np.all((scored.levels >= 0.0) & (scored.levels <= 1.0))


@pytest.mark.slow
def test_bumps_are_named_first_and_keep_their_mean() -> None:
    """Hidden floor bumps (0.5 crossings per metre, each losing 3 mm of one wheel's travel, as
    cables of about 16 mm under this wheel): the workflow names **floor_bumps** first — not the
    distance scale their mean loss looks like, which the backward check hands to the bumps —
    their held-out log score beats the model without them by more than a standard error, and E_s
    stays at its true value 1.

    Not asserted, known limits recorded in docs/diagnose.md: the 95 % region's coverage (on
    the generators' bump fields 89–94 %, against the 90 % required), and the size of the bumps:
    the filter's jump mixture fits fewer and smaller jumps than the generator makes (here 0.28
    per metre of 12 mrad for 0.5 of 15 mrad: a mean loss of 0.46 of the true one)."""
    jump = 0.003 / 0.2
    robot = IndependentRobot(effects={"floor_bumps": {"rate": 0.5, "heading_jump": jump}})
    runs = generate(robot, rich_protocol(), np.random.default_rng(5))
    result = diagnose(runs, NOMINAL_ROBOT, DiagnoseConfig(seed=5))
    assert result.named_effects[0] == "floor_bumps", result.named_effects
    assert "distance_scale" not in result.named_effects
    check = next(c for c in result.spread if c["effect"] == "floor_bumps")
    assert check["better"], check["reason"]
    assert 0.40 <= check["coverage"]["50"] <= 0.60
    assert result.model.e_s == 1.0
    moved = next(v for k, v in result.geometry_check.items() if k.startswith("E_s"))
    assert moved["moved_by"] == ["floor_bumps"] and moved["without_noise_effects"] < 1.0
    rate = result.parameters["floor_bumps"]["rate"]["value"]
    size = result.parameters["floor_bumps"]["heading_jump"]["value"]
    assert rate > 0.0 and size > 0.0 and math.isfinite(check["difference"])

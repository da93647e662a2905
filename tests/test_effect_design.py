"""Experiment design over the effect catalogue (issue 45, steps 1–3): the prior, the menu's
linear-Gaussian model, the exact subset posterior and the schedule searches.

A small menu keeps the file fast (its model is built once: ~40 replays).
"""

from __future__ import annotations

import itertools
import math
import time

import numpy as np
import pytest
from scipy.linalg import block_diag
from scipy.stats import multivariate_normal

from odomgym.design import (
    DEFAULT_PRIOR,
    DesignPrior,
    DesignRobots,
    EffectPrior,
    LinearModel,
    ModelPosterior,
    SessionRobot,
    SubsetPrior,
    best_fixed_schedule,
    build_model,
    greedy_session,
    oracle_loss,
    oracle_schedules,
    select,
    spec_of,
    validation_errors,
    validation_runs,
)
from odomgym.design.menu import item_run
from odomgym.design.model import SENSOR, WHEEL_NOISE_K, wheel_noise_covariance
from odomgym.design.nonlinear import ReplayModel, laplace_estimate, relinearised_estimate
from odomgym.design.prior import PARAMETERS
from odomgym.design.schedules import check_budget, enumerate_schedules
from odomgym.design.tree import PROBES, SURVEY, tree_session
from odomgym.diagnose.replay import replay_run
from odomgym.errors import SpecError

SMALL = ("spin180", "spin180-back", "straight3", "circle0.25")


@pytest.fixture(scope="module")
def model() -> LinearModel:
    return build_model(select(SMALL))


def _theta(**values: float) -> np.ndarray:
    theta = np.zeros(len(PARAMETERS))
    names = [f"{e}.{p}" for e, p in PARAMETERS]
    for key, value in values.items():
        theta[names.index(key.replace("__", "."))] = value
    return theta


def test_posterior_after_several_updates_equals_batch_weighted_least_squares(
    model: LinearModel,
) -> None:
    rng = np.random.default_rng(3)
    theta = _theta(wheelbase__e_b=0.02, turn_skid__gain=0.4, wheel_diameter_ratio__e_d=-0.004)
    post = ModelPosterior(model)
    jacs, covs, ys = [], [], []
    for i in (0, 2, 3, 2, 1):
        y = model.items[i].measure(theta, rng)
        post.update(i, y)
        jacs.append(model.items[i].jacobian)
        covs.append(model.items[i].chol @ model.items[i].chol.T)
        ys.append(y)
    # R is block diagonal (runs independent): JᵀR⁻¹J and JᵀR⁻¹y block by block
    jtr = np.hstack([np.linalg.solve(c, jj).T for jj, c in zip(jacs, covs, strict=True)])
    j, y = np.vstack(jacs), np.concatenate(ys)
    mean0, var0 = model.prior.gaussian()
    for subset in range(model.prior.subsets):
        cols = model.prior.subset_columns(subset)
        p0inv = np.diag(1.0 / var0[cols])
        lam = p0inv + jtr[cols] @ j[:, cols]
        batch = np.linalg.solve(lam, p0inv @ mean0[cols] + jtr[cols] @ y)
        got = post.subset_mean(subset)
        np.testing.assert_allclose(got[cols], batch, rtol=1e-7, atol=1e-12)
        absent = np.setdiff1d(np.arange(len(PARAMETERS)), cols)
        assert not got[absent].any()
        np.testing.assert_allclose(post.stats.cov[subset][np.ix_(cols, cols)], np.linalg.inv(lam))


def test_marginal_likelihood_equals_the_closed_form(model: LinearModel) -> None:
    """ln p(y | S) = ln N(y; J·μ₀, J·P₀·Jᵀ + R) for every subset (Bishop 2006, Eq. 3.86)."""
    rng = np.random.default_rng(4)
    theta = _theta(backlash__angle=0.02, wheelbase__e_b=-0.01)
    post = ModelPosterior(model)
    jacs, covs, ys = [], [], []
    for i in (1, 2):
        y = model.items[i].measure(theta, rng)
        post.update(i, y)
        jacs.append(model.items[i].jacobian)
        covs.append(model.items[i].chol @ model.items[i].chol.T)
        ys.append(y)
    j, r, y = np.vstack(jacs), block_diag(*covs), np.concatenate(ys)
    mean0, var0 = model.prior.gaussian()
    evidence = post.log_evidence()
    for subset in range(model.prior.subsets):
        cols = model.prior.subset_columns(subset)
        js = j[:, cols]
        closed = multivariate_normal.logpdf(
            y, js @ mean0[cols], js @ np.diag(var0[cols]) @ js.T + r
        )
        assert evidence[subset] == pytest.approx(closed, abs=1e-6)
    # and the model posterior is the prior times the evidence, normalised
    w = evidence + model.prior.log_subset_prior()
    np.testing.assert_allclose(post.probability(), np.exp(w - w.max()) / np.exp(w - w.max()).sum())


def test_the_jacobian_predicts_the_replay_and_is_exact_for_backlash_and_skid_headings(
    model: LinearModel,
) -> None:
    """Small θ: J·θ is the replay's change of the measured poses (0.1 %). The one-sided
    effects' replay is linear in them from their absent value (docs/effects.md steps 1 and 4),
    so the headings stay exact at the prior's sizes; the positions, which follow the heading
    through cos and sin, do not (the linear model's limit, docs/effect-design.md)."""
    for i, item in enumerate(model.items):
        run = item_run(item.item.experiment)
        rows = np.arange(len(run.time))[20::20]
        base = replay_run(run, spec_of(np.zeros(8))).tracked
        # (θ, headings only, relative tolerance): second-order terms ~ the heading change
        for theta, heading_only, tolerance in (
            (
                _theta(wheelbase__e_b=1e-4, wheel_toe__angle=2e-4, gt_sensor_offset__dx=1e-3),
                False,
                1e-3,
            ),
            (_theta(backlash__angle=1e-3, turn_skid__gain=5e-3), False, 2e-2),
            (_theta(backlash__angle=0.03), True, 1e-6),
            (_theta(turn_skid__gain=0.5), True, 1e-6),
        ):
            moved = replay_run(run, spec_of(theta)).tracked
            change = (moved - base)[rows]
            predicted = (model.items[i].jacobian @ theta)[: 3 * len(rows)].reshape(-1, 3)
            if heading_only:
                change, predicted = change[:, 2], predicted[:, 2]
            scale = max(float(np.abs(change).max()), 1e-6)
            assert np.abs(predicted - change).max() <= tolerance * scale + 1e-9, item.item.name


def test_wheel_noise_heading_variance_on_a_straight_is_chong_and_kleeman() -> None:
    """Along a straight of d metres both wheels roll d: the heading variance is
    2·k²·d/b² (Chong & Kleeman 1997, Eq. 4 summed over the wheels)."""
    (item,) = select(("straight3",))
    run = item_run(item.experiment)
    rows = np.array([len(run.time) - 1])
    cov = wheel_noise_covariance(run, rows, WHEEL_NOISE_K, spec_of(np.zeros(8)))
    d = 3.0
    assert cov[2, 2] == pytest.approx(2 * WHEEL_NOISE_K**2 * d / 0.2**2, rel=1e-3)
    # lateral: the heading's random walk integrated along the run, ≥ its end-heading share
    assert cov[1, 1] > 0 and cov[0, 0] == pytest.approx(WHEEL_NOISE_K**2 * d / 2, rel=1e-3)


def test_an_update_takes_milliseconds(model: LinearModel) -> None:
    rng = np.random.default_rng(0)
    post = ModelPosterior(model)
    times = []
    for k in range(20):
        y = model.items[k % 4].measure(np.zeros(8), rng)
        t0 = time.perf_counter()
        post.update(k % 4, y)
        post.estimate()
        times.append(time.perf_counter() - t0)
    assert float(np.median(times)) < 0.02  # measured ~0.5 ms; 40× slack for a loaded CI


def test_the_oracle_is_never_worse_than_the_fixed_schedule_in_the_linear_model(
    model: LinearModel,
) -> None:
    prior = SubsetPrior.of(model)
    robots = DesignRobots.draw(model, 40, 4.0, np.random.default_rng(1))
    fixed = best_fixed_schedule(model, prior, 4.0, robots)
    assert fixed @ model.costs <= 4.0 + 1e-9
    oracles = oracle_schedules(model, prior, 4.0, fixed)
    for s, schedule in enumerate(oracles):
        assert schedule @ model.costs <= 4.0 + 1e-9
        assert oracle_loss(model, prior, s, schedule) <= oracle_loss(model, prior, s, fixed)


def test_enumeration_lists_every_schedule_within_the_budget() -> None:
    costs = np.array([1.0, 1.5, 2.5])
    got = enumerate_schedules(costs, 4.0)
    assert got is not None
    brute = [c for c in itertools.product(range(5), repeat=3) if any(c) and np.dot(c, costs) <= 4.0]
    assert sorted(map(tuple, got.tolist())) == sorted(brute)
    assert enumerate_schedules(costs, 40.0, limit=10) is None


def test_prior_draws_lie_in_the_stated_ranges() -> None:
    rng = np.random.default_rng(7)
    draws = [DEFAULT_PRIOR.draw(rng) for _ in range(2000)]
    present = np.array([[s >> k & 1 for k in range(4)] for s, _ in draws])
    # each effect present with probability 0.3: 2000 draws, 5 standard errors
    assert np.all(np.abs(present.mean(axis=0) - 0.3) < 5 * math.sqrt(0.21 / 2000))
    theta = np.array([t for _, t in draws])
    for g, j in zip(DEFAULT_PRIOR.geometry, (0, 1, 2), strict=True):
        assert np.abs(theta[:, j]).max() <= g.half_range
    for k, e in enumerate(DEFAULT_PRIOR.effects):
        on = present[:, k] == 1
        cols = DEFAULT_PRIOR.subset_columns(1 << k)[3:]
        size = np.linalg.norm(theta[on][:, cols], axis=1)
        assert size.min() >= e.low and size.max() <= e.high
        assert not theta[~on][:, cols].any()


def test_same_seed_gives_bit_identical_sessions(model: LinearModel) -> None:
    prior = SubsetPrior.of(model)

    def session() -> tuple[np.ndarray, list[int]]:
        rng = np.random.default_rng(np.random.SeedSequence([5, 1]))
        _, theta = model.prior.draw(rng)
        robot = SessionRobot(model, theta, (5, 2))
        post = greedy_session(model, prior, robot, 5.0, rng, draws=4)
        return post.estimate(), post.taken

    (a, ta), (b, tb) = session(), session()
    assert a.tobytes() == b.tobytes() and ta == tb and len(ta) > 0


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"probability": 1.5}, "prior.turn_skid.probability"),
        ({"low": 0.5, "high": 0.1}, "prior.turn_skid.low"),
        ({"high": 50.0}, "prior.turn_skid.high"),
    ],
)
def test_a_bad_prior_range_is_a_one_line_error_naming_the_field(
    change: dict[str, float], field: str
) -> None:
    good = DEFAULT_PRIOR.effects[1]
    bad = EffectPrior(**{**good.__dict__, **change})
    with pytest.raises(SpecError) as info:
        DesignPrior(
            DEFAULT_PRIOR.geometry, (DEFAULT_PRIOR.effects[0], bad, *DEFAULT_PRIOR.effects[2:])
        )
    assert info.value.field == field
    assert field in str(info.value) and "\n" not in str(info.value)


def test_an_unknown_menu_item_or_an_unaffordable_budget_is_a_one_line_error(
    model: LinearModel,
) -> None:
    with pytest.raises(SpecError, match="unknown item 'spin999'") as info:
        select(("spin180", "spin999"))
    assert info.value.field == "menu" and "\n" not in str(info.value)
    with pytest.raises(SpecError, match="budget") as info:
        check_budget(0.01, model)
    assert info.value.field == "budget"


def test_the_sensor_is_the_detection_limit_tables() -> None:
    assert SENSOR == (0.001, 0.002)


def test_relinearising_recovers_a_robot_the_linear_model_misses(model: LinearModel) -> None:
    """A robot at the prior's upper sizes measured through the replay: the linear model's
    estimate misses the validation runs by ~10 cm; relinearised (Gauss–Newton, converged in
    3 steps) it does as well as the same runs do on the linear model's own data."""
    theta = _theta(wheelbase__e_b=0.045, turn_skid__gain=0.7, backlash__angle=0.035)
    replay = ReplayModel(model)
    prior = SubsetPrior.of(model)
    taken = [0, 1, 2, 3, 0, 2]
    rng = np.random.default_rng(11)
    ys = [replay.measure(i, theta, rng) for i in taken]
    rng = np.random.default_rng(11)  # the same noise, on the linear model's data
    post = ModelPosterior(model, prior)
    for i in taken:
        post.update(i, model.items[i].measure(theta, rng))
    runs = validation_runs()
    linear, _ = relinearised_estimate(replay, prior, taken, ys, iterations=0)
    iterated, prob = relinearised_estimate(replay, prior, taken, ys, iterations=3)
    before = validation_errors(linear, theta, runs).combined
    after = validation_errors(iterated, theta, runs).combined
    own = validation_errors(post.estimate(), theta, runs).combined
    assert before > 5 * own and after < 1.5 * own, (before, after, own)
    assert int(np.argmax(prob)) == 0b0110  # turn skid and backlash, nothing else
    # each subset relinearised around its own mode, weighted by its Laplace evidence
    laplace, prob = laplace_estimate(replay, prior, taken, ys, iterations=2)
    assert validation_errors(laplace, theta, runs).combined < 1.5 * own
    assert int(np.argmax(prob)) == 0b0110


def test_the_scripted_tree_surveys_first_probes_the_undecided_and_keeps_the_budget(
    model: LinearModel,
) -> None:
    prior = SubsetPrior.of(model)
    theta = _theta(turn_skid__gain=0.5)
    with pytest.raises(SpecError, match="spin360-ccw") as info:
        tree_session(model, prior, SessionRobot(model, theta, (1,)), 10.0)
    assert info.value.field == "menu"
    full = build_model(select((*SURVEY, *PROBES.values())))
    full_prior = SubsetPrior.of(full)

    def session() -> tuple[list[str], np.ndarray]:
        post = tree_session(full, full_prior, SessionRobot(full, theta, (1,)), 10.0)
        return [full.names[i] for i in post.taken], post.estimate()

    (names, a), (again, b) = session(), session()
    assert names == again and a.tobytes() == b.tobytes()
    assert names[:3] == list(SURVEY)
    assert "circle0.25" in names  # the skid is undecided after the survey: probed
    travel = sum(full.costs[full.names.index(n)] for n in names)
    assert travel <= 10.0 + 1e-9
    # it stops only when the next item of its cycle (straight, 180° spin, …) no longer fits
    assert travel + full.costs[full.names.index("spin180")] > 10.0 - 1e-9

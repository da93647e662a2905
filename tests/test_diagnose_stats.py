"""The statistical tests of ``odomgym.diagnose.stats`` against numbers known in closed form.

Each expected value is derived by hand (a χ² with two degrees of freedom has survival function
exp(−x/2), a χ² with one is erfc(√(x/2)), a Student t with three degrees of freedom has an
elementary CDF, a sign-flip test over few units is a count of sign patterns), so a change of any
test's formula, correction or tie rule fails here, not only somewhere inside a diagnosis.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from odomgym.diagnose import stats as dstats

DIAGNOSE = Path(__file__).resolve().parents[1] / "odomgym" / "diagnose"


# ------------------------------------------------------------------ likelihood-ratio tests
def test_likelihood_ratio_is_twice_the_gain_and_never_negative() -> None:
    assert dstats.likelihood_ratio(1.5) == 3.0
    assert dstats.likelihood_ratio(-0.3) == 0.0
    assert dstats.likelihood_ratio(0.0) == 0.0


def test_lr_test_two_dof_is_exp_minus_half_and_bonferroni_multiplies() -> None:
    # χ²₂ survival function: exp(−x/2).
    assert dstats.lr_test(10.0, 2, 1) == pytest.approx(math.exp(-5.0), rel=1e-12)
    assert dstats.lr_test(10.0, 2, 4) == pytest.approx(4 * math.exp(-5.0), rel=1e-12)
    # χ²₁ at its 95 % point: p = 0.05; three candidates: 0.15.
    assert dstats.lr_test(3.841458820694124, 1, 1) == pytest.approx(0.05, rel=1e-9)
    assert dstats.lr_test(3.841458820694124, 1, 3) == pytest.approx(0.15, rel=1e-9)
    # A statistic of 0 is p = 1, and the correction never exceeds 1.
    assert dstats.lr_test(0.0, 3, 1) == 1.0
    assert dstats.lr_test(1.0, 1, 5) == 1.0


def test_bonferroni_and_its_combination() -> None:
    assert dstats.bonferroni(0.01, 7) == pytest.approx(0.07)
    assert dstats.bonferroni(0.3, 4) == 1.0
    assert dstats.combine_bonferroni(0.01, 0.3) == pytest.approx(0.02)
    assert dstats.combine_bonferroni(0.6, 0.9) == 1.0
    assert dstats.combine_bonferroni(0.004, 0.5, 0.2) == pytest.approx(0.012)


def test_wald_p_is_two_sided_and_corrected() -> None:
    z95 = 1.959963984540054  # the standard normal's 97.5 % point
    assert dstats.wald_p(z95, 1) == pytest.approx(0.05, rel=1e-9)
    assert dstats.wald_p(-z95, 1) == pytest.approx(0.05, rel=1e-9)
    assert dstats.wald_p(z95, 10) == pytest.approx(0.5, rel=1e-9)
    assert dstats.wald_p(0.0, 1) == 1.0


# ------------------------------------------------------------------ the consistency check
def test_whiteness_p_from_run_means_and_lag_one_correlation() -> None:
    """One run, four samples; only x measured, all +1: the mean statistic is 4²/4 = 4 (χ²₁:
    p = erfc(√2)), the lag-1 statistic 3/√3 = √3 (p = erfc(√1.5)); Bonferroni: twice the smaller.
    The y column's single measured value (a series of one) and every unmeasured value count for
    nothing."""
    w = np.zeros((4, 3))
    w[:, 0] = 1.0
    w[2, 1] = 50.0  # y measured once: ignored
    w[:, 2] = 99.0  # θ not measured: ignored
    mask = np.zeros((4, 3), dtype=bool)
    mask[:, 0] = True
    mask[2, 1] = True
    p_mean = math.erfc(math.sqrt(2.0))
    p_lag = math.erfc(math.sqrt(1.5))
    assert p_mean < p_lag
    expected = 2.0 * p_mean
    assert dstats.whiteness_p([w.reshape(-1)], [mask]) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(0.0910005277927, rel=1e-9)


def test_whiteness_p_of_alternating_signs_is_driven_by_the_lag_term() -> None:
    """x = (+1, −1, +1, −1): the mean is 0 (χ²₁ = 0, p = 1), the lag products are all −1:
    |−3/√3| = √3, p = erfc(√1.5), doubled."""
    w = np.zeros((4, 3))
    w[:, 0] = [1.0, -1.0, 1.0, -1.0]
    mask = np.zeros((4, 3), dtype=bool)
    mask[:, 0] = True
    got = dstats.whiteness_p([w.reshape(-1)], [mask])
    assert got == pytest.approx(2.0 * math.erfc(math.sqrt(1.5)), rel=1e-12)


def test_whiteness_p_without_a_series_is_one() -> None:
    assert dstats.whiteness_p([], []) == 1.0
    mask = np.zeros((2, 3), dtype=bool)
    mask[1] = True  # one sample per component: no series of two
    assert dstats.whiteness_p([np.full(6, 5.0)], [mask]) == 1.0


# ------------------------------------------------------------------ the gap report
def test_bootstrap_of_two_points_spans_them() -> None:
    """Resampled means of (0, 1) are 0, 1/2 or 1 with probabilities 1/4, 1/2, 1/4: the
    2.5 % and 97.5 % percentiles are 0 and 1."""
    rng = np.random.default_rng(0)
    assert dstats.bootstrap_ci([np.array([0.0, 1.0])], lambda v: float(np.mean(v)), rng) == [
        0.0,
        1.0,
    ]


def test_bootstrap_of_a_normal_sample_matches_the_standard_error() -> None:
    """The percentile interval of a mean of 1000 standard-normal values is the mean ± 1.96 of
    its standard error (0.062) to a few per cent; the same Generator state gives the same
    interval, and paired samples are resampled together."""
    x = np.random.default_rng(3).standard_normal(1000)
    se = x.std(ddof=1) / math.sqrt(len(x))

    def mean(v: np.ndarray) -> float:
        return float(np.mean(v))

    low, high = dstats.bootstrap_ci([x], mean, np.random.default_rng(7))
    assert low == pytest.approx(x.mean() - 1.96 * se, abs=0.1 * se)
    assert high == pytest.approx(x.mean() + 1.96 * se, abs=0.1 * se)
    assert dstats.bootstrap_ci([x], mean, np.random.default_rng(7)) == [low, high]
    # Paired: the difference of a sample with itself shifted by 2 is 2 in every draw.
    diff = dstats.bootstrap_ci(
        [x + 2.0, x], lambda a, b: float(np.mean(a - b)), np.random.default_rng(1), draws=200
    )
    assert diff == pytest.approx([2.0, 2.0], abs=1e-12)


def test_bootstrap_of_an_undefined_statistic_is_nan() -> None:
    got = dstats.bootstrap_ci([np.ones(5)], lambda v: math.nan, np.random.default_rng(0), 100)
    assert all(math.isnan(v) for v in got) and len(got) == 2


def test_rms_and_reducible_fraction() -> None:
    assert dstats.rms(np.array([1.0, 4.0, 4.0])) == pytest.approx(math.sqrt(3.0))
    before, after, floor = np.array([4.0, 4.0]), np.array([2.0, 2.0]), np.ones(2)
    assert dstats.reducible_fraction(before, after, floor) == pytest.approx(2.0 / 3.0)
    assert math.isnan(dstats.reducible_fraction(floor, after, floor))  # nothing to close


# ------------------------------------------------------------------ sign-flip tests
def test_studentised_mean() -> None:
    # (1, 2, 3, 4): mean 2.5, sd √(5/3), t = 2.5/(sd/2) = √15.
    t = dstats.studentised(np.array([[1.0, 2.0, 3.0, 4.0], [2.0, 2.0, 2.0, 2.0]]))
    assert t[0] == pytest.approx(math.sqrt(15.0), rel=1e-12)
    assert t[1] == math.inf  # every run agrees
    assert dstats.studentised(np.array([-1.0, -1.0])) == 0.0


def test_max_t_of_one_candidate_is_the_share_of_sign_patterns() -> None:
    """Four runs that all improve by the same amount: t = ∞, reached by the identity pattern
    only among 2⁴ = 16, so p = 1/16."""
    t, p = dstats.max_t_test(np.ones((1, 4)), np.random.default_rng(0))
    assert t[0] == math.inf
    assert p[0] == pytest.approx(1.0 / 16.0)


def test_max_t_corrects_for_the_family() -> None:
    """A second candidate whose improvements alternate (t = 0) turns into a unanimous one under
    the pattern (+, −, +, −): the null maximum now reaches ∞ twice in 16, and the first
    candidate's family-wise p-value doubles to 1/8. The second's t = 0 is missed only where
    both candidates' flipped means are negative: s₁ = s₃ = −1 and s₂ = −s₄ (two patterns), so
    p = 14/16."""
    d = np.array([[1.0, 1.0, 1.0, 1.0], [1.0, -1.0, 1.0, -1.0]])
    t, p = dstats.max_t_test(d, np.random.default_rng(0))
    assert t.tolist() == [math.inf, 0.0]
    assert p.tolist() == pytest.approx([2.0 / 16.0, 14.0 / 16.0])


def test_max_t_with_random_flips_counts_the_identity() -> None:
    """Twenty runs (> 12: random patterns): a unanimous improvement is matched by the identity
    row only (a random row is all + with chance 2⁻²⁰), p = 1/draws."""
    _, p = dstats.max_t_test(np.ones((1, 20)), np.random.default_rng(5), draws=500)
    assert p[0] == pytest.approx(1.0 / 500.0)


def test_sign_matrix_is_exact_for_few_units_and_seeded_beyond() -> None:
    rng = np.random.default_rng(0)
    exact = dstats.sign_matrix(3, rng, draws=10)
    assert exact.shape == (8, 3)
    assert {tuple(row) for row in exact.tolist()} == {
        (a, b, c) for a in (1.0, -1.0) for b in (1.0, -1.0) for c in (1.0, -1.0)
    }
    drawn = dstats.sign_matrix(13, np.random.default_rng(4), draws=10)
    assert drawn.shape == (10, 13)
    assert (drawn[0] == 1.0).all()
    assert np.array_equal(drawn, dstats.sign_matrix(13, np.random.default_rng(4), draws=10))


def test_sign_flip_p_counts_patterns_reaching_the_observed_norm() -> None:
    """Two unit scores (1) and (1): the sums under (±, ±) are 2, 0, 0, −2; their squares reach
    the observed 4 in two patterns of four."""
    parts = np.array([[1.0], [1.0]])
    basis = np.eye(1)
    assert dstats.sign_flip_p(parts, basis, 4.0, np.random.default_rng(0), 100) == 0.5
    assert dstats.sign_flip_p(parts, basis, 0.0, np.random.default_rng(0), 100) == 1.0


def test_sign_flip_p_draws_its_patterns_in_blocks_of_rows_as_one_draw(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Beyond ``_SIGN_CHUNK`` pattern entries the patterns are drawn a block of rows at a time
    (the block sign-flip test's matrix is 4 000 × ~4 400 on real logs): one draw of the whole
    matrix consumes the stream row after row, so the blocks hold its rows. The same p-values as
    one draw, and the generator left where one draw leaves it, with the last block shorter."""
    gen = np.random.default_rng(3)
    parts = gen.normal(size=(50, 4))
    basis = np.linalg.qr(gen.normal(size=(4, 4)))[0]
    whole = np.random.default_rng(9)
    null = np.sum(((dstats.sign_matrix(50, whole, 997) @ parts) @ basis) ** 2, axis=1)
    ranked = np.sort(null)
    monkeypatch.setattr(dstats, "_SIGN_CHUNK", 50 * 64 + 7)  # blocks of 64 rows, 37 last
    for k in (10, 498, 900):
        observed = 0.5 * (ranked[k] + ranked[k + 1])  # between two patterns: no tie
        blocks = np.random.default_rng(9)
        assert dstats.sign_flip_p(parts, basis, observed, blocks, 997) == pytest.approx(
            (997 - k - 1) / 997, abs=1e-15
        )
        assert blocks.bit_generator.state == whole.bit_generator.state


# ------------------------------------------------------------------ standard errors
def test_clustered_covariance_by_hand() -> None:
    """Model covariance 2·I (2×2), three runs in two clusters: s_a = (1, 0) + (0, 1),
    s_b = (1, −1); Σ s·sᵀ = [[2, 0], [0, 2]], sandwich 2·I·that·2·I·G/(G−1) = 8·2·I = 16·I."""
    cov = 2.0 * np.eye(2)
    scores = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, -1.0]])
    got = dstats.clustered_covariance(cov, scores, ["a", "a", "b"])
    assert got == pytest.approx(16.0 * np.eye(2))
    assert np.isnan(dstats.clustered_covariance(cov, scores, ["a"] * 3)).all()
    assert np.isnan(dstats.clustered_covariance(np.full((2, 2), np.inf), scores, [0, 1, 2])).all()


# ------------------------------------------------------------------ the "where" table
def test_mean_t_test_against_the_t_distribution_with_three_dof() -> None:
    """(1, 2, 3, 4): t = √15 with three degrees of freedom, whose CDF is elementary:
    p = 1 − (2/π)·(√5/6 + atan √5) at t²/3 = 5; the 97.5 % point of t₃ is 3.182446305."""
    mean, low, high, p = dstats.mean_t_test(np.array([1.0, 2.0, 3.0, 4.0, math.nan]))
    assert mean == 2.5
    expected = 1.0 - (2.0 / math.pi) * (math.sqrt(5.0) / 6.0 + math.atan(math.sqrt(5.0)))
    assert p == pytest.approx(expected, rel=1e-9)
    se = math.sqrt(5.0 / 3.0) / 2.0
    assert low == pytest.approx(2.5 - 3.182446305284263 * se, rel=1e-9)
    assert high == pytest.approx(2.5 + 3.182446305284263 * se, rel=1e-9)
    flat = dstats.mean_t_test(np.array([1.0, 1.0, 1.0]))
    assert flat[0] == 1.0 and math.isnan(flat[1]) and flat[3] == 1.0


def test_holm_step_down() -> None:
    """Sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1 = 0.02, 0.03, 0.06, 0.04 → monotone:
    0.02, 0.03, 0.06, 0.06."""
    got = dstats.holm(np.array([0.01, 0.04, 0.03, 0.005]))
    assert got.tolist() == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert dstats.holm(np.array([0.5, 0.6])).tolist() == [1.0, 1.0]


# ------------------------------------------------------------------ the dependency direction
def _diagnose_imports(module: str) -> set[str]:
    """Every ``odomgym.diagnose`` module that ``module`` imports, at the top or inside a
    function (a lazy import up the chain would be a cycle too)."""
    tree = ast.parse((DIAGNOSE / f"{module}.py").read_text())
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            if node.module == "odomgym.diagnose":
                found.update(alias.name for alias in node.names)
            elif node.module.startswith("odomgym.diagnose."):
                found.add(node.module.split(".")[2])
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("odomgym.diagnose."):
                    found.add(alias.name.split(".")[2])
    return found


def test_workflow_fit_stats_depend_one_way() -> None:
    """workflow → fit → stats: stats imports no diagnose module, fit neither the workflow (the
    orchestration, its rounds and the steps after them) nor any module that imports it."""
    workflow = {"workflow", "rounds", "verdict"}
    assert _diagnose_imports("stats") == set()
    assert not workflow & _diagnose_imports("fit")
    assert "stats" in _diagnose_imports("fit")
    assert {"fit", "rounds", "verdict"} <= _diagnose_imports("workflow")
    assert {"fit", "stats"} <= _diagnose_imports("rounds")
    assert {"fit", "stats"} <= _diagnose_imports("verdict")
    for below in _diagnose_imports("fit"):
        assert not workflow & _diagnose_imports(below), below

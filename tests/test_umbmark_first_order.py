"""UMBmark inverts its first-order model exactly (Borenstein & Feng 1994, Eqs. 6.3–6.20).

Return errors are built from injected E_d and E_b through the model (α from Eq. 6.29, β from
Eqs. 6.23–6.24, positions from Eqs. 6.19–6.20 and their y counterparts); the estimates must give
back E_d and E_b to rounding (relative 1e-12), from x, from y, and from both.
"""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np
import pytest
from numpy.typing import NDArray

from odomgym.baselines.umbmark import (
    Components,
    UMBmark,
    alpha_from_e_b,
    beta_from_e_d,
    e_b_from_alpha,
    e_d_from_beta,
    first_order_return_errors,
    umbmark_estimates,
)

# (E_d, E_b, side L [m], wheelbase b [m])
CASES = {
    # Borenstein & Feng 1994, Fig. 6.5: LabMate 4 × 4 m, b 340.00 → 336.17 mm, D_R/D_L = 1.00084
    "labmate": (1.00084, 336.17 / 340.0, 4.0, 0.340),
    # solderspot 2014: NavBot 800 mm square, b = 78 mm, first-round estimates
    "navbot": (1.002463028, 0.9918532967, 0.8, 0.078),
    # OptiOdom session 230620202144, the authors' UMBmark: b 0.205 → 0.201304 m
    "optiodom": (0.084022 / 0.083978, 0.201304 / 0.205, 0.75, 0.205),
    "large": (0.99, 1.05, 4.0, 0.5),
}


@pytest.mark.parametrize("use", ["xy", "x", "y"])
@pytest.mark.parametrize("case", list(CASES))
def test_estimates_recover_injected_errors(case: str, use: Components) -> None:
    e_d, e_b, side, b = CASES[case]
    alpha, beta = alpha_from_e_b(e_b), beta_from_e_d(e_d, side, b)
    cw, ccw = first_order_return_errors(alpha, beta, side)
    found = umbmark_estimates([cw] * 5, [ccw] * 5, side, b, use=use)
    assert found.e_d == pytest.approx(e_d, rel=1e-12)
    assert found.e_b == pytest.approx(e_b, rel=1e-12)
    assert found.alpha == pytest.approx(alpha, rel=1e-12)
    assert found.beta == pytest.approx(beta, rel=1e-12)
    assert found.radius == pytest.approx(0.5 * side / math.sin(0.5 * beta), rel=1e-12)


@pytest.mark.parametrize("case", list(CASES))
def test_corrected_wheelbase_variant_recovers_its_own_model(case: str) -> None:
    """The OptiOdom authors put E_b·b into Eq. 6.24; β built with E_b·b comes back exactly, and
    the two variants differ only at second order, |ΔE_d| ≈ |E_b − 1|·|E_d − 1|/E_b."""
    e_d, e_b, side, b = CASES[case]
    cw, ccw = first_order_return_errors(
        alpha_from_e_b(e_b), beta_from_e_d(e_d, side, e_b * b), side
    )
    corrected = umbmark_estimates([cw], [ccw], side, b, use="x", ed_wheelbase="corrected")
    assert corrected.e_d == pytest.approx(e_d, rel=1e-12)
    nominal = umbmark_estimates([cw], [ccw], side, b, use="x")
    assert abs(nominal.e_d - e_d) <= 1.01 * abs(e_b - 1.0) * abs(e_d - 1.0) / min(e_b, 1.0)


def test_non_systematic_spread_averages_out() -> None:
    """Centres of gravity (Eq. 3.2) cancel a symmetric spread of the individual runs."""
    e_d, e_b, side, b = CASES["labmate"]
    cw, ccw = first_order_return_errors(alpha_from_e_b(e_b), beta_from_e_d(e_d, side, b), side)
    spread = np.array([[0.02, -0.01, 0.0], [-0.02, 0.01, 0.0], [0.005, 0.03, 0.0]])
    spread = np.vstack([spread, -spread])
    found = umbmark_estimates(cw + spread, ccw - spread, side, b)
    assert found.e_d == pytest.approx(e_d, rel=1e-12)
    assert found.e_b == pytest.approx(e_b, rel=1e-12)


def test_type_a_and_b_signs_follow_figures_6_1_and_6_2() -> None:
    """A wheelbase larger than believed (E_b > 1) under-turns every corner in both directions
    (Type A, Fig. 6.1); a larger right wheel (E_d > 1) bends every leg left, adding rotation in
    ccw and removing it in cw (Type B, Fig. 6.2)."""
    alpha = alpha_from_e_b(1.02)
    assert alpha > 0.0
    cw, ccw = first_order_return_errors(alpha, 0.0, 4.0)
    assert cw[2] > 0.0 > ccw[2]  # |θ_total| < 2π both ways: true − odometry has these signs
    beta = beta_from_e_d(1.002, 4.0, 0.34)
    assert beta > 0.0
    cw, ccw = first_order_return_errors(0.0, beta, 4.0)
    assert cw[2] > 0.0 and ccw[2] > 0.0  # cw turns less than −2π, ccw more than +2π


def _exact_corners(alpha: float, beta: float, side: float, direction: str) -> NDArray[np.float64]:
    """End point of Borenstein & Feng 1994, Eqs. 6.3–6.18, before the small-angle approximations."""
    a, b, s = alpha, beta, side
    if direction == "ccw":
        type_a = (
            s + s * math.sin(a) - s * math.cos(2 * a) - s * math.sin(3 * a),
            s * math.cos(a) + s * math.sin(2 * a) - s * math.cos(3 * a),
        )
        type_b = (
            s * (math.cos(b / 2) - math.sin(3 * b / 2) - math.cos(5 * b / 2) + math.sin(7 * b / 2)),
            s * (math.sin(b / 2) + math.cos(3 * b / 2) - math.sin(5 * b / 2) - math.cos(7 * b / 2)),
        )
    else:
        type_a = (
            s + s * math.sin(a) - s * math.cos(2 * a) - s * math.sin(3 * a),
            -s * math.cos(a) - s * math.sin(2 * a) + s * math.cos(3 * a),
        )
        type_b = (
            s * (math.cos(b / 2) + math.sin(3 * b / 2) - math.cos(5 * b / 2) - math.sin(7 * b / 2)),
            s * (math.sin(b / 2) - math.cos(3 * b / 2) - math.sin(5 * b / 2) + math.cos(7 * b / 2)),
        )
    return np.add(type_a, type_b, dtype=np.float64)


@pytest.mark.parametrize("direction", ["cw", "ccw"])
def test_first_order_model_is_the_small_angle_limit_of_the_exact_equations(direction: str) -> None:
    """Superposing the exact Eqs. 6.3–6.18 differs from Eqs. 6.19–6.20 only at O(L·γ²)."""
    side = 4.0
    for alpha, beta in ((0.01, 0.0), (0.0, 0.01), (0.01, -0.004), (-0.003, 0.002)):
        model = first_order_return_errors(alpha, beta, side)[0 if direction == "cw" else 1]
        exact = _exact_corners(alpha, beta, side, direction)
        assert np.allclose(model[:2], exact, atol=20 * side * max(abs(alpha), abs(beta)) ** 2)


def test_equation_helpers_are_inverse_and_finite() -> None:
    assert e_b_from_alpha(alpha_from_e_b(0.97)) == pytest.approx(0.97, rel=1e-14)
    assert e_d_from_beta(beta_from_e_d(1.003, 4.0, 0.34), 4.0, 0.34) == pytest.approx(1.003)
    assert e_d_from_beta(0.0, 4.0, 0.34) == 1.0  # R = ∞ handled
    assert math.isinf(umbmark_estimates([[0.0, 0.0]], [[0.0, 0.0]], 4.0, 0.34).radius)
    with pytest.raises(ValueError, match="outside the model"):
        e_b_from_alpha(2.0)
    with pytest.raises(ValueError, match="first-order model"):
        e_d_from_beta(3.0, 0.2, 0.5)


def test_calibrator_arguments_are_checked() -> None:
    with pytest.raises(ValueError, match="no E_s phase"):
        UMBmark(conventions="optiodom", second_compensation=True)
    with pytest.raises(ValueError, match="conventions"):
        UMBmark(conventions=cast(Any, "borenstein"))
    assert UMBmark(conventions="optiodom").use == "x"
    assert UMBmark().use == "xy"
    assert [e.kind for e in UMBmark().experiments()] == ["straight"] * 2 + ["square"] * 2

"""Jung & Chung's heading-error equations: exact inversion of their model, agreement with the
first-order model of Borenstein & Feng 1994, and the OptiOdom authors' heading-centre bug."""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np
import pytest

from odomgym.baselines.jung_chung import (
    JungChung,
    heading_centre,
    jung_chung_estimates,
    jung_chung_from_headings,
)
from odomgym.baselines.umbmark import (
    alpha_from_e_b,
    beta_from_e_d,
    e_b_from_alpha,
    first_order_return_errors,
)

# (E_d, E_b, side L [m], wheelbase b [m])
CASES = {
    "labmate": (1.00084, 336.17 / 340.0, 4.0, 0.340),
    "optiodom": (0.99893, 1.0073, 0.75, 0.2),
    "large": (1.01, 0.95, 4.0, 0.5),
}


def _headings(e_d: float, e_b: float, side: float, b: float) -> tuple[float, float]:
    """θ_cw, θ_ccw [rad] in Jung & Chung's model: each corner turns α_b too little, of which
    α_d = π·b·β/(4L) is undone by the larger wheel; each leg bends by β."""
    beta = beta_from_e_d(e_d, side, e_b * b)
    alpha_b = alpha_from_e_b(e_b) - math.pi * b * beta / (4.0 * side)
    return 4.0 * (alpha_b + beta), 4.0 * (beta - alpha_b)


@pytest.mark.parametrize("case", list(CASES))
def test_estimates_invert_the_model(case: str) -> None:
    e_d, e_b, side, b = CASES[case]
    found = jung_chung_from_headings(*_headings(e_d, e_b, side, b), side, b)
    assert found.e_b == pytest.approx(e_b, rel=1e-12)
    assert found.e_d == pytest.approx(e_d, rel=1e-12)
    assert found.alpha_d == pytest.approx(math.pi * b * found.beta / (4 * side), rel=1e-12)


@pytest.mark.parametrize("case", list(CASES))
def test_angles_agree_with_the_first_order_model_of_borenstein_feng_1994(case: str) -> None:
    """From the return errors of the model of Borenstein & Feng 1994, α_b and β are UMBmark's α
    and β exactly; E_d too (to second order); E_b differs by the α_d that Jung & Chung attribute
    to E_d."""
    e_d, e_b, side, b = CASES[case]
    alpha, beta = alpha_from_e_b(e_b), beta_from_e_d(e_d, side, b)
    cw, ccw = first_order_return_errors(alpha, beta, side)
    found = jung_chung_estimates([cw] * 3, [ccw] * 3, side, b)
    assert found.alpha_b == pytest.approx(alpha, rel=1e-9)
    assert found.beta == pytest.approx(beta, rel=1e-9)
    assert found.e_b == pytest.approx(e_b_from_alpha(alpha + found.alpha_d), rel=1e-12)
    assert abs(found.e_d - e_d) <= 1.05 * abs(e_b - 1.0) * abs(e_d - 1.0) + 1e-15


def test_heading_centre_is_circular() -> None:
    near_pi = np.array([[0, 0, math.pi - 0.01], [0, 0, -math.pi + 0.03]])
    assert abs(heading_centre(near_pi)) == pytest.approx(math.pi - 0.01, abs=1e-9)
    small = np.array([[0, 0, 0.01], [0, 0, 0.03], [0, 0, 0.02]])
    assert heading_centre(small) == pytest.approx(0.02, abs=1e-8)


@pytest.mark.parametrize("n", [1, 3, 5])
def test_optiodom_heading_centre_divides_by_n_twice(n: int) -> None:
    """The authors' computeEvaluationMeasures.m: wrapToPi(atan2(Σsin, Σcos)/n)."""
    errors = np.tile([0.0, 0.0, -0.12], (n, 1))
    assert heading_centre(errors) == pytest.approx(-0.12)
    assert heading_centre(errors, mean="optiodom") == pytest.approx(-0.12 / n)


def test_optiodom_convention_shrinks_the_correction_by_n() -> None:
    """With n runs per direction the buggy centres make α_b, β, hence E − 1, about n× too small."""
    e_d, e_b, side, b = CASES["large"]
    theta_cw, theta_ccw = _headings(e_d, e_b, side, b)
    n = 5
    cw = np.tile([0.0, 0.0, theta_cw], (n, 1))
    ccw = np.tile([0.0, 0.0, theta_ccw], (n, 1))
    right = jung_chung_estimates(cw, ccw, side, b)
    buggy = jung_chung_estimates(cw, ccw, side, b, heading_mean="optiodom")
    assert buggy.beta == pytest.approx(right.beta / n)
    assert buggy.alpha_b == pytest.approx(right.alpha_b / n)
    assert (buggy.e_b - 1.0) / (right.e_b - 1.0) == pytest.approx(1.0 / n, rel=0.1)


def test_arguments_are_checked() -> None:
    with pytest.raises(ValueError, match="conventions"):
        JungChung(conventions=cast(Any, "umbmark"))
    with pytest.raises(ValueError, match="shape"):
        heading_centre(np.zeros((3, 2)))
    assert [(e.kind, e.direction) for e in JungChung().experiments()] == [
        ("square", "cw"),
        ("square", "ccw"),
    ]

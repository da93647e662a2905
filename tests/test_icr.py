"""Skid-steer odometry models (:mod:`odomgym.odometry.icr`): their equations and their fits.

The fits are checked on runs whose ground truth *is* a model with known parameters (the wheel
travel of a circle or a free path, the poses dead-reckoned through the model), so that the
known answer is exact; the simulated robots' figures live in ``odomgym bench skid``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from odomgym.odometry.icr import SkidModel, fit_skid_model, skid_dead_reckon
from odomgym.odometry.runs import Run
from odomgym.robot import PRESETS

ROBOT = PRESETS["scout2"]
B = ROBOT.wheelbase


def _travels(curvatures: list[float], step: float = 0.01, seconds: float = 8.0) -> np.ndarray:
    """Wheel travel per 0.05 s sample [m] of legs of the given curvatures [1/m] (nominal track),
    ``step`` metres of path per sample."""
    rows = []
    n = round(seconds / 0.05)
    for kappa in curvatures:
        half = 0.5 * B * kappa * step
        rows += [(step - half, step + half)] * n
    return np.array(rows)


def _run(model: SkidModel, travels: np.ndarray) -> Run:
    """A run whose ground truth is ``model`` driven through ``travels``."""
    counts = np.vstack(([0.0, 0.0], np.cumsum(travels, axis=0))) / ROBOT.metres_per_tick
    pose = skid_dead_reckon(model, travels, np.zeros(3))
    time = 0.05 * np.arange(pose.shape[0])
    return Run(kind="free", time=time, counts=counts, true_pose=pose)


def test_the_icr_model_with_symmetric_centres_is_the_constant_factor() -> None:
    travels = _travels([0.0, 1.0, -0.5, 2.0])
    chi = 1.6
    constant = SkidModel("constant", B, chi_inf=chi)
    icr = SkidModel("icr", B, y_left=0.5 * chi * B, y_right=-0.5 * chi * B)
    np.testing.assert_allclose(
        skid_dead_reckon(icr, travels, np.zeros(3)),
        skid_dead_reckon(constant, travels, np.zeros(3)),
        atol=1e-12,
    )


def test_a_constant_x_icr_is_a_tracked_point_offset() -> None:
    """Mandow's x_ICR moves the reported point as a point d = −x_ICR ahead of it would move
    under the same model without it: the confound docs/skid-steer.md states."""
    travels = _travels([0.5, -1.0, 2.0, 0.0])
    x_icr = 0.07
    with_x = SkidModel("icr", B, y_left=0.45, y_right=-0.45, x_icr=x_icr)
    without = SkidModel("icr", B, y_left=0.45, y_right=-0.45)
    moved = skid_dead_reckon(with_x, travels, np.zeros(3))
    body = skid_dead_reckon(without, travels, np.zeros(3))
    # The same body motion, reported at the point −x_ICR ahead of the centre (plus the start
    # offset, so that both start at the origin).
    offset = -x_icr
    point = body[:, :2] + offset * np.column_stack((np.cos(body[:, 2]), np.sin(body[:, 2])))
    point -= point[0]
    # Midpoint integration of the offset point's rotation is exact only to second order in
    # each step's turn (≤ 0.01 rad): millimetres over the whole run.
    np.testing.assert_allclose(moved[:, :2], point, atol=2e-3)
    np.testing.assert_allclose(moved[:, 2], body[:, 2], atol=1e-12)


@pytest.mark.parametrize(
    "truth",
    [
        SkidModel("constant", B, chi_inf=1.55),
        SkidModel("icr", B, y_left=0.52, y_right=-0.41, x_icr=0.03),
        SkidModel("curvature", B, chi_inf=1.25, alpha=0.42, beta=0.25, power=2.0),
    ],
    ids=lambda m: m.kind,
)
def test_each_fit_recovers_the_model_that_drove_the_runs(truth: SkidModel) -> None:
    runs = [
        _run(truth, _travels([k, -k, 0.0, 2 * k], seconds=6.0)) for k in (0.25, 0.5, 1.0, 2.0, 3.0)
    ]
    fit = fit_skid_model(truth.kind, runs, ROBOT)
    names = {"constant": ["chi_inf"], "icr": ["y_left", "y_right", "x_icr"]}.get(
        truth.kind, ["chi_inf", "alpha", "beta", "power"]
    )
    for name in names:
        assert getattr(fit, name) == pytest.approx(getattr(truth, name), rel=1e-3, abs=1e-4), name


def test_the_curvature_factor_falls_from_the_spin_to_its_asymptote() -> None:
    model = SkidModel("curvature", B, chi_inf=1.25, alpha=0.42, beta=0.25, power=2.0)
    lam = np.array([0.0, 1.0, 4.0, 1e4])
    factor = model.factor(lam)
    assert factor[0] == pytest.approx(1.67)
    assert np.all(np.diff(factor) < 0.0)
    assert factor[-1] == pytest.approx(1.25, abs=1e-6)
    assert math.isclose(model.factor(np.array([-4.0]))[0], factor[2])


def test_an_unknown_model_and_empty_runs_are_refused() -> None:
    with pytest.raises(ValueError, match="kind must be one of"):
        fit_skid_model("ackermann", [], ROBOT)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="at least one run"):
        fit_skid_model("constant", [], ROBOT)

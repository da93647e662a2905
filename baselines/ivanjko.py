"""Ivanjko et al.: wheel diameters from straight runs, wheelbase from ±180° in-place spins.

E. Ivanjko, I. Komšić, I. Petrović, *Simple off-line odometry calibration of differential drive
mobile robots*, Proc. 16th Int. Workshop on Robotics in Alpe-Adria-Danube Region (RAAD), 2007;
as implemented by the OptiOdom authors (``src/diff/ivanjko-et-al/main.m``, ``optimizeKD.m``,
``optimizeKL.m``, github.com/sousarbarb/optiodom). The robot drives straight runs and turns on
the spot by 180° clockwise and counter-clockwise; the encoder counts are replayed with corrected
parameters and the corrections are fitted to the measured end poses by nonlinear least squares:

1. **Wheels** (``optimizeKD``): factors K_R, K_L on the right and left wheel diameters,
   minimising Σ_runs ‖p_odo,end(K_R·D_R, K_L·D_L) − p_gt,end‖² over the straight runs. The
   forward distance fixes the mean diameter (E_s), the lateral drift the ratio (E_d).
2. **Wheelbase** (``optimizeKL``): a factor K_b on b, minimising Σ_runs (θ_odo,end(K_b·b) −
   θ_gt,end)² over the cw spins and, separately, the ccw spins, with the wheels of step 1;
   K_b is the mean of the two (as the authors' code).
3. Repeat from step 1 with the corrected parameters until every factor is within
   ``tolerance`` of 1 (the authors: 0.001) or ``max_iterations`` rounds have passed.

Each fit is :func:`scipy.optimize.least_squares` (Levenberg–Marquardt, as the authors'
``lsqnonlin``) with the analytic Jacobian of
:func:`odomgym.odometry.runs.replay_with_jacobian`. With ``residuals="samples"`` every
sample of the runs enters the cost instead of the end pose only.

On the OptiOdom authors' four straight-and-spin sessions (nominal b = 0.2 m, D = 0.084 m, all
runs of each session) this reproduces their published Ivanjko parameters (b, D_R, D_L) to 1 µm
(``tests/test_calibrators_more.py``); their cost is the distance per run, whose sum of squares
is the one fitted here. On the simulated LabMate (E_d = 1.004, E_b = 1.02, E_s = 0.995, 3 m
straight runs, 3 runs of each kind, 2 mm / 0.4° ground truth) the end-pose fit recovers E_b to
about 7 % of its deviation from 1 — the 0.4° end-heading noise of a 180° spin — and
``residuals="samples"`` to about 1.4 %.

**Estimates** (``CalibrationResult.estimates``): K_R, K_L, K_b (products over the rounds, relative
to the calibration in place), K_b_cw and K_b_ccw (the per-direction wheelbase factors, likewise;
their spread shows how much the two directions disagree), the resulting b, D_R, D_L [m] and the
number of rounds.

**Frames and units.** Poses are in the ground-truth frame; the odometry starts at the first
ground-truth pose; position residuals in metres, heading residuals in radians (unwrapped, so a
180° spin is compared as ±π, not wrapped). Factors are dimensionless and multiply the
calibration in place; the result is an absolute :class:`~odomgym.odometry.calibration.Calibration`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from odomgym.baselines.base import (
    CalibrationResult,
    Calibrator,
    Holdings,
    perform,
    require_choice,
)
from odomgym.baselines.trajectory import sample_indices
from odomgym.errors import require_count, require_positive
from odomgym.lab.experiment import Experiment, ExperimentKind, Lab
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run, replay_with_jacobian, require_differential
from odomgym.robot import RobotSpec

__all__ = [
    "Ivanjko",
    "IvanjkoOptions",
    "ResidualSamples",
    "fit_wheelbase",
    "fit_wheels",
    "scale_parameters",
]

FloatArray = NDArray[np.float64]
ResidualSamples = Literal["end", "samples"]


def scale_parameters(
    robot: RobotSpec,
    calibration: Calibration,
    *,
    right: float = 1.0,
    left: float = 1.0,
    wheelbase: float = 1.0,
) -> Calibration:
    """``calibration`` with its effective D_R, D_L and b multiplied by the given factors."""
    params = calibration.parameters(robot)
    return Calibration.from_parameters(
        robot,
        wheelbase=wheelbase * params["wheelbase"],
        right_diameter=right * params["right_diameter"],
        left_diameter=left * params["left_diameter"],
    )


def _fit(
    runs: Sequence[Run],
    robot: RobotSpec,
    calibration: Calibration,
    columns: list[int],
    rows: list[int],
    residuals: ResidualSamples,
    make: Callable[[FloatArray], Calibration],
) -> FloatArray:
    """Least-squares factors (relative changes, log scale) of the parameter ``columns``
    (0 left, 1 right, 2 wheelbase) fitted to pose components ``rows`` (0 x, 1 y, 2 θ)."""
    chosen = [
        sample_indices(run) if residuals == "samples" else np.array([len(run.time) - 1])
        for run in runs
    ]
    truth = np.concatenate(
        [run.true_pose[idx][:, rows] for run, idx in zip(runs, chosen, strict=True)]
    ).reshape(-1)

    def residual_and_jacobian(x: FloatArray) -> tuple[FloatArray, FloatArray]:
        cal = make(x)
        poses, jacs = [], []
        for run, idx in zip(runs, chosen, strict=True):
            pose, jac = replay_with_jacobian(run, robot, cal)
            poses.append(pose[idx][:, rows])
            jacs.append(jac[idx][:, rows][:, :, columns])
        residual = np.concatenate(poses).reshape(-1) - truth
        return residual, np.concatenate(jacs).reshape(-1, len(columns))

    x0 = np.zeros(len(columns))
    _, j0 = residual_and_jacobian(x0)
    if np.linalg.matrix_rank(j0) < len(columns):
        raise ValueError("the runs do not determine the parameters (singular Jacobian)")
    solution = least_squares(
        lambda x: residual_and_jacobian(x)[0],
        x0,
        jac=lambda x: residual_and_jacobian(x)[1],
        method="lm",
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
    )
    factors: FloatArray = np.exp(np.asarray(solution.x, dtype=float))
    return factors


def fit_wheels(
    runs: Sequence[Run],
    robot: RobotSpec,
    calibration: Calibration,
    *,
    residuals: ResidualSamples = "end",
) -> tuple[float, float]:
    """Step 1 (``optimizeKD``): factors (K_R, K_L) on D_R, D_L fitted to the end positions
    (x, y [m]) of straight ``runs`` replayed with ``calibration``; b stays fixed."""

    def make(x: FloatArray) -> Calibration:
        return scale_parameters(robot, calibration, left=math.exp(x[0]), right=math.exp(x[1]))

    k_left, k_right = _fit(runs, robot, calibration, [0, 1], [0, 1], residuals, make)
    return float(k_right), float(k_left)


def fit_wheelbase(
    runs: Sequence[Run],
    robot: RobotSpec,
    calibration: Calibration,
    *,
    residuals: ResidualSamples = "end",
) -> float:
    """Step 2 (``optimizeKL``): the factor K_b on b fitted to the end headings [rad] of
    in-place spins ``runs`` replayed with ``calibration``; the wheels stay fixed."""

    def make(x: FloatArray) -> Calibration:
        return scale_parameters(robot, calibration, wheelbase=math.exp(x[0]))

    (k_b,) = _fit(runs, robot, calibration, [2], [2], residuals, make)
    return float(k_b)


@dataclass(frozen=True)
class IvanjkoOptions:
    """The settings of :class:`Ivanjko` (see its Args for meaning and units)."""

    straight_distance: float = 3.0
    straight_runs: int = 3
    spin_angle: float = math.pi
    spin_runs: int = 3
    tolerance: float = 0.001
    max_iterations: int = 10
    residuals: ResidualSamples = "end"

    def __post_init__(self) -> None:
        require_positive("straight_distance", self.straight_distance)
        require_count("straight_runs", self.straight_runs, 1)
        require_positive("spin_angle", self.spin_angle)
        require_count("spin_runs", self.spin_runs, 1)
        require_positive("tolerance", self.tolerance)
        require_count("max_iterations", self.max_iterations, 1)
        require_choice("residuals", self.residuals, ("end", "samples"))


class Ivanjko(Calibrator):
    """Ivanjko et al.'s calibration from straight runs and ±180° spins (see the module).

    Args:
        straight_distance: length of the straight runs [m].
        straight_runs: straight runs (the recorded OptiOdom sessions hold 3).
        spin_angle: spin angle [rad] (the paper: π).
        spin_runs: spins per direction.
        tolerance: stop when |K − 1| < tolerance for all factors of a round (the authors:
            0.001) [-].
        max_iterations: at most this many rounds (the authors loop until the tolerance is met).
        residuals: ``"end"`` (end poses, as the paper and the authors' code) or ``"samples"``
            (every sample of the runs).
    """

    name: ClassVar[str] = "ivanjko"
    reference: ClassVar[str] = (
        "E. Ivanjko, I. Komšić, I. Petrović, Simple off-line odometry calibration of "
        "differential drive mobile robots, Proc. 16th Int. Workshop on Robotics in "
        "Alpe-Adria-Danube Region (RAAD), 2007"
    )
    options_type: ClassVar[type[IvanjkoOptions]] = IvanjkoOptions
    min_budget: ClassVar[int] = 3

    @classmethod
    def budget_options(cls, runs: int) -> dict[str, Any]:
        """A third straight runs, a third spins each way (Ivanjko et al.'s experiment)."""
        share = max(1, runs // 3)
        return {"straight_runs": share, "spin_runs": share}

    @classmethod
    def session_options(cls, held: Holdings) -> dict[str, Any]:
        """Straight runs and spins; no squares to size (so ``--side``/``--runs`` do nothing)."""
        out: dict[str, Any] = {}
        if held.runs(ExperimentKind.STRAIGHT):
            out["straight_runs"] = held.runs(ExperimentKind.STRAIGHT)
        if held.runs(ExperimentKind.SPIN, "cw"):
            out["spin_runs"] = held.runs(ExperimentKind.SPIN, "cw")
        return out

    def __init__(
        self,
        straight_distance: float = 3.0,
        straight_runs: int = 3,
        *,
        spin_angle: float = math.pi,
        spin_runs: int = 3,
        tolerance: float = 0.001,
        max_iterations: int = 10,
        residuals: ResidualSamples = "end",
    ) -> None:
        options = IvanjkoOptions(
            straight_distance=straight_distance,
            straight_runs=straight_runs,
            spin_angle=spin_angle,
            spin_runs=spin_runs,
            tolerance=tolerance,
            max_iterations=max_iterations,
            residuals=residuals,
        )
        self.options = options
        self.straight_distance = options.straight_distance
        self.straight_runs = options.straight_runs
        self.spin_angle = options.spin_angle
        self.spin_runs = options.spin_runs
        self.tolerance = options.tolerance
        self.max_iterations = options.max_iterations
        self.residuals: ResidualSamples = options.residuals

    def experiments(self) -> list[Experiment]:
        """The straight runs, the cw spins and the ccw spins (all driven once; the iteration
        re-fits the same runs)."""
        return [
            Experiment(ExperimentKind.STRAIGHT, None, self.straight_runs, self.straight_distance),
            Experiment(ExperimentKind.SPIN, "cw", self.spin_runs, self.spin_angle),
            Experiment(ExperimentKind.SPIN, "ccw", self.spin_runs, self.spin_angle),
        ]

    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        """Drive the experiments with ``initial`` active, then fit and iterate."""
        require_differential(initial, self.name)
        robot = lab.robot
        runs0, dist0 = lab.runs_used, lab.distance_used
        start = initial if initial is not None else Calibration()
        straight, spin_cw, spin_ccw = (
            perform(
                lab,
                e,
                start,
                method="Ivanjko et al.'s calibration",
                hint=" (straight runs [m] and 180° spins [rad])",
            )
            for e in self.experiments()
        )

        calibration = start
        k_r = k_l = k_b = 1.0
        k_b_cw = k_b_ccw = 1.0
        converged = False
        rounds = 0
        while not converged and rounds < self.max_iterations:
            rounds += 1
            right, left = fit_wheels(straight, robot, calibration, residuals=self.residuals)
            calibration = scale_parameters(robot, calibration, right=right, left=left)
            cw = fit_wheelbase(spin_cw, robot, calibration, residuals=self.residuals)
            ccw = fit_wheelbase(spin_ccw, robot, calibration, residuals=self.residuals)
            factor = 0.5 * (cw + ccw)
            calibration = scale_parameters(robot, calibration, wheelbase=factor)
            k_r, k_l, k_b = k_r * right, k_l * left, k_b * factor
            k_b_cw, k_b_ccw = k_b_cw * cw, k_b_ccw * ccw
            converged = max(abs(right - 1.0), abs(left - 1.0), abs(factor - 1.0)) < self.tolerance
        notes = (
            []
            if converged
            else [f"not converged to |K − 1| < {self.tolerance:g} after {rounds} rounds"]
        )
        params = calibration.parameters(robot)
        return CalibrationResult(
            calibration=calibration,
            estimates={
                "K_R": k_r,
                "K_L": k_l,
                "K_b": k_b,
                "K_b_cw": k_b_cw,
                "K_b_ccw": k_b_ccw,
                "b": params["wheelbase"],
                "D_R": params["right_diameter"],
                "D_L": params["left_diameter"],
                "iterations": float(rounds),
            },
            runs_used=lab.runs_used - runs0,
            distance_used=lab.distance_used - dist0,
            notes=notes,
        )

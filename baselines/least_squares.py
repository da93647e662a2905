"""Linear least squares over whole runs (Antonelli, Chiaverini & Fusco 2005).

G. Antonelli, S. Chiaverini, G. Fusco, *A calibration method for odometry of mobile robots based
on the least-squares technique: theory and experimental validation*, IEEE Trans. Robotics
21(5):994–1004, 2005. The odometry of a differential-drive robot is *linear* in its parameters
once they are grouped suitably, so start and end poses of a set of runs, with the encoder
increments in between, give the parameters by two ordinary least-squares problems:

1. **Heading.** Over a run, with φ_R, φ_L the wheel rotations [rad] (encoder counts × 2π/C):

       θ_end − θ_start = (r_R/b)·Σ Δφ_R − (r_L/b)·Σ Δφ_L

   one row per run, linear in c = (r_R/b, r_L/b) [-]: Φ_θ·c = Δθ, solved by least squares.
2. **Position.** With c fixed, the heading is known at every sample (θ_j from the partial sums,
   midpoint μ_j = θ_j + Δθ_j/2 as :mod:`odomgym.odometry.calibration`), and the displacement is
   linear in the wheel radii r = (r_R, r_L) [m]:

       x_end − x_start = Σ_j (r_R·Δφ_R,j + r_L·Δφ_L,j)/2 · cos μ_j
       y_end − y_start = Σ_j (r_R·Δφ_R,j + r_L·Δφ_L,j)/2 · sin μ_j

   two rows per run: Φ_xy·r = Δp. As published (``position="radii"``) both radii are unknowns
   and b = argmin ‖(r_R, r_L) − b·c‖² = (c·r)/(c·c).

**Departure (default ``position="wheelbase"``).** On the paths a lab offers (straight runs,
squares, spins) the wheels turn either together (φ_R ≈ φ_L on straight legs) or against each
other (φ_R ≈ −φ_L on the spot, where the centre does not move), so the two columns of Φ_xy are
nearly proportional: the position rows fix the mean radius well but the *ratio* r_R/r_L hardly
at all (measured on the LabMate with E_d = 1.004, 3+3 squares and 3 straight runs from random
start poses: cond(Φ_xy) ≈ 54 and E_d estimates from 0.70 to 1.88 over ten seeds). The heading
rows, on the other hand, fix c_R/c_L = r_R/r_L precisely. By default that ratio is kept and the
position rows estimate a single unknown, b, with r_R = b·c_R and r_L = b·c_L (then Φ_xy·c is
the one-column regressor). Paths on which the wheels turn at many different ratios (arcs of
different curvatures) make Φ_xy well conditioned; ``position="radii"`` is the published
estimator for such data.

**Departure (default ``weighting="propagated"``).** The position rows are predicted with the
c of step 1, whose error they inherit: a square driven with an uncalibrated odometry ends about
1 m from its start, and a 0.03 % error in c moves that end by millimetres — several times the
motion-capture noise — whereas a straight run's end hardly depends on c. Ordinary least squares
(``weighting="uniform"``, as published) lets the squares dominate the scale (measured on the
LabMate with E_d = 1.004, E_b = 1.02, E_s = 0.995, ten seeds: E_s within 70 % of its deviation
from 1, E_b within 12 %). By default each position row is
weighted by 1/(2σ_p² + gᵀ·Σ_c·g), with g the row's sensitivity to c, Σ_c = s_θ²·(Φ_θᵀΦ_θ)⁻¹ the
covariance of step 1 (s_θ² its residual variance) and σ_p the ground-truth position noise
estimated from the runs' second differences (:func:`position_noise`); the first, unweighted
solution supplies the radii in g. Measured: E_s within 23 %, E_b within 5 %.

The condition numbers of Φ_θ and of the two-column Φ_xy (``cond_theta``, ``cond_xy``) say how
informative the runs were.

**Frames and units.** Poses are the runs' ground truth in its own frame (x, y [m], θ [rad]
unwrapped); headings start from the first ground-truth heading. The result is absolute
(D = 2r, b), independent of the calibration active while driving.

Default experiments: 3 cw and 3 ccw UMBmark squares of 4 m (heading rows: ±2π of turning fixes b
relative to the wheels, the legs' drift the ratio r_R/r_L) and 3 straight runs of 3 m (position
rows: squares return to their start, so the distance of the straight runs fixes the scale).
Any runs a lab provides will do.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.baselines.base import (
    CalibrationResult,
    Calibrator,
    Holdings,
    perform,
    require_choice,
)
from odomgym.errors import SpecError, require_count, require_positive
from odomgym.lab.experiment import Experiment, ExperimentKind, Lab
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run, require_differential
from odomgym.robot import RobotSpec

__all__ = [
    "LeastSquares",
    "LeastSquaresFit",
    "LeastSquaresOptions",
    "PositionUnknowns",
    "Weighting",
    "fit_least_squares",
    "position_noise",
]

FloatArray = NDArray[np.float64]
PositionUnknowns = Literal["wheelbase", "radii"]
Weighting = Literal["propagated", "uniform"]


@dataclass(frozen=True)
class LeastSquaresFit:
    """The result of :func:`fit_least_squares`.

    Attributes:
        calibration: the calibration equivalent to the estimated (b, D_R, D_L).
        c_right, c_left: r_R/b and r_L/b from the heading rows [-].
        r_right, r_left: wheel radii r_R, r_L from the position rows [m].
        wheelbase: b [m].
        cond_theta: condition number of the heading regressor Φ_θ (runs × 2) [-].
        cond_xy: condition number of the position regressor Φ_xy (2·runs × 2) [-].
        rms_theta: RMS residual of the heading rows [rad].
        rms_xy: RMS residual of the position rows [m].
    """

    calibration: Calibration
    c_right: float
    c_left: float
    r_right: float
    r_left: float
    wheelbase: float
    cond_theta: float
    cond_xy: float
    rms_theta: float
    rms_xy: float


def _wheel_rotations(run: Run, robot: RobotSpec) -> FloatArray:
    """Per-sample wheel rotation increments (T−1, 2) [rad], columns [right, left]."""
    increments = np.diff(run.counts, axis=0).astype(float)
    return increments[:, ::-1] * (2.0 * math.pi / robot.ticks_per_rev)


def position_noise(runs: Sequence[Run]) -> float:
    """Standard deviation of the ground-truth position noise [m], from second differences.

    White noise of σ on every sample gives the second differences p_{k+1} − 2p_k + p_{k−1} a
    variance of 6σ² per axis; smooth motion adds little at the sampling rates of motion capture.
    The median over the runs is returned (0 for runs of fewer than three samples).
    """
    values = [
        float(np.mean(np.diff(run.true_pose[:, :2], n=2, axis=0) ** 2) / 6.0)
        for run in runs
        if len(run.time) >= 3
    ]
    return math.sqrt(float(np.median(values))) if values else 0.0


def fit_least_squares(
    runs: Sequence[Run],
    robot: RobotSpec,
    *,
    position: PositionUnknowns = "wheelbase",
    weighting: Weighting = "propagated",
) -> LeastSquaresFit:
    """Antonelli et al.'s two least-squares problems on ``runs`` (see the module docstring).

    Args:
        runs: the runs (at least two; their regressors must have full rank).
        robot: the nominal robot (its ``ticks_per_rev``).
        position: the unknowns of the position rows: ``"wheelbase"`` (default; r_R/r_L kept
            from the heading rows, one unknown b) or ``"radii"`` (r_R and r_L, as published).
        weighting: of the position rows: ``"propagated"`` (default) or ``"uniform"`` (ordinary
            least squares, as published); see the module docstring.

    Raises:
        ValueError: fewer than two runs, or runs whose regressors are rank-deficient (e.g. only
            straight runs for the heading rows, or no run that ends away from its start).
    """
    if position not in ("wheelbase", "radii"):
        raise ValueError(f"position must be 'wheelbase' or 'radii', got {position!r}")
    if weighting not in ("propagated", "uniform"):
        raise ValueError(f"weighting must be 'propagated' or 'uniform', got {weighting!r}")
    if len(runs) < 2:
        raise ValueError(f"least-squares calibration needs at least two runs, got {len(runs)}")
    rotations = [_wheel_rotations(run, robot) for run in runs]

    # Step 1: heading rows, Δθ = c_R·Σφ_R − c_L·Σφ_L.
    phi_theta = np.array([[rot[:, 0].sum(), -rot[:, 1].sum()] for rot in rotations])
    d_theta = np.array([np.unwrap(run.true_pose[:, 2])[-1] - run.true_pose[0, 2] for run in runs])
    if np.linalg.matrix_rank(phi_theta) < 2:
        raise ValueError(
            "the heading regressor is rank-deficient: the runs need different ratios of "
            "right to left wheel rotation (e.g. turns in both directions, or turns and "
            "straight runs)"
        )
    c, *_ = np.linalg.lstsq(phi_theta, d_theta, rcond=None)
    c_right, c_left = float(c[0]), float(c[1])
    theta_residual = phi_theta @ c - d_theta
    dof = len(runs) - 2
    theta_variance = float(theta_residual @ theta_residual) / dof if dof > 0 else 0.0
    c_covariance = theta_variance * np.linalg.inv(phi_theta.T @ phi_theta)

    # Step 2: position rows with the headings of step 1; for each row also the sensitivity of
    # its prediction to c: through the headings μ_j and, for position="wheelbase" (r = b·c),
    # through the travel.
    rows: list[FloatArray] = []
    mid_gradients: list[FloatArray] = []  # Σ_j ½Δφ_j·(−sin μ_j | cos μ_j)·∂μ_j/∂c, (2, 2, 2)
    targets: list[float] = []
    for run, rot in zip(runs, rotations, strict=True):
        dtheta = c_right * rot[:, 0] - c_left * rot[:, 1]
        mid = run.true_pose[0, 2] + np.cumsum(dtheta) - 0.5 * dtheta
        cos_mid, sin_mid = np.cos(mid), np.sin(mid)
        d_mid = np.stack(  # ∂μ_j/∂(c_R, c_L)
            [np.cumsum(rot[:, 0]) - 0.5 * rot[:, 0], 0.5 * rot[:, 1] - np.cumsum(rot[:, 1])],
            axis=1,
        )
        half = 0.5 * rot
        rows += [cos_mid @ half, sin_mid @ half]
        mid_gradients += [
            np.einsum("jw,jk->wk", half * -sin_mid[:, None], d_mid),
            np.einsum("jw,jk->wk", half * cos_mid[:, None], d_mid),
        ]
        targets.extend(float(v) for v in run.true_pose[-1, :2] - run.true_pose[0, :2])
    phi_xy = np.array(rows)
    d_xy = np.array(targets)

    def solve(weights: FloatArray) -> tuple[float, float, float]:
        """(r_R, r_L, b) [m] by weighted least squares on the position rows."""
        root = np.sqrt(weights)
        if position == "radii":
            r, *_ = np.linalg.lstsq(phi_xy * root[:, None], d_xy * root, rcond=None)
            r_r, r_l = float(r[0]), float(r[1])
            return r_r, r_l, (c_right * r_r + c_left * r_l) / (c_right**2 + c_left**2)
        column = phi_xy @ c
        b = float((weights * column) @ d_xy) / float((weights * column) @ column)
        return b * c_right, b * c_left, b

    if position == "radii" and np.linalg.matrix_rank(phi_xy) < 2:
        raise ValueError(
            "the position regressor is rank-deficient: the runs need to end away from "
            "their start with different ratios of right to left wheel rotation"
        )
    if position == "wheelbase" and not float(np.sum((phi_xy @ c) ** 2)) > 0.0:
        raise ValueError("the runs do not move the robot away from their start")
    r_right, r_left, wheelbase = solve(np.ones(len(d_xy)))
    if weighting == "propagated":
        radii = np.array([r_right, r_left])
        gradients = np.einsum("iwk,w->ik", np.array(mid_gradients), radii)
        if position == "wheelbase":
            gradients += wheelbase * phi_xy
        noise = position_noise(runs)
        variance = 2.0 * noise**2 + np.einsum("ik,kl,il->i", gradients, c_covariance, gradients)
        r_right, r_left, wheelbase = solve(1.0 / np.maximum(variance, 1e-12))
    if not (r_right > 0.0 and r_left > 0.0 and wheelbase > 0.0):
        raise ValueError(
            f"least squares gave non-physical parameters r_R = {r_right}, r_L = {r_left}, "
            f"b = {wheelbase} [m]: the runs do not determine them"
        )
    r = np.array([r_right, r_left])
    calibration = Calibration.from_parameters(
        robot, wheelbase=wheelbase, right_diameter=2.0 * r_right, left_diameter=2.0 * r_left
    )
    return LeastSquaresFit(
        calibration=calibration,
        c_right=c_right,
        c_left=c_left,
        r_right=r_right,
        r_left=r_left,
        wheelbase=wheelbase,
        cond_theta=float(np.linalg.cond(phi_theta)),
        cond_xy=float(np.linalg.cond(phi_xy)),
        rms_theta=float(np.sqrt(np.mean(theta_residual**2))),
        rms_xy=float(np.sqrt(np.mean((phi_xy @ r - d_xy) ** 2))),
    )


@dataclass(frozen=True)
class LeastSquaresOptions:
    """The settings of :class:`LeastSquares` (see its Args for meaning and units)."""

    side: float = 4.0
    squares_per_direction: int = 3
    straight_runs: int = 3
    straight_distance: float = 3.0
    spins_per_direction: int = 0
    spin_angle: float = math.pi
    position: PositionUnknowns = "wheelbase"
    weighting: Weighting = "propagated"

    def __post_init__(self) -> None:
        require_positive("side", self.side)
        require_count("squares_per_direction", self.squares_per_direction, 0)
        require_count("straight_runs", self.straight_runs, 0)
        require_positive("straight_distance", self.straight_distance)
        require_count("spins_per_direction", self.spins_per_direction, 0)
        require_positive("spin_angle", self.spin_angle)
        if not (self.squares_per_direction or self.spins_per_direction):
            raise SpecError(
                "need squares or spins (squares_per_direction or spins_per_direction >= 1): "
                "the heading rows need turning",
                field="squares_per_direction",
            )
        if not self.straight_runs:
            raise SpecError(
                "need straight runs: closed paths hardly fix the wheel radii",
                field="straight_runs",
            )
        require_choice("position", self.position, ("wheelbase", "radii"))
        require_choice("weighting", self.weighting, ("propagated", "uniform"))


class LeastSquares(Calibrator):
    """Antonelli et al.'s least-squares calibration over the runs it performs.

    Args:
        side: square side L [m].
        squares_per_direction: cw and ccw squares (0: none; then give spins).
        straight_runs: straight runs (0: none).
        straight_distance: their length [m].
        spins_per_direction: cw and ccw in-place spins of ``spin_angle`` (default 0).
        spin_angle: spin angle [rad].
        position: unknowns of the position rows, ``"wheelbase"`` (default) or ``"radii"`` (as
            published); see the module docstring.
        weighting: of the position rows, ``"propagated"`` (default) or ``"uniform"`` (as
            published); see the module docstring.
    """

    name: ClassVar[str] = "least_squares"
    reference: ClassVar[str] = (
        "G. Antonelli, S. Chiaverini, G. Fusco, A calibration method for odometry of mobile "
        "robots based on the least-squares technique: theory and experimental validation, "
        "IEEE Trans. Robotics 21(5):994-1004, 2005"
    )
    options_type: ClassVar[type[LeastSquaresOptions]] = LeastSquaresOptions
    min_budget: ClassVar[int] = 3

    @classmethod
    def budget_options(cls, runs: int) -> dict[str, Any]:
        """A quarter straight runs, the rest squares split between the directions."""
        straight = max(1, runs // 4)
        return {"straight_runs": straight, "squares_per_direction": max(1, (runs - straight) // 2)}

    @classmethod
    def square_options(cls, side: float, runs_per_direction: int) -> dict[str, Any]:
        return {"side": side, "squares_per_direction": runs_per_direction}

    @classmethod
    def session_options(cls, held: Holdings) -> dict[str, Any]:
        out: dict[str, Any] = {
            "squares_per_direction": held.runs(ExperimentKind.SQUARE, "cw"),
            "spins_per_direction": held.runs(ExperimentKind.SPIN, "cw"),
        }
        if held.side > 0.0:
            out["side"] = held.side
        if held.runs(ExperimentKind.STRAIGHT):
            out["straight_runs"] = held.runs(ExperimentKind.STRAIGHT)
        return out

    def __init__(
        self,
        side: float = 4.0,
        squares_per_direction: int = 3,
        *,
        straight_runs: int = 3,
        straight_distance: float = 3.0,
        spins_per_direction: int = 0,
        spin_angle: float = math.pi,
        position: PositionUnknowns = "wheelbase",
        weighting: Weighting = "propagated",
    ) -> None:
        options = LeastSquaresOptions(
            side=side,
            squares_per_direction=squares_per_direction,
            straight_runs=straight_runs,
            straight_distance=straight_distance,
            spins_per_direction=spins_per_direction,
            spin_angle=spin_angle,
            position=position,
            weighting=weighting,
        )
        self.options = options
        self.side = options.side
        self.squares_per_direction = options.squares_per_direction
        self.straight_runs = options.straight_runs
        self.straight_distance = options.straight_distance
        self.spins_per_direction = options.spins_per_direction
        self.spin_angle = options.spin_angle
        self.position: PositionUnknowns = options.position
        self.weighting: Weighting = options.weighting

    def experiments(self) -> list[Experiment]:
        """Squares (cw, ccw), spins (cw, ccw) and straight runs, as configured."""
        out: list[Experiment] = []
        if self.squares_per_direction:
            n = self.squares_per_direction
            out += [
                Experiment(ExperimentKind.SQUARE, "cw", n, self.side),
                Experiment(ExperimentKind.SQUARE, "ccw", n, self.side),
            ]
        if self.spins_per_direction:
            n = self.spins_per_direction
            out += [
                Experiment(ExperimentKind.SPIN, "cw", n, self.spin_angle),
                Experiment(ExperimentKind.SPIN, "ccw", n, self.spin_angle),
            ]
        out.append(
            Experiment(ExperimentKind.STRAIGHT, None, self.straight_runs, self.straight_distance)
        )
        return out

    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        """Perform the experiments with ``initial`` active; estimate (b, D_R, D_L)."""
        require_differential(initial, self.name)
        runs0, dist0 = lab.runs_used, lab.distance_used
        calibration = initial if initial is not None else Calibration()
        runs: list[Run] = []
        for experiment in self.experiments():
            runs.extend(perform(lab, experiment, calibration, method="least-squares calibration"))
        fit = fit_least_squares(runs, lab.robot, position=self.position, weighting=self.weighting)
        notes = []
        if self.position == "radii" and fit.cond_xy > 30.0:
            notes.append(
                f"position regressor poorly conditioned (cond = {fit.cond_xy:.0f}): the runs "
                "say little about the wheel radii"
            )
        return CalibrationResult(
            calibration=fit.calibration,
            estimates={
                "r_R/b": fit.c_right,
                "r_L/b": fit.c_left,
                "r_R": fit.r_right,
                "r_L": fit.r_left,
                "b": fit.wheelbase,
                "cond_theta": fit.cond_theta,
                "cond_xy": fit.cond_xy,
                "rms_theta": fit.rms_theta,
                "rms_xy": fit.rms_xy,
            },
            runs_used=lab.runs_used - runs0,
            distance_used=lab.distance_used - dist0,
            notes=notes,
        )

"""Skid-steer odometry models and their fit to measured runs.

A skid-steer robot's sides drive its contacts at the rim speeds v_L, v_R, but the body does not
turn at (v_R − v_L)/b: its wheels slide sideways and along. Three models of where the body goes,
each a kinematic map from the two rim speeds to the body velocity (u forward, w to the left
[m/s], ω [rad/s]) at the tracked point:

* **constant factor** — the track widened by an expansion factor χ (the apparent track χ·b;
  Clearpath's ``wheel_separation_multiplier``; this project's E_b): ω = (v_R − v_L)/(χ·b),
  u = (v_L + v_R)/2, w = 0.
* **ICR** (Mandow et al. 2007, Eqs. 4–6) — each side's instantaneous centre of rotation
  (x_ICR, y_L) and (x_ICR, y_R) fixed in the body: ω = (v_R − v_L)/(y_L − y_R), u = (v_R·y_L −
  v_L·y_R)/(y_L − y_R), w = (v_L − v_R)·x_ICR/(y_L − y_R). With y_L = −y_R = χ·b/2 and x_ICR =
  0 it is the constant factor. A constant x_ICR moves the reported point exactly as a
  tracked-point offset along the body would: the two cannot be told apart from logs.
* **curvature-dependent factor** — Wang et al. (2015) measured the Pioneer 3-AT's ICR
  coefficient fall as the path straightens, χ(λ) = 1 + α/(1 + β·√|λ|) with λ = (v_L + v_R)/(v_R −
  v_L) (as cited second-hand in docs/skid-steer.md); here with a free asymptote and power,
  χ(λ) = χ_∞ + α/(1 + (β·|λ|)^p), χ_∞ ≥ 1, α ≥ 0: a tyre's elastic range leaves χ_∞ above 1
  and the fall from the spin's value to it is steeper than √|λ| (docs/skid-steer.md, "Tyres").

:func:`fit_skid_model` fits one model's parameters to runs with ground truth: least squares on
the motion over short windows (each window dead-reckoned from its measured start pose), the
measurement the trajectory calibrator of this project uses for differential-drive robots.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from odomgym.odometry.calibration import path_parameter
from odomgym.odometry.runs import Run, wheel_travels
from odomgym.robot import RobotSpec

__all__ = ["SKID_MODELS", "SkidModel", "SkidModelKind", "fit_skid_model", "skid_dead_reckon"]

FloatArray = NDArray[np.float64]
SkidModelKind = Literal["nominal", "constant", "icr", "curvature"]
SKID_MODELS: tuple[SkidModelKind, ...] = ("nominal", "constant", "icr", "curvature")
"""The models, simplest first: the nominal track (χ = 1), a constant factor, Mandow's ICRs,
a curvature-dependent factor."""


@dataclass(frozen=True)
class SkidModel:
    """One skid-steer odometry model with its parameters.

    Attributes:
        kind: which model (module docstring).
        track: the true track b the factors multiply [m] (the spec's ``wheelbase``).
        y_left, y_right: the sides' ICR offsets to the left of the tracked point [m] (``icr``;
            for the others ±χ·b/2 at a spin).
        x_icr: the ICRs' common offset ahead of the tracked point [m] (``icr``; else 0).
        chi_inf, alpha, beta, power: χ(λ) = χ_∞ + α/(1 + (β·|λ|)^p) (``curvature``;
            ``constant`` uses χ_∞ alone) [-].
    """

    kind: SkidModelKind
    track: float
    y_left: float = 0.0
    y_right: float = 0.0
    x_icr: float = 0.0
    chi_inf: float = 1.0
    alpha: float = 0.0
    beta: float = 0.0
    power: float = 0.5

    @classmethod
    def nominal(cls, robot: RobotSpec) -> SkidModel:
        """The kinematic odometry with the nominal track: χ = 1."""
        b = float(robot.wheelbase)
        return cls("nominal", b, 0.5 * b, -0.5 * b)

    def factor(self, lam: FloatArray) -> FloatArray:
        """The expansion factor χ at path parameters ``lam`` = (v_L + v_R)/(v_R − v_L) [-]
        (``constant``/``nominal``: χ_∞ everywhere; ``icr``: (y_L − y_R)/b)."""
        lam = np.asarray(lam, dtype=float)
        if self.kind == "icr":
            return np.full_like(lam, (self.y_left - self.y_right) / self.track)
        if self.kind == "curvature":
            return self.chi_inf + self.alpha / (1.0 + (self.beta * np.abs(lam)) ** self.power)
        return np.full_like(lam, self.chi_inf)

    def body_steps(self, left: FloatArray, right: FloatArray) -> FloatArray:
        """Body-frame motion of each step (n, 3): forward, leftward [m] and turn [rad], for the
        wheels' travel ``left``, ``right`` (n,) [m] (module docstring's equations, per step)."""
        if self.kind == "icr":
            span = self.y_left - self.y_right
            turn = (right - left) / span
            forward = (right * self.y_left - left * self.y_right) / span
            return np.column_stack((forward, -self.x_icr * turn, turn))
        # λ of a step that does not turn is infinite: χ_∞ (the 1e-12 m floor keeps it finite).
        turn = (right - left) / (self.factor(path_parameter(left, right)) * self.track)
        return np.column_stack((0.5 * (right + left), np.zeros_like(turn), turn))

    def to_dict(self) -> dict[str, float | str]:
        """The parameters, for JSON."""
        return {
            "kind": self.kind,
            "track": self.track,
            "y_left": self.y_left,
            "y_right": self.y_right,
            "x_icr": self.x_icr,
            "chi_inf": self.chi_inf,
            "alpha": self.alpha,
            "beta": self.beta,
            "power": self.power,
        }


def skid_dead_reckon(model: SkidModel, travels: FloatArray, start: FloatArray) -> FloatArray:
    """Poses (T, 3) [m, m, rad] dead-reckoned from ``start`` through the wheel travels
    ``travels`` (T − 1, 2) [m] with ``model`` (each step's body motion turned by its midpoint
    heading, as :class:`odomgym.odometry.calibration.Odometry` integrates)."""
    steps = model.body_steps(travels[:, 0], travels[:, 1])
    heading = start[2] + np.concatenate(([0.0], np.cumsum(steps[:, 2])))
    mid = heading[:-1] + 0.5 * steps[:, 2]
    c, s = np.cos(mid), np.sin(mid)
    dx = c * steps[:, 0] - s * steps[:, 1]
    dy = s * steps[:, 0] + c * steps[:, 1]
    x = start[0] + np.concatenate(([0.0], np.cumsum(dx)))
    y = start[1] + np.concatenate(([0.0], np.cumsum(dy)))
    return np.column_stack((x, y, heading))


def _model(kind: SkidModelKind, track: float, p: FloatArray) -> SkidModel:
    if kind == "constant":
        return SkidModel(kind, track, chi_inf=float(p[0]))
    if kind == "icr":
        return SkidModel(kind, track, y_left=float(p[0]), y_right=float(p[1]), x_icr=float(p[2]))
    chi_inf, alpha, beta, power = (float(x) for x in p)
    return SkidModel(kind, track, chi_inf=chi_inf, alpha=alpha, beta=beta, power=power)


def fit_skid_model(
    kind: SkidModelKind,
    runs: Sequence[Run],
    robot: RobotSpec,
    *,
    window: float = 2.0,
    heading_weight: float = 0.3,
) -> SkidModel:
    """Fit ``kind``'s parameters to ``runs`` (their ground truth is the measured pose).

    Every run is cut into windows of ``window`` seconds; each window is dead-reckoned from its
    measured start pose and compared with its measured end pose: the residuals are the
    position error [m] and ``heading_weight`` [m/rad] times the heading error. Windows keep the
    fit from weighting a run's late errors by everything before them; the weight puts a 1°
    heading error level with 5 mm. ``nominal`` needs no fit.

    Raises:
        ValueError: ``kind`` unknown, or no run with at least two samples.
    """
    if kind not in SKID_MODELS:
        raise ValueError(f"kind must be one of {', '.join(SKID_MODELS)}, got {kind!r}")
    if kind == "nominal":
        return SkidModel.nominal(robot)
    pieces: list[tuple[FloatArray, FloatArray, FloatArray]] = []
    for run in runs:
        if run.time.shape[0] < 2:
            continue
        travels, _ = wheel_travels(run, robot)
        period = float(np.median(np.diff(run.time)))
        n = max(1, round(window / period))
        for first in range(0, run.time.shape[0] - 1, n):
            last = min(first + n, run.time.shape[0] - 1)
            pieces.append((travels[first:last], run.true_pose[first], run.true_pose[last]))
    if not pieces:
        raise ValueError("fit_skid_model needs at least one run with two or more samples")
    b = float(robot.wheelbase)
    start = {
        "constant": np.array([1.5]),
        "icr": np.array([0.75 * b, -0.75 * b, 0.0]),
        "curvature": np.array([1.2, 0.5, 0.3, 1.0]),
    }[kind]
    # Bounds keep the curvature model physical: χ_∞ ≥ 1 (no track narrower than the wheels'),
    # a factor that falls as the path straightens (α ≥ 0), a power between ¼ and 4.
    low, high = {
        "constant": ([0.2], [10.0]),
        "icr": ([-10.0 * b, -10.0 * b, -10.0 * b], [10.0 * b, 10.0 * b, 10.0 * b]),
        "curvature": ([1.0, 0.0, 1e-3, 0.25], [10.0, 10.0, 1e3, 4.0]),
    }[kind]

    def residual(p: FloatArray) -> FloatArray:
        model = _model(kind, b, p)
        out = np.empty((len(pieces), 3))
        for k, (travels, begin, end) in enumerate(pieces):
            pose = skid_dead_reckon(model, travels, begin)[-1]
            out[k, :2] = pose[:2] - end[:2]
            out[k, 2] = heading_weight * math.remainder(pose[2] - end[2], math.tau)
        return out.ravel()

    fit = least_squares(residual, start, bounds=(low, high), x_scale="jac")
    return _model(kind, b, fit.x)

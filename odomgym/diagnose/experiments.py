"""Synthetic characterisation experiments: wheel-count sequences of standard manoeuvres.

Used to design, not to simulate physics: when two fitted models explain the data equally well,
:func:`separating_experiment` replays each experiment of the menu through both and names the one
whose predicted outcomes differ most, in units of the ground-truth sensor's noise. The counts come
from the nominal robot driving each manoeuvre with trapezoidal wheel-speed profiles at 20 Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym.diagnose.likelihood import SensorNoise
from odomgym.diagnose.replay import replay_run
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "SEPARATING_EXPERIMENTS",
    "Separation",
    "SyntheticExperiment",
    "separating_experiment",
    "synthetic_run",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SyntheticExperiment:
    """A manoeuvre: ``legs`` of (body speed v [m/s], yaw rate ω [rad/s], duration [s])."""

    name: str
    legs: tuple[tuple[float, float, float], ...]
    description: str


def _square(side: float, sign: float, v: float) -> tuple[tuple[float, float, float], ...]:
    legs: list[tuple[float, float, float]] = []
    w = 1.0
    for _ in range(4):
        legs.append((v, 0.0, side / v))
        legs.append((0.0, sign * w, (math.pi / 2) / w))
    return tuple(legs)


SEPARATING_EXPERIMENTS: tuple[SyntheticExperiment, ...] = (
    SyntheticExperiment("straight 4 m one way", ((0.3, 0.0, 4 / 0.3),), "drive 4 m straight"),
    SyntheticExperiment(
        "straight 4 m out and back",
        ((0.3, 0.0, 4 / 0.3), (-0.3, 0.0, 4 / 0.3)),
        "4 m forward, then 4 m in reverse",
    ),
    SyntheticExperiment("spin 90° slow", ((0.0, 0.5, (math.pi / 2) / 0.5),), "turn in place"),
    SyntheticExperiment("spin 180° slow", ((0.0, 0.5, math.pi / 0.5),), "turn in place"),
    SyntheticExperiment("spin 360° slow", ((0.0, 0.5, 2 * math.pi / 0.5),), "turn in place"),
    SyntheticExperiment("spin 360° fast", ((0.0, 2.0, 2 * math.pi / 2.0),), "turn in place"),
    SyntheticExperiment(
        "spin 180° there and back",
        ((0.0, 1.0, math.pi), (0.0, -1.0, math.pi)),
        "turn 180° and back (wheel reversals)",
    ),
    SyntheticExperiment("arc 1 m radius slow", ((0.15, 0.15, math.pi / 0.15),), "half circle"),
    SyntheticExperiment("arc 1 m radius fast", ((0.5, 0.5, math.pi / 0.5),), "half circle"),
    SyntheticExperiment("square 2 m cw", _square(2.0, -1.0, 0.3), "UMBmark square, cw"),
    SyntheticExperiment("square 2 m ccw", _square(2.0, 1.0, 0.3), "UMBmark square, ccw"),
)


def synthetic_run(experiment: SyntheticExperiment, robot: RobotSpec, dt: float = 0.05) -> Run:
    """Encoder counts of the *nominal* robot performing ``experiment`` (trapezoid ramps of
    0.5 m/s² on each leg, a 0.5 s stop between legs); the ground truth is only the start pose."""
    half_b = 0.5 * robot.wheelbase
    speeds: list[tuple[float, float]] = []
    accel = 0.5
    for v, w, duration in experiment.legs:
        steps = max(1, round(duration / dt))
        left, right = v - w * half_b, v + w * half_b
        peak = max(abs(left), abs(right), 1e-9)
        ramp = min(max(1, round(peak / accel / dt)), steps // 2 or 1)
        profile = np.ones(steps)
        profile[:ramp] = np.arange(1, ramp + 1) / ramp
        profile[steps - ramp :] = np.arange(ramp, 0, -1) / ramp
        profile *= steps / profile.sum()  # keep the leg's distance and angle
        speeds.extend((left * f, right * f) for f in profile)
        speeds.extend([(0.0, 0.0)] * round(0.5 / dt))
    rim = np.array(speeds) * dt
    counts = np.vstack([[0.0, 0.0], np.cumsum(rim, axis=0)]) / robot.metres_per_tick
    pose = np.full((len(counts), 3), np.nan)
    pose[0] = 0.0
    return Run(
        kind="free",
        time=np.arange(len(counts), dtype=np.float64) * dt,
        counts=np.round(counts).astype(np.int64),
        true_pose=pose,
        meta={"experiment": experiment.name},
    )


@dataclass(frozen=True)
class Separation:
    """How far apart two models' predictions of one experiment are, at their largest over the
    run: position [m], heading [rad], and the larger of the two in sensor σ."""

    experiment: str
    position: float
    heading: float
    sigma: float


def separating_experiment(
    first: RobotSpec, second: RobotSpec, sensor: SensorNoise
) -> tuple[Separation, list[Separation]]:
    """The menu experiment whose predicted tracked poses under ``first`` and ``second`` differ
    most, in sensor standard deviations (largest over the run, position and heading); returns
    it and every experiment's separation."""
    scores = []
    for experiment in SEPARATING_EXPERIMENTS:
        run = synthetic_run(experiment, first)
        a = replay_run(run, first).tracked
        b = replay_run(run, second).tracked
        pos = float(np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1]).max())
        head = float(np.abs(a[:, 2] - b[:, 2]).max())
        sigma = max(pos / max(sensor.position, 1e-9), head / max(sensor.heading, 1e-9))
        scores.append(Separation(experiment.name, pos, head, sigma))
    return max(scores, key=lambda item: item.sigma), scores

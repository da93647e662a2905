"""An independent skid-steer robot: four rigid wheels on Coulomb friction, quasi-static.

The second "robot from somewhere else" (beside :mod:`independent_robot`), for the skid-steer
diagnosis. Like it, it never imports odomgym's simulator, effects or diagnosis: its apparent
track comes from a contact model written here, not from the World's elastic tyres
(``odomgym.sim.world.skid_contacts``) nor from the catalogue's ``skid_track`` formula.

**The contact model** is the classical one of skid-steer kinematics (Kozłowski & Pazderski
2004; Mandow et al. 2007, whose ICR kinematics it produces): four rigid wheels at
(±a/2, ±B/2) from the geometric centre, a the front-to-back axle spacing and B the side-to-side
track, each side's two wheels turning at one rim speed u_L or u_R. A wheel's contact point slides
over the floor at

    s_i = (v_x − ω·y_i − u_i,  v_y + ω·x_i)

for the body twist (v_x, v_y, ω) in the body frame, and the floor pushes back with Coulomb
friction F_i = −μ·N_i·s_i/|s_i|. Motion is quasi-static (the slow speeds of a calibration):
the twist is the one at which the four forces and their moment about the centre balance,
ΣF_i = 0 and Σ(x_i·F_iy − y_i·F_ix) = 0. The centre of mass is at the geometric centre, so
the four loads are equal. μ cancels.

Coulomb friction depends only on the directions of the slips, so the balance is homogeneous:
the twist scales with the rim speeds and depends only on their ratio ψ = atan2(u_R, u_L). It is
solved once on a grid of ψ (:data:`_GRID` points) as the minimum of the dissipated power
(Alexander & Maddocks 1989) and interpolated per integration step
(``tests/test_independent_skid.py`` checks the interpolation against direct solutions). The
apparent track χ = (u_R − u_L)/(B·ω) comes out
**the same at every turn radius**, χ = 1 + (a/B)² (1.64 for the default robot), and the sides'
ICRs sit at y = ±χ·B/2 with no offset along the body. Rigid wheels on Coulomb friction give a
skid-steer robot a constant apparent track; the fall of χ from spins to wide arcs that Mandow et
al. (2007) and Wang et al. (2015) measure needs tyres that deform before they slide (the World's
elastic contacts, ``docs/skid-steer.md``). This robot is therefore the physics-made negative for
the diagnosis: a skid-steer robot whose logs must be named ``wheelbase`` (E_b = χ), not
``skid_track``.

Motion, encoders and logging are :mod:`independent_robot`'s: open-loop S-curve moves of the two
motor angles planned with the *nominal* track, exact constant-twist steps at ``integration_hz``,
quantised encoders with a random phase, ground truth at ``log_rate_hz`` with Gaussian noise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from independent_robot import (
    IndependentRobot,
    Manoeuvre,
    TurnDirection,
    _motor_angles,
    _timeline,
    logged_run,
    run_streams,
    time_grid,
)
from numpy.typing import NDArray
from scipy.optimize import minimize

from odomgym.odometry.runs import Run

__all__ = ["CoulombSkidRobot", "generate_skid", "skid_protocol"]

FloatArray = NDArray[np.float64]

_GRID = 1001
"""Points of the twist table over ψ ∈ [−π, π]."""
_SMOOTH = 1e-9
"""Slip speed [per unit rim speed] below which Coulomb's direction is smoothed (|s| → √(s² + δ²)),
so that the power stays differentiable where a contact happens not to slide."""


@dataclass(frozen=True)
class CoulombSkidRobot:
    """A four-wheel skid-steer robot on rigid wheels and Coulomb friction.

    Attributes:
        wheel_diameter: wheel diameter D [m] (nominal = true: the robot's error is its scrub).
        track: side-to-side spacing B of the wheel centres [m] (the nominal track).
        axle_spacing: front-to-back spacing a of the two axles [m].
        ticks_per_rev: encoder counts per wheel revolution.
        sensor_position_std: ground-truth sensor noise per axis [m].
        sensor_heading_std: ground-truth sensor heading noise [rad].
    """

    wheel_diameter: float = 0.084
    track: float = 0.200
    axle_spacing: float = 0.16
    ticks_per_rev: float = 2796.8
    sensor_position_std: float = 0.001
    sensor_heading_std: float = 0.002

    def __post_init__(self) -> None:
        for name in ("wheel_diameter", "track", "axle_spacing", "ticks_per_rev"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be positive and finite, got {value}")

    @property
    def contacts(self) -> FloatArray:
        """(4, 4): per wheel x [m], y [m], side (0 left, 1 right) and load share [-]."""
        a, b = self.axle_spacing, self.track
        rows = [(0.5 * a, 0.5 * b, 0, 0.25), (-0.5 * a, 0.5 * b, 0, 0.25)]
        rows += [(0.5 * a, -0.5 * b, 1, 0.25), (-0.5 * a, -0.5 * b, 1, 0.25)]
        return np.array(rows, dtype=np.float64)

    def balance(self, twist: FloatArray, rims: tuple[float, float]) -> FloatArray:
        """The net force (x, y) and moment of the floor on the robot [per μ·m·g] at body
        ``twist`` (v_x, v_y, ω) and rim speeds (u_L, u_R)."""
        vx, vy, w = twist
        out = np.zeros(3)
        for x, y, side, load in self.contacts:
            sx = vx - w * y - rims[int(side)]
            sy = vy + w * x
            norm = math.sqrt(sx * sx + sy * sy + _SMOOTH * _SMOOTH)
            fx, fy = -load * sx / norm, -load * sy / norm
            out += (fx, fy, x * fy - y * fx)
        return out

    def power(self, twist: FloatArray, rims: tuple[float, float]) -> tuple[float, FloatArray]:
        """The power the floor's friction dissipates [per μ·m·g·(unit rim speed)] at body
        ``twist`` and rim speeds (u_L, u_R), and its gradient with respect to the twist, which is
        minus :meth:`balance`: Σ N_i·|s_i|, a convex function of the twist (each slip is affine
        in it)."""
        vx, vy, w = twist
        total = 0.0
        grad = np.zeros(3)
        for x, y, side, load in self.contacts:
            sx = vx - w * y - rims[int(side)]
            sy = vy + w * x
            norm = math.sqrt(sx * sx + sy * sy + _SMOOTH * _SMOOTH)
            total += load * norm
            grad += load * np.array([sx, sy, -y * sx + x * sy]) / norm
        return total, grad

    def solve(self, psi: float) -> FloatArray:
        """The body twist (v_x [m/s], v_y [m/s], ω [rad/s]) at rim speeds (cos ψ, sin ψ).

        The balance is the stationary point of the dissipated power (:meth:`power`, whose
        gradient is minus the net force and moment), and that power is convex in the twist: the
        twist is its minimum, found by quasi-Newton descent from the no-slip kinematics. This is
        the minimum-power principle of Coulomb-slipping wheeled vehicles (Alexander & Maddocks
        1989); it always converges, where a root finder on the non-smooth balance need not."""
        rims = (math.cos(psi), math.sin(psi))
        guess = np.array([0.5 * (rims[0] + rims[1]), 0.0, (rims[1] - rims[0]) / self.track])
        found = minimize(
            self.power, guess, args=(rims,), jac=True, method="BFGS", options={"gtol": 1e-12}
        )
        twist: FloatArray = found.x
        if np.max(np.abs(self.balance(twist, rims))) > 1e-6:
            raise RuntimeError(f"no quasi-static twist at psi={psi}: {found.message}")
        return twist

    @cached_property
    def _table(self) -> tuple[FloatArray, FloatArray]:
        psi = np.linspace(-math.pi, math.pi, _GRID)
        return psi, np.array([self.solve(float(p)) for p in psi])

    def twist(self, rims: FloatArray) -> FloatArray:
        """Body twists (n, 3) for rim speeds or travels (n, 2), interpolated in ψ and scaled
        by |(u_L, u_R)| (the balance is homogeneous of degree one)."""
        psi_grid, table = self._table
        size = np.hypot(rims[:, 0], rims[:, 1])
        psi = np.arctan2(rims[:, 1], rims[:, 0])
        out = np.stack([np.interp(psi, psi_grid, table[:, k]) for k in range(3)], axis=1)
        scaled: FloatArray = out * size[:, None]
        return scaled

    def apparent_track(self, psi: float) -> float:
        """χ = (u_R − u_L)/(B·ω) at rim speeds (cos ψ, sin ψ) [-]."""
        _, _, w = self.solve(psi)
        return (math.sin(psi) - math.cos(psi)) / (self.track * w)


def _planner(robot: CoulombSkidRobot) -> IndependentRobot:
    """The nominal differential-drive kinematics the moves are planned with."""
    return IndependentRobot(
        wheel_diameter=robot.wheel_diameter,
        wheelbase=robot.track,
        ticks_per_rev=robot.ticks_per_rev,
    )


def _simulate_run(
    m: Manoeuvre,
    robot: CoulombSkidRobot,
    rng: np.random.Generator,
    *,
    index: int,
    log_rate_hz: float,
    integration_hz: float,
) -> Run:
    motion_rng, _, sensor_rng, start, phase = run_streams(rng)
    segments = _timeline(m, _planner(robot), motion_rng)
    log_times, grid, log_index = time_grid(segments, log_rate_hz, integration_hz)
    motor = _motor_angles(segments, grid)
    rims = np.diff(motor, axis=0) * (0.5 * robot.wheel_diameter)  # rim travel per step [m]
    # The step's displacement (dx, dy, dθ) in the body frame at its start: the twist per unit
    # of rim travel, times the travel (the balance is homogeneous, so time drops out).
    step = robot.twist(rims)
    dtheta = step[:, 2]
    theta = start[2] + np.concatenate([[0.0], np.cumsum(dtheta)])
    # Exact constant-twist step: the body-frame displacement rotated by the step's mean heading
    # and scaled by the chord factor sinc(dθ/2).
    chord = np.sinc(dtheta / (2.0 * math.pi))
    mid = theta[:-1] + 0.5 * dtheta
    c, s = np.cos(mid), np.sin(mid)
    dx = chord * (c * step[:, 0] - s * step[:, 1])
    dy = chord * (s * step[:, 0] + c * step[:, 1])
    x = start[0] + np.concatenate([[0.0], np.cumsum(dx)])
    y = start[1] + np.concatenate([[0.0], np.cumsum(dy)])
    pose = np.stack([x[log_index], y[log_index], theta[log_index]], axis=1)
    pose[:, :2] += robot.sensor_position_std * sensor_rng.standard_normal((len(log_times), 2))
    pose[:, 2] += robot.sensor_heading_std * sensor_rng.standard_normal(len(log_times))
    return logged_run(
        m, index, "independent-skid", log_times, pose, motor[log_index], phase, robot.ticks_per_rev
    )


def generate_skid(
    robot: CoulombSkidRobot,
    protocol: Sequence[Manoeuvre],
    rng: np.random.Generator,
    *,
    log_rate_hz: float = 10.0,
    integration_hz: float = 200.0,
) -> list[Run]:
    """Drive ``robot`` through ``protocol``; the measured logs, one run per manoeuvre. All
    randomness (start poses, encoder phases, stops, sensor noise) from ``rng``."""
    return [
        _simulate_run(
            m, robot, rng, index=i, log_rate_hz=log_rate_hz, integration_hz=integration_hz
        )
        for i, m in enumerate(protocol)
    ]


def skid_protocol() -> list[Manoeuvre]:
    """The experiments the skid-steer papers calibrate on (Mandow et al. 2007; Wang et al.
    2015), sized for a small robot: arcs of radius 0.25, 0.5, 1 and 2 m through 180° both ways
    at 0.15 and 0.3 m/s, spins of 90°, 180° and 360° both ways at 0.1 m/s rim speed, a 2 m
    square and a 3 m out-and-back straight each way (26 runs)."""
    out: list[Manoeuvre] = []
    senses: tuple[TurnDirection, TurnDirection] = ("cw", "ccw")
    for speed in (0.15, 0.3):
        for radius in (0.25, 0.5, 1.0, 2.0):
            for sense in senses:
                out.append(
                    Manoeuvre(
                        "arc",
                        sense,
                        size=radius,
                        angle=math.pi,
                        speed=speed,
                        label=f"arc_{sense}_{radius:g}_{speed:g}",
                    )
                )
    for degrees in (90, 180, 360):
        for sense in senses:
            out.append(
                Manoeuvre(
                    "spin",
                    sense,
                    angle=math.radians(degrees),
                    speed=0.1,
                    label=f"spin_{sense}_{degrees}",
                )
            )
    for sense in senses:
        out.append(Manoeuvre("square", sense, size=2.0, speed=0.3, label=f"square_{sense}"))
        out.append(
            Manoeuvre(
                "straight", sense, size=3.0, speed=0.3, return_trip=True, label="straight_return"
            )
        )
    return out

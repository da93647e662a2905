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

**The elastic robot** (:class:`ElasticSkidRobot`) is the positive: the same four wheels on
tyres that deform before they slide, under a tyre law written here and unlike the World's. Each
contact's *practical slip* is its sliding velocity over a reference speed of the wheel,

    σ_i = (u_i − c_x, −c_y) / V_i,   V_i = √((u_i² + c_x²)/2),

c = (v_x − ω·y_i, v_y + ω·x_i) the contact point's velocity and u_i its side's rim speed (V_i is
the rim speed while the wheel rolls, and stays positive for a wheel at rest that is dragged).
The linear tyre force is N_i·l_i, l_i = (C_κ·σ_x, C_α·σ_y) (the longitudinal and cornering
stiffnesses per unit load); its size saturates exponentially at the friction limit and its
direction turns from the elastic one to Coulomb's, opposite the sliding, as it does:

    F_i = N_i·μ·g_i·d_i,   g_i = 1 − exp(−|l_i|/μ),   d_i ∥ (1 − g_i)·l_i/|l_i| + g_i·σ_i/|σ_i|.

The exponential approach to the friction circle is that of the "TMeasy" family of handling tyre
models (Hirschberg, Rill & Weinfurter 2007); the turn of the direction is written here, so that
a wheel sliding sideways in a spin pushes back as a Coulomb contact does, whatever its
stiffnesses (a law that kept the elastic direction while saturated would scale all four forces of
a symmetric spin alike, and keep χ_∞ in spins too). It is not the World's split of an elastic and
a sliding share (``odomgym.sim.world.skid_contacts``). The slips are ratios of speeds, so the
balance is again homogeneous of degree one in the rim speeds and solved once per ψ, here by
Newton's root finder continued along the grid. In wide arcs every contact is in its linear range
and the moment balance gives in closed form

    χ_∞ = 1 + (C_α/C_κ)·(a/B)²

(the Coulomb robot's value when C_α = C_κ), while in spins the lateral slips of ±a/(χ·B)
saturate, and the track approaches the Coulomb value: the factor falls from spins to wide arcs,
by an amount and at a radius that come from C_κ, C_α and μ, not from any formula of the
catalogue (``tests/test_independent_skid.py`` checks both limits).

Motion, encoders and logging are :mod:`independent_robot`'s: open-loop S-curve moves of the two
motor angles planned with the *nominal* track, exact constant-twist steps at ``integration_hz``,
quantised encoders with a random phase, ground truth at ``log_rate_hz`` with Gaussian noise.
"""

from __future__ import annotations

import functools
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
from scipy.optimize import minimize, root

from odomgym.odometry.runs import Run

__all__ = ["CoulombSkidRobot", "ElasticSkidRobot", "generate_skid", "skid_protocol"]

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


@dataclass(frozen=True)
class ElasticSkidRobot(CoulombSkidRobot):
    """A four-wheel skid-steer robot on elastic tyres with a saturating friction law (module
    docstring): the geometry, encoders and sensor of :class:`CoulombSkidRobot`, and

    Attributes:
        slip_stiffness: C_κ, longitudinal force per unit load and unit slip ratio [-].
        cornering_stiffness: C_α, lateral force per unit load and unit slip angle [1/rad].
        friction: μ, the friction coefficient the force saturates at [-] (it no longer cancels).

    The defaults (C_κ = 12, C_α = 6 /rad, μ = 0.8) are of the order of small pneumatic and solid
    rubber tyres; C_α < C_κ is what lets the track fall from spins to wide arcs (χ_∞ = 1 +
    (C_α/C_κ)·(a/B)² = 1.32 here, against 1.64 for rigid wheels).
    """

    slip_stiffness: float = 12.0
    cornering_stiffness: float = 6.0
    friction: float = 0.8

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("slip_stiffness", "cornering_stiffness", "friction"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be positive and finite, got {value}")

    def tyre_force(self, slip: FloatArray, load: float) -> FloatArray:
        """The floor's force on one wheel [per m·g] for its practical slip σ (2,) and load share
        N: N·μ·g·d with g = 1 − exp(−|l|/μ), l = (C_κ·σ_x, C_α·σ_y), and the direction d the
        unit vector of (1 − g)·l/|l| + g·σ/|σ| (module docstring); N·l itself while |l| ≪ μ,
        Coulomb's μ·N opposite the sliding once |l| ≫ μ."""
        lin = np.array([self.slip_stiffness * slip[0], self.cornering_stiffness * slip[1]])
        size = math.hypot(lin[0], lin[1])
        if size < 1e-12 * self.friction:
            return load * lin
        used = -math.expm1(-size / self.friction)  # g: the share of the friction limit in use
        way = (1.0 - used) * lin / size + used * slip / math.hypot(slip[0], slip[1])
        force: FloatArray = load * self.friction * used * way / math.hypot(way[0], way[1])
        return force

    def balance(self, twist: FloatArray, rims: tuple[float, float]) -> FloatArray:
        """The net force (x, y) and moment of the floor on the robot [per m·g] at body
        ``twist`` (v_x, v_y, ω) and rim speeds (u_L, u_R)."""
        vx, vy, w = twist
        out = np.zeros(3)
        for x, y, side, load in self.contacts:
            u = rims[int(side)]
            cx = vx - w * y
            cy = vy + w * x
            speed = math.sqrt(0.5 * (u * u + cx * cx))
            if speed == 0.0:
                continue  # neither rolling nor dragged along: no slip, no force
            fx, fy = self.tyre_force(np.array([(u - cx) / speed, -cy / speed]), load)
            out += (fx, fy, x * fy - y * fx)
        return out

    def power(self, twist: FloatArray, rims: tuple[float, float]) -> tuple[float, FloatArray]:
        """Not defined: the elastic forces are no gradient of a dissipated power (the slips are
        normalised by the wheels' speeds), so the twist is a root of :meth:`balance` instead."""
        raise TypeError("an elastic tyre's balance has no power potential; use solve()")

    def solve(self, psi: float) -> FloatArray:
        """The body twist (v_x [m/s], v_y [m/s], ω [rad/s]) at rim speeds (cos ψ, sin ψ): the
        root of :meth:`balance`, found by MINPACK's hybrid Newton method (Powell 1970) from the
        twist of a nearby ψ (:meth:`_continued`, which walks the grid from straight driving,
        where the twist is exact) or from the no-slip kinematics."""
        return self._root(psi, self._start(psi))

    def _start(self, psi: float) -> FloatArray:
        rims = (math.cos(psi), math.sin(psi))
        return np.array([0.5 * (rims[0] + rims[1]), 0.0, (rims[1] - rims[0]) / self.track])

    def _root(self, psi: float, guess: FloatArray) -> FloatArray:
        rims = (math.cos(psi), math.sin(psi))
        found = root(
            self.balance, guess, args=(rims,), jac=self._jacobian, method="hybr",
            options={"xtol": 1e-13},
        )  # fmt: skip
        twist: FloatArray = found.x
        if np.max(np.abs(self.balance(twist, rims))) > 1e-9:
            raise RuntimeError(f"no quasi-static twist at psi={psi}: {found.message}")
        return twist

    def _jacobian(self, twist: FloatArray, rims: tuple[float, float]) -> FloatArray:
        """∂ balance/∂ twist by central differences of a fixed step (10⁻⁷ of the unit rim
        speed): MINPACK's own step is relative to each unknown and vanishes where ω = 0."""
        out = np.zeros((3, 3))
        for k in range(3):
            step = np.zeros(3)
            step[k] = 1e-7
            out[:, k] = (self.balance(twist + step, rims) - self.balance(twist - step, rims)) / 2e-7
        return out

    @property
    def _table(self) -> tuple[FloatArray, FloatArray]:
        """Four times :class:`CoulombSkidRobot`'s grid: the track moves with ψ close to straight
        driving (λ from 20 to 2.5 within 0.4 rad of it), where the rigid robot's stays put, and
        linear interpolation wants the finer steps for the same 10⁻⁵. Solved once per robot
        (equal robots share it: :func:`_elastic_table`)."""
        return _elastic_table(self)

    def _continued(self, psi: FloatArray) -> FloatArray:
        """Twists on the grid ``psi`` (ascending over [−π, π]), each solved from its
        neighbour's, outward from straight forward driving (ψ = π/4, exact) both ways, then on
        from the ends to reverse driving: a smooth path of roots, without a fresh start where
        the no-slip guess is far off (spins)."""
        out = np.zeros((len(psi), 3))
        first = int(np.argmin(np.abs(psi - 0.25 * math.pi)))
        out[first] = self._root(float(psi[first]), self._start(float(psi[first])))
        for k in range(first + 1, len(psi)):
            out[k] = self._root(float(psi[k]), out[k - 1])
        for k in range(first - 1, -1, -1):
            out[k] = self._root(float(psi[k]), out[k + 1])
        return out


@functools.lru_cache(maxsize=8)
def _elastic_table(robot: ElasticSkidRobot) -> tuple[FloatArray, FloatArray]:
    psi = np.linspace(-math.pi, math.pi, 4 * (_GRID - 1) + 1)
    return psi, robot._continued(psi)


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
    x, y, theta = integrate_steps(start, robot.twist(rims))
    pose = np.stack([x[log_index], y[log_index], theta[log_index]], axis=1)
    pose[:, :2] += robot.sensor_position_std * sensor_rng.standard_normal((len(log_times), 2))
    pose[:, 2] += robot.sensor_heading_std * sensor_rng.standard_normal(len(log_times))
    return logged_run(
        m, index, "independent-skid", log_times, pose, motor[log_index], phase, robot.ticks_per_rev
    )


def integrate_steps(start: FloatArray, step: FloatArray) -> tuple[FloatArray, ...]:
    """The path x, y [m], θ [rad] at every integration step from ``start`` (x, y, θ) and each
    step's body-frame displacement ``step`` (n, 3) [m, m, rad], each step an exact
    constant-twist one: the displacement rotated by the step's mean heading and scaled by the
    chord factor sinc(dθ/2) (``benchmarks/skid_field_independent.py`` drives its robot so
    too)."""
    dtheta = step[:, 2]
    theta = start[2] + np.concatenate([[0.0], np.cumsum(dtheta)])
    chord = np.sinc(dtheta / (2.0 * math.pi))
    mid = theta[:-1] + 0.5 * dtheta
    c, s = np.cos(mid), np.sin(mid)
    dx = chord * (c * step[:, 0] - s * step[:, 1])
    dy = chord * (s * step[:, 0] + c * step[:, 1])
    x = start[0] + np.concatenate([[0.0], np.cumsum(dx)])
    y = start[1] + np.concatenate([[0.0], np.cumsum(dy)])
    return x, y, theta


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

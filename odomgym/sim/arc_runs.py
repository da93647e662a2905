"""Circles and free paths driven in simulation: continuous arcs, not routes of stops and turns.

:func:`drive_arcs` drives each robot through a plan of :class:`Arc` s (constant-curvature legs,
:func:`circle_plan`, :func:`free_plan`) by its own odometry, without stopping between legs — the
controller a differential-drive base has for a (v, ω) command, so a calibration changes the
path driven as on a real robot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.floor import FloorSpec
from odomgym.odometry.calibration import Calibration, Odometry
from odomgym.odometry.runs import Direction, Run
from odomgym.robot import RobotSpec
from odomgym.sim.route_runs import Recording
from odomgym.sim.world import World

__all__ = ["FREE_LEG_LENGTH", "FREE_MIN_RADIUS", "Arc", "circle_plan", "drive_arcs", "free_plan"]

FloatArray = NDArray[np.float64]


#: Length of each leg of a simulated free run [m]: long enough to show a curvature (a quarter
#: turn at the tightest radius), short enough that a 10 m run changes course ten times.
FREE_LEG_LENGTH = 1.0
#: Tightest turning radius of a simulated free run [m]: curvatures are drawn uniformly from
#: [−1/FREE_MIN_RADIUS, 1/FREE_MIN_RADIUS], so the inner wheel of a 0.34 m LabMate still rolls
#: forwards at 0.66 of the cruise speed.
FREE_MIN_RADIUS = 0.5


@dataclass(frozen=True)
class Arc:
    """One leg of constant curvature, driven without stopping.

    Attributes:
        length: path length of the axle midpoint along the leg, as the odometry measures it [m].
        curvature: 1/radius, positive turning left (ccw) [1/m]; 0 for a straight leg.
    """

    length: float
    curvature: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.length) and self.length > 0.0):
            raise ValueError(f"an arc's length must be > 0 [m], got {self.length!r}")
        if not math.isfinite(self.curvature):
            raise ValueError(f"an arc's curvature must be finite [1/m], got {self.curvature!r}")


def circle_plan(radius: float, direction: Direction, laps: float = 1.0) -> tuple[Arc, ...]:
    """``laps`` laps of a circle of ``radius`` [m], turning right (``cw``) or left (``ccw``)."""
    if not radius > 0.0 or not laps > 0.0:
        raise ValueError(f"need radius > 0 [m] and laps > 0, got {radius}, {laps}")
    sign = -1.0 if direction == "cw" else 1.0
    return (Arc(2.0 * math.pi * radius * laps, sign / radius),)


def free_plan(rng: np.random.Generator, length: float) -> tuple[Arc, ...]:
    """A random path of ``length`` [m]: legs of :data:`FREE_LEG_LENGTH` (the last one shorter)
    whose curvatures are uniform in ±1/:data:`FREE_MIN_RADIUS` — the simulator's stand-in for a
    person driving the robot about. It turns both ways, which is what lets a trajectory fit
    tell the two wheels apart (Sousa et al. 2022 fit such free paths too)."""
    if not length > 0.0:
        raise ValueError(f"length must be > 0 [m], got {length}")
    legs = math.ceil(length / FREE_LEG_LENGTH - 1e-9)
    curvatures = rng.uniform(-1.0 / FREE_MIN_RADIUS, 1.0 / FREE_MIN_RADIUS, size=legs)
    last = length - (legs - 1) * FREE_LEG_LENGTH
    return tuple(
        Arc(FREE_LEG_LENGTH if k < legs - 1 else last, float(c)) for k, c in enumerate(curvatures)
    )


def _curved_half_track(cal: Calibration, track: float, mean: float, omega: float) -> float:
    """Half the track [m] a calibration whose track moves with the turn believes for the rims'
    mean speed ``mean`` [m/s] and yaw rate ``omega`` [rad/s]: b_eff(λ)/2 at the λ = mean/(ω·
    b_eff/2) it makes, found by fixed-point iteration (the factor moves slowly with λ)."""
    factor = cal.wheelbase_scale
    for _ in range(50):
        lam = mean / (omega * 0.5 * factor * track)
        new = float(cal.track_factor(lam))
        if abs(new - factor) < 1e-12:
            break
        factor = new
    return 0.5 * factor * track


def drive_arcs(
    robots: RobotSpec | Sequence[RobotSpec],
    floor: FloorSpec,
    plans: Sequence[Sequence[Arc]],
    *,
    calibration: Calibration | Sequence[Calibration] | None = None,
    rng: np.random.Generator | Sequence[np.random.Generator] | None = None,
    cruise_speed: float = 0.2,
    dt: float = 0.05,
    kind: str = "free",
    direction: Direction | None = None,
    start_poses: FloatArray | None = None,
    max_time: float | None = None,
    on_timeout: Literal["raise", "keep"] = "raise",
) -> list[Run]:
    """Drive each robot through its plan of arcs by its own odometry; return the runs.

    The robot's controller does what a differential-drive base does with a (v, ω) command:
    for a leg of curvature κ it asks for the body speed v = ``cruise_speed`` [m/s] and the yaw
    rate ω = κ·v, i.e. rim speeds v ∓ ω·b/2, and turns them into wheel rates with the
    wheelbase b and wheel diameters it *believes* (the nominal ones corrected by
    ``calibration``) — so a calibration changes the path driven, as on a real robot. A
    skid-steer calibration's y_ICR moves the body y_ICR·ω forward beyond the rims' mean: the
    rims then run at v − y_ICR·ω ∓ ω·b/2, and the odometric path length counts its y_ICR·Δθ. Rim
    speeds beyond ``max_wheel_speed`` are scaled down together (the curvature is kept). A leg
    ends when the odometry has measured its length; the next starts without stopping (the
    wheel controllers' acceleration limit smooths the change). The robot brakes when the
    odometric distance left is what it needs to stop at ``max_wheel_accel``, and the run ends
    when both wheels are at rest.

    Args:
        robots: one spec per plan, or one spec for every plan.
        floor: the floor; rough floors draw their noise from ``rng``.
        plans: one sequence of arcs per robot.
        calibration: the odometry calibration while driving (one, or one per robot).
        rng: random source (required on rough floors): one Generator, or one per robot.
        cruise_speed: body speed on the legs [m/s].
        dt: control period [s].
        kind, direction: labels stored in the runs.
        start_poses: where each robot starts on the floor (K, 3) [m, m, rad] (default: the
            origin); the plan is driven in each robot's start frame.
        max_time: give up after this much simulated time [s] (default: 3 × the nominal time
            + 60 s).
        on_timeout: ``"raise"`` — RuntimeError naming the robots that did not stop;
            ``"keep"`` — return their runs up to the time limit, marked
            ``run.meta["finished"] = False`` (as :func:`simulate_runs`).

    Returns:
        One run per plan, true poses in the floor's frame (apply :func:`measure` before showing
        them to a calibrator).
    """
    count = len(plans)
    specs = [robots] * count if isinstance(robots, RobotSpec) else list(robots)
    if len(specs) != count or count == 0:
        raise ValueError(f"need one robot per plan, got {len(specs)} robots and {count} plans")
    cals = (
        [calibration if calibration is not None else Calibration()] * count
        if calibration is None or isinstance(calibration, Calibration)
        else list(calibration)
    )
    if len(cals) != count:
        raise ValueError(f"need one calibration per plan ({count}), got {len(cals)}")
    if not cruise_speed > 0.0:
        raise ValueError(f"cruise_speed must be > 0 [m/s], got {cruise_speed}")
    world = World(specs, floor, dt=dt, rng=rng)
    if start_poses is not None:
        world.reset(np.asarray(start_poses, dtype=float))
    odometry = Odometry(specs, cals)
    believed = [c.parameters(s) for c, s in zip(cals, specs, strict=True)]
    half_base = np.array([0.5 * b["wheelbase"] for b in believed])
    # A skid-steer calibration's ICRs (Mandow et al. 2007): the body moves y_ICR forward per
    # radian turned, so the rims' mean speed is what is left of the cruise speed.
    icr_y = np.array([c.icr_y for c in cals])
    skid_terms = bool(np.any(icr_y != 0.0))
    curved = [c.has_track_curve for c in cals]
    radius = np.array([[0.5 * b["left_diameter"], 0.5 * b["right_diameter"]] for b in believed])
    max_speed = np.array([s.max_wheel_speed for s in specs])
    max_accel = np.array([s.max_wheel_accel for s in specs])
    stop_speed = np.maximum(0.005, np.array([1.5 * s.metres_per_tick / dt for s in specs]))
    totals = np.array([sum(leg.length for leg in plan) for plan in plans])
    ends = [np.cumsum([leg.length for leg in plan]) for plan in plans]
    curvature = [np.array([leg.curvature for leg in plan]) for plan in plans]

    nominal_time = float(totals.max()) / cruise_speed
    limit = max_time if max_time is not None else 3.0 * nominal_time + 60.0
    max_steps = math.ceil(limit / dt)
    record = world.tracked_pose if world.has_tracked_point else (lambda: world.pose)
    recording = Recording(count, int(1.5 * nominal_time / dt) + 100)
    recording.store(0, record(), world.counts)
    travelled = np.zeros(count)  # odometric path length [m]
    braking = np.zeros(count, dtype=bool)
    command = np.zeros((count, 2))
    step = 0
    timed_out = np.zeros(count, dtype=bool)
    while (recording.finished_at < 0).any():
        if step >= max_steps and on_timeout == "keep":
            timed_out = recording.finished_at < 0
            recording.finished_at[timed_out] = step
            break
        if step >= max_steps:
            stuck = np.flatnonzero(recording.finished_at < 0).tolist()
            raise RuntimeError(
                f"robots {stuck} did not finish their arcs within {limit:.0f} s of simulated "
                "time (a slippery floor?)"
            )
        speed = 0.5 * odometry.wheel_speed.sum(axis=1)  # odometric body speed [m/s]
        braking |= totals - travelled <= speed**2 / (2.0 * max_accel) + np.abs(speed) * dt
        command[:] = 0.0
        for r in np.flatnonzero(~braking).tolist():
            leg = min(int(np.searchsorted(ends[r], travelled[r], side="right")), len(ends[r]) - 1)
            omega = curvature[r][leg] * cruise_speed
            mean = cruise_speed - icr_y[r] * omega if skid_terms else cruise_speed
            half = half_base[r]
            if curved[r] and omega != 0.0:
                half = _curved_half_track(cals[r], specs[r].wheelbase, mean, omega)
            rims = mean + np.array([-omega, omega]) * half
            rims *= min(1.0, max_speed[r] / float(np.abs(rims).max()))
            command[r] = rims / radius[r]
        world.step(command)
        heading = odometry.pose[:, 2].copy() if skid_terms else None
        odometry.update(world.counts, dt)
        travelled += 0.5 * odometry.wheel_speed.sum(axis=1) * dt
        if heading is not None:
            travelled += icr_y * (odometry.pose[:, 2] - heading)
        step += 1
        recording.store(step, record(), world.counts)
        at_rest = braking & (np.abs(odometry.wheel_speed).max(axis=1) < stop_speed)
        recording.finished_at[at_rest & (recording.finished_at < 0)] = step
    label = str(kind)
    runs = []
    for i, plan in enumerate(plans):
        time_arr, count_arr, pose_arr = recording.series(i, step, dt)
        length = float(totals[i])
        shape = (
            {
                "radius": 1.0 / abs(plan[0].curvature),
                "laps": length * abs(plan[0].curvature) / (2.0 * math.pi),
            }
            if label == "circular" and len(plan) == 1 and plan[0].curvature
            else {"length": length}
        )
        runs.append(
            Run(
                kind=label,
                time=time_arr,
                counts=count_arr,
                true_pose=pose_arr,
                direction=direction,
                side=float(shape.get("radius", 0.0)),
                source=f"sim:{label}-{length:g}m",
                meta={
                    "robot": specs[i].name,
                    "floor": floor.name,
                    "finished": not bool(timed_out[i]),
                    **shape,
                },
            )
        )
    return runs

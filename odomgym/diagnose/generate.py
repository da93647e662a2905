"""Logs of a simulated robot carrying a hidden effect, for proving the workflow.

:func:`simulate_protocol` drives a robot spec (with whatever effects it carries) through the pymunk
World under one of two documented protocols and returns runs as a tracking system would log them
(the tracked point with Gaussian sensor noise on every logged row):

* ``"rich"`` — the characterisation protocol: 1.5 m squares (2 cw, 2 ccw, by odometry with the
  reference driver at 0.2 m/s), 3 m straights out and back in reverse (2) and one way (2),
  in-place turns of 90°, 180° and 360° both ways at wheel speeds 0.1 and 0.3 m/s (12), and
  half circles of 1 m radius both ways at 0.15 and 0.35 m/s (4, open-loop wheel commands);
  ground truth at every 50 ms sample;
* ``"umbmark"`` — 5 cw + 5 ccw 1.5 m squares, ground truth at the first and last rows only.

:func:`simulate_field_log` drives a robot (of either class) through one session as a user's
logs hold it, not as a protocol asks: squares, circles, spins and free paths, a marker off the
axle, and a tracker that lost the marker for a share of the samples.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.effects.sensor import offset_point
from odomgym.errors import SpecError
from odomgym.floor import FloorSpec
from odomgym.lab.experiment import SensorAccuracy
from odomgym.lab.simulated import measure
from odomgym.odometry.runs import Direction, Run
from odomgym.robot import RobotSpec
from odomgym.sim.arc_runs import circle_plan, drive_arcs, free_plan
from odomgym.sim.route_runs import simulate_runs
from odomgym.sim.routes import Route, spin_route, square_route, straight_route
from odomgym.sim.world import World

__all__ = ["Protocol", "simulate_field_log", "simulate_protocol"]

FloatArray = NDArray[np.float64]
Protocol = Literal["rich", "umbmark"]
_DIRECTIONS: tuple[Direction, ...] = ("cw", "ccw")


def _arc(
    robot: RobotSpec,
    radius: float,
    speed: float,
    sign: float,
    rng: np.random.Generator,
    floor: FloorSpec | None = None,
) -> Run:
    """An open-loop half circle on ``floor`` (default: a plain floor): ramp up, hold (v,
    ω = v/R), ramp down, at 20 Hz."""
    dt = 0.05
    world = World(robot, floor if floor is not None else FloorSpec(), dt=dt, rng=rng)
    half_b = 0.5 * robot.wheelbase
    r_nom = 0.5 * robot.wheel_diameter
    omega = sign * speed / radius
    rates = np.array([speed - omega * half_b, speed + omega * half_b]) / r_nom
    hold = round((math.pi * radius / speed) / dt)
    ramp = 20
    profile = np.concatenate([np.linspace(0.05, 1, ramp), np.ones(hold), np.linspace(1, 0, ramp)])
    profile = np.concatenate([profile, np.zeros(10)])
    times, counts, poses = [0.0], [world.counts[0].copy()], [world.tracked_pose()[0]]
    for f in profile:
        world.step((rates * f)[None, :])
        times.append(world.time)
        counts.append(world.counts[0].copy())
        poses.append(world.tracked_pose()[0])
    return Run("free", np.array(times), np.array(counts), np.array(poses))


FloorDraw = Callable[[np.random.Generator], FloorSpec]
"""A floor drawn afresh for every run (e.g. a new layout of cables): what a robot meets when
each run starts somewhere else on a cluttered floor."""


def simulate_protocol(
    robot: RobotSpec,
    protocol: Protocol,
    rng: np.random.Generator,
    *,
    sensor: tuple[float, float] = (0.001, 0.002),
    floor: FloorSpec | FloorDraw | None = None,
) -> list[Run]:
    """Runs of ``robot`` under ``protocol`` (module docstring), logged with sensor noise
    ``sensor`` = (position σ [m], heading σ [rad]). ``floor``: one floor for every run, or a
    function drawing each run's floor from ``rng`` (then every run is driven on its own floor,
    one after the other)."""

    def drive(route: Route, repeats: int = 1, cruise_speed: float = 0.2) -> list[Run]:
        if callable(floor):
            out: list[Run] = []
            for _ in range(repeats):
                runs, _ = simulate_runs(
                    robot, floor(rng), route, rng=rng, cruise_speed=cruise_speed
                )
                out.extend(runs)
            return out
        ground = floor if floor is not None else FloorSpec()
        runs, _ = simulate_runs(
            robot, ground, route, rng=rng, repeats=repeats, cruise_speed=cruise_speed
        )
        return runs

    def floor_of() -> FloorSpec:
        if callable(floor):
            return floor(rng)
        return floor if floor is not None else FloorSpec()

    plans: list[tuple[str, list[Run]]] = []
    if protocol == "umbmark":
        for d in _DIRECTIONS:
            plans.append((f"square_{d}", drive(square_route(1.5, d), 5)))
    else:
        for d in _DIRECTIONS:
            plans.append((f"square_{d}", drive(square_route(1.5, d), 2)))
        plans.append(("straight_return", drive(straight_route(3.0, True), 2)))
        plans.append(("straight_oneway", drive(straight_route(3.0), 2)))
        for speed, tag in ((0.1, "slow"), (0.3, "fast")):
            for angle in (90, 180, 360):
                for d in _DIRECTIONS:
                    runs = drive(
                        spin_route(math.radians(angle), d),
                        cruise_speed=min(speed, robot.max_wheel_speed),
                    )
                    plans.append((f"spin_{d}_{angle}_{tag}", runs))
        for speed, tag in ((0.15, "slow"), (0.35, "fast")):
            for sign, d in ((-1.0, "cw"), (1.0, "ccw")):
                plans.append((f"arc_{d}_{tag}", [_arc(robot, 1.0, speed, sign, rng, floor_of())]))
    out: list[Run] = []
    for label, runs in plans:
        for run in runs:
            pose = run.true_pose + rng.standard_normal(run.true_pose.shape) * np.array(
                [sensor[0], sensor[0], sensor[1]]
            )
            if protocol == "umbmark":
                pose[1:-1] = np.nan
            out.append(
                Run(
                    run.kind,
                    run.time,
                    run.counts,
                    pose,
                    run.direction,
                    run.side,
                    source="sim",
                    meta={"run": f"{len(out) + 1:03d}", "experiment": label},
                )
            )
    return out


#: Directions of the two-parameter effects' hidden values: (dx, dy) of ``gt_sensor_offset`` is
#: drawn uniformly on the circle; ``floor_roughness`` has k_L = k_R; ``floor_bumps`` has a fixed
#: rate and a varying jump.
BUMP_RATE = 0.5
"""Bumps per metre of one wheel's travel in hidden ``floor_bumps`` effects [1/m]."""


def simulate_field_log(
    robot: RobotSpec,
    rng: np.random.Generator,
    *,
    lost: float = 0.0,
    marker: tuple[float, float] = (0.29, 0.0),
    sensor: tuple[float, float] = (0.001, math.radians(0.2)),
    floor: FloorSpec | None = None,
) -> list[Run]:
    """One session of ``robot``'s logs as a user brings them: 3 m squares both ways and
    circles of 1 and 2.5 m radius both ways at 0.5 m/s, a full spin each way at 0.4 m/s, and
    six 25 m free paths (legs of 1 m, turning up to 2 /m,
    :func:`~odomgym.sim.arc_runs.free_plan`) at 0.6 m/s, on ``floor`` (default: a plain floor).
    The tracked point sits at ``marker`` = (dx, dy) [m] in the body frame (a motion-capture
    rigid body is rarely on the axle), measured with ``sensor`` = (position σ [m], heading σ
    [rad]); the tracker lost the marker for a share ``lost`` (0–0.9) of each run's samples, in
    bursts of 3–59 samples, written as gaps (NaN: what a held pose becomes, or an empty cell).
    Runs are named ``r00``, ``r01``, … and labelled with their experiment.

    Why: the protocols above are what a calibration asks for; a diagnosis also meets logs
    that were not recorded for it, and a real skid-steer robot's logs had 45 % of their
    tracker samples held (issue 42). ``tests/test_skid_diagnose.py`` and
    ``benchmarks/skid_field.py`` diagnose such logs.

    Raises:
        SpecError: ``lost`` outside [0, 0.9] (``field`` = ``lost``).
    """
    if not 0.0 <= lost <= 0.9:
        raise SpecError(f"lost must lie in [0, 0.9], got {lost}", field="lost")
    ground = floor if floor is not None else FloorSpec()

    def tagged(runs: list[Run], label: str) -> list[Run]:
        return [dataclasses.replace(r, meta=dict(r.meta, experiment=label)) for r in runs]

    runs: list[Run] = []
    for direction in _DIRECTIONS:
        route = square_route(3.0, direction)
        squares, _ = simulate_runs(
            robot, ground, route, cruise_speed=0.5, kind="square", direction=direction
        )
        runs += tagged(squares, f"square_{direction}")
    for radius in (1.0, 2.5):
        for direction in _DIRECTIONS:
            plan = [circle_plan(radius, direction, laps=1.0)]
            circles = drive_arcs(robot, ground, plan, cruise_speed=0.5, kind="circular")
            runs += tagged(circles, f"circle_{direction}_{radius:g}")
    for direction in _DIRECTIONS:
        route = spin_route(2.0 * math.pi, direction)
        spins, _ = simulate_runs(
            robot, ground, route, cruise_speed=0.4, kind="spin", direction=direction
        )
        runs += tagged(spins, f"spin_{direction}")
    for i in range(6):
        plan = [free_plan(rng, 25.0)]
        runs += tagged(drive_arcs(robot, ground, plan, cruise_speed=0.6, kind="free"), f"free_{i}")
    dx, dy = marker
    runs = [dataclasses.replace(r, true_pose=offset_point(r.true_pose, dx, dy)) for r in runs]
    runs = measure(runs, SensorAccuracy(sensor[0], sensor[1]), rng)
    out = []
    for i, run in enumerate(runs):
        pose = run.true_pose.copy()
        held = np.zeros(len(pose), dtype=bool)
        while held.mean() < lost:
            start = int(rng.integers(1, len(pose) - 1))
            # a burst stops before the last sample, which is kept
            held[start : min(start + int(rng.integers(3, 60)), len(pose) - 1)] = True
        pose[held] = np.nan
        out.append(dataclasses.replace(run, true_pose=pose, meta=dict(run.meta, run=f"r{i:02d}")))
    return out


def detection_limit(
    name: str,
    protocol: Protocol,
    *,
    robot: RobotSpec | None = None,
    sensor: tuple[float, float] = (0.001, 0.002),
    direction: tuple[float, ...] | None = None,
) -> float:
    """The smallest detectable magnitude of effect ``name`` under ``protocol`` [its unit].

    Systematic effects: three Cramér–Rao standard errors of the magnitude along ``direction``
    (unit vector in parameter space; default the first parameter), from the Fisher information
    of the protocol's noise-free runs measured by a sensor of σ = ``sensor`` — i.e. the
    magnitude whose expected likelihood-ratio statistic is 9. Magnitudes are offsets from the
    absent value (e_d − 1 for ``wheel_diameter_ratio``).
    An effect that ``diagnose`` fits with partners free beside it (:attr:`Effect.partners`:
    ``skid_track`` with ``wheelbase``) is detectable only by what its partners cannot take up:
    their parameters are unknowns of the same fit, so the information along ``direction`` is
    the Schur complement I_uu − I_up·I_pp⁻¹·I_pu (the Cramér–Rao bound with nuisance
    parameters, Kay 1993, Theorem 3.2: var θ̂_i ≥ [I⁻¹]_ii; the effect's own other parameters
    stay fixed, since at the absent value ``skid_track``'s λ½ has no information). Noise
    partners are not profiled out (the fit leaves them to the noise). For ``skid_track`` under
    the rich protocol that is 4.5e-4 against 9.9e-5 with the track held at its nominal value
    (the two columns correlate at 0.976: the protocol's spins and squares see mostly a constant
    factor).
    Noise effects (no Fisher information at their absent value): ``floor_roughness`` — the k
    (both wheels) whose heading spread over 6 m of travel equals the sensor's heading σ,
    σ_θ·b/√(2·6 m) (Chong & Kleeman 1997, Eq. 4 summed over both wheels); ``floor_bumps`` —
    a heading jump equal to the sensor's heading σ at :data:`BUMP_RATE` bumps per metre.
    """
    from odomgym.diagnose.fit import CandidateFit, Dataset, _linearise
    from odomgym.diagnose.likelihood import SensorNoise
    from odomgym.effects import EFFECTS

    nominal = robot if robot is not None else NOMINAL_ROBOT
    effect = EFFECTS[name]
    if name == "floor_roughness":
        return sensor[1] * nominal.true_wheelbase / math.sqrt(2.0 * 6.0)
    if name == "floor_bumps":
        return sensor[1]
    runs = simulate_protocol(nominal, protocol, np.random.default_rng(0), sensor=(0.0, 0.0))
    data = Dataset.of(runs, 0.25)
    noise = SensorNoise(*sensor)
    jacobian: list[NDArray[np.float64]] | None = None
    scales: list[float] = []
    for member in (name, *(p for p in effect.partners if not EFFECTS[p].noise)):
        fit = CandidateFit(
            member, nominal, noise, EFFECTS[member].read(nominal), np.zeros(len(runs))
        )
        _linearise(data, fit, EFFECTS[member])
        scales += [p.scale for p in EFFECTS[member].parameters]
        jacobian = (
            fit.jacobian
            if jacobian is None
            else [np.hstack([a, b]) for a, b in zip(jacobian, fit.jacobian, strict=True)]
        )
    assert jacobian is not None
    scale = np.array(scales)
    physical = sum(j.T @ j for j in jacobian) / np.outer(scale, scale)
    own = len(effect.parameters)
    info = physical[:own, :own]
    if own < len(scale):
        info = info - physical[:own, own:] @ np.linalg.solve(
            physical[own:, own:], physical[own:, :own]
        )
    u = np.zeros(own)
    if direction is None:
        u[0] = 1.0
    else:
        u[:] = direction
    return float(3.0 / math.sqrt(max(float(u @ info @ u), 1e-300)))


def hidden_effect(
    name: str, factor: float, protocol: Protocol, rng: np.random.Generator
) -> dict[str, float]:
    """Parameter values of effect ``name`` at ``factor`` × its :func:`detection_limit` under
    ``protocol``, with a random sign (and a random direction for ``gt_sensor_offset``)."""
    from odomgym.effects import EFFECTS

    effect = EFFECTS[name]
    sign = 1.0 if rng.random() < 0.5 else -1.0
    if name == "floor_roughness":
        k = factor * detection_limit(name, protocol)
        return {"k_left": k, "k_right": k}
    if name == "floor_bumps":
        return {"rate": BUMP_RATE, "heading_jump": factor * detection_limit(name, protocol)}
    if name == "gt_sensor_offset":
        angle = rng.uniform(0.0, 2.0 * math.pi)
        u = (math.cos(angle), math.sin(angle))
        m = factor * detection_limit(name, protocol, direction=u)
        return {"dx": m * u[0], "dy": m * u[1]}
    p = effect.parameters[0]
    m = factor * detection_limit(name, protocol)
    if name in ("turn_skid", "backlash", "skid_track", "skid_speed"):
        sign = 1.0  # one-sided parameters
    return {p.name: p.absent + sign * m}


NOMINAL_ROBOT = RobotSpec(
    name="optiodom-ideal",
    wheel_diameter=0.084,
    wheelbase=0.200,
    ticks_per_rev=64 * 43.7,
    mass=3.0,
    chassis_length=0.26,
    chassis_width=0.26,
    max_wheel_speed=0.4,
    max_wheel_accel=0.5,
    source="the OptiOdom robot's nominal parameters (optiodom-diff README), no errors",
)
"""The robot the generator's hidden effects are added to."""

NOMINAL_SKID_ROBOT = dataclasses.replace(
    NOMINAL_ROBOT,
    name="optiodom-ideal-skid",
    axle_spacing=0.16,
    drive_load_fraction=1.0,
    source="NOMINAL_ROBOT's wheels and side-to-side track on two axles 0.16 m apart: the "
    "nominal model of the independent rigid-Coulomb skid-steer robot (tests/independent_skid.py)",
)
"""The same wheels and track as :data:`NOMINAL_ROBOT` on two axles: the nominal model against
which the independent skid-steer robot of ``tests/independent_skid.py`` (the same geometry on
rigid Coulomb wheels) is diagnosed, in ``tests/test_skid_diagnose.py`` and
``benchmarks/skid_matrix.py``. The diagnosis does not read the class from it: every robot is
screened for every catalogue effect."""


def _top1(name: str | None, result: Any) -> str:
    from odomgym.effects import EFFECTS

    noise = name is not None and EFFECTS[name].noise
    group = result.noise_model if noise else result.systematic_effects
    if group:
        return str(group[0])
    return str(result.named_effects[0]) if result.named_effects else str(result.verdict)


def hidden_effect_trial(
    name: str | None,
    protocol: Protocol,
    seed: int,
    *,
    factor_range: tuple[float, float] = (3.0, 10.0),
) -> dict[str, object]:
    """One blind trial: a robot carrying effect ``name`` (None: no effect) at a random
    magnitude of ``factor_range`` × its detection limit, simulated under ``protocol`` with seed
    ``seed``, diagnosed against the nominal model without being told the effect. Returns the
    truth, the verdict, the named/tied effects and the held-out gaps."""
    from odomgym.diagnose.workflow import DiagnoseConfig, diagnose

    rng = np.random.default_rng(seed)
    factor = float(rng.uniform(*factor_range))
    robot = NOMINAL_ROBOT
    values: dict[str, float] = {}
    if name is not None:
        from odomgym.effects import EFFECTS

        values = hidden_effect(name, factor, protocol, rng)
        robot = EFFECTS[name].write(robot, values)
    runs = simulate_protocol(robot, protocol, rng)
    result = diagnose(runs, NOMINAL_ROBOT, DiagnoseConfig(seed=seed))
    last = result.rounds[-1]
    return {
        "truth": name or "none",
        "factor": factor if name else 0.0,
        "values": values,
        "verdict": result.verdict,
        # The report names systematic effects before the noise model: a noise effect's trial
        # is scored on the first noise effect named, any other on the first systematic one.
        "top1": _top1(name, result),
        # What the likelihood's first round proposed, before the open-loop gate judged it.
        "proposed": result.rounds[0].winner if result.rounds else None,
        "named": result.named_effects,
        "tied": last.tied,
        "fitted": result.parameters,
        "gap_before": result.gap_before,
        "gap_after": result.gap_after,
        "seed": seed,
    }

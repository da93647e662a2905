"""The simulated lab: drive robots through routes with the reference driver and record runs.

:func:`simulate_runs` is the workhorse: a batch of robots (one :class:`~odomgym.sim.trial.Trial`)
drives a route with the :class:`~odomgym.sim.driver.ReferenceDriver` until every robot's odometry
says it is done, and each robot's time series becomes a :class:`~odomgym.odometry.runs.Run`.
Repetitions of one experiment are simulated *together* (one pymunk space), which is why a 5 cw + 5
ccw UMBmark costs about as much as two runs.

Circular and free runs are not routes of stops and turns but continuous arcs:
:func:`drive_arcs` drives each robot through a plan of :class:`Arc` s (constant-curvature legs,
:func:`circle_plan`, :func:`free_plan`) by its own odometry, without stopping between legs.

:class:`SimLab` implements the :class:`~odomgym.lab.experiment.Lab` protocol over a hidden true
robot: a calibrator asks for experiments and receives runs whose ground truth went through a
:class:`~odomgym.lab.experiment.SensorAccuracy` (noisy like a real sensor), never the truth itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from odomgym.floor import FloorSpec
from odomgym.lab.experiment import BookkeepingLab, Experiment, ExperimentKind, SensorAccuracy
from odomgym.odometry.calibration import Calibration, Odometry
from odomgym.odometry.runs import Direction, Run
from odomgym.robot import RobotSpec
from odomgym.sim.driver import ReferenceDriver
from odomgym.sim.routes import Route, spin_route, square_route, straight_route
from odomgym.sim.trial import OBSERVATION_NAMES, Trial
from odomgym.sim.world import World

__all__ = [
    "ARC_KINDS",
    "FREE_LEG_LENGTH",
    "FREE_MIN_RADIUS",
    "Arc",
    "RunRequests",
    "SimLab",
    "arc_plans",
    "circle_plan",
    "drive_arcs",
    "experiment_route",
    "free_plan",
    "measure",
    "perform_many",
    "random_start_poses",
    "simulate_runs",
]

FloatArray = NDArray[np.float64]

_ROUTE_FRACTION = OBSERVATION_NAMES.index("route_fraction")  # column of the route state


def experiment_route(experiment: Experiment) -> Route:
    """The route a square, straight or spin experiment drives (circular and free experiments
    drive arcs: :func:`circle_plan`, :func:`free_plan`)."""
    kind = experiment.kind
    if kind is ExperimentKind.SQUARE:
        assert experiment.direction is not None
        return square_route(experiment.size, experiment.direction)
    if kind is ExperimentKind.STRAIGHT:
        return straight_route(experiment.size, experiment.return_trip)
    if kind is ExperimentKind.SPIN:
        assert experiment.direction is not None
        return spin_route(experiment.size, experiment.direction)
    raise ValueError(f"a {kind} experiment drives arcs, not a route (see drive_arcs)")


class _Recording:
    """The time series of a batch: poses (T, K, 3) and counts (T, K, 2), grown geometrically,
    and the step at which each robot finished."""

    def __init__(self, robots: int, capacity: int) -> None:
        self.poses = np.empty((capacity, robots, 3))
        self.counts = np.empty((capacity, robots, 2), dtype=np.int64)
        self.finished_at = np.full(robots, -1, dtype=np.int64)

    def store(self, step: int, pose: FloatArray, counts: NDArray[np.int64]) -> None:
        if step == len(self.poses):
            self.poses = np.concatenate([self.poses, np.empty_like(self.poses)])
            self.counts = np.concatenate([self.counts, np.empty_like(self.counts)])
        self.poses[step] = pose
        self.counts[step] = counts

    def series(
        self, robot: int, last_step: int, dt: float
    ) -> tuple[FloatArray, NDArray[np.int64], FloatArray]:
        """Time [s], counts and poses of ``robot`` up to the step it finished (or
        ``last_step``)."""
        end = (int(self.finished_at[robot]) if self.finished_at[robot] >= 0 else last_step) + 1
        time = np.arange(end, dtype=np.float64) * dt
        return time, self.counts[:end, robot].copy(), self.poses[:end, robot].copy()


def simulate_runs(
    robots: RobotSpec | Sequence[RobotSpec],
    floor: FloorSpec,
    route: Route | Sequence[Route],
    *,
    calibration: Calibration | Sequence[Calibration] | None = None,
    rng: np.random.Generator | Sequence[np.random.Generator] | None = None,
    repeats: int = 1,
    cruise_speed: float = 0.2,
    dt: float = 0.05,
    max_time: float | None = None,
    kind: str | Sequence[str] = "square",
    direction: str | Sequence[str | None] | None = None,
    progress: Callable[[float], None] | None = None,
    start_poses: FloatArray | None = None,
    on_timeout: Literal["raise", "keep"] = "raise",
) -> tuple[list[Run], FloatArray]:
    """Drive ``route`` with the reference driver; return the runs and the robots' own odometry
    end poses (K, 3).

    Args:
        robots: one spec (repeated ``repeats`` times) or a list of specs (a population; all
            must share the nominal parameters the driver uses).
        floor: the floor; rough floors draw their noise from ``rng``.
        route: what to drive: one route for all, or one per robot.
        calibration: the odometry calibration active while driving (one, or one per robot).
        rng: random source (required on rough floors): one Generator, or one per robot.
        repeats: copies of a single spec to simulate together.
        cruise_speed: leg speed [m/s] of the reference driver (UMBmark: 0.2).
        dt: control period [s].
        max_time: give up after this much simulated time [s] (default: 20 × the nominal
            route time + 60 s).
        on_timeout: ``"raise"`` — RuntimeError naming the robots that did not finish;
            ``"keep"`` — return their runs up to the time limit, marked
            ``run.meta["finished"] = False`` (a batch of many robots then does not fail for
            one robot's sake).
        kind, direction: labels stored in the runs (one for all, or one per robot).
        progress: called with the completed fraction (0..1) now and then, for progress bars.
        start_poses: where each robot starts on the floor (K, 3) [m, m, rad] (default: the
            origin). The route is driven in each robot's start frame.

    Returns:
        ``(runs, odometry_end_poses)``. Runs hold the *true* poses in the floor's frame; the
        odometry end poses are in each run's start frame (compare them with
        :func:`odomgym.odometry.runs.end_error`). Apply a sensor model (:func:`measure`) before
        showing runs to a calibrator.
    """
    specs = [robots] * repeats if isinstance(robots, RobotSpec) else list(robots)
    routes = [route] * len(specs) if isinstance(route, Route) else list(route)
    kinds = [kind] * len(specs) if isinstance(kind, str) else list(kind)
    directions = (
        [direction] * len(specs)
        if direction is None or isinstance(direction, str)
        else list(direction)
    )
    driven = {(s.wheelbase, s.max_wheel_speed, s.max_wheel_accel) for s in specs}
    if len(driven) != 1:
        raise ValueError("robots driven together must share nominal wheelbase, speed and accel")
    trial = Trial(
        specs, floor, routes, calibration=calibration, dt=dt, rng=rng, start_poses=start_poses
    )
    driver = ReferenceDriver(specs[0], cruise_speed=cruise_speed)
    nominal_time = max(r.wheel_travel(specs[0].wheelbase) for r in routes) / cruise_speed
    limit = max_time if max_time is not None else 20.0 * nominal_time + 60.0
    max_steps = math.ceil(limit / dt)
    recording = _Recording(trial.n, int(2.0 * nominal_time / dt) + 100)
    # What a tracking system reports: the true pose, or the tracked point of a robot whose
    # ground-truth sensor is offset (effect ``gt_sensor_offset``).
    world = trial.world
    record = world.tracked_pose if world.has_tracked_point else (lambda: trial.true_pose)
    recording.store(0, record(), trial.world.counts)
    finished_at = recording.finished_at
    done = trial.progress.done
    step = 0
    act, observe, advance = driver.act, trial.observation, trial.step

    def observe_batch() -> FloatArray:
        return np.asarray(observe(), dtype=np.float64)

    while not done.all():
        if step >= max_steps and on_timeout == "keep":
            finished_at[finished_at < 0] = step
            break
        if step >= max_steps:
            stuck = np.flatnonzero(~done).tolist()
            names = sorted({routes[i].name for i in stuck})
            raise RuntimeError(
                f"robots {stuck} did not finish {', '.join(names)} within {limit:.0f} s of "
                "simulated time (a slippery floor or an unreachable tolerance?)"
            )
        if advance(act(observe_batch())).any():
            done = trial.progress.done
            finished_at[done & (finished_at < 0)] = step + 1
        step += 1
        recording.store(step, record(), trial.world.counts)
        if progress is not None and step % 100 == 0:
            progress(float(trial.progress.state[:, _ROUTE_FRACTION].mean()))
    if progress is not None:
        progress(1.0)
    runs = []
    for i in range(trial.n):
        time_arr, count_arr, pose_arr = recording.series(i, step, dt)
        runs.append(
            Run(
                kind=str(kinds[i]),
                time=time_arr,
                counts=count_arr,
                true_pose=pose_arr,
                direction=directions[i],  # type: ignore[arg-type]
                side=_route_size(routes[i]),
                source=f"sim:{routes[i].name}",
                meta={"robot": specs[i].name, "floor": floor.name, "finished": bool(done[i])},
            )
        )
    return runs, trial.odom_pose.copy()


@dataclass
class RunRequests:
    """Runs to simulate as *one* batch, added one at a time: the parallel per-run lists that
    :func:`simulate_runs` takes, built in one place for every caller that mixes robots,
    routes and calibrations in a batch (the experiments of several labs, the benchmark's and
    the self-calibration env's validations).

    :meth:`add` returns the run's slot: its index in what :meth:`simulate` returns.
    """

    specs: list[RobotSpec] = field(default_factory=list)
    routes: list[Route] = field(default_factory=list)
    calibrations: list[Calibration] = field(default_factory=list)
    streams: list[np.random.Generator] = field(default_factory=list)
    starts: list[FloatArray] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)
    directions: list[str | None] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.specs)

    def add(
        self,
        spec: RobotSpec,
        route: Route,
        calibration: Calibration,
        *,
        stream: np.random.Generator | None = None,
        start: FloatArray | None = None,
        kind: str = "square",
        direction: str | None = None,
    ) -> int:
        """Add one run: ``spec`` drives ``route`` with ``calibration`` in its odometry from
        ``start`` (x, y [m], θ [rad]; the origin if None), its floor noise drawn from
        ``stream`` (runs added without one share the ``rng`` given to :meth:`simulate`)."""
        if (stream is None) != (not self.streams) and self.specs:
            raise ValueError("give every run of a batch its own stream, or none of them")
        self.specs.append(spec)
        self.routes.append(route)
        self.calibrations.append(calibration)
        if stream is not None:
            self.streams.append(stream)
        self.starts.append(np.zeros(3) if start is None else np.asarray(start, dtype=float))
        self.kinds.append(kind)
        self.directions.append(direction)
        return len(self.specs) - 1

    def simulate(
        self,
        floor: FloorSpec,
        *,
        rng: np.random.Generator | None = None,
        cruise_speed: float = 0.2,
        on_timeout: Literal["raise", "keep"] = "keep",
    ) -> tuple[list[Run], FloatArray]:
        """Drive every run (:func:`simulate_runs`); ``rng`` is the one stream of runs added
        without their own. Returns the runs and the odometry end poses, in slot order (an empty
        batch gives no runs)."""
        if not self.specs:
            return [], np.zeros((0, 3))
        return simulate_runs(
            self.specs,
            floor,
            self.routes,
            calibration=self.calibrations,
            rng=self.streams if self.streams else rng,
            cruise_speed=cruise_speed,
            kind=self.kinds,
            direction=self.directions,
            start_poses=np.array(self.starts),
            on_timeout=on_timeout,
        )


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


def drive_arcs(
    robots: RobotSpec | Sequence[RobotSpec],
    floor: FloorSpec,
    plans: Sequence[Sequence[Arc]],
    *,
    calibration: Calibration | Sequence[Calibration] | None = None,
    rng: np.random.Generator | Sequence[np.random.Generator] | None = None,
    cruise_speed: float = 0.2,
    dt: float = 0.05,
    kind: ExperimentKind | str = ExperimentKind.FREE,
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
    ``calibration``) — so a calibration changes the path driven, as on a real robot. Rim
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
    recording = _Recording(count, int(1.5 * nominal_time / dt) + 100)
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
            rims = cruise_speed + np.array([-omega, omega]) * half_base[r]
            rims *= min(1.0, max_speed[r] / float(np.abs(rims).max()))
            command[r] = rims / radius[r]
        world.step(command)
        odometry.update(world.counts, dt)
        travelled += 0.5 * odometry.wheel_speed.sum(axis=1) * dt
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
            if label == ExperimentKind.CIRCULAR and len(plan) == 1 and plan[0].curvature
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


def random_start_poses(
    rng: np.random.Generator, count: int, region: float | None
) -> FloatArray | None:
    """``count`` poses uniform in [−region, region]² [m] × [−π, π) [rad], or None."""
    if region is None:
        return None
    xy = rng.uniform(-region, region, size=(count, 2))
    heading = rng.uniform(-np.pi, np.pi, size=(count, 1))
    return np.hstack([xy, heading])


def _route_size(route: Route) -> float:
    drives = [s.length for s in route.segments if s.kind == "drive"]
    return drives[0] if drives else route.segments[0].length


def measure(runs: Sequence[Run], sensor: SensorAccuracy, rng: np.random.Generator) -> list[Run]:
    """Runs as a ground-truth sensor of the given accuracy sees them: every pose sample gets
    independent Gaussian noise (σ_x = σ_y = ``position_std``, σ_θ = ``heading_std``), except
    the first — the start pose is where the sensor's frame is set up, as in Borenstein & Feng
    1994, §6.3."""
    measured = []
    for run in runs:
        noise = rng.standard_normal(run.true_pose.shape) * np.array(
            [sensor.position_std, sensor.position_std, sensor.heading_std]
        )
        noise[0] = 0.0
        measured.append(
            Run(
                kind=run.kind,
                time=run.time,
                counts=run.counts,
                true_pose=run.true_pose + noise,
                direction=run.direction,
                side=run.side,
                source=run.source,
                meta=dict(run.meta, sensor=(sensor.position_std, sensor.heading_std)),
            )
        )
    return measured


ARC_KINDS = (ExperimentKind.CIRCULAR, ExperimentKind.FREE)
"""The experiment kinds driven as arcs (:func:`drive_arcs`) rather than routes."""


def arc_plans(experiment: Experiment, rng: np.random.Generator) -> list[tuple[Arc, ...]]:
    """One plan of arcs per run of a circular or free ``experiment``: the same circle for every
    run, or a new random path per free run drawn from ``rng``."""
    if experiment.kind is ExperimentKind.CIRCULAR:
        assert experiment.direction is not None
        circle = circle_plan(experiment.size, experiment.direction, experiment.laps)
        return [circle] * experiment.runs
    if experiment.kind is ExperimentKind.FREE:
        return [free_plan(rng, experiment.size) for _ in range(experiment.runs)]
    raise ValueError(f"a {experiment.kind} experiment drives a route, not arcs")


class _ArcRun(NamedTuple):
    """One circular or free run of a :func:`perform_many` request."""

    owner: int
    robot: RobotSpec
    plan: tuple[Arc, ...]
    calibration: Calibration
    stream: np.random.Generator
    start: FloatArray


@dataclass
class _ArcRequests:
    """Circular and free runs of several requests, collected for :func:`drive_arcs`: one batch
    per kind and direction, since those label every run of a batch."""

    groups: dict[tuple[str, Direction | None], list[_ArcRun]] = field(default_factory=dict)

    def add(
        self,
        owner: int,
        robot: RobotSpec,
        experiment: Experiment,
        calibration: Calibration,
        rng: np.random.Generator,
        start_region: float | None,
    ) -> None:
        """Draw the request's paths and start poses from its ``rng``, then one floor-noise
        stream per run (``rng.spawn``), as :func:`perform_many` does for routes."""
        plans = arc_plans(experiment, rng)
        poses = random_start_poses(rng, experiment.runs, start_region)
        group = self.groups.setdefault((str(experiment.kind), experiment.direction), [])
        for k, stream in enumerate(rng.spawn(experiment.runs)):
            start = np.zeros(3) if poses is None else poses[k]
            group.append(_ArcRun(owner, robot, plans[k], calibration, stream, start))

    def simulate(self, floor: FloorSpec, *, cruise_speed: float) -> list[tuple[int, Run]]:
        """Drive every group (a robot that does not stop within the time limit gets its run
        marked unfinished); return ``(owner, run)`` pairs."""
        out: list[tuple[int, Run]] = []
        for (kind, direction), group in self.groups.items():
            runs = drive_arcs(
                [run.robot for run in group],
                floor,
                [run.plan for run in group],
                calibration=[run.calibration for run in group],
                rng=[run.stream for run in group],
                cruise_speed=cruise_speed,
                kind=kind,
                direction=direction,
                start_poses=np.array([run.start for run in group]),
                on_timeout="keep",
            )
            out.extend((request.owner, run) for request, run in zip(group, runs, strict=True))
        return out


def perform_many(
    requests: Sequence[tuple[RobotSpec, Experiment, Calibration, np.random.Generator]],
    floor: FloorSpec,
    *,
    sensor: SensorAccuracy,
    cruise_speed: float = 0.2,
    start_region: float | None = None,
) -> list[list[Run] | RuntimeError]:
    """Perform several robots' experiments, of every kind :meth:`SimLab.perform` drives, as
    one batch of routes (squares, straights, spins: :func:`simulate_runs`) and one of arcs
    (circles, free paths: :func:`drive_arcs`).

    Each request is ``(robot, experiment, calibration, rng)``; its ``rng`` alone draws a free
    experiment's paths (:func:`free_plan`), the start poses (within ±``start_region`` [m], or
    the origin), one floor-noise stream per run (``rng.spawn``) and the sensor noise of
    :func:`measure` — so a robot's runs do not depend on which other robots share the batch.
    Why one batch: a pymunk space of many robots costs little more per step than one robot
    (Python overhead per step dominates).

    Returns, per request, its measured runs, or a ``RuntimeError`` if that robot did not finish
    within the time limit (its batch companions are unaffected). Other errors (an invalid
    calibration) propagate to the caller.
    """
    batch = RunRequests()
    owners: list[int] = []
    arcs = _ArcRequests()
    for index, (robot, experiment, calibration, rng) in enumerate(requests):
        if experiment.kind in ARC_KINDS:
            arcs.add(index, robot, experiment, calibration, rng, start_region)
            continue
        route = experiment_route(experiment)
        poses = random_start_poses(rng, experiment.runs, start_region)
        for k, stream in enumerate(rng.spawn(experiment.runs)):
            batch.add(
                robot,
                route,
                calibration,
                stream=stream,
                start=None if poses is None else poses[k],
                kind=experiment.kind,
                direction=experiment.direction,
            )
            owners.append(index)
    runs, _ = batch.simulate(floor, cruise_speed=cruise_speed)
    grouped: list[list[Run]] = [[] for _ in requests]
    for owner, run in zip(owners, runs, strict=True):
        grouped[owner].append(run)
    for owner, run in arcs.simulate(floor, cruise_speed=cruise_speed):
        grouped[owner].append(run)
    outcome: list[list[Run] | RuntimeError] = []
    for (_, experiment, _, rng), own in zip(requests, grouped, strict=True):
        if all(run.meta["finished"] for run in own):
            outcome.append(measure(own, sensor, rng))
        else:
            outcome.append(
                RuntimeError(
                    f"the robot did not finish its {experiment.kind} runs within the time "
                    "limit (a slippery floor, or a calibration that makes it circle?)"
                )
            )
    return outcome


class SimLab(BookkeepingLab):
    """A simulated lab around a hidden true robot.

    Args:
        robot: the true robot (its nominal parameters are what the calibrator may know; its
            true ones stay hidden inside the simulation).
        floor: the lab's floor.
        sensor: accuracy of the ground-truth measurement shown to calibrators.
        rng: randomness for floor roughness, sensor noise and start poses.
        cruise_speed: the reference driver's leg speed [m/s].
        start_region: if given, every run starts at a uniformly random position in
            [−start_region, start_region]² [m] with a uniformly random heading, so that floor
            features (cables) are met at random, as in a lab where the robot does not start on
            the same spot of floor each time; default: every run starts at the origin.
    """

    def __init__(
        self,
        robot: RobotSpec,
        floor: FloorSpec | None = None,
        *,
        sensor: SensorAccuracy | None = None,
        rng: np.random.Generator | None = None,
        cruise_speed: float = 0.2,
        start_region: float | None = None,
    ) -> None:
        super().__init__(robot)
        self.start_region = start_region
        self.floor = floor if floor is not None else FloorSpec()
        self.sensor = sensor if sensor is not None else SensorAccuracy()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.cruise_speed = cruise_speed

    def perform(self, experiment: Experiment, calibration: Calibration) -> list[Run]:
        """Drive the experiment ``experiment.runs`` times with ``calibration`` in the odometry
        (squares, straight runs and spins by the reference driver; circles and free paths by
        :func:`drive_arcs`, a new random path for every free run)."""
        if experiment.kind in ARC_KINDS:
            runs = self._drive_arcs(experiment, calibration)
        else:
            runs = self._drive_route(experiment, calibration)
        self._book(runs)  # the true path length, before the sensor adds its noise
        return measure(runs, self.sensor, self.rng)

    def _drive_arcs(self, experiment: Experiment, calibration: Calibration) -> list[Run]:
        return drive_arcs(
            self._robot,
            self.floor,
            arc_plans(experiment, self.rng),
            calibration=calibration,
            rng=self.rng,
            cruise_speed=self.cruise_speed,
            kind=experiment.kind,
            direction=experiment.direction,
            start_poses=random_start_poses(self.rng, experiment.runs, self.start_region),
        )

    def _drive_route(self, experiment: Experiment, calibration: Calibration) -> list[Run]:
        runs, _ = simulate_runs(
            self._robot,
            self.floor,
            experiment_route(experiment),
            calibration=calibration,
            rng=self.rng,
            repeats=experiment.runs,
            cruise_speed=self.cruise_speed,
            kind=experiment.kind,
            direction=experiment.direction,
            start_poses=random_start_poses(self.rng, experiment.runs, self.start_region),
        )
        return runs

"""The simulated lab: experiments driven by a hidden true robot and shown through a sensor.

:class:`SimLab` implements the :class:`~odomgym.lab.experiment.Lab` protocol over a hidden true
robot: a calibrator asks for experiments and receives runs whose ground truth went through a
:class:`~odomgym.lab.experiment.SensorAccuracy` (:func:`measure`: noisy like a real sensor),
never the truth itself. :func:`perform_many` performs several robots' experiments as one batch
(the lockstep of :mod:`odomgym.lab.lockstep`). Both drive every experiment kind the same way:
squares, straights and spins as routes (:func:`experiment_route`, driven by
:func:`odomgym.sim.route_runs.simulate_runs`), circles and free paths as arcs
(:func:`arc_plans`, driven by :func:`odomgym.sim.arc_runs.drive_arcs`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from odomgym.floor import FloorSpec, load_floor
from odomgym.lab.experiment import BookkeepingLab, Experiment, ExperimentKind, SensorAccuracy
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Direction, Run
from odomgym.robot import RobotSpec, load_robot
from odomgym.sim.arc_runs import Arc, circle_plan, drive_arcs, free_plan
from odomgym.sim.route_runs import RunRequests, simulate_runs
from odomgym.sim.routes import Route, spin_route, square_route, straight_route

__all__ = [
    "ARC_KINDS",
    "SimLab",
    "arc_plans",
    "experiment_route",
    "measure",
    "perform_many",
    "random_start_poses",
]

FloatArray = NDArray[np.float64]


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


def random_start_poses(
    rng: np.random.Generator, count: int, region: float | None
) -> FloatArray | None:
    """``count`` poses uniform in [−region, region]² [m] × [−π, π) [rad], or None."""
    if region is None:
        return None
    xy = rng.uniform(-region, region, size=(count, 2))
    heading = rng.uniform(-np.pi, np.pi, size=(count, 1))
    return np.hstack([xy, heading])


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
        robot: RobotSpec | str,
        floor: FloorSpec | str | None = None,
        *,
        sensor: SensorAccuracy | None = None,
        rng: np.random.Generator | None = None,
        cruise_speed: float = 0.2,
        start_region: float | None = None,
    ) -> None:
        # A preset name or file as readily as a spec; anything else refused in one line.
        super().__init__(load_robot(robot))
        self.start_region = start_region
        self.floor = load_floor(floor) if floor is not None else FloorSpec()
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

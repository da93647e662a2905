"""The simulated lab: drive robots through routes with the reference driver and record runs.

:func:`simulate_runs` is the workhorse: a batch of robots (one :class:`~odomgym.trial.Trial`)
drives a route with the :class:`~odomgym.drivers.ReferenceDriver` until every robot's odometry
says it is done, and each robot's time series becomes a :class:`~odomgym.runs.Run`. Repetitions
of one experiment are simulated *together* (one pymunk space), which is why a 5 cw + 5 ccw
UMBmark costs about as much as two runs.

:class:`SimLab` implements the :class:`~odomgym.experiments.Lab` protocol over a hidden true
robot: a calibrator asks for experiments and receives runs whose ground truth went through a
:class:`~odomgym.experiments.SensorAccuracy` (noisy like a real sensor), never the truth itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.drivers import ReferenceDriver
from odomgym.experiments import BookkeepingLab, Experiment, SensorAccuracy
from odomgym.floor import FloorSpec
from odomgym.odometry import Calibration
from odomgym.paths import Route, spin_route, square_route, straight_route
from odomgym.robot import RobotSpec
from odomgym.runs import Run
from odomgym.trial import Trial

__all__ = ["SimLab", "experiment_route", "measure", "random_start_poses", "simulate_runs"]

FloatArray = NDArray[np.float64]


def experiment_route(experiment: Experiment) -> Route:
    """The route an experiment drives."""
    if experiment.kind == "square":
        assert experiment.direction is not None
        return square_route(experiment.size, experiment.direction)
    if experiment.kind == "straight":
        return straight_route(experiment.size, experiment.return_trip)
    assert experiment.direction is not None
    return spin_route(experiment.size, experiment.direction)


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
        :func:`odomgym.runs.end_error`). Apply a sensor model (:func:`measure`) before showing
        runs to a calibrator.
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
    capacity = int(2.0 * nominal_time / dt) + 100
    poses = np.empty((capacity, trial.n, 3))
    counts = np.empty((capacity, trial.n, 2), dtype=np.int64)
    # What a tracking system reports: the true pose, or the tracked point of a robot whose
    # ground-truth sensor is offset (effect ``gt_sensor_offset``).
    world = trial.world
    record = world.tracked_pose if world.has_tracked_point else (lambda: trial.true_pose)
    poses[0] = record()
    counts[0] = trial.world.counts
    finished_at = np.full(trial.n, -1, dtype=np.int64)
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
        if step == capacity:  # grow the recording buffers geometrically
            capacity *= 2
            poses = np.concatenate([poses, np.empty_like(poses)])
            counts = np.concatenate([counts, np.empty_like(counts)])
        poses[step] = record()
        counts[step] = trial.world.counts
        if progress is not None and step % 100 == 0:
            progress(float(trial.progress.state[:, 7].mean()))
    if progress is not None:
        progress(1.0)
    time_arr = np.arange(step + 1, dtype=np.float64) * dt
    pose_arr = poses[: step + 1].transpose(1, 0, 2)  # (K, T, 3)
    count_arr = counts[: step + 1].transpose(1, 0, 2)
    runs = []
    for i in range(trial.n):
        end = int(finished_at[i]) + 1
        runs.append(
            Run(
                kind=kinds[i],
                time=time_arr[:end].copy(),
                counts=count_arr[i, :end].copy(),
                true_pose=pose_arr[i, :end].copy(),
                direction=directions[i],  # type: ignore[arg-type]
                side=_route_size(routes[i]),
                source=f"sim:{routes[i].name}",
                meta={"robot": specs[i].name, "floor": floor.name, "finished": bool(done[i])},
            )
        )
    return runs, trial.odom_pose.copy()


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
        """Drive the experiment ``experiment.runs`` times with ``calibration`` in the odometry."""
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
        self._book(runs)  # the true path length, before the sensor adds its noise
        return measure(runs, self.sensor, self.rng)

"""Routes driven in simulation by the reference driver: a batch of robots, one Trial, their runs.

:func:`simulate_runs` is the workhorse: a batch of robots (one :class:`~odomgym.sim.trial.Trial`)
drives a route with the :class:`~odomgym.sim.driver.ReferenceDriver` until every robot's odometry
says it is done, and each robot's time series becomes a :class:`~odomgym.odometry.runs.Run`.
Repetitions of one experiment are simulated *together* (one pymunk space), which is why a 5 cw + 5
ccw UMBmark costs about as much as two runs. :class:`RunRequests` builds such a batch run by
run, for callers that mix robots, routes and calibrations. The runs hold the true poses: a lab
shows them to a calibrator through its sensor (:func:`odomgym.lab.simulated.measure`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.floor import FloorSpec
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec
from odomgym.sim.driver import ReferenceDriver
from odomgym.sim.routes import Route
from odomgym.sim.trial import OBSERVATION_NAMES, Trial

__all__ = ["Recording", "RunRequests", "simulate_runs"]

FloatArray = NDArray[np.float64]

_ROUTE_FRACTION = OBSERVATION_NAMES.index("route_fraction")  # column of the route state


class Recording:
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
    recording = Recording(trial.n, int(2.0 * nominal_time / dt) + 100)
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


def _route_size(route: Route) -> float:
    drives = [s.length for s in route.segments if s.kind == "drive"]
    return drives[0] if drives else route.segments[0].length

"""Many simulated labs stepped together: calibrate a whole robot population at batch speed.

A calibrator is a sequential procedure (perform an experiment, think, perform the next), and
one robot's experiment is a few hundred physics steps of one to ten robots — Python overhead
per step dominates. :func:`run_lockstep` runs one procedure per robot, each in its own thread
with its own :class:`~odomgym.lab.experiment.Lab`; whenever every still-running procedure is
waiting for an experiment, all the requested runs are simulated as *one* batch
(:func:`odomgym.lab.simulated.perform_many`: one pymunk space for the routes, one for the arcs),
and each procedure gets its runs back, whatever kind of experiment it asked for. The
threads pass a baton: exactly one of them runs at any time (the procedures in a fixed order, then
the batch simulation), so the schedule is deterministic and a process never runs more than one
thread's numerical work at once.

Results are independent of the batch composition: each participant's sensor noise, start poses
and floor-roughness streams come from its own Generator, so robot 7's calibration is the same
whether it shares a batch with 9 or 99 others (which is what lets a benchmark split its
population over processes without changing a number).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

from odomgym.floor import FloorSpec
from odomgym.lab.experiment import BookkeepingLab, Experiment, Lab, SensorAccuracy
from odomgym.lab.simulated import perform_many
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = ["Outcome", "run_lockstep"]

T = TypeVar("T")


@dataclass
class Outcome(Generic[T]):
    """What one participant's procedure returned, or the exception it raised."""

    value: T | None = None
    error: BaseException | None = None


class _Participant(BookkeepingLab):
    """The Lab one procedure sees (see :class:`odomgym.lab.experiment.Lab`)."""

    def __init__(self, coordinator: _Coordinator, index: int, robot: RobotSpec) -> None:
        super().__init__(robot)
        self._coordinator = coordinator
        self._index = index

    def perform(self, experiment: Experiment, calibration: Calibration) -> list[Run]:
        return self._book(self._coordinator.request(self._index, experiment, calibration))


class _Coordinator:
    """Baton passing: exactly one thread runs at a time — the coordinator, or one participant
    between two of its experiments. Deterministic, and no oversubscription of the cores."""

    def __init__(
        self,
        robots: Sequence[RobotSpec],
        floor: FloorSpec,
        rngs: Sequence[np.random.Generator],
        sensor: SensorAccuracy,
        cruise_speed: float,
        start_region: float | None,
    ) -> None:
        self.robots = list(robots)
        self.floor = floor
        self.rngs = list(rngs)
        self.sensor = sensor
        self.cruise_speed = cruise_speed
        self.start_region = start_region
        self.turn = [threading.Event() for _ in robots]  # participant i may run
        self.yielded = threading.Event()  # the running participant handed the baton back
        self.pending: dict[int, tuple[Experiment, Calibration]] = {}
        self.results: dict[int, list[Run] | BaseException] = {}
        self.active: set[int] = set()

    def request(self, index: int, experiment: Experiment, calibration: Calibration) -> list[Run]:
        self.pending[index] = (experiment, calibration)
        self._hand_back(index)
        result = self.results.pop(index)
        if isinstance(result, BaseException):
            raise result
        return result

    def finished(self, index: int) -> None:
        self.active.discard(index)
        self.yielded.set()

    def _hand_back(self, index: int) -> None:
        self.turn[index].clear()
        self.yielded.set()
        self.turn[index].wait()

    def _run(self, index: int) -> None:
        """Let participant ``index`` run until it asks for an experiment or finishes."""
        self.yielded.clear()
        self.turn[index].set()
        self.yielded.wait()

    def serve(self) -> None:
        """Alternate: every participant runs to its next request; one batch simulates them."""
        ready = sorted(self.active)
        while True:
            for index in ready:
                self._run(index)
            if not self.pending:
                return
            batch = sorted(self.pending.items())
            self.pending.clear()
            self.results.update(self._simulate(batch))
            ready = [index for index, _ in batch]

    def _simulate(
        self, batch: list[tuple[int, tuple[Experiment, Calibration]]]
    ) -> dict[int, list[Run] | BaseException]:
        requests = [
            (self.robots[index], experiment, calibration, self.rngs[index])
            for index, (experiment, calibration) in batch
        ]
        try:
            results = perform_many(
                requests,
                self.floor,
                sensor=self.sensor,
                cruise_speed=self.cruise_speed,
                start_region=self.start_region,
            )
        except Exception as exc:  # e.g. an invalid calibration: every requester is told
            return {index: exc for index, _ in batch}
        outcome: dict[int, list[Run] | BaseException] = {}
        for (index, _), result in zip(batch, results, strict=True):
            if isinstance(result, RuntimeError):  # only this robot fails, not its companions
                result = RuntimeError(f"robot {index}: {result}")
            outcome[index] = result
        return outcome


def run_lockstep(
    procedure: Callable[[Lab, int], T],
    robots: Sequence[RobotSpec],
    floor: FloorSpec,
    rngs: Sequence[np.random.Generator],
    *,
    sensor: SensorAccuracy | None = None,
    cruise_speed: float = 0.2,
    start_region: float | None = None,
) -> list[Outcome[T]]:
    """Run ``procedure(lab, index)`` for every robot, simulating their experiments together.

    Args:
        procedure: e.g. ``lambda lab, i: calibrator.calibrate(lab)``; called in a worker
            thread per robot with that robot's Lab.
        robots: the hidden true robots (they must share the nominal parameters the reference
            driver uses).
        floor: the floor all robots share (they do not collide).
        rngs: one Generator per robot: its sensor noise, start poses and roughness.
        sensor: the ground-truth sensor's accuracy (default: the sonar calibrator of Borenstein &
            Feng 1994).
        cruise_speed: the reference driver's leg speed [m/s].
        start_region: random start poses within ±start_region [m] (see ``SimLab``).

    Returns:
        One :class:`Outcome` per robot, in order.
    """
    if len(rngs) != len(robots):
        raise ValueError(f"need one Generator per robot ({len(robots)}), got {len(rngs)}")
    coordinator = _Coordinator(
        robots, floor, rngs, sensor or SensorAccuracy(), cruise_speed, start_region
    )
    outcomes: list[Outcome[T]] = [Outcome() for _ in robots]

    def work(index: int) -> None:
        coordinator.turn[index].wait()  # start only when handed the baton
        try:
            outcomes[index].value = procedure(
                _Participant(coordinator, index, robots[index]), index
            )
        except Exception as exc:  # reported per robot, the others carry on
            outcomes[index].error = exc
        finally:
            coordinator.finished(index)

    coordinator.active = set(range(len(robots)))
    threads = [threading.Thread(target=work, args=(i,), daemon=True) for i in range(len(robots))]
    for thread in threads:
        thread.start()
    coordinator.serve()
    for thread in threads:
        thread.join()
    return outcomes

"""Experiments and labs: how a calibrator asks for runs without knowing where they come from.

A calibrator is a *procedure*: it asks a :class:`Lab` to perform :class:`Experiment` s (with the
calibration it wants the robot to use while driving), reads the returned :class:`~odomgym.runs.Run`
records, and decides what to do next — a second compensation round, another phase. A lab is
either the simulator (:class:`SimLab`, which drives the hidden true robot through the physics with
the reference driver) or a recorded session of a real robot (``odomgym.data``), which serves the
runs that were recorded and refuses experiments it does not hold.

A lab also keeps the books: the number of runs and the distance travelled, so a benchmark can
give every calibrator the same budget.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol

from odomgym.odometry import Calibration
from odomgym.robot import RobotSpec
from odomgym.runs import Direction, Run

__all__ = ["BookkeepingLab", "Experiment", "ExperimentKind", "Lab", "SensorAccuracy"]

ExperimentKind = Literal["square", "straight", "spin"]


@dataclass(frozen=True)
class Experiment:
    """What to drive and how often.

    Attributes:
        kind: ``"square"`` (UMBmark square, stop and turn in place at the corners),
            ``"straight"`` (drive ``size`` metres, optionally back), ``"spin"`` (turn in place
            by ``size`` radians).
        direction: ``"cw"``/``"ccw"`` for squares and spins; ``None`` for straight runs.
        runs: how many repetitions.
        size: square side L or straight distance D [m], or spin angle [rad].
        return_trip: straight runs only: drive back to the start as well (Borenstein 1995, §6.1).
    """

    kind: ExperimentKind
    direction: Direction | None = None
    runs: int = 1
    size: float = 4.0
    return_trip: bool = False

    def __post_init__(self) -> None:
        if self.kind not in ("square", "straight", "spin"):
            raise ValueError(f"unknown experiment kind {self.kind!r}")
        if self.kind in ("square", "spin") and self.direction not in ("cw", "ccw"):
            raise ValueError(f"a {self.kind} experiment needs direction 'cw' or 'ccw'")
        if self.runs < 1:
            raise ValueError(f"runs must be >= 1, got {self.runs}")
        if not self.size > 0:
            raise ValueError(f"size must be > 0, got {self.size}")


@dataclass(frozen=True)
class SensorAccuracy:
    """Standard deviations of the ground-truth sensor that measures a run's poses.

    Defaults: the sonar calibrator of Borenstein & Feng 1994, §6.3 (±2 mm in x and y, ±0.4° in
    orientation), read as one standard deviation.
    """

    position_std: float = 0.002  # [m]
    heading_std: float = 0.4 * 3.141592653589793 / 180.0  # [rad]


class Lab(Protocol):
    """Where experiments happen (simulation or a recorded session)."""

    @property
    def robot(self) -> RobotSpec:
        """The robot as its owner knows it: the nominal parameters are what count."""
        ...

    def perform(self, experiment: Experiment, calibration: Calibration) -> list[Run]:
        """Drive ``experiment`` with ``calibration`` in the odometry; return the runs, their
        ground truth as the lab's sensor measured it.

        A lab that cannot perform an experiment (a recorded session that holds no such runs)
        raises ``LookupError``, so calibrators can skip an optional phase uniformly."""
        ...

    @property
    def runs_used(self) -> int:
        """Runs performed so far."""
        ...

    @property
    def distance_used(self) -> float:
        """Distance travelled so far [m]."""
        ...


class BookkeepingLab:
    """Base of labs that drive robots: the robot under test and the books (runs, distance).

    Subclasses call :meth:`_book` with the runs each experiment produced.
    """

    def __init__(self, robot: RobotSpec) -> None:
        self._robot = robot
        self._runs_used = 0
        self._distance_used = 0.0

    @property
    def robot(self) -> RobotSpec:
        """The robot under test (calibrators use only its nominal parameters)."""
        return self._robot

    @property
    def runs_used(self) -> int:
        """Runs performed so far."""
        return self._runs_used

    @property
    def distance_used(self) -> float:
        """Distance travelled so far [m] (the true path length in simulation)."""
        return self._distance_used

    def _book(self, runs: list[Run]) -> list[Run]:
        self._runs_used += len(runs)
        self._distance_used += sum(run.distance for run in runs)
        return runs

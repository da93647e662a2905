"""Experiments and labs: how a calibrator asks for runs without knowing where they come from.

A calibrator is a *procedure*: it asks a :class:`Lab` to perform :class:`Experiment` s (with the
calibration it wants the robot to use while driving), reads the returned
:class:`~odomgym.odometry.runs.Run` records, and decides what to do next — a second compensation
round, another phase. A lab is either the simulator (:class:`SimLab`, which drives the hidden true
robot through the physics with the reference driver) or a recorded session of a real robot
(``odomgym.data``), which serves the runs that were recorded and refuses experiments it does not
hold.

A lab also keeps the books: the number of runs and the distance travelled, so a benchmark can
give every calibrator the same budget.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Protocol, TypeVar

from odomgym.errors import SpecError
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Direction, Run
from odomgym.robot import RobotSpec
from odomgym.sim.routes import check_extent

__all__ = [
    "BookkeepingLab",
    "Experiment",
    "ExperimentKind",
    "Lab",
    "SensorAccuracy",
    "parse_choice",
]

ChoiceT = TypeVar("ChoiceT", bound=StrEnum)


def parse_choice(choices: type[ChoiceT], value: object, *, field: str) -> ChoiceT:
    """``value`` as a member of the string enum ``choices``: a member, or its spelling.

    Why: settings arrive as strings from TOML files and the command line, and as members from
    Python; both must land on the same member, and a misspelling must say which field was wrong
    and what it may be — :class:`~odomgym.errors.SpecError` with ``field``.
    """
    if isinstance(value, choices):
        return value
    if isinstance(value, str):
        try:
            return choices(value)
        except ValueError:
            pass
    allowed = ", ".join(repr(member.value) for member in choices)
    raise SpecError(f"unknown {field} {value!r}; choose one of {allowed}", field=field)


class ExperimentKind(StrEnum):
    """What a run drives. The values are the spellings used in TOML, logs and run records.

    * ``square`` — the UMBmark square: ``size`` = side L [m], stop and turn in place by 90° at
      each corner (Borenstein & Feng 1994, §6.3);
    * ``straight`` — ``size`` = distance D [m], optionally back in reverse (Borenstein 1995,
      §6.1);
    * ``spin`` — turn in place by ``size`` [rad] (Ivanjko et al.'s ±180° spins);
    * ``circular`` — drive ``laps`` laps of a circle of radius ``size`` [m] without stopping
      (as in the circular sessions of the OptiOdom data set, Sousa et al. 2022);
    * ``free`` — any path, ``size`` = its length [m]: a person driving the robot about, or the
      simulator's random stand-in for one (:func:`odomgym.sim.arc_runs.free_plan`).
    """

    SQUARE = "square"
    STRAIGHT = "straight"
    SPIN = "spin"
    CIRCULAR = "circular"
    FREE = "free"

    @property
    def has_direction(self) -> bool:
        """Whether runs of this kind turn one way (``cw``/``ccw``) by design."""
        return self in (ExperimentKind.SQUARE, ExperimentKind.SPIN, ExperimentKind.CIRCULAR)


@dataclass(frozen=True)
class Experiment:
    """What to drive and how often.

    Attributes:
        kind: an :class:`ExperimentKind` (its string spelling, e.g. ``"square"``, is accepted
            and converted).
        direction: ``"cw"``/``"ccw"`` for squares, spins and circles; ``None`` for straight
            and free runs.
        runs: how many repetitions.
        size: square side L, straight distance D, circle radius or free path length [m], or
            spin angle [rad].
        return_trip: straight runs only: drive back to the start as well (Borenstein 1995, §6.1).
        laps: circular runs only: how many times round the circle (may be fractional) [-].
    """

    kind: ExperimentKind
    direction: Direction | None = None
    runs: int = 1
    size: float = 4.0
    return_trip: bool = False
    laps: float = 1.0

    def __post_init__(self) -> None:
        kind = parse_choice(ExperimentKind, self.kind, field="kind")
        object.__setattr__(self, "kind", kind)
        if kind.has_direction and self.direction not in ("cw", "ccw"):
            raise SpecError(
                f"a {kind} experiment needs direction 'cw' or 'ccw', got {self.direction!r}",
                field="direction",
            )
        if not kind.has_direction and self.direction is not None:
            raise SpecError(
                f"a {kind} experiment has no direction, got {self.direction!r}", field="direction"
            )
        if self.runs < 1:
            raise SpecError(f"runs must be >= 1, got {self.runs}", field="runs")
        if not self.size > 0:
            raise SpecError(f"size must be > 0, got {self.size}", field="size")
        if self.return_trip and kind is not ExperimentKind.STRAIGHT:
            raise SpecError(
                f"return_trip applies to straight runs, not {kind} runs", field="return_trip"
            )
        if not self.laps > 0:
            raise SpecError(f"laps must be > 0, got {self.laps}", field="laps")
        if kind is ExperimentKind.SPIN:
            check_extent("size", self.size, self.size, turn=True)
        else:
            length = {
                ExperimentKind.SQUARE: 4.0 * self.size,
                ExperimentKind.STRAIGHT: self.size * (2.0 if self.return_trip else 1.0),
                ExperimentKind.CIRCULAR: 2.0 * math.pi * self.size * self.laps,
            }.get(kind, self.size)
            check_extent("size", self.size, length)


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

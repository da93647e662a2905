"""The interface every calibrator implements.

A calibrator is a procedure that talks to a :class:`odomgym.experiments.Lab`: it performs the
experiments it needs (with the calibration it wants active while driving), measures what a
person would measure, and returns corrected odometry parameters as a
:class:`odomgym.odometry.Calibration`. Because labs serve simulated and recorded runs alike, the
same calibrator object calibrates a simulated robot and a real robot's recorded session.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

from odomgym.experiments import Experiment, Lab
from odomgym.odometry import Calibration
from odomgym.runs import Run

__all__ = [
    "CalibrationResult",
    "Calibrator",
    "SquareCalibrator",
    "check_square_settings",
    "perform",
    "square_experiments",
]


def check_square_settings(side: float, runs_per_direction: int) -> None:
    """Raise ValueError unless the square side [m] is positive and there is at least one run."""
    if not side > 0.0 or runs_per_direction < 1:
        raise ValueError(
            f"need side > 0 and runs_per_direction >= 1, got {side}, {runs_per_direction}"
        )


def square_experiments(side: float, runs_per_direction: int) -> list[Experiment]:
    """The bi-directional square experiment: ``runs_per_direction`` cw, then as many ccw."""
    return [
        Experiment("square", "cw", runs_per_direction, side),
        Experiment("square", "ccw", runs_per_direction, side),
    ]


def perform(
    lab: Lab, experiment: Experiment, calibration: Calibration, *, method: str, hint: str = ""
) -> list[Run]:
    """``lab.perform``, with a ``LookupError`` saying which method needed which runs.

    Recorded labs refuse experiments their session does not hold; the message then names the
    method, the runs it needed and what the lab said (``hint`` adds method-specific advice).
    """
    try:
        return lab.perform(experiment, calibration)
    except LookupError as exc:
        what = f"{experiment.direction or ''} {experiment.kind}".strip()
        raise LookupError(
            f"{method} needs {experiment.runs} {what} runs of size {experiment.size:g} that "
            f"this lab cannot provide{hint}: {exc}"
        ) from exc


@dataclass
class CalibrationResult:
    """What a calibrator found.

    Attributes:
        calibration: the corrected parameters, absolute (relative to the uncalibrated robot).
        estimates: the method's intermediate quantities (α, β [rad], R [m], E_d, E_b, …), named
            as in the method's paper, for reports and tests.
        runs_used: runs the method performed.
        distance_used: distance travelled [m].
        notes: anything a user should know (e.g. "second compensation advised").
    """

    calibration: Calibration
    estimates: dict[str, float] = field(default_factory=dict)
    runs_used: int = 0
    distance_used: float = 0.0
    notes: list[str] = field(default_factory=list)


class Calibrator(ABC):
    """Base class of calibration methods.

    Subclasses set ``name`` (the command-line name), ``reference`` (the paper) and implement
    :meth:`experiments` (what they will ask for, for budgeting and documentation) and
    :meth:`calibrate`.
    """

    name: ClassVar[str]
    reference: ClassVar[str]

    @abstractmethod
    def experiments(self) -> list[Experiment]:
        """The experiments one call of :meth:`calibrate` performs, in order."""

    @abstractmethod
    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        """Run the method in ``lab``, starting from ``initial`` (default: uncalibrated)."""


class SquareCalibrator(Calibrator):
    """Base of methods that need only the bi-directional square experiment.

    Args:
        side: square side L [m] (Borenstein & Feng 1994: 4 m).
        runs_per_direction: squares per direction (Borenstein & Feng 1994: 5).
    """

    def __init__(self, side: float = 4.0, runs_per_direction: int = 5) -> None:
        check_square_settings(side, runs_per_direction)
        self.side = side
        self.runs_per_direction = runs_per_direction

    def experiments(self) -> list[Experiment]:
        """The cw and the ccw squares."""
        return square_experiments(self.side, self.runs_per_direction)

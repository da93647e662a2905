"""A new calibration method is one file: ``register_calibrator`` makes the benchmark, the
validation and the command line offer it, sized by the method's own rules."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, ClassVar

import pytest

from odomgym.baselines import CALIBRATORS, register_calibrator
from odomgym.baselines.base import CalibrationResult, Calibrator, square_experiments
from odomgym.baselines.benchmark import BenchConfig, run_benchmark
from odomgym.baselines.validation import calibrator_for_squares
from odomgym.errors import SpecError
from odomgym.lab.experiment import Experiment, Lab
from odomgym.odometry.calibration import Calibration


@dataclass(frozen=True)
class _LookOptions:
    runs_per_direction: int = 1


class _LookOnly(Calibrator):
    """Drives the squares it is given and changes nothing: the do-nothing reference."""

    name: ClassVar[str] = "look_only"
    reference: ClassVar[str] = "a test method"
    options_type: ClassVar[type[Any]] = _LookOptions
    min_budget: ClassVar[int] = 4

    def __init__(self, runs_per_direction: int = 1) -> None:
        self.options = _LookOptions(runs_per_direction)

    @classmethod
    def budget_options(cls, runs: int) -> dict[str, Any]:
        return {"runs_per_direction": runs // 2}

    @classmethod
    def square_options(cls, side: float, runs_per_direction: int) -> dict[str, Any]:
        del side
        return {"runs_per_direction": runs_per_direction}

    def experiments(self) -> list[Experiment]:
        return square_experiments(4.0, self.options.runs_per_direction)

    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        start = initial or Calibration()
        runs = [run for e in self.experiments() for run in lab.perform(e, start)]
        return CalibrationResult(start, runs_used=len(runs))


@pytest.fixture
def look_only() -> Iterator[type[_LookOnly]]:
    register_calibrator(_LookOnly)
    try:
        yield _LookOnly
    finally:
        CALIBRATORS.pop("look_only", None)


def test_a_registered_method_is_benchmarked_with_its_own_budget_rule(
    look_only: type[_LookOnly],
) -> None:
    config = BenchConfig(
        robots=1, floors=("concrete",), methods=("look_only",), budget=6, oracle=False
    )
    rows = run_benchmark(config, jobs=1)
    assert [row["runs_used"] for row in rows] == [6]  # budget_options: 3 squares each way
    assert (rows[0]["method"], rows[0]["budget"]) == ("look_only", 6)
    assert rows[0]["improvement"] == pytest.approx(1.0)  # it calibrates nothing


def test_a_registered_method_sets_its_own_minimum_budget(look_only: type[_LookOnly]) -> None:
    with pytest.raises(SpecError, match="look_only needs a budget of at least 4 runs"):
        BenchConfig(robots=1, methods=("look_only",), budget=3)


def test_a_registered_method_reads_the_square_settings_its_way(
    look_only: type[_LookOnly],
) -> None:
    calibrator = calibrator_for_squares(look_only, side=2.0, runs_per_direction=3)
    assert calibrator.options == _LookOptions(3)


def test_registering_checks_the_name_and_refuses_a_taken_one() -> None:
    with pytest.raises(ValueError, match="already registered"):

        class Another(_LookOnly):
            name: ClassVar[str] = "umbmark"

        register_calibrator(Another)

    class Nameless(_LookOnly):
        name: ClassVar[str] = "has space"

    with pytest.raises(ValueError, match="letters, digits"):
        register_calibrator(Nameless)
    assert "has space" not in CALIBRATORS

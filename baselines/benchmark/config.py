"""The benchmark's configuration and its random streams: what is compared, on which robots and
floors, and the ``SeedSequence([seed, robot, floor, purpose])`` stream of every draw.

Randomness: robot i on floor f draws everything (its errors, sensor noise, start poses, floor
roughness) from ``SeedSequence([seed, i, f, purpose])``, and every method sees the same streams
for the same robot and floor; so results do not depend on the backend, the number of jobs, the
chunking or the order, and the comparison between methods is paired.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from odomgym.baselines.base import CALIBRATORS, Calibrator
from odomgym.errors import SpecError, refuse_repeats
from odomgym.floor import FloorSpec
from odomgym.lab.population import BENCH_FLOORS, Population, check_bench_floor
from odomgym.odometry.calibration import Calibration
from odomgym.robot import PRESETS, RobotSpec

__all__ = [
    "ORACLE",
    "BenchConfig",
    "bench_floor",
    "bench_stream",
    "calibration_streams",
    "config_record",
    "configure",
    "oracle_calibration",
    "population",
]


def configure(cls: type[Calibrator], runs: int) -> Calibrator:
    """``cls`` set up to use at most ``runs`` runs, by its own rule
    (:meth:`~odomgym.baselines.base.Calibrator.budget_options`)."""
    return cls(**cls.budget_options(runs))


@dataclass(frozen=True)
class BenchConfig:
    """What to benchmark.

    Attributes:
        robots: population size.
        floors: names in :data:`BENCH_FLOORS` (``concrete``, ``rough``, ``cables``).
        methods: calibrator names (:data:`odomgym.baselines.base.CALIBRATORS`).
        budget: runs each calibrator may perform per robot.
        extra_budgets: further budgets to compare (each method then appears once per budget,
            labelled ``method@runs``), e.g. ``(4,)`` to see which methods survive few runs.
        seed: master seed.
        validation_runs: fresh squares per direction used to validate each result.
        population: the error ranges.
        oracle: also validate the robot's *true* parameters as a calibration (the ``oracle``
            row, no runs): the best any method could do, so the validation's own noise floor —
            every method's improvement is also reported as a fraction of the oracle's.
    """

    robots: int = 100
    floors: tuple[str, ...] = ("concrete", "rough", "cables")
    methods: tuple[str, ...] = ()
    budget: int = 16
    extra_budgets: tuple[int, ...] = ()
    seed: int = 0
    validation_runs: int = 5
    population: Population = Population()  # noqa: RUF009  (frozen, so one shared default is safe)
    oracle: bool = True

    def __post_init__(self) -> None:
        for floor in self.floors:
            check_bench_floor(floor)
        if self.population.base not in PRESETS:
            raise SpecError(
                f"unknown population base {self.population.base!r}; presets: {', '.join(PRESETS)}",
                field="population.base",
            )
        if self.oracle and PRESETS[self.population.base].is_skid_steer:
            # The oracle validates the robot's true geometry as its calibration; a skid-steer
            # robot's odometry needs an apparent track that emerges from its contacts instead.
            raise SpecError(
                f"the oracle row needs a robot whose true geometry is its odometry's; "
                f"{self.population.base} is skid-steer, whose apparent track emerges from its "
                "contacts (leave the oracle out: --no-oracle, oracle=False)",
                field="oracle",
            )
        if self.robots < 1:
            raise SpecError(f"robots must be >= 1, got {self.robots}", field="robots")
        if self.validation_runs < 1:
            raise SpecError(
                f"validation_runs must be >= 1, got {self.validation_runs}",
                field="validation_runs",
            )
        refuse_repeats(self.methods, "methods")
        refuse_repeats(self.floors, "floors")
        for method in self.methods:
            least = CALIBRATORS[method].min_budget if method in CALIBRATORS else 2
            if min(self.budgets) < least:
                raise SpecError(
                    f"{method} needs a budget of at least {least} runs, got {min(self.budgets)}",
                    field="budget",
                )
            most = CALIBRATORS[method].max_budget if method in CALIBRATORS else None
            if most is not None and max(self.budgets) > most:
                # Each robot's calibration failed alone, after the other methods had driven
                # the budget's runs.
                raise SpecError(
                    f"{method} takes a budget of at most {most} runs, got {max(self.budgets)}",
                    field="budget",
                )

    @property
    def budgets(self) -> tuple[int, ...]:
        """Every budget compared, the main one first."""
        return (self.budget, *(b for b in self.extra_budgets if b != self.budget))

    def labels(self) -> list[str]:
        """Every row label of the report, in order: the competitors, then ``oracle``."""
        return [label for label, _, _ in self.entries()] + ([ORACLE] if self.oracle else [])

    def entries(self) -> list[tuple[str, str, int]]:
        """``(label, method, budget)`` of every competitor, in report order."""
        several = len(self.budgets) > 1
        return [
            (f"{method}@{budget}" if several else method, method, budget)
            for method in self.methods
            for budget in self.budgets
        ]


ORACLE = "oracle"
"""The label of the row whose calibration is the robot's true parameters."""


def oracle_calibration(robot: RobotSpec) -> Calibration:
    """The calibration that makes the odometry's geometry the robot's true one
    (Borenstein & Feng 1994, Eqs. 6.33–6.35 with the true E_d; E_b and E_s as they are)."""
    return Calibration.from_errors(robot.e_d, robot.e_b, robot.e_s)


def bench_stream(config: BenchConfig, *key: int) -> np.random.Generator:
    """A Generator determined by the master seed and ``key`` alone (robot, floor, purpose)."""
    return np.random.default_rng(np.random.SeedSequence([config.seed, *key]))


def bench_floor(config: BenchConfig, name: str) -> tuple[FloorSpec, float | None, int]:
    """The benchmark floor ``name`` as laid out for ``config``'s seed, the half-width [m] of
    its start region (None: runs start at the origin) and the floor's index in the streams."""
    floor_index = list(BENCH_FLOORS).index(name)
    floor, start_region = BENCH_FLOORS[name].make(bench_stream(config, 0, floor_index, 1))
    return floor, start_region, floor_index


def calibration_streams(
    config: BenchConfig, indices: Sequence[int], floor_index: int
) -> list[np.random.Generator]:
    """The random streams the calibrations of robots ``indices`` draw from on a floor (the
    same for every method: a paired comparison)."""
    return [bench_stream(config, i, floor_index, 2) for i in indices]


def population(config: BenchConfig) -> list[RobotSpec]:
    """The benchmark's robots (robot i depends only on the seed and i)."""
    return [
        config.population.sample(bench_stream(config, i, 0, 0), f"robot-{i:03d}")
        for i in range(config.robots)
    ]


def config_record(config: BenchConfig) -> dict[str, Any]:
    """The configuration as JSON-ready data (results.json, the journal's first line)."""
    return {
        "robots": config.robots,
        "floors": list(config.floors),
        "methods": list(config.methods),
        "budget": config.budget,
        "extra_budgets": list(config.extra_budgets),
        "seed": config.seed,
        "validation_runs": config.validation_runs,
        "oracle": config.oracle,
        "population": [
            config.population.base,
            *config.population.e_d,
            *config.population.e_b,
            *config.population.e_s,
        ],
    }

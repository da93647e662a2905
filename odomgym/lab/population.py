"""What a calibration is judged on: the population of robots and the benchmark floors.

Both the benchmark (:mod:`odomgym.baselines.benchmark`) and the self-calibration env
(:mod:`odomgym.envs.selfcal`) draw their robots from :class:`Population` and take their floors'
settings from :data:`BENCH_FLOORS` (roughness, random starts) and :func:`cable_field` (the
cables), so they live here, below both: an env must not import the benchmark runner to know
what a benchmark robot is. (The env lays one fixed cable field of its own, so that the
benchmark evaluates on cables the agent never trained on.)

Floors (:data:`BENCH_FLOORS`; their names never mean another floor elsewhere in odomgym):

* ``concrete`` — the ``concrete`` preset of :data:`odomgym.floor.FLOORS`, a smooth lab floor
  with roughness k = 0.0004 m^½, which gives the LabMate return-error scatter σ ≈ 25 mm that
  Borenstein & Feng 1994, §6.3, report (the noiseless ``smooth`` preset would make every method
  look 100× better than any real lab allows);
* ``rough`` — the ``rough`` preset, k = 0.002 m^½ (five times rougher);
* ``cables`` — the concrete floor strewn with 10 mm cables (1.5 per m², 0.3 m long, laid out
  once per benchmark seed) and every run started at a random pose, so cables are met at random
  (≈ 0.29 crossings per metre per wheel, about 5 per wheel on a 4×4 m square; Borenstein 1995,
  §6.1, laid 10 cables along 18 m). Unlike the ``bumpy`` preset (one fixed layout under the
  4×4 m squares), no two runs meet the same cables.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from odomgym.errors import SpecError
from odomgym.floor import FLOORS, FloorSpec
from odomgym.robot import PRESETS, RobotSpec

__all__ = [
    "BENCH_FLOORS",
    "CABLES_PER_SQUARE_METRE",
    "CABLES_START_REGION",
    "CABLE_FIELD_HALF_SIZE",
    "BenchFloor",
    "Population",
    "cable_field",
    "check_bench_floor",
]

CABLES_START_REGION = 12.0
"""Half-width [m] of the square area of cable-strewn floor that runs start in (24 × 24 m)."""
CABLE_FIELD_HALF_SIZE = CABLES_START_REGION + 6.0
"""Half-width [m] of the cable field: 6 m beyond the start region, so that a 4×4 m square
started at its edge still runs over cables."""
CABLES_PER_SQUARE_METRE = 1.5
"""Density of the cable field [1/m²] (10 mm cables, 0.3 m long)."""


def cable_field(rng: np.random.Generator, *, roughness: float, name: str) -> FloorSpec:
    """The benchmark's cable field laid out from ``rng``: 10 mm cables at
    :data:`CABLES_PER_SQUARE_METRE` over ±:data:`CABLE_FIELD_HALF_SIZE` [m], on a floor of
    roughness ``roughness`` [m^½]."""
    return FloorSpec.scattered_cables(
        rng,
        half_size=CABLE_FIELD_HALF_SIZE,
        per_square_metre=CABLES_PER_SQUARE_METRE,
        roughness=roughness,
        name=name,
    )


@dataclass(frozen=True)
class BenchFloor:
    """A benchmark floor.

    Attributes:
        description: one line for reports and ``--help``.
        make: the floor, laid out from a generator (a benchmark draws it once per seed), and
            the half-width [m] of the square area runs start in at random poses (``None``:
            every run starts at the origin).
        roughness: the floor's roughness k [m^½] (Chong & Kleeman 1997, Eq. 4).
        cables: whether the floor is a cable field whose runs start at random poses.
    """

    description: str
    make: Callable[[np.random.Generator], tuple[FloorSpec, float | None]]
    roughness: float
    cables: bool = False


def _preset(name: str) -> Callable[[np.random.Generator], tuple[FloorSpec, float | None]]:
    def make(rng: np.random.Generator) -> tuple[FloorSpec, float | None]:
        del rng  # a preset is a fixed fact, not a draw
        return FLOORS[name], None

    return make


def _cables(rng: np.random.Generator) -> tuple[FloorSpec, float | None]:
    floor = cable_field(rng, roughness=FLOORS["concrete"].roughness, name="cables")
    return floor, CABLES_START_REGION


# The order fixes each floor's random streams (its index): keep it, append new floors.
BENCH_FLOORS: dict[str, BenchFloor] = {
    "concrete": BenchFloor(
        "the concrete preset, roughness k = 0.0004 m^0.5",
        _preset("concrete"),
        FLOORS["concrete"].roughness,
    ),
    "rough": BenchFloor(
        "the rough preset, k = 0.002 m^0.5", _preset("rough"), FLOORS["rough"].roughness
    ),
    "cables": BenchFloor(
        "concrete strewn with random 10 mm cables, runs started at random poses",
        _cables,
        FLOORS["concrete"].roughness,
        cables=True,
    ),
}


def check_bench_floor(name: str) -> None:
    """Raise :class:`SpecError` (field ``floor``) unless ``name`` is a benchmark floor."""
    if name in BENCH_FLOORS:
        return
    raise SpecError(
        f"unknown benchmark floor {name!r}; floors: {', '.join(BENCH_FLOORS)}", field="floor"
    )


@dataclass(frozen=True)
class Population:
    """Ranges of the true systematic errors, drawn uniformly and independently [-].

    Defaults: E_d ∈ [0.99, 1.01], E_b ∈ [0.95, 1.05], E_s ∈ [0.98, 1.02] on the LabMate.
    """

    base: str = "labmate"
    e_d: tuple[float, float] = (0.99, 1.01)
    e_b: tuple[float, float] = (0.95, 1.05)
    e_s: tuple[float, float] = (0.98, 1.02)

    def __post_init__(self) -> None:
        """Refuse, in one line naming the field, an unknown base or a range that is not two
        finite, positive factors in order — which surfaced as a ``KeyError`` when an env was
        made, or as numpy's ``high - low < 0`` at its first reset."""
        if not isinstance(self.base, str) or self.base not in PRESETS:
            raise SpecError(
                f"unknown robot preset {self.base!r}; presets: {', '.join(PRESETS)}",
                field="base",
            )
        for field in ("e_d", "e_b", "e_s"):
            bounds = getattr(self, field)
            try:
                low, high = (float(v) for v in bounds)
            except (TypeError, ValueError):
                raise SpecError(
                    f"{field} must be a (low, high) pair of factors, got {bounds!r}", field=field
                ) from None
            if not (np.isfinite(low) and np.isfinite(high) and 0.0 < low <= high):
                raise SpecError(
                    f"{field} must be finite positive factors with low <= high, got {bounds!r}",
                    field=field,
                )
        # Every robot the ranges can draw must be a valid spec (a true track within 0.5–2 ×
        # the nominal, …): checked at the ranges' corners, the extremes of each true value,
        # so that a bad range is refused here, naming its field, not at a later reset
        # naming a derived one (``true_wheelbase``).
        ideal = PRESETS[self.base].ideal()
        names = ("e_d", "e_b", "e_s")
        for corner in itertools.product(*(getattr(self, n) for n in names)):
            try:
                ideal.with_errors(*(float(v) for v in corner))
            except SpecError as exc:
                field = "e_b" if exc.field == "true_wheelbase" else "e_d, e_s"
                drawn = ", ".join(f"{n} = {v:g}" for n, v in zip(names, corner, strict=True))
                raise SpecError(
                    f"{field}: a robot drawn at {drawn} is no valid {self.base}: {exc}",
                    field=field,
                ) from None

    def sample(self, rng: np.random.Generator, name: str) -> RobotSpec:
        """One robot with errors drawn from ``rng``."""
        robot = PRESETS[self.base].ideal()
        errors = [rng.uniform(*bounds) for bounds in (self.e_d, self.e_b, self.e_s)]
        spec = robot.with_errors(*errors)
        return RobotSpec(**{**spec.to_dict(), "name": name})

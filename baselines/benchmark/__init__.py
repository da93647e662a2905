"""The calibrator benchmark: every method, the same robots, floors and budget, fresh validation.

Which calibration method should a user trust, with how many runs, on which floor? The benchmark
samples a population of simulated robots with systematic errors drawn uniformly over
:class:`Population`'s ranges, gives every calibrator the same experiment budget on the same robot
and floor (same random streams), then validates each result on fresh UMBmark squares it has not
seen (5 cw + 5 ccw, 4×4 m, true return errors; E_max,syst of Borenstein & Feng 1994, Eq. 3.3).

Floors are :data:`odomgym.lab.population.BENCH_FLOORS` (``concrete``, ``rough``, ``cables``) and the
robots are drawn from :class:`odomgym.lab.population.Population`: the self-calibration env draws
from the same ones, so they live in the core below both.

The package's modules: :mod:`~odomgym.baselines.benchmark.config` (what is compared, the
random streams), :mod:`~odomgym.baselines.benchmark.chunk` (a chunk of robots calibrated and
validated, its rows), :mod:`~odomgym.baselines.benchmark.journal` (the resume journal),
:mod:`~odomgym.baselines.benchmark.runner` (the local and Ray backends, ``run_benchmark``) and
:mod:`~odomgym.baselines.benchmark.summary` (the rows per method and floor). Their public names
are importable from here.
"""

from odomgym.baselines.benchmark.chunk import (
    failed_rows,
    oracle_fractions,
    run_chunk,
    validate_calibrations,
)
from odomgym.baselines.benchmark.config import (
    ORACLE,
    BenchConfig,
    bench_floor,
    calibration_streams,
    config_record,
    configure,
    oracle_calibration,
    population,
)
from odomgym.baselines.benchmark.journal import Journal
from odomgym.baselines.benchmark.runner import Backend, ChunkTask, run_benchmark
from odomgym.baselines.benchmark.summary import summarize

__all__ = [
    "ORACLE",
    "Backend",
    "BenchConfig",
    "ChunkTask",
    "Journal",
    "bench_floor",
    "calibration_streams",
    "config_record",
    "configure",
    "failed_rows",
    "oracle_calibration",
    "oracle_fractions",
    "population",
    "run_benchmark",
    "run_chunk",
    "summarize",
    "validate_calibrations",
]

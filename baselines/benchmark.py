"""The calibrator benchmark: every method, the same robots, floors and budget, fresh validation.

Which calibration method should a user trust, with how many runs, on which floor? The benchmark
samples a population of simulated robots with systematic errors drawn uniformly over
:class:`Population`'s ranges, gives every calibrator the same experiment budget on the same robot
and floor (same random streams), then validates each result on fresh UMBmark squares it has not
seen (5 cw + 5 ccw, 4×4 m, true return errors; E_max,syst of Borenstein & Feng 1994, Eq. 3.3).

Floors are :data:`odomgym.lab.population.BENCH_FLOORS` (``concrete``, ``rough``, ``cables``) and the
robots are drawn from :class:`odomgym.lab.population.Population`: the self-calibration env draws
from the same ones, so they live in the core below both.

Randomness: robot i on floor f draws everything (its errors, sensor noise, start poses, floor
roughness) from ``SeedSequence([seed, i, f, purpose])``, and every method sees the same streams
for the same robot and floor; so results do not depend on the backend, the number of jobs, the
chunking or the order, and the comparison between methods is paired.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import json
import math
import os
import signal
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym import interrupt
from odomgym.baselines.base import CALIBRATORS, CalibrationResult, Calibrator
from odomgym.baselines.validation import ValidationSquare, square_errors
from odomgym.errors import SpecError
from odomgym.floor import FloorSpec
from odomgym.lab.experiment import Lab, parse_choice
from odomgym.lab.lockstep import run_lockstep
from odomgym.lab.population import BENCH_FLOORS, Population, check_bench_floor
from odomgym.lab.simulated import random_start_poses
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Direction
from odomgym.odometry.umbmark_measures import e_max_syst
from odomgym.robot import RobotSpec
from odomgym.workers import TaskFailed, WorkerDeath, run_tasks

__all__ = [
    "ORACLE",
    "Backend",
    "BenchConfig",
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

FloatArray = NDArray[np.float64]


class Backend(StrEnum):
    """Where the benchmark's chunks of robots run.

    * ``local`` — this machine: ``jobs`` worker processes (1: this process);
    * ``ray`` — Ray tasks (``pip install 'odomgym[distributed]'``), on a cluster if
      ``ray.init`` was called, else on a local Ray with ``jobs`` CPUs.
    """

    LOCAL = "local"
    RAY = "ray"

    def check_available(self) -> None:
        """Raise :class:`SpecError` (field ``backend``) if this backend cannot run here; cheap
        enough to call before any work."""
        if self is Backend.RAY and importlib.util.find_spec("ray") is None:
            raise SpecError(
                "--backend ray needs Ray, which is not installed: "
                "pip install 'odomgym[distributed]'",
                field="backend",
            )


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
        if self.robots < 1:
            raise SpecError(f"robots must be >= 1, got {self.robots}", field="robots")
        if self.validation_runs < 1:
            raise SpecError(
                f"validation_runs must be >= 1, got {self.validation_runs}",
                field="validation_runs",
            )
        for method in self.methods:
            least = CALIBRATORS[method].min_budget if method in CALIBRATORS else 2
            if min(self.budgets) < least:
                raise SpecError(
                    f"{method} needs a budget of at least {least} runs, got {min(self.budgets)}",
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


def _stream(config: BenchConfig, *key: int) -> np.random.Generator:
    """A Generator determined by the master seed and ``key`` alone (robot, floor, purpose)."""
    return np.random.default_rng(np.random.SeedSequence([config.seed, *key]))


def bench_floor(config: BenchConfig, name: str) -> tuple[FloorSpec, float | None, int]:
    """The benchmark floor ``name`` as laid out for ``config``'s seed, the half-width [m] of
    its start region (None: runs start at the origin) and the floor's index in the streams."""
    floor_index = list(BENCH_FLOORS).index(name)
    floor, start_region = BENCH_FLOORS[name].make(_stream(config, 0, floor_index, 1))
    return floor, start_region, floor_index


def calibration_streams(
    config: BenchConfig, indices: Sequence[int], floor_index: int
) -> list[np.random.Generator]:
    """The random streams the calibrations of robots ``indices`` draw from on a floor (the
    same for every method: a paired comparison)."""
    return [_stream(config, i, floor_index, 2) for i in indices]


def population(config: BenchConfig) -> list[RobotSpec]:
    """The benchmark's robots (robot i depends only on the seed and i)."""
    return [
        config.population.sample(_stream(config, i, 0, 0), f"robot-{i:03d}")
        for i in range(config.robots)
    ]


def run_chunk(config: BenchConfig, indices: Sequence[int]) -> list[dict[str, Any]]:
    """Calibrate robots ``indices`` with every method on every floor and validate them.

    All robots of the chunk run in lockstep (:func:`odomgym.lab.lockstep.run_lockstep`): one
    method at a time, their experiments simulated as one batch.
    """
    robots_all = population(config)
    robots = [robots_all[i] for i in indices]
    rows: list[dict[str, Any]] = []
    for f, floor_name in enumerate(config.floors):
        floor, start_region, floor_index = bench_floor(config, floor_name)
        calibrations: list[list[Calibration]] = [[] for _ in robots]
        method_rows: list[list[dict[str, Any]]] = [[] for _ in robots]
        for label, method, budget in config.entries():
            cls = CALIBRATORS[method]
            start = time.perf_counter()

            def procedure(
                lab: Lab, _index: int, cls: type[Calibrator] = cls, budget: int = budget
            ) -> CalibrationResult:
                return configure(cls, budget).calibrate(lab)

            outcomes = run_lockstep(
                procedure,
                robots,
                floor,
                calibration_streams(config, indices, floor_index),
                start_region=start_region,
            )
            wall = (time.perf_counter() - start) / len(robots)
            for k, (robot, outcome) in enumerate(zip(robots, outcomes, strict=True)):
                result = outcome.value
                calibration = result.calibration if result is not None else Calibration()
                calibrations[k].append(calibration)
                method_rows[k].append(
                    _row(label, budget, floor_name, indices[k], robot, calibration, result, wall)
                )
                if outcome.error is not None:
                    method_rows[k][-1]["failed"] = repr(outcome.error)
        if config.oracle:
            for k, robot in enumerate(robots):
                truth = oracle_calibration(robot)
                calibrations[k].append(truth)
                method_rows[k].append(_row(ORACLE, 0, floor_name, indices[k], robot, truth, None))
        errors = validate_calibrations(
            config, floor, start_region, floor_index, indices, robots, calibrations
        )
        for k in range(len(robots)):
            before = errors[k][0]
            e_before = e_max_syst(before["cw"], before["ccw"])
            for row, after in zip(method_rows[k], errors[k][1:], strict=True):
                e_after = e_max_syst(after["cw"], after["ccw"])
                row["e_max_before_mm"] = 1e3 * e_before
                row["e_max_after_mm"] = 1e3 * e_after
                row["improvement"] = e_before / e_after if e_after > 0 else math.inf
                if not math.isfinite(e_after) and not row["failed"]:
                    row["failed"] = "validation squares did not finish with this calibration"
                for name in ("E_d", "E_b", "E_s"):
                    row[f"err_{name}"] = row[f"est_{name}"] - row[f"true_{name}"]
                if indices[k] == 0 and f == 0:
                    row["scatter"] = {
                        "before": {d: v.tolist() for d, v in before.items()},
                        "after": {d: v.tolist() for d, v in after.items()},
                    }
            rows.extend(method_rows[k])
    return rows


def _row(
    label: str,
    budget: int,
    floor: str,
    index: int,
    robot: RobotSpec,
    calibration: Calibration | None,
    result: CalibrationResult | None,
    wall: float = 0.0,
) -> dict[str, Any]:
    """One result row before validation: the truth, the estimate (NaN without a
    ``calibration``), what it cost. The one layout of a row, failed or not."""
    if calibration is None:
        estimate = (math.nan, math.nan, math.nan)
    else:
        estimate = (calibration.e_d, calibration.wheelbase_scale, calibration.distance_scale)
    return {
        "method": label,
        "budget": budget,
        "floor": floor,
        "robot": index,
        "true_E_d": robot.e_d,
        "true_E_b": robot.e_b,
        "true_E_s": robot.e_s,
        "est_E_d": estimate[0],
        "est_E_b": estimate[1],
        "est_E_s": estimate[2],
        "runs_used": result.runs_used if result is not None else 0,
        "distance_m": result.distance_used if result is not None else 0.0,
        "wall_time_s": wall,
        "failed": "",
    }


def oracle_fractions(
    errors: Sequence[Sequence[Mapping[str, FloatArray]]], oracle: int, method: int
) -> list[float]:
    """Per robot, the *of oracle* figure of calibration ``method``: the oracle's E_max,syst
    (Borenstein & Feng 1994, Eq. 3.3) over the method's on the same validation squares, from
    :func:`validate_calibrations`'s ``errors`` (indices as there: 0 is uncalibrated)."""
    return [
        e_max_syst(e[oracle]["cw"], e[oracle]["ccw"])
        / e_max_syst(e[method]["cw"], e[method]["ccw"])
        for e in errors
    ]


def validate_calibrations(
    config: BenchConfig,
    floor: FloorSpec,
    start_region: float | None,
    floor_index: int,
    indices: Sequence[int],
    robots: Sequence[RobotSpec],
    calibrations: Sequence[Sequence[Calibration]],
) -> list[list[dict[str, FloatArray]]]:
    """Fresh squares for every robot, uncalibrated and with each method's calibration, from
    the same start poses; all robots and calibrations simulated together per direction.

    Returns ``errors[k][c][direction]`` (runs, 3) for robot k and calibration c (0: none).

    Public so that studies beside the benchmark (``benchmarks/bench_selfcal.py``'s error
    budget, ``benchmarks/design_bound.py``'s schedules) validate their calibrations on exactly
    the benchmark's squares and floor noise, paired with its rows.
    """
    runs = config.validation_runs
    out: list[list[dict[str, FloatArray]]] = [
        [{} for _ in range(len(calibrations[k]) + 1)] for k in range(len(robots))
    ]
    directions: tuple[Direction, Direction] = ("cw", "ccw")
    for d, direction in enumerate(directions):
        squares: list[ValidationSquare] = []
        slots: list[tuple[int, int]] = []
        for k, (i, robot) in enumerate(zip(indices, robots, strict=True)):
            rng = _stream(config, i, floor_index, 3 + d)
            poses = random_start_poses(rng, runs, start_region)
            for c, calibration in enumerate([Calibration(), *calibrations[k]]):
                # The same floor noise for every calibration of this robot: a paired comparison.
                seeds = np.random.SeedSequence([config.seed, i, floor_index, 5 + d]).spawn(runs)
                for r, seed in enumerate(seeds):
                    squares.append(
                        ValidationSquare(
                            robot,
                            calibration,
                            start=None if poses is None else poses[r],
                            stream=np.random.default_rng(seed),
                        )
                    )
                    slots.append((k, c))
        # A calibration so wrong that the robot cannot finish a square gets NaN errors (and so
        # a NaN E_max,syst): it is reported as failed, not allowed to stop the benchmark.
        errors = square_errors(squares, floor, direction)
        for (k, c), start_row in zip(slots[::runs], range(0, len(slots), runs), strict=True):
            out[k][c][direction] = errors[start_row : start_row + runs]
    return out


class Journal:
    """Each finished chunk of robots, recorded as it completes (JSON lines), so an interrupted
    benchmark can resume where it stopped.

    Line 1 is the configuration (a resume under another configuration is refused), every further
    line one finished chunk: ``{"robots": [...], "rows": [...]}``, appended, flushed and synced
    before the next is started. A last line cut short by the interruption is ignored.
    """

    VERSION = 1

    def __init__(self, path: Path, config: BenchConfig) -> None:
        self.path = Path(path)
        self.config = config

    def _header(self) -> dict[str, Any]:
        return {"journal": self.VERSION, "config": config_record(self.config)}

    def start(self) -> None:
        """Begin a new journal (replacing any earlier one)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._write(json.dumps(self._header()) + "\n", "w")

    def read(self) -> dict[int, list[dict[str, Any]]]:
        """The recorded rows per robot (empty if there is no journal yet)."""
        if not self.path.exists():
            return {}
        lines = self.path.read_text(encoding="utf-8").splitlines()
        if not lines:
            return {}
        try:
            header = json.loads(lines[0])
        except json.JSONDecodeError as exc:
            raise SpecError(
                f"{self.path}:1: not a benchmark journal ({exc})", field="resume"
            ) from None
        if header != self._header():
            raise SpecError(
                f"{self.path}:1: recorded for another benchmark configuration "
                f"({header.get('config') if isinstance(header, dict) else header}); run "
                "without --resume to start over",
                field="resume",
            )
        done: dict[int, list[dict[str, Any]]] = {}
        for number, line in enumerate(lines[1:], start=2):
            try:
                entry = json.loads(line)
                robots, rows = list(entry["robots"]), list(entry["rows"])
            except (json.JSONDecodeError, KeyError, TypeError) as exc:
                if number == len(lines):  # cut short by the interruption: run it again
                    break
                raise SpecError(
                    f"{self.path}:{number}: damaged entry ({exc})", field="resume"
                ) from None
            for robot in robots:
                done[int(robot)] = [r for r in rows if r["robot"] == robot]
        return done

    def record(self, robots: Sequence[int], rows: Sequence[dict[str, Any]]) -> None:
        """Append one finished chunk."""
        self._write(json.dumps({"robots": list(robots), "rows": list(rows)}) + "\n", "a")

    def _write(self, line: str, mode: str) -> None:
        """Write ``line`` to the disk now; if that fails (a full disk), cut the journal back to
        its whole lines and name it in the error."""
        size = self.path.stat().st_size if mode == "a" and self.path.exists() else 0
        try:
            with self.path.open(mode, encoding="utf-8") as f:
                f.write(line)
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.truncate(self.path, size)
            raise OSError(exc.errno, exc.strerror or str(exc), str(self.path)) from exc


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


def failed_rows(config: BenchConfig, robots: Sequence[int], reason: str) -> list[dict[str, Any]]:
    """Rows for robots whose worker died twice: every entry marked failed with ``reason``,
    its numbers NaN, so the tables count them as failures and the run still finishes."""
    nan = math.nan
    truth = population(config)
    out = []
    competitors = [(label, budget) for label, _, budget in config.entries()]
    if config.oracle:
        competitors.append((ORACLE, 0))
    for floor in config.floors:
        for robot in robots:
            for label, budget in competitors:
                row = _row(label, budget, floor, robot, truth[robot], None, None)
                row.update(failed=reason, e_max_before_mm=nan, e_max_after_mm=nan, improvement=nan)
                row.update({f"err_{name}": nan for name in ("E_d", "E_b", "E_s")})
                out.append(row)
    return out


def _chunk_task(config: BenchConfig, part: list[int], attempt: int) -> list[dict[str, Any]]:
    """The benchmark's task for :func:`odomgym.workers.run_tasks`: one chunk of robots (the
    attempt does not matter; every attempt computes the same rows)."""
    del attempt
    return run_chunk(config, part)


ChunkTask = Callable[[BenchConfig, list[int], int], list[dict[str, Any]]]
"""What a worker runs for a chunk: ``task(config, robots, attempt) -> rows``."""


def _run_processes(
    config: BenchConfig,
    parts: list[list[int]],
    jobs: int,
    finished: Callable[[list[int], list[dict[str, Any]]], None],
    notify: Callable[[str], None],
    task: ChunkTask = _chunk_task,
) -> None:
    """Run the chunks in at most ``jobs`` worker processes (:mod:`odomgym.workers`), each
    serving chunk after chunk. A worker that dies (killed, out of memory) is reported,
    replaced, and its chunk retried once; if it dies again, its robots are recorded as failed.
    Whatever ends this function early (an error, Ctrl-C, SIGTERM) terminates every worker
    before it returns."""

    def died(death: WorkerDeath[int]) -> bool:
        part = parts[death.key]
        if death.attempt == 0:
            notify(
                f"worker for robots {part[0]}-{part[-1]} died (exit code {death.exitcode}); "
                "retrying once"
            )
            return True
        reason = f"worker died twice (exit code {death.exitcode})"
        notify(f"worker for robots {part[0]}-{part[-1]} died again; marked failed")
        finished(part, failed_rows(config, part, reason))
        return False

    try:
        run_tasks(
            functools.partial(task, config),
            enumerate(parts),
            processes=jobs,
            finished=lambda k, rows: finished(parts[k], rows),
            died=died,
        )
    except TaskFailed as exc:
        part = parts[exc.key]
        raise RuntimeError(f"benchmark worker for robots {part} failed: {exc.message}") from None


def run_benchmark(
    config: BenchConfig,
    *,
    jobs: int = 1,
    backend: Backend | str = Backend.LOCAL,
    progress: Callable[[int, int], None] | None = None,
    journal: Path | str | None = None,
    resume: bool = False,
    chunk: int | None = None,
    notify: Callable[[str], None] | None = None,
    task: ChunkTask = _chunk_task,
) -> list[dict[str, Any]]:
    """Run the benchmark; rows do not depend on ``jobs``, ``backend``, ``chunk`` or on being
    interrupted and resumed.

    ``backend`` (a :class:`Backend` or its spelling): ``local`` uses ``jobs`` worker processes
    (1: this process); ``ray`` submits the chunks as Ray tasks (``ray.init`` must have been
    called, or a local Ray is started with ``jobs`` CPUs). An unknown or unavailable backend
    raises :class:`SpecError` (field ``backend``) before any work.

    ``journal``: record every finished chunk there (:class:`Journal`); with ``resume``, the
    robots it holds are not run again. ``chunk``: robots per unit of work (default: as many as
    spread the robots over the jobs, at most 16, so a long run records progress often; larger
    chunks batch more robots together). ``notify`` receives one-line reports (a worker died).
    ``task`` is what a local worker process runs per chunk (tests give one that fails, to
    check the recovery; it must be picklable by reference).
    """
    backend = parse_choice(Backend, backend, field="backend")
    backend.check_available()
    book = Journal(Path(journal), config) if journal is not None else None
    done = book.read() if book is not None and resume else {}
    if book is not None and not done:
        book.start()
    todo = [i for i in range(config.robots) if i not in done]
    size = chunk or min(16, max(1, math.ceil(len(todo) / max(1, jobs))))
    parts = [todo[k : k + size] for k in range(0, len(todo), size)]
    rows: list[dict[str, Any]] = [row for robot in sorted(done) for row in done[robot]]
    count = len(done)

    def finished(part: list[int], part_rows: list[dict[str, Any]]) -> None:
        nonlocal count
        if book is not None:
            book.record(part, part_rows)
        interrupt.check()  # a stop request a finalizer swallowed: recorded, now stop
        rows.extend(part_rows)
        count += len(part)
        if progress is not None:
            progress(count, config.robots)

    if progress is not None and count:
        progress(count, config.robots)
    if backend is Backend.RAY:
        _run_ray(config, parts, jobs, finished)
    elif jobs <= 1 or len(parts) <= 1:
        for part in parts:
            finished(part, run_chunk(config, part))
    else:
        _run_processes(config, parts, jobs, finished, notify or (lambda text: None), task)
    order = config.labels()
    rows.sort(key=lambda r: (config.floors.index(r["floor"]), r["robot"], order.index(r["method"])))
    return rows


def _run_ray(
    config: BenchConfig,
    parts: list[list[int]],
    jobs: int,
    finished: Callable[[list[int], list[dict[str, Any]]], None],
) -> None:
    import ray  # Backend.RAY.check_available() has looked for it

    started = not ray.is_initialized()
    if started:
        # ray.init replaces the SIGTERM handler with one that calls sys.exit, and Ray's C++
        # core installs absl's failure-signal handler, which prints a stack dump for a plain
        # SIGTERM. Keep the caller's handler (the command line's: stop cleanly, exit 143) and
        # no dump; Ray's own processes still end with the driver (ray.shutdown at exit).
        previous = signal.getsignal(signal.SIGTERM)
        os.environ.setdefault("RAY_DISABLE_FAILURE_SIGNAL_HANDLER", "1")
        ray.init(num_cpus=max(1, jobs), include_dashboard=False, log_to_driver=False)
        if callable(previous) and signal.getsignal(signal.SIGTERM) is not previous:
            signal.signal(signal.SIGTERM, previous)
    remote = ray.remote(num_cpus=1, max_retries=1)(run_chunk)  # a dead worker: retried once
    pending = {remote.remote(config, part): part for part in parts}
    try:
        while pending:
            try:
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
            except SystemError:
                # A stop request raised by the signal handler inside Ray's compiled wait comes
                # back wrapped ("returned a result with an exception set"): stop as asked.
                interrupt.check()
                raise
            interrupt.check()
            for ref in ready:
                finished(pending.pop(ref), ray.get(ref))
    finally:
        if pending and started:
            # Interrupted on the local Ray this call started: shutting it down stops every
            # worker now (force-cancelling first made Ray's task manager abort at exit).
            ray.shutdown()
        elif pending:  # on the caller's cluster: stop this benchmark's tasks, nothing else
            for ref in pending:
                ray.cancel(ref, force=True)


def summarize(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per method and floor: median and quartiles of the improvement, parameter errors,
    distance, wall time and failures; and, when the rows hold the ``oracle``, the fraction of
    the oracle's improvement (per robot: the oracle's E_max,syst after / the method's, the
    same robot's E_max,syst before cancelling; its median; NaN without an oracle)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    ceiling: dict[tuple[str, int], float] = {}
    for row in rows:
        groups.setdefault((row["method"], row["floor"]), []).append(row)
        if row["method"] == ORACLE and not row["failed"]:
            ceiling[(row["floor"], row["robot"])] = row["improvement"]
    summary: list[dict[str, Any]] = []
    for (method, floor), all_rows in groups.items():
        # Failed calibrations are counted, not scored: scoring them as "uncalibrated" would
        # pull the medians toward 1 and hide how often a method fails.
        group = [r for r in all_rows if not r["failed"]] or all_rows
        improvement = np.array([r["improvement"] for r in group])
        q25, q50, q75 = np.percentile(improvement, [25, 50, 75])

        def median_abs(key: str, group: list[dict[str, Any]] = group) -> float:
            return float(np.median([abs(r[key]) for r in group]))

        fractions = [
            r["improvement"] / ceiling[(floor, r["robot"])]
            for r in group
            if (floor, r["robot"]) in ceiling and not r["failed"]
        ]

        summary.append(
            {
                "method": method,
                "floor": floor,
                "robots": len(group),
                "improvement_median": float(q50),
                "improvement_q25": float(q25),
                "improvement_q75": float(q75),
                "of_oracle_median": float(np.median(fractions)) if fractions else math.nan,
                "e_max_before_median_mm": float(np.median([r["e_max_before_mm"] for r in group])),
                "e_max_after_median_mm": float(np.median([r["e_max_after_mm"] for r in group])),
                "abs_err_E_d_median": median_abs("err_E_d"),
                "abs_err_E_b_median": median_abs("err_E_b"),
                "abs_err_E_s_median": median_abs("err_E_s"),
                "distance_m_mean": float(np.mean([r["distance_m"] for r in group])),
                "runs_mean": float(np.mean([r["runs_used"] for r in group])),
                "wall_time_s_mean": float(np.mean([r["wall_time_s"] for r in group])),
                "failures": sum(1 for r in all_rows if r["failed"]),
            }
        )
    summary.sort(key=lambda s: (str(s["floor"]), -float(s["improvement_median"])))
    return summary

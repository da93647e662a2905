"""Running the benchmark: its chunks on worker processes of this machine or as Ray tasks, each
finished chunk journalled, the rows in one order whatever ran them.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from odomgym import interrupt
from odomgym.baselines.benchmark.chunk import failed_rows, run_chunk
from odomgym.baselines.benchmark.config import BenchConfig
from odomgym.baselines.benchmark.journal import Journal
from odomgym.distributed import Backend, ray_session, run_ray_tasks
from odomgym.lab.experiment import parse_choice
from odomgym.workers import TaskFailed, WorkerDeath, run_tasks

__all__ = [
    "Backend",
    "ChunkTask",
    "run_benchmark",
]


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
    address: str | None = None,
) -> list[dict[str, Any]]:
    """Run the benchmark; rows do not depend on ``jobs``, ``backend``, ``chunk`` or on being
    interrupted and resumed.

    ``backend`` (a :class:`Backend` or its spelling): ``local`` uses ``jobs`` worker processes
    (1: this process); ``ray`` submits the chunks as Ray tasks: on the Ray this process
    initialised, else the cluster at ``address`` or ``RAY_ADDRESS``, else a local Ray of
    ``jobs`` CPUs started for the run (:mod:`odomgym.distributed`). An unknown or unavailable
    backend raises :class:`SpecError` (field ``backend``) before any work.

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
        _run_ray(config, parts, jobs, finished, address)
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
    address: str | None,
) -> None:
    """The chunks as Ray tasks (:mod:`odomgym.distributed`: the cluster at ``address`` or
    ``RAY_ADDRESS``, else a local Ray of ``jobs`` CPUs); a dead worker's chunk is retried once
    by Ray."""
    with ray_session(address, jobs) as started:
        run_ray_tasks(
            run_chunk,
            ((k, (config, part)) for k, part in enumerate(parts)),
            lambda k, rows: finished(parts[k], rows),
            started=started,
        )

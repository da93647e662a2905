"""Running the benchmark: its chunks on worker processes of this machine or as Ray tasks, each
finished chunk journalled, the rows in one order whatever ran them.
"""

from __future__ import annotations

import functools
import importlib.util
import math
import os
import signal
from collections.abc import Callable
from enum import StrEnum
from pathlib import Path
from typing import Any

from odomgym import interrupt
from odomgym.baselines.benchmark.chunk import failed_rows, run_chunk
from odomgym.baselines.benchmark.config import BenchConfig
from odomgym.baselines.benchmark.journal import Journal
from odomgym.errors import SpecError
from odomgym.lab.experiment import parse_choice
from odomgym.workers import TaskFailed, WorkerDeath, run_tasks

__all__ = [
    "Backend",
    "ChunkTask",
    "run_benchmark",
]


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

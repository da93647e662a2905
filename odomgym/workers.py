"""One worker pool for odomgym: processes that serve requests through pipes.

Three parts of odomgym spread work over processes — the benchmark (chunks of robots), the
``diagnose`` candidate fits and the self-calibration training (shards of sessions that keep
their state between steps). They share this module, so they share its behaviour:

* a worker is started with Ctrl-C/SIGTERM deferred (interrupted half-way, it would be left
  half-started and unknown to the clean-up) and serves request after request, so its start-up
  (imports, the compiled kernels: ~2 s) is paid once; a task worker ignores SIGINT (the parent
  stops its workers; a terminal's Ctrl-C reaches the whole process group);
* whatever ends the parent's work early — an error, Ctrl-C, SIGTERM, a callback raising —
  terminates every worker (then kills it if it lingers) before the exception propagates;
* a worker that dies (killed, out of memory) shows as end-of-file on its pipe: the caller is
  told which request it held, with the exit code, and decides whether to retry it;
* an exception inside a request is not a death: its text travels back and is raised in the
  parent as :class:`TaskFailed`.

:func:`run_tasks` hands independent requests to a pool of workers, as they become idle;
:class:`Shards` keeps one worker per shard of a stateful object and sends each the same command.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any, Generic, TypeVar

from odomgym import interrupt

__all__ = ["Shards", "TaskFailed", "WorkerDeath", "run_tasks"]

K = TypeVar("K")
P = TypeVar("P")
R = TypeVar("R")

Handler = Callable[[Any, int], Any]
"""A task handler: ``handler(payload, attempt) -> result`` (attempt 0 first, then 1, … after
the worker holding it died). It must be picklable by reference under ``spawn`` (a module-level
function, or a :func:`functools.partial` of one)."""


class TaskFailed(RuntimeError):
    """A request raised inside its worker; ``key`` names the request and ``message`` the
    worker's exception (type and text)."""

    def __init__(self, key: object, message: str) -> None:
        super().__init__(f"worker task {key!r} failed: {message}")
        self.key: Any = key
        self.message = message


@dataclass(frozen=True)
class WorkerDeath(Generic[K]):
    """A worker died holding request ``key`` (its ``attempt``-th try); ``exitcode`` as the
    process reported it (negative: killed by that signal)."""

    key: K
    attempt: int
    exitcode: int | None


def _serve_tasks(conn: Connection, handler: Handler) -> None:
    """A task worker: answers ``(payload, attempt)`` requests with ``("ok", result)`` or
    ``("error", text)`` until it receives ``None`` or the parent goes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops its workers itself
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a forked worker: not the parent's handler
    try:
        while (request := conn.recv()) is not None:
            payload, attempt = request
            try:
                conn.send(("ok", handler(payload, attempt)))
            except Exception as exc:  # a bug, not a death: the parent raises it
                conn.send(("error", f"{type(exc).__name__}: {exc}"))
    except EOFError:  # the parent has gone
        pass
    finally:
        conn.close()


class _Workers:
    """Started worker processes and their pipes; :meth:`stop` ends them all, politely first."""

    def __init__(self, start_method: str) -> None:
        self.context: Any = multiprocessing.get_context(start_method)  # spawn or fork
        self.processes: dict[Connection, Any] = {}  # parent end of the pipe -> process

    def start(self, target: Callable[..., None], *args: Any) -> Connection:
        pipe: tuple[Connection, Connection] = self.context.Pipe()
        parent, child = pipe
        process = self.context.Process(target=target, args=(child, *args), daemon=True)
        with interrupt.deferred():
            process.start()
            child.close()
            self.processes[parent] = process
        return parent

    def drop(self, conn: Connection, timeout: float | None = 3.0) -> int | None:
        """Forget a worker whose pipe broke (waiting up to ``timeout`` [s] for it to end);
        its exit code."""
        process = self.processes.pop(conn)
        conn.close()
        process.join(timeout=timeout)
        exitcode: int | None = process.exitcode
        return exitcode

    def finish(self, goodbye: object) -> None:
        """Send every worker ``goodbye`` (the message that ends its loop) and wait for it."""
        for conn in self.processes:
            with contextlib.suppress(OSError):
                conn.send(goodbye)
        for process in self.processes.values():
            process.join(timeout=5)

    def stop(self) -> None:
        """Terminate every worker still alive (kill one that lingers) and close the pipes."""
        for process in self.processes.values():
            if process.is_alive():
                process.terminate()
        for conn, process in self.processes.items():
            process.join(timeout=3)
            if process.is_alive():
                process.kill()
                process.join(timeout=3)
            conn.close()
        self.processes.clear()


def run_tasks(
    handler: Handler,
    tasks: Iterable[tuple[K, Any]],
    *,
    processes: int,
    finished: Callable[[K, Any], None],
    died: Callable[[WorkerDeath[K]], bool],
    start_method: str = "spawn",
) -> None:
    """Run ``handler(payload, attempt)`` for every ``(key, payload)`` of ``tasks`` in at most
    ``processes`` worker processes, each serving task after task; ``finished(key, result)``
    receives each result as it arrives (in the parent, in whatever order they finish).

    A worker that dies holding a task is replaced and ``died(WorkerDeath)`` decides: True
    queues the task again (``attempt`` + 1), False drops it (the callback records what it
    must). A task that raises is :class:`TaskFailed` here. ``start_method``: ``spawn`` (fresh
    interpreters; the handler is pickled by reference) or ``fork`` (the workers share this
    process's state, e.g. effects a user registered; no thread may be running). Interruption:
    see the module docstring; :func:`odomgym.interrupt.check` runs at least once a second.
    """
    queue: list[tuple[K, Any, int]] = [(key, payload, 0) for key, payload in tasks]
    pool = _Workers(start_method)
    busy: dict[Connection, tuple[K, Any, int]] = {}

    def hand_out() -> None:
        # Give queued tasks to idle workers, starting workers up to ``processes``. A worker that
        # died while idle (its pipe is broken) is replaced; its task never ran, so it goes back
        # to the queue as it was.
        while queue:
            idle = [c for c in pool.processes if c not in busy]
            if not idle:
                if len(pool.processes) >= processes:
                    return
                pool.start(_serve_tasks, handler)
                continue
            conn, task = idle[0], queue.pop(0)
            try:
                conn.send((task[1], task[2]))
            except OSError:
                queue.insert(0, task)
                pool.drop(conn)
                continue
            busy[conn] = task

    try:
        while queue or busy:
            hand_out()
            # A result arrives on the connection; a death shows as end-of-file there.
            ready_now: list[Any] = wait(list(busy), timeout=1.0)
            interrupt.check()  # at least once a second, even while every worker is busy
            for ready in ready_now:
                key, payload, attempt = busy.pop(ready)
                try:
                    status, value = ready.recv()
                except (EOFError, OSError):
                    status, value = "died", None
                if status == "ok":
                    finished(key, value)
                elif status == "error":
                    raise TaskFailed(key, value)
                elif died(WorkerDeath(key, attempt, pool.drop(ready, timeout=None))):
                    queue.append((key, payload, attempt + 1))
        pool.finish(None)
    finally:
        pool.stop()


class Shards:
    """One worker per shard of a stateful object, all sent the same command at once.

    ``target(conn, *args)`` is the worker's loop (module-level, for ``spawn``): it answers
    each ``(command, payload)`` with ``("ok", value)`` or ``("error", exception)`` and returns
    on ``("close", ())``. ``args_per_shard`` gives each worker its arguments.
    """

    def __init__(
        self,
        target: Callable[..., None],
        args_per_shard: Sequence[tuple[Any, ...]],
        *,
        start_method: str = "spawn",
    ) -> None:
        self._pool = _Workers(start_method)
        try:
            self._pipes = [self._pool.start(target, *args) for args in args_per_shard]
        except BaseException:
            self._pool.stop()
            raise

    def call(self, command: str, payloads: Sequence[tuple[Any, ...]]) -> list[Any]:
        """Send ``command`` with its payload to every shard (in order) and return the values;
        every reply is read, so the pipes stay in step after an error, then the first error
        is raised."""
        for pipe, payload in zip(self._pipes, payloads, strict=True):
            pipe.send((command, payload))
        values: list[Any] = []
        error: BaseException | None = None
        for pipe in self._pipes:
            status, value = pipe.recv()
            if status == "error":
                error = error or value
            else:
                values.append(value)
        if error is not None:
            raise error
        return values

    def close(self) -> None:
        """Ask every worker to end, then make sure it has."""
        self._pool.finish(("close", ()))
        self._pool.stop()

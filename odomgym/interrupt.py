"""Stopping a command on Ctrl-C or SIGTERM, even when the signal lands in a finalizer.

The command line turns SIGINT and SIGTERM into :class:`Interrupted` (exit codes 130 and 143),
raised in the main thread so that every ``finally`` runs: worker processes are terminated,
temporary files removed. CPython runs a signal handler at the next bytecode of the main thread,
which may be inside a finalizer — pymunk frees its Chipmunk bodies from ``ffi.gc`` callbacks
during garbage collection — and an exception raised there is printed ("Exception ignored
in …") and dropped: the command went on as if never signalled (found by
``benchmarks/fuzz_cli.py``: a SIGTERM during ``train selfcal`` was lost that way). So the
handler also records the request, the long loops call :func:`check` at each unit of progress
(a benchmark chunk, a candidate fit, a training step), which raises it again, and
``odomgym.cli.main`` reports a request that arrived after the last check.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from typing import NoReturn

__all__ = ["Interrupted", "check", "deferred", "pending", "reset", "stop"]


class Interrupted(BaseException):
    """Ctrl-C (exit code 130) or SIGTERM (143): the command stops its workers and says so.

    A ``BaseException``, as ``KeyboardInterrupt`` is: the ``except Exception`` that turns a
    damaged file or a failing calibration into a one-line error must not turn a stop into
    one too."""

    def __init__(self, code: int, message: str = "stopped") -> None:
        super().__init__(message)
        self.code = code


_requested: Interrupted | None = None


def stop(code: int, message: str) -> NoReturn:
    """Record a stop request and raise it (call from a signal handler)."""
    global _requested
    _requested = Interrupted(code, message)
    raise Interrupted(code, message)


def check() -> None:
    """Raise the recorded stop request, if any: a long loop calls this at each unit of work, so
    a request whose first raise was swallowed by a finalizer still stops it."""
    if _requested is not None:
        raise Interrupted(_requested.code, str(_requested))


def pending() -> Interrupted | None:
    """The recorded stop request, if any."""
    return _requested


def reset() -> None:
    """Forget the request (a command starts, or has reported it)."""
    global _requested
    _requested = None


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back for the block (delivered when it ends): for steps that must
    not be cut in two, such as starting a worker process or writing a checkpoint's files. A
    no-op where the platform cannot (no ``pthread_sigmask``)."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    held = {signal.SIGINT, signal.SIGTERM}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)

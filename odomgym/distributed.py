"""Where odomgym's independent units of work run: worker processes of this machine, or Ray.

Three commands spread independent work: ``bench`` (chunks of robots), ``fleet`` (one diagnosis
per robot and period) and ``diagnose`` (its candidate fits, and with ``--loso`` its
leave-one-session-out folds). Each unit is a deterministic function of its inputs, so where it
runs cannot change a result: ``--backend ray`` gives byte-identical outputs to ``--backend
local`` (tested against a real ``ray start --head`` in ``tests/test_distributed.py``).

Which Ray, by Ray's own convention (``ray.init``, "address" resolution):

* already initialised in this process (a script called ``ray.init`` itself): that one;
* ``--ray-address ADDRESS`` (``ray://host:10001`` for Ray Client, or ``host:6379`` from a
  node of the cluster), or else the ``RAY_ADDRESS`` environment variable: that cluster;
* neither: a new local Ray with ``jobs`` CPUs (``address="local"``, so a cluster started on
  this machine by ``ray start`` is not picked up by accident), shut down when the work ends.

On a cluster, every node needs odomgym (and the same versions of numpy, scipy, pymunk) in the
Python its Ray workers run; a unit's inputs travel with it (logs already read, configs), and
its outputs come back to this process, which writes every file, so no shared file system is
needed. Effects a user registered at run time exist only in this process: a Ray worker knows
the catalogue (:mod:`odomgym.effects`) and what its own imports register. Ray puts the working
folder of the process that calls ``ray.init`` first on its workers' ``sys.path``, so
:func:`ray_session` calls it from the folder that holds this process's odomgym, and gives the
workers the user's folders behind it (a ``PYTHONPATH``); a Ray the caller initialised is used as
it is.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import re
import signal
import socket
import sys
from collections.abc import Callable, Iterable, Iterator
from enum import StrEnum
from pathlib import Path
from typing import Any, TypeVar

from odomgym import interrupt
from odomgym.errors import SpecError

__all__ = [
    "RAY_MISSING",
    "REACH_TIMEOUT",
    "Backend",
    "check_client",
    "check_reachable",
    "on_ray",
    "ray_session",
    "ray_started",
    "run_ray_tasks",
]

K = TypeVar("K")

RAY_MISSING = "--backend ray needs Ray, which is not installed: pip install 'odomgym[distributed]'"
"""The one line a command prints when Ray is asked for and absent."""


class Backend(StrEnum):
    """Where a command's independent units of work run.

    * ``local`` — this machine: ``jobs`` worker processes (1: this process);
    * ``ray`` — Ray tasks (``pip install 'odomgym[distributed]'``), on the cluster named by
      ``--ray-address`` or ``RAY_ADDRESS``, else on a local Ray with ``jobs`` CPUs.
    """

    LOCAL = "local"
    RAY = "ray"

    def check_available(self) -> None:
        """Raise :class:`SpecError` (field ``backend``) if this backend cannot run here; cheap
        enough to call before any work."""
        if self is Backend.RAY and importlib.util.find_spec("ray") is None:
            raise SpecError(RAY_MISSING, field="backend")


_RAY_STARTED: bool | None = None
"""Inside :func:`on_ray`: whether that block started its Ray; None outside (work runs here)."""


def ray_started() -> bool | None:
    """None when the units of work that may go to Ray run on this machine; inside
    :func:`on_ray`, whether its Ray was started by it (for :func:`run_ray_tasks`)."""
    return _RAY_STARTED


@contextlib.contextmanager
def on_ray(backend: Backend | str, address: str | None = None, cpus: int = 1) -> Iterator[None]:
    """With ``backend`` ``ray``, the block's units of work that can go to Ray do (a diagnosis'
    candidate fits: :func:`odomgym.diagnose.fit.run_fit_jobs`), in a :func:`ray_session`;
    with ``local`` nothing changes. Not reentrant across threads (one command at a time)."""
    global _RAY_STARTED
    if Backend(backend) is Backend.LOCAL:
        yield
        return
    with ray_session(address, cpus) as started:
        before, _RAY_STARTED = _RAY_STARTED, started
        try:
            yield
        finally:
            _RAY_STARTED = before


def _address(address: str | None) -> str | None:
    """The cluster to join: ``address``, else ``RAY_ADDRESS``, else None (start a local one)."""
    chosen = address or os.environ.get("RAY_ADDRESS") or None
    return chosen.strip() if chosen else None


def _package_root() -> str:
    """The folder holding the imported ``odomgym`` package, this module's, as it stands on
    ``sys.path`` (site-packages for an install, the checkout for an editable one; not resolved
    through symbolic links): where :func:`ray_session` starts Ray from."""
    return str(Path(__file__).absolute().parents[1])


def _user_paths() -> str:
    """The folders Ray would have put first on its workers' ``sys.path`` (the script's folder
    where it is on this process's path, and the working folder), then this process's
    ``PYTHONPATH``, all absolute: a ``PYTHONPATH`` for the workers, so that the user's own
    modules (an effect registered in a module beside the script) still import there, behind
    the odomgym this process runs."""
    found: list[str] = []
    script = os.path.dirname(os.path.realpath(sys.argv[0])) if sys.argv and sys.argv[0] else ""
    if script and script in sys.path:
        found.append(script)
    found.append(os.path.abspath(os.curdir))
    found += [os.path.abspath(p) for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    return os.pathsep.join(dict.fromkeys(found))


REACH_TIMEOUT = 5.0
"""Seconds a cluster's address has to accept a connection before ``ray.init`` is called on it
(:func:`check_reachable`)."""

_HOST_PORT = re.compile(r"^(?:ray://)?(\[[^\]]+\]|[^:/\[\]]+):(\d+)$")


def check_reachable(target: str, timeout: float = REACH_TIMEOUT) -> None:
    """Refuse, in one line, a cluster address (``host:port`` or ``ray://host:port``) where
    nothing accepts a connection within ``timeout`` seconds; other forms (``auto``) are left to
    Ray.

    Why: ``ray.init`` on an address where nothing answers retried for minutes, printing Ray's
    multi-line connection errors (a user's ``--ray-address 127.0.0.1:1`` still hung after
    300 s).

    Raises:
        SpecError: naming the address and what the connection said (field ``ray-address``).
    """
    found = _HOST_PORT.match(target.strip())
    if found is None:
        return
    host, port = found.group(1).strip("[]"), int(found.group(2))
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as exc:
        reason = (
            f"no answer within {timeout:g} s"
            if isinstance(exc, TimeoutError)
            else (exc.strerror or str(exc))
        )
        shown = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
        raise SpecError(
            f"cannot join Ray at {target}: nothing accepts a connection at {shown} "
            f"({reason}); is the cluster up, and is that its address "
            "(host:6379 from one of its nodes, ray://host:10001 through Ray Client)?",
            field="ray-address",
        ) from None


def check_client(target: str) -> None:
    """Refuse, in one line, a ``ray://`` address when Ray Client's dependency (grpcio, Ray's
    ``client`` extra) is not installed: the ``[distributed]`` extra installs Ray's core only,
    and ``ray.init("ray://…")`` then failed after the connection check with Ray's own message.

    Raises:
        SpecError: naming the address and the install command (field ``ray-address``).
    """
    import importlib.util

    if target.strip().startswith("ray://") and importlib.util.find_spec("grpc") is None:
        raise SpecError(
            f"cannot join Ray at {target}: a ray:// address goes through Ray Client, which "
            "needs grpcio (pip install 'ray[client]'); or, from one of the cluster's nodes, "
            "give the head's host:6379",
            field="ray-address",
        )


def _init(ray: Any, target: str | None, cpus: int) -> None:
    """``ray.init``: a new local Ray with ``cpus`` CPUs (``target`` None), else the cluster at
    ``target``; the workers' ``PYTHONPATH`` is :func:`_user_paths`'s."""
    options: dict[str, Any] = {
        "log_to_driver": False,
        "runtime_env": {"env_vars": {"PYTHONPATH": _user_paths()}},
    }
    if target is None:
        options.update(address="local", num_cpus=max(1, cpus), include_dashboard=False)
    else:
        options.update(address=target)
    with contextlib.chdir(_package_root()):
        ray.init(**options)


@contextlib.contextmanager
def ray_session(address: str | None = None, cpus: int = 1) -> Iterator[bool]:
    """Ray, initialised for the ``with`` block (module docstring: which one); yields whether
    this call started it (then it is shut down when the block ends, also on an error).

    Raises:
        SpecError: Ray is not installed (field ``backend``), or the cluster at the address
            cannot be reached (field ``ray-address``, naming the address).
    """
    Backend.RAY.check_available()
    import ray

    if ray.is_initialized():
        yield False
        return
    target = _address(address)
    if target is not None:
        check_client(target)
        check_reachable(target)
    # ray.init replaces the SIGTERM handler with one that calls sys.exit, and Ray's C++ core
    # installs absl's failure-signal handler, which prints a stack dump for a plain SIGTERM.
    # Keep the caller's handler (the command line's: stop cleanly, exit 143) and no dump.
    previous = signal.getsignal(signal.SIGTERM)
    os.environ.setdefault("RAY_DISABLE_FAILURE_SIGNAL_HANDLER", "1")
    try:
        # Ray puts the working folder of the process that calls ray.init first on its
        # workers' sys.path. From a source checkout with odomgym installed (not editable),
        # the workers then imported the checkout's odomgym/ while this process ran the
        # installed one: other code, without the envs/ and baselines/ that package-dir maps
        # in, and numba's cache of neither (in CI a leave-one-session-out test on Ray took
        # 96.8 s, 14.6 s with this; each worker had compiled every kernel again). So ray.init
        # is called from the folder that holds this process's odomgym (the working folder is
        # given back when it returns: this process's other threads see the change meanwhile,
        # and a local Ray's processes keep that folder as theirs), and the folders Ray would
        # have put first follow it on the workers' path (_user_paths).
        _init(ray, target, cpus)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        hint = (
            " (is the cluster up? A cluster with token authentication also needs "
            "RAY_AUTH_MODE=token and its token in ~/.ray/auth_token or RAY_AUTH_TOKEN)"
            if target
            else ""
        )
        raise SpecError(
            f"cannot {'join Ray at ' + target if target else 'start a local Ray'}: {first}{hint}",
            field="ray-address" if target else "backend",
        ) from None
    finally:
        if callable(previous) and signal.getsignal(signal.SIGTERM) is not previous:
            signal.signal(signal.SIGTERM, previous)
    try:
        yield True
    finally:
        ray.shutdown()


def run_ray_tasks(
    function: Callable[..., Any],
    tasks: Iterable[tuple[K, tuple[Any, ...]]],
    finished: Callable[[K, Any], None],
    *,
    started: bool,
    max_retries: int = 1,
) -> None:
    """``function(*args)`` for every ``(key, args)`` of ``tasks`` as a Ray task of one CPU,
    each result handed to ``finished(key, result)`` in this process as it arrives (in whatever
    order they finish). Ray must be initialised (:func:`ray_session`; ``started``: whether by
    this command, which decides how an interruption ends the tasks).

    A worker that dies is retried ``max_retries`` times by Ray itself (every attempt computes
    the same result); an exception inside a task is raised here as a RuntimeError naming the
    key. Ctrl-C/SIGTERM (:mod:`odomgym.interrupt`) and an exception from ``finished`` stop the
    work: on a Ray this command started, by shutting it down; on the caller's cluster, by
    cancelling this call's tasks only.
    """
    import ray

    remote = ray.remote(num_cpus=1, max_retries=max_retries)(function)
    pending: dict[Any, K] = {remote.remote(*args): key for key, args in tasks}
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
                key = pending.pop(ref)
                try:
                    value = ray.get(ref)
                except ray.exceptions.RayTaskError as exc:
                    cause = exc.cause if getattr(exc, "cause", None) is not None else exc
                    raise RuntimeError(
                        f"Ray task {key!r} failed: {type(cause).__name__}: {cause}"
                    ) from None
                finished(key, value)
    finally:
        if pending and started:
            # Interrupted on the local Ray this command started: shutting it down stops every
            # worker now (force-cancelling first made Ray's task manager abort at exit).
            ray.shutdown()
        elif pending:  # on the caller's cluster: stop this call's tasks, nothing else
            for ref in pending:
                ray.cancel(ref, force=True)

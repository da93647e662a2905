"""The ``odomgym`` command line: thin — it parses, calls the library, prints and plots.

Commands:
    ``odomgym run square|straight …``   drive runs in simulation, report return errors;
    ``odomgym run clapper-straight|clapper-rectangle …``  the CLAPPER two-truck vehicle with
                                         and without IPEC (Borenstein 1995, §6);
    ``odomgym calibrate METHOD …``      calibrate (simulated robot or measured session) and
                                         validate on fresh runs;
    ``odomgym bench calibrators …``     every calibrator on a robot population, three floors;
    ``odomgym leaderboard --data DIR``  real data: calibrate on one session, test on the others;
    ``odomgym covariance …``            Chong & Kleeman closed-form covariance (+ Monte Carlo);
    ``odomgym fit-noise …``             estimate k_L, k_R from repeated runs;
    ``odomgym diagnose DATA --robot R``  where a model and a robot's logs disagree, which
                                         catalogue effect is missing, and the gap it closes;
    ``odomgym train selfcal …``         train a self-calibration policy (the rl extra).

Exit codes, the same for every command:

* **0** — done;
* **1** — the machine refused a write after all (a full disk; every output path is checked
  before any work);
* **2** — bad input: one line ``odomgym: error: …`` naming the field and, where it came from a
  file, the file and line (output paths included);
* **3** — an internal error: anything else that went wrong is a bug in odomgym, not in the
  input, and is said to be one in one line (``odomgym: internal error: <type>: <message> — a
  bug in odomgym …``); ``odomgym --debug COMMAND …`` shows its full traceback instead, for the
  report;
* **130** / **143** — stopped by Ctrl-C / SIGTERM (workers stopped, nothing half-written);
* **141** — stdout closed by its reader (``odomgym … | head``): the command stops quietly, as
  a program killed by SIGPIPE does (128 + 13), files already written kept.

No command leaves a half-written output file. After its results a command says what it wrote
(``wrote: …``) and, where odometry is driven, which calibration it applied.

Layout: one module per command (``odomgym/cli/<command>.py``, each with ``register`` adding
its parser and ``run`` doing the work), and :mod:`odomgym.cli._common` for what they share —
argument types, output checks, the :class:`~odomgym.cli._common.Reporter` of results and
status lines, and the :class:`~odomgym.cli._common.Progress` bar. This module builds the
parser from the commands and runs one, turning the library's exceptions into exit codes.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from typing import Any

from odomgym import interrupt
from odomgym.cli import (
    bench,
    calibrate,
    covariance,
    diagnose,
    fit_noise,
    fleet,
    leaderboard,
    run,
    train,
)
from odomgym.cli._common import Command, StdoutClosed, notice, to_stdout

# The argument types and the output check under the names they had in the single-module
# command line, which tests and benchmarks/fuzz_cli.py import from here.
from odomgym.cli._common import check_output as _check_output
from odomgym.cli._common import count as _count
from odomgym.cli._common import positive as _positive
from odomgym.cli._common import seed as _seed
from odomgym.errors import SpecError
from odomgym.interrupt import Interrupted

__all__ = [
    "INTERNAL_ERROR",
    "_check_output",
    "_count",
    "_positive",
    "_seed",
    "build_parser",
    "internal_error",
    "main",
]

COMMANDS: tuple[Command, ...] = (
    run,
    calibrate,
    bench,
    train,
    leaderboard,
    covariance,
    fit_noise,
    diagnose,
    fleet,
)
"""Every command, in the order ``odomgym --help`` lists them."""


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every command (every option has a help text: tested)."""
    from odomgym import __version__

    parser = argparse.ArgumentParser(
        prog="odomgym",
        description="Wheel-odometry experiments, calibration and benchmarks in simulation and "
        "on measured logs.",
    )
    parser.add_argument("--version", action="version", version=f"odomgym {__version__}")
    parser.add_argument(
        "--debug",
        action="store_true",
        help="on an internal error (a bug in odomgym, exit 3) show the full traceback instead "
        "of one line (give it before the command)",
    )
    commands = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", help="what to do (COMMAND --help)"
    )
    for command in COMMANDS:
        command.register(commands)
    return parser


def _on_signal(signum: int, frame: object) -> None:
    """SIGINT and SIGTERM ask the running command to stop at its next check (it then leaves
    no half-written output), instead of killing it wherever it is."""
    import signal

    if signum == signal.SIGINT:
        interrupt.stop(130, "interrupted")
    interrupt.stop(143, "stopped by SIGTERM")


INTERNAL_ERROR = 3
"""The exit code of an internal error (module docstring)."""
BROKEN_PIPE = 141
"""The exit code when stdout's reader is gone (128 + SIGPIPE, what a shell reports for a
program killed by its pipe; module docstring)."""


def internal_error(exc: Exception, command: str) -> str:
    """The one line that reports ``exc``, raised by ``command``, as a bug in odomgym."""
    message = " ".join(str(exc).split())  # one line, whatever the exception's text holds
    what = f"{type(exc).__name__}: {message}" if message else type(exc).__name__
    return (
        f"internal error: {what} — a bug in odomgym, not in your input; please report it with "
        f"the command line and the output of odomgym --debug {command} …"
    )


def _located(exc: SpecError, args: argparse.Namespace) -> str:
    """``exc``'s message, led by the robot file's line that sets its field when the refusal
    came after the file was read: a value valid alone that the command cannot use (a
    ``max_wheel_speed`` below the experiments' speed). Only for the robot spec's own fields,
    from a ``--robot`` file that sets them; any other message is as raised."""
    import dataclasses
    from pathlib import Path

    from odomgym.errors import locate_key
    from odomgym.robot import RobotSpec

    robot = getattr(args, "robot", None)
    fields = {f.name for f in dataclasses.fields(RobotSpec)}
    if exc.source is None and exc.field in fields and isinstance(robot, str):
        path = Path(robot)
        if path.suffix == ".toml" and path.is_file():
            where = locate_key(path, exc.field)
            if where != str(path):
                return f"{where}: {exc}"
    return str(exc)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``odomgym`` command (exit codes: module docstring)."""
    import os
    import signal
    import sys
    import threading
    import traceback

    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Callable[[argparse.Namespace], int] = args.handler
    previous: dict[signal.Signals, Any] = {}
    interrupt.reset()
    if threading.current_thread() is threading.main_thread():
        for number in (signal.SIGINT, signal.SIGTERM):
            previous[number] = signal.signal(number, _on_signal)
    try:
        code = handler(args)
        to_stdout("", flush=True)  # a closed pipe is found here, not at the interpreter's exit
        late = interrupt.pending()
        if late is None:
            return code
        raise late  # the signal's own raise was swallowed after the last check
    except Interrupted as exc:
        notice(str(exc))
        return exc.code
    except KeyboardInterrupt:
        notice("interrupted")
        return 130
    except SpecError as exc:
        notice(f"error: {_located(exc, args)}")
        return 2
    except StdoutClosed:
        # The reader is gone (`| head`): no message (it would say nothing the user does not
        # know), and stdout pointed at /dev/null so that the interpreter's own flush at exit
        # does not print "Exception ignored ... BrokenPipeError" (Python's signal module docs,
        # "Note on SIGPIPE").
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return BROKEN_PIPE
    except OSError as exc:
        # Checked up front (check_output); what is left is the machine's (a full disk).
        where = f"{exc.filename}: " if exc.filename else ""
        notice(f"error: {where}{exc.strerror or exc}")
        return 1
    except Exception as exc:
        # Every input problem is a SpecError, so anything else is odomgym's own failure: say
        # so, rather than present it as the user's input error or drop a traceback on them.
        if args.debug:
            traceback.print_exc()
        else:
            notice(internal_error(exc, args.command))
        return INTERNAL_ERROR
    finally:
        interrupt.reset()
        for number, handler_before in previous.items():
            signal.signal(number, handler_before)

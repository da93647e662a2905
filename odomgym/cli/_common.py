"""What every ``odomgym`` command shares: argument types, shared options, output checks, the
one reporter of results and status lines, and the one progress bar.

The commands are thin (parse, call the library, report), so the rules they must all follow
live here once: every number is range-checked by its argparse type (a bad value is one line
naming the option, never a traceback deep in the library); every output path is checked
before any work (:func:`check_output`); results go to stdout, status lines go beside them
or, with ``--json``, to stderr so that stdout stays machine-readable (:class:`Reporter`);
and a progress bar is drawn only on a terminal and never with ``--json`` (:class:`Progress`).
"""

from __future__ import annotations

import argparse
import errno
import os
import sys
import tempfile
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, NoReturn, Protocol, Self

import numpy as np

from odomgym.errors import SpecError
from odomgym.floor import FLOORS
from odomgym.lab.report import to_json
from odomgym.odometry.calibration import Calibration
from odomgym.robot import PRESETS, RobotSpec, load_robot

if TYPE_CHECKING:
    from typing import TypeAlias

    Commands: TypeAlias = argparse._SubParsersAction[argparse.ArgumentParser]
    """The ``add_subparsers`` object a command's ``register`` adds its parser to."""


class Command(Protocol):
    """What a command module provides (``odomgym/cli/<command>.py``): the top-level parser is
    built by calling every command's ``register``, and the parsed arguments carry the
    ``handler`` (a ``run``) that :func:`odomgym.cli.main` calls."""

    def register(self, commands: Commands) -> None: ...

    def run(self, args: argparse.Namespace) -> int: ...


# ----------------------------------------------------------------------------- argument types
def finite(text: str) -> float:
    """An argparse type: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not np.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def positive(text: str) -> float:
    """An argparse type: a finite number > 0."""
    value = finite(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def nonnegative(text: str) -> float:
    """An argparse type: a finite number >= 0."""
    value = finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return value


def fraction(text: str) -> float:
    """An argparse type: a number strictly between 0 and 1."""
    value = finite(text)
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"must lie strictly between 0 and 1, got {text!r}")
    return value


MAX_COUNT = 10**9
"""The largest count an option takes (runs, robots, steps): beyond it a run would not end in a
lifetime, and numbers past 2**63 overflow numpy's and the OS's integers."""
MAX_PROCESSES = 1024
"""The most worker processes (``--jobs``, ``--workers``) or batched sessions (``--envs``)."""


def count(text: str, limit: int = MAX_COUNT) -> int:
    """An argparse type: a whole number from 1 to ``limit``."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text!r}")
    if value > limit:
        raise argparse.ArgumentTypeError(f"must be at most {limit}, got {text!r}")
    return value


def processes(text: str) -> int:
    """An argparse type: a number of worker processes or batched sessions, 1 to 1024."""
    return count(text, MAX_PROCESSES)


def seed(text: str) -> int:
    """An argparse type: a whole number >= 0 (numpy seeds and counts)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def seed32(text: str) -> int:
    """An argparse type: a seed from 0 to 2**32 - 1 (what torch and SB3 take)."""
    value = seed(text)
    if value > 2**32 - 1:
        raise argparse.ArgumentTypeError(f"must be at most 2**32 - 1, got {text!r}")
    return value


def bumps(text: str) -> int:
    """An argparse type: a number of cables, 0 to 1000 (more than one every 4 cm of the
    CLAPPER's 36 m)."""
    value = seed(text)
    if value > 1000:
        raise argparse.ArgumentTypeError(f"must be at most 1000, got {text!r}")
    return value


# ------------------------------------------------------------------------------ shared options
def floor_help(default: str = "smooth") -> str:
    """The ``--floor`` help of every command that takes a preset floor: it lists every preset,
    so a new floor appears in all of them at once (tested)."""
    return (
        f"floor: a preset ({', '.join(FLOORS)}; smooth has no wheel noise, concrete is a lab "
        f"floor, bumpy one fixed cable layout) or a floor .toml file (default {default})"
    )


def add_backend_arguments(parser: argparse.ArgumentParser, units: str) -> None:
    """``--backend local|ray`` and ``--ray-address``: where a command's independent ``units``
    of work run (:mod:`odomgym.distributed`), the same two options on every command that
    spreads work (``bench``, ``diagnose``, ``fleet``)."""
    parser.add_argument(
        "--backend",
        choices=["local", "ray"],
        default="local",
        help=f"where the {units} run: local, worker processes on this machine (default); ray, "
        "Ray tasks on the cluster of --ray-address or RAY_ADDRESS, else on a local Ray of "
        "--jobs CPUs (pip install 'odomgym[distributed]'); results are the same",
    )
    parser.add_argument(
        "--ray-address",
        metavar="ADDRESS",
        help="with --backend ray: the Ray cluster to join (ray://HOST:10001, or HOST:6379 on a "
        "node of the cluster; default: RAY_ADDRESS, else a new local Ray)",
    )


def check_backend(args: argparse.Namespace) -> None:
    """Before any work: Ray is installed when asked for (one line naming the extra), and
    ``--ray-address`` is given only with ``--backend ray``."""
    from odomgym.distributed import Backend

    if args.ray_address and args.backend != "ray":
        raise SpecError("--ray-address needs --backend ray", field="ray-address")
    Backend(args.backend).check_available()


def add_robot_arguments(parser: argparse.ArgumentParser, *, calibration: bool = True) -> None:
    """The robot, its injected errors, the floor and the seed: the same options for every
    command that drives a simulated robot (``run square|straight``, ``calibrate``).

    Args:
        parser: the command's parser.
        calibration: also ``--calibration`` (``calibrate`` starts uncalibrated, so it has none).
    """
    parser.add_argument(
        "--robot",
        default="labmate",
        help=f"robot preset ({', '.join(PRESETS)}) or a robot .toml file (default labmate)",
    )
    parser.add_argument("--ed", type=positive, help="true E_d = D_R/D_L to inject")
    parser.add_argument("--eb", type=positive, help="true E_b = b_actual/b_nominal to inject")
    parser.add_argument("--es", type=positive, help="true E_s = D_mean/D_nominal to inject")
    parser.add_argument("--floor", default="smooth", help=floor_help())
    parser.add_argument("--seed", type=seed, default=0, help="random seed >= 0 (default 0)")
    if calibration:
        parser.add_argument(
            "--calibration",
            help="calibration .toml the odometry applies (default: none, the nominal robot)",
        )


def robot_from(args: argparse.Namespace) -> RobotSpec:
    """The robot of :func:`add_robot_arguments`' options, with the injected errors."""
    robot = load_robot(args.robot)
    if args.ed is not None or args.eb is not None or args.es is not None:
        try:
            robot = robot.with_errors(args.ed, args.eb, args.es)
        except SpecError as exc:
            # Said as the option the user typed, not the derived field (true_wheelbase).
            option = "--eb" if exc.field == "true_wheelbase" else "--ed/--es"
            raise SpecError(f"{option}: {exc}", field=option) from None
    return robot


def describe_calibration(calibration: Calibration) -> str:
    """A calibration in one line, as the status lines of ``run`` and ``calibrate`` show it."""
    line = (
        f"c_L = {calibration.c_left:.6f}, c_R = {calibration.c_right:.6f}, "
        f"E_b = {calibration.wheelbase_scale:.6f}, E_s = {calibration.distance_scale:.6f}"
    )
    if calibration.has_icr:
        line += f", x_ICR = {calibration.icr_x:.6f} m, y_ICR = {calibration.icr_y:.6f} m"
    if calibration.has_track_curve:
        line += (
            f", track curve alpha = {calibration.track_alpha:.6f}, "
            f"beta = {calibration.track_beta:.6f}, p = {calibration.track_power:.6f}"
        )
    return line


def check_methods(methods: Sequence[str] | None) -> None:
    """Fail in one line, before any work, if a ``--methods`` name is not a calibrator."""
    from odomgym.baselines import CALIBRATORS

    unknown = [m for m in methods or () if m not in CALIBRATORS]
    if unknown:
        raise SpecError(
            f"unknown method(s) {', '.join(unknown)}; methods: {', '.join(CALIBRATORS)}",
            field="methods",
        )


# ------------------------------------------------------------------------------ output checks
def check_output(
    path: str | Path, *, option: str, folder: bool = False, swap: bool = False
) -> None:
    """Fail before any work, in one line naming ``option``, if ``path`` cannot be written.

    Outputs are written atomically (:mod:`odomgym.io`: a temporary file beside the target,
    renamed over it), so what must be writable is the folder where the first new entry is
    created: the nearest existing folder above ``path``, or ``path`` itself for an existing
    output folder. Write access is probed by creating and removing a temporary file there, as
    a permission check alone passes for root in read-only places such as ``/proc``.

    Args:
        path: the output the user named.
        option: the command-line option that named it (``--out``), for the message; its
            name without dashes is the :class:`SpecError`'s field.
        folder: ``path`` is a folder that the command writes files into (created if
            missing); otherwise a file.
        swap: the folder is replaced whole by a rename in its parent (``diagnose``), so the
            parent must be writable even if the folder exists.
    """
    target = Path(path)
    field = option.lstrip("-").replace("-", "_")

    def fail(reason: str) -> NoReturn:
        raise SpecError(f"{option} {path}: {reason}", field=field)

    if folder and target.exists() and not target.is_dir():
        fail("exists and is not a folder; give a folder (created if missing)")
    if not folder and target.is_dir():
        fail("is a folder; give a file name")
    if not folder and target.exists() and not target.is_file():
        # A device (/dev/full, /dev/null), FIFO or socket: replacing it by a rename would
        # destroy it, and writing into it is not what an output file means.
        fail("is not a regular file (a device, pipe or socket); give a file name")
    if swap and Path.cwd().resolve().is_relative_to(target.resolve()):
        fail("is replaced whole at the end and holds the working folder; give a folder of its own")
    where = target if folder and target.is_dir() and not swap else target.absolute().parent
    while not where.exists():
        where = where.parent
    if not where.is_dir():
        fail(f"{where} is a file, not a folder")
    try:
        handle, probe = tempfile.mkstemp(prefix=".odomgym-write-check-", dir=where)
    except OSError as exc:
        # ENOENT from a folder that exists: a pseudo-filesystem such as /proc.
        reason = "" if exc.errno == errno.ENOENT else f" ({exc.strerror or exc})"
        fail(f"cannot create files in {where}{reason}")
    os.close(handle)
    os.unlink(probe)


def check_plot_path(path: str | None) -> None:
    """Fail before any simulation if matplotlib cannot write ``path``'s format, or the file
    cannot be written there."""
    if path is None:
        return
    from matplotlib.backend_bases import FigureCanvasBase

    suffix = Path(path).suffix.lstrip(".").lower()
    formats = FigureCanvasBase.get_supported_filetypes()
    if suffix not in formats:
        raise SpecError(
            f"cannot write a plot as {path!r}: use one of .{', .'.join(sorted(formats))}",
            field="plot",
        )
    check_output(path, option="--plot")


# ---------------------------------------------------------------------------------- reporting
class StdoutClosed(Exception):
    """stdout's reader is gone (``odomgym … | head``): raised where stdout is written, so that
    :func:`odomgym.cli.main` stops quietly for this, and only this, broken pipe (another one,
    a worker's or a socket's, stays an error)."""


def to_stdout(text: str, *, flush: bool = False) -> None:
    """``print(text)`` to stdout (or only a flush, for ``text`` ``""`` with ``flush``), with a
    closed pipe raised as :class:`StdoutClosed`."""
    try:
        if text or not flush:
            print(text)
        if flush:
            sys.stdout.flush()
    except BrokenPipeError:
        raise StdoutClosed from None


def notice(text: str) -> None:
    """A message from the program itself (an error, an interruption, a retried worker) on
    stderr, prefixed ``odomgym:`` so that it is told apart from a library's output."""
    print(f"odomgym: {text}", file=sys.stderr)


class Reporter:
    """Everything a command prints, so that every command follows the same rules.

    Results (JSON documents or text tables) go to stdout. Status lines — which calibration was
    applied, what was written (``wrote: …``), how to use the result — go to stdout beside a
    table, but to stderr with ``--json``, so that stdout stays one JSON document per line.
    The command decides what to print in which mode; the reporter decides where it goes.

    Args:
        json: the command's ``--json``: results are JSON, status lines go to stderr.
    """

    def __init__(self, json: bool) -> None:
        self.json = json

    @classmethod
    def of(cls, args: argparse.Namespace) -> Self:
        """The reporter of a parsed command line (a command without ``--json`` prints text)."""
        return cls(bool(getattr(args, "json", False)))

    def document(self, value: object) -> None:
        """One JSON document on its own line of stdout (a run's record, a summary)."""
        to_stdout(to_json(value))

    def text(self, text: str) -> None:
        """Text for a reader (a table, a report) on stdout."""
        to_stdout(text)

    def result(self, json: Callable[[], object], text: Callable[[], str]) -> None:
        """The command's result: the JSON document with ``--json``, the text otherwise.

        Both are functions, so that only the one printed is computed.
        """
        if self.json:
            self.document(json())
        else:
            self.text(text())

    def status(self, text: str) -> None:
        """A status line (files written, calibration applied): on stdout beside a table, on
        stderr with ``--json`` so that stdout stays machine-readable."""
        if self.json:
            print(text, file=sys.stderr)
        else:
            to_stdout(text)

    def notice(self, text: str) -> None:
        """A notice about the input that the command works around (a run set aside): one line
        on stderr, prefixed ``odomgym:``, in every mode — it is neither a result nor a status
        of the output, and stdout stays machine-readable."""
        notice(text)

    def wrote(self, paths: Iterable[str | Path]) -> None:
        """The ``wrote: …`` status line naming every file written, in order; none if none."""
        names = [str(p) for p in paths]
        if names:
            self.status("wrote: " + ", ".join(names))

    @property
    def shows_progress(self) -> bool:
        """Whether a progress bar may be drawn: on a terminal only (a log file would fill with
        carriage returns), and never with ``--json`` (a consumer reads the output, not a
        person)."""
        return not self.json and sys.stderr.isatty()


class Progress:
    """The one progress bar of the commands: tqdm on stderr, drawn only when the reporter
    :attr:`~Reporter.shows_progress`, closed on leaving the ``with`` block however it is left.

    The library reports progress through callbacks of different shapes (a fraction, done of
    total, a stage and a fraction); the methods translate each into the bar's position.

    Args:
        reporter: the command's reporter (whether to draw).
        desc: the bar's label.
        total: the bar's full count (100 for a percentage).
        unit: the unit after the rate.
        leave: keep the finished bar on the screen.
        bar_format: tqdm's layout, if not its default.
    """

    def __init__(
        self,
        reporter: Reporter,
        desc: str,
        *,
        total: int = 100,
        unit: str = "it",
        leave: bool = True,
        bar_format: str | None = None,
    ) -> None:
        from tqdm import tqdm

        self.total = total
        self._bar: Any = tqdm(
            total=total,
            unit=unit,
            desc=desc,
            disable=not reporter.shows_progress,
            leave=leave,
            file=sys.stderr,
            bar_format=bar_format,
        )

    @classmethod
    def percent(cls, reporter: Reporter, desc: str = "simulating") -> Self:
        """A bar of percentages with the elapsed and remaining time, removed when done (the
        simulations of ``run``)."""
        return cls(
            reporter,
            desc,
            unit="%",
            leave=False,
            bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}",
        )

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._bar.close()

    def at(self, position: int) -> None:
        """Move the bar to ``position`` of :attr:`total`."""
        self._bar.n = position
        self._bar.refresh()

    def fraction(self, fraction: float) -> None:
        """A library's progress as a fraction from 0 to 1."""
        self.at(int(self.total * fraction))

    def done_of(self, done: int, total: int) -> None:
        """A library's progress as ``done`` of ``total`` units."""
        self.at(int(self.total * done / total))

    def stage(self, stage: str, fraction: float) -> None:
        """A library's progress as the name of its current stage and a fraction from 0 to 1."""
        self._bar.set_description(stage)
        self.fraction(fraction)

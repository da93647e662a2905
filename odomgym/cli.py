"""The ``odomgym`` command line: thin — it parses, calls the library, prints and plots.

Commands:
    ``odomgym run square|straight …``   drive runs in simulation, report return errors;
    ``odomgym calibrate METHOD …``      calibrate (simulated robot or measured session) and
                                         validate on fresh runs;
    ``odomgym bench calibrators …``     every calibrator on a robot population, three floors;
    ``odomgym leaderboard --data DIR``  real data: calibrate on one session, test on the others;
    ``odomgym covariance …``            Chong & Kleeman closed-form covariance (+ Monte Carlo);
    ``odomgym fit-noise …``             estimate k_L, k_R from repeated runs;
    ``odomgym diagnose DATA --robot R``  where a model and a robot's logs disagree, which
                                         catalogue effect is missing, and the gap it closes.

Every command exits 0 on success, 2 on bad input (one line naming the field and, where it came
from a file, the file and line) — output paths included, which are checked before any work —
and 1 if the machine refuses a write after all (a full disk); it never leaves a half-written
output file. After its results it says what it wrote (``wrote: …``) and, where odometry is
driven, which calibration it applied.
"""

from __future__ import annotations

import argparse
import dataclasses
import errno
import os
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from odomgym import interrupt
from odomgym.errors import SpecError
from odomgym.floor import FLOORS, FloorSpec, load_floor
from odomgym.interrupt import Interrupted
from odomgym.io import atomic_write_text
from odomgym.odometry import Calibration, load_calibration
from odomgym.planning import drive_plans, ros2_yaml, square_plans, straight_plans
from odomgym.report import (
    format_return_errors,
    format_session_report,
    format_simulation_report,
    plot_return_errors,
    to_json,
)
from odomgym.robot import PRESETS, RobotSpec, load_robot

__all__ = ["main"]


def _finite(text: str) -> float:
    """An argparse type: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not np.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def _positive(text: str) -> float:
    """An argparse type: a finite number > 0."""
    value = _finite(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def _nonnegative(text: str) -> float:
    """An argparse type: a finite number >= 0."""
    value = _finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return value


MAX_COUNT = 10**9
"""The largest count an option takes (runs, robots, steps): beyond it a run would not end in a
lifetime, and numbers past 2**63 overflow numpy's and the OS's integers."""
MAX_PROCESSES = 1024
"""The most worker processes (``--jobs``, ``--workers``) or batched sessions (``--envs``)."""


def _count(text: str, limit: int = MAX_COUNT) -> int:
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


def _processes(text: str) -> int:
    """An argparse type: a number of worker processes or batched sessions, 1 to 1024."""
    return _count(text, MAX_PROCESSES)


def _bumps(text: str) -> int:
    """An argparse type: a number of cables, 0 to 1000 (more than one every 4 cm of the
    CLAPPER's 36 m)."""
    value = _seed(text)
    if value > 1000:
        raise argparse.ArgumentTypeError(f"must be at most 1000, got {text!r}")
    return value


def _seed(text: str) -> int:
    """An argparse type: a whole number >= 0 (numpy seeds and counts)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def _seed32(text: str) -> int:
    """An argparse type: a seed from 0 to 2**32 - 1 (what torch and SB3 take)."""
    value = _seed(text)
    if value > 2**32 - 1:
        raise argparse.ArgumentTypeError(f"must be at most 2**32 - 1, got {text!r}")
    return value


def _check_output(
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


def _check_plot_path(path: str | None) -> None:
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
    _check_output(path, option="--plot")


def _say(args: argparse.Namespace, text: str) -> None:
    """A status line (files written, calibration applied): on stdout beside a table, on
    stderr with ``--json`` so that stdout stays machine-readable."""
    print(text, file=sys.stderr if getattr(args, "json", False) else sys.stdout)


def _report_written(args: argparse.Namespace, paths: Sequence[str | Path]) -> None:
    if paths:
        _say(args, "wrote: " + ", ".join(str(p) for p in paths))


def _describe_calibration(calibration: Calibration) -> str:
    return (
        f"c_L = {calibration.c_left:.6f}, c_R = {calibration.c_right:.6f}, "
        f"E_b = {calibration.wheelbase_scale:.6f}, E_s = {calibration.distance_scale:.6f}"
    )


def _check_methods(methods: Sequence[str] | None) -> None:
    from odomgym.baselines import CALIBRATORS

    unknown = [m for m in methods or () if m not in CALIBRATORS]
    if unknown:
        raise SpecError(
            f"unknown method(s) {', '.join(unknown)}; methods: {', '.join(CALIBRATORS)}",
            field="methods",
        )


def _floor_help(default: str = "smooth") -> str:
    return (
        f"floor: a preset ({', '.join(FLOORS)}; smooth has no wheel noise, concrete is a lab "
        f"floor, bumpy one fixed cable layout) or a floor .toml file (default {default})"
    )


def _add_robot_arguments(parser: argparse.ArgumentParser, *, calibration: bool = True) -> None:
    parser.add_argument(
        "--robot",
        default="labmate",
        help=f"robot preset ({', '.join(PRESETS)}) or a robot .toml file (default labmate)",
    )
    parser.add_argument("--ed", type=_positive, help="true E_d = D_R/D_L to inject")
    parser.add_argument("--eb", type=_positive, help="true E_b = b_actual/b_nominal to inject")
    parser.add_argument("--es", type=_positive, help="true E_s = D_mean/D_nominal to inject")
    parser.add_argument("--floor", default="smooth", help=_floor_help())
    parser.add_argument("--seed", type=_seed, default=0, help="random seed >= 0 (default 0)")
    if calibration:
        parser.add_argument(
            "--calibration",
            help="calibration .toml the odometry applies (default: none, the nominal robot)",
        )


def _robot_from(args: argparse.Namespace) -> RobotSpec:
    robot = load_robot(args.robot)
    if args.ed is not None or args.eb is not None or args.es is not None:
        robot = robot.with_errors(args.ed, args.eb, args.es)
    return robot


def _progress_bar(enabled: bool) -> Any:
    from tqdm import tqdm

    return tqdm(
        total=100,
        unit="%",
        desc="simulating",
        disable=not enabled,
        leave=False,
        file=sys.stderr,
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}",
    )


def _command_run(args: argparse.Namespace) -> int:
    plot: str | None = getattr(args, "plot", None)
    _check_plot_path(plot)
    if args.log:
        _check_output(args.log, option="--log")
    robot = _robot_from(args)
    floor: FloorSpec = load_floor(args.floor)
    calibration = load_calibration(args.calibration) if args.calibration else None
    if args.path == "square":
        plans = square_plans(args.side, args.direction)
    else:
        plans = straight_plans(args.distance, args.return_trip)
    bar = _progress_bar(not args.json and sys.stderr.isatty())

    def update(fraction: float) -> None:
        bar.n = int(100 * fraction)
        bar.refresh()

    try:
        batch = drive_plans(
            robot,
            floor,
            plans,
            repeats=args.runs,
            calibration=calibration,
            rng=np.random.default_rng(args.seed),
            progress=update,
        )
    finally:
        bar.close()
    written: list[str] = []
    if args.log:
        from odomgym.data.native import write_native

        write_native(Path(args.log), batch.runs)
        written.append(args.log)
    summary = batch.summary()
    if args.json:
        for record in batch.records():
            print(to_json(record))
        if summary is not None:
            print(to_json({"summary": summary.__dict__}))
    else:
        print(
            f"robot {robot.name}: E_d = {robot.e_d:.5f}, E_b = {robot.e_b:.5f}, "
            f"E_s = {robot.e_s:.5f}; floor {floor.name}; route {batch.route_name}"
        )
    if calibration is None:
        _say(args, "applied calibration: none (the nominal robot's odometry)")
    else:
        _say(
            args, f"applied calibration: {args.calibration} ({_describe_calibration(calibration)})"
        )
    if not args.json:
        print("return errors (true - odometry, start frame)")
        print(format_return_errors(batch.rows(), summary))
    if plot:
        plot_return_errors(
            Path(plot),
            [("runs", batch.errors_of("cw"), batch.errors_of("ccw"))],
            f"{robot.name}: return errors, {floor.name} floor",
        )
        written.append(plot)
    _report_written(args, written)
    return 0


def _check_calibration_outputs(args: argparse.Namespace) -> None:
    if args.export_path is not None and args.export is None:
        raise SpecError("--export-path needs --export ros2", field="export_path")
    if args.save:
        _check_output(args.save, option="--save")
    if args.export:
        _check_output(_export_path(args), option="--export-path")
    _check_plot_path(args.plot)


def _export_path(args: argparse.Namespace) -> str:
    return str(args.export_path or "diff_drive_controller.yaml")


def _write_calibration_outputs(args: argparse.Namespace, calibration: Calibration) -> list[str]:
    written: list[str] = []
    if args.save:
        calibration.save(args.save)
        written.append(args.save)
    if args.export == "ros2":
        atomic_write_text(Path(_export_path(args)), ros2_yaml(calibration))
        written.append(_export_path(args))
    return written


def _command_calibrate(args: argparse.Namespace) -> int:
    from odomgym.baselines import CALIBRATORS
    from odomgym.baselines.validation import (
        calibrate_in_simulation,
        calibrate_on_session,
        calibrator_for_session,
        calibrator_for_squares,
    )

    if args.method not in CALIBRATORS:
        raise SpecError(
            f"unknown method {args.method!r}; methods: {', '.join(sorted(CALIBRATORS))}",
            field="method",
        )
    cls = CALIBRATORS[args.method]
    _check_calibration_outputs(args)
    if args.data:
        from odomgym.data import read_session, resolve_data

        session = read_session(resolve_data(args.data, session=True))
        try:
            calibrator = calibrator_for_session(cls, session, args.conventions)
            report = calibrate_on_session(calibrator, session)
        except (LookupError, ValueError) as exc:
            if isinstance(exc, SpecError):
                raise
            # The session lacks an experiment the method needs (e.g. squares for UMBmark).
            message = str(exc.args[0]) if exc.args else str(exc)
            raise SpecError(
                f"{args.method} cannot calibrate on {args.data}: {message}", field="data"
            ) from None
        written = _write_calibration_outputs(args, report.result.calibration)
        if args.json:
            print(to_json(report.as_dict()))
        else:
            print(format_session_report(report))
        _say(args, f"calibrated: {_describe_calibration(report.result.calibration)}")
        _report_written(args, written)
        return 0
    if args.conventions == "optiodom":
        raise SpecError(
            "--conventions optiodom applies to measured data (--data DIR)", field="conventions"
        )
    robot = _robot_from(args)
    floor = load_floor(args.floor)
    extra = {"policy": args.policy} if args.policy is not None else {}
    calibrator = calibrator_for_squares(cls, side=args.side, runs_per_direction=args.runs, **extra)
    report_sim = calibrate_in_simulation(
        calibrator,
        robot,
        floor,
        seed=args.seed,
        validation_side=args.side,
        validation_runs=args.runs,
    )
    written = _write_calibration_outputs(args, report_sim.result.calibration)
    if args.plot:
        plot_return_errors(
            Path(args.plot),
            [
                ("before", report_sim.errors_before["cw"], report_sim.errors_before["ccw"]),
                ("after", report_sim.errors_after["cw"], report_sim.errors_after["ccw"]),
            ],
            f"{args.method} on {robot.name}, {floor.name} floor: "
            f"{report_sim.improvement:.1f}-fold improvement",
        )
        written.append(args.plot)
    if args.json:
        print(to_json(report_sim.as_dict()))
    else:
        print(format_simulation_report(report_sim, floor.name))
    _say(args, f"calibrated: {_describe_calibration(report_sim.result.calibration)}")
    _report_written(args, written)
    return 0


def _command_bench(args: argparse.Namespace) -> int:
    import time

    from odomgym.baselines import CALIBRATORS
    from odomgym.baselines.bench_report import markdown_summary, write_outputs
    from odomgym.baselines.benchmark import Backend, BenchConfig, run_benchmark, summarize

    backend = Backend(args.backend)
    backend.check_available()
    _check_output(args.out, option="--out", folder=True)
    _check_methods(args.methods)
    methods = tuple(args.methods or CALIBRATORS)
    # BenchConfig names the offending field itself (SpecError).
    config = BenchConfig(
        robots=args.robots,
        floors=tuple(args.floor),
        methods=methods,
        budget=args.budget[0],
        extra_budgets=tuple(args.budget[1:]),
        seed=args.seed,
    )
    jobs = args.jobs or os.cpu_count() or 1
    show_bar = not args.json and sys.stderr.isatty()
    from tqdm import tqdm

    bar = tqdm(
        total=config.robots, unit="robot", desc="benchmark", disable=not show_bar, file=sys.stderr
    )

    def progress(done: int, total: int) -> None:
        bar.n = done
        bar.refresh()

    journal = Path(args.out) / JOURNAL_NAME
    start = time.perf_counter()
    try:
        rows = run_benchmark(
            config,
            jobs=jobs,
            backend=backend,
            progress=progress,
            journal=journal,
            resume=args.resume,
            chunk=args.chunk,
            notify=lambda text: print(f"odomgym: {text}", file=sys.stderr),
        )
    except (KeyboardInterrupt, Interrupted) as exc:
        code = exc.code if isinstance(exc, Interrupted) else 130
        raise Interrupted(
            code,
            f"stopped; the finished robots are recorded in {journal}: add --resume to continue",
        ) from None
    finally:
        bar.close()
    elapsed = time.perf_counter() - start
    written = write_outputs(config, rows, Path(args.out), elapsed)
    journal.unlink(missing_ok=True)  # finished: the outputs hold everything
    if args.json:
        print(to_json({"elapsed_s": elapsed, "jobs": jobs, "summary": summarize(rows)}))
    else:
        print(markdown_summary(config, rows))
        print(f"{len(rows)} results in {elapsed:.1f} s on {jobs} job(s) ({backend}).")
    _report_written(args, written)
    return 0


def _command_leaderboard(args: argparse.Namespace) -> int:
    from odomgym.baselines.leaderboard import format_leaderboard, run_leaderboard
    from odomgym.data import resolve_data

    _check_methods(args.methods)
    if args.out:
        _check_output(args.out, option="--out")
    board = run_leaderboard(
        resolve_data(args.data), methods=args.methods, conventions=args.conventions
    )
    text = format_leaderboard(board)
    if args.out:
        atomic_write_text(Path(args.out), text + "\n")
    if args.json:
        print(to_json(board.as_dict()))
    else:
        print(text)
    _report_written(args, [args.out] if args.out else [])
    return 0


def _all_finite(value: object) -> bool:
    """Whether every number inside ``value`` (nested dicts, lists, arrays) is finite."""
    if isinstance(value, dict):
        return all(_all_finite(v) for v in value.values())
    if isinstance(value, list | tuple):
        return all(_all_finite(v) for v in value)
    if isinstance(value, np.ndarray):
        return value.dtype.kind not in "fc" or bool(np.all(np.isfinite(value)))
    if isinstance(value, float | np.floating):
        return bool(np.isfinite(value))
    return True


def _command_covariance(args: argparse.Namespace) -> int:
    from odomgym.montecarlo import covariance_report, format_report

    too_large = SpecError(
        "the distances, wheelbase or noise constants are too large for the closed forms (the "
        "covariance overflows a double); use metres and m^½ of a real robot",
        field="covariance",
    )
    try:
        with np.errstate(over="raise", invalid="raise"):
            report = covariance_report(
                args.left,
                args.right,
                args.wheelbase,
                args.kl,
                args.kr,
                init_std=tuple(args.init_std),
                montecarlo_runs=args.montecarlo,
                partitions=args.partitions,
                rng=np.random.default_rng(args.seed),
            )
    except (ArithmeticError, FloatingPointError):
        raise too_large from None
    except ValueError as exc:
        raise SpecError(str(exc)) from None
    if not _all_finite(report):
        raise too_large
    print(to_json(report) if args.json else format_report(report))
    return 0


def _command_fit_noise(args: argparse.Namespace) -> int:
    from odomgym.data import resolve_data
    from odomgym.noise_report import fit_noise_report, format_noise_report

    _check_plot_path(args.plot)
    data = tuple(resolve_data(folder) for folder in args.data or ())
    try:
        report = fit_noise_report(
            robot=args.robot,
            k=args.k,
            runs=args.runs,
            distance=args.distance,
            seed=args.seed,
            data=data,
            pool=args.pool,
            interval=args.interval,
            plot=args.plot,
        )
    except ValueError as exc:
        raise SpecError(str(exc)) from None
    print(to_json(report) if args.json else format_noise_report(report))
    _report_written(args, report.get("plots", []))
    return 0


def _fraction(text: str) -> float:
    """An argparse type: a number strictly between 0 and 1."""
    value = _finite(text)
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"must lie strictly between 0 and 1, got {text!r}")
    return value


def _command_diagnose(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from odomgym.data.logs import read_log
    from odomgym.data.samples import resolve_data
    from odomgym.diagnose.report import format_markdown, report_json, write_outputs
    from odomgym.diagnose.workflow import DiagnoseConfig, FitJournal, diagnose

    data = resolve_data(args.data, field="DATA")
    robot = load_robot(args.robot) if args.robot else None
    config = DiagnoseConfig(
        holdout=args.holdout,
        seed=args.seed,
        max_rounds=args.max_rounds,
        candidates=tuple(args.candidates) if args.candidates else None,
        jobs=args.jobs or os.cpu_count() or 1,
        discover=not args.no_discover,
        session_frames={"auto": None, "on": True, "off": False}[args.session_frames],
    )
    out = Path(args.out) if args.out else Path(f"{data.stem or 'data'}-diagnose")
    _check_output(out, option="--out", folder=True, swap=True)
    runs, nominal = read_log(
        data,
        robot=robot,
        format=args.format,
        pose_topic=args.pose_topic,
        joint_topic=args.joint_topic,
        encoder_topic=args.encoder_topic,
        left_joint=args.left_joint,
        right_joint=args.right_joint,
    )
    model = robot if robot is not None else nominal
    if model is None:
        raise SpecError("give the robot model with --robot robot.toml", field="robot")
    show_bar = not args.json and sys.stderr.isatty()
    bar = tqdm(total=100, desc="diagnose", disable=not show_bar, file=sys.stderr, leave=False)

    def progress(stage: str, fraction: float) -> None:
        bar.set_description(stage)
        bar.n = int(100 * fraction)
        bar.refresh()

    # Every finished candidate fit is kept beside the output (which is replaced whole), so an
    # interrupted diagnosis resumes with --resume; it is removed once the outputs are written.
    journal = FitJournal(out.parent / f"{out.name}.journal", resume=args.resume)
    try:
        diagnosis = diagnose(runs, model, config, progress=progress, journal=journal)
    except ValueError as exc:
        if isinstance(exc, SpecError):
            raise
        raise SpecError(str(exc)) from None
    finally:
        bar.close()
    if journal.reused:
        _say(args, f"resumed: {journal.reused} candidate fits taken from {journal.folder}")
    written = write_outputs(diagnosis, out, str(data))
    journal.clear()
    if args.json:
        print(report_json(diagnosis))
    else:
        print(format_markdown(diagnosis, str(data)))
    _report_written(args, written)
    return 0


def _add_run_outputs(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--json", action="store_true", help="print JSON lines (one per run) instead of a table"
    )
    parser.add_argument(
        "--log", help="also save the runs in odomgym's native CSV format here (for diagnose)"
    )


def _add_run_parsers(commands: Any) -> None:
    run = commands.add_parser(
        "run",
        help="drive squares or straight runs in simulation and report return errors",
        description="Drive a simulated robot with the reference driver and report the return "
        "errors (true - odometry end pose, start frame).",
    )
    routes = run.add_subparsers(
        dest="path",
        required=True,
        metavar="ROUTE",
        help="what to drive: square, straight, clapper-straight or clapper-rectangle",
    )
    square = routes.add_parser(
        "square",
        help="UMBmark squares (Borenstein & Feng 1994): return errors and E_max,syst",
        description="Drive UMBmark squares cw and/or ccw; with both directions, report the "
        "centres of gravity and E_max,syst (Borenstein & Feng 1994, Eq. 3.3).",
    )
    _add_robot_arguments(square)
    square.add_argument(
        "--direction",
        choices=["cw", "ccw", "both"],
        default="both",
        help="square direction (default both: cw runs, then ccw)",
    )
    square.add_argument("--runs", type=_count, default=5, help="runs per direction (default 5)")
    square.add_argument("--side", type=_positive, default=4.0, help="square side L [m] (default 4)")
    square.add_argument("--plot", help="write the return-error scatter here (.png, .pdf, .svg)")
    _add_run_outputs(square)
    square.set_defaults(handler=_command_run)

    straight = routes.add_parser(
        "straight",
        help="straight runs (optionally there and back) and their end errors",
        description="Drive straight runs (Borenstein 1995, §6.1, drove 18 m over cables) and "
        "report each run's end error.",
    )
    _add_robot_arguments(straight)
    straight.add_argument("--runs", type=_count, default=5, help="runs (default 5)")
    straight.add_argument(
        "--distance", type=_positive, default=10.0, help="straight run length [m] (default 10)"
    )
    straight.add_argument(
        "--return-trip",
        action="store_true",
        help="turn on the spot at the end and drive back to the start",
    )
    _add_run_outputs(straight)
    straight.set_defaults(handler=_command_run)
    _add_clapper_parsers(routes)


def _command_clapper(args: argparse.Namespace) -> int:
    from odomgym.clapper import VehicleDriver
    from odomgym.clapper_runs import (
        PAPER_CONDITIONS,
        SONAR,
        Condition,
        format_clapper_runs,
        plot_clapper_runs,
        run_clapper,
        summarize,
    )
    from odomgym.envs.clapper import ipec_estimator
    from odomgym.vehicle import PAPER_ERRORS, load_vehicle

    _check_plot_path(args.plot)
    spec = load_vehicle(args.vehicle)
    if args.errors == "paper":
        spec = dataclasses.replace(spec, **PAPER_ERRORS)  # type: ignore[arg-type]
    floor: FloorSpec = load_floor(args.floor)
    experiment = "straight" if args.path == "clapper-straight" else "rectangle"
    custom = args.bumps is not None or args.ipec is not None
    if custom:
        bumps = 10 if args.bumps is None else args.bumps
        modes = (False, True) if args.ipec is None else (bool(args.ipec),)
        conditions = [Condition("with IPEC" if m else "without IPEC", m, bumps) for m in modes]
    else:
        conditions = list(PAPER_CONDITIONS[experiment])
    direction = getattr(args, "direction", "-")  # the straight experiment has none
    directions = ("cw", "ccw") if direction == "both" else (direction,)
    side = getattr(args, "side", "right")
    sides = ("right", "left") if side == "both" else (side,)
    runs_each = args.runs if args.runs is not None else (3 if experiment == "straight" else 10)
    bar = _progress_bar(not args.json and sys.stderr.isatty())

    def progress(done: int, total: int) -> None:
        bar.n = int(100 * done / total)
        bar.refresh()

    try:
        runs = run_clapper(
            spec,
            floor,
            experiment,  # type: ignore[arg-type]
            conditions=conditions,
            directions=directions,
            sides=sides,
            runs=runs_each,
            seed=args.seed,
            ipec=ipec_estimator(args.ipec_config, spec.rotary_resolution),
            driver=lambda: VehicleDriver(steering=args.steering),
            sonar=SONAR if args.errors == "paper" else None,
            progress=progress,
        )
    finally:
        bar.close()
    settings = (
        f"vehicle {spec.name}: trucks {spec.truck_a.name}/{spec.truck_b.name}, link "
        f"{spec.link_length:g} m; floor {floor.name}; {experiment}; IPEC {args.ipec_config}; "
        f"steering {args.steering}; error sources {args.errors}; {runs_each} runs per "
        f"condition{' and direction' if len(directions) > 1 else ''}, seed {args.seed}"
    )
    if args.json:
        for run in runs:
            print(to_json(run.record()))
        print(to_json({"settings": settings, "summary": summarize(runs)}))
    else:
        print(settings)
        print(
            "conditions: "
            + "; ".join(
                f"{c.label}: IPEC {'on' if c.ipec else 'off'}, {c.bumps} cables" for c in conditions
            )
        )
        print("return errors (true - estimated; vehicle = midpoint of the trucks, link heading)")
        print(format_clapper_runs(runs))
    written: list[str] = []
    if args.plot:
        title = f"CLAPPER {experiment}: return errors, {floor.name} floor"
        plot_clapper_runs(Path(args.plot), runs, title)
        written.append(args.plot)
    _report_written(args, written)
    return 0


def _add_clapper_parsers(routes: Any) -> None:
    from odomgym.clapper import CLAPPER_FLOOR

    for name, what in (
        (
            "clapper-straight",
            "18 m straight out and back backwards, cables on the return leg "
            "under the right-side wheels (Borenstein 1995, §6.1)",
        ),
        (
            "clapper-rectangle",
            "the 7x4 m rectangle with smooth turns, cables under one side (Borenstein 1995, §6.2)",
        ),
    ):
        parser = routes.add_parser(
            name,
            help=f"the CLAPPER two-truck vehicle with/without IPEC: {what}",
            description=f"Drive the CLAPPER (two trucks, compliant linkage) {what}, with and "
            "without internal position error correction (IPEC), and report the return errors "
            "and the average absolute orientation errors.",
        )
        parser.add_argument(
            "--vehicle",
            default="clapper",
            help="vehicle preset (clapper, clapper-uncalibrated, trailer) or vehicle .toml file",
        )
        parser.add_argument("--floor", default=CLAPPER_FLOOR, help=_floor_help(CLAPPER_FLOOR))
        parser.add_argument(
            "--bumps",
            type=_bumps,
            default=None,
            help="10 mm cables to cross, 0 to 1000, in every run (default: the paper's "
            "conditions — straight: a/b/c/d with 0/10/0/20 cables; rectangle: 10)",
        )
        parser.add_argument(
            "--ipec",
            action=argparse.BooleanOptionalAction,
            default=None,
            help="only runs with (--ipec) or without (--no-ipec) IPEC (default: the paper's "
            "conditions)",
        )
        parser.add_argument(
            "--ipec-config",
            choices=["recommended", "paper", "gated", "heading-only"],
            default="recommended",
            help="IPEC configuration (docs/clapper.md): recommended (default: corrections "
            "consistent with the 10-bit readings), paper (Eqs. 9-16 as printed), gated (Eq. 15 "
            "only for one count or more in straight travel), heading-only (without Eq. 15)",
        )
        parser.add_argument(
            "--steering",
            choices=["psi", "pose"],
            default="psi",
            help="psi (default): the follower truck holds its rotary encoder at the path's "
            "angle (the paper's §5.2); pose: each truck tracks its own estimate",
        )
        parser.add_argument(
            "--errors",
            choices=["none", "paper"],
            default="none",
            help="error sources: none (default) or paper (link bias 2 mm, jitter 0.1°, "
            "eccentricity 1 mm, read skew 4 ms, and the return pose measured to ±2 mm, ±0.25° "
            "as the paper's sonars did; docs/clapper.md)",
        )
        if name == "clapper-rectangle":
            parser.add_argument(
                "--direction",
                choices=["cw", "ccw", "both"],
                default="both",
                help="driving direction (default both)",
            )
            parser.add_argument(
                "--side",
                choices=["right", "left", "both"],
                default="both",
                help="cables under the right or left wheels (default both: alternating runs)",
            )
        parser.add_argument(
            "--runs",
            type=_count,
            default=None,
            help="runs per condition (and direction) (default: the paper's — 3 on the "
            "straight, 10 per direction on the rectangle)",
        )
        parser.add_argument("--seed", type=_seed, default=0, help="seed of the floor noise")
        parser.add_argument(
            "--json", action="store_true", help="print JSON lines (one per run, then a summary)"
        )
        parser.add_argument(
            "--plot", help="write the return-error figure (like the paper's Figs. 8/10) here"
        )
        parser.set_defaults(handler=_command_clapper)


def _command_train(args: argparse.Namespace) -> int:
    import importlib.util

    if importlib.util.find_spec("stable_baselines3") is None:
        raise SpecError(
            "training needs stable-baselines3 and torch: pip install 'odomgym[rl]'",
            field="train",
        )
    _check_output(args.out, option="--out", folder=True)
    from odomgym.baselines.selfcal_train import (
        CHECKPOINT_EVERY,
        EVAL_SEEDS,
        load_hyperparams,
        train,
    )

    params = load_hyperparams(args.algo, args.hyperparams)  # one-line errors before any work
    steps = args.steps or int(params.get("n_timesteps", 100_000))
    envs = args.envs or int(params.get("n_envs", 8))
    command = (
        f"odomgym train selfcal --algo {args.algo} --steps {steps} --envs {envs} "
        f"--workers {args.workers} --seed {args.seed} --out {args.out}"
        + (f" --hyperparams {args.hyperparams}" if args.hyperparams else "")
    )
    result = train(
        algo=args.algo,
        steps=steps,
        envs=envs,
        workers=args.workers,
        seed=args.seed,
        out=args.out,
        hyperparams=args.hyperparams,
        progress=not args.json and sys.stderr.isatty(),
        command=command,
        checkpoint_every=args.checkpoint_every or CHECKPOINT_EVERY,
        resume=args.resume,
    )
    summary = {
        "algo": args.algo,
        "steps": result.steps,
        "wall_time_s": round(result.wall_time_s, 1),
        "evaluation": result.evaluation,
        "policy": str(result.policy_file),
        "model": str(result.model_file),
    }
    if args.json:
        print(to_json(summary))
    else:
        ev = result.evaluation
        print(
            f"trained {args.algo} for {result.steps} steps in {result.wall_time_s / 60:.1f} min; "
            f"on {len(EVAL_SEEDS)} held-out sessions: mean reward "
            f"{ev['reward_mean']:.2f}, mean ln(E_max before/after) "
            f"{ev['log_improvement_mean']:.2f}, {ev['runs_mean']:.1f} runs"
        )
    _say(args, f"use it: odomgym calibrate selfcal --policy {result.policy_file}")
    _report_written(
        args,
        [
            str(result.policy_file),
            str(result.model_file),
            str(Path(args.out) / "policy.json"),
            str(Path(args.out) / "progress.csv"),
            str(Path(args.out) / "learning_curve.png"),
        ],
    )
    return 0


def _add_train_parser(commands: Any) -> None:
    from odomgym.baselines.selfcal import MENU

    train = commands.add_parser(
        "train",
        help="train a self-calibration policy (needs the rl extra)",
        description="Train a policy in SelfCalibration-v0 with stable-baselines3: each step it "
        f"picks one of {len(MENU) - 1} experiments or stops; the reward is the validated "
        "improvement of the final corrections. Writes the SB3 model, the numpy policy that "
        "odomgym calibrate selfcal --policy takes, progress.csv and a learning-curve plot.",
    )
    train.add_argument("what", choices=["selfcal"], help="what to train: selfcal")
    train.add_argument(
        "--algo",
        choices=["ppo", "a2c", "dqn"],
        default="ppo",
        help="SB3 algorithm (Discrete actions: ppo, a2c, dqn; default ppo)",
    )
    train.add_argument(
        "--steps", type=_count, help="environment steps (default: the data file's n_timesteps)"
    )
    train.add_argument(
        "--envs",
        type=_processes,
        help="sessions stepped together (default: the data file's n_envs)",
    )
    train.add_argument(
        "--workers", type=_processes, default=2, help="processes simulating them (default 2)"
    )
    train.add_argument(
        "--seed", type=_seed32, default=0, help="random seed, 0 to 2**32 - 1 (default 0)"
    )
    train.add_argument("--out", default="runs/selfcal", help="output folder (default runs/selfcal)")
    train.add_argument(
        "--hyperparams",
        help='a TOML file with [<algo>."SelfCalibration-v0"] tables (default: the shipped '
        "odomgym/data/hyperparams/selfcal.toml)",
    )
    train.add_argument(
        "--checkpoint-every",
        type=_count,
        metavar="STEPS",
        help="write a checkpoint (OUT/checkpoint.zip) every STEPS environment steps "
        "(default 10000, about two minutes)",
    )
    train.add_argument(
        "--resume",
        action="store_true",
        help="go on from the checkpoint an interrupted training left in --out (same --algo, "
        "--envs, --seed and --hyperparams) to --steps in all",
    )
    train.add_argument("--json", action="store_true", help="one JSON object instead of text")
    train.set_defaults(handler=_command_train)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every command (every option has a help text: tested)."""
    from odomgym.baselines.benchmark import BENCH_FLOORS, Backend

    parser = argparse.ArgumentParser(
        prog="odomgym",
        description="Wheel-odometry experiments, calibration and benchmarks in simulation and "
        "on measured logs.",
    )
    from odomgym import __version__

    parser.add_argument("--version", action="version", version=f"odomgym {__version__}")
    commands = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", help="what to do (COMMAND --help)"
    )
    _add_run_parsers(commands)

    calibrate = commands.add_parser(
        "calibrate",
        help="calibrate a simulated robot (or a measured session) and validate the result",
        description="Run a calibration method's experiments in simulation on a robot with hidden "
        "systematic errors, then compare E_max,syst on fresh squares before and after; or, with "
        "--data, calibrate from a recorded OptiOdom session and report its evaluation measures.",
    )
    calibrate.add_argument("method", help="calibration method, e.g. umbmark, jung_chung")
    _add_robot_arguments(calibrate, calibration=False)
    calibrate.add_argument(
        "--side", type=_positive, default=4.0, help="square side L [m] (default 4)"
    )
    calibrate.add_argument(
        "--runs", type=_count, default=5, help="squares per direction (default 5)"
    )
    calibrate.add_argument(
        "--data",
        help="a recorded OptiOdom session folder instead of simulation, or a shipped session "
        "(optiodom:square/230620202042)",
    )
    calibrate.add_argument(
        "--conventions",
        choices=["optiodom"],
        default=None,
        help="optiodom: reproduce the published OptiOdom conventions (with --data)",
    )
    calibrate.add_argument(
        "--policy",
        help="selfcal only: learned (the shipped policy, default), scripted (alternate 4 m "
        "squares) or a policy .npz file written by odomgym train selfcal",
    )
    calibrate.add_argument("--save", help="write the calibration as TOML here")
    calibrate.add_argument(
        "--export", choices=["ros2"], help="also export the calibration (ros2: diff_drive YAML)"
    )
    calibrate.add_argument(
        "--export-path", help="where --export writes (default diff_drive_controller.yaml)"
    )
    calibrate.add_argument("--json", action="store_true", help="one JSON object instead of a table")
    calibrate.add_argument(
        "--plot", help="write the before/after return-error scatter here (.png, .pdf, .svg)"
    )
    calibrate.set_defaults(handler=_command_calibrate)

    bench = commands.add_parser(
        "bench",
        help="benchmark calibrators on a simulated robot population",
        description="Sample robots with hidden systematic errors, give every calibrator the same "
        "budget on the same robots and floors, validate on fresh squares, report.",
    )
    bench.add_argument("what", choices=["calibrators"], help="what to benchmark: calibrators")
    bench.add_argument("--robots", type=_count, default=100, help="population size (default 100)")
    bench.add_argument(
        "--floor",
        nargs="+",
        metavar="FLOOR",
        default=list(BENCH_FLOORS),
        help="benchmark floors (default: all): "
        + "; ".join(f"{name}: {floor.description}" for name, floor in BENCH_FLOORS.items()),
    )
    bench.add_argument(
        "--methods",
        nargs="+",
        help="calibrators (default: all, selfcal included: its shipped policy runs in numpy)",
    )
    bench.add_argument(
        "--budget",
        type=_count,
        nargs="+",
        default=[16],
        help="runs per calibration (16); several values compare budgets, e.g. --budget 16 4",
    )
    bench.add_argument("--jobs", type=_processes, help="worker processes (default: all cores)")
    bench.add_argument(
        "--backend",
        choices=[b.value for b in Backend],
        default=Backend.LOCAL.value,
        help="local: worker processes on this machine (default); ray: Ray tasks "
        "(pip install 'odomgym[distributed]')",
    )
    bench.add_argument("--seed", type=_seed, default=0, help="master random seed >= 0 (default 0)")
    bench.add_argument(
        "--out", default="bench-out", help="output folder, created if missing (default bench-out)"
    )
    bench.add_argument("--json", action="store_true", help="print the summary as JSON")
    bench.add_argument(
        "--resume",
        action="store_true",
        help=f"continue an interrupted run: robots recorded in OUT/{JOURNAL_NAME} are not run "
        "again (the same options are required); the tables equal an uninterrupted run's",
    )
    bench.add_argument(
        "--chunk",
        type=_count,
        help="robots per unit of work, recorded as each finishes (default: up to 16)",
    )
    bench.set_defaults(handler=_command_bench)

    _add_train_parser(commands)

    board = commands.add_parser(
        "leaderboard",
        help="real-data leaderboard: calibrate on one recorded session, evaluate on the others",
        description="Calibrate every method on every recorded session that holds the runs it "
        "needs, evaluate it on all other sessions (OptiOdom measures), and compare the "
        "in-session results with the published ones (Sousa et al. 2022).",
    )
    board.add_argument(
        "--data",
        required=True,
        help="folder of OptiOdom sessions, or optiodom: for the shipped ones",
    )
    board.add_argument("--methods", nargs="+", help="calibrators (default: all)")
    board.add_argument(
        "--conventions",
        choices=["optiodom"],
        default=None,
        help="optiodom: run UMBmark and Jung & Chung with the OptiOdom authors' conventions, "
        "so that the in-session column reproduces their published results",
    )
    board.add_argument("--out", help="also write the Markdown tables to this file")
    board.add_argument("--json", action="store_true", help="print one JSON object")
    board.set_defaults(handler=_command_leaderboard)

    cov = commands.add_parser(
        "covariance",
        help="Chong & Kleeman odometry covariance in closed form (and by Monte Carlo)",
        description="Mean, standard deviations and correlations of the end pose after wheel "
        "travels L (left) and R (right) [m] with wheel noise k [m^0.5] (Chong & Kleeman 1997), "
        "laid out like the paper's Tables 1-7.",
    )
    cov.add_argument("--left", type=_finite, required=True, help="left wheel travel L [m]")
    cov.add_argument("--right", type=_finite, required=True, help="right wheel travel R [m]")
    cov.add_argument("--wheelbase", type=_positive, required=True, help="wheelbase B [m]")
    cov.add_argument("--kl", type=_nonnegative, required=True, help="k_L [m^0.5]")
    cov.add_argument("--kr", type=_nonnegative, required=True, help="k_R [m^0.5]")
    cov.add_argument(
        "--init-std",
        nargs=3,
        type=_nonnegative,
        default=[0.0, 0.0, 0.0],
        metavar=("SX", "SY", "STH"),
        help="initial pose standard deviations [m, m, rad]",
    )
    cov.add_argument(
        "--montecarlo",
        type=_seed,
        default=0,
        metavar="RUNS",
        help="Monte Carlo runs beside the closed form (default 0: none)",
    )
    cov.add_argument(
        "--partitions", type=_count, default=1000, help="path partitions (default 1000)"
    )
    cov.add_argument("--seed", type=_seed, default=0, help="Monte Carlo seed >= 0 (default 0)")
    cov.add_argument("--json", action="store_true", help="print one JSON object")
    cov.set_defaults(handler=_command_covariance)

    noise = commands.add_parser(
        "fit-noise",
        help="estimate the wheel noise constants k_L, k_R from repeated runs "
        "(Chong & Kleeman 1997, §6.3)",
        description="Without --data: simulate N runs of D m forward and back on a rough floor of "
        "known k and fit it back. With --data: fit recorded OptiOdom sessions.",
    )
    noise.add_argument(
        "--robot",
        default="labmate",
        help=f"robot preset for the simulation ({', '.join(PRESETS)}; default labmate)",
    )
    noise.add_argument(
        "--k", type=_nonnegative, default=0.0005, help="true k [m^0.5] to simulate (0.0005)"
    )
    noise.add_argument("--runs", type=_count, default=60, help="simulated runs (default 60)")
    noise.add_argument(
        "--distance", type=_positive, default=10.0, help="out-and-back length [m] (default 10)"
    )
    noise.add_argument("--seed", type=_seed, default=0, help="random seed >= 0 (default 0)")
    noise.add_argument(
        "--data",
        nargs="+",
        help="OptiOdom session folders (or their parents), or shipped data (optiodom:ivanjko)",
    )
    noise.add_argument(
        "--pool",
        choices=["all", "path-type", "kind", "session"],
        default="kind",
        help="which recorded runs are fitted together (default: by run kind)",
    )
    noise.add_argument(
        "--interval",
        choices=["profile", "bootstrap"],
        default="profile",
        help="confidence intervals by profile likelihood (default) or bootstrap",
    )
    noise.add_argument(
        "--plot",
        help="write the error scatters with 95 %% ellipses here (.png; one file per fitted "
        "group, suffixed by its name, when there are several)",
    )
    noise.add_argument("--json", action="store_true", help="print one JSON object")
    noise.set_defaults(handler=_command_fit_noise)

    diag = commands.add_parser(
        "diagnose",
        help="find where a robot model and measured logs disagree and which effect is missing",
        description="Replay measured runs through the robot model, localise the disagreement, "
        "fit every catalogue effect, name the one the data support (or say the data cannot tell "
        "them apart), discover terms outside the catalogue by sparse regression when structure "
        "is left, name noise effects last, write the updated robot TOML, and report the gap "
        "before and after and whether structure remains on held-out runs.",
    )
    diag.add_argument(
        "data",
        help="a native CSV, an OptiOdom folder, shipped data (optiodom:square) or a ROS 2 bag",
    )
    diag.add_argument("--robot", help="robot .toml (or preset) of the model to test")
    diag.add_argument(
        "--format",
        choices=["native", "optiodom", "rosbag"],
        help="log format (default: detected from DATA)",
    )
    diag.add_argument("--out", help="output folder, replaced whole (default: <DATA name>-diagnose)")
    diag.add_argument(
        "--holdout", type=_fraction, default=0.3, help="share of runs held out (default 0.3)"
    )
    diag.add_argument("--seed", type=_seed, default=0, help="random seed >= 0 (default 0)")
    diag.add_argument(
        "--max-rounds", type=_count, default=8, help="most rounds of adding an effect (8)"
    )
    diag.add_argument("--candidates", nargs="+", help="effects to consider (default: all)")
    diag.add_argument(
        "--no-discover",
        action="store_true",
        help="catalogue effects only: no sparse regression over the error grammar when the "
        "catalogue leaves structure",
    )
    diag.add_argument(
        "--session-frames",
        choices=["auto", "on", "off"],
        default="auto",
        help="fit a tracked-point offset and yaw misalignment per session (auto: when the runs "
        "come from two or more sessions)",
    )
    diag.add_argument("--jobs", type=_processes, help="worker processes (default: all cores)")
    diag.add_argument(
        "--resume",
        action="store_true",
        help="take the candidate fits an interrupted diagnose stored in OUT.journal (the "
        "result is the same as an uninterrupted run's); without it the journal starts afresh",
    )
    diag.add_argument("--pose-topic", help="ROS 2 bags: ground-truth pose topic")
    diag.add_argument("--joint-topic", help="ROS 2 bags: sensor_msgs/JointState topic")
    diag.add_argument("--encoder-topic", help="ROS 2 bags: [left, right] counts topic")
    diag.add_argument(
        "--left-joint",
        default="left_wheel_joint",
        help="ROS 2 bags: the left wheel's joint name (default left_wheel_joint)",
    )
    diag.add_argument(
        "--right-joint",
        default="right_wheel_joint",
        help="ROS 2 bags: the right wheel's joint name (default right_wheel_joint)",
    )
    diag.add_argument("--json", action="store_true", help="print report.json")
    diag.set_defaults(handler=_command_diagnose)
    return parser


JOURNAL_NAME = "journal.jsonl"


def _on_signal(signum: int, frame: object) -> None:
    import signal

    if signum == signal.SIGINT:
        interrupt.stop(130, "interrupted")
    interrupt.stop(143, "stopped by SIGTERM")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``odomgym`` command."""
    import signal
    import threading

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
        late = interrupt.pending()
        if late is None:
            return code
        raise late  # the signal's own raise was swallowed after the last check
    except Interrupted as exc:
        print(f"odomgym: {exc}", file=sys.stderr)
        return exc.code
    except KeyboardInterrupt:
        print("odomgym: interrupted", file=sys.stderr)
        return 130
    except SpecError as exc:
        print(f"odomgym: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        # Checked up front (_check_output); what is left is the machine's (a full disk).
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"odomgym: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1
    finally:
        interrupt.reset()
        for number, handler_before in previous.items():
            signal.signal(number, handler_before)


if __name__ == "__main__":
    raise SystemExit(main())

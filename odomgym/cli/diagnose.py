"""``odomgym diagnose DATA --robot R``: where a robot model and measured logs disagree, which
catalogue effect is missing, and how much of the gap it closes; with ``--loso``, whether the
answer holds with each session left out in turn (:mod:`odomgym.diagnose.loso`)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING

from odomgym.cli._common import (
    Progress,
    Reporter,
    add_backend_arguments,
    check_backend,
    check_output,
    count,
    fraction,
    positive,
    processes,
    seed,
)
from odomgym.errors import SpecError
from odomgym.robot import RobotSpec, load_robot

if TYPE_CHECKING:
    from collections.abc import Callable

    from odomgym.cli._common import Commands
    from odomgym.diagnose.config import DiagnoseConfig
    from odomgym.odometry.runs import Run


def register(commands: Commands) -> None:
    """Add ``diagnose``."""
    parser = commands.add_parser(
        "diagnose",
        help="find where a robot model and measured logs disagree and which effect is missing",
        description="Replay measured runs through the robot model, localise the disagreement, "
        "fit every catalogue effect, name the one the data support (or say the data cannot tell "
        "them apart), discover terms outside the catalogue by sparse regression when structure "
        "is left, name noise effects last, write the updated robot TOML, and report the gap "
        "before and after and whether structure remains on held-out runs.",
    )
    parser.add_argument(
        "data",
        help="a native CSV, an OptiOdom folder, shipped data (optiodom:square) or a ROS 2 bag",
    )
    parser.add_argument(
        "--robot",
        help="robot .toml (or preset) of the model to test (default: an OptiOdom session's "
        "own, or the robot.toml of a folder of native logs)",
    )
    parser.add_argument(
        "--format",
        choices=["native", "optiodom", "rosbag"],
        help="log format (default: detected from DATA)",
    )
    parser.add_argument(
        "--out",
        help="output folder, replaced whole (default: <DATA name>-diagnose); with --loso the "
        "folder of fold files, kept and added to (default: <DATA name>-loso)",
    )
    parser.add_argument(
        "--holdout", type=fraction, default=0.3, help="share of runs held out (default 0.3)"
    )
    parser.add_argument("--seed", type=seed, default=0, help="random seed >= 0 (default 0)")
    parser.add_argument(
        "--max-rounds", type=count, default=8, help="most rounds of adding an effect (8)"
    )
    parser.add_argument("--candidates", nargs="+", help="effects to consider (default: all)")
    parser.add_argument(
        "--no-discover",
        action="store_true",
        help="catalogue effects only: no sparse regression over the error grammar when the "
        "catalogue leaves structure",
    )
    parser.add_argument(
        "--gate-order",
        choices=["catalogue-first", "joint"],
        default="catalogue-first",
        help="how the open-loop gate eliminates proposals: the catalogue effects alone, then "
        "the discovered terms on the effects kept (catalogue-first, the default), or effects "
        "and terms together (joint, the order before; docs/diagnose.md)",
    )
    parser.add_argument(
        "--session-frames",
        choices=["auto", "on", "off"],
        default="auto",
        help="fit a tracked-point offset and yaw misalignment per session (auto: when the runs "
        "come from two or more sessions)",
    )
    parser.add_argument(
        "--no-time-offset",
        action="store_true",
        help="do not fit a time offset between the encoder log and the ground truth per session",
    )
    parser.add_argument(
        "--max-time-offset",
        type=positive,
        default=1.0,
        help="largest time offset searched, seconds (default 1.0)",
    )
    parser.add_argument(
        "--max-obstacle",
        type=positive,
        default=0.02,
        help="largest obstacle the floor may hold, metres: bounds what named floor bumps may "
        "do (default 0.02)",
    )
    parser.add_argument(
        "--max-bump-rate",
        type=positive,
        default=1.0,
        help="most obstacle crossings per metre of a wheel's travel the floor may hold: bounds "
        "named floor bumps (default 1.0)",
    )
    parser.add_argument(
        "--no-baseline",
        action="store_true",
        help="skip the baseline calibration (trajectory optimisation of b, D_R, D_L on the fit "
        "runs) the held-out comparison reports beside the diagnosed model",
    )
    parser.add_argument("--jobs", type=processes, help="worker processes (default: all cores)")
    add_backend_arguments(parser, "candidate fits (with --loso: the folds)")
    parser.add_argument(
        "--resume",
        action="store_true",
        help="take the candidate fits an interrupted diagnose stored in OUT.journal (the "
        "result is the same as an uninterrupted run's); without it the journal starts afresh "
        "(--loso always keeps the fold files in OUT)",
    )
    add_bag_arguments(parser)
    parser.add_argument(
        "--loso",
        action="store_true",
        help="leave one session out: for every session, diagnose the others and predict it "
        "open loop (the model as given, the diagnosed model, the baseline); writes "
        "OUT/fold-<session>.json as each fold ends, keeps the fold files already in OUT "
        "(resume), and prints the table of the folds (docs/diagnose.md)",
    )
    parser.add_argument(
        "--shard",
        type=shard,
        metavar="K/N",
        help="with --loso: diagnose only folds K, K+N, ... (N processes with --jobs 1 on N "
        "cores, or machines sharing OUT; then --table-only gathers their files)",
    )
    parser.add_argument(
        "--sessions",
        nargs="+",
        metavar="SESSION",
        help="with --loso: leave out only these sessions (default: every one)",
    )
    parser.add_argument(
        "--table-only",
        action="store_true",
        help="with --loso: print the table of the folds already in OUT, diagnosing none "
        "(the missing ones are listed)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print report.json (with --loso: the folds and their summary)",
    )
    parser.set_defaults(handler=run)


def shard(text: str) -> tuple[int, int]:
    """An argparse type: ``K/N`` with 1 <= K <= N (:func:`odomgym.diagnose.loso.parse_shard`)."""
    from odomgym.diagnose.loso import parse_shard

    try:
        return parse_shard(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def run(args: argparse.Namespace) -> int:
    """Read the logs, diagnose (resuming from the journal with ``--resume``), replace ``--out``
    with the report, then print it (Markdown, or report.json) and the files written; with
    ``--loso``, the leave-one-session-out folds instead (:func:`run_loso_command`)."""
    from odomgym.baselines.trajectory import TrajectoryBaseline
    from odomgym.data.samples import resolve_data
    from odomgym.diagnose.report import (
        check_replaceable,
        format_markdown,
        report_json,
        write_outputs,
    )
    from odomgym.diagnose.workflow import FitJournal, diagnose
    from odomgym.distributed import on_ray

    report = Reporter.of(args)
    check_backend(args)
    if not args.loso:
        for given, option in (
            (args.shard is not None, "--shard"),
            (bool(args.sessions), "--sessions"),
            (args.table_only, "--table-only"),
        ):
            if given:
                raise SpecError(f"{option} needs --loso", field=option[2:].replace("-", "_"))
    data = resolve_data(args.data, field="DATA")
    robot = load_robot(args.robot) if args.robot else None
    config = diagnose_config(args)
    if args.loso:
        return run_loso_command(args, report, data, robot, config)
    out = Path(args.out) if args.out else Path(f"{data.stem or 'data'}-diagnose")
    check_output(out, option="--out", folder=True, swap=True)
    check_replaceable(out, option="--out")  # it is replaced whole: nothing else may be lost
    runs, model = read_runs(args, data, robot)
    say_set_aside(runs, model, report)
    baseline = None if args.no_baseline else TrajectoryBaseline()
    # Every finished candidate fit is kept beside the output (which is replaced whole), so an
    # interrupted diagnosis resumes with --resume; it is removed once the outputs are written.
    journal = FitJournal(out.parent / f"{out.name}.journal", resume=args.resume)
    with (
        on_ray(args.backend, args.ray_address, config.jobs),
        Progress(report, "diagnose", leave=False) as bar,
    ):
        diagnosis = diagnose(
            runs, model, config, baseline=baseline, progress=bar.stage, journal=journal
        )
    if journal.reused:
        report.status(f"resumed: {journal.reused} candidate fits taken from {journal.folder}")
    written = write_outputs(diagnosis, out, str(data))
    journal.clear()
    if report.json:
        report.text(report_json(diagnosis))  # report.json's text, already JSON
    else:
        report.text(format_markdown(diagnosis, str(data)))
    report.wrote(written)
    return 0


def diagnose_config(args: argparse.Namespace) -> DiagnoseConfig:
    """The diagnosis options of the command line (a ``--loso`` fold's diagnosis takes the
    same)."""
    from odomgym.diagnose.workflow import DiagnoseConfig

    return DiagnoseConfig(
        holdout=args.holdout,
        seed=args.seed,
        max_rounds=args.max_rounds,
        candidates=tuple(args.candidates) if args.candidates else None,
        jobs=args.jobs or os.cpu_count() or 1,
        discover=not args.no_discover,
        session_frames={"auto": None, "on": True, "off": False}[args.session_frames],
        time_offset=not args.no_time_offset,
        max_time_offset=args.max_time_offset,
        max_obstacle=args.max_obstacle,
        max_bump_rate=args.max_bump_rate,
        gate_order=args.gate_order.replace("-", " "),
    )


_JOINTS = {"left_joint": "left_wheel_joint", "right_joint": "right_wheel_joint"}
"""The wheels' joint names a bag is read with unless named (``read_log``'s own defaults)."""


def add_bag_arguments(parser: argparse.ArgumentParser) -> None:
    """The options a ROS 2 bag is read with (``diagnose`` and ``fleet``): its topics and the
    wheels' joint names (:func:`bag_options`)."""
    parser.add_argument("--pose-topic", help="ROS 2 bags: ground-truth pose topic")
    parser.add_argument("--joint-topic", help="ROS 2 bags: sensor_msgs/JointState topic")
    parser.add_argument("--encoder-topic", help="ROS 2 bags: [left, right] counts topic")
    for name, default in _JOINTS.items():
        side = name.split("_")[0]
        parser.add_argument(
            f"--{side}-joint",
            default=default,
            help=f"ROS 2 bags: the {side} wheel's joint name (default {default})",
        )


def bag_options(args: argparse.Namespace) -> dict[str, str]:
    """:func:`add_bag_arguments`' options as :func:`odomgym.data.logs.read_log`'s keywords:
    the topics given, and the joint names where they are not the defaults. Why only those: a
    fleet's resume digest holds them (:attr:`odomgym.diagnose.fleet.FleetRobot.reading`), and
    a fleet of CSV logs must keep the digest it had before the options existed."""
    topics = ("pose_topic", "joint_topic", "encoder_topic")
    given = {name: getattr(args, name) for name in topics if getattr(args, name) is not None}
    given.update({n: getattr(args, n) for n, d in _JOINTS.items() if getattr(args, n) != d})
    return given


def read_runs(
    args: argparse.Namespace, data: Path, robot: RobotSpec | None
) -> tuple[list[Run], RobotSpec]:
    """The runs of ``data`` and the model to test (``--robot``, else the data's own nominal
    robot)."""
    from odomgym.data.logs import read_log

    runs, nominal = read_log(data, robot=robot, format=args.format, **bag_options(args))
    model = robot if robot is not None else nominal
    if model is None:
        raise SpecError("give the robot model with --robot robot.toml", field="robot")
    return runs, model


def say_set_aside(
    runs: list[Run], model: RobotSpec, report: Reporter, *, robot: str | None = None
) -> None:
    """Notices of the runs the diagnosis will cut at a hole or set aside, and of the held poses
    made gaps; too few usable runs, or logs a unit away from the model, are a
    :class:`SpecError` here, before any work. ``robot``: a fleet's robot the runs are, named in
    every notice and in the refusal (``odomgym fleet`` screens every robot before the first
    diagnosis)."""
    if robot is None:
        _say_set_aside(runs, model, report.notice)
        return
    try:
        _say_set_aside(runs, model, lambda text: report.notice(f"robot {robot}: {text}"))
    except SpecError as exc:
        raise SpecError(f"robot {robot}: {exc}", field=exc.field) from None


def _say_set_aside(runs: list[Run], model: RobotSpec, notice: Callable[[str], None]) -> None:
    """:func:`say_set_aside`, each notice handed to ``notice``."""
    from odomgym.data.gaps import held_poses
    from odomgym.diagnose.screen import holes, part_names, slow_clock, usable_runs

    interval = slow_clock(runs)
    if interval is not None:
        notice(
            f"the samples are {interval:.4g} s apart (median over all runs), where wheel "
            "odometry is logged at 10-1000 Hz: the logs' time must be in seconds (a time in "
            "milliseconds needs dividing by 1000); diagnosed as given"
        )
    for index, run in enumerate(runs):
        found = holes(run)
        if found:
            name = str(run.meta.get("run", index + 1))
            parts = ", ".join(part_names(name, found))
            said = "; ".join(str(hole) for hole in found)
            notice(
                f"run {name} ({run.source}): {said}: rows were dropped, and the path in between "
                f"is unknown, so it is diagnosed as {len(found) + 1} runs ({parts})"
            )
    # What the diagnosis will set aside, said before its minutes of work (it screens the runs
    # again and records the same in report.json); too few usable runs stop here in one line.
    _, skipped = usable_runs(runs, model)
    for one in skipped:
        notice(str(one))
    held = [held_poses(run) for run in runs]
    if any(held):
        poses = f"{sum(held)} held pose" + ("s" if sum(held) > 1 else "")
        notice(
            f"{poses} (the tracker repeated its last pose while the wheels turned) taken as "
            f"gaps in {sum(1 for n in held if n)} of {len(runs)} runs"
        )


def run_loso_command(
    args: argparse.Namespace,
    report: Reporter,
    data: Path,
    robot: RobotSpec | None,
    config: DiagnoseConfig,
) -> int:
    """``--loso``: the folds of :func:`odomgym.diagnose.loso.run_loso` in ``--out`` (fold files
    already there are kept, not diagnosed again), a progress bar over the folds, then the
    table (or, with ``--json``, the folds and their summary) and the fold files written.
    With ``--backend ray`` every fold is one Ray task (not its candidate fits)."""
    from odomgym.baselines.trajectory import TrajectoryBaseline
    from odomgym.diagnose.loso import fold_path, fold_sessions, run_loso, table

    out = Path(args.out) if args.out else Path(f"{data.stem or 'data'}-loso")
    check_output(out, option="--out", folder=True)
    runs, model = read_runs(args, data, robot)
    shard_of = args.shard or (1, 1)
    mine = fold_sessions(runs, args.sessions, shard_of)  # bad --sessions: before any work
    say_set_aside(runs, model, report)
    before = {s for s in mine if fold_path(out, s).is_file()}
    with Progress(report, "leave one session out", total=len(mine), unit="fold") as bar:
        folds, summary = run_loso(
            runs,
            model,
            out,
            config=config,
            baseline=None if args.no_baseline else TrajectoryBaseline,
            sessions=args.sessions,
            shard=shard_of,
            table_only=args.table_only,
            backend=args.backend,
            address=args.ray_address,
            progress=lambda done, _: bar.at(done),
            status=report.status,
        )
    missing = summary["missing_folds"]
    if report.json:
        report.document({"folds": folds, "summary": summary})
    else:
        text = table(folds, summary)
        if missing:
            text += f"\n\nNot diagnosed yet ({len(missing)} of {len(mine)}): {', '.join(missing)}"
        report.text(text)
    report.wrote(fold_path(out, s) for s in mine if s not in before and fold_path(out, s).is_file())
    return 0

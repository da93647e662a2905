"""``odomgym fleet ROBOTS/``: every robot of a fleet diagnosed on its own logs, then compared
(:mod:`odomgym.diagnose.fleet`); ``odomgym fleet --example N OUT`` writes a fleet to try it on."""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from odomgym.cli._common import (
    Progress,
    Reporter,
    add_backend_arguments,
    check_backend,
    check_output,
    count,
    processes,
    seed,
)
from odomgym.cli.diagnose import add_bag_arguments, bag_options
from odomgym.errors import SpecError

if TYPE_CHECKING:
    from odomgym.cli._common import Commands


def register(commands: Commands) -> None:
    """Add ``fleet``."""
    parser = commands.add_parser(
        "fleet",
        help="diagnose every robot of a fleet and compare them (recurring effects, odd robots)",
        description="Diagnose each robot of ROBOTS (one sub-folder per robot: its robot.toml "
        "and its logs, optionally in one sub-folder per period) on all its sessions, then "
        "compare the robots: which effects and terms recur in how many robots, each "
        "parameter's values across the fleet, the robots more than 3 robust standard "
        "deviations from it, and what moved between a robot's periods. Writes fleet.md, "
        "fleet.json, a figure per effect and every robot's own report folder. An effect gets a "
        "fleet distribution, and odd robots, once at least 5 robots name it; below that its "
        "recurrence count is the finding. Every robot's logs are read before the first "
        "diagnosis, so a bad log stops the command at once.",
    )
    parser.add_argument(
        "robots",
        metavar="ROBOTS",
        help="the fleet's folder (with --example: the folder to write the example into)",
    )
    parser.add_argument("--out", help="output folder (default: <ROBOTS>-fleet)")
    parser.add_argument(
        "--example",
        type=count,
        metavar="N",
        help="only write an example fleet of N >= 2 simulated robots into ROBOTS and stop",
    )
    parser.add_argument(
        "--sessions", type=count, default=3, help="sessions per example robot (default 3)"
    )
    parser.add_argument("--seed", type=seed, default=0, help="random seed >= 0 (default 0)")
    parser.add_argument(
        "--jobs", type=processes, help="worker processes per diagnosis (default: all cores)"
    )
    add_backend_arguments(parser, "diagnoses (one per robot and period)")
    parser.add_argument(
        "--no-baseline",
        action="store_true",
        help="do not run the baseline trajectory calibration beside each diagnosis",
    )
    parser.add_argument(
        "--resume", action="store_true", help="keep the robots already diagnosed in --out"
    )
    parser.add_argument(
        "--loso",
        action="store_true",
        help="also diagnose every robot of two or more sessions once per session left out "
        "(OUT/loso/<robot>/, kept across interruptions) and report the stability of its "
        "effects and E_d, E_b, E_s across the folds",
    )
    parser.add_argument("--json", action="store_true", help="print fleet.json instead of fleet.md")
    add_bag_arguments(parser)  # every robot's bags are read with the same topics
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Write the example, or diagnose the fleet and write its report."""
    from odomgym.baselines.trajectory import TrajectoryBaseline
    from odomgym.diagnose.fleet import (
        diagnose_fleet,
        find_fleet,
        format_fleet,
        plot_fleet,
        read_robot_runs,
        report_folders,
        summarise_fleet,
        write_example_fleet,
    )
    from odomgym.diagnose.report import check_replaceable
    from odomgym.diagnose.workflow import DiagnoseConfig
    from odomgym.io import atomic_write_text

    report = Reporter.of(args)
    root = Path(args.robots)
    if args.example is not None:
        # Options of the diagnosis, which --example does not run: said, not silently dropped.
        for given, option in (
            (args.out is not None, "--out"),
            (args.loso, "--loso"),
            (args.resume, "--resume"),
        ):
            if given:
                raise SpecError(
                    f"{option} is an option of the fleet's diagnosis; --example only writes "
                    "the logs (run `odomgym fleet ROBOTS` on them next)",
                    field=option[2:],
                )
        check_output(root, option="ROBOTS", folder=True)
        if root.is_dir() and any(root.iterdir()):
            # Written over an earlier fleet, the old robots and sessions stayed beside the
            # new ones, and truth.json listed only the new.
            raise SpecError(
                f"ROBOTS {root} is not empty: --example writes a fleet into a new or empty folder",
                field="ROBOTS",
            )
        truth = write_example_fleet(root, args.example, seed=args.seed, sessions=args.sessions)
        robots_said = f"{args.example} robot" + ("s" if args.example != 1 else "")
        sessions_said = f"{args.sessions} session" + ("s" if args.sessions != 1 else "")
        report.status(
            f"wrote {robots_said} ({sessions_said} each) into {root}; the "
            f"truth, which the fleet command never reads: {root / 'truth.json'}"
        )
        if report.json:
            report.document(truth)
        return 0
    check_backend(args)
    out = Path(args.out) if args.out else _beside(root)
    if out.resolve().is_relative_to(root.resolve()):
        # Its folder would be taken for a robot's on the next call (a user's `fleet .` wrote
        # ./fleet-fleet, and every later call stopped on it).
        raise SpecError(
            f"--out {out} lies inside ROBOTS ({root}), where its folders would be taken for "
            "robots: give a folder outside it",
            field="out",
        )
    robots = find_fleet(root, bag_options(args))
    check_output(out, option="--out", folder=True)
    for folder in report_folders(robots, out):  # replaced whole: only earlier reports
        check_replaceable(folder, option="--out")
    # A bad log stops here, not after the robots before it (minutes). The runs are not kept:
    # diagnose_fleet reads each robot's again when its turn comes, holding one robot's at a
    # time. Reading is about 0.5 s a robot against tens of seconds of diagnosis (a 3-session
    # example robot, measured on 2026-12-02), and a fleet's runs held together would grow
    # with the fleet.
    # Each robot's runs are screened as `odomgym diagnose` screens them (too few usable runs,
    # a unit away from the model, holes and held poses said), here, before the first
    # diagnosis: a robot that cannot be diagnosed stopped the command only when its turn came.
    from odomgym.cli.diagnose import say_set_aside

    for robot in robots:
        say_set_aside(read_robot_runs(robot), robot.robot, report, robot=robot.name)
    config = DiagnoseConfig(seed=args.seed, jobs=args.jobs or os.cpu_count() or 1)
    bars: list[Progress] = []

    def progress(label: str) -> Callable[[str, float], None]:
        """A bar per robot: its label, then the diagnosis' stage and fraction."""
        if bars:
            bars.pop().__exit__(None, None, None)
        bar = Progress(report, label, leave=True)
        bars.append(bar)

        def stage(name: str, fraction: float) -> None:
            bar.stage(f"{label}: {name}", fraction)

        return stage

    on_ray = args.backend == "ray"
    # Locally a bar per robot (its diagnosis' stages); on Ray one bar over the fleet's
    # diagnoses, whose stages stay in their tasks, and a line as each ends.
    overall = Progress(report, "fleet on Ray: diagnoses done, %") if on_ray else None
    if overall is not None:
        bars.append(overall)
    try:
        diagnose_fleet(
            robots,
            out,
            config=config,
            baseline=None if args.no_baseline else TrajectoryBaseline,
            resume=args.resume,
            progress=None if on_ray else progress,
            status=report.status,
            backend=args.backend,
            address=args.ray_address,
            done=overall.done_of if overall is not None else None,
            loso=args.loso,
        )
    finally:
        for bar in bars:
            bar.__exit__(None, None, None)
    summary = summarise_fleet(out, robots, loso=args.loso)
    text = format_fleet(summary, str(root))
    document = json.dumps(summary.to_json(), indent=1)
    atomic_write_text(out / "fleet.md", text)
    atomic_write_text(out / "fleet.json", document + "\n")
    figures = plot_fleet(summary, out)
    if report.json:
        report.text(document)
    else:
        report.text(text)
    report.wrote([out / "fleet.md", out / "fleet.json", *figures])
    return 0


def _beside(root: Path) -> Path:
    """The default ``--out``: ``<ROBOTS>-fleet`` beside ROBOTS (for ``.`` or ``..`` named
    after the folder they stand for, so never inside it)."""
    if root.name and root.name not in (".", ".."):
        return root.parent / f"{root.name}-fleet"
    resolved = root.resolve()
    return resolved.parent / f"{resolved.name or 'fleet'}-fleet"

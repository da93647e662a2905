"""``odomgym leaderboard --data DIR``: real data — calibrate every method on one recorded
session, evaluate it on the others, and compare with the published results."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from odomgym.cli._common import Reporter, check_methods, check_output
from odomgym.io import atomic_write_text

if TYPE_CHECKING:
    from odomgym.cli._common import Commands


def register(commands: Commands) -> None:
    """Add ``leaderboard``."""
    parser = commands.add_parser(
        "leaderboard",
        help="real-data leaderboard: calibrate on one recorded session, evaluate on the others",
        description="Calibrate every method on every recorded session that holds the runs it "
        "needs, evaluate it on all other sessions (OptiOdom measures), and compare the "
        "in-session results with the published ones (Sousa et al. 2022).",
    )
    parser.add_argument(
        "--data",
        required=True,
        help="folder of OptiOdom sessions, or optiodom: for the shipped ones",
    )
    parser.add_argument(
        "--methods",
        nargs="+",
        help="calibrators (default: every method made for differential-drive robots)",
    )
    parser.add_argument(
        "--conventions",
        choices=["optiodom"],
        default=None,
        help="optiodom: run UMBmark and Jung & Chung with the OptiOdom authors' conventions, "
        "so that the in-session column reproduces their published results",
    )
    parser.add_argument("--out", help="also write the Markdown tables to this file")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Build the leaderboard, write its Markdown tables to ``--out`` if asked, then print it
    (the tables, or one JSON object) and the file written."""
    from odomgym.baselines.leaderboard import format_leaderboard, run_leaderboard
    from odomgym.data import resolve_data

    report = Reporter.of(args)
    check_methods(args.methods)
    if args.out:
        check_output(args.out, option="--out")
    board = run_leaderboard(
        resolve_data(args.data), methods=args.methods, conventions=args.conventions
    )
    text = format_leaderboard(board)
    if args.out:
        atomic_write_text(Path(args.out), text + "\n")
    report.result(board.as_dict, lambda: text)
    report.wrote([args.out] if args.out else [])
    return 0

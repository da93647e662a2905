"""``odomgym run square|straight``: drive a simulated robot and report its return errors.

The ``run`` parser also holds the CLAPPER routes (``clapper-straight``, ``clapper-rectangle``),
which drive a different vehicle with different options: they live in
:mod:`odomgym.cli.run_clapper` and are registered here, under ``run``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from odomgym.cli import run_clapper
from odomgym.cli._common import (
    Progress,
    Reporter,
    add_robot_arguments,
    check_output,
    check_plot_path,
    count,
    describe_calibration,
    positive,
    robot_from,
)
from odomgym.errors import SpecError
from odomgym.floor import FloorSpec, load_floor
from odomgym.lab.plans import drive_plans, square_plans, straight_plans
from odomgym.lab.report import format_return_errors, plot_return_errors
from odomgym.odometry.calibration import load_calibration

if TYPE_CHECKING:
    from odomgym.cli._common import Commands


def register(commands: Commands) -> None:
    """Add ``run`` and its routes: ``square``, ``straight`` and the two CLAPPER routes."""
    parser = commands.add_parser(
        "run",
        help="drive squares or straight runs in simulation and report return errors",
        description="Drive a simulated robot with the reference driver and report the return "
        "errors (true - odometry end pose, start frame).",
    )
    routes = parser.add_subparsers(
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
    add_robot_arguments(square)
    square.add_argument(
        "--direction",
        choices=["cw", "ccw", "both"],
        default="both",
        help="square direction (default both: cw runs, then ccw)",
    )
    square.add_argument("--runs", type=count, default=5, help="runs per direction (default 5)")
    square.add_argument("--side", type=positive, default=4.0, help="square side L [m] (default 4)")
    square.add_argument("--plot", help="write the return-error scatter here (.png, .pdf, .svg)")
    _add_outputs(square)
    square.set_defaults(handler=run)

    straight = routes.add_parser(
        "straight",
        help="straight runs (optionally there and back) and their end errors",
        description="Drive straight runs (Borenstein 1995, §6.1, drove 18 m over cables) and "
        "report each run's end error.",
    )
    add_robot_arguments(straight)
    straight.add_argument("--runs", type=count, default=5, help="runs (default 5)")
    straight.add_argument(
        "--distance", type=positive, default=10.0, help="straight run length [m] (default 10)"
    )
    straight.add_argument(
        "--return-trip",
        action="store_true",
        help="stop at the end and drive back to the start in reverse, without turning (as "
        "the CLAPPER did: Borenstein 1995, 18 m out and back)",
    )
    _add_outputs(straight)
    straight.set_defaults(handler=run)
    run_clapper.register(routes)


def _add_outputs(parser: argparse.ArgumentParser) -> None:
    """``--json`` and ``--log``, the outputs both routes share (only squares are plotted)."""
    parser.add_argument(
        "--json", action="store_true", help="print JSON lines (one per run) instead of a table"
    )
    parser.add_argument(
        "--log", help="also save the runs in odomgym's native CSV format here (for diagnose)"
    )


def run(args: argparse.Namespace) -> int:
    """Drive the runs, then print them (a table, or a JSON line per run and a summary), the
    calibration the odometry applied and the files written (the runs' log, the scatter)."""
    report = Reporter.of(args)
    plot: str | None = getattr(args, "plot", None)  # straight runs have no plot
    check_plot_path(plot)
    if args.log:
        check_output(args.log, option="--log")
    robot = robot_from(args)
    floor: FloorSpec = load_floor(args.floor)
    calibration = load_calibration(args.calibration) if args.calibration else None
    if args.path == "square":
        plans = square_plans(args.side, args.direction, args.runs)
    else:
        plans = straight_plans(args.distance, args.return_trip, args.runs)
    with Progress.percent(report) as bar:
        try:
            batch = drive_plans(
                robot,
                floor,
                plans,
                calibration=calibration,
                rng=np.random.default_rng(args.seed),
                progress=bar.fraction,
            )
        except (RuntimeError, ValueError) as exc:
            if calibration is None or isinstance(exc, SpecError):
                raise
            # The driver steers by the calibrated odometry, so a calibration the file allows
            # (any finite x_ICR, any positive factor) but far from this robot (x_ICR in mm
            # read as m, a factor of 1000) sends it in circles or asks the wheels for
            # infinite rates: the user's input, said as such rather than as a bug.
            raise SpecError(
                f"{args.calibration}: driving by this calibration "
                f"({describe_calibration(calibration)}), {exc}; are its values this robot's "
                "(metres, factors near 1)?",
                field="calibration",
            ) from exc
    written: list[str] = []
    if args.log:
        from odomgym.data.native import write_native

        write_native(Path(args.log), batch.runs)
        written.append(args.log)
    summary = batch.summary()
    if report.json:
        for record in batch.records():
            report.document(record)
        if summary is not None:
            report.document({"summary": summary.__dict__})
    else:
        report.text(
            f"robot {robot.name}: E_d = {robot.e_d:.5f}, E_b = {robot.e_b:.5f}, "
            f"E_s = {robot.e_s:.5f}; floor {floor.name}; route {batch.route_name}"
        )
    if calibration is None:
        report.status("applied calibration: none (the nominal robot's odometry)")
    else:
        report.status(
            f"applied calibration: {args.calibration} ({describe_calibration(calibration)})"
        )
    if not report.json:
        report.text("return errors (true - odometry, start frame)")
        report.text(format_return_errors(batch.rows(), summary))
    if plot:
        plot_return_errors(
            Path(plot),
            [("runs", batch.errors_of("cw"), batch.errors_of("ccw"))],
            f"{robot.name}: return errors, {floor.name} floor",
        )
        written.append(plot)
    report.wrote(written)
    return 0

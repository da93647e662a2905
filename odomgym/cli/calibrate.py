"""``odomgym calibrate METHOD``: calibrate a simulated robot (or a recorded session) and
validate the result; save or export the calibration."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from odomgym.cli._common import (
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
from odomgym.floor import load_floor
from odomgym.io import atomic_write_text
from odomgym.lab.report import format_session_report, format_simulation_report, plot_return_errors
from odomgym.odometry.calibration import Calibration

if TYPE_CHECKING:
    from odomgym.cli._common import Commands


def register(commands: Commands) -> None:
    """Add ``calibrate``."""
    parser = commands.add_parser(
        "calibrate",
        help="calibrate a simulated robot (or a measured session) and validate the result",
        description="Run a calibration method's experiments in simulation on a robot with hidden "
        "systematic errors, then compare E_max,syst on fresh squares before and after; or, with "
        "--data, calibrate from a recorded OptiOdom session and report its evaluation measures.",
    )
    parser.add_argument("method", help="calibration method, e.g. umbmark, jung_chung")
    add_robot_arguments(parser, calibration=False)
    parser.add_argument("--side", type=positive, default=4.0, help="square side L [m] (default 4)")
    parser.add_argument("--runs", type=count, default=5, help="squares per direction (default 5)")
    parser.add_argument(
        "--data",
        help="a recorded OptiOdom session folder instead of simulation, or a shipped session "
        "(optiodom:square/230620202042)",
    )
    parser.add_argument(
        "--conventions",
        choices=["optiodom"],
        default=None,
        help="optiodom: reproduce the published OptiOdom conventions (with --data)",
    )
    parser.add_argument(
        "--policy",
        help="selfcal only: learned (the shipped policy, default), scripted (alternate 4 m "
        "squares) or a policy .npz file written by odomgym train selfcal",
    )
    parser.add_argument(
        "--schedule",
        help="selfcal_scripted and selfcal_end_pose only: menu items driven in this order, "
        "comma-separated, repeated until the budget is spent (e.g. square4-cw,square4-ccw,"
        "straight4); default the scripted schedule",
    )
    parser.add_argument("--save", help="write the calibration as TOML here")
    parser.add_argument(
        "--export", choices=["ros2"], help="also export the calibration (ros2: diff_drive YAML)"
    )
    parser.add_argument(
        "--export-path", help="where --export writes (default diff_drive_controller.yaml)"
    )
    parser.add_argument("--json", action="store_true", help="one JSON object instead of a table")
    parser.add_argument(
        "--plot", help="write the before/after return-error scatter here (.png, .pdf, .svg)"
    )
    parser.set_defaults(handler=run)


def _export_path(args: argparse.Namespace) -> str:
    """Where ``--export`` writes."""
    return str(args.export_path or "diff_drive_controller.yaml")


def _check_outputs(args: argparse.Namespace) -> None:
    """Fail before any calibration if an output cannot be written (or is named uselessly)."""
    if args.export_path is not None and args.export is None:
        raise SpecError("--export-path needs --export ros2", field="export_path")
    if args.save:
        check_output(args.save, option="--save")
    if args.export:
        check_output(_export_path(args), option="--export-path")
    check_plot_path(args.plot)


def _write_outputs(args: argparse.Namespace, calibration: Calibration) -> list[str]:
    """Save and export the calibration as asked; returns the files written, in order."""
    written: list[str] = []
    if args.save:
        calibration.save(args.save)
        written.append(args.save)
    if args.export == "ros2":
        atomic_write_text(Path(_export_path(args)), calibration.ros2_yaml())
        written.append(_export_path(args))
    return written


def run(args: argparse.Namespace) -> int:
    """Calibrate on the recorded session (``--data``) or in simulation, then print the report,
    the calibration found and the files written."""
    from odomgym.baselines import CALIBRATORS
    from odomgym.baselines.validation import (
        calibrate_in_simulation,
        calibrate_on_session,
        calibrator_for_session,
        calibrator_for_squares,
    )

    report = Reporter.of(args)
    if args.method not in CALIBRATORS:
        raise SpecError(
            f"unknown method {args.method!r}; methods: {', '.join(sorted(CALIBRATORS))}",
            field="method",
        )
    cls = CALIBRATORS[args.method]
    _check_outputs(args)
    if args.data:
        from odomgym.data import read_session, resolve_data

        session = read_session(resolve_data(args.data, session=True))
        try:
            calibrator = calibrator_for_session(cls, session, args.conventions)
            on_session = calibrate_on_session(calibrator, session)
        except (LookupError, ValueError) as exc:
            if isinstance(exc, SpecError):
                raise
            # The session lacks an experiment the method needs (e.g. squares for UMBmark).
            message = str(exc.args[0]) if exc.args else str(exc)
            raise SpecError(
                f"{args.method} cannot calibrate on {args.data}: {message}", field="data"
            ) from None
        written = _write_outputs(args, on_session.result.calibration)
        report.result(on_session.as_dict, lambda: format_session_report(on_session))
        report.status(f"calibrated: {describe_calibration(on_session.result.calibration)}")
        report.wrote(written)
        return 0
    if args.conventions == "optiodom":
        raise SpecError(
            "--conventions optiodom applies to measured data (--data DIR)", field="conventions"
        )
    robot = robot_from(args)
    floor = load_floor(args.floor)
    extra: dict[str, object] = {"policy": args.policy} if args.policy is not None else {}
    if args.schedule is not None:
        extra["schedule"] = args.schedule
    calibrator = calibrator_for_squares(cls, side=args.side, runs_per_direction=args.runs, **extra)
    simulated = calibrate_in_simulation(
        calibrator,
        robot,
        floor,
        seed=args.seed,
        validation_side=args.side,
        validation_runs=args.runs,
    )
    written = _write_outputs(args, simulated.result.calibration)
    if args.plot:
        plot_return_errors(
            Path(args.plot),
            [
                ("before", simulated.errors_before["cw"], simulated.errors_before["ccw"]),
                ("after", simulated.errors_after["cw"], simulated.errors_after["ccw"]),
            ],
            f"{args.method} on {robot.name}, {floor.name} floor: "
            f"{simulated.improvement:.1f}-fold improvement",
        )
        written.append(args.plot)
    report.result(simulated.as_dict, lambda: format_simulation_report(simulated, floor.name))
    report.status(f"calibrated: {describe_calibration(simulated.result.calibration)}")
    report.wrote(written)
    return 0

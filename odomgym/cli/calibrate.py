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
    # The simulation's options default to None here and take their defaults in `run`, so that
    # one given with --data (which they do not apply to) can be told from one left out.
    parser.set_defaults(handler=run, **dict.fromkeys(SIMULATION_DEFAULTS))


SIMULATION_DEFAULTS: dict[str, object] = {
    "robot": "labmate",
    "ed": None,
    "eb": None,
    "es": None,
    "floor": "smooth",
    "seed": 0,
    "side": 4.0,
    "runs": 5,
    "policy": None,
    "schedule": None,
    "plot": None,
}
"""The options that apply to a simulated calibration only, with their defaults (the help
texts say the same): with ``--data`` the session's own robot, floor and runs are used."""


def _check_simulation_options(args: argparse.Namespace) -> None:
    """Refuse, before any work, simulation options given with ``--data``, naming them — they
    were silently ignored (a --plot never written, an --ed never applied); without --data,
    fill in their defaults."""
    given = [name for name in SIMULATION_DEFAULTS if getattr(args, name) is not None]
    if args.data and given:
        options = ", ".join("--" + name for name in given)
        raise SpecError(
            f"{options} apply to a simulated calibration, not to --data (the session's own "
            "robot, floor and runs are used): leave them out, or leave out --data",
            field=given[0],
        )
    for name, default in SIMULATION_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, default)
    if not args.data:
        from odomgym.sim.routes import check_extent

        # Said as the option typed; the calibrators' experiments would call it their `size`.
        check_extent("--side", args.side, 4.0 * args.side)


def _export_path(args: argparse.Namespace) -> str:
    """Where ``--export`` writes."""
    return str(args.export_path or "diff_drive_controller.yaml")


def _check_outputs(args: argparse.Namespace) -> None:
    """Fail before any calibration if an output cannot be written (or is named uselessly), or
    two outputs are one file: the later write would replace the earlier (--save and
    --export-path at the same file lost the calibration to the ROS 2 YAML)."""
    if args.export_path is not None and args.export is None:
        raise SpecError("--export-path needs --export ros2", field="export_path")
    outputs: list[tuple[str, str]] = []
    if args.save:
        check_output(args.save, option="--save")
        outputs.append(("--save", args.save))
    if args.export:
        check_output(_export_path(args), option="--export-path")
        outputs.append(("--export-path", _export_path(args)))
    check_plot_path(args.plot)
    if args.plot:
        outputs.append(("--plot", args.plot))
    seen: dict[Path, str] = {}
    for option, path in outputs:
        target = Path(path).resolve()
        if target in seen:
            raise SpecError(
                f"{seen[target]} and {option} name the same file {path}; the second would "
                "replace the first: give each its own file",
                field=option.lstrip("-").replace("-", "_"),
            )
        seen[target] = option


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
    _check_simulation_options(args)
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
    try:
        simulated = calibrate_in_simulation(
            calibrator,
            robot,
            floor,
            seed=args.seed,
            validation_side=args.side,
            validation_runs=args.runs,
        )
    except SpecError as exc:
        # A method's model that the squares of --side break (Lee et al.'s on squares far too
        # small): the library names its option `side`; here it is the user's --side.
        if exc.field != "side":
            raise
        message = str(exc)
        if not message.startswith("side "):
            message = f"side {args.side:g}: {message}"
        message = "--" + message
        raise SpecError(message, field="side") from None
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

"""``odomgym fit-noise``: estimate the wheel noise constants k_L, k_R from repeated runs
(Chong & Kleeman 1997, §6.3), simulated or recorded."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from odomgym.cli._common import (
    Reporter,
    check_plot_path,
    count,
    nonnegative,
    positive,
    seed,
)
from odomgym.errors import SpecError
from odomgym.floor import MAX_ROUGHNESS
from odomgym.robot import PRESETS

if TYPE_CHECKING:
    from odomgym.cli._common import Commands


def register(commands: Commands) -> None:
    """Add ``fit-noise``."""
    parser = commands.add_parser(
        "fit-noise",
        help="estimate the wheel noise constants k_L, k_R from repeated runs "
        "(Chong & Kleeman 1997, §6.3)",
        description="Without --data: simulate N runs of D m forward and back on a rough floor of "
        "known k and fit it back. With --data: fit recorded OptiOdom sessions.",
    )
    parser.add_argument(
        "--robot",
        default="labmate",
        help=f"robot preset for the simulation ({', '.join(PRESETS)}; default labmate)",
    )
    parser.add_argument(
        "--k",
        type=roughness,
        default=0.0005,
        help=f"true k [m^0.5] to simulate, 0 to {MAX_ROUGHNESS:g} (0.0005)",
    )
    parser.add_argument("--runs", type=count, default=60, help="simulated runs (default 60)")
    parser.add_argument(
        "--distance", type=positive, default=10.0, help="out-and-back length [m] (default 10)"
    )
    parser.add_argument("--seed", type=seed, default=0, help="random seed >= 0 (default 0)")
    parser.add_argument(
        "--data",
        nargs="+",
        help="OptiOdom session folders (or their parents), or shipped data (optiodom:ivanjko)",
    )
    parser.add_argument(
        "--pool",
        choices=["all", "path-type", "kind", "session"],
        default="kind",
        help="which recorded runs are fitted together (default: by run kind)",
    )
    parser.add_argument(
        "--interval",
        choices=["profile", "bootstrap"],
        default="profile",
        help="confidence intervals by profile likelihood (default) or bootstrap",
    )
    parser.add_argument(
        "--plot",
        help="write the error scatters with 95 %% ellipses here (.png; one file per fitted "
        "group, suffixed by its name, when there are several)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(handler=run)


def roughness(text: str) -> float:
    """An argparse type: a floor roughness k [m^½] the simulation accepts, 0 to
    :data:`~odomgym.floor.MAX_ROUGHNESS` — checked here so that the refusal names ``--k``
    (the floor's own check said "roughness must lie in …", an option the command has not)."""
    value = nonnegative(text)
    if value > MAX_ROUGHNESS:
        raise argparse.ArgumentTypeError(
            f"must lie in [0, {MAX_ROUGHNESS:g}] m^0.5 (a floor's roughness), got {text!r}"
        )
    return value


def run(args: argparse.Namespace) -> int:
    """Fit (simulating the runs first without ``--data``), then print the fits (a table, or
    one JSON object) and the plots the report says it wrote."""
    from odomgym.data import resolve_data
    from odomgym.noise.experiment import fit_noise_report, format_noise_report
    from odomgym.noise.fit import MIN_RUNS

    report = Reporter.of(args)
    check_plot_path(args.plot)
    if not args.data and args.runs < MIN_RUNS:
        # The simulated runs form one group whose mean is removed: fewer than MIN_RUNS leave
        # nothing the fit accepts, and it had ended in an empty table with exit 0.
        raise SpecError(
            f"--runs {args.runs}: the noise fit needs at least {MIN_RUNS} runs",
            field="runs",
        )
    data = tuple(resolve_data(folder) for folder in args.data or ())
    try:
        fits = fit_noise_report(
            robot=args.robot,
            k=args.k,
            runs=args.runs,
            distance=args.distance,
            seed=args.seed,
            data=data,
            pool=args.pool,
            interval=args.interval,
            plot=args.plot,
            check_plot=lambda path: check_plot_path(str(path)),
        )
    except SpecError:
        raise
    except ValueError as exc:
        raise SpecError(str(exc)) from None
    report.result(lambda: fits, lambda: format_noise_report(fits))
    report.wrote(fits.get("plots", []))
    return 0

"""``odomgym covariance``: Chong & Kleeman's closed-form odometry covariance (1997), and
optionally a Monte Carlo check beside it."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

import numpy as np

from odomgym.cli._common import Reporter, count, finite, nonnegative, positive, seed
from odomgym.errors import SpecError

if TYPE_CHECKING:
    from odomgym.cli._common import Commands


def register(commands: Commands) -> None:
    """Add ``covariance``."""
    parser = commands.add_parser(
        "covariance",
        help="Chong & Kleeman odometry covariance in closed form (and by Monte Carlo)",
        description="Mean, standard deviations and correlations of the end pose after wheel "
        "travels L (left) and R (right) [m] with wheel noise k [m^0.5] (Chong & Kleeman 1997), "
        "laid out like the paper's Tables 1-7.",
    )
    parser.add_argument("--left", type=finite, required=True, help="left wheel travel L [m]")
    parser.add_argument("--right", type=finite, required=True, help="right wheel travel R [m]")
    parser.add_argument("--wheelbase", type=positive, required=True, help="wheelbase B [m]")
    parser.add_argument("--kl", type=nonnegative, required=True, help="k_L [m^0.5]")
    parser.add_argument("--kr", type=nonnegative, required=True, help="k_R [m^0.5]")
    parser.add_argument(
        "--init-std",
        nargs=3,
        type=nonnegative,
        default=[0.0, 0.0, 0.0],
        metavar=("SX", "SY", "STH"),
        help="initial pose standard deviations [m, m, rad]",
    )
    parser.add_argument(
        "--montecarlo",
        type=seed,
        default=0,
        metavar="RUNS",
        help="Monte Carlo runs beside the closed form (default 0: none)",
    )
    parser.add_argument(
        "--partitions", type=count, default=1000, help="path partitions (default 1000)"
    )
    parser.add_argument("--seed", type=seed, default=0, help="Monte Carlo seed >= 0 (default 0)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(handler=run)


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


def run(args: argparse.Namespace) -> int:
    """Compute the report, refusing inputs whose covariance overflows a double (one line, not
    a table of inf and nan), and print it (the paper's tables, or one JSON object)."""
    from odomgym.noise.montecarlo import covariance_report, format_report

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
    except SpecError:
        raise
    except ValueError as exc:
        raise SpecError(str(exc)) from None
    if not _all_finite(report):
        raise too_large
    Reporter.of(args).result(lambda: report, lambda: format_report(report))
    return 0

"""``odomgym run clapper-straight|clapper-rectangle``: the CLAPPER two-truck vehicle on the
paper's experiments (Borenstein 1995, §6), with and without IPEC.

Registered under ``run`` by :mod:`odomgym.cli.run`: a route of ``run`` like ``square``, but a
different vehicle (a vehicle spec, not a robot) with its own options, so its own module.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from odomgym.cli._common import (
    Progress,
    Reporter,
    bumps,
    check_plot_path,
    count,
    floor_help,
    seed,
)
from odomgym.floor import FloorSpec, load_floor

if TYPE_CHECKING:
    from odomgym.cli._common import Commands


def register(routes: Commands) -> None:
    """Add the two CLAPPER routes to ``run``'s routes."""
    from odomgym.vehicle.trial import CLAPPER_FLOOR

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
        parser.add_argument("--floor", default=CLAPPER_FLOOR, help=floor_help(CLAPPER_FLOOR))
        parser.add_argument(
            "--bumps",
            type=bumps,
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
            type=count,
            default=None,
            help="runs per condition (and direction) (default: the paper's — 3 on the "
            "straight, 10 per direction on the rectangle)",
        )
        parser.add_argument("--seed", type=seed, default=0, help="seed of the floor noise")
        parser.add_argument(
            "--json", action="store_true", help="print JSON lines (one per run, then a summary)"
        )
        parser.add_argument(
            "--plot", help="write the return-error figure (like the paper's Figs. 8/10) here"
        )
        parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Drive the experiment's conditions (the paper's, or the one ``--bumps``/``--ipec`` ask
    for), then print the settings and the runs (a table, or a JSON line per run and a
    summary) and the figure written."""
    from odomgym.vehicle.controller import VehicleDriver
    from odomgym.vehicle.ipec import ipec_estimator
    from odomgym.vehicle.paper_runs import (
        PAPER_CONDITIONS,
        SONAR,
        Condition,
        format_clapper_runs,
        plot_clapper_runs,
        run_clapper,
        summarize,
    )
    from odomgym.vehicle.spec import PAPER_ERRORS, load_vehicle

    report = Reporter.of(args)
    check_plot_path(args.plot)
    spec = load_vehicle(args.vehicle)
    if args.errors == "paper":
        spec = dataclasses.replace(spec, **PAPER_ERRORS)  # type: ignore[arg-type]
    floor: FloorSpec = load_floor(args.floor)
    experiment = "straight" if args.path == "clapper-straight" else "rectangle"
    custom = args.bumps is not None or args.ipec is not None
    if custom:
        cables = 10 if args.bumps is None else args.bumps
        modes = (False, True) if args.ipec is None else (bool(args.ipec),)
        conditions = [Condition("with IPEC" if m else "without IPEC", m, cables) for m in modes]
    else:
        conditions = list(PAPER_CONDITIONS[experiment])
    direction = getattr(args, "direction", "-")  # the straight experiment has none
    directions = ("cw", "ccw") if direction == "both" else (direction,)
    side = getattr(args, "side", "right")
    sides = ("right", "left") if side == "both" else (side,)
    runs_each = args.runs if args.runs is not None else (3 if experiment == "straight" else 10)
    with Progress.percent(report) as bar:
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
            progress=bar.done_of,
        )
    settings = (
        f"vehicle {spec.name}: trucks {spec.truck_a.name}/{spec.truck_b.name}, link "
        f"{spec.link_length:g} m; floor {floor.name}; {experiment}; IPEC {args.ipec_config}; "
        f"steering {args.steering}; error sources {args.errors}; {runs_each} runs per "
        f"condition{' and direction' if len(directions) > 1 else ''}, seed {args.seed}"
    )
    if report.json:
        for one in runs:
            report.document(one.record())
        report.document({"settings": settings, "summary": summarize(runs)})
    else:
        report.text(settings)
        report.text(
            "conditions: "
            + "; ".join(
                f"{c.label}: IPEC {'on' if c.ipec else 'off'}, {c.bumps} cables" for c in conditions
            )
        )
        report.text(
            "return errors (true - estimated; vehicle = midpoint of the trucks, link heading)"
        )
        report.text(format_clapper_runs(runs))
    written: list[str] = []
    if args.plot:
        title = f"CLAPPER {experiment}: return errors, {floor.name} floor"
        plot_clapper_runs(Path(args.plot), runs, title)
        written.append(args.plot)
    report.wrote(written)
    return 0

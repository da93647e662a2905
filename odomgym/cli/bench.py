"""``odomgym bench calibrators``: every calibrator on the same simulated robot population and
floors, with a journal so that an interrupted benchmark resumes where it stopped.

``odomgym bench skid``: the skid-steer odometry models (constant factor, Mandow et al. 2007's
ICRs, a curvature-dependent factor) fitted beside the six classical calibrators on the
skid-steer presets, validated on circles and free paths they never saw
(:mod:`odomgym.baselines.skid_bench`)."""

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
    check_methods,
    check_output,
    count,
    notice,
    processes,
    seed,
)
from odomgym.errors import SpecError, first_few
from odomgym.interrupt import Interrupted

if TYPE_CHECKING:
    from odomgym.cli._common import Commands

JOURNAL_NAME = "journal.jsonl"
"""The file in ``--out`` recording every finished chunk of robots while the benchmark runs."""

SKID_FILES = ("skid_models.md", "skid_models.json", "skid_models.png")
"""What ``bench skid`` writes into ``--out``
(:func:`odomgym.baselines.skid_bench.write_skid_outputs`)."""


def register(commands: Commands) -> None:
    """Add ``bench``."""
    from odomgym.lab.population import BENCH_FLOORS
    from odomgym.robot import PRESETS, SKID_STEER_PRESETS

    skid_presets = list(SKID_STEER_PRESETS)
    parser = commands.add_parser(
        "bench",
        help="benchmark calibrators on a simulated robot population",
        description="calibrators: sample robots with hidden systematic errors, give every "
        "calibrator the same budget on the same robots and floors, validate on fresh squares, "
        "report. skid: fit the skid-steer odometry models and the classical calibrators on the "
        "skid-steer presets, validate on circles and free paths they never saw, report.",
    )
    parser.add_argument(
        "what",
        choices=["calibrators", "skid"],
        help="what to benchmark: calibrators (a population of robots drawn around --base), or "
        "skid (skid-steer odometry models and calibrators on the skid-steer presets)",
    )
    parser.add_argument(
        "--robots",
        type=count,
        help="calibrators: population size (default 100)",
    )
    parser.add_argument(
        "--base",
        metavar="PRESET",
        choices=list(PRESETS),
        help="calibrators: the preset the population's robots are drawn around (default "
        f"labmate; one of {', '.join(PRESETS)}). A skid-steer preset adds the methods made for "
        "skid-steer robots (skid_icr, skid_curvature) to the default methods and leaves the "
        "oracle row out: its apparent track emerges from the contacts, so no true geometry is "
        "its odometry's",
    )
    # The list options accumulate when repeated (--floor concrete --floor rough runs both), as
    # a user expects; argparse's default "store" kept only the last silently.
    parser.add_argument(
        "--presets",
        nargs="+",
        action="extend",
        metavar="PRESET",
        choices=skid_presets,
        help=f"skid: the skid-steer presets (default: all: {', '.join(skid_presets)})",
    )
    parser.add_argument(
        "--floor",
        nargs="+",
        action="extend",
        metavar="FLOOR",
        help="calibrators: benchmark floors (default: all): "
        + "; ".join(f"{name}: {floor.description}" for name, floor in BENCH_FLOORS.items())
        + ". skid: any floor preset (default: smooth slippery)",
    )
    parser.add_argument(
        "--methods",
        nargs="+",
        action="extend",
        help="calibrators (default: every method made for differential-drive robots, selfcal "
        "included: its shipped policy runs in numpy; skid_icr and skid_curvature too with a "
        "skid-steer --base)",
    )
    parser.add_argument(
        "--budget",
        type=count,
        nargs="+",
        action="extend",  # no default list: "extend" would add the values given to it
        help="runs per calibration (16); several values compare budgets, e.g. --budget 16 4",
    )
    parser.add_argument("--jobs", type=processes, help="worker processes (default: all cores)")
    add_backend_arguments(parser, "chunks of robots")
    parser.add_argument("--seed", type=seed, default=0, help="master random seed >= 0 (default 0)")
    parser.add_argument(
        "--out", default="bench-out", help="output folder, created if missing (default bench-out)"
    )
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument(
        "--oracle",
        action=argparse.BooleanOptionalAction,
        help="also validate each robot's true parameters as a calibration (the oracle row, the "
        "ceiling the validation noise allows) and report every method as a fraction of it "
        "(default: on; off for a skid-steer --base, and refused there)",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help=f"continue an interrupted run: robots recorded in OUT/{JOURNAL_NAME} are not run "
        "again (the same options are required); the tables equal an uninterrupted run's",
    )
    parser.add_argument(
        "--chunk",
        type=count,
        help="robots per unit of work, recorded as each finishes (default: up to 16)",
    )
    # What `bench skid` compares an option of `bench calibrators` against: its default as
    # this parser has it, so the refusal cannot drift from the options.
    parser.set_defaults(
        handler=run, calibrator_defaults={name: parser.get_default(name) for name in SKID_REFUSES}
    )


SKID_REFUSES = (
    "robots", "base", "methods", "budget", "jobs", "oracle", "resume", "chunk", "backend",
    "ray_address",
)  # fmt: skip
"""Options of ``bench calibrators`` that ``bench skid`` does not take (one line if given)."""


def run(args: argparse.Namespace) -> int:
    """``bench calibrators`` or ``bench skid``, by ``what``."""
    if args.what == "skid":
        return run_skid(args)
    if args.presets is not None:
        raise SpecError("--presets is an option of `odomgym bench skid`", field="--presets")
    if args.robots is None:
        args.robots = 100
    if args.budget is None:
        args.budget = [16]
    if args.floor is None:
        from odomgym.lab.population import BENCH_FLOORS

        args.floor = list(BENCH_FLOORS)
    return run_calibrators(args)


def run_skid(args: argparse.Namespace) -> int:
    """Fit and validate the skid-steer models and the classical calibrators on the presets,
    write the table, JSON and figure into ``--out``, print the table (or ``--json``)."""
    import time

    from odomgym.baselines.skid_bench import (
        SkidBenchConfig,
        run_skid_bench,
        skid_table,
        write_skid_outputs,
    )

    defaults = getattr(args, "calibrator_defaults", {})
    for name in SKID_REFUSES:
        value = getattr(args, name, None)
        if value is not None and value != defaults.get(name):
            option = "--" + name.replace("_", "-")
            raise SpecError(f"{option} is an option of `odomgym bench calibrators`", field=option)
    report = Reporter.of(args)
    check_output(args.out, option="--out", folder=True)
    check_out_folder(Path(args.out))
    config = SkidBenchConfig(
        robots=tuple(args.presets) if args.presets else SkidBenchConfig.robots,
        floors=tuple(args.floor) if args.floor else SkidBenchConfig.floors,
        seed=args.seed,
    )
    cells = len(config.robots) * len(config.floors)
    with Progress(report, "skid benchmark", total=cells, unit="robot-floor") as bar:
        start = time.perf_counter()
        rows = run_skid_bench(config, progress=lambda done, total: bar.at(done))
    elapsed = time.perf_counter() - start
    written = write_skid_outputs(config, rows, Path(args.out), elapsed)
    if report.json:
        report.document(
            {"elapsed_s": elapsed, "seed": config.seed, "results": [r.as_dict() for r in rows]}
        )
    else:
        report.text(skid_table(rows, config.robots, config.floors))
        report.text(f"{len(rows)} results in {elapsed:.1f} s.")
    report.wrote(written)
    return 0


def run_calibrators(args: argparse.Namespace) -> int:
    """Run the benchmark (resuming from the journal with ``--resume``), write the tables and
    plots into ``--out``, then print the summary and the files written."""
    import time

    from odomgym.baselines.base import default_methods
    from odomgym.baselines.bench_report import markdown_summary, write_outputs
    from odomgym.baselines.benchmark import Backend, BenchConfig, run_benchmark, summarize
    from odomgym.lab.population import Population
    from odomgym.robot import PRESETS

    report = Reporter.of(args)
    check_backend(args)
    backend = Backend(args.backend)
    check_output(args.out, option="--out", folder=True)
    check_out_folder(Path(args.out))
    check_methods(args.methods)
    population = Population(base=args.base or "labmate")
    skid = PRESETS[population.base].is_skid_steer
    methods = tuple(args.methods or default_methods(skid_steer=skid))
    # BenchConfig names the offending field itself (SpecError).
    config = BenchConfig(
        robots=args.robots,
        floors=tuple(args.floor),
        methods=methods,
        budget=args.budget[0],
        extra_budgets=tuple(args.budget[1:]),
        seed=args.seed,
        population=population,
        oracle=(not skid) if args.oracle is None else args.oracle,
    )
    jobs = args.jobs or os.cpu_count() or 1
    journal = Path(args.out) / JOURNAL_NAME
    if args.resume and not journal.exists():
        # Said, as `train --resume` says it: started over without a word, a finished
        # benchmark's --resume ran every robot again.
        raise SpecError(
            f"{journal}: no journal to resume from (an interrupted benchmark leaves one; a "
            "finished one removes it, its results are in the folder): start without --resume",
            field="resume",
        )
    with Progress(report, "benchmark", total=config.robots, unit="robot") as bar:
        start = time.perf_counter()
        try:
            rows = run_benchmark(
                config,
                jobs=jobs,
                backend=backend,
                progress=lambda done, total: bar.at(done),
                journal=journal,
                resume=args.resume,
                chunk=args.chunk,
                notify=notice,
                address=args.ray_address,
            )
        except (KeyboardInterrupt, Interrupted) as exc:
            code = exc.code if isinstance(exc, Interrupted) else 130
            raise Interrupted(
                code,
                f"stopped; the finished robots are recorded in {journal}: add --resume to continue",
            ) from None
    elapsed = time.perf_counter() - start
    written = write_outputs(config, rows, Path(args.out), elapsed)
    journal.unlink(missing_ok=True)  # finished: the outputs hold everything
    if report.json:
        report.document({"elapsed_s": elapsed, "jobs": jobs, "summary": summarize(rows)})
    else:
        report.text(markdown_summary(config, rows))
        report.text(f"{len(rows)} results in {elapsed:.1f} s on {jobs} job(s) ({backend}).")
    report.wrote(written)
    return 0


# ----------------------------------------------------------------------- the output folder
def _plain_file(path: Path) -> bool:
    """A regular file, not a link (a link named like an output may point at a user's file)."""
    return path.is_file() and not path.is_symlink()


def _json_with(path: Path, *keys: str) -> bool:
    """Whether ``path`` is a plain file holding a JSON object with every one of ``keys``: how
    an earlier benchmark's ``results.json`` or ``skid_models.json`` is told from a user's."""
    import json

    if not _plain_file(path):
        return False
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(document, dict) and all(key in document for key in keys)


def _is_journal(path: Path) -> bool:
    """Whether ``path`` is a benchmark's journal: a plain file whose first line is a journal
    header, or empty (a journal cut short before its header was synced)."""
    import json

    if not _plain_file(path):
        return False
    try:
        with path.open(encoding="utf-8") as f:
            first = f.readline()
        if not first:
            return True
        header = json.loads(first)
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(header, dict) and "journal" in header


def foreign_entries(out: Path) -> list[str]:
    """The entries of ``out`` (sorted names) that no earlier benchmark wrote: empty for a
    missing or empty folder, or one holding only an earlier ``bench calibrators`` or ``bench
    skid`` run's files (both write to ``bench-out`` by default). A desktop's own files
    (:data:`odomgym.diagnose.report.OS_FILES`) are never foreign.

    Why: the benchmark writes its files over those of the same names and removes an earlier
    run's scatter plots, so a user's ``summary.md`` in ``--out`` was overwritten silently. A
    file counts as the benchmark's only beside the record that says so — a ``results.json``
    or ``skid_models.json`` of the benchmark's layout, or a benchmark journal — and only as a
    plain file (a folder or link named like an output is the user's)."""
    from odomgym.baselines.bench_report import is_output_name
    from odomgym.diagnose.report import OS_FILES

    if not out.is_dir():
        return []
    calibrators = _json_with(out / "results.json", "config", "rows") or _is_journal(
        out / JOURNAL_NAME
    )
    skid = _json_with(out / "skid_models.json", "results", "seconds")

    def own(entry: Path) -> bool:
        name = entry.name
        if name in OS_FILES:
            return _plain_file(entry)
        if name == JOURNAL_NAME:
            return _is_journal(entry)
        mine = (calibrators and is_output_name(name)) or (skid and name in SKID_FILES)
        return mine and _plain_file(entry)

    return sorted(entry.name for entry in out.iterdir() if not own(entry))


def check_out_folder(out: Path) -> None:
    """Refuse, before any work and in one line naming ``--out``, an output folder holding
    anything an earlier benchmark did not write (:func:`foreign_entries`): the first few are
    named. A new, empty or earlier benchmark's folder passes (``--resume`` reads its journal).
    """
    foreign = foreign_entries(out)
    if not foreign:
        return
    raise SpecError(
        f"--out {out}: holds {first_few(foreign)}, which the benchmark did not write; its "
        "files would be written over and beside them: give a new or empty folder, or an "
        "earlier benchmark's",
        field="out",
    )

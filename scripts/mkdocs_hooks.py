"""mkdocs hooks of odomgym's documentation site (``mkdocs.yml``: ``hooks:``).

At every build (``mkdocs build``/``mkdocs serve``), nothing of it committed:

* ``cli.md`` — the command-line reference, generated from the argparse parser itself
  (:func:`odomgym.cli.build_parser`), every command and subcommand's ``--help``, so the page
  cannot drift from the code;
* ``api/*.md`` — the API reference: one mkdocstrings block per module of :data:`API`;
* ``changelog.md`` — ``CHANGELOG.md`` of the repository root (one file, two places);
* a check that fails a strict build (a warning) when a public module is missing from
  :data:`API`, or a public class or function (a module's ``__all__``, else its public names
  defined there) has no docstring.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import logging
import os
import pkgutil
import shutil
from pathlib import Path
from typing import Any

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files

log = logging.getLogger("mkdocs.plugins.odomgym")

ROOT = Path(__file__).resolve().parents[1]

API: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "core": (
        "Core",
        "The package's public names and the foundation below every layer folder: robot and "
        "floor specs, the compiled kernels, files, errors, interruption, the worker pool and "
        "the Ray backend "
        "(docs/architecture.md shows how the layers fit).",
        (
            "odomgym",
            "odomgym.robot",
            "odomgym.floor",
            "odomgym.workers",
            "odomgym.distributed",
            "odomgym.io",
            "odomgym.errors",
            "odomgym.interrupt",
        ),
    ),
    "odometry": (
        "Odometry",
        "Dead reckoning from encoder counts, the run record and the measures taken on runs "
        "(UMBmark's and OptiOdom's).",
        (
            "odomgym.odometry",
            "odomgym.odometry.calibration",
            "odomgym.odometry.runs",
            "odomgym.odometry.umbmark_measures",
            "odomgym.odometry.optiodom_measures",
            "odomgym.odometry.icr",
        ),
    ),
    "sim": (
        "Simulation",
        "The batched pymunk World, cables, routes, the reference driver, the Trial that "
        "steps them with the odometry, and steady turns (a skid-steer robot's apparent track).",
        (
            "odomgym.sim",
            "odomgym.sim.world",
            "odomgym.sim.chipmunk_link",
            "odomgym.sim.cables",
            "odomgym.sim.routes",
            "odomgym.sim.driver",
            "odomgym.sim.trial",
            "odomgym.sim.route_runs",
            "odomgym.sim.arc_runs",
            "odomgym.sim.turns",
        ),
    ),
    "lab": (
        "Labs and experiments",
        "Experiments, the Lab protocol, the simulated and recorded labs, the lockstep, plans, "
        "the benchmark population and the reports of runs.",
        (
            "odomgym.lab",
            "odomgym.lab.experiment",
            "odomgym.lab.simulated",
            "odomgym.lab.lockstep",
            "odomgym.lab.recorded",
            "odomgym.lab.plans",
            "odomgym.lab.population",
            "odomgym.lab.report",
        ),
    ),
    "noise": (
        "Noise",
        "The random part of odometry error: Chong & Kleeman's covariance, its Monte Carlo, "
        "fitting k_L, k_R and the paper's experiment.",
        (
            "odomgym.noise",
            "odomgym.noise.covariance",
            "odomgym.noise.montecarlo",
            "odomgym.noise.fit",
            "odomgym.noise.experiment",
        ),
    ),
    "selfcal": (
        "Self-calibration",
        "The self-calibration session shared by the env, the training vector env and the "
        "calibrator.",
        (
            "odomgym.selfcal",
            "odomgym.selfcal.menu",
            "odomgym.selfcal.estimators",
            "odomgym.selfcal.session",
            "odomgym.selfcal.episodes",
        ),
    ),
    "vehicle": (
        "Vehicles and IPEC",
        "The two-truck CLAPPER (and the encoder trailer), its internal estimators and IPEC "
        "(Borenstein 1995).",
        (
            "odomgym.vehicle",
            "odomgym.vehicle.spec",
            "odomgym.vehicle.estimator",
            "odomgym.vehicle.ipec",
            "odomgym.vehicle.paths",
            "odomgym.vehicle.cable_layout",
            "odomgym.vehicle.controller",
            "odomgym.vehicle.trial",
            "odomgym.vehicle.paper_runs",
        ),
    ),
    "envs": (
        "Environments",
        "The Gymnasium envs (one page each under Environments), their shared base, the native "
        "vector env and the renderer.",
        (
            "odomgym.envs",
            "odomgym.envs.base",
            "odomgym.envs.info",
            "odomgym.envs.umbmark",
            "odomgym.envs.straight",
            "odomgym.envs.clapper",
            "odomgym.envs.selfcal",
            "odomgym.envs.vector",
            "odomgym.envs.render",
        ),
    ),
    "calibrators": (
        "Calibrators",
        "The calibration methods, their validation, the benchmark and the leaderboard.",
        (
            "odomgym.baselines",
            "odomgym.baselines.base",
            "odomgym.baselines.umbmark",
            "odomgym.baselines.jung_chung",
            "odomgym.baselines.lee",
            "odomgym.baselines.ivanjko",
            "odomgym.baselines.least_squares",
            "odomgym.baselines.trajectory",
            "odomgym.baselines.selfcal",
            "odomgym.baselines.selfcal_vec_env",
            "odomgym.baselines.selfcal_checkpoints",
            "odomgym.baselines.selfcal_train",
            "odomgym.baselines.validation",
            "odomgym.baselines.benchmark",
            "odomgym.baselines.benchmark.config",
            "odomgym.baselines.benchmark.chunk",
            "odomgym.baselines.benchmark.journal",
            "odomgym.baselines.benchmark.runner",
            "odomgym.baselines.benchmark.summary",
            "odomgym.baselines.bench_report",
            "odomgym.baselines.leaderboard",
        ),
    ),
    "data": (
        "Data and effects",
        "Reading measured logs (OptiOdom, odomgym's CSV, ROS 2 bags), the shipped samples, "
        "hyperparameters and policies, and the effect catalogue (docs/effects.md).",
        (
            "odomgym.data",
            "odomgym.data.optiodom",
            "odomgym.data.native",
            "odomgym.data.rosbag2",
            "odomgym.data.logs",
            "odomgym.data.gaps",
            "odomgym.data.samples",
            "odomgym.data.hyperparams",
            "odomgym.data.policies",
            "odomgym.effects",
            "odomgym.effects.registry",
            "odomgym.effects.geometry",
            "odomgym.effects.motion",
            "odomgym.effects.transmission",
            "odomgym.effects.noise",
            "odomgym.effects.sensor",
            "odomgym.effects.discovered",
            "odomgym.effects.term_replay",
        ),
    ),
    "diagnose": (
        "diagnose",
        "Where a model and a robot disagree, and what is missing (docs/diagnose.md).",
        (
            "odomgym.diagnose.workflow",
            "odomgym.diagnose.fleet",
            "odomgym.diagnose.loso",
            "odomgym.diagnose.screen",
            "odomgym.diagnose.config",
            "odomgym.diagnose.results",
            "odomgym.diagnose.journal",
            "odomgym.diagnose.rounds",
            "odomgym.diagnose.verdict",
            "odomgym.diagnose.replay",
            "odomgym.diagnose.likelihood",
            "odomgym.diagnose.stats",
            "odomgym.diagnose.fit",
            "odomgym.diagnose.where",
            "odomgym.diagnose.discover",
            "odomgym.diagnose.nuisances",
            "odomgym.diagnose.openloop",
            "odomgym.diagnose.physical",
            "odomgym.diagnose.gate",
            "odomgym.diagnose.heldout",
            "odomgym.diagnose.spread",
            "odomgym.diagnose.sensitivity",
            "odomgym.diagnose.confounds",
            "odomgym.diagnose.steps",
            "odomgym.diagnose.keep",
            "odomgym.diagnose.confirm",
            "odomgym.diagnose.experiments",
            "odomgym.diagnose.report",
            "odomgym.diagnose.plots",
            "odomgym.diagnose.generate",
        ),
    ),
}
"""API pages: file stem → (title, introduction, modules in page order)."""

NOT_IN_API = ("odomgym.__main__", "odomgym.cli")
"""Public modules (and their submodules) documented elsewhere than the API pages: the command
line, whose page is generated from its parser."""


def _public_modules() -> set[str]:
    """Every importable public module of odomgym (no part of its name starting with _)."""
    import odomgym
    import odomgym.baselines
    import odomgym.envs

    found = {"odomgym", "odomgym.envs", "odomgym.baselines"}
    for package in (odomgym, odomgym.envs, odomgym.baselines):
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            found.add(info.name)
    diagnose = ROOT / "odomgym" / "diagnose"
    found |= {f"odomgym.diagnose.{p.stem}" for p in diagnose.glob("*.py")}
    return {name for name in found if not any(part.startswith("_") for part in name.split("."))}


def _undocumented(module_name: str) -> list[str]:
    """The public classes and functions of a module without a docstring of their own."""
    module = importlib.import_module(module_name)
    if not (module.__doc__ or "").strip():
        return [module_name]
    names = getattr(module, "__all__", None)
    if names is None:
        names = [
            n
            for n, v in vars(module).items()
            if not n.startswith("_") and getattr(v, "__module__", None) == module_name
        ]
    missing = []
    for name in names:
        value = getattr(module, name)
        if inspect.isclass(value):
            own = value.__dict__.get("__doc__")  # not a base class's
        elif inspect.isfunction(value) or (callable(value) and hasattr(value, "__wrapped__")):
            own = value.__doc__
        else:
            continue  # constants: their docstrings are comments griffe reads, not checked here
        if not (own or "").strip():
            missing.append(f"{module_name}.{name}")
    return missing


def _api_page(stem: str) -> str:
    title, intro, modules = API[stem]
    blocks = "\n\n".join(f"::: {name}" for name in modules)
    return f"# {title}\n\n{intro}\n\n{blocks}\n"


def _cli_page() -> str:
    """Every command's help, generated from :func:`odomgym.cli.build_parser`."""
    os.environ["COLUMNS"] = "100"  # argparse wraps help to this width
    from odomgym.cli import build_parser

    parser = build_parser()
    parts = [
        "# Command line",
        "",
        "Generated at documentation build time from the argument parser itself "
        "(`odomgym.cli.build_parser()`), so it shows exactly what `odomgym COMMAND --help` "
        "prints.",
        "",
        "```text",
        parser.format_help().rstrip(),
        "```",
    ]

    def walk(p: argparse.ArgumentParser, prefix: str, depth: int) -> None:
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    command = f"{prefix} {name}"
                    heading = f"{'#' * depth} `{command}`"
                    parts.extend(["", heading, "", "```text", sub.format_help().rstrip(), "```"])
                    walk(sub, command, min(depth + 1, 4))

    walk(parser, "odomgym", 2)
    return "\n".join(parts) + "\n"


SOURCE_LAYOUT = ROOT / "build" / "docs-src"
"""Where :func:`on_config` lays out the package as installed (``mkdocs.yml``: ``paths``)."""


@event_priority(100)  # before mkdocstrings reads ``paths``: a fresh clone has no layout yet
def on_config(config: Any) -> Any:
    """Lay the source tree out as the installed package (``odomgym/envs`` and
    ``odomgym/baselines`` mapped in from the top-level folders, as setuptools' ``package-dir``
    does) with symbolic links, for mkdocstrings to read."""
    package = SOURCE_LAYOUT / "odomgym"
    if package.exists():
        shutil.rmtree(package)
    package.mkdir(parents=True)
    for entry in (ROOT / "odomgym").iterdir():
        if entry.name == "__pycache__":
            continue
        if entry.is_dir() and not (entry / "__init__.py").exists():
            # A namespace package (odomgym.diagnose): griffe finds its modules when the folder
            # has an __init__.py, so the copy gets an empty one.
            shutil.copytree(entry, package / entry.name, ignore=shutil.ignore_patterns("__py*"))
            (package / entry.name / "__init__.py").write_text("")
        elif entry.is_dir():
            (package / entry.name).symlink_to(entry)
        else:  # copied: griffe resolves a linked __init__.py to the folder without envs/
            shutil.copy2(entry, package / entry.name)
    for name in ("envs", "baselines"):
        (package / name).symlink_to(ROOT / name)
    return config


def on_files(files: Files, config: Any) -> Files:
    """Add the generated pages; check that every public module and name is documented."""
    for stem in API:
        files.append(File.generated(config, f"api/{stem}.md", content=_api_page(stem)))
    files.append(File.generated(config, "cli.md", content=_cli_page()))
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    files.append(File.generated(config, "changelog.md", content=changelog))
    listed = {name for _, _, modules in API.values() for name in modules}
    unlisted = {
        name
        for name in _public_modules() - listed
        if not any(name == skip or name.startswith(skip + ".") for skip in NOT_IN_API)
    }
    for name in sorted(unlisted):
        log.warning(f"public module {name} is on no API page (scripts/mkdocs_hooks.py, API)")
    for name in sorted(listed):
        for missing in _undocumented(name):
            log.warning(f"{missing}: a public name without a docstring")
    return files

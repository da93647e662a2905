"""A fleet of robots of one model, each diagnosed on its own logs, compared across the fleet.

A lab or a company runs tens of robots of one model. The questions are which effects recur,
which robot is the odd one out, and what moved since the last period of logs. This module:

* :func:`find_fleet` reads the layout ``ROBOTS/<robot>/robot.toml`` beside the robot's logs
  (any format :func:`odomgym.data.logs.read_log` reads: native CSV files, OptiOdom session
  folders, ROS 2 bags). Periods: when every log of a robot carries its date (OptiOdom
  sessions are named by their start, :func:`odomgym.data.optiodom.session_time`), a period is
  a calendar month (``2020-06``) and sub-folders only organise the logs (OptiOdom's
  ``square/``, ``circular/``); otherwise logs directly in the robot's folder belong to no
  period and logs in a sub-folder to the period named by it (``2026-10/``, ``after-repair/``).
  Every log is one session (its file or folder name), so the diagnosis holds out whole
  sessions when there are two or more.
* :func:`diagnose_fleet` diagnoses each robot on all its sessions (and, with two or more
  periods, each period on its own) with :func:`odomgym.diagnose.workflow.diagnose`; each
  robot's report folder is that diagnosis' output, written atomically, so an interrupted
  fleet resumes from the robots already done. With ``backend="ray"`` every diagnosis is one
  Ray task (:mod:`odomgym.distributed`); the reports are byte-identical to the local ones.
* :func:`summarise_fleet` reads the reports back and compares the robots:
  the effects and terms named and in how many robots; every parameter's values with their
  standard errors; the robots more than :data:`ODD_Z` robust standard deviations from the
  fleet (median and 1.4826 × the median absolute deviation, over the robots that name the
  effect, when at least :data:`MIN_NAMING` do); and per robot, what moved between periods.
* :func:`write_example_fleet` writes a fleet of simulated robots to try it on, with planted
  odd robots (``odomgym fleet --example``).

Units: the parameters' own (docs/effects.md).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from odomgym.data.logs import period_logs, session_name
from odomgym.errors import SpecError
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec, load_robot

__all__ = [
    "INPUTS_FILE",
    "MIN_NAMING",
    "ODD_Z",
    "ROBUST_SD",
    "ExamplePrior",
    "FleetRobot",
    "FleetSummary",
    "diagnose_fleet",
    "find_fleet",
    "format_fleet",
    "inputs_digest",
    "plot_fleet",
    "read_robot_runs",
    "summarise_fleet",
    "write_example_fleet",
]

ODD_Z = 3.0
"""A robot is odd on a parameter when it lies more than this many robust standard deviations
from the fleet's median [-]."""

MIN_NAMING = 5
"""Fewest robots that must name an effect before its parameters get a fleet distribution and
odd robots: below, its recurrence count is the finding [-]."""

ROBUST_SD = 1.4826
"""Median absolute deviation → standard deviation of a normal distribution [-]."""

_LOG_SUFFIXES = (".csv", ".mcap", ".db3")


@dataclass(frozen=True)
class FleetRobot:
    """One robot of a fleet: its name (the folder's), model and logs.

    Attributes:
        name: the robot's folder name.
        folder: the folder.
        robot: the nominal model from its ``robot.toml``.
        logs: (period, path) per log; period ``""`` for logs directly in the folder.
        reading: options of :func:`odomgym.data.logs.read_log` its logs need, as (name, value)
            pairs: a ROS 2 bag's topics and joint names (``odomgym fleet --pose-topic`` …);
            empty for formats that need none.
    """

    name: str
    folder: Path
    robot: RobotSpec
    logs: tuple[tuple[str, Path], ...]
    reading: tuple[tuple[str, str], ...] = ()

    @property
    def periods(self) -> tuple[str, ...]:
        """The periods its logs come from, sorted (``("",)`` when none is named)."""
        return tuple(sorted({period for period, _ in self.logs}))


def _is_log(path: Path) -> bool:
    """A log file, or a folder that holds a log format's own layout (OptiOdom, ROS 2 bag)."""
    if path.name.startswith("."):
        return False
    if path.is_file():
        return path.suffix.lower() in _LOG_SUFFIXES
    return any(path.glob("*_metadata.csv")) or (path / "metadata.yaml").exists()


def _log_month(path: Path) -> str | None:
    """The calendar month (``YYYY-MM``) a log was recorded in, where its format says so (an
    OptiOdom session folder named by its start), else None."""
    from odomgym.data.optiodom import session_time

    if not (path.is_dir() and (path / f"{path.name}_metadata.csv").exists()):
        return None
    when = session_time(path.name)
    return f"{when:%Y-%m}" if when is not None else None


def find_fleet(root: str | Path, reading: Mapping[str, str] | None = None) -> list[FleetRobot]:
    """The robots under ``root`` (one sub-folder each, sorted by name); ``reading``: the
    options of :func:`odomgym.data.logs.read_log` every robot's logs are read with
    (:attr:`FleetRobot.reading`; a fleet's robots are of one kind, logged alike).

    Raises:
        SpecError: ``root`` is not a folder or holds no robot folder; a robot folder has no
            ``robot.toml`` (or an invalid one: its error names field, file and line) or no
            log.
    """
    where = Path(root)
    if not where.is_dir():
        raise SpecError("not a folder of robot folders", field="ROBOTS", source=str(where))
    robots = []
    for folder in sorted(p for p in where.iterdir() if p.is_dir() and not p.name.startswith(".")):
        toml = folder / "robot.toml"
        if not toml.exists():
            raise SpecError(
                "a robot folder needs its robot.toml (the nominal model its logs are "
                "diagnosed against)",
                field="robot.toml",
                source=str(folder),
            )
        robot = load_robot(toml)
        logs = period_logs(folder, _is_log)
        months = [_log_month(path) for _, path in logs]
        if logs and all(months):  # the logs carry their dates: periods are months
            logs = [(str(month), path) for month, (_, path) in zip(months, logs, strict=True)]
        loose = [path.name for period, path in logs if not period]
        grouped = sorted({period for period, _ in logs if period})
        if loose and grouped:
            # Their period would be "" beside named ones, and its report folder the robot's
            # periods folder itself, holding the others' (a user's fleet broke that way).
            raise SpecError(
                f"holds logs both directly ({loose[0]}) and in period sub-folders "
                f"({grouped[0]}/): put every log in a period sub-folder, or all of them "
                "directly in the robot folder",
                field="logs",
                source=str(folder),
            )
        if not logs:
            raise SpecError(
                "no log in this robot folder (native .csv files, OptiOdom session folders or "
                "ROS 2 bags, directly or in one sub-folder per period)",
                field="logs",
                source=str(folder),
            )
        options = tuple(sorted((reading or {}).items()))
        robots.append(FleetRobot(folder.name, folder, robot, tuple(logs), options))
    if not robots:
        raise SpecError(
            "no robot folder (each sub-folder holds one robot's robot.toml and logs)",
            field="ROBOTS",
            source=str(where),
        )
    return robots


def read_robot_runs(robot: FleetRobot) -> list[Run]:
    """Every run of ``robot``, each marked with its session (the period and the log's name)
    and period in ``run.meta``."""
    from odomgym.data.logs import read_log

    runs: list[Run] = []
    for period, path in robot.logs:
        log_runs, _ = read_log(path, robot=robot.robot, format=None, **dict(robot.reading))
        session = session_name(period, path)
        for run in log_runs:
            run.meta["session"] = str(run.meta.get("session") or session)
            run.meta["period"] = period
        runs.extend(log_runs)
    return runs


def report_folders(robots: Sequence[FleetRobot], out: Path) -> list[Path]:
    """The report folders :func:`diagnose_fleet` writes under ``out``: each robot's, and each
    period's of a robot with two or more (``odomgym fleet`` checks them before any work)."""
    return [folder for *_, folder in _units(robots, out)]


def _units(robots: Sequence[FleetRobot], out: Path) -> list[tuple[FleetRobot, str, str, Path]]:
    """The diagnoses a fleet needs, as (robot, period, label, report folder): each robot on all
    its sessions, and each period of a robot with two or more on its own (period ``""``: all)."""
    units = []
    for robot in robots:
        units.append((robot, "", robot.name, out / "robots" / robot.name))
        if len(robot.periods) > 1:
            units += [
                (robot, period, f"{robot.name} {period}", out / "periods" / robot.name / period)
                for period in robot.periods
            ]
    return units


INPUTS_FILE = "inputs.json"
"""The fleet output's record of what each report was made from (:func:`inputs_digest` per
diagnosis label), which ``resume`` compares before it keeps a report."""


def inputs_digest(robot: FleetRobot, period: str, config: Any, baseline: Any) -> str:
    """A SHA-256 over everything a diagnosis' report depends on: the odomgym version, the
    options (``config``'s fields but ``jobs``, which changes no result, and the baseline's
    name), the robot's ``robot.toml`` and every file of its logs of ``period`` (all logs for
    ``""``), names and bytes. Why: ``resume`` kept a robot's report after its logs were
    replaced (a user's fleet reported last month's values for it, without a word)."""
    import dataclasses
    import hashlib

    from odomgym import __version__

    options: dict[str, Any] = {"odomgym": __version__}
    if config is not None:
        options.update(
            (f.name, repr(getattr(config, f.name)))
            for f in dataclasses.fields(config)
            if f.name != "jobs"
        )
    named = None if baseline is None else getattr(baseline, "__qualname__", repr(baseline))
    options["baseline"] = named
    if robot.reading:  # only when given, so that the digests of other fleets stay as they were
        options["reading"] = [list(pair) for pair in robot.reading]
    digest = hashlib.sha256(json.dumps(options, sort_keys=True).encode())
    files = [robot.folder / "robot.toml"]
    for log_period, path in robot.logs:
        if not period or log_period == period:
            files += [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for path in files:
        digest.update(path.relative_to(robot.folder).as_posix().encode() + b"\0")
        with path.open("rb") as handle:
            digest.update(hashlib.file_digest(handle, "sha256").digest())
    return digest.hexdigest()


def _read_inputs(path: Path) -> dict[str, str]:
    """The record :data:`INPUTS_FILE` (label → digest); empty when missing or unreadable (its
    reports are then made again, never kept on trust)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    units = data.get("units") if isinstance(data, dict) else None
    if not isinstance(units, dict):
        return {}
    return {str(k): str(v) for k, v in units.items()}


def _diagnose_files(
    runs: list[Run],
    robot: RobotSpec,
    config: Any,
    baseline: Callable[[], Any] | None,
    source: str,
    progress: Callable[[str, float], None] | None = None,
) -> tuple[str, dict[str, bytes]]:
    """One diagnosis, here or as a Ray task: its verdict and its report folder's files (name →
    bytes), written in a temporary folder and carried back, so the driver writes every file
    (:func:`_write_folder`) whichever backend ran it and a cluster needs no shared file
    system."""
    import tempfile

    from odomgym.diagnose.report import write_outputs
    from odomgym.diagnose.workflow import diagnose

    trusted = baseline() if baseline is not None else None
    diagnosis = diagnose(runs, robot, config, baseline=trusted, progress=progress)
    with tempfile.TemporaryDirectory() as tmp:
        written = write_outputs(diagnosis, Path(tmp) / "report", source)
        files = {path.name: path.read_bytes() for path in written}
    return diagnosis.verdict, files


def _write_folder(folder: Path, files: dict[str, bytes]) -> None:
    """Replace ``folder`` by one holding ``files`` (name → bytes), atomically
    (:func:`odomgym.io.atomic_folder`), unless it holds anything a report does not
    (:func:`odomgym.diagnose.report.check_replaceable`)."""
    from odomgym.diagnose.report import check_replaceable
    from odomgym.io import atomic_folder

    check_replaceable(folder)

    def fill(tmp: Path) -> None:
        for name, data in files.items():
            (tmp / name).write_bytes(data)

    atomic_folder(folder, fill)


def diagnose_fleet(
    robots: Sequence[FleetRobot],
    out: Path,
    *,
    config: Any = None,
    baseline: Callable[[], Any] | None = None,
    resume: bool = False,
    progress: Callable[[str], Callable[[str, float], None]] | None = None,
    status: Callable[[str], None] | None = None,
    backend: str = "local",
    address: str | None = None,
    done: Callable[[int, int], None] | None = None,
    loso: bool = False,
) -> list[Path]:
    """Diagnose every robot into ``out/robots/<name>/`` and, for a robot of two or more
    periods, each period into ``out/periods/<name>/<period>/``; returns the report folders.
    With ``resume``, a report already there is not made again when :data:`INPUTS_FILE`
    records it as made from the same logs, ``robot.toml`` and options
    (:func:`inputs_digest`); one whose inputs changed, or are not recorded, is made again and
    ``status`` says so. ``baseline()`` makes the
    trusted calibration each diagnosis compares with (:class:`odomgym.diagnose.heldout.
    Baseline`; ``odomgym fleet`` passes the trajectory calibration's), none if omitted;
    ``status`` receives one line per diagnosis as it ends, ``done(finished, total)`` the count.

    ``backend``: ``local`` diagnoses one robot after the other here, each with ``config.jobs``
    worker processes for its candidate fits, and ``progress(label)`` gives the callback of
    each one's progress bar; ``ray`` makes every diagnosis one Ray task on the cluster at
    ``address`` (or ``RAY_ADDRESS``; else a local Ray of ``config.jobs`` CPUs), whose report
    files come back to be written here (:mod:`odomgym.distributed`). The reports are
    byte-identical either way (tested).

    ``loso``: then, for every robot of two or more sessions, its leave-one-session-out folds
    (:func:`odomgym.diagnose.loso.run_loso`) into ``out/loso/<name>/``, one fold file per
    session, run on the same backend; with ``resume`` a fold file already there is kept (not
    made again), without it every fold is made again. :func:`summarise_fleet` reports their
    stability."""
    from odomgym.distributed import Backend, ray_session

    chosen_backend = Backend(backend)
    chosen_backend.check_available()
    if chosen_backend is Backend.RAY:  # one Ray for the diagnoses and the folds
        with ray_session(address, getattr(config, "jobs", 1) or 1) as started:
            return _diagnose_fleet(
                robots, out, config, baseline, resume, progress, status, started, done, loso
            )
    return _diagnose_fleet(
        robots, out, config, baseline, resume, progress, status, None, done, loso
    )


def _diagnose_fleet(
    robots: Sequence[FleetRobot],
    out: Path,
    config: Any,
    baseline: Callable[[], Any] | None,
    resume: bool,
    progress: Callable[[str], Callable[[str, float], None]] | None,
    status: Callable[[str], None] | None,
    ray_started: bool | None,
    done: Callable[[int, int], None] | None,
    loso: bool,
) -> list[Path]:
    """:func:`diagnose_fleet` once its backend is settled: ``ray_started`` None runs here,
    else inside a Ray session (True: started by this call, which an interruption shuts
    down)."""
    import dataclasses

    from odomgym.distributed import run_ray_tasks
    from odomgym.io import atomic_write_text

    units = _units(robots, out)
    folders = [folder for *_, folder in units]
    digests = {
        label: inputs_digest(robot, period, config, baseline) for robot, period, label, _ in units
    }
    recorded = _read_inputs(out / INPUTS_FILE) if resume else {}
    # What is recorded stays only for reports kept: a label diagnosed again gets its new digest.
    made = {label: digest for label, digest in recorded.items() if digests.get(label) == digest}
    todo = []
    for unit in units:
        robot, _, label, folder = unit
        if resume and (folder / "report.json").exists():
            if made.get(label) == digests[label]:
                if status is not None:
                    status(f"{label}: done before, kept")
                continue
            if status is not None:
                status(
                    f"{label}: its logs, robot.toml or the options changed since its report "
                    f"(or {INPUTS_FILE} does not record them): diagnosed again"
                )
        todo.append(unit)
    # A robot diagnosed again has its leave-one-session-out folds made again too.
    again = {robot.name for robot, period, _, _ in todo if not period}
    finished = len(units) - len(todo)
    if done is not None:
        done(finished, len(units))
    cache: dict[str, list[Run]] = {}  # a robot's logs, read once for all its diagnoses

    def runs_of(robot: FleetRobot, period: str) -> list[Run]:
        if robot.name not in cache:
            cache.clear()  # the robots come in order: keep one robot's runs at a time
            cache[robot.name] = read_robot_runs(robot)
        runs = cache[robot.name]
        return [r for r in runs if r.meta["period"] == period] if period else runs

    def record(key: int, result: tuple[str, dict[str, bytes]]) -> None:
        nonlocal finished
        verdict, files = result
        _write_folder(todo[key][3], files)
        made[todo[key][2]] = digests[todo[key][2]]
        atomic_write_text(
            out / INPUTS_FILE, json.dumps({"units": dict(sorted(made.items()))}, indent=1) + "\n"
        )
        finished += 1
        if status is not None:
            status(f"{todo[key][2]}: {verdict}")
        if done is not None:
            done(finished, len(units))

    if ray_started is not None:
        # A Ray task holds one CPU: its candidate fits run one after the other, which changes
        # no result (odomgym.diagnose.fit.run_fit_jobs).
        one = dataclasses.replace(config, jobs=1) if config is not None else None
        tasks = (
            (k, (runs_of(robot, period), robot.robot, one, baseline, str(robot.folder)))
            for k, (robot, period, _, _) in enumerate(todo)
        )
        run_ray_tasks(_diagnose_files, tasks, record, started=ray_started)
    else:
        for k, (robot, period, label, _) in enumerate(todo):
            callback = progress(label) if progress is not None else None
            runs = runs_of(robot, period)
            record(
                k, _diagnose_files(runs, robot.robot, config, baseline, str(robot.folder), callback)
            )
    if loso:
        backend = "local" if ray_started is None else "ray"
        _fleet_loso(robots, out, config, baseline, backend, status, runs_of, resume, again)
    return folders


def _fleet_loso(
    robots: Sequence[FleetRobot],
    out: Path,
    config: Any,
    baseline: Callable[[], Any] | None,
    backend: str,
    status: Callable[[str], None] | None,
    runs_of: Callable[[FleetRobot, str], list[Run]],
    resume: bool,
    again: set[str],
) -> None:
    """Every robot's leave-one-session-out folds into ``out/loso/<name>/`` (those of two or
    more sessions). With ``resume`` the fold files already there are kept, but for the robots
    in ``again`` (diagnosed again by this call: new, or their inputs changed); without, they
    are made again, as every report is (a user's changed logs had kept their old folds)."""
    from odomgym.diagnose.loso import run_loso
    from odomgym.diagnose.nuisances import sessions_of

    for robot in robots:
        if not resume or robot.name in again:
            for stale in sorted((out / "loso" / robot.name).glob("fold-*.json")):
                stale.unlink()
        runs = runs_of(robot, "")
        if len(set(sessions_of(runs))) < 2:
            if status is not None:
                status(f"{robot.name}: one session, no leave-one-session-out folds")
            continue
        folds, summary = run_loso(
            runs,
            robot.robot,
            out / "loso" / robot.name,
            config=config,
            baseline=baseline,
            backend=backend,
        )
        if status is not None:
            status(
                f"{robot.name}: {len(folds)} leave-one-session-out folds, the same systematic "
                f"effects in {summary['folds_with_modal_set']}"
            )


# ---------------------------------------------------------------------------- the summary
@dataclass
class FleetSummary:
    """What the fleet's reports say together (:func:`summarise_fleet`).

    Attributes:
        robots: the robots' names, in order.
        stability: robot → its leave-one-session-out folds' checks (``fleet --loso``):
            ``folds``, ``folds_with_modal_set`` ("k/n"), ``modal_effect_set``,
            ``intervals_overlap`` (E_d, E_b, E_s: do the folds' 95 % intervals share a part;
            None when no fold has one)
            and ``better_than_as_given`` ("k/n"); timing left out, so the summary is the same
            wherever the folds ran.
        verdicts: each robot's verdict.
        named: effect → the robots that name it.
        terms: discovered term → the robots that keep it.
        values: (effect, parameter) → robot → (value, standard error) for the robots naming it.
        fleet: (effect, parameter) → {"median", "robust_sd", "robots"} where at least
            :data:`MIN_NAMING` robots name the effect.
        odd: (robot, effect, parameter, value, robust z) for every robot beyond :data:`ODD_Z`.
        moved: (robot, effect, parameter, first period, last period, change, z) between a
            robot's first and last period where the change is beyond 3 combined standard errors.
    """

    robots: list[str]
    verdicts: dict[str, str]
    named: dict[str, list[str]] = field(default_factory=dict)
    terms: dict[str, list[str]] = field(default_factory=dict)
    values: dict[tuple[str, str], dict[str, tuple[float, float]]] = field(default_factory=dict)
    fleet: dict[tuple[str, str], dict[str, float]] = field(default_factory=dict)
    odd: list[tuple[str, str, str, float, float]] = field(default_factory=list)
    moved: list[tuple[str, str, str, str, str, float, float]] = field(default_factory=list)
    stability: dict[str, dict[str, Any]] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (the keys of tuples joined by ``.``)."""
        return {
            "robots": self.robots,
            "verdicts": self.verdicts,
            "named": self.named,
            "terms": self.terms,
            "values": {
                f"{e}.{p}": {r: {"value": v, "stderr": s} for r, (v, s) in per.items()}
                for (e, p), per in self.values.items()
            },
            "fleet": {f"{e}.{p}": stats for (e, p), stats in self.fleet.items()},
            "odd": [
                {"robot": r, "effect": e, "parameter": p, "value": v, "robust_z": z}
                for r, e, p, v, z in self.odd
            ],
            "moved": [
                {"robot": r, "effect": e, "parameter": p, "from": a, "to": b, "change": d, "z": z}
                for r, e, p, a, b, d, z in self.moved
            ],
            "stability": self.stability,
        }


def _report(folder: Path) -> dict[str, Any]:
    path = folder / "report.json"
    try:
        data: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SpecError("no report here: diagnose the fleet first", source=str(path)) from None
    return data


def _parameters(report: dict[str, Any]) -> dict[tuple[str, str], tuple[float, float]]:
    out = {}
    for effect, parameters in report.get("parameters", {}).items():
        for name, entry in parameters.items():
            out[(effect, name)] = (float(entry["value"]), float(entry.get("stderr", math.nan)))
    return out


def _stability(out: Path, names: Sequence[str]) -> dict[str, dict[str, Any]]:
    """The leave-one-session-out checks of every robot with fold files under ``out/loso/``."""
    from odomgym.diagnose.loso import fold_numbers, summarise

    stability = {}
    for name in names:
        files = sorted((out / "loso" / name).glob("fold-*.json"))
        if not files:
            continue
        folds = [fold_numbers(json.loads(path.read_text(encoding="utf-8"))) for path in files]
        checks = summarise(folds)
        stability[name] = {
            "folds": checks["folds"],
            "folds_with_modal_set": checks["folds_with_modal_set"],
            "modal_effect_set": checks["modal_effect_set"],
            "intervals_overlap": {k: v["overlap"] for k, v in checks["intervals"].items()},
            "better_than_as_given": checks["better_than_as_given"],
        }
    return stability


def summarise_fleet(out: Path, robots: Sequence[FleetRobot], *, loso: bool = True) -> FleetSummary:
    """Read the reports :func:`diagnose_fleet` wrote under ``out`` and compare the robots;
    with ``loso``, also the stability of the leave-one-session-out folds found there (``odomgym
    fleet`` reads them only with ``--loso``: a fresh report without it showed folds of an
    earlier call)."""
    names = [robot.name for robot in robots]
    summary = FleetSummary(robots=names, verdicts={})
    for robot in robots:
        report = _report(out / "robots" / robot.name)
        summary.verdicts[robot.name] = str(report.get("verdict", ""))
        for effect in report.get("named_effects", []):
            summary.named.setdefault(str(effect), []).append(robot.name)
        # report.json lists the kept terms under "discovered" ("terms_kept" is their count).
        for entry in report.get("discovered", []):
            summary.terms.setdefault(str(entry["term"]), []).append(robot.name)
        for key, estimate in _parameters(report).items():
            if key[0] in report.get("named_effects", []):
                summary.values.setdefault(key, {})[robot.name] = estimate
        if len(robot.periods) > 1:
            first, last = robot.periods[0], robot.periods[-1]
            before = _parameters(_report(out / "periods" / robot.name / first))
            after = _parameters(_report(out / "periods" / robot.name / last))
            for key in sorted(set(before) & set(after)):
                (a, sa), (b, sb) = before[key], after[key]
                spread = math.hypot(sa, sb)
                z = (b - a) / spread if spread > 0.0 else math.inf
                if abs(z) > 3.0:
                    summary.moved.append((robot.name, *key, first, last, b - a, z))
    for key, per in sorted(summary.values.items()):
        if len(per) < MIN_NAMING:
            continue
        values = np.array([v for v, _ in per.values()])
        median = float(np.median(values))
        robust = ROBUST_SD * float(np.median(np.abs(values - median)))
        summary.fleet[key] = {"median": median, "robust_sd": robust, "robots": len(per)}
        if robust <= 0.0:
            continue
        for name, (value, _) in per.items():
            z = (value - median) / robust
            if abs(z) > ODD_Z:
                summary.odd.append((name, *key, value, z))
    summary.stability = _stability(out, names) if loso else {}
    summary.named = dict(sorted(summary.named.items(), key=lambda kv: (-len(kv[1]), kv[0])))
    summary.terms = dict(sorted(summary.terms.items(), key=lambda kv: (-len(kv[1]), kv[0])))
    return summary


def format_fleet(summary: FleetSummary, source: str) -> str:
    """The fleet report as Markdown (``fleet.md``)."""
    n = len(summary.robots)
    lines = [f"# Fleet report: {n} robots ({source})", "", "## Effects and terms named", ""]
    lines += ["| effect or term | robots | which |", "|---|---|---|"]
    for what, robots in [*summary.named.items(), *summary.terms.items()]:
        lines.append(f"| `{what}` | {len(robots)} of {n} | {', '.join(robots)} |")
    if not summary.named and not summary.terms:
        lines.append("| (none) | | |")
    lines += ["", "## Parameters across the fleet", ""]
    lines += [
        f"Median and robust standard deviation (1.4826 × median absolute deviation) over the "
        f"robots naming the effect, when at least {MIN_NAMING} do.",
        "",
        "| parameter | robots | median | robust s.d. | range |",
        "|---|---|---|---|---|",
    ]
    for (effect, name), per in sorted(summary.values.items()):
        values = [v for v, _ in per.values()]
        stats = summary.fleet.get((effect, name))
        median = f"{stats['median']:.6g}" if stats else "—"
        robust = f"{stats['robust_sd']:.3g}" if stats else f"(fewer than {MIN_NAMING})"
        lines.append(
            f"| `{effect}.{name}` | {len(per)} | {median} | {robust} | "
            f"{min(values):.6g} … {max(values):.6g} |"
        )
    lines += ["", f"## Odd robots (more than {ODD_Z:g} robust s.d. from the fleet)", ""]
    if summary.odd:
        lines += ["| robot | parameter | value | robust z |", "|---|---|---|---|"]
        for robot, effect, name, value, z in sorted(summary.odd):
            lines.append(f"| {robot} | `{effect}.{name}` | {value:.6g} | {z:+.1f} |")
    else:
        lines.append("None.")
    lines += ["", "## What moved between periods", ""]
    if summary.moved:
        lines += ["| robot | parameter | from → to | change | z |", "|---|---|---|---|---|"]
        for robot, effect, name, a, b, change, z in summary.moved:
            lines.append(f"| {robot} | `{effect}.{name}` | {a} → {b} | {change:+.4g} | {z:+.1f} |")
    else:
        lines.append("Nothing beyond three combined standard errors (or one period per robot).")
    if summary.stability:
        lines += ["", "## Stability: leave one session out (`--loso`)", ""]
        lines += [
            "Each robot diagnosed once per session, on its other sessions: in how many folds "
            "the most frequent set of systematic effects was named, whether the folds' 95 % "
            "intervals of E_d, E_b, E_s share a part, and in how many folds the left-out "
            "session was predicted better than by the model as given.",
            "",
            "| robot | folds | the same effects in | that set | E_d, E_b, E_s overlap | "
            "left-out session better |",
            "|---|---|---|---|---|---|",
        ]
        for robot, st in summary.stability.items():
            overlap = ", ".join(
                "—" if ok is None else ("yes" if ok else "**no**")
                for ok in st["intervals_overlap"].values()
            )
            lines.append(
                f"| {robot} | {st['folds']} | {st['folds_with_modal_set']} | "
                f"{', '.join(st['modal_effect_set']) or '—'} | {overlap} | "
                f"{st['better_than_as_given']} |"
            )
    lines += ["", "## Verdicts", "", "| robot | verdict |", "|---|---|"]
    lines += [f"| {r} | {summary.verdicts[r]} |" for r in summary.robots]
    return "\n".join(lines) + "\n"


def plot_fleet(summary: FleetSummary, out: Path) -> list[Path]:
    """One figure per effect named by any robot (``fleet_<effect>.png``): each parameter's
    value per robot with its standard error, the fleet median and its ±3 robust s.d. band,
    the odd robots in red. Figures of this name left by an earlier call for an effect no robot
    names now are removed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from odomgym.io import atomic_writer

    written = []
    odd = {(r, e, p) for r, e, p, _, _ in summary.odd}
    effects = sorted({e for e, _ in summary.values})
    for effect in effects:
        keys = sorted(k for k in summary.values if k[0] == effect)
        fig, axes = plt.subplots(len(keys), 1, figsize=(9, 2.8 * len(keys)), squeeze=False)
        for ax, key in zip(axes[:, 0], keys, strict=True):
            per = summary.values[key]
            index = [summary.robots.index(r) for r in per]
            values = [v for v, _ in per.values()]
            errors = [0.0 if not math.isfinite(s) else s for _, s in per.values()]
            colours = ["tab:red" if (r, *key) in odd else "tab:blue" for r in per]
            ax.errorbar(index, values, yerr=errors, fmt="none", ecolor="0.5", lw=1)
            ax.scatter(index, values, c=colours, zorder=3, s=24)
            stats = summary.fleet.get(key)
            if stats:
                m, s = stats["median"], stats["robust_sd"]
                ax.axhline(m, color="0.3", lw=1, label="fleet median")
                ax.axhspan(
                    m - ODD_Z * s, m + ODD_Z * s, color="0.85", label=f"±{ODD_Z:g} robust s.d."
                )
                ax.legend(fontsize=8, loc="best")
            ax.set_xticks(range(len(summary.robots)), summary.robots, rotation=60, fontsize=7)
            ax.set_ylabel(f"{key[1]} [-]" if key[1].startswith("e_") else key[1])
            ax.set_title(f"{effect}.{key[1]}: {len(per)} of {len(summary.robots)} robots name it")
            ax.grid(True, alpha=0.3)
        fig.tight_layout()
        path = out / f"fleet_{effect}.png"
        atomic_writer(path, _saver(fig))
        plt.close(fig)
        written.append(path)
    # A figure of an effect no robot names any longer (an earlier call's) would sit beside
    # this report as if it were one of its figures.
    for stale in sorted(out.glob("fleet_*.png")):
        if stale not in written:
            stale.unlink()
    return written


def _saver(fig: Any) -> Callable[[Path], None]:
    """Save ``fig`` as PNG to the path given (for :func:`odomgym.io.atomic_writer`)."""

    def save(path: Path) -> None:
        fig.savefig(path, dpi=100, format="png")

    return save


# ---------------------------------------------------------------------------- an example
@dataclass(frozen=True)
class ExamplePrior:
    """The prior the example fleet's robots are drawn from (standard deviations of normal
    draws around 1, probabilities and ranges of the optional effects).

    Attributes:
        e_b_sd, e_s_sd: spread of E_b and E_s [-].
        toe_p, toe_range: chance a robot's wheels are toed, and the angle's range [rad].
        backlash_p, backlash_range: chance of gear backlash, and its range [rad].
        odd_sd: how far the planted robots lie, in the prior's standard deviations [-].
    """

    e_b_sd: float = 0.01
    e_s_sd: float = 0.005
    toe_p: float = 0.3
    toe_range: tuple[float, float] = (0.01, 0.02)
    backlash_p: float = 0.3
    backlash_range: tuple[float, float] = (0.01, 0.03)
    odd_sd: float = 5.0


def write_example_fleet(
    out: Path,
    robots: int,
    *,
    seed: int = 0,
    model: str = "labmate",
    sessions: int = 3,
    floor: str = "concrete",
    prior: ExamplePrior | None = None,
) -> dict[str, Any]:
    """Write ``robots`` simulated robots of preset ``model`` under ``out`` in the fleet layout
    (``robot.toml`` = the nominal preset, one native CSV per session of the ``rich`` protocol of
    :mod:`odomgym.diagnose.generate` on ``floor``), each carrying effects drawn from ``prior``;
    two robots (one if fewer than ten) get a planted odd E_b or E_s. Returns the truth (also
    written to ``out/truth.json``), which the fleet command never reads."""
    from odomgym.data.native import write_native
    from odomgym.diagnose.generate import simulate_protocol
    from odomgym.floor import FLOORS
    from odomgym.io import atomic_write_text
    from odomgym.robot import PRESETS

    if robots < 2:
        raise SpecError(f"an example fleet needs at least 2 robots, got {robots}", field="example")
    if model not in PRESETS:
        raise SpecError(f"unknown robot model {model!r}", field="model")
    if floor not in FLOORS:
        raise SpecError(f"unknown floor {floor!r}; floors: {', '.join(FLOORS)}", field="floor")
    p = prior if prior is not None else ExamplePrior()
    rng = np.random.default_rng(seed)
    base = PRESETS[model].ideal()
    planted_count = 2 if robots >= 10 else 1
    planted = {int(i) for i in rng.choice(robots, size=planted_count, replace=False)}
    truth: dict[str, Any] = {"model": model, "floor": floor, "seed": seed, "robots": {}}
    width = len(str(robots))
    for k in range(robots):
        name = f"robot-{k + 1:0{width}d}"
        e_b = 1.0 + p.e_b_sd * float(rng.standard_normal())
        e_s = 1.0 + p.e_s_sd * float(rng.standard_normal())
        odd = None
        if k in planted:
            sign = 1.0 if rng.random() < 0.5 else -1.0
            if len(planted) == 1 or k == min(planted):
                e_b, odd = 1.0 + sign * p.odd_sd * p.e_b_sd, "wheelbase.e_b"
            else:
                e_s, odd = 1.0 + sign * p.odd_sd * p.e_s_sd, "distance_scale.e_s"
        effects: dict[str, dict[str, float]] = {}
        if rng.random() < p.toe_p:
            effects["wheel_toe"] = {"angle": float(rng.uniform(*p.toe_range))}
        if rng.random() < p.backlash_p:
            effects["backlash"] = {"angle": float(rng.uniform(*p.backlash_range))}
        true = base.with_errors(1.0, e_b, e_s)
        for effect, values in effects.items():
            true = true.apply_effect(effect, values)
        folder = out / name
        folder.mkdir(parents=True, exist_ok=True)
        base.save(folder / "robot.toml")
        for s in range(sessions):
            runs = simulate_protocol(true, "rich", rng, floor=FLOORS[floor])
            write_native(folder / f"session-{s + 1}.csv", runs)
        truth["robots"][name] = {"e_b": e_b, "e_s": e_s, "effects": effects, "planted": odd}
    atomic_write_text(out / "truth.json", json.dumps(truth, indent=1) + "\n")
    return truth

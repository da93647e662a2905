"""Leave one session out: is a diagnosis a finding about the robot, or about the sessions it saw?

One diagnosis of all sessions says which effects the data support; it does not say whether
another set of sessions of the same robot would say the same. Leaving each session out in turn
answers that with the data at hand (cross-validation over whole sessions, the clusters of the
data: Hastie, Tibshirani & Friedman 2009, §7.10). For every session ``S`` (a *fold*):

* every other session is diagnosed (:func:`odomgym.diagnose.workflow.diagnose`, with its own
  held-out split inside them);
* ``S``, never seen by any step, is predicted open loop by the model as given, the diagnosed
  model and, when a baseline calibration is given, the baseline's geometry from the same fit
  runs — each with ``S``'s measurement nuisances (tracked point, yaw misalignment, time offset)
  fitted on ``S``'s own runs with the model fixed
  (:func:`odomgym.diagnose.openloop.evaluate_open_loop`).

:func:`summarise` then checks what a replication needs: the same systematic effects named in
every fold (as sets: the order a fold's rounds named them is not a finding); overlapping 95 %
intervals of E_d, E_b, E_s (session-clustered standard errors, Student's t on G − 1 degrees of
freedom for G fitted sessions: Cameron & Miller 2015); the left-out session predicted better
than by the model as given in every fold, and how often at least as well as the baseline.

Each fold's result is one JSON file, ``OUT/fold-<session>.json``, written atomically
(:func:`odomgym.io.atomic_write_text`) as the fold ends. A fold whose file exists is read, not
diagnosed again, so an interrupted run resumes where it stopped, and ``shard=(K, N)`` runs only
folds K, K + N, … so that N processes (or machines sharing ``OUT``) split the work; a last call
with ``table_only`` gathers their files. A fold file is reused whatever options made it (its
``gate_order`` is checked): give a new ``OUT`` when the options change.

Folds are independent. With ``backend="local"`` they run one after the other here, each
diagnosis with ``config.jobs`` worker processes for its candidate fits; with ``backend="ray"``
each fold is one Ray task (:mod:`odomgym.distributed`; the diagnosis inside on one CPU), whose
result comes back to this process, which writes the file (no shared file system needed). A
fold is a function of its runs, robot and options only, so both give the same fold files except
the timing fields (:data:`TIMING_FIELDS`: ``seconds``, the wall time of the fold's diagnosis
and, in the summary, their sum), which depend on the machine (tested, without them,
byte for byte).

Who uses it: ``odomgym diagnose DATA --loso`` and ``benchmarks/diagnose_loso.py`` (the 14 June
sessions of the OptiOdom robot, Sousa et al. 2022; the table in ``docs/diagnose.md``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np
from scipy import stats

from odomgym.diagnose.config import DiagnoseConfig
from odomgym.diagnose.heldout import AS_GIVEN, BASELINE, DIAGNOSED, Baseline
from odomgym.diagnose.nuisances import sessions_of
from odomgym.diagnose.openloop import NuisanceOptions, evaluate_open_loop
from odomgym.errors import SpecError
from odomgym.io import atomic_write_text
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "GEOMETRY",
    "TIMING_FIELDS",
    "fold",
    "fold_numbers",
    "fold_path",
    "fold_sessions",
    "parse_shard",
    "run_loso",
    "summarise",
    "table",
    "without_timing",
]

Fold = dict[str, Any]
"""One fold's result, as its JSON file holds it (keys: :func:`fold`)."""

GEOMETRY = (("wheel_diameter_ratio", "e_d"), ("wheelbase", "e_b"), ("distance_scale", "e_s"))
"""(effect, parameter) of the three geometry errors every fold reports: E_d = D_R/D_L,
E_b = b_actual/b_nominal, E_s = D_mean/D_nominal (dimensionless)."""

TIMING_FIELDS = frozenset({"seconds"})
"""Keys whose values are wall times [s] (a fold's diagnosis, the summary's sum): they differ
between machines and runs, and are the only ones that may (:func:`without_timing`)."""

CHECKPOINT_INTERVAL = 0.25
"""Seconds between the open-loop error's samples on the left-out session (the diagnosis's
default ``checkpoint_interval``)."""


def fold(
    runs: Sequence[Run],
    robot: RobotSpec,
    left_out: str,
    config: DiagnoseConfig | None = None,
    baseline: Callable[[], Baseline] | None = None,
) -> Fold:
    """Diagnose every session of ``runs`` but ``left_out``, then predict ``left_out`` open loop.

    A module-level function of its arguments only (the runs travel with it, not the data's
    location), so that it can run as a Ray task.

    Args:
        runs: every run, each with its session in ``meta["session"]`` (:func:`sessions_of`).
        robot: the model as given.
        left_out: the session left out.
        config: the diagnosis's options (default :class:`DiagnoseConfig`); ``jobs`` worker
            processes fit its candidates, which does not change the result.
        baseline: makes the calibration the diagnosis compares with (``odomgym diagnose``
            and the benchmark pass :class:`odomgym.baselines.trajectory.TrajectoryBaseline`:
            trajectory optimisation of b, D_R, D_L on the fit runs); None: no baseline.

    Returns:
        ``left_out``; ``gate_order``; ``runs`` (of the left-out session); ``seconds`` (wall
        time of the diagnosis [s]); ``verdict``; ``systematic_effects``; ``noise_model``;
        ``terms_kept``; ``terms_tried``; ``sessions_fitted``; ``geometry`` (``e_d``, ``e_b``,
        ``e_s``: ``value`` and ``stderr_sessions``, NaN for an effect the diagnosis did not
        name, whose value is then the model's); ``left_out_open_loop`` (per model —
        ``as given``, ``diagnosed``, ``baseline`` — its error summary: position RMS [mm],
        heading RMS [°], combined RMS [mm] …); ``gate`` (the open-loop gate's steps).
    """
    from odomgym.diagnose.workflow import diagnose

    cfg = config if config is not None else DiagnoseConfig()
    labels = sessions_of(runs)
    train = [r for r, s in zip(runs, labels, strict=True) if s != left_out]
    test = [r for r, s in zip(runs, labels, strict=True) if s == left_out]
    start = time.perf_counter()
    result = diagnose(train, robot, cfg, baseline=baseline() if baseline is not None else None)
    seconds = time.perf_counter() - start
    options = NuisanceOptions(frames=True)
    models = {AS_GIVEN: robot, DIAGNOSED: result.model}
    if result.held_out is not None and result.held_out.baseline_geometry:
        g = result.held_out.baseline_geometry
        models[BASELINE] = robot.with_errors(g["E_d"], g["E_b"], g["E_s"])
    errors = {
        label: evaluate_open_loop(
            label, test, spec, {}, options, CHECKPOINT_INTERVAL, robot.wheelbase
        ).summary()
        for label, spec in models.items()
    }
    geometry = {}
    for name, key in GEOMETRY:
        entry = result.parameters.get(name, {}).get(key)
        geometry[key] = (
            {"value": entry["value"], "stderr_sessions": entry["stderr_sessions"]}
            if entry
            else {"value": getattr(result.model, key), "stderr_sessions": math.nan}
        )
    return {
        "left_out": left_out,
        "gate_order": cfg.gate_order,
        "runs": len(test),
        "seconds": seconds,
        "verdict": result.verdict,
        "systematic_effects": result.systematic_effects,
        "noise_model": result.noise_model,
        "terms_kept": [e["term"] for e in result.discovered],
        "terms_tried": result.terms_tried,
        "sessions_fitted": len(set(sessions_of(train))),
        "geometry": geometry,
        "left_out_open_loop": errors,
        "gate": [step.as_dict() for step in result.gate],
    }


def summarise(folds: Sequence[Fold]) -> dict[str, Any]:
    """The replication checks over ``folds`` (module docstring): ``folds`` (how many);
    ``same_systematic_effects``; ``systematic_effect_sets``; ``modal_effect_set`` and
    ``folds_with_modal_set`` ("k/n"); ``intervals`` (per geometry parameter the common part
    of the folds' 95 % intervals and whether it is not empty); ``better_than_as_given`` and
    ``as_good_as_baseline`` ("k/n", in combined open-loop RMS [mm]); ``seconds`` (the folds'
    diagnoses' wall time [s], a timing field)."""
    # The order in which a fold's rounds named its effects is not a finding: sets are compared.
    named = [tuple(sorted(f["systematic_effects"])) for f in folds]
    effects = set(named)
    modal = max(effects, key=named.count) if named else ()
    overlap: dict[str, Any] = {}
    for _, key in GEOMETRY:
        low, high = [], []
        intervals = 0  # folds with a standard error (a fold fitted on one session has none)
        for f in folds:
            entry = f["geometry"][key]
            se = entry["stderr_sessions"]
            finite = se is not None and math.isfinite(se)
            intervals += finite
            dof = max(f["sessions_fitted"] - 1, 1)
            # A fold without one is its value alone: it must lie inside the others' common part.
            half = float(stats.t.ppf(0.975, dof)) * se if finite else 0.0
            low.append(entry["value"] - half)
            high.append(entry["value"] + half)
        common = [max(low), min(high)] if folds else [math.nan, math.nan]
        overlap[key] = {
            "common_interval": common,
            # None when no fold has an interval: points alone agree only to the last digit,
            # and said "no" for values that agreed to four (folds fitted on one session each).
            "overlap": (common[0] <= common[1]) if intervals else None,
        }
    better = [
        f["left_out_open_loop"][DIAGNOSED]["combined_rms_mm"]
        < f["left_out_open_loop"][AS_GIVEN]["combined_rms_mm"]
        for f in folds
    ]
    with_base = [f for f in folds if BASELINE in f["left_out_open_loop"]]
    as_good = [
        f["left_out_open_loop"][DIAGNOSED]["combined_rms_mm"]
        <= f["left_out_open_loop"][BASELINE]["combined_rms_mm"]
        for f in with_base
    ]
    return {
        "folds": len(folds),
        "same_systematic_effects": len(effects) == 1,
        "systematic_effect_sets": sorted(list(e) for e in effects),
        "modal_effect_set": list(modal),
        "folds_with_modal_set": f"{named.count(modal)}/{len(folds)}",
        "intervals": overlap,
        "better_than_as_given": f"{sum(better)}/{len(folds)}",
        "as_good_as_baseline": f"{sum(as_good)}/{len(with_base)}",
        "seconds": sum(f["seconds"] for f in folds),
    }


def table(folds: Sequence[Fold], summary: dict[str, Any]) -> str:
    """The folds as the Markdown table of ``docs/diagnose.md`` (one row per fold: the effects
    named, E_d, E_b, E_s ± session-clustered s.e., terms kept of tried, the noise model, and
    the left-out session's open-loop position RMS [mm] and heading RMS [°] per model), then
    the summary's checks in one paragraph, ending with the diagnoses' wall time [s]."""
    lines = [
        "| left out | runs | systematic effects | E_d | E_b | E_s | terms kept / tried | "
        "noise | as given [mm, °] | diagnosed [mm, °] | baseline [mm, °] |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for f in folds:
        cells = []
        for _, key in GEOMETRY:
            g = f["geometry"][key]
            se = g["stderr_sessions"]
            cells.append(f"{g['value']:.4f}" + (f" ± {se:.4f}" if math.isfinite(se) else ""))
        errs = []
        for label in (AS_GIVEN, DIAGNOSED, BASELINE):
            e = f["left_out_open_loop"].get(label)
            errs.append(f"{e['position_rms_mm']:.1f}, {e['heading_rms_deg']:.2f}" if e else "—")
        lines.append(
            f"| {f['left_out']} | {f['runs']} | {', '.join(f['systematic_effects']) or '—'} | "
            + " | ".join(cells)
            + f" | {len(f['terms_kept'])} / {f['terms_tried']} | "
            f"{', '.join(f['noise_model']) or '—'} | " + " | ".join(errs) + " |"
        )
    lines += [
        "",
        f"Same systematic effects in every fold: {summary['same_systematic_effects']} "
        f"({summary['systematic_effect_sets']}; the most frequent set in "
        f"{summary['folds_with_modal_set']} folds); 95 % intervals overlap: "
        + ", ".join(f"{k} {_said(v['overlap'])}" for k, v in summary["intervals"].items())
        + f"; left-out session better than as given: {summary['better_than_as_given']}; "
        f"at least as good as the baseline: {summary['as_good_as_baseline']}; "
        f"{summary['seconds']:.0f} s of diagnosis.",
    ]
    return "\n".join(lines)


def without_timing(value: Any) -> Any:
    """A copy of ``value`` (a fold, a summary, a list or dict of them) without the keys of
    :data:`TIMING_FIELDS` at any depth: what must be the same wherever the folds ran."""
    if isinstance(value, dict):
        return {k: without_timing(v) for k, v in value.items() if k not in TIMING_FIELDS}
    if isinstance(value, list | tuple):
        return [without_timing(v) for v in value]
    return value


def parse_shard(text: str) -> tuple[int, int]:
    """``"K/N"`` as ``(K, N)`` with 1 <= K <= N: run folds K, K + N, K + 2N, …

    Raises:
        ValueError: anything else, in one line naming what was expected.
    """
    parts = text.split("/")
    try:
        shard, shards = (int(p) for p in parts)
    except ValueError:
        raise ValueError(f"expected K/N with 1 <= K <= N, got {text!r}") from None
    if not 1 <= shard <= shards:
        raise ValueError(f"expected K/N with 1 <= K <= N, got {text!r}")
    return shard, shards


def fold_sessions(
    runs: Sequence[Run],
    sessions: Sequence[str] | None = None,
    shard: tuple[int, int] = (1, 1),
) -> list[str]:
    """The sessions whose folds this call owns, in the order the data give them: every
    session (or those of ``sessions``), then every N-th from the K-th for ``shard=(K, N)``.

    Raises:
        SpecError: fewer than two sessions in the data (field ``DATA``); a session of
            ``sessions`` not in the data (field ``sessions``); a bad shard (field ``shard``).
    """
    every = list(dict.fromkeys(sessions_of(runs)))
    if len(every) < 2:
        raise SpecError(
            "leaving one session out needs runs of two or more sessions; the data hold "
            f"{len(every)} ({', '.join(repr(s) for s in every) or 'no runs'})",
            field="DATA",
        )
    chosen = every
    if sessions:
        unknown = sorted(set(sessions) - set(every))
        if unknown:
            raise SpecError(
                f"--sessions: not in the data: {', '.join(unknown)} (the data hold "
                f"{', '.join(every)})",
                field="sessions",
            )
        chosen = [s for s in every if s in set(sessions)]
    shard_k, shards = shard
    if not 1 <= shard_k <= shards:
        raise SpecError(
            f"--shard: expected K/N with 1 <= K <= N, got {shard_k}/{shards}", field="shard"
        )
    return chosen[shard_k - 1 :: shards]


def fold_path(out: Path, session: str) -> Path:
    """The file of ``session``'s fold in ``out``: ``fold-<session>.json``, the session's name
    percent-encoded where it is not a plain file name (a ``/`` of a fleet's period)."""
    return Path(out) / f"fold-{quote(session, safe='')}.json"


def _read_fold(path: Path, gate_order: str) -> Fold:
    """A fold file written before, checked to be one (and of the same gate order)."""
    try:
        done: Fold = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SpecError(
            f"cannot read this fold file ({exc}); remove it to diagnose the fold again",
            source=str(path),
        ) from None
    if not isinstance(done, dict) or "left_out" not in done:
        raise SpecError(
            "not a fold file of leave-one-session-out; remove it to diagnose the fold again",
            source=str(path),
        )
    order = done.get("gate_order", gate_order)
    if order != gate_order:
        raise SpecError(
            f"made with gate order {order!r}, not {gate_order!r}: give another --out, or "
            "remove it to diagnose the fold again",
            source=str(path),
        )
    return fold_numbers(done)


def _write_fold(path: Path, result: Fold) -> Fold:
    """Write ``result`` to ``path`` atomically; returns it as read back from the file's text,
    so a fold diagnosed now and one resumed from its file are the same values.

    The file is strict JSON: a number that is not finite (the standard error of a fold
    fitted on one session) is written ``null``, as in ``report.json`` — Python's ``NaN``
    literal, which ``json.dumps`` writes by default, is refused by strict parsers
    (JavaScript's ``JSON.parse``, ``jq``); it is read back as NaN (:func:`fold_numbers`)."""
    text = json.dumps(_strict(result), indent=1, default=float, allow_nan=False)
    atomic_write_text(path, text)
    written: Fold = json.loads(text)
    return fold_numbers(written)


def _strict(value: Any) -> Any:
    """``value`` with every float that is not finite replaced by None (strict JSON)."""
    if isinstance(value, dict):
        return {k: _strict(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_strict(v) for v in value]
    if isinstance(value, float | np.floating) and not math.isfinite(float(value)):
        return None
    return value


_NUMERIC = ("geometry", "left_out_open_loop", "gate")
"""A fold's parts that hold only numbers (and names, flags, rules): a ``null`` there is a
number that was not finite."""


def fold_numbers(fold: Fold) -> Fold:
    """``fold`` as read from its file, each ``null`` of its numeric parts (:data:`_NUMERIC`)
    NaN again, so the checks and the table treat it as the number it was (an infinite one,
    written ``null`` too, comes back NaN: only a gate step's variance inflation can be one, and
    no check reads it)."""

    def nan(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: nan(v) for k, v in value.items()}
        if isinstance(value, list):
            return [nan(v) for v in value]
        return math.nan if value is None else value

    return {key: nan(value) if key in _NUMERIC else value for key, value in fold.items()}


def run_loso(
    runs: Sequence[Run],
    robot: RobotSpec,
    out: str | Path,
    *,
    config: DiagnoseConfig | None = None,
    baseline: Callable[[], Baseline] | None = None,
    sessions: Sequence[str] | None = None,
    shard: tuple[int, int] = (1, 1),
    table_only: bool = False,
    backend: str = "local",
    address: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    status: Callable[[str], None] | None = None,
) -> tuple[list[Fold], dict[str, Any]]:
    """Every fold this call owns (:func:`fold_sessions`), read from ``out`` if its file is
    there, else diagnosed (:func:`fold`) and written there as it ends (module docstring).

    Args:
        runs: every run, with its session in ``meta["session"]``.
        robot: the model as given.
        out: the folder of fold files (created if missing; never emptied).
        config: each fold's diagnosis options (with ``backend="ray"``: ``jobs`` is the CPUs of
            a local Ray, and each fold runs on one).
        baseline: makes the baseline calibration (:func:`fold`); None: none.
        sessions: leave out only these sessions (default: every one).
        shard: ``(K, N)``: only folds K, K + N, … of the chosen sessions.
        table_only: diagnose nothing; folds without a file are listed in the summary's
            ``missing_folds``.
        backend: ``local`` or ``ray`` (:mod:`odomgym.distributed`).
        address: with ``ray``, the cluster to join (else ``RAY_ADDRESS``, else a local Ray).
        progress: called with (folds done, folds owned) at the start and as each fold ends.
        status: receives one line when folds were taken from files written before.

    Returns:
        The folds, in the data's session order (the ones still missing left out), and
        :func:`summarise` of them with ``missing_folds``: the owned sessions without a fold.
    """
    from odomgym.distributed import Backend, ray_session, run_ray_tasks

    chosen_backend = Backend(backend)
    cfg = config if config is not None else DiagnoseConfig()
    mine = fold_sessions(runs, sessions, shard)
    folder = Path(out)
    done: dict[str, Fold] = {}
    for session in mine:
        path = fold_path(folder, session)
        if path.is_file():
            done[session] = _read_fold(path, cfg.gate_order)
    if done and status is not None and not table_only:
        status(f"resumed: {len(done)} of {len(mine)} folds taken from {folder}")
    todo = [] if table_only else [s for s in mine if s not in done]
    if progress is not None:
        progress(len(done), len(mine))

    def record(session: str, result: Fold) -> None:
        done[session] = _write_fold(fold_path(folder, session), result)
        if progress is not None:
            progress(len(done), len(mine))

    if todo:
        folder.mkdir(parents=True, exist_ok=True)
        chosen_backend.check_available()
    if todo and chosen_backend is Backend.RAY:
        one = dataclasses.replace(cfg, jobs=1)  # a Ray task holds one CPU
        with ray_session(address, cfg.jobs) as started:
            tasks = ((s, (list(runs), robot, s, one, baseline)) for s in todo)
            run_ray_tasks(fold, tasks, record, started=started)
    else:
        for session in todo:
            record(session, fold(runs, robot, session, cfg, baseline))
    folds = [done[s] for s in mine if s in done]
    summary = summarise(folds)
    summary["missing_folds"] = [s for s in mine if s not in done]
    return folds, summary


def _said(overlap: bool | None) -> str:
    """An interval check in the table's words: True, False, or n/a (no interval to compare)."""
    return "n/a" if overlap is None else str(bool(overlap))

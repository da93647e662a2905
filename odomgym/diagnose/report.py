"""The diagnose outputs: ``report.json``, ``report.md``, ``model.toml`` and the figures
(:mod:`odomgym.diagnose.plots`).

Written into a temporary folder beside the target and renamed into place only when everything
succeeded, so a failed run leaves no partial output folder.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from odomgym.diagnose.gate import BLOCKING, MAX_INFLATION, REAL_SIZE, UNIDENTIFIED, GateStep
from odomgym.diagnose.plots import plot_all
from odomgym.diagnose.results import GAP_METRIC, Diagnosis, Round
from odomgym.effects import EFFECTS
from odomgym.errors import SpecError, first_few
from odomgym.io import atomic_folder

__all__ = [
    "OS_FILES",
    "REPORT_FILES",
    "check_replaceable",
    "foreign_entries",
    "format_markdown",
    "write_outputs",
]

REPORT_FILES = (
    "report.json",
    "report.md",
    "model.toml",
    "gap_before_after.png",
    "held_out_paths.png",
    "where.png",
)
"""The files a diagnose report folder may hold, besides one figure per discovered term
(``discovered-<term>.png``): what :func:`write_outputs` writes."""


def _report_file(path: Path) -> bool:
    """Whether ``path`` is a regular file a report folder holds (:data:`REPORT_FILES`)."""
    name = path.name
    named = name in REPORT_FILES or (name.startswith("discovered-") and name.endswith(".png"))
    return named and path.is_file() and not path.is_symlink()


OS_FILES = frozenset({".DS_Store", "Thumbs.db", "desktop.ini"})
"""Files a desktop writes into any folder a person opens (macOS Finder, Windows Explorer):
no user's data, so a report folder holding them may still be replaced."""


def foreign_entries(folder: Path) -> list[str]:
    """The entries of ``folder`` (sorted names) that no diagnose report holds: all of them if
    it holds no ``report.json``, else those not among :data:`REPORT_FILES` (sub-folders,
    links and other files included). Empty for a missing or empty folder. A desktop's own
    files (:data:`OS_FILES`) are never foreign.

    Why: the report folder is replaced whole (:func:`odomgym.io.atomic_folder`), so whatever
    else it holds would be deleted with it. A user who gave the folder holding the logs and the
    robot file as ``--out`` lost them (exit 0, only the report left)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    names = sorted(
        entry.name
        for entry in folder.iterdir()
        if not (entry.name in OS_FILES and entry.is_file() and not entry.is_symlink())
    )
    if "report.json" not in names:
        return names
    return [name for name in names if not _report_file(folder / name)]


def check_replaceable(folder: Path, *, option: str = "out") -> None:
    """Refuse, in one line naming ``option``, to replace ``folder`` if it holds anything a
    diagnose report does not (:func:`foreign_entries`): a new, empty or earlier report folder
    passes.

    Raises:
        SpecError: naming the first few foreign entries (field ``option`` without dashes).
    """
    foreign = foreign_entries(folder)
    if not foreign:
        return
    raise SpecError(
        f"{option} {folder}: holds {first_few(foreign)}, which diagnose did not write; the "
        "report folder is replaced whole, so they would be deleted: give a new or empty "
        "folder, or an earlier diagnose report's",
        field=option.lstrip("-").replace("-", "_"),
    )


def _clean(value: Any) -> Any:
    """JSON-safe: NaN/inf become None, numpy scalars plain numbers."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _found(d: Diagnosis) -> str:
    """What the diagnosis added, in words: systematic, discovered, noise."""
    parts = []
    if d.systematic_effects:
        parts.append(", then ".join(f"**{n}**" for n in d.systematic_effects))
    if d.discovered:
        parts.append(
            "the discovered term(s) " + ", ".join(f"**{e['term']}**" for e in d.discovered)
        )
    if d.noise_model:
        parts.append("the noise model " + ", ".join(f"**{n}**" for n in d.noise_model))
    return "; ".join(parts) or "nothing"


def _refused(d: Diagnosis) -> str:
    """The proposals the open-loop gate refused, in words."""
    return ", ".join(f"**{step.name}**" for step in d.gate if not step.kept) or "nothing"


def report_json(diagnosis: Diagnosis) -> str:
    """``report.json`` as text (strict JSON)."""
    return json.dumps(_clean(diagnosis.as_dict()), indent=2, allow_nan=False)


def format_markdown(diagnosis: Diagnosis, data: str) -> str:
    """``report.md``: what a person reads first — one story. The verdict, then the decisions
    (what each yardstick kept or refused on held-out data, and why), then the figures behind
    them, each once; the rounds' likelihood numbers come last, marked as the proposals they
    are."""
    d = diagnosis
    lines = [f"# odomgym diagnose: {data}", ""]
    lines += _verdict_lines(d)
    lines += [f"Set aside: run {s['run']} — {s['reason']}." for s in d.skipped_runs] + (
        [""] if d.skipped_runs else []
    )
    lines += _decision_lines(d)
    lines += _held_out_lines(d)
    lines += _spread_lines(d)
    lines += _parameter_lines(d)
    lines += _nuisance_lines(d)
    lines += _confound_lines(d)
    lines += _check_lines(d)
    lines += _proposal_lines(d)
    lines += _diagnostic_lines(d)
    lines += _where_lines(d)
    return "\n".join(lines) + "\n"


def _confirmed_words(d: Diagnosis) -> tuple[list[str], list[str]]:
    """Each held-out confirmation in words, its figures left to the tables below (each figure
    appears once): (confirmed, not confirmed — with the reason)."""
    yes: list[str] = []
    no: list[str] = []
    for c in d.final_test.get("confirmations", []):
        names = ", ".join(f"**{n}**" for n in c["names"])
        if c["yardstick"] == "open-loop error":
            words = f"{names} by the open-loop error of the held-out runs"
            if not c["confirmed"]:
                words += (
                    ": the diagnosed model does not predict them better than the model as given"
                )
        else:
            words = f"{names} by the spread it predicts"
            if not c["confirmed"]:
                words += f": {c['reason']}"
        (yes if c["confirmed"] else no).append(words)
    return yes, no


def _verdict_lines(d: Diagnosis) -> list[str]:
    """The verdict and what it rests on, in one paragraph (the figures are the tables')."""
    final = d.final_test
    left = final.get("residual_follows")
    found = _found(d)
    yes, no = _confirmed_words(d)
    confirmed = "; ".join(yes)
    structure = (
        f"but structure is left there: the residuals follow **{left}** most (score z = "
        f"{final.get('residual_follows_z', math.nan):.1f}; held-out test p = "
        f"{final.get('held_out_p', math.nan):.2g})"
        if final.get("held_out_p", 1.0) < 0.025
        else "but the last round left what the catalogue and the grammar could not name"
    )
    verdicts = {
        "explained": f"the model was missing {found}. Confirmed on the held-out runs: "
        f"{confirmed}; their residuals under the updated model show no dependence on any term "
        "of the grammar and look white",
        "partly explained": f"the model was missing {found}. Confirmed on the held-out runs: "
        f"{confirmed}; {structure}",
        "partly confirmed": f"the fit runs pointed to {found}. Confirmed on the held-out runs: "
        f"{confirmed}. **Not** confirmed: {'; '.join(no)} — read those as proposals, not "
        "findings",
        "confounded": f"the model was missing {found} — or the measurement erred: confirmed "
        f"on the held-out runs: {confirmed}, but the fitted values moved along a direction "
        "in which a measurement error gives the same logs. "
        + " ".join(c["sentence"] for c in d.confounds if c["moved"]).rstrip("."),
        "ambiguous": "several effects explain the data equally well (see below)",
        "unexplained": "the model disagrees with the data beyond noise, and neither the catalogue "
        f"nor the grammar's terms explain it (the residuals follow **{left}** most)",
        "none": "the model already matches the data within noise",
        "unconfirmed": (
            f"the fit runs pointed to {found}, but the held-out runs do **not** confirm it "
            f"({'; '.join(no)}): nothing here is a finding to copy into the robot"
            if found != "nothing"
            else f"the fit runs' likelihood proposed {_refused(d)}, but the checks after it "
            "kept none of it (below): the model stays as given, and nothing here is a finding "
            "to copy into the robot"
        ),
    }
    return [f"**Verdict: {d.verdict}** — {verdicts.get(d.verdict, d.verdict)}.", ""]


def _decision_lines(d: Diagnosis) -> list[str]:
    """What was kept and what was refused, each with the check that decided and why (the
    open-loop figures are the check's table's)."""
    final = d.final_test
    lines = ["## What was kept, and why", ""]
    confirmed = {n: c["confirmed"] for c in final.get("confirmations", []) for n in c["names"]}
    for step in (step for step in d.gate if step.kept):
        if step.rule.startswith("held by "):
            # Kept under the principle of marginality (gate module docstring): it did not
            # pass its own rule, and the sentence must not say it did.
            lines.append(
                f"- kept **{step.name}** ({step.kind}): {step.rule.removeprefix('held by ')} "
                "extends it and stayed, so it stays too (the principle of marginality), "
                "though alone it did not lower the error of predicting left-out folds open "
                "loop enough"
            )
            continue
        lines.append(
            f"- kept **{step.name}** ({step.kind}): it lowered the error of predicting "
            f"left-out folds open loop (rule: {_rule(step)})"
        )
    for name in d.noise_model:
        lines.append(
            f"- kept **{name}** (noise effect): named by the rounds' held-out likelihood"
            + (", its signature and size checked" if name in d.noise_checks else "")
            + ("" if confirmed.get(name, True) else " — **not confirmed** by its spread")
        )
    for step in (step for step in d.gate if not step.kept):
        if step.rule.startswith(("not identifiable beside ", BLOCKING)):
            # Exchanged (gate._exchange): it lowered the error, but the model without it,
            # with the terms it had blocked, predicted better.
            lines.append(
                f"- refused **{step.name}** ({step.kind}): the model without it, with the "
                "terms it had blocked, predicted left-out folds open loop better "
                f"(rule: {_rule(step)})"
            )
            continue
        lines.append(
            f"- refused **{step.name}** ({step.kind}): it did not lower the error of "
            f"predicting left-out folds open loop enough (rule: {_rule(step)})"
        )
    for entry in d.refused_terms:
        lines.append(f"- refused **{entry['term']}** (term): {entry['reason']}")
    for name, check in d.noise_checks.items():
        if not check["accepted"]:
            lines.append(f"- refused **{name}** (noise effect): {check['reason']}")
    for name in final.get("noise_carried_by_the_rest", []):
        lines.append(
            f"- dropped **{name}** (noise effect): refitted on the final model it went to "
            "the floor of its range — the rest of the model carries it"
        )
    absorbed = final.get("absorbed", [])
    # The open-loop check judges every effect a round found significant, absorbed ones too: one
    # the backward check removed may still be kept by it (and is then listed as kept above).
    out = [n for n in absorbed if n not in d.named_effects]
    back = [n for n in absorbed if n in d.named_effects]
    if out:
        lines.append(
            "- absorbed by the backward check (named on the way, not needed by the final "
            f"likelihood): {', '.join(out)}"
        )
    if back:
        lines.append(
            f"- {', '.join(back)}: not needed by the final likelihood (backward check), but "
            "kept by the open-loop check above, which judges every effect a round found "
            "significant"
        )
    if final.get("unsupported"):
        lines.append(
            "- not proposed to the open-loop check (significant in an earlier round only, not "
            f"beside the final model): {', '.join(final['unsupported'])}"
        )
    if len(lines) == 2:
        lines.append("- nothing was proposed")
    yes, no = _confirmed_words(d)
    lines.append("")
    if yes or no:
        lines.append("On the held-out runs, each by the yardstick of its kind (the tables below):")
        lines.append("")
        lines += [f"- confirmed: {w}" for w in yes]
        lines += [f"- **not confirmed**: {w}" for w in no]
        lines.append("")
    return lines


def _spread_lines(d: Diagnosis) -> list[str]:
    """The noise effects' yardstick: the held-out spread against the model without each."""
    if not d.spread:
        return []
    lines = [
        "## Noise effects on held-out runs: the spread they predict",
        "",
        "Log predictive density of each held-out run's open-loop errors (at its checkpoints, "
        "jointly) under the model with the effect and without it (refitted on the fit runs, "
        "wheel noise beside), and the share of the held-out errors inside the model's 50 % "
        "and 95 % one-step predictive regions (40–60 % and 90–98 % required).",
        "",
        "| noise effect | score with − without [nats] | per | 50 % region | 95 % region "
        "| confirmed |",
        "|---|---|---|---|---|---|",
    ]
    for c in d.spread:
        lines.append(
            f"| {c['effect']} | {c['difference']:+.1f} ± {c['stderr']:.2g} | "
            f"{c['units'][:-1]} ({c['unit_count']}) | {100 * c['coverage']['50']:.1f} % | "
            f"{100 * c['coverage']['95']:.1f} % | {'yes' if c['confirmed'] else 'no'} |"
        )
    lines.append("")
    for key, entry in d.geometry_check.items():
        if entry["moved_by"]:
            lines.append(
                f"- {key} {entry['with_noise_effects']:.5f} with {', '.join(entry['moved_by'])}"
                f" (its mean part belongs to it); {entry['without_noise_effects']:.5f} in the "
                "model without it, refitted"
            )
    if d.geometry_check:
        lines.append("")
    return lines


def _parameter_lines(d: Diagnosis) -> list[str]:
    """The kept effects' values and the discovered terms."""
    lines: list[str] = []
    bounded: list[str] = []
    for title, group in (
        ("Systematic effects", d.systematic_effects),
        ("Noise model", d.noise_model),
    ):
        if not group:
            continue
        lines += [
            f"## {title}",
            "",
            "| effect (in the order named; an extension before its partner, the tracker's offset "
            "last) | parameter | value | standard error "
            "| run-clustered | session-clustered |",
            "|---|---|---|---|---|---|",
        ]
        for name in group:
            limits = {p.name: p for p in EFFECTS[name].parameters}
            for key, entry in d.parameters[name].items():
                value = entry["value"]
                edge = key in limits and limits[key].at_limit(value)
                if edge:
                    bounded.append(f"{name}.{key}")
                first = entry.get("stderr_model", entry.get("stderr", math.nan))
                errors = " | ".join(
                    _error(v)
                    for v in (
                        first,
                        entry.get("stderr_runs", math.nan),
                        entry.get("stderr_sessions", math.nan),
                    )
                )
                lines.append(
                    f"| {name} | {key} | {value:.6g}{' (bound)' if edge else ''} | {errors} |"
                )
        lines.append("")
    if d.discovered:
        lines += [
            "## Discovered terms",
            "",
            "Terms of the error grammar (channel × modulator, `docs/diagnose.md`) found by sparse "
            "regression on the residuals the catalogue left, kept by the open-loop check and "
            "at a real size (at least two standard errors from zero, the sign the discovery "
            "proposed); saved in `model.toml` as `[robot.effects.discovered]`, so the envs "
            "apply them.",
            "",
            "| term | coefficient | standard error | reading |",
            "|---|---|---|---|",
        ]
        for e in d.discovered:
            lines.append(
                f"| `{e['term']}` | {e['coefficient']:.4g} "
                f"{'' if e['unit'] == '1' else e['unit']} | {e['stderr']:.2g} | {e['sentence']} |"
            )
        lines.append("")
    if bounded:
        lines += [
            f"At the edge of its allowed range: {', '.join(bounded)}. The effect stands in "
            "for something the catalogue describes only roughly: read its name as the "
            "closest mechanism, not a measurement.",
            "",
        ]
    for name in d.named_effects:
        if EFFECTS[name].confounded:
            lines += [f"Also consistent with `{name}`: {EFFECTS[name].confounded}.", ""]
    last = d.rounds[-1] if d.rounds else None
    if last is not None and last.verdict == "ambiguous" and last.separating:
        sep = last.separating
        lines += [
            f"Tied in round {last.number}: {', '.join(last.tied)}. The experiment that would "
            f"separate {sep['between'][0]} from {sep['between'][1]} best: "
            f"**{sep['experiment']}** (the two fitted models' predictions differ by up to "
            f"{sep['separation_mm']:.1f} mm and {sep['separation_deg']:.2f}°, "
            f"{sep['separation_sigma']:.1f} × the sensor noise fitted on these data).",
            "",
        ]
    return lines


def _error(value: float) -> str:
    """A standard error for a table: two digits, or a dash where none was computed."""
    return f"{value:.2g}" if math.isfinite(value) else "—"


def _decision_of(d: Diagnosis, name: str) -> str:
    """What became of a proposal of the rounds, in a few words."""
    if name in d.named_effects:
        confirmations = d.final_test.get("confirmations", [])
        if any(name in c["names"] and not c["confirmed"] for c in confirmations):
            return "kept, not confirmed"
        return "kept"
    gate = {step.name: step for step in d.gate}
    if name in gate:
        return f"refused by the open-loop check ({_rule(gate[name])})"
    if name in d.final_test.get("absorbed", []):
        return "absorbed (backward check)"
    if name in d.final_test.get("unsupported", []):
        return "not significant added to the final model (forward check)"
    if name in d.final_test.get("taken_over", []):
        return "its part taken by a noise effect's mean"
    if name in d.noise_checks and not d.noise_checks[name]["accepted"]:
        return "refused (signature or size)"
    if name in d.final_test.get("noise_carried_by_the_rest", []):
        return "carried by the rest of the model"
    return "not proposed"


def _proposal_lines(d: Diagnosis) -> list[str]:
    """The rounds: the likelihood's proposals, with what became of each."""
    lines = [
        "## The rounds: the likelihood's proposals",
        "",
        "These are proposals, scored on the fit runs by the Kalman filter's likelihood; the "
        "decisions above are what the held-out checks made of them. Held-out gain: "
        "log-likelihood gained on runs left out of the fit (cross-validation), summed over the "
        "fit runs; LR: in-sample likelihood ratio 2Δℓ, its p-value Bonferroni-corrected over "
        "the candidates; sign flips: family-wise max-T p over runs; proposed: significant by "
        "the likelihood (the values are the round's fit, not the final ones).",
        "",
        "| round | stage | effect | held-out gain [nats] | LR | p (family-wise) | p (sign flips) "
        "| proposed | proposal's values | decision |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in d.rounds:
        for c in sorted(r.candidates, key=lambda c: (c.stage, -c.cv_gain)):
            fitted = ", ".join(f"{k} = {v:.4g}" for k, v in c.values.items())
            decision = _decision_of(d, c.name) if c.significant else "—"
            lines.append(
                f"| {r.number} | {c.stage} | {c.name} | {c.cv_gain:.1f} | {c.lr:.1f} | "
                f"{c.p_family:.2g} | {c.p_sign_flip:.2g} | {'yes' if c.significant else 'no'} "
                f"| {fitted} | {decision} |"
            )
    lines += ["", "Rounds:", ""]
    for r in d.rounds:
        st = r.structure
        extra = (
            f"; structure test p = {st['p_value']:.2g}, residuals follow {st['follows']}"
            if st
            else ""
        )
        lines.append(f"- round {r.number}: {_round_words(r)}{extra}")
        for name, reason in r.screened.items():
            lines.append(f"  - {name} not fitted this round (refused whatever its fit): {reason}")
    lines.append("")
    return lines


def _round_words(r: Round) -> str:
    """A round's outcome as a proposal, never in the words of a final verdict (a round that
    "explained" an effect the checks later refused would contradict the report's decisions)."""
    if r.verdict == "explained":
        return f"proposed **{r.winner}**"
    if r.verdict == "discovered":
        return "proposed discovered terms (the error grammar)"
    if r.verdict == "ambiguous":
        return f"a tie between {', '.join(r.tied)}, not resolved by these data"
    if r.verdict == "none":
        return "nothing further to propose"
    return "structure left that no candidate explains"


def _diagnostic_lines(d: Diagnosis) -> list[str]:
    """The whitened gap: a diagnostic of the noise model, not a yardstick (its open-loop
    figures are the held-out table's)."""
    return [
        "## Diagnostic: the whitened gap on held-out runs",
        "",
        f"Held out: {len(d.holdout_runs)} runs ({', '.join(d.holdout_runs)}); fitted on "
        f"{len(d.fit_runs)}. Gap = {GAP_METRIC}. A statement about the noise model: a wider "
        "noise model shrinks it without moving a single prediction.",
        "",
        "| | gap (1 = noise) | 95 % interval |",
        "|---|---|---|",
        f"| model as given | {d.gap_before:.2f} | "
        f"{d.gap_ci['before'][0]:.2f}–{d.gap_ci['before'][1]:.2f} |",
        f"| updated model | {d.gap_after:.2f} | "
        f"{d.gap_ci['after'][0]:.2f}–{d.gap_ci['after'][1]:.2f} |",
        f"| noise alone | {d.noise_floor:.2f} | |",
        "",
        f"Fraction of the reducible gap closed: {d.fraction_closed:.2f} "
        f"(95 % interval {d.fraction_ci[0]:.2f}–{d.fraction_ci[1]:.2f}). Sensor noise fitted: "
        f"{1e3 * d.sensor.position:.2f} mm, {math.degrees(d.sensor.heading):.3f}°.",
        "",
    ]


def _where_lines(d: Diagnosis) -> list[str]:
    """Where the model as given disagrees, and which experiments reveal which effect."""
    lines = ["## Where the model as given disagrees (Holm-corrected tests)", ""]
    lines += [
        "| view | group | component | n | mean | 95 % interval | p |",
        "|---|---|---|---|---|---|---|",
    ]
    for f in sorted(d.findings, key=lambda f: f.p):
        star = " **" if f.significant else ""
        lines.append(
            f"| {f.view} | {f.group} | {f.component} [{f.unit}] | {f.n} | {f.mean:.4g}{star} | "
            f"{f.low:.3g} … {f.high:.3g} | {f.p:.3g} |"
        )
    lines += ["", "Which experiments reveal which effect:", ""]
    for name, effect in EFFECTS.items():
        lines.append(f"- `{name}`: {effect.reveals}")
    return lines


def _held_out_lines(d: Diagnosis) -> list[str]:
    """The headline table: the held-out runs predicted open loop by each model."""
    held = d.held_out
    if held is None:
        return []
    out = held.as_dict()
    how = (
        "whole sessions the fit never saw"
        if held.split == "sessions"
        else "per experiment family a contiguous block of runs in time"
    )
    lines = [
        "## Held-out runs, predicted open loop (the gap that counts)",
        "",
        f"Held out: {len(out['runs'])} runs — {how} "
        f"({', '.join(out['sessions']) if held.split == 'sessions' else ', '.join(out['runs'])}). "
        "Each model replays their logged wheel motions open loop, from where the measured "
        "poses of a run's first second put it; "
        + (
            "a held-out session's measurement nuisances (time offset, tracked point, yaw) are "
            "fitted on its own runs with each model fixed. "
            if held.split == "sessions"
            else "the session's measurement nuisances are those fitted on the fit runs. "
        )
        + "RMS over every measured sample after that second, runs weighing equally.",
        "",
        "| model | position RMS [mm] | heading RMS [°] | E_max,syst [mm] |",
        "|---|---|---|---|",
    ]
    for label, summary in out["models"].items():
        name = f"baseline: {held.baseline_name}" if label == "baseline" else label
        e_max = summary["e_max_syst_mm"]
        e_text = ", ".join(f"{v:.1f}" for v in e_max.values()) if e_max else "—"
        lines.append(
            f"| {name} | {summary['position_rms_mm']:.1f} | {summary['heading_rms_deg']:.2f} | "
            f"{e_text} |"
        )
    lines.append("")
    for key, ci in out["differences_ci"].items():
        lines.append(
            f"- {key}: position 95 % interval {ci['position_mm'][0]:+.1f} … "
            f"{ci['position_mm'][1]:+.1f} mm, heading {ci['heading_deg'][0]:+.2f} … "
            f"{ci['heading_deg'][1]:+.2f}° (bootstrap over the held-out runs)"
        )
    if d.systematic_effects or d.discovered:
        better = "yes" if out["better_than_as_given"] else "**no**"
        lines.append(f"- Better than the model as given: {better}.")
    else:
        lines.append(
            "- No systematic effect or term was kept: the predictions differ from the model as "
            "given only by a noise effect's mean part (bumps shorten the travel); a noise "
            "effect is judged by the spread it predicts (below)."
        )
    if out["as_good_as_baseline"] is not None:
        good = "yes" if out["as_good_as_baseline"] else "**no** — the baseline predicts better"
        lines.append(f"- At least as good as the baseline calibration: {good}.")
    lines.append("")
    return lines


def _nuisance_lines(d: Diagnosis) -> list[str]:
    """The measurement nuisances per session (never robot effects)."""
    if not d.nuisances or not any(n.frame or n.time_offset for n in d.nuisances):
        return []
    lines = [
        "## Measurement nuisances (of the recording, not the robot)",
        "",
        "| session | runs | time offset [ms] | tracked point dx [mm] | dy [mm] | yaw [°] |",
        "|---|---|---|---|---|---|",
    ]
    for n in d.nuisances:
        frame = (
            f"{1e3 * n.dx:.2f} ± {1e3 * n.dx_se:.2f} | {1e3 * n.dy:.2f} ± {1e3 * n.dy_se:.2f} | "
            f"{math.degrees(n.yaw):.3f} ± {math.degrees(n.yaw_se):.3f}"
            if n.frame
            else "— | — | —"
        )
        label = (n.session or "(one session)") + (" (held out)" if n.held_out else "")
        lines.append(
            f"| {label} | {n.runs} | {1e3 * n.time_offset:.1f} ± "
            f"{1e3 * n.time_offset_se:.1f} | {frame} |"
        )
    lines += [
        "",
        "Positive time offset: the encoder log lags the ground truth. A yaw misalignment and a "
        "wheel toe of the opposite angle produce identical pose logs, so a part shared by all "
        "sessions may be either.",
        "",
    ]
    return lines


def _confound_lines(d: Diagnosis) -> list[str]:
    """The confounds derived from the data (:mod:`odomgym.diagnose.confounds`): the ones the
    fit moved along first, each with its two readings and what separates them."""
    if not d.confounds:
        return []
    moved = [c for c in d.confounds if c["moved"]]
    rest = [c for c in d.confounds if not c["moved"]]
    lines = [
        "## Confounds: where the robot and the measurement give the same logs",
        "",
        "Derived from these data: directions in which the kept robot parameters and the "
        "measurement nuisances (time offset, tracked point, frame yaw, and errors of the "
        "ground-truth system itself: its frame's scale, rotation and translation, its clock "
        "rate) change the open-loop residuals by less than 10⁻³ of the largest direction.",
        "",
    ]
    if moved and d.verdict == "confounded":
        lines.append(f"- {len(moved)} the fit moved along: its readings are in the verdict above")
    else:
        lines += [f"- **moved along it**: {c['sentence']}" for c in moved]
    lines += [f"- {c['sentence']}" for c in rest]
    lines.append("")
    return lines


def _rule(step: GateStep) -> str:
    """A gate step's rule, with the variance inflation that made a proposal unidentifiable."""
    if step.rule.startswith(("not identifiable", UNIDENTIFIED)):
        inflation = "∞" if math.isinf(step.inflation) else f"{step.inflation:.2g}"
        return f"{step.rule} (VIF {inflation})"
    return step.rule


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def _power_of_ten(value: float) -> str:
    """``value`` as 10 with a superscript exponent (10⁶) when it is a power of ten, else in
    ``g`` format: the report's bounds read from the constants that set them."""
    if value > 0 and 10.0 ** round(math.log10(value)) == value:
        return "10" + str(round(math.log10(value))).translate(_SUPERSCRIPT)
    return f"{value:g}"


def _check_lines(d: Diagnosis) -> list[str]:
    """The open-loop check of every systematic proposal and the stand-ins."""
    lines: list[str] = []
    if d.gate:
        lines += [
            "## Open-loop check of every proposal (held-out folds of the fit runs)",
            "",
            "Each systematic proposal of the rounds had to lower the error of predicting the "
            "left-out folds open loop (a discovered term by more than one standard error, and "
            "only if the open-loop fit can identify it: variance inflation ≤ "
            f"{_power_of_ten(MAX_INFLATION)}). An effect "
            "that fit cannot tell from the other robot effects (the same bound) must lower it "
            f"by more than one standard error and by at least {100 * REAL_SIZE:g} % of it, and "
            "leaves where the model without it, and with a term it blocked, predicts better.",
            "",
            "| kind | name | before [mm] | with it [mm] | change ± s.e. [mm²] | rule | kept |",
            "|---|---|---|---|---|---|---|",
        ]
        for step in d.gate:
            lines.append(
                f"| {step.kind} | {step.name} | {step.before_mm:.2f} | {step.after_mm:.2f} | "
                f"{step.difference:+.3g} ± {step.stderr:.2g} | {_rule(step)} | "
                f"{'yes' if step.kept else 'no'} |"
            )
        lines.append("")
    lines.append(
        f"Grammar terms tried: {d.terms_tried}; proposed by the discovery: "
        f"{sum(1 for s in d.gate if s.kind == 'term') + len(d.stand_ins)}; kept: "
        f"{len(d.discovered)}."
    )
    lines.append("")
    if d.stand_ins:
        lines += [
            "Stand-ins (terms too large for what the robot physically did, reported not kept: "
            "a synchronisation error, a frame error or a mechanism the grammar lacks):",
            "",
        ]
        lines += [f"- `{s['term']}` = {s['coefficient']:.4g}: {s['reason']}" for s in d.stand_ins]
        lines.append("")
    return lines


def write_outputs(diagnosis: Diagnosis, out: Path, data: str) -> list[Path]:
    """Write everything into ``out`` (replacing an earlier diagnose output there) atomically
    (:func:`odomgym.io.atomic_folder`).

    Raises:
        SpecError: ``out`` holds anything else (:func:`check_replaceable`); nothing written.
    """
    out = Path(out)
    check_replaceable(out)

    def fill(tmp: Path) -> list[str]:
        (tmp / "report.json").write_text(report_json(diagnosis) + "\n", encoding="utf-8")
        (tmp / "report.md").write_text(format_markdown(diagnosis, data), encoding="utf-8")
        diagnosis.model.save(tmp / "model.toml")
        return ["report.json", "report.md", "model.toml", *plot_all(diagnosis, tmp)]

    names = atomic_folder(out, fill)
    return [out / n for n in names]

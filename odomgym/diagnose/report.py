"""The diagnose outputs: ``report.json``, ``report.md``, ``model.toml`` and two plots.

Written into a temporary folder beside the target and renamed into place only when everything
succeeded, so a failed run leaves no partial output folder.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from odomgym.diagnose.workflow import GAP_METRIC, Diagnosis
from odomgym.effects import EFFECTS

__all__ = ["format_markdown", "write_outputs"]


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


def report_json(diagnosis: Diagnosis) -> str:
    """``report.json`` as text (strict JSON)."""
    return json.dumps(_clean(diagnosis.as_dict()), indent=2, allow_nan=False)


def format_markdown(diagnosis: Diagnosis, data: str) -> str:
    """``report.md``: what a person reads first."""
    d = diagnosis
    lines = [f"# odomgym diagnose: {data}", ""]
    verdicts = {
        "explained": "the model was missing " + ", then ".join(f"**{n}**" for n in d.named_effects),
        "ambiguous": "several effects explain the data equally well (see below)",
        "unexplained": "the model disagrees with the data beyond noise, but no effect of the "
        "catalogue explains it",
        "none": "the model already matches the data within noise",
    }
    lines += [f"**Verdict: {d.verdict}** — {verdicts[d.verdict]}.", ""]
    if d.named_effects:
        lines += ["| effect (in the order added) | parameter | value | standard error |"]
        lines += ["|---|---|---|---|"]
        bounded: list[str] = []
        for name in d.named_effects:
            limits = {p.name: (p.low, p.high) for p in EFFECTS[name].parameters}
            for key, entry in d.parameters[name].items():
                value = entry["value"]
                edge = value in limits.get(key, ())
                if edge:
                    bounded.append(f"{name}.{key}")
                lines.append(
                    f"| {name} | {key} | {value:.6g}{' (bound)' if edge else ''} | "
                    f"{entry['stderr']:.2g} |"
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
    last = d.rounds[-1]
    if last.verdict == "ambiguous" and last.separating:
        sep = last.separating
        lines += [
            f"Tied in round {last.number}: {', '.join(last.tied)}. The experiment that would "
            f"separate {sep['between'][0]} from {sep['between'][1]} best: "
            f"**{sep['experiment']}** (the two fitted models' predictions differ by up to "
            f"{sep['separation_mm']:.1f} mm and {sep['separation_deg']:.2f}°, "
            f"{sep['separation_sigma']:.1f} × the sensor noise fitted on these data).",
            "",
        ]
    lines += [
        "## The gap on held-out runs",
        "",
        f"Held out: {len(d.holdout_runs)} runs ({', '.join(d.holdout_runs)}); fitted on "
        f"{len(d.fit_runs)}. Gap = {GAP_METRIC}.",
        "",
        "| | gap (1 = noise) | 95 % interval | position RMS [mm] | heading RMS [°] |",
        "|---|---|---|---|---|",
        f"| model as given | {d.gap_before:.2f} | "
        f"{d.gap_ci['before'][0]:.2f}–{d.gap_ci['before'][1]:.2f} | "
        f"{d.physical['gap_position_mm'][0]:.2f} | {d.physical['gap_heading_deg'][0]:.3f} |",
        f"| updated model | {d.gap_after:.2f} | "
        f"{d.gap_ci['after'][0]:.2f}–{d.gap_ci['after'][1]:.2f} | "
        f"{d.physical['gap_position_mm'][1]:.2f} | {d.physical['gap_heading_deg'][1]:.3f} |",
        f"| noise alone | {d.noise_floor:.2f} | | | |",
        "",
        f"Fraction of the reducible gap closed: {d.fraction_closed:.2f} "
        f"(95 % interval {d.fraction_ci[0]:.2f}–{d.fraction_ci[1]:.2f}). Sensor noise fitted: "
        f"{1e3 * d.sensor.position:.2f} mm, {math.degrees(d.sensor.heading):.3f}°.",
        "",
        "## Candidates",
        "",
        "Held-out gain: log-likelihood gained on runs left out of the fit (cross-validation), "
        "summed over the fit runs; LR: in-sample likelihood ratio 2Δℓ, its p-value "
        "Bonferroni-corrected over the candidates; sign flips: family-wise max-T p over runs.",
        "",
        "| round | stage | effect | held-out gain [nats] | LR | p (family-wise) | p (sign flips) "
        "| fitted |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in d.rounds:
        for c in sorted(r.candidates, key=lambda c: (c.stage, -c.cv_gain)):
            fitted = ", ".join(f"{k} = {v:.4g}" for k, v in c.values.items())
            mark = " ✔" if c.significant else ""
            lines.append(
                f"| {r.number} | {c.stage} | {c.name}{mark} | {c.cv_gain:.1f} | {c.lr:.1f} | "
                f"{c.p_family:.2g} | {c.p_sign_flip:.2g} | {fitted} |"
            )
    lines += ["", "## Where the model as given disagrees (Holm-corrected tests)", ""]
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
    return "\n".join(lines) + "\n"


def _unit(unit: str) -> str:
    """Plot unit (mm, deg) of a finding's SI unit."""
    base = "mm" if unit in ("m", "m/m") else "deg"
    per = {"rad/m": "/m", "m/m": "/m", "rad/rad": "/rad"}.get(unit, "")
    return base + per


def _plot(diagnosis: Diagnosis, folder: Path) -> list[str]:
    from matplotlib.figure import Figure

    d = diagnosis
    written = []
    fig = Figure(figsize=(7, 4))
    ax = fig.add_subplot(1, 1, 1)
    runs = np.arange(len(d.holdout_runs))
    gaps = d.holdout_gaps
    ax.bar(runs - 0.2, np.array(gaps["before"]), 0.4, label="model as given")
    ax.bar(runs + 0.2, np.array(gaps["after"]), 0.4, label="updated model")
    ax.plot(runs, np.array(gaps["noise"]), "k_", markersize=14, label="noise alone")
    ax.set_xticks(runs, d.holdout_runs, rotation=60, fontsize=7)
    ax.set_ylabel("gap: RMS whitened innovation (1 = noise)")
    ax.set_title("held-out runs: gap before and after " + (", ".join(d.named_effects) or "—"))
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(folder / "gap_before_after.png", dpi=110)
    written.append("gap_before_after.png")

    findings = [f for f in d.findings]
    if findings:
        fig = Figure(figsize=(7, 0.28 * len(findings) + 1.2))
        ax = fig.add_subplot(1, 1, 1)
        y = np.arange(len(findings))
        scale = [1e3 if f.unit in ("m", "m/m") else math.degrees(1) for f in findings]
        means = [f.mean * s for f, s in zip(findings, scale, strict=True)]
        lows = [
            (f.mean - f.low) * s if math.isfinite(f.low) else 0
            for f, s in zip(findings, scale, strict=True)
        ]
        colours = ["tab:red" if f.significant else "tab:gray" for f in findings]
        ax.barh(y, means, xerr=lows, color=colours)
        ax.set_yticks(
            y, [f"{f.group}: {f.component} [{_unit(f.unit)}]" for f in findings], fontsize=7
        )
        ax.axvline(0, color="k", lw=0.5)
        ax.set_title("where the model as given disagrees (red: significant)")
        fig.tight_layout()
        fig.savefig(folder / "where.png", dpi=110)
        written.append("where.png")
    return written


def write_outputs(diagnosis: Diagnosis, out: Path, data: str) -> list[Path]:
    """Write everything into ``out`` (replacing an earlier diagnose output there) atomically."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OSError(f"{out} exists and is not a folder")
    parent = out.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=parent))
    try:
        (tmp / "report.json").write_text(report_json(diagnosis) + "\n", encoding="utf-8")
        (tmp / "report.md").write_text(format_markdown(diagnosis, data), encoding="utf-8")
        diagnosis.model.save(tmp / "model.toml")
        names = ["report.json", "report.md", "model.toml", *_plot(diagnosis, tmp)]
        os.chmod(tmp, 0o755)
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=parent))
            os.replace(out, old / "x")
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return [out / n for n in names]

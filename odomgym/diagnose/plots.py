"""The figures of a diagnosis (``odomgym diagnose --out``): ``gap_before_after.png``,
``held_out_paths.png``, ``where.png`` and one ``discovered-TERM.png`` per kept term.

Figures are matplotlib ``Figure`` objects drawn off-screen (no pyplot state), written by
:func:`plot_all` into the output folder :func:`odomgym.diagnose.report.write_outputs` renames
into place.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Any

import numpy as np

from odomgym.diagnose.results import Diagnosis

__all__ = ["plot_all"]


def _unit(unit: str) -> str:
    """Plot unit (mm, deg) of a finding's SI unit."""
    base = "mm" if unit in ("m", "m/m") else "deg"
    per = {"rad/m": "/m", "m/m": "/m", "rad/rad": "/rad"}.get(unit, "")
    return base + per


def plot_all(diagnosis: Diagnosis, folder: Path) -> list[str]:
    """Every figure of the report into ``folder``; returns their file names."""
    from matplotlib.figure import Figure

    d = diagnosis
    written = []
    fig = Figure(figsize=(8, 4.4), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    runs = np.arange(len(d.holdout_runs))
    gaps = d.holdout_gaps
    ax.bar(runs - 0.2, np.array(gaps["before"]), 0.4, label="model as given")
    ax.bar(runs + 0.2, np.array(gaps["after"]), 0.4, label="updated model")
    ax.plot(runs, np.array(gaps["noise"]), "k_", markersize=14, label="noise alone")
    ax.set_xticks(runs, d.holdout_runs, rotation=60, fontsize=7)
    ax.set_xlabel("held-out run (session-run)", fontsize=8)
    ax.set_ylabel("gap: RMS whitened innovation (1 = noise)")
    # The title names every effect added, wrapped so that no name is cut off.
    added = ", ".join(d.named_effects + [e["term"] for e in d.discovered]) or "nothing"
    title = textwrap.fill(
        f"held-out runs, whitened gap (a diagnostic): before and after {added}", 80
    )
    ax.set_title(title, fontsize=8)
    # Beside the bars, not over them: a tall first bar ran under the legend's corner.
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    fig.savefig(folder / "gap_before_after.png", dpi=110)
    written.append("gap_before_after.png")
    if d.held_out is not None and d.held_out.truth:
        written.append(_paths_plot(d, folder))

    findings = list(d.findings)
    if findings:
        written.append(_where_plot(findings, folder))
    for entry in d.discovered:
        if entry.get("evidence"):
            written.append(_evidence_plot(entry, folder))
    return written


_STYLES = {  # (colour, line style) of each model's path
    "as given": ("tab:gray", "--"),
    "diagnosed": ("tab:blue", "-"),
    "baseline": ("tab:orange", ":"),
}


def _paths_plot(d: Diagnosis, folder: Path) -> str:
    """``held_out_paths.png``: for a few held-out runs, the measured path and the open-loop
    predictions of the model as given, the diagnosed model and the baseline, in metres; below
    each, the three position errors over time (the paths alone hide millimetres).

    Where the ground truth has gaps the measured path and the errors are drawn at the measured
    samples only: lines break at a gap, and every measured sample is marked, so that a sample
    between two gaps shows and no line stands for what was not measured."""
    from matplotlib.figure import Figure

    assert d.held_out is not None
    held = d.held_out
    names = list(held.truth)
    cols = min(2, len(names))
    rows = math.ceil(len(names) / cols)
    fig = Figure(figsize=(5.4 * cols, 6.4 * rows + 0.4))
    grid = fig.add_gridspec(2 * rows, cols, height_ratios=[3.0, 1.2] * rows)
    for k, name in enumerate(names):
        row, col = divmod(k, cols)
        ax = fig.add_subplot(grid[2 * row, col])
        err_ax = fig.add_subplot(grid[2 * row + 1, col])
        truth = held.truth[name]
        time, xy = truth[:, 0], truth[:, 1:]
        gappy = bool(np.isnan(xy).any())
        dot = "." if gappy else None
        ax.plot(
            xy[:, 0], xy[:, 1], "k-", lw=2.2, alpha=0.35, label="ground truth", marker=dot, ms=3
        )
        for label, model in held.models.items():
            if name not in model.paths:
                continue
            path = model.paths[name]
            index = model.runs.index(name)
            colour, style = _STYLES.get(label, ("tab:green", "-"))
            ax.plot(
                path[:, 0],
                path[:, 1],
                color=colour,
                linestyle=style,
                lw=1.2,
                label=f"{label}: {1e3 * model.position[index]:.1f} mm RMS",
            )
            error = 1e3 * np.hypot(*(path - xy).T)  # NaN in the gaps: the line breaks
            err_ax.plot(time, error, color=colour, linestyle=style, lw=1.0, marker=dot, ms=3)
        ax.plot(xy[0, 0], xy[0, 1], "ko", ms=4)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(f"run {name}", fontsize=9)
        ax.legend(fontsize=7, loc="best")
        ax.grid(True, lw=0.3)
        err_ax.set_xlabel("time [s]")
        err_ax.set_ylabel("position error [mm]")
        err_ax.grid(True, lw=0.3)
    fig.suptitle("held-out runs predicted open loop from the logged wheel motions", fontsize=10)
    fig.tight_layout()
    fig.savefig(folder / "held_out_paths.png", dpi=110)
    return "held_out_paths.png"


def _panel_key(unit: str, component: str) -> tuple[str, str, float]:
    """(panel title, axis unit, SI → plot factor) of a finding: one panel per component, with
    rates per metre or per radian apart from the final disagreements."""
    factor = 1e3 if unit in ("m", "m/m") else math.degrees(1.0)
    axis = _unit(unit)
    rate = unit in ("rad/m", "m/m", "rad/rad")
    title = f"{component} ({'rate' if rate else 'final'})"
    return title, axis, factor


def _where_plot(findings: list[Any], folder: Path) -> str:
    """``where.png``: one panel per component (along, cross, heading; rates apart), each in its
    own unit."""
    from matplotlib.figure import Figure

    panels: dict[tuple[str, str], list[Any]] = {}
    factors: dict[tuple[str, str], float] = {}
    for f in findings:
        title, axis, factor = _panel_key(f.unit, f.component)
        panels.setdefault((title, axis), []).append(f)
        factors[(title, axis)] = factor
    keys = sorted(panels)
    heights = [0.26 * len(panels[k]) + 0.9 for k in keys]
    # Constrained layout makes room for the longest group name ("manoeuvres: reversal: heading
    # per reversal" was cut at the left edge under tight_layout with this grid).
    fig = Figure(figsize=(7.5, sum(heights) + 0.6), layout="constrained")
    grid = fig.add_gridspec(len(keys), 1, height_ratios=heights)
    for row, key in enumerate(keys):
        ax = fig.add_subplot(grid[row, 0])
        group = panels[key]
        factor = factors[key]
        y = np.arange(len(group))
        means = [f.mean * factor for f in group]
        errs = [(f.mean - f.low) * factor if math.isfinite(f.low) else 0.0 for f in group]
        colours = ["tab:red" if f.significant else "tab:gray" for f in group]
        ax.barh(y, means, xerr=errs, color=colours)
        ax.set_yticks(y, [f"{f.view}: {f.group}" for f in group], fontsize=7)
        ax.axvline(0, color="k", lw=0.5)
        # Intervals of two-run groups can be huge: keep the means readable.
        reach = 3.0 * max([abs(m) for m in means] + [1e-9])
        ax.set_xlim(-reach, reach)
        ax.set_xlabel(f"{key[0]} [{key[1]}]", fontsize=8)
        ax.tick_params(axis="x", labelsize=7)
    fig.suptitle(
        "where the model as given disagrees with the logs: mean error per group with its 95 % "
        "interval\n(red: significant after Holm's correction; grey: not significant)",
        fontsize=9,
    )
    fig.savefig(folder / "where.png", dpi=110, bbox_inches="tight")
    return "where.png"


def _evidence_plot(entry: dict[str, Any], folder: Path) -> str:
    """``discovered-TERM.png``: the term's channel against its modulator (binned means with
    standard errors) and the fitted term."""
    from matplotlib.figure import Figure

    ev = entry["evidence"]
    crab = entry["channel"] == "crab"
    factor = math.degrees(1.0) if crab else 100.0
    fig = Figure(figsize=(5.5, 3.6))
    ax = fig.add_subplot(1, 1, 1)
    x = np.array(ev["x"])
    ax.errorbar(
        x,
        np.array(ev["y"]) * factor,
        yerr=np.array(ev["se"]) * factor,
        fmt="o",
        label=f"measured, binned ({ev['intervals']} intervals)",
    )
    line = np.linspace(float(x.min()), float(x.max()), 50)
    ax.plot(line, entry["coefficient"] * line * factor, "-", label="discovered term")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel(f"modulator: {entry['modulator']}")
    channel = {
        "left": "left wheel travel error [%]",
        "right": "right wheel travel error [%]",
        "crab": "crab angle [°]",
        "yaw": "yaw error [%]",
    }[entry["channel"]]
    ax.set_ylabel(channel)
    ax.set_title(entry["sentence"][:90] + ("…" if len(entry["sentence"]) > 90 else ""), fontsize=7)
    ax.legend(fontsize=7)
    fig.tight_layout()
    name = f"discovered-{entry['term']}.png"
    fig.savefig(folder / name, dpi=110)
    return name

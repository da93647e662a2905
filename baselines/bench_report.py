"""Tables, files and plots of the calibrator benchmark (:mod:`odomgym.baselines.benchmark`).

Everything is written atomically into one output folder:

* ``summary.md`` — per floor, one row per method: improvement of E_max,syst (median and
  quartiles), E_max,syst after, parameter errors against the hidden truth, runs, distance, wall
  time, failures; then the same split by the size of the wheelbase error |E_b − 1|;
* ``summary.csv``, ``results.csv`` (one row per robot, method, floor), ``results.json``;
* ``improvement.png`` (distributions per method and floor) and ``scatter_<method>.png``
  (robot 0's return errors before/after, like Borenstein & Feng 1994, Fig. 6.5).
"""

from __future__ import annotations

import csv
import io
import json
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from odomgym.baselines.benchmark import BenchConfig, config_record, summarize
from odomgym.io import atomic_write_text, atomic_writer
from odomgym.lab.population import BENCH_FLOORS
from odomgym.lab.report import plot_return_errors
from odomgym.robot import PRESETS

__all__ = ["OUTPUT_FILES", "is_output_name", "markdown_summary", "write_outputs"]

OUTPUT_FILES = ("summary.md", "summary.csv", "results.csv", "results.json", "improvement.png")
"""The files :func:`write_outputs` writes into the output folder, besides one
``scatter_<method>.png`` per method: what ``odomgym bench`` may replace there."""

SCATTER_PREFIX, SCATTER_SUFFIX = "scatter_", ".png"


def is_output_name(name: str) -> bool:
    """Whether a file called ``name`` is one :func:`write_outputs` writes (:data:`OUTPUT_FILES`
    or a ``scatter_<method>.png``)."""
    scatter = name.startswith(SCATTER_PREFIX) and name.endswith(SCATTER_SUFFIX)
    return name in OUTPUT_FILES or scatter


LARGE_EB = 0.025  # |E_b − 1| above this counts as a "large" wheelbase error


def _cell(summary: dict[str, Any]) -> str:
    return (
        f"{summary['improvement_median']:.1f} "
        f"[{summary['improvement_q25']:.1f}–{summary['improvement_q75']:.1f}]"
    )


def _fraction(summary: dict[str, Any]) -> str:
    value = summary["of_oracle_median"]
    return f"{100 * value:.0f} %" if np.isfinite(value) else "–"


def _robots(count: int) -> str:
    """``"1 robot"``, ``"20 robots"``: a header's count in words a reader expects."""
    return f"{count} robot" + ("" if count == 1 else "s")


def markdown_summary(config: BenchConfig, rows: Sequence[dict[str, Any]]) -> str:
    """The Markdown report (see the module docstring)."""
    summary = summarize(rows)
    lines = [
        f"# Calibrator benchmark: {_robots(config.robots)}, budget "
        f"{' / '.join(str(b) for b in config.budgets)} runs, "
        f"seed {config.seed}",
        "",
        f"Population: {config.population.base}, E_d ∈ {list(config.population.e_d)}, "
        f"E_b ∈ {list(config.population.e_b)}, E_s ∈ {list(config.population.e_s)}. "
        f"Validation: {config.validation_runs} cw + {config.validation_runs} ccw fresh 4×4 m "
        "squares per robot, true return errors. Improvement = E_max,syst before / after "
        "(Borenstein & Feng 1994, Table III, reports 10–22-fold for UMBmark on a LabMate)."
        + (
            " The `oracle` row is the robot's true parameters as the calibration, validated the "
            "same way: the ceiling the validation's own noise allows; *of oracle* is, per robot, "
            "the oracle's E_max,syst after / the method's (median)."
            if config.oracle
            else ""
        )
        + (
            " On a skid-steer base, abs(ΔE_b) is the fitted E_b — the apparent track the "
            "odometry needs, wider than the wheels' spacing by the scrub — against the spacing's "
            "true error, so it is large for every method that works (about the apparent track's "
            "factor − 1): read the improvement. There is no oracle row (the true geometry is "
            "not the odometry such a robot needs), so *of oracle* is –."
            if PRESETS[config.population.base].is_skid_steer
            else ""
        ),
        "",
    ]
    for floor in config.floors:
        lines += [
            f"## Floor: {floor} ({BENCH_FLOORS[floor].description})",
            "",
            "| method | E_max,syst before → after [mm] | improvement median [q25–q75] | "
            "of oracle | abs(ΔE_d) | abs(ΔE_b) | abs(ΔE_s) | runs | distance [m] | "
            "wall/robot [s] | failed |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for s in (s for s in summary if s["floor"] == floor):
            lines.append(
                f"| {s['method']} | {s['e_max_before_median_mm']:.0f} → "
                f"{s['e_max_after_median_mm']:.1f} | {_cell(s)} | {_fraction(s)} | "
                f"{s['abs_err_E_d_median']:.2e} | {s['abs_err_E_b_median']:.2e} | "
                f"{s['abs_err_E_s_median']:.2e} | {s['runs_mean']:.0f} | "
                f"{s['distance_m_mean']:.0f} | {s['wall_time_s_mean']:.3f} | {s['failures']} |"
            )
        small = [r for r in rows if r["floor"] == floor and abs(r["true_E_b"] - 1) <= LARGE_EB]
        large = [r for r in rows if r["floor"] == floor and abs(r["true_E_b"] - 1) > LARGE_EB]
        if small and large:
            lines += [
                "",
                f"By wheelbase error (|E_b − 1| ≤ {LARGE_EB} vs larger), median improvement:",
                "",
                "| method | small E_b error | large E_b error |",
                "|---|---|---|",
            ]
            by_small = {s["method"]: s for s in summarize(small)}
            by_large = {s["method"]: s for s in summarize(large)}
            for method in config.labels():
                if method in by_small and method in by_large:
                    lines.append(
                        f"| {method} | {_cell(by_small[method])} | {_cell(by_large[method])} |"
                    )
        lines.append("")
    return "\n".join(lines)


def _csv(records: Sequence[dict[str, Any]]) -> str:
    if not records:
        return ""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(records[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(records)
    return buffer.getvalue()


def write_outputs(
    config: BenchConfig, rows: Sequence[dict[str, Any]], out: Path, elapsed: float
) -> list[Path]:
    """Write every output file into ``out``; returns their paths.

    A ``scatter_<method>.png`` of an earlier run whose method is not in this one is removed
    (after everything else is written): beside this run's summary it would read as one of its
    results."""
    out.mkdir(parents=True, exist_ok=True)
    plain = [{k: v for k, v in r.items() if k != "scatter"} for r in rows]
    summary = summarize(rows)
    written = [out / name for name in ("summary.md", "summary.csv", "results.csv", "results.json")]
    atomic_write_text(written[0], markdown_summary(config, rows))
    atomic_write_text(written[1], _csv(summary))
    atomic_write_text(written[2], _csv(plain))
    document = {
        "config": config_record(config),
        "elapsed_s": elapsed,
        "summary": summary,
        "rows": plain,
    }
    atomic_write_text(written[3], json.dumps(document, indent=1, default=float))
    written.append(_plot_improvements(config, rows, out / "improvement.png"))
    for row in rows:
        if "scatter" in row:
            path = out / f"{SCATTER_PREFIX}{row['method']}{SCATTER_SUFFIX}"
            before, after = row["scatter"]["before"], row["scatter"]["after"]
            plot_return_errors(
                path,
                [
                    ("before", np.array(before["cw"]), np.array(before["ccw"])),
                    ("after", np.array(after["cw"]), np.array(after["ccw"])),
                ],
                f"UMBmark return errors before and after calibration by {row['method']}\n"
                f"(robot {row['robot']}, {row['floor']} floor)",
            )
            written.append(path)
    for stale in out.glob(f"{SCATTER_PREFIX}*{SCATTER_SUFFIX}"):
        if stale not in written and stale.is_file() and not stale.is_symlink():
            stale.unlink()
    return written


def _improvement_axis(ax: Any, values: Sequence[float]) -> None:
    """A log axis for improvement factors (dimensionless) in plain numbers, without
    minor-tick labels: matplotlib's default labels every minor tick of a log axis spanning
    less than a decade ("4×10⁰ 6×10⁰ 2×10¹ 3×10¹…"), which overlapped on a narrow panel such
    as the `rough` floor's. Labels run 1-2-5 per decade while the factors span at most two
    decades, one per decade beyond: a skid-steer population's factors run from 1× to over
    1000×, where 1-2-5 labels ran together ("5001000")."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    positive = [v for v in values if np.isfinite(v) and v > 0]
    decades = np.log10(max(positive) / min(positive)) if positive else 0.0
    ax.set_xscale("log")
    subs = (1.0, 2.0, 5.0) if decades <= 2.0 else (1.0,)
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=subs))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _pos: f"{x:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())


def _plot_improvements(config: BenchConfig, rows: Sequence[dict[str, Any]], path: Path) -> Path:
    """Box plots of the improvement per method, one panel per floor. The boxes lie
    horizontally with the method names beside them on the left, one line each, so that ten
    or more methods (and their budgets) stay readable; the figure grows with their number."""
    # A Figure without pyplot: no global backend switch, nothing left open in a notebook.
    from matplotlib.figure import Figure

    labels = config.labels()
    height = 1.6 + 0.32 * len(labels)
    fig = Figure(figsize=(1.6 + 3.6 * len(config.floors), max(3.2, height)), layout="constrained")
    axes = fig.subplots(1, len(config.floors), sharey=True, squeeze=False)
    for ax, floor in zip(axes[0], config.floors, strict=True):
        data = [
            [
                r["improvement"]
                for r in rows
                if r["floor"] == floor and r["method"] == m and np.isfinite(r["improvement"])
            ]
            for m in labels
        ]
        ax.boxplot(data, showfliers=True, orientation="horizontal")
        ax.set_yticks(range(1, len(labels) + 1), labels, fontsize=8)
        ax.invert_yaxis()  # the first method on top, as in the tables
        _improvement_axis(ax, [v for d in data for v in d])
        ax.axvspan(
            10,
            22,
            color="tab:green",
            alpha=0.12,
            label="Borenstein & Feng 1994, Table III (10–22×)",
        )
        ax.set_title(f"{floor} floor")
        ax.grid(True, axis="x", alpha=0.3)
        ax.set_xlabel("improvement: E_max,syst before / after [×, log scale]")
    handles, names = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, names, fontsize=8, loc="outside lower center")  # clear of the boxes
    budgets = " / ".join(str(b) for b in config.budgets)
    title = (
        f"How much each calibrator reduces the UMBmark error E_max,syst (fresh validation "
        f"squares): {_robots(config.robots)} per floor, budget {budgets} runs"
    )
    # Wrapped to the figure's width (about ten characters of the title's 12-pt type per inch):
    # with one or two floors the figure is narrower than the title's single line.
    fig.suptitle(textwrap.fill(title, width=int(10 * fig.get_figwidth())))

    def write(tmp: Path) -> None:
        fig.savefig(tmp, dpi=110, format="png")

    atomic_writer(path, write)
    return path

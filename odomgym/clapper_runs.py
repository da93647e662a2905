"""The CLAPPER experiments of Borenstein 1995, §6, as repeated runs with and without IPEC: the
records, the table of average absolute orientation errors and a figure like the paper's
Figs. 8 and 10 (``odomgym run clapper-straight|clapper-rectangle``).

Runs differ by the floor's wheel noise (the ``concrete`` floor by default, each run from its
own seed) and, on the rectangle, by the side the cables lie under (half the runs right, half
left, as in §6.2).

Every file is written atomically (:mod:`odomgym.io`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.clapper import (
    CableLayer,
    EstimatorFactory,
    VehicleOutcome,
    drive_vehicles,
    evenly,
    rectangle_cable_positions,
    rectangle_path,
    straight_path,
)
from odomgym.floor import FloorSpec
from odomgym.report import save_error_axes
from odomgym.vehicle import VehicleSpec

__all__ = ["ClapperRun", "format_clapper_runs", "plot_clapper_runs", "run_clapper"]

FloatArray = NDArray[np.float64]
Experiment = Literal["straight", "rectangle"]


@dataclass(frozen=True)
class ClapperRun:
    """One run (``index`` from 1, as ``odomgym run square``): its settings and its outcome (a
    vehicle of one)."""

    index: int
    experiment: Experiment
    ipec: bool
    direction: str
    side: str
    bumps: int
    outcome: VehicleOutcome

    def record(self) -> dict[str, Any]:
        """A JSON-ready record: ``return_error`` {x, y [m], theta [rad]} of the vehicle (true
        minus estimated; midpoint of the truck centres, heading of the link) and per truck."""
        vehicle = self.outcome.return_error[0]
        trucks = self.outcome.truck_errors[0]

        def pose(e: FloatArray) -> dict[str, float]:
            return {"x": float(e[0]), "y": float(e[1]), "theta": float(e[2])}

        return {
            "run": self.index,
            "experiment": self.experiment,
            "ipec": self.ipec,
            "direction": self.direction,
            "side": self.side,
            "bumps": self.bumps,
            "return_error": pose(vehicle),
            "trucks": {"A": pose(trucks[0]), "B": pose(trucks[1])},
            "duration_s": self.outcome.time,
            "finished": bool(self.outcome.finished[0]),
        }


def run_clapper(
    spec: VehicleSpec,
    floor: FloorSpec,
    experiment: Experiment,
    *,
    ipec_modes: Sequence[bool] = (False, True),
    directions: Sequence[str] = ("cw",),
    bumps: int = 10,
    sides: Sequence[str] = ("right",),
    runs: int = 1,
    seed: int = 0,
    ipec: EstimatorFactory | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[ClapperRun]:
    """Drive ``runs`` runs per (IPEC mode, direction); run r lays its cables under
    ``sides[r % len(sides)]`` and draws its floor noise from ``SeedSequence([seed, r])``, so
    the runs with and without IPEC meet the same floor. ``ipec`` builds the IPEC estimator
    (e.g. :func:`odomgym.envs.clapper.ipec_estimator`; the core does not import baselines)."""
    if ipec is None and any(ipec_modes):
        raise ValueError("runs with IPEC need ipec= (e.g. odomgym.envs.clapper.ipec_estimator())")
    plans = [(mode, d, r) for mode in ipec_modes for d in directions for r in range(runs)]
    done: list[ClapperRun] = []
    for k, (mode, direction, r) in enumerate(plans):
        side = sides[r % len(sides)]
        if experiment == "straight":
            path = straight_path(18.0)
            cables = CableLayer(evenly(bumps), leg=1, side=side) if bumps else None  # type: ignore[arg-type]
        else:
            path = rectangle_path(direction=direction)  # type: ignore[arg-type]
            positions = rectangle_cable_positions(path, bumps)
            cables = CableLayer(positions, leg=0, side=side) if bumps else None  # type: ignore[arg-type]
        rng = np.random.default_rng(np.random.SeedSequence([seed, r]))
        outcome = drive_vehicles(
            spec, floor, path, estimator=ipec if mode else None, cables=cables, rng=rng
        )
        done.append(ClapperRun(r + 1, experiment, mode, direction, side, bumps, outcome))
        if progress is not None:
            progress(k + 1, len(plans))
    return done


def _mean_abs_theta(runs: Sequence[ClapperRun]) -> float:
    return float(np.mean([abs(run.outcome.return_error[0, 2]) for run in runs]))


def summarize(runs: Sequence[ClapperRun]) -> dict[str, Any]:
    """Average absolute return orientation error [rad] (Borenstein 1995, Eq. 17, as recovered
    in docs/clapper_design_notes.md) with and without IPEC, per direction and overall, and the
    fold reduction."""
    out: dict[str, Any] = {"runs": len(runs)}
    for label, mode in (("without_ipec", False), ("with_ipec", True)):
        chosen = [r for r in runs if r.ipec == mode]
        if chosen:
            out[label] = {"mean_abs_theta": _mean_abs_theta(chosen)}
            for d in sorted({r.direction for r in chosen}):
                out[label][d] = _mean_abs_theta([r for r in chosen if r.direction == d])
    if "with_ipec" in out and "without_ipec" in out:
        ratio = out["without_ipec"]["mean_abs_theta"] / max(
            out["with_ipec"]["mean_abs_theta"], 1e-12
        )
        out["reduction"] = ratio
    return out


def format_clapper_runs(runs: Sequence[ClapperRun]) -> str:
    """The runs as a table (mm, degrees) and the average absolute orientation errors."""
    lines = ["run  IPEC  dir  side   bumps  x [mm]    y [mm]   theta [deg]"]
    for run in runs:
        e = run.outcome.return_error[0]
        lines.append(
            f"{run.index:3d}  {'yes' if run.ipec else 'no ':3}  {run.direction:3}  "
            f"{run.side:5}  {run.bumps:5d}  {1e3 * e[0]:8.1f}  {1e3 * e[1]:8.1f}  "
            f"{np.degrees(e[2]):9.3f}"
        )
    summary = summarize(runs)
    lines.append("")
    lines.append("average absolute return orientation error [deg]")
    for label in ("without_ipec", "with_ipec"):
        if label in summary:
            parts = [f"all {np.degrees(summary[label]['mean_abs_theta']):.3f}"]
            parts += [
                f"{d} {np.degrees(v):.3f}"
                for d, v in summary[label].items()
                if d != "mean_abs_theta"
            ]
            lines.append(f"  {label.replace('_', ' ')}: " + ", ".join(parts))
    if "reduction" in summary:
        lines.append(f"  IPEC reduces it {summary['reduction']:.1f}-fold")
    return "\n".join(lines)


def plot_clapper_runs(path: Path, runs: Sequence[ClapperRun], title: str) -> None:
    """Return position errors with and without IPEC, like Borenstein 1995, Figs. 8 and 10,
    with the average absolute orientation errors in the legend."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.5, 6.0))
    ax = fig.subplots()
    styles = {False: ("*", "tab:red", "without IPEC"), True: ("s", "tab:blue", "with IPEC")}
    for mode, (marker, colour, label) in styles.items():
        chosen = [r for r in runs if r.ipec == mode]
        if not chosen:
            continue
        e = 1e3 * np.array([r.outcome.return_error[0, :2] for r in chosen])
        mean = np.degrees(_mean_abs_theta(chosen))
        ax.scatter(
            e[:, 0], e[:, 1], marker=marker, color=colour, label=f"{label}: |θ| avg {mean:.2f}°"
        )
    save_error_axes(fig, ax, path, title)

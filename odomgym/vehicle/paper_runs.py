"""The CLAPPER experiments of Borenstein 1995, §6, as seeded Monte-Carlo sets: the records,
the distributions the paper's figures show (mean ± sd and the worst run, per condition, for the
vehicle and for each truck) and a figure like the paper's Figs. 8 and 10
(``odomgym run clapper-straight|clapper-rectangle``).

The paper's conditions (:data:`PAPER_CONDITIONS`): the 18 m straight out and back (§6.1)
a. without IPEC, without bumps; b. without IPEC, ten bumps; c. with IPEC, without bumps;
d. with IPEC, twenty bumps (on the return leg, under the right-side wheels); the 7×4 m
rectangle (§6.2) with ten bumps, with and without IPEC, cw and ccw, the cables under the right
wheels in half the runs and the left in the other half. Runs differ by the floor's wheel noise
(:data:`CLAPPER_FLOOR`, each run from its own seed) and, on the rectangle, the cables' side.

Every file is written atomically (:mod:`odomgym.io`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.floor import FloorSpec
from odomgym.lab.report import save_error_axes
from odomgym.vehicle.cable_layout import CableLayer, evenly, rectangle_cable_positions
from odomgym.vehicle.controller import VehicleDriver
from odomgym.vehicle.paths import rectangle_path, straight_path
from odomgym.vehicle.spec import VehicleSpec
from odomgym.vehicle.trial import CLAPPER_FLOOR, EstimatorFactory, VehicleOutcome, drive_vehicles

__all__ = [
    "CLAPPER_FLOOR",
    "PAPER_CONDITIONS",
    "SONAR",
    "ClapperRun",
    "Condition",
    "format_clapper_runs",
    "plot_clapper_runs",
    "run_clapper",
    "summarize",
]

FloatArray = NDArray[np.float64]
Experiment = Literal["straight", "rectangle"]


SONAR = (0.002, float(np.radians(0.25)))
"""The paper's measurement of the return pose: ±2 mm in x and y, ±0.25° (Borenstein 1995, §6)."""


@dataclass(frozen=True)
class Condition:
    """One experimental condition: a label, IPEC on or off and the number of cables."""

    label: str
    ipec: bool
    bumps: int


PAPER_CONDITIONS: dict[str, tuple[Condition, ...]] = {
    "straight": (
        Condition("a", False, 0),
        Condition("b", False, 10),
        Condition("c", True, 0),
        Condition("d", True, 20),
    ),
    "rectangle": (Condition("without IPEC", False, 10), Condition("with IPEC", True, 10)),
}
"""Borenstein 1995, §6.1 (a–d, three runs each) and §6.2 (10 cw + 10 ccw runs, ten bumps)."""


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
    condition: str = ""
    sonar: FloatArray | None = None  # the return-pose measurement's error (x, y [m], θ [rad])

    def measured(self) -> tuple[FloatArray, FloatArray]:
        """(vehicle (3,), trucks (2, 3)) return errors as measured: true minus estimated, plus
        the sonar's measurement error when the run had one (``run_clapper(sonar=...)``)."""
        vehicle = self.outcome.return_error[0].copy()
        trucks = self.outcome.truck_errors[0].copy()
        if self.sonar is not None:
            vehicle += self.sonar
            trucks += self.sonar[None, :]
        return vehicle, trucks

    def record(self) -> dict[str, Any]:
        """A JSON-ready record: ``return_error`` {x, y [m], theta [rad]} of the vehicle (true
        minus estimated; midpoint of the truck centres, heading of the link) and per truck."""
        vehicle, trucks = self.measured()

        def pose(e: FloatArray) -> dict[str, float]:
            return {"x": float(e[0]), "y": float(e[1]), "theta": float(e[2])}

        outcome = self.outcome
        return {
            "run": self.index,
            "experiment": self.experiment,
            "condition": self.condition,
            "ipec": self.ipec,
            "direction": self.direction,
            "side": self.side,
            "bumps": self.bumps,
            "return_error": pose(vehicle),
            "trucks": {"A": pose(trucks[0]), "B": pose(trucks[1])},
            "link_force_max_n": float(outcome.link_force[0]),
            "link_range_m": [float(v) for v in outcome.link_range[0]],
            "cable_crossings": {
                "A": int(outcome.cable_crossings[0, 0]) if len(outcome.cable_crossings) else 0,
                "B": int(outcome.cable_crossings[0, 1]) if len(outcome.cable_crossings) else 0,
            },
            "corrections_rad": {
                "A": float(outcome.corrections[0, 0]),
                "B": float(outcome.corrections[0, 1]),
            },
            "sonar_error": pose(self.sonar) if self.sonar is not None else None,
            "duration_s": outcome.time,
            "finished": bool(outcome.finished[0]),
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
    conditions: Sequence[Condition] | None = None,
    driver: Callable[[], VehicleDriver] | None = None,
    sonar: tuple[float, float] | None = None,
) -> list[ClapperRun]:
    """Drive ``runs`` runs per (condition, direction); run r lays its cables under
    ``sides[r % len(sides)]`` and draws its floor noise from ``SeedSequence([seed, r])``, so
    the runs of every condition meet the same floors. ``conditions`` (e.g.
    ``PAPER_CONDITIONS["straight"]``) replace ``ipec_modes`` × ``bumps``. ``ipec`` builds the
    IPEC estimator (e.g. :func:`odomgym.vehicle.ipec.ipec_estimator`; the core does not import
    baselines); ``driver`` builds the controller (default :class:`VehicleDriver`). ``sonar``
    = (position, heading) half-widths [m, rad]: the return pose is measured as the paper's
    sonars did, "within ±2 millimeters in the x and y directions, and to about ±0.25° in
    orientation" (§6; ``SONAR``), a uniform error added to every reported return error, drawn
    from its own stream (``SeedSequence([seed, r, 1, k])``, k the run's place in the set), so
    the runs themselves do not change."""
    chosen = (
        list(conditions)
        if conditions is not None
        else [Condition("with IPEC" if m else "without IPEC", bool(m), bumps) for m in ipec_modes]
    )
    if ipec is None and any(c.ipec for c in chosen):
        raise ValueError("runs with IPEC need ipec= (e.g. odomgym.vehicle.ipec.ipec_estimator())")
    plans = [(c, d, r) for c in chosen for d in directions for r in range(runs)]
    done: list[ClapperRun] = []
    for k, (condition, direction, r) in enumerate(plans):
        mode, bumps = condition.ipec, condition.bumps
        side = sides[r % len(sides)]
        if experiment == "straight":
            path = straight_path(18.0)
            cables = CableLayer(evenly(bumps), leg=1, side=side) if bumps else None  # type: ignore[arg-type]
        else:
            path = rectangle_path(direction=direction)  # type: ignore[arg-type]
            positions = rectangle_cable_positions(path, bumps, trailing=spec.link_length)
            cables = CableLayer(positions, leg=0, side=side) if bumps else None  # type: ignore[arg-type]
        rng = np.random.default_rng(np.random.SeedSequence([seed, r]))
        outcome = drive_vehicles(
            spec,
            floor,
            path,
            estimator=ipec if mode else None,
            cables=cables,
            rng=rng,
            driver=driver() if driver is not None else None,
        )
        error = None
        if sonar is not None:
            measuring = np.random.default_rng(np.random.SeedSequence([seed, r, 1, k]))
            error = measuring.uniform(-1.0, 1.0, 3) * np.array([sonar[0], sonar[0], sonar[1]])
        done.append(
            ClapperRun(
                r + 1, experiment, mode, direction, side, bumps, outcome, condition.label, error
            )
        )
        if progress is not None:
            progress(k + 1, len(plans))
    return done


def _mean_abs_theta(runs: Sequence[ClapperRun]) -> float:
    return float(np.mean([abs(run.measured()[0][2]) for run in runs]))


def _spread(values: Sequence[float]) -> dict[str, float]:
    """Mean of the absolute values, their sample standard deviation and the worst one."""
    a = np.abs(np.asarray(values, dtype=float))
    return {
        "mean_abs": float(a.mean()),
        "sd": float(a.std(ddof=1)) if len(a) > 1 else 0.0,
        "worst": float(a.max()),
    }


def _group(runs: Sequence[ClapperRun]) -> dict[str, Any]:
    """The distributions of one group of runs: orientation errors [rad] of the vehicle and of
    each truck, position errors [m], the largest end-stop force [N] and the cable crossings."""
    vehicle, trucks = zip(*(r.measured() for r in runs), strict=True)
    crossings = np.array(
        [r.outcome.cable_crossings[0] if len(r.outcome.cable_crossings) else (0, 0) for r in runs]
    )
    theta_vehicle = _spread([e[2] for e in vehicle])
    return {
        "runs": len(runs),
        "ipec": runs[0].ipec,
        "bumps": runs[0].bumps,
        "theta_vehicle": theta_vehicle,
        "theta_truck_a": _spread([t[0, 2] for t in trucks]),
        "theta_truck_b": _spread([t[1, 2] for t in trucks]),
        "position": _spread([float(np.hypot(e[0], e[1])) for e in vehicle]),
        "mean_abs_theta": theta_vehicle["mean_abs"],
        "link_force_max_n": float(max(r.outcome.link_force[0] for r in runs)),
        "cable_crossings_mean": {
            "A": float(crossings[:, 0].mean()),
            "B": float(crossings[:, 1].mean()),
        },
    }


def summarize(runs: Sequence[ClapperRun]) -> dict[str, Any]:
    """Per condition (and, with two directions, per direction): mean ± sd and worst of the
    absolute return orientation error [rad] of the vehicle (link heading, Borenstein 1995,
    Eq. 17 as recovered in docs/clapper_design_notes.md) and of each truck's own heading, of the
    position error [m], the largest end-stop force and the mean cable crossings; and the fold
    reduction of the mean absolute orientation error by IPEC — vehicle and per truck — between
    the runs without IPEC with the most bumps and those with IPEC with the most bumps (§6.1:
    b vs d; §6.2: without vs with)."""
    out: dict[str, Any] = {"runs": len(runs), "conditions": {}}

    def label(run: ClapperRun) -> str:
        return run.condition or ("with IPEC" if run.ipec else "without IPEC")

    for name in dict.fromkeys(label(r) for r in runs):
        chosen = [r for r in runs if label(r) == name]
        group = _group(chosen)
        directions = sorted({r.direction for r in chosen})
        if len(directions) > 1:
            group["by_direction"] = {
                d: _group([r for r in chosen if r.direction == d]) for d in directions
            }
        out["conditions"][name] = group
    groups = out["conditions"].values()
    without = [g for g in groups if not g["ipec"]]
    with_ipec = [g for g in groups if g["ipec"]]
    if without and with_ipec:
        a = max(without, key=lambda g: g["bumps"])
        b = max(with_ipec, key=lambda g: g["bumps"])
        out["reduction"] = {
            key: a[key]["mean_abs"] / max(b[key]["mean_abs"], 1e-12)
            for key in ("theta_vehicle", "theta_truck_a", "theta_truck_b")
        }
    return out


def format_clapper_runs(runs: Sequence[ClapperRun]) -> str:
    """The runs as a table (mm, degrees) and the distributions per condition."""
    lines = [
        "run  cond.         dir  side   bumps  x [mm]    y [mm]   θ veh [°]  θ A [°]  θ B [°]  "
        "F [N]"
    ]
    for run in runs:
        e, t = run.measured()
        lines.append(
            f"{run.index:3d}  {run.condition[:12]:12}  {run.direction:3}  "
            f"{run.side:5}  {run.bumps:5d}  {1e3 * e[0]:8.1f}  {1e3 * e[1]:8.1f}  "
            f"{np.degrees(e[2]):9.3f}  {np.degrees(t[0, 2]):7.3f}  {np.degrees(t[1, 2]):7.3f}  "
            f"{run.outcome.link_force[0]:5.0f}"
        )
    summary = summarize(runs)
    lines += ["", "absolute return errors per condition: mean ± sd (worst run)"]
    lines.append(
        f"  {'condition':14} {'runs':>4}  {'vehicle θ [°]':>20}  {'truck A θ [°]':>20}  "
        f"{'truck B θ [°]':>20}  {'position [mm]':>20}"
    )

    def cell(d: dict[str, float], scale: float, digits: int) -> str:
        mean, sd, worst = (scale * d[k] for k in ("mean_abs", "sd", "worst"))
        return f"{mean:.{digits}f} ± {sd:.{digits}f} ({worst:.{digits}f})"

    for label, g in summary["conditions"].items():
        rows = [(label, g)] + [(f"  {d}", gd) for d, gd in g.get("by_direction", {}).items()]
        for name, gr in rows:
            deg = 180.0 / np.pi
            lines.append(
                f"  {name:14} {gr['runs']:4d}  {cell(gr['theta_vehicle'], deg, 2):>20}  "
                f"{cell(gr['theta_truck_a'], deg, 2):>20}  "
                f"{cell(gr['theta_truck_b'], deg, 2):>20}  "
                f"{cell(gr['position'], 1e3, 1):>20}"
            )
    if "reduction" in summary:
        r = summary["reduction"]
        lines.append(
            f"  IPEC reduces the mean absolute orientation error {r['theta_truck_a']:.1f}-fold "
            f"(truck A) and {r['theta_truck_b']:.1f}-fold (truck B); the vehicle's link heading "
            "is no measure without IPEC (the trucks' estimates drift apart: docs/clapper.md)"
        )
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
        e = 1e3 * np.array([r.measured()[0][:2] for r in chosen])
        mean = np.degrees(_mean_abs_theta(chosen))
        ax.scatter(
            e[:, 0], e[:, 1], marker=marker, color=colour, label=f"{label}: |θ| avg {mean:.2f}°"
        )
    save_error_axes(fig, ax, path, title)

"""Tables and plots for people, JSON for scripts — the output side of the command line.

Every file is written atomically (:mod:`odomgym.io`); nothing here runs a simulation.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.io import atomic_writer
from odomgym.odometry.umbmark_measures import UMBmarkSummary

__all__ = [
    "format_return_errors",
    "format_session_report",
    "format_simulation_report",
    "plot_return_errors",
    "to_json",
]

FloatArray = NDArray[np.float64]


def to_json(data: Any) -> str:
    """One line of JSON; numpy scalars and arrays become plain numbers and lists, and
    non-finite numbers become ``null``."""

    return json.dumps(_plain(data), allow_nan=False)


def _plain(value: Any) -> Any:
    """JSON-ready copy: arrays → lists, numpy scalars → Python, NaN/±inf → None (strict JSON,
    so tools like jq can read it)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def format_return_errors(
    rows: Sequence[tuple[int, str, FloatArray]], summary: UMBmarkSummary | None
) -> str:
    """A table of return errors ε (true − odometry) [mm, mm, deg] and the UMBmark measures."""
    lines = [
        f"{'run':>4} {'dir':>4} {'eps_x [mm]':>11} {'eps_y [mm]':>11} {'eps_theta [deg]':>16}",
    ]
    for run, direction, error in rows:
        lines.append(
            f"{run:>4} {direction:>4} {1e3 * error[0]:>11.2f} {1e3 * error[1]:>11.2f} "
            f"{math.degrees(error[2]):>16.3f}"
        )
    if summary is not None:
        lines.append("")
        lines.append(
            f"centre of gravity cw : x = {1e3 * summary.cg_cw[0]:8.2f} mm, "
            f"y = {1e3 * summary.cg_cw[1]:8.2f} mm"
        )
        lines.append(
            f"centre of gravity ccw: x = {1e3 * summary.cg_ccw[0]:8.2f} mm, "
            f"y = {1e3 * summary.cg_ccw[1]:8.2f} mm"
        )
        lines.append(
            f"E_max,syst = {1e3 * summary.e_max_syst:.2f} mm (Borenstein & Feng 1994, Eq. 3.3)"
        )
    return "\n".join(lines)


def plot_return_errors(
    path: Path,
    groups: Sequence[tuple[str, FloatArray, FloatArray]],
    title: str,
) -> None:
    """Scatter of return position errors like Borenstein & Feng 1994, Fig. 6.5.

    ``groups`` are ``(label, cw_errors (n, ≥2), ccw_errors (m, ≥2))`` — e.g. before and after
    calibration; each group's centres of gravity are marked and E_max,syst is in the legend.
    """
    # A Figure without pyplot: no global backend switch, nothing left open in a notebook.
    from matplotlib.figure import Figure

    from odomgym.odometry.umbmark_measures import centre_of_gravity, e_max_syst

    fig = Figure(figsize=(8.6, 6.0))  # 6.5 for the axes, the rest for the legend beside them
    ax = fig.subplots()
    markers = ("o", "s", "^", "D")
    for k, (label, cw, ccw) in enumerate(groups):
        marker = markers[k % len(markers)]
        filled = k > 0
        for errors, colour, name in ((cw, "tab:blue", "cw"), (ccw, "tab:red", "ccw")):
            if len(errors) == 0:
                continue
            e = 1e3 * np.asarray(errors)
            ax.scatter(
                e[:, 0],
                e[:, 1],
                marker=marker,
                facecolors=colour if filled else "none",
                edgecolors=colour,
                label=f"{label} {name}",
            )
            cg = 1e3 * centre_of_gravity(errors)
            ax.plot(cg[0], cg[1], marker="+", color=colour, markersize=16, mew=2)
        if len(cw) and len(ccw):
            ax.plot([], [], " ", label=f"{label}: E_max,syst = {1e3 * e_max_syst(cw, ccw):.1f} mm")
    ax.plot([], [], "+", color="0.3", markersize=12, mew=2, label="centre of gravity")
    save_error_axes(fig, ax, path, title)


def save_error_axes(fig: Any, ax: Any, path: Path, title: str) -> None:
    """Finish a return-position-error scatter (axes through zero, labels in mm, equal scale,
    legend) and write the figure to ``path`` atomically, in the format its suffix names."""
    ax.axhline(0.0, color="0.7", lw=0.8)
    ax.axvline(0.0, color="0.7", lw=0.8)
    ax.set_xlabel("return error x [mm]")
    ax.set_ylabel("return error y [mm]")
    ax.set_title(title)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    # Beside the axes, not on them: "best" still covered points when the errors filled the plot.
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    fig.tight_layout()

    def write(tmp: Path) -> None:
        fig.savefig(tmp, dpi=120, format=path.suffix.lstrip(".") or "png", bbox_inches="tight")

    atomic_writer(path, write)


def format_simulation_report(report: Any, floor_name: str) -> str:
    """Estimated versus hidden parameters, and E_max,syst before/after on fresh squares.

    ``report`` is an :class:`odomgym.baselines.validation.SimulationReport`.
    """
    robot = report.robot
    cal = report.result.calibration
    estimated = cal.parameters(robot)
    true = {
        "wheelbase": robot.true_wheelbase,
        "right_diameter": robot.true_right_diameter,
        "left_diameter": robot.true_left_diameter,
    }
    nominal = {
        "wheelbase": robot.wheelbase,
        "right_diameter": robot.wheel_diameter,
        "left_diameter": robot.wheel_diameter,
    }
    lines = [
        f"{report.method} on {robot.name}, {floor_name} floor: {report.result.runs_used} runs, "
        f"{report.result.distance_used:.1f} m driven, {report.wall_time:.2f} s",
        "",
        f"{'parameter':<16}{'nominal':>12}{'estimated':>12}{'true':>12}",
    ]
    for key, label in (
        ("wheelbase", "b [mm]"),
        ("right_diameter", "D_R [mm]"),
        ("left_diameter", "D_L [mm]"),
    ):
        lines.append(
            f"{label:<16}{1e3 * nominal[key]:>12.3f}{1e3 * estimated[key]:>12.3f}"
            f"{1e3 * true[key]:>12.3f}"
        )
    for label, est, tru in (
        ("E_d", cal.e_d, robot.e_d),
        ("E_b", cal.wheelbase_scale, robot.e_b),
        ("E_s", cal.distance_scale, robot.e_s),
    ):
        lines.append(f"{label:<16}{1.0:>12.5f}{est:>12.5f}{tru:>12.5f}")
    if cal.has_icr:
        # A skid-steer calibration's ICRs (Mandow et al. 2007); a robot's own geometry has none
        # to compare with (its apparent track emerges from the contacts' friction).
        for key, label in (
            ("icr_y_left", "y_L [mm]"),
            ("icr_y_right", "y_R [mm]"),
            ("icr_x", "x_ICR [mm]"),
        ):
            lines.append(f"{label:<16}{'':>12}{1e3 * estimated[key]:>12.3f}{'':>12}")
    if cal.has_track_curve:
        # A track that moves with the turn (Wang et al. 2015's form): its spin value.
        spin = 1e3 * estimated["spin_wheelbase"]
        lines.append(f"{'b in a spin [mm]':<16}{'':>12}{spin:>12.3f}{'':>12}")
        for label, value in (
            ("alpha", cal.track_alpha),
            ("beta", cal.track_beta),
            ("p", cal.track_power),
        ):
            lines.append(f"{label:<16}{'':>12}{value:>12.5f}{'':>12}")
    lines += [
        "",
        f"validation on fresh squares ({len(report.errors_before['cw'])} cw + "
        f"{len(report.errors_before['ccw'])} ccw, true return errors):",
        f"{'':<22}{'before':>10}{'after':>10}",
        f"{'E_max,syst [mm]':<22}{1e3 * report.e_max_before:>10.2f}"
        f"{1e3 * report.e_max_after:>10.2f}   -> {report.improvement:.1f}-fold improvement",
    ]
    lines += [f"note: {note}" for note in report.result.notes]
    return "\n".join(lines)


def _skid_parameters(params: dict[str, float]) -> str:
    """A skid-steer calibration's terms for the session report's parameter line, from
    :meth:`odomgym.odometry.calibration.Calibration.parameters` [m] ("" for none)."""
    parts = []
    if "icr_x" in params:
        parts.append(
            f"y_L = {params['icr_y_left']:.6f} m, y_R = {params['icr_y_right']:.6f} m, "
            f"x_ICR = {params['icr_x']:.6f} m"
        )
    if "spin_wheelbase" in params:
        parts.append(f"b in a spin = {params['spin_wheelbase']:.6f} m")
    return "".join(f", {part}" for part in parts)


def format_session_report(report: Any) -> str:
    """Calibrated parameters and the OptiOdom evaluation measures before/after.

    ``report`` is an :class:`odomgym.baselines.validation.SessionReport`.
    """
    params = report.result.calibration.parameters(report.robot)
    before, after = report.before.as_published(), report.after.as_published()
    lines = [
        f"{report.method} on session {report.session}",
        f"b = {params['wheelbase']:.6f} m, D_R = {params['right_diameter']:.6f} m, "
        f"D_L = {params['left_diameter']:.6f} m" + _skid_parameters(params),
        "",
        f"{'measure':<22}{'before':>12}{'after':>12}",
        f"{'max position [mm]':<22}{1e3 * before['max_pos']:>12.2f}{1e3 * after['max_pos']:>12.2f}",
        f"{'max heading [deg]':<22}{before['max_th_deg']:>12.3f}{after['max_th_deg']:>12.3f}",
        f"{'final position [mm]':<22}{1e3 * before['final_pos']:>12.2f}"
        f"{1e3 * after['final_pos']:>12.2f}",
        f"{'final heading [deg]':<22}{before['final_th_deg']:>12.3f}{after['final_th_deg']:>12.3f}",
    ]
    lines += [f"note: {note}" for note in report.result.notes]
    return "\n".join(lines)

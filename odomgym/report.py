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
from odomgym.metrics import UMBmarkSummary

__all__ = ["format_return_errors", "plot_return_errors", "to_json"]

FloatArray = NDArray[np.float64]


def to_json(data: Any) -> str:
    """One line of JSON; numpy scalars and arrays become plain numbers and lists."""

    def default(value: Any) -> Any:
        if isinstance(value, np.ndarray):
            return value.tolist()
        if isinstance(value, np.generic):
            return value.item()
        raise TypeError(f"cannot serialise {type(value).__name__}")

    return json.dumps(data, default=default, allow_nan=True)


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
        lines.append(f"E_max,syst = {1e3 * summary.e_max_syst:.2f} mm (seed 000 Eq. 3.3)")
    return "\n".join(lines)


def plot_return_errors(
    path: Path,
    groups: Sequence[tuple[str, FloatArray, FloatArray]],
    title: str,
) -> None:
    """Scatter of return position errors like seed 000 Fig. 6.5.

    ``groups`` are ``(label, cw_errors (n, ≥2), ccw_errors (m, ≥2))`` — e.g. before and after
    calibration; each group's centres of gravity are marked and E_max,syst is in the legend.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from odomgym.metrics import centre_of_gravity, e_max_syst

    fig, ax = plt.subplots(figsize=(6.5, 6.0))
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
    ax.axhline(0.0, color="0.7", lw=0.8)
    ax.axvline(0.0, color="0.7", lw=0.8)
    ax.set_xlabel("return error x [mm]")
    ax.set_ylabel("return error y [mm]")
    ax.set_title(title)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()

    def write(tmp: Path) -> None:
        fig.savefig(tmp, dpi=120, format=path.suffix.lstrip(".") or "png")

    try:
        atomic_writer(path, write)
    finally:
        plt.close(fig)

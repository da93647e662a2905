"""The benchmark's rows summarised per method and floor (the tables of ``summary.md``)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from odomgym.baselines.benchmark.config import ORACLE

__all__ = [
    "summarize",
]


def summarize(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per method and floor: median and quartiles of the improvement, parameter errors,
    distance, wall time and failures; and, when the rows hold the ``oracle``, the fraction of
    the oracle's improvement (per robot: the oracle's E_max,syst after / the method's, the
    same robot's E_max,syst before cancelling; its median; NaN without an oracle)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    ceiling: dict[tuple[str, int], float] = {}
    for row in rows:
        groups.setdefault((row["method"], row["floor"]), []).append(row)
        if row["method"] == ORACLE and not row["failed"]:
            ceiling[(row["floor"], row["robot"])] = row["improvement"]
    summary: list[dict[str, Any]] = []
    for (method, floor), all_rows in groups.items():
        # Failed calibrations are counted, not scored: scoring them as "uncalibrated" would
        # pull the medians toward 1 and hide how often a method fails.
        group = [r for r in all_rows if not r["failed"]] or all_rows
        improvement = np.array([r["improvement"] for r in group])
        q25, q50, q75 = np.percentile(improvement, [25, 50, 75])

        def median_abs(key: str, group: list[dict[str, Any]] = group) -> float:
            return float(np.median([abs(r[key]) for r in group]))

        fractions = [
            r["improvement"] / ceiling[(floor, r["robot"])]
            for r in group
            if (floor, r["robot"]) in ceiling and not r["failed"]
        ]

        summary.append(
            {
                "method": method,
                "floor": floor,
                "robots": len(group),
                "improvement_median": float(q50),
                "improvement_q25": float(q25),
                "improvement_q75": float(q75),
                "of_oracle_median": float(np.median(fractions)) if fractions else math.nan,
                "e_max_before_median_mm": float(np.median([r["e_max_before_mm"] for r in group])),
                "e_max_after_median_mm": float(np.median([r["e_max_after_mm"] for r in group])),
                "abs_err_E_d_median": median_abs("err_E_d"),
                "abs_err_E_b_median": median_abs("err_E_b"),
                "abs_err_E_s_median": median_abs("err_E_s"),
                "distance_m_mean": float(np.mean([r["distance_m"] for r in group])),
                "runs_mean": float(np.mean([r["runs_used"] for r in group])),
                "wall_time_s_mean": float(np.mean([r["wall_time_s"] for r in group])),
                "failures": sum(1 for r in all_rows if r["failed"]),
            }
        )
    summary.sort(key=lambda s: (str(s["floor"]), -float(s["improvement_median"])))
    return summary

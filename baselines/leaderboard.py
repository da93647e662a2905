"""The real-data leaderboard: calibrate on one recorded session, evaluate on the others.

A calibration is only worth what it does on runs it has not seen. For every method and every
recorded session it can use, the method calibrates on that session; its parameters (b, D_R, D_L,
absolute, in metres) are then applied to every *other* session — squares, straight-and-spin
and circular paths alike, each with its own nominal robot — and judged by the OptiOdom
evaluation measures (:mod:`odomgym.odometry.optiodom_measures`). The leaderboard ranks methods
by the mean cross-session final and maximum position errors on the evaluation sessions all of
them were judged on. Beside it, the in-session results are compared with the authors' own
numbers in ``published_results.csv`` (Sousa et al. 2022, whose "optiodom" rows are compared
with our ``trajectory`` method).

``conventions="optiodom"`` runs the methods that have the authors' conventions (UMBmark and
Jung & Chung: their frames, their heading centre of gravity, no E_s phase) with them, so that
the in-session column reproduces the authors' results (Sousa et al. 2022, as shipped in
``published_results.csv``; tested to two units of their last printed digit on the shipped
sessions, Ivanjko et al.'s rows included, which need no flag); the other methods run as usual.
By default every method runs as its paper states it, which is what the cross-session ranking
should compare.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from odomgym.baselines.base import CALIBRATORS, Calibrator, default_methods, option_names
from odomgym.baselines.validation import calibrator_for_session, method_options
from odomgym.data import find_sessions, read_session
from odomgym.errors import SpecError
from odomgym.lab.recorded import RecordedLab
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.optiodom_measures import EvaluationMeasures, evaluate
from odomgym.robot import RobotSpec

__all__ = [
    "Leaderboard",
    "format_leaderboard",
    "published_results",
    "run_leaderboard",
    "takes_conventions",
]

PUBLISHED_NAMES = {
    "umbmark": "umbmark",
    "jung_chung": "jung_chung",
    "ivanjko": "ivanjko",
    "optiodom": "trajectory",
}


@dataclass
class Leaderboard:
    """Cross-session and in-session results.

    Attributes:
        cross: per (method, calibration session, evaluation session) the measures.
        in_session: per (method, session) the measures on the calibration session itself.
        parameters: per (method, session) the calibrated (b, D_R, D_L) [m].
        failures: per (method, session) why the method could not run there.
        published: per (method, session) the authors' in-session "after" measures.
        conventions: the conventions the methods that have them ran with (``None``: each
            method's own).
    """

    cross: dict[tuple[str, str, str], EvaluationMeasures] = field(default_factory=dict)
    in_session: dict[tuple[str, str], EvaluationMeasures] = field(default_factory=dict)
    parameters: dict[tuple[str, str], tuple[float, float, float]] = field(default_factory=dict)
    failures: dict[tuple[str, str], str] = field(default_factory=dict)
    published: dict[tuple[str, str], dict[str, float]] = field(default_factory=dict)
    conventions: str | None = None

    def evaluation_sessions(self) -> list[str]:
        """The sessions every ranked method was evaluated on (sorted): those the ranking judges
        each method on."""
        methods = {m for m, _, _ in self.cross}
        targets = [{t for (m, _, t) in self.cross if m == method} for method in methods]
        return sorted(set.intersection(*targets)) if targets else []

    def ranking(self) -> list[dict[str, Any]]:
        """Methods by mean cross-session final position error (then max position error), each
        judged on the same runs: per evaluation session of :meth:`evaluation_sessions`, the mean
        over the method's calibration sessions, then the mean over those evaluation sessions.

        Why not the mean over each method's own pairs: a method that cannot calibrate on some
        sessions (least squares needs squares) was then judged on fewer and other runs, and on
        the shipped sessions ranked first on 10 pairs against the others' 15."""
        common = self.evaluation_sessions()
        methods = sorted({m for m, _, _ in self.cross})
        table = []
        for method in methods:
            mine = {(s, t): v for (m, s, t), v in self.cross.items() if m == method}
            per_target = [[v for (_, t), v in mine.items() if t == target] for target in common]

            def mean(name: str, groups: list[list[EvaluationMeasures]] = per_target) -> float:
                return float(
                    np.mean([np.mean([getattr(v, name) for v in group]) for group in groups])
                )

            table.append(
                {
                    "method": method,
                    "calibrated_on": len({s for s, _ in mine}),
                    "pairs": sum(len(group) for group in per_target),  # the pairs averaged
                    "evaluated_on": len(common),
                    "final_pos_mm": 1e3 * mean("final_position"),
                    "max_pos_mm": 1e3 * mean("max_position"),
                    "final_th_deg": math.degrees(mean("final_heading")),
                    "max_th_deg": math.degrees(mean("max_heading")),
                }
            )
        table.sort(key=lambda row: (row["final_pos_mm"], row["max_pos_mm"]))
        return table

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "conventions": self.conventions,
            "ranking": self.ranking(),
            "in_session": {f"{m}/{s}": v.as_published() for (m, s), v in self.in_session.items()},
            "parameters": {
                f"{m}/{s}": dict(zip(("b", "dr", "dl"), p, strict=True))
                for (m, s), p in self.parameters.items()
            },
            "published": {f"{m}/{s}": v for (m, s), v in self.published.items()},
            "failures": {f"{m}/{s}": why for (m, s), why in self.failures.items()},
        }


def published_results(path: Path) -> dict[tuple[str, str], dict[str, float]]:
    """The authors' "after" measures per (our method name, session) from the CSV."""
    results: dict[tuple[str, str], dict[str, float]] = {}
    if not path.is_file():
        return results
    with path.open(newline="", encoding="utf-8") as handle:
        for row in csv.DictReader(handle):
            method = PUBLISHED_NAMES.get(row["method"])
            if method is None:
                continue
            results[(method, row["session"])] = {
                key: float(row[f"after_{key}"])
                for key in ("max_pos", "max_th_deg", "final_pos", "final_th_deg")
            }
    return results


def takes_conventions(cls: type[Calibrator]) -> bool:
    """Whether method ``cls`` can follow another author's conventions (a ``conventions``
    option)."""
    return "conventions" in option_names(cls.options_type)


def run_leaderboard(
    root: str | Path,
    methods: Sequence[str] | None = None,
    path_types: Sequence[str] = ("square", "ivanjko"),
    conventions: str | None = None,
) -> Leaderboard:
    """Calibrate every method on every session of ``path_types`` below ``root`` that holds
    the runs it needs; evaluate each result on *all* other sessions (every path type), and rank
    the methods on the evaluation sessions they all have (:meth:`Leaderboard.ranking`), so that
    methods calibrating on different experiments are judged on the same runs.

    ``conventions`` (e.g. ``"optiodom"``) applies to the methods that take a ``conventions``
    option (:func:`takes_conventions`); the others run with their own.
    """
    names = list(methods or default_methods())
    every = [read_session(p) for p in find_sessions(root)]
    sessions = [s for s in every if s.path_type in path_types]
    if not sessions:
        raise SpecError(f"no sessions of types {list(path_types)} below {root}", field="data")
    if conventions is not None:
        for cls in (CALIBRATORS[m] for m in names if takes_conventions(CALIBRATORS[m])):
            method_options(cls, {"conventions": conventions})  # SpecError if unknown to it
    board = Leaderboard(
        published=published_results(Path(root) / "published_results.csv"), conventions=conventions
    )
    for method in names:
        cls = CALIBRATORS[method]
        own = conventions if conventions is not None and takes_conventions(cls) else None
        for source in sessions:
            try:
                calibrator = calibrator_for_session(cls, source, own)
                result = calibrator.calibrate(RecordedLab(source), source.initial)
            except (LookupError, ValueError, ArithmeticError) as exc:
                board.failures[(method, source.name)] = str(exc)
                continue
            params = result.calibration.parameters(source.robot)
            absolute = (params["wheelbase"], params["right_diameter"], params["left_diameter"])
            board.parameters[(method, source.name)] = absolute
            board.in_session[(method, source.name)] = evaluate(
                source.runs, source.robot, result.calibration
            )
            for target in every:
                if target.name == source.name:
                    continue
                transferred = _transfer(result.calibration, source.robot, target.robot)
                board.cross[(method, source.name, target.name)] = evaluate(
                    target.runs, target.robot, transferred
                )
    return board


def _transfer(calibration: Calibration, source: RobotSpec, target: RobotSpec) -> Calibration:
    """``calibration`` (found on ``source``'s nominal robot) as the same absolute odometry on
    ``target``'s: the same b, D_R, D_L [m], the same ICR offsets [m], and a track curve whose
    α is rescaled like E_b (both are fractions of the nominal track); β and p are unitless."""
    params = calibration.parameters(source)
    absolute = (params["wheelbase"], params["right_diameter"], params["left_diameter"])
    return dataclasses.replace(
        Calibration.from_parameters(target, *absolute),
        icr_x=calibration.icr_x,
        icr_y=calibration.icr_y,
        track_alpha=calibration.track_alpha * source.wheelbase / target.wheelbase,
        track_beta=calibration.track_beta,
        track_power=calibration.track_power,
    )


def format_leaderboard(board: Leaderboard) -> str:
    """Markdown: the cross-session ranking, then in-session results against the published."""
    lines = [
        "## Cross-session leaderboard (calibrate on one session, evaluate on the others)",
        "",
        f"Every method is judged on the same {len(board.evaluation_sessions())} evaluation "
        "sessions (those all of them were evaluated on): per session, the mean over the "
        "method's calibration sessions; then the mean over the sessions.",
        "",
        "| rank | method | calibrated on | pairs | final pos [mm] | max pos [mm] | final θ [deg] "
        "| max θ [deg] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for rank, row in enumerate(board.ranking(), start=1):
        lines.append(
            f"| {rank} | {row['method']} | {row['calibrated_on']} | {row['pairs']} | "
            f"{row['final_pos_mm']:.2f} | {row['max_pos_mm']:.2f} | {row['final_th_deg']:.3f} | "
            f"{row['max_th_deg']:.3f} |"
        )
    followed = (
        f"methods with {board.conventions} conventions follow them"
        if board.conventions
        else "every method as its paper states it; --conventions optiodom reproduces the table"
    )
    lines += [
        "",
        f"## In-session results against the published ones (Sousa et al. 2022; {followed})",
        "",
        "| method | session | final pos ours / published [mm] | max pos ours / published [mm] |",
        "|---|---|---|---|",
    ]
    if not board.published:  # a user's own sessions: no published numbers to set beside
        lines[-4:] = [
            "## In-session results (no published_results.csv beside the sessions)",
            "",
            "| method | session | final pos [mm] | max pos [mm] |",
            "|---|---|---|---|",
        ]
        for (method, session), ours in sorted(board.in_session.items()):
            mine = ours.as_published()
            lines.append(
                f"| {method} | {session} | {1e3 * mine['final_pos']:.2f} | "
                f"{1e3 * mine['max_pos']:.2f} |"
            )
    for (method, session), ours in sorted(board.in_session.items()):
        theirs = board.published.get((method, session))
        if theirs is None:
            continue
        mine = ours.as_published()
        lines.append(
            f"| {method} | {session} | {1e3 * mine['final_pos']:.2f} / "
            f"{1e3 * theirs['final_pos']:.2f} | {1e3 * mine['max_pos']:.2f} / "
            f"{1e3 * theirs['max_pos']:.2f} |"
        )
    if board.failures:
        lines += ["", "Not run (the session lacks the experiments the method needs):", ""]
        by_method: dict[str, list[str]] = {}
        for (method, session), _why in sorted(board.failures.items()):
            by_method.setdefault(method, []).append(session)
        for method, sessions in by_method.items():
            first = board.failures[(method, sessions[0])]
            lines.append(f"* {method}: {', '.join(sessions)} — e.g. {first}")
    return "\n".join(lines)

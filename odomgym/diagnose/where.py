"""Where the model and the robot disagree: the disagreement split by run, manoeuvre and component,
tested for being more than noise.

Each run is replayed through the model; the disagreement (measured − predicted tracked pose) is
split into the components a roboticist reads: **along-track** and **cross-track** position (in the
predicted heading's frame) and **heading**. Two views, each with a test per group:

* **runs** — the final disagreement of each run, grouped by experiment label and by turning
  direction (the sign of the run's net rotation: cw vs ccw); one-sample t-tests of the group means
  against 0 and a Welch test of cw against ccw;
* **manoeuvres** (when the ground truth is dense) — how much heading disagreement accrues while
  the robot drives straight (per metre), turns in place (per radian), drives arcs (per radian),
  and at wheel reversals (per reversal), and how the arc/turn rates depend on speed.

All p-values are Holm-corrected over the whole table, so "significant" is a statement about the
table, not a single line.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym.data.gaps import measured_end
from odomgym.diagnose.openloop import _interval_rates
from odomgym.diagnose.replay import replay_run
from odomgym.diagnose.stats import holm, mean_t_test
from odomgym.odometry.runs import Run, rotate_into
from odomgym.robot import RobotSpec

__all__ = ["Finding", "RunResidual", "localise", "run_residuals"]

FloatArray = NDArray[np.float64]
COMPONENTS = ("along", "cross", "heading")


@dataclass(frozen=True)
class RunResidual:
    """One run's disagreement with the model at its measured samples.

    Attributes:
        label: the experiment label; turn: "cw", "ccw" or "none" from the predicted net turn.
        time: measured sample times (K,) [s]; residual: (K, 3) along, cross [m], heading [rad].
        final: the last measured sample's residual (3,) if it is the run's end pose
            (:func:`odomgym.data.gaps.measured_end`), else NaN.
        classes: per-sample manoeuvre class of the replay (n,): 0 stop, 1 straight,
            2 in-place turn, 3 arc; speed (n,) [m/s], omega (n,) [rad/s]; reversal (n,) bool.
    """

    label: str
    turn: str
    index: NDArray[np.intp]
    residual: FloatArray
    final: FloatArray
    classes: NDArray[np.int64]
    speed: FloatArray
    omega: FloatArray
    reversal: NDArray[np.bool_]
    ds: FloatArray
    dtheta: FloatArray


@dataclass(frozen=True)
class Finding:
    """One tested group: mean disagreement, its 95 % interval, the Holm-corrected p-value."""

    view: str
    group: str
    component: str
    unit: str
    n: int
    mean: float
    low: float
    high: float
    p: float
    significant: bool

    def as_dict(self) -> dict[str, object]:
        return dict(self.__dict__)


def run_residuals(runs: Sequence[Run], spec: RobotSpec) -> list[RunResidual]:
    """Replay every run through ``spec`` and express the disagreement along/cross/heading."""
    out = []
    for run in runs:
        rep = replay_run(run, spec)
        measured = np.isfinite(run.true_pose[:, :2]).all(axis=1)
        index = np.flatnonzero(measured)[1:]
        d = run.true_pose[index] - rep.tracked[index]
        heading = rep.pose[index, 2]
        dtheta = np.mod(d[:, 2] + math.pi, 2 * math.pi) - math.pi
        residual = np.column_stack([rotate_into(d[:, 0], d[:, 1], heading), dtheta])
        dt = np.maximum(np.diff(run.time), 1e-9)
        speed = rep.ds / dt
        omega = rep.dtheta / dt
        moving = np.abs(speed) > 0.01
        turning = np.abs(omega) > 0.05
        classes = np.where(moving & turning, 3, np.where(moving, 1, np.where(turning, 2, 0)))
        sign = np.sign(rep.travel)
        reversal = np.zeros(len(dt), dtype=bool)
        for w in range(2):
            last = 0.0
            for m in range(len(dt)):
                if sign[m, w] != 0:
                    if last != 0 and sign[m, w] != last:
                        reversal[m] = True
                    last = sign[m, w]
        net = float(rep.pose[-1, 2] - rep.pose[0, 2])
        turn = "none" if abs(net) < 0.5 else ("ccw" if net > 0 else "cw")
        # The final disagreement is the run's only where its end pose was measured (the wheels
        # did not turn after the last measured position): a tracker that lost the robot before
        # it stopped saw a shorter run than its experiment's others.
        final = (
            residual[-1] if len(residual) and measured_end(run) is not None else np.full(3, np.nan)
        )
        out.append(
            RunResidual(
                str(run.meta.get("experiment", run.kind)),
                turn,
                index,
                residual,
                final,
                classes,
                speed,
                omega,
                reversal,
                rep.ds,
                rep.dtheta,
            )
        )
    return out


def localise(residuals: Sequence[RunResidual], alpha: float = 0.05) -> list[Finding]:
    """The tests of the module docstring, Holm-corrected together."""
    rows: list[tuple[str, str, str, str, FloatArray]] = []
    units = {"along": "m", "cross": "m", "heading": "rad"}
    finals = np.array([r.final for r in residuals])
    labels = sorted({r.label for r in residuals})
    for label in labels:
        pick = np.array([r.label == label for r in residuals])
        for c, name in enumerate(COMPONENTS):
            rows.append(("runs", f"experiment {label}", name, units[name], finals[pick, c]))
    for turn in ("cw", "ccw"):
        pick = np.array([r.turn == turn for r in residuals])
        if pick.sum() >= 2:
            for c, name in enumerate(COMPONENTS):
                rows.append(("runs", f"turning {turn}", name, units[name], finals[pick, c]))
    dense = [r for r in residuals if len(r.index) >= 10]
    if dense:
        rates: dict[str, list[float]] = {
            "straight: heading per metre": [],
            "straight: cross-track per metre": [],
            "in-place turn: heading per radian": [],
            "arc: heading per radian": [],
            "reversal: heading per reversal": [],
        }
        for r in dense:
            gained = np.zeros(len(r.ds) + 1)
            gained[r.index] = r.residual[:, 2]
            cross = np.zeros(len(r.ds) + 1)
            cross[r.index] = r.residual[:, 1]
            # Heading disagreement gained between consecutive measured samples, attributed to
            # the manoeuvre that dominated in between — only where one manoeuvre (or stops)
            # filled the interval: across a gap in the ground truth the robot may have driven
            # straight and turned, and what each added cannot be told apart.
            classes = np.ascontiguousarray(r.classes, dtype=np.int64)
            if len(classes) and (classes.min() < 0 or classes.max() > 3):  # the kernel's counts
                raise RuntimeError(f"manoeuvre classes outside 0-3: {sorted(set(classes))}")
            kind = np.empty(max(len(r.index) - 1, 0), dtype=np.int64)
            heading, off_track, per_reversal = (np.empty(len(kind)) for _ in range(3))
            reversed_ = np.empty(len(kind), dtype=np.bool_)
            _interval_rates(
                np.ascontiguousarray(r.index, dtype=np.int64),
                gained,
                cross,
                classes,
                np.ascontiguousarray(r.ds, dtype=np.float64),
                np.ascontiguousarray(r.dtheta, dtype=np.float64),
                np.ascontiguousarray(r.reversal, dtype=np.bool_),
                kind,
                heading,
                off_track,
                per_reversal,
                reversed_,
            )
            rates["straight: heading per metre"] += heading[kind == 1].tolist()
            rates["straight: cross-track per metre"] += off_track[kind == 1].tolist()
            rates["in-place turn: heading per radian"] += heading[kind == 2].tolist()
            rates["arc: heading per radian"] += heading[kind == 3].tolist()
            rates["reversal: heading per reversal"] += per_reversal[reversed_].tolist()
        for group, values in rates.items():
            if len(values) >= 3:
                unit = "m/m" if "cross" in group else ("rad/m" if "metre" in group else "rad")
                if "per radian" in group:
                    unit = "rad/rad"
                component = "cross" if "cross" in group else "heading"
                rows.append(("manoeuvres", group, component, unit, np.array(values)))
    # A group without a single measured value (runs whose ground truth stopped before their
    # wheels did, a position-only tracker's headings) is no test: it is left out of the table
    # and of the Holm family.
    tested = [(row, mean_t_test(row[4])) for row in rows if np.isfinite(row[4]).any()]
    pvals = np.array([t[3] for _, t in tested])
    adjusted = holm(pvals)
    findings = []
    for ((view, group, component, unit, sample), (mean, low, high, _)), p in zip(
        tested, adjusted, strict=True
    ):
        findings.append(
            Finding(
                view,
                group,
                component,
                unit,
                int(np.isfinite(sample).sum()),
                mean,
                low,
                high,
                float(p),
                bool(p < alpha),
            )
        )
    return findings

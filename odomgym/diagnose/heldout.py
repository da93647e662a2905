"""The gap that counts: the open-loop prediction of held-out runs, in plain units, against the
model as given and against a calibration a user already trusts.

The held-out runs are whole sessions the fit never saw when the data have two or more sessions
(else per experiment family a contiguous block of runs in time:
:func:`odomgym.diagnose.workflow.split_runs`). Each model — the robot as given, the diagnosed
one, and the *baseline*, a 3-parameter calibration (E_d, E_b, E_s) of the same fit runs by a
calibrator of the user's choice (the command line uses the project's trajectory optimisation,
Sousa et al. 2022) — replays the held-out runs' logged wheel motions open loop
(:func:`odomgym.diagnose.openloop.evaluate_open_loop`); a held-out session's measurement
nuisances are fitted on its own runs *with each model fixed* (they belong to the recording, and
every model gets the same treatment). Position and heading RMS over every measured sample, runs
weighing equally, and, for sessions of squares both ways, Borenstein & Feng's E_max,syst (1994,
Eq. 3.3) of the predicted return positions; 95 % bootstrap intervals of the differences over the
held-out runs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from odomgym.diagnose.nuisances import correct_runs
from odomgym.diagnose.openloop import ModelErrors, rms_over_runs
from odomgym.diagnose.stats import bootstrap_ci
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = ["Baseline", "HeldOut", "compare_models", "pictured_runs"]

FloatArray = NDArray[np.float64]

AS_GIVEN, DIAGNOSED, BASELINE = "as given", "diagnosed", "baseline"


class Baseline(Protocol):
    """A calibration a user already trusts, run on the diagnosis's fit runs (nuisances removed):
    returns the robot with the calibrated true geometry. ``name`` says which, in the report.
    :class:`odomgym.baselines.trajectory.TrajectoryBaseline` is one."""

    @property
    def name(self) -> str:
        """Which calibration this is, in the report (read-only, so frozen dataclasses qualify)."""
        ...

    def __call__(self, runs: Sequence[Run], robot: RobotSpec) -> RobotSpec: ...


@dataclass
class HeldOut:
    """The held-out comparison (module docstring).

    Attributes:
        split: ``"sessions"`` (whole sessions held out) or ``"blocks"`` (runs in time blocks).
        models: each model's errors, keyed ``"as given"``, ``"diagnosed"``, ``"baseline"``.
        baseline_name: which calibration made the baseline (None: no baseline given).
        baseline_geometry: its E_d, E_b, E_s.
        intervals: 95 % bootstrap intervals over the held-out runs of the position and heading
            RMS differences, diagnosed − as given and diagnosed − baseline [mm], [°].
        truth: the measured paths of the runs whose predictions the models keep
            (:attr:`odomgym.diagnose.openloop.ModelErrors.paths`), for the picture: time since
            the run's start [s], x, y [m] (T, 3).
    """

    split: str
    models: dict[str, ModelErrors]
    baseline_name: str | None = None
    baseline_geometry: dict[str, float] = field(default_factory=dict)
    intervals: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    truth: dict[str, FloatArray] = field(default_factory=dict)

    def _combined(self, label: str) -> float:
        return float(np.sqrt(np.mean(self.models[label].combined)))

    @property
    def better_than_as_given(self) -> bool:
        """The diagnosed model predicts the held-out runs better than the model as given
        (lower RMS combined open-loop error)."""
        return self._combined(DIAGNOSED) < self._combined(AS_GIVEN)

    @property
    def as_good_as_baseline(self) -> bool | None:
        """The diagnosed model predicts the held-out runs at least as well as the baseline
        calibration (None without a baseline)."""
        if BASELINE not in self.models:
            return None
        return self._combined(DIAGNOSED) <= self._combined(BASELINE)

    def corrected(self, runs: Sequence[Run]) -> list[Run]:
        """The held-out ``runs`` with the nuisances the diagnosed model got on their sessions
        removed (what the filter's tests and the spread are scored on)."""
        return correct_runs(runs, self.models[DIAGNOSED].nuisances)

    def as_dict(self) -> dict[str, Any]:
        """The report's ``held_out_open_loop`` entry."""
        per_run = {
            label: {
                "position_mm": (1e3 * m.position).tolist(),
                "heading_deg": np.degrees(m.heading).tolist(),
            }
            for label, m in self.models.items()
        }
        any_model = next(iter(self.models.values()))
        return {
            "split": self.split,
            "runs": any_model.runs,
            "sessions": sorted(set(any_model.sessions)),
            "models": {label: m.summary() for label, m in self.models.items()},
            "per_run": per_run,
            "differences_ci": self.intervals,
            "better_than_as_given": self.better_than_as_given,
            "as_good_as_baseline": self.as_good_as_baseline,
            "baseline": self.baseline_name,
            "baseline_geometry": self.baseline_geometry,
            "held_out_nuisances": {
                label: [n.as_dict() for s, n in m.nuisances.items() if s in set(m.sessions)]
                for label, m in self.models.items()
            },
        }


def compare_models(
    split: str,
    models: dict[str, ModelErrors],
    rng: np.random.Generator,
    baseline_name: str | None = None,
    baseline_geometry: dict[str, float] | None = None,
    truth: dict[str, FloatArray] | None = None,
) -> HeldOut:
    """The comparison of ``models`` (:class:`HeldOut`), with bootstrap intervals of the
    diagnosed model's differences to the others over the held-out runs."""
    intervals: dict[str, dict[str, list[float]]] = {}
    diagnosed = models[DIAGNOSED]
    for other in (AS_GIVEN, BASELINE):
        if other not in models:
            continue
        ref = models[other]
        intervals[f"{DIAGNOSED} - {other}"] = {
            "position_mm": [
                1e3 * v
                for v in bootstrap_ci(
                    [diagnosed.position, ref.position],
                    lambda a, b: rms_over_runs(a) - rms_over_runs(b),
                    rng,
                )
            ],
            "heading_deg": [
                math.degrees(v)
                for v in bootstrap_ci(
                    [diagnosed.heading, ref.heading],
                    lambda a, b: rms_over_runs(a) - rms_over_runs(b),
                    rng,
                )
            ],
        }
    return HeldOut(split, models, baseline_name, baseline_geometry or {}, intervals, truth or {})


def pictured_runs(runs: Sequence[Run], most: int = 4) -> list[int]:
    """The held-out runs a picture shows: the first of each session (then of each experiment
    family), at most ``most``."""
    seen: set[str] = set()
    out = []
    for j, run in enumerate(runs):
        key = str(run.meta.get("session", "")) or str(run.meta.get("experiment", run.kind))
        if key not in seen:
            seen.add(key)
            out.append(j)
    return out[:most]

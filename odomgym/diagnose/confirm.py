"""What confirms a diagnosis on runs the fit never saw (``docs/diagnose.md``, steps 12–14),
each one call of :func:`odomgym.diagnose.workflow.diagnose`: the yardstick of each kind.

12. :func:`held_out` — the held-out runs predicted open loop by the model as given, the
    diagnosed model and a baseline calibration (:mod:`odomgym.diagnose.heldout`): the
    yardstick of systematic effects and terms;
13. :func:`spread` — each kept noise effect against the model without it, by the spread it
    predicts (:mod:`odomgym.diagnose.spread`): the yardstick of noise effects;
14. :func:`confounds` — the directions in which the kept robot parameters and the measurement
    nuisances make the same logs (:mod:`odomgym.diagnose.confounds`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from odomgym.diagnose.config import DiagnoseConfig
from odomgym.diagnose.confounds import Confound, derive_confounds
from odomgym.diagnose.fit import Dataset, Model
from odomgym.diagnose.heldout import (
    AS_GIVEN,
    BASELINE,
    DIAGNOSED,
    Baseline,
    HeldOut,
    compare_models,
)
from odomgym.diagnose.nuisances import SessionNuisance, with_clock
from odomgym.diagnose.openloop import ModelErrors, evaluate_open_loop, fit_open_loop
from odomgym.diagnose.spread import SpreadCheck, judge_spread, model_without
from odomgym.diagnose.steps import NoiseNamed, Recording, RunSplit, SystematicModel, run_id
from odomgym.robot import RobotSpec

__all__ = ["confounds", "final_nuisances", "held_out", "spread"]

Report = Callable[[str, float], None]


def final_nuisances(rec: Recording, found: SystematicModel) -> dict[str, SessionNuisance]:
    """The fit sessions' nuisances under the diagnosed model: the gate's frames, the clock of
    step 2."""
    return with_clock(found.gate.fit.nuisances, rec.clock)


def held_out(
    split: RunSplit,
    rec: Recording,
    robot: RobotSpec,
    found: SystematicModel,
    final: Model,
    as_given: ModelErrors,
    baseline: Baseline | None,
    cfg: DiagnoseConfig,
    report: Report,
) -> HeldOut:
    """Step 12: the held-out runs predicted open loop by the model as given, the diagnosed
    model and the baseline (:mod:`odomgym.diagnose.heldout`) — the yardstick of systematic
    effects and terms."""
    report("held-out test", 1.0)
    interval, length = rec.open_data.interval, rec.open_data.length
    models = {AS_GIVEN: as_given}
    models[DIAGNOSED] = evaluate_open_loop(
        DIAGNOSED,
        split.held,
        final.spec,
        final_nuisances(rec, found),
        rec.clock_options,
        interval,
        length,
        rec.pictured,
    )
    baseline_name, baseline_geometry = None, None
    if baseline is not None:
        report("baseline", 1.0)
        base_spec = baseline(rec.corrected, robot)
        base_fit = fit_open_loop(rec.open_data, base_spec, None, rec.options, rec.frames)
        models[BASELINE] = evaluate_open_loop(
            BASELINE,
            split.held,
            base_spec,
            with_clock(base_fit.nuisances, rec.clock),
            rec.clock_options,
            interval,
            length,
            rec.pictured,
        )
        baseline_name = baseline.name
        baseline_geometry = {"E_d": base_spec.e_d, "E_b": base_spec.e_b, "E_s": base_spec.e_s}
    truth = {
        run_id(split.held[j], j): np.column_stack(
            [split.held[j].time - split.held[j].time[0], split.held[j].true_pose[:, :2]]
        )
        for j in rec.pictured
    }
    return compare_models(
        split.kind,
        models,
        np.random.default_rng(cfg.seed + 2),
        baseline_name,
        baseline_geometry,
        truth,
    )


def spread(
    split: RunSplit,
    held: HeldOut,
    final: Model,
    noise: NoiseNamed,
    found: SystematicModel,
    cfg: DiagnoseConfig,
    report: Report,
) -> list[SpreadCheck]:
    """Step 13: each kept noise effect judged by the spread it predicts on the held-out runs
    (:func:`odomgym.diagnose.spread.judge_spread`) against the model without it, refitted on
    the fit runs."""
    if not noise.kept:
        return []
    report("held-out spread", 1.0)
    fit_data = Dataset.of(found.corrected, found.interval)
    runs = held.corrected(split.held)
    return [
        judge_spread(
            name,
            runs,
            final,
            model_without(fit_data, final, name, noise.kept),
            cfg.checkpoint_interval,
        )
        for name in noise.kept
    ]


def confounds(
    rec: Recording,
    robot: RobotSpec,
    found: SystematicModel,
    noise: NoiseNamed,
    final: Model,
    report: Report,
) -> list[Confound]:
    """Step 14: the directions in which the kept robot parameters and the measurement
    nuisances (those fitted, those that are not, and errors of the ground-truth system itself)
    make the same logs on the fit runs, derived from their joint Jacobian
    (:func:`odomgym.diagnose.confounds.derive_confounds`), with whether the fitted values
    moved along one beyond their errors."""
    if not (found.gate.effects or found.gate.terms):
        return []
    report("confounds", 1.0)
    return derive_confounds(
        rec.open_data, found.gate.fit, noise.with_means(robot), sensor=final.sensor
    )

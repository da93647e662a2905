"""What a diagnosis keeps: the steps after the rounds that decide the model (``docs/diagnose.md``,
steps 6–11), each one call of :func:`odomgym.diagnose.workflow.diagnose`.

6. :func:`noise_effects` — the noise effects the rounds named, kept only with their signature
   and a plausible size;
7. :func:`term_sizes` — every discovered term at the data's operating range (stand-ins out);
8.–10. :func:`systematic` — the open-loop gate over the rounds' proposals, the estimator of the
   kept values, and the real-size rule for kept terms, again without a refused term;
11. :func:`noise_refit` — the kept noise effects refitted on the final systematic model.

What passes between them is in :mod:`odomgym.diagnose.steps`; what confirms the result on
held-out runs, in :mod:`odomgym.diagnose.confirm`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from odomgym.diagnose.config import DiagnoseConfig
from odomgym.diagnose.fit import Dataset, Model, fit_noise, fit_noise_model, noise_stderr
from odomgym.diagnose.gate import (
    FilterLinearisation,
    GateResult,
    SystematicFit,
    filter_estimate,
    model_effect,
    open_loop_estimate,
    open_loop_gate,
    spec_with,
)
from odomgym.diagnose.nuisances import correct_runs
from odomgym.diagnose.openloop import OpenLoopData, OpenLoopFit, fit_open_loop, open_loop_folds
from odomgym.diagnose.physical import TermSize, check_bumps, term_size
from odomgym.diagnose.rounds import DISCOVERED, NUISANCE, DiagnosisState
from odomgym.diagnose.steps import Backward, NoiseNamed, Recording, SystematicModel, TermRefusal
from odomgym.diagnose.verdict import (
    _discovered_order,
    _significant_effects,
    _tied_effects,
    real_size,
)
from odomgym.effects import EFFECTS, Effect
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = ["noise_effects", "noise_refit", "systematic", "term_sizes"]

Report = Callable[[str, float], None]


def noise_effects(rec: Recording, state: DiagnosisState, cfg: DiagnoseConfig) -> NoiseNamed:
    """Step 6: the noise effects the rounds named, kept only with their signature in the data
    and a size the floor can produce (floor bumps: :func:`odomgym.diagnose.physical.
    check_bumps`, on the rounds' systematic model without the bumps' mean loss)."""
    kept: list[str] = []
    checks: dict[str, dict[str, Any]] = {}
    for name in (n for n in state.named if EFFECTS[n].noise):
        effect = EFFECTS[name]
        values = effect.read(state.model.spec)
        if effect.wheel_jumps(values, np.ones((1, 2)), rec.open_data.length) is not None:
            check = check_bumps(
                rec.corrected,
                effect.write(state.model.spec, effect.absent_values()),
                values,
                max_obstacle=cfg.max_obstacle,
                max_rate=cfg.max_bump_rate,
                interval=rec.open_data.interval,
                alpha=0.5 * cfg.alpha,
            )
            checks[name] = check.as_dict()
            if not check.accepted:
                continue
        kept.append(name)
    return NoiseNamed(
        kept=kept,
        refused=[n for n in state.named if EFFECTS[n].noise and n not in kept],
        checks=checks,
        values={n: EFFECTS[n].read(state.model.spec) for n in kept},
        partners_named=tuple(n for n in state.named if not EFFECTS[n].noise),
    )


def term_sizes(rec: Recording, state: DiagnosisState) -> list[TermSize]:
    """Step 7: every discovered term of the rounds judged at the data's operating range: one
    too large for what the robot did is a stand-in (for a clock, a frame or a mechanism the
    grammar lacks), reported, not proposed."""
    present = state.model.spec.effect_values(DISCOVERED) or {}
    return [
        term_size(rec.corrected, state.model.spec, t, present[t]) for t in _discovered_order(state)
    ]


def systematic(
    rec: Recording,
    robot: RobotSpec,
    state: DiagnosisState,
    backward: Backward,
    noise: NoiseNamed,
    sizes: Sequence[TermSize],
    cfg: DiagnoseConfig,
    report: Report,
) -> SystematicModel:
    """Steps 8–10: the open-loop gate, the estimator, and the real-size rule for terms —
    again without a term the rule refused, until every kept term passes.

    The gate's robot *as given* carries the kept noise effects' mean parts (floor bumps'
    shortened travel): a noise effect's mean belongs to it, and a systematic partner (the
    distance scale) must earn its place on top of it, not for it."""
    base_robot = noise.with_means(robot)
    nominal = (
        rec.nominal
        if base_robot is robot
        else fit_open_loop(rec.open_data, base_robot, None, rec.options, rec.frames)
    )
    terms = [size.term for size in sizes if size.plausible]
    refused: list[TermRefusal] = []
    while True:  # every pass refuses a term or ends: at most one pass more than terms
        gate, tied, resolved = _gate(
            rec, base_robot, nominal, state, backward, noise, terms, cfg, report
        )
        chosen, estimators, corrected = _estimate(rec, state, gate, report)
        failing = real_size(chosen, gate.terms, state.passes)
        if not failing:
            break
        refused.extend(failing)
        out = {t for f in failing for t in f.term.split("+")}
        terms = [t for t in terms if t not in out]
    return SystematicModel(
        gate, chosen, estimators, corrected, tied, resolved, refused, rec.open_data.interval
    )


def _gate(
    rec: Recording,
    robot: RobotSpec,
    nominal: OpenLoopFit,
    state: DiagnosisState,
    backward: Backward,
    noise: NoiseNamed,
    terms: Sequence[str],
    cfg: DiagnoseConfig,
    report: Report,
) -> tuple[GateResult, list[str], bool]:
    """Step 8: the open-loop gate on the proposals of the rounds (:func:`odomgym.diagnose.
    verdict._significant_effects`) and the plausible ``terms``: each must lower the error of
    predicting the held-out folds (whole sessions, or blocks of time) open loop.

    Effects the likelihood could not tell apart (a last round ended ``ambiguous``) are
    proposed too, each under the one-standard-error rule: if the open-loop prediction of
    left-out folds needs every one of them beside the others, the tie is resolved (on June
    OptiOdom sessions a turn skid tied with the distance scale, and the folds needed both); if
    it keeps only some, it could not tell them apart either — the gate is run again without
    them, and the verdict stays ambiguous with its separating experiment. Returns the gate, the
    tied effects and whether the tie was resolved."""
    tied = _tied_effects(state)
    # The filter's estimates, linearised at the rounds' model without the mean part of a noise
    # effect step 6 refused (a kept one is in ``robot``, the start of every open-loop fit).
    base = state.model.spec
    for name in noise.refused:
        base = EFFECTS[name].write(base, EFFECTS[name].absent_values())

    def gated(proposed_effects: list[str]) -> GateResult:
        linearised = FilterLinearisation(
            rec.data, Model(base, state.model.sensor), proposed_effects, terms
        )
        return open_loop_gate(
            rec.open_data,
            robot,
            state.model.spec,
            proposed_effects,
            terms,
            rec.options,
            open_loop_folds(rec.timed),
            start=rec.frames,
            nominal=nominal,
            report=report,
            filtered=linearised,
            corrected=OpenLoopData(rec.corrected, rec.open_data.interval, rec.open_data.length),
            named=[n for n in state.named if not EFFECTS[n].noise],
            order=cfg.gate_order,
            jobs=cfg.jobs,
        )

    out = {*noise.took_over, *backward.unsupported}
    pool = [n for n in _significant_effects(state, tied=True) if n not in out]
    pool += _partners_missing([n for n in pool if n in state.named], pool)
    gate = gated(pool)
    resolved = bool(tied) and set(tied) <= set(gate.effects)
    if tied and not resolved:
        # Without the tied effects still in doubt. An effect a round had already named stays:
        # its refit tying with a newcomer puts the newcomer in doubt, not it (the World's
        # scout2: the skid track named in round 1, its refit tied with the turn skid in
        # round 2, and without this rule neither reached the gate).
        doubtful = set(tied) - set(state.named)
        gate = gated([n for n in pool if n not in doubtful])
    return gate, tied, resolved


def _partners_missing(named: Sequence[str], pool: Sequence[str]) -> list[str]:
    """The systematic partners of the ``named`` effects that the gate's ``pool`` lacks
    (``wheelbase`` beside a named ``skid_track``), proposed to the gate under the
    one-standard-error rule as any effect the rounds did not name. The rounds fitted each
    partner with its effect (the skid track's fit frees E_b), so a forward check of the partner
    added to the rounds' model finds nothing left for it, and without this the gate fitted the
    skid track on the model as given's E_b: the asymptote of straight paths stayed at 1 where
    the physics has 1.25–1.32, and the held-out error at 56 mm where the pair gives 4 mm (the
    independent elastic robot, seed 0)."""
    missing = [
        partner
        for name in named
        for partner in EFFECTS[name].partners
        if not EFFECTS[partner].noise and partner not in pool
    ]
    return list(dict.fromkeys(missing))


def _estimate(
    rec: Recording, state: DiagnosisState, gate: GateResult, report: Report
) -> tuple[SystematicFit, dict[str, float], list[Run]]:
    """Step 9: the estimator of the kept model's values: the filter's (efficient when its noise
    model is right), unless the open-loop fit's (what the held-out comparison measures, robust
    to a wrong noise model) predicts the left-out folds better by one standard error. Between
    two estimators that predict equally well the efficient one wins: an open-loop estimate
    chosen on fold noise leaves the filter a residual it can see (E_d 3e-5 off on a simulated
    robot). Returns the chosen fit, each estimator's fold error [m²] and the fit runs with the
    kept model's nuisances removed."""
    chosen = open_loop_estimate(gate.fit, gate.cv_error)
    corrected = correct_runs(rec.timed, gate.fit.nuisances)
    estimators: dict[str, float] = {"open loop": chosen.fold_error(gate.folds)}
    effect = model_effect(gate.effects, gate.terms)
    if effect is not None:
        report("estimator", 1.0)
        kf_data = Dataset.of(corrected, rec.open_data.interval)
        nuisance = EFFECTS.get(NUISANCE)
        start = spec_with(gate.fit.spec, state.model.spec, gate.effects, gate.terms)
        start_model = fit_noise_model(kf_data, Model(start, state.model.sensor), nuisance)
        filtered = filter_estimate(
            kf_data,
            start_model,
            effect,
            nuisance,
            OpenLoopData(corrected, rec.open_data.interval, rec.open_data.length),
            gate.folds,
            start,
        )
        estimators["filter"] = filtered.fold_error(gate.folds)
        if not chosen.better_than(filtered, gate.folds):
            chosen = filtered
    return chosen, estimators, corrected


def noise_refit(
    found: SystematicModel, state: DiagnosisState, noise: NoiseNamed
) -> tuple[Model, NoiseNamed]:
    """Step 11: the final model — the chosen systematic values and the kept noise effects,
    whose parameters and the sensor noise are refitted by maximum likelihood on the fit runs
    under it (the rounds fitted them beside a systematic model the gate may since have
    changed), with their standard errors there. A noise effect the refit takes to the floor of
    its range (the fit's "absent": a tenth of its parameters' scale) was carried by the rest of
    the model and leaves it. The held-out figures (step 12) are this model's: a refit of floor
    bumps moves their mean part a little from the one the gate's fits carried, and what is
    saved is what is judged."""
    spec = found.chosen.spec
    for name in noise.kept:
        spec = EFFECTS[name].write(spec, noise.values[name])
    data = Dataset.of(found.corrected, found.interval)
    kept = list(noise.kept)
    sensor = state.model.sensor
    while True:
        effects = [EFFECTS[n] for n in kept]
        refit, sensor, _ = fit_noise(data, spec, sensor, *effects, warm=bool(effects))
        vanished = [n for n in kept if _at_floor(EFFECTS[n], EFFECTS[n].read(refit))]
        if not vanished:
            break
        for name in vanished:
            spec = EFFECTS[name].write(spec, EFFECTS[name].absent_values())
            kept.remove(name)
    errors = noise_stderr(data, refit, sensor, [EFFECTS[n] for n in kept])
    return Model(refit, sensor), dataclasses.replace(
        noise, kept=kept, vanished=[n for n in noise.kept if n not in kept], errors=errors
    )


def _at_floor(effect: Effect, values: Mapping[str, float]) -> bool:
    """Whether a noise effect's fitted ``values`` make it absent once every parameter at the
    noise fit's floor (a tenth of its scale, :func:`odomgym.diagnose.fit.fit_noise`) is read as
    absent."""
    floor = {p.name: (0.1 * p.scale * (1.0 + 1e-6), p.absent) for p in effect.parameters}
    read = {k: (floor[k][1] if v <= floor[k][0] else v) for k, v in values.items()}
    return effect.is_absent(read)

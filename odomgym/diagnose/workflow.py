"""The discrepancy workflow: where the model and the robot disagree, which effect is missing,
add it, and show on data the fit never saw that the updated model predicts the robot better.

:func:`diagnose` takes logged runs (any source: :mod:`odomgym.data`) and a robot model and returns
a :class:`~odomgym.diagnose.results.Diagnosis`. This module holds the orchestration — the order
of the steps and what passes between them — and the split; each step's work lives where the list
below points. The steps, numbered as in ``docs/diagnose.md`` (which gives each in full):

1. **Split** (:func:`split_runs`): whole sessions are held out, or with one session, per
   experiment family a contiguous block of runs in time. Nothing is fitted on them.
2. **Measurement nuisances** (:mod:`odomgym.diagnose.nuisances`): each session's time offset
   (and, with several sessions, tracked point and yaw misalignment), fitted open loop jointly
   with E_d, E_b, E_s (:func:`odomgym.diagnose.openloop.fit_open_loop`) and removed from the
   runs.
3. **Where** (:mod:`odomgym.diagnose.where`) the model as given disagrees.
4. **Which — systematic effects first** (:func:`odomgym.diagnose.rounds.run_round`): catalogue
   effects, each beside the wheel noise as nuisance, scored by the Kalman filter's
   cross-validated likelihood and tested family-wise (:mod:`odomgym.diagnose.fit`); tied winners
   end the round ``ambiguous`` with a separating experiment
   (:mod:`odomgym.diagnose.experiments`).
5. **Is the systematic structure exhausted?** The grammar's score test
   (:func:`odomgym.diagnose.discover.structure_test`, in the round).
6. **Discovery** (:func:`odomgym.diagnose.discover.discover`), when it finds structure: sparse
   regression over the error grammar.
7. **The noise model, last** (the round's noise stages): only when no structure is left.
8. **Backward check** (:func:`odomgym.diagnose.rounds._backward_check`): a named systematic
   effect the final model no longer needs is removed (``absorbed``).
9. **Verdict, on held-out runs** (:func:`odomgym.diagnose.verdict._final_test`): the grammar's
   score test and a whiteness test on the held-out runs decide ``explained`` / ``partly
   explained`` (or ``ambiguous``, ``unexplained``, ``none``).
10. **Physical sizes** (:func:`odomgym.diagnose.physical.term_size`): a discovered term too
    large for what the robot did is a stand-in, reported and not kept.
11. **The open-loop gate** (:func:`odomgym.diagnose.gate.open_loop_gate`, its pool
    :func:`odomgym.diagnose.verdict._significant_effects`): each proposal in turn is kept only
    if it lowers the error of predicting left-out folds (sessions, or blocks) open loop, and a
    discovered term only if the open-loop fit can identify it; effects tied in a last
    ``ambiguous`` round are resolved here when the folds need every one of them.
12. **The estimator** of the kept model's values (:mod:`odomgym.diagnose.gate`) — the filter's,
    unless the open-loop fit's predicts the left-out folds better by one standard error.
13. **Noise effects, checked** (:func:`odomgym.diagnose.physical.check_bumps`,
    :func:`odomgym.diagnose.verdict._geometry_moves`): floor bumps only with their signature
    and a size the floor can produce; how far a noise effect with a mean part moved E_d, E_b,
    E_s is reported.
14. **Held-out verdict** (:mod:`odomgym.diagnose.heldout`): the held-out runs predicted open loop
    by the model as given, the diagnosed model and a baseline calibration, in mm and degrees —
    the headline; a model that does not predict the held-out runs better than the model as
    given, or proposals of which the open-loop gate kept none, are ``unconfirmed``.
15. **The whitened gap, a diagnostic** (:func:`odomgym.diagnose.verdict._shrink`).

The settings are :class:`~odomgym.diagnose.config.DiagnoseConfig`; finished candidate fits are
kept in a :class:`~odomgym.diagnose.journal.FitJournal` for ``--resume``. Every public name of
those modules, of :mod:`odomgym.diagnose.results` and of :mod:`odomgym.diagnose.rounds` also
imports from here, where it was defined before the workflow was split.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from odomgym import interrupt
from odomgym.diagnose.config import DiagnoseConfig
from odomgym.diagnose.fit import (
    Dataset,
    Model,
    candidate_effects,
    fit_noise_model,
    folds_for,
    strata,
)
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
from odomgym.diagnose.heldout import (
    AS_GIVEN,
    BASELINE,
    DIAGNOSED,
    Baseline,
    compare_models,
    pictured_runs,
)
from odomgym.diagnose.journal import FitJournal
from odomgym.diagnose.likelihood import SensorNoise
from odomgym.diagnose.nuisances import (
    SESSION_EFFECTS,
    SessionNuisance,
    correct_runs,
    offset_is_significant,
    sessions_of,
)
from odomgym.diagnose.openloop import (
    NuisanceOptions,
    OpenLoopData,
    cross_validate_open_loop,
    evaluate_open_loop,
    fit_open_loop,
    open_loop_folds,
)
from odomgym.diagnose.physical import check_bumps, term_size

# Candidate, Round and GAP_METRIC are re-exported (``as``): they were importable from here
# before the split without being in ``__all__``, and stay so.
from odomgym.diagnose.results import GAP_METRIC as GAP_METRIC
from odomgym.diagnose.results import Candidate as Candidate
from odomgym.diagnose.results import Diagnosis
from odomgym.diagnose.results import Round as Round
from odomgym.diagnose.rounds import (
    DISCOVERED,
    NUISANCE,
    ROUND_GOES_ON,
    DiagnosisState,
    RoundContext,
    _backward_check,
    _discovery_record,
    run_round,
)
from odomgym.diagnose.screen import usable_runs
from odomgym.diagnose.verdict import (
    _discovered_order,
    _final_test,
    _geometry_moves,
    _kept_terms,
    _parameters,
    _shrink,
    _significant_effects,
    _terms_tried,
    _tied_effects,
)
from odomgym.diagnose.where import localise, run_residuals
from odomgym.effects import EFFECTS, Effect
from odomgym.errors import SpecError
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "DISCOVERED",
    "NUISANCE",
    "ROUND_GOES_ON",
    "DiagnoseConfig",
    "Diagnosis",
    "DiagnosisState",
    "FitJournal",
    "RoundContext",
    "diagnose",
    "run_round",
    "split_runs",
]


GEOMETRY = ("wheel_diameter_ratio", "wheelbase", "distance_scale")
"""The catalogue's geometric effects (E_d, E_b, E_s): fitted beside the measurement nuisances,
the baseline's parameters."""


def _run_id(run: Run, index: int) -> str:
    return str(run.meta.get("run", index + 1))


def _session_family(runs: Sequence[Run], members: Sequence[int]) -> str:
    """A session's kind of experiment: ``meta["path_type"]`` (OptiOdom), else the experiment
    families of its runs (:func:`odomgym.diagnose.fit.strata`)."""
    given = runs[members[0]].meta.get("path_type")
    if given:
        return str(given)
    return "+".join(strata([runs[j] for j in members]))


def _time_order(runs: Sequence[Run], members: Sequence[int]) -> list[int]:
    return sorted(members, key=lambda j: (float(runs[j].meta.get("session_time", 0.0)), j))  # type: ignore[arg-type]


def split_runs(
    runs: Sequence[Run], holdout: float, rng: np.random.Generator
) -> tuple[list[int], list[int], str]:
    """(fit, held-out) run indices and how they were split.

    With two or more sessions (``meta["session"]``) whole sessions are held out (``"sessions"``):
    per kind of session (:func:`_session_family`) a ``holdout`` share, rounded, at least one
    session of each kind kept for fitting; at least one session held out overall. With one
    session (``"blocks"``): per experiment family (:func:`odomgym.diagnose.fit.strata`) a
    contiguous block of a ``holdout`` share of its runs in time order (``meta
    ["session_time"]``, then the runs' order), at a random place, at least one run of each
    family kept; at least one run held out overall. A model is judged on what it did not see:
    another recording, or a later or earlier stretch of the same one — never on runs
    interleaved with the fit's (a drift over the session would pass unnoticed)."""
    labels = sessions_of(runs)
    order = list(dict.fromkeys(labels))
    held: list[int] = []
    if len(order) >= 2:
        members = {s: [j for j, lab in enumerate(labels) if lab == s] for s in order}
        families: dict[str, list[str]] = {}
        for s in order:
            families.setdefault(_session_family(runs, members[s]), []).append(s)
        chosen: list[str] = []
        for family in sorted(families):
            group = families[family]
            count = min(round(holdout * len(group)), len(group) - 1)
            chosen.extend(group[int(k)] for k in rng.permutation(len(group))[:count])
        if not chosen:
            chosen = [order[int(rng.integers(len(order)))]]
        held = [j for j, lab in enumerate(labels) if lab in set(chosen)]
        split = "sessions"
    else:
        for family_runs in strata(runs).values():
            ordered = _time_order(runs, family_runs)
            count = min(round(holdout * len(ordered)), len(ordered) - 1)
            if count > 0:
                begin = int(rng.integers(len(ordered) - count + 1))
                held.extend(ordered[begin : begin + count])
        if not held:
            held = [int(rng.integers(len(runs)))]
        split = "blocks"
    fit = [j for j in range(len(runs)) if j not in set(held)]
    return fit, sorted(held), split


def _significant_offset(nuisance: SessionNuisance) -> SessionNuisance:
    """``nuisance``'s time offset alone (the frame is refitted at that offset), zero — with its
    standard error kept — where :func:`~odomgym.diagnose.nuisances.offset_is_significant` says
    the data show none."""
    keep = offset_is_significant(nuisance)
    return SessionNuisance(
        nuisance.session,
        nuisance.runs,
        time_offset=nuisance.time_offset if keep else 0.0,
        time_offset_se=nuisance.time_offset_se,
    )


def _with_clock(
    nuisances: Mapping[str, SessionNuisance], clock: Mapping[str, SessionNuisance]
) -> dict[str, SessionNuisance]:
    """``nuisances`` (frames, fitted on runs whose clocks were already corrected) with each
    session's time offset from ``clock`` put back."""
    out = {}
    for session, n in nuisances.items():
        c = clock.get(session)
        out[session] = (
            dataclasses.replace(n, time_offset=c.time_offset, time_offset_se=c.time_offset_se)
            if c is not None
            else n
        )
    return out


def diagnose(
    runs: Sequence[Run],
    robot: RobotSpec,
    config: DiagnoseConfig | None = None,
    *,
    baseline: Baseline | None = None,
    progress: Callable[[str, float], None] | None = None,
    journal: FitJournal | None = None,
) -> Diagnosis:
    """Run the workflow of the module docstring on ``runs`` with the model ``robot``.

    ``baseline``: a calibration a user already trusts (:class:`odomgym.diagnose.heldout.
    Baseline`), run on the same fit runs and compared on the held-out ones; ``journal``: store
    every finished candidate fit there, and take the fits it already holds
    (:class:`FitJournal`: an interrupted diagnosis resumed gives the same result).

    The BLAS libraries numpy and scipy load run on one thread here (threadpoolctl, for the
    whole diagnosis and the worker processes it forks). Why: the workflow's linear algebra is
    small (3×3 covariances, least-squares systems of a few parameters), and OpenBLAS's idle
    threads wait for the next call by spinning, which took about a third of the CPU time of a
    diagnosis on 2 cores from the filter and the replays (``perf``: ``blas_thread_server``).
    One thread also makes the results independent of the machine's core count: a threaded dot
    product of long vectors sums its parts in an order that depends on the thread count. The
    limit is the process's while the diagnosis runs (other threads of the caller's get it too)
    and the caller's setting is back afterwards; threadpoolctl changes it only from the thread
    that controls OpenBLAS, so call :func:`diagnose` from the main thread for these bytes."""
    cfg = config if config is not None else DiagnoseConfig()
    with threadpool_limits(limits=1, user_api="blas"):
        return _diagnose(runs, robot, cfg, baseline, progress, journal)


def _diagnose(
    runs: Sequence[Run],
    robot: RobotSpec,
    cfg: DiagnoseConfig,
    baseline: Baseline | None,
    progress: Callable[[str, float], None] | None,
    journal: FitJournal | None,
) -> Diagnosis:
    """:func:`diagnose` itself, its BLAS on one thread."""

    def report(stage: str, fraction: float) -> None:
        interrupt.check()  # a stop request a finalizer swallowed (odomgym.interrupt)
        if progress is not None:
            progress(stage, fraction)

    # Each run from its first full pose; runs with too little ground truth set aside.
    runs, skipped = usable_runs(runs, robot)
    rng = np.random.default_rng(cfg.seed)
    fit_index, held_index, split = split_runs(runs, cfg.holdout, rng)
    fit_runs = [runs[j] for j in fit_index]
    held_runs = [runs[j] for j in held_index]
    if len(fit_runs) < 2:
        raise SpecError("too few runs left to fit after the hold-out split", field="holdout")
    use_frames = cfg.session_frames
    if use_frames is None:
        use_frames = len(set(sessions_of(runs))) >= 2
    clock_options = NuisanceOptions(
        time_offset=cfg.time_offset, frames=use_frames, max_time_offset=cfg.max_time_offset
    )
    interval, length = cfg.checkpoint_interval, float(robot.wheelbase)
    # Step 2 (module docstring): the recording's nuisances, fitted jointly with the geometry (E_d,
    # E_b, E_s) so that a curving straight is not read as a tilted frame, nor a scale as a clock. A
    # time offset is removed only where the data show one (module docstring of
    # odomgym.diagnose.nuisances): resampling the counts at a spurious offset adds the acceleration-
    # correlated disagreement the filter is most sensitive to.
    report("measurement nuisances", 0.0)
    geometry = model_effect(GEOMETRY, [])
    clock = {
        s: _significant_offset(n)
        for s, n in fit_open_loop(
            OpenLoopData(fit_runs, interval, length), robot, geometry, clock_options
        ).nuisances.items()
    }
    timed = correct_runs(fit_runs, clock)
    options = NuisanceOptions(time_offset=False, frames=use_frames)
    open_data = OpenLoopData(timed, interval, length)
    nuisances = (
        fit_open_loop(open_data, robot, geometry, options).nuisances
        if use_frames
        else {s: SessionNuisance(s, n.runs) for s, n in clock.items()}
    )
    fit_corrected = correct_runs(timed, nuisances)
    data = Dataset.of(fit_corrected, interval)
    names = cfg.candidates or tuple(EFFECTS)
    if use_frames:
        names = tuple(n for n in names if n not in SESSION_EFFECTS)
    model = fit_noise_model(data, Model(robot, SensorNoise(*cfg.initial_sensor)))
    # The model as given, open loop: its own nuisances; the held-out sessions' on their own.
    nominal = fit_open_loop(open_data, robot, None, options, nuisances)
    pictured = pictured_runs(held_runs)
    as_given = evaluate_open_loop(
        AS_GIVEN,
        held_runs,
        robot,
        _with_clock(nominal.nuisances, clock),
        clock_options,
        interval,
        length,
        pictured,
    )
    report("where", 0.0)
    shown = [*fit_corrected, *correct_runs(held_runs, as_given.nuisances)]
    findings = localise(run_residuals(shown, robot), cfg.alpha)
    nuisance = EFFECTS.get(NUISANCE)
    excluded = (NUISANCE, DISCOVERED)
    systematic = [e.name for e in candidate_effects(excluded) if not e.noise and e.name in names]
    noise = [e.name for e in candidate_effects(excluded) if e.noise and e.name in names]
    # Systematic effects first, then (once their structure is exhausted) discovery, then the
    # noise model: a noise effect may stand for nothing a systematic term explains.
    ctx = RoundContext(
        data=data,
        folds=folds_for(fit_corrected, min(cfg.folds, len(fit_corrected)), rng),
        nuisance=nuisance,
        stages=[
            ("mean", systematic, nuisance),
            ("noise", noise, nuisance),
            ("noise", [NUISANCE] if NUISANCE in names else [], None),
        ],
        config=cfg,
        rng=rng,
        report=report,
        journal=journal,
    )
    state = DiagnosisState(model=model, before_discovery=model.spec)
    for number in range(1, cfg.max_rounds + 1):
        if run_round(number, ctx, state).verdict not in ROUND_GOES_ON:
            break
    # Backward check: a systematic effect named early may have stood in for what a later one
    # (or a discovered term) explains better; each must still be significant in the final model.
    absorbed = _backward_check(data, state.model, state.named, cfg.alpha)
    for name in absorbed:
        spec = EFFECTS[name].write(state.model.spec, EFFECTS[name].absent_values())
        state.model = Model(spec, state.model.sensor)
        state.named.remove(name)
        state.parameters.pop(name, None)
    # Step 10: physical sizes: a discovered term implausible at the data's operating range is a
    # stand-in (for a clock, a frame or a mechanism the grammar lacks), reported, not kept.
    proposed_terms = _discovered_order(state)
    present = state.model.spec.effect_values(DISCOVERED) or {}
    sizes = [term_size(fit_corrected, state.model.spec, t, present[t]) for t in proposed_terms]
    plausible_terms = [size.term for size in sizes if size.plausible]
    # Step 11: the open-loop gate: each proposal in turn must lower the error of predicting the
    # held-out folds (whole sessions, or blocks of time) open loop.
    # Effects the likelihood could not tell apart (a last round ended ``ambiguous``) are
    # proposed too, each under the one-standard-error rule: if the open-loop prediction of
    # left-out folds needs every one of them beside the others, the tie is resolved (on June
    # OptiOdom sessions a turn skid tied with the distance scale, and the folds needed both);
    # if it keeps only some, it could not tell them apart either — the gate is run again
    # without them, and the verdict stays ambiguous with its separating experiment.
    tied = _tied_effects(state)
    # The filter's estimates, linearised at the rounds' model, without a noise effect's mean part
    # (floor bumps shorten the travel: their partner takes it in the fits).
    base = state.model.spec
    for name in state.named:
        if EFFECTS[name].noise and type(EFFECTS[name]).replay is not Effect.replay:
            base = EFFECTS[name].write(base, EFFECTS[name].absent_values())

    def gated(proposed_effects: list[str]) -> GateResult:
        linearised = FilterLinearisation(
            data, Model(base, state.model.sensor), proposed_effects, plausible_terms
        )
        return open_loop_gate(
            open_data,
            robot,
            state.model.spec,
            proposed_effects,
            plausible_terms,
            options,
            open_loop_folds(fit_runs),
            start=nuisances,
            nominal=nominal,
            report=report,
            filtered=linearised,
            corrected=OpenLoopData(fit_corrected, interval, length),
            named=[n for n in state.named if not EFFECTS[n].noise],
            order=cfg.gate_order,
        )

    gate = gated(_significant_effects(state, tied=True))
    resolved = bool(tied) and set(tied) <= set(gate.effects)
    if tied and not resolved:
        gate = gated(_significant_effects(state, tied=False))
    # Step 12: the estimator of the kept model's values: the filter's (efficient when its noise
    # model is right), unless the open-loop fit's (what the held-out comparison measures, robust to
    # a wrong noise model) predicts the left-out folds better by one standard error. Between two
    # estimators that predict equally well the efficient one wins: an open-loop estimate chosen on
    # fold noise leaves the filter a residual it can see (E_d 3e-5 off on a simulated robot).
    kept = list(gate.effects)
    chosen = open_loop_estimate(gate.fit, gate.cv_error)
    corrected_final = correct_runs(timed, gate.fit.nuisances)
    kf_data = Dataset.of(corrected_final, interval)
    corrected_open = OpenLoopData(corrected_final, interval, length)
    effect = model_effect(kept, gate.terms)

    def by_filter(spec_start: RobotSpec, effect_now: Effect) -> SystematicFit:
        start_model = fit_noise_model(kf_data, Model(spec_start, state.model.sensor), nuisance)
        return filter_estimate(
            kf_data, start_model, effect_now, nuisance, corrected_open, gate.folds, spec_start
        )

    estimators: dict[str, float] = {"open loop": chosen.fold_error(gate.folds)}
    if effect is not None:
        report("estimator", 1.0)
        filtered = by_filter(spec_with(gate.fit.spec, state.model.spec, kept, gate.terms), effect)
        estimators["filter"] = filtered.fold_error(gate.folds)
        if not chosen.better_than(filtered, gate.folds):
            chosen = filtered
    # Step 13: noise effects: named by the rounds' held-out likelihood; floor bumps only with their
    # signature and a size the floor can produce. One with a mean part (bumps shorten travel)
    # is fitted beside its systematic partners, and how far it moved E_d, E_b, E_s is reported.
    noise_checks: dict[str, dict[str, Any]] = {}
    noise_kept: list[str] = []
    for name in (n for n in state.named if EFFECTS[n].noise):
        values = EFFECTS[name].read(state.model.spec)
        if EFFECTS[name].wheel_jumps(values, np.ones((1, 2)), length) is not None:
            check = check_bumps(
                corrected_final,
                chosen.spec,
                values,
                max_obstacle=cfg.max_obstacle,
                max_rate=cfg.max_bump_rate,
                interval=interval,
                alpha=0.5 * cfg.alpha,
            )
            noise_checks[name] = check.as_dict()
            if not check.accepted:
                continue
        noise_kept.append(name)
    spec = chosen.spec
    for name in noise_kept:
        spec = EFFECTS[name].write(spec, EFFECTS[name].read(state.model.spec))
    geometry_check: dict[str, dict[str, Any]] = {}
    moving = [n for n in noise_kept if type(EFFECTS[n]).replay is not Effect.replay]
    if moving:
        kept += [p for n in moving for p in EFFECTS[n].partners if p not in kept]
        joint = model_effect(kept, gate.terms)
        assert joint is not None  # the partners at least
        if chosen.estimator == "filter":
            refit = by_filter(spec, joint)
        else:
            again = fit_open_loop(open_data, spec, joint, options, gate.fit.nuisances)
            refit = open_loop_estimate(
                again, cross_validate_open_loop(open_data, again, gate.folds)
            )
        geometry_check = _geometry_moves(chosen, refit, moving)
        chosen, spec = refit, refit.spec
    named = kept + noise_kept
    parameters = _parameters(chosen, kept)
    for name in noise_kept:
        parameters[name] = state.parameters.get(name, {})
    report("held-out test", 1.0)
    final_model = fit_noise_model(kf_data, Model(spec, state.model.sensor))
    # Step 14: the held-out runs: the model as given, the diagnosed one and the baseline, open loop.
    models = {AS_GIVEN: as_given}
    final_nuisances = _with_clock(gate.fit.nuisances, clock)
    models[DIAGNOSED] = evaluate_open_loop(
        DIAGNOSED, held_runs, spec, final_nuisances, clock_options, interval, length, pictured
    )
    baseline_name, baseline_geometry = None, None
    if baseline is not None:
        report("baseline", 1.0)
        base_spec = baseline(fit_corrected, robot)
        base_fit = fit_open_loop(open_data, base_spec, None, options, nuisances)
        models[BASELINE] = evaluate_open_loop(
            BASELINE,
            held_runs,
            base_spec,
            _with_clock(base_fit.nuisances, clock),
            clock_options,
            interval,
            length,
            pictured,
        )
        baseline_name = baseline.name
        baseline_geometry = {"E_d": base_spec.e_d, "E_b": base_spec.e_b, "E_s": base_spec.e_s}
    truth = {
        _run_id(held_runs[j], j): np.column_stack(
            [held_runs[j].time - held_runs[j].time[0], held_runs[j].true_pose[:, :2]]
        )
        for j in pictured
    }
    held_out = compare_models(
        split, models, np.random.default_rng(cfg.seed + 2), baseline_name, baseline_geometry, truth
    )
    held_corrected = correct_runs(held_runs, models[DIAGNOSED].nuisances)
    found_anything = bool(named) or bool(gate.terms)
    last = state.rounds[-1].verdict if state.rounds else "none"
    if resolved:
        last = "explained"  # the open-loop gate told the tied effects apart
    verdict, final_test = _final_test(
        Dataset.of(held_corrected, interval), final_model, found_anything, last, cfg.alpha, cfg.seed
    )
    if found_anything and not held_out.better_than_as_given:
        verdict = "unconfirmed"
    elif not found_anything and gate.steps:
        # The likelihood proposed effects or terms, none lowered the error of predicting
        # left-out folds open loop: the model stays as given, and the report says what was not
        # confirmed (never "explained" on a proposal the open-loop check refused).
        verdict = "unconfirmed"
    final_test["absorbed"] = absorbed
    final_test["tie_resolved_open_loop"] = tied if resolved else []
    report("shrink", 1.0)
    gaps = _shrink(held_corrected, robot, final_model, cfg)
    return Diagnosis(
        verdict=verdict,
        named_effects=named,
        parameters=parameters,
        initial=robot,
        model=spec,
        sensor=final_model.sensor,
        rounds=state.rounds,
        candidates=state.candidates,
        findings=findings,
        discovered=_kept_terms(state, gate.terms, chosen, corrected_final),
        discovery=_discovery_record(state.passes),
        final_test=final_test,
        nuisances=[
            *final_nuisances.values(),
            *(
                dataclasses.replace(n, held_out=True)
                for s, n in models[DIAGNOSED].nuisances.items()
                if s not in final_nuisances
            ),
        ],
        estimators={
            "chosen": chosen.estimator,
            "held_out_fold_rms_mm": {k: 1e3 * math.sqrt(v) for k, v in estimators.items()},
        },
        held_out=held_out,
        gate=gate.steps,
        stand_ins=[size.as_dict() for size in sizes if not size.plausible],
        noise_checks=noise_checks,
        geometry_check=geometry_check,
        filter_parameters={
            name: {key: entry["value"] for key, entry in state.parameters[name].items()}
            for name in state.named
            if name in state.parameters
        },
        terms_tried=_terms_tried(state.passes),
        fit_runs=[_run_id(runs[j], j) for j in fit_index],
        holdout_runs=[_run_id(runs[j], j) for j in held_index],
        skipped_runs=[s.as_dict() for s in skipped],
        **gaps,
    )

"""The discrepancy workflow: where the model and the robot disagree, which effect is missing,
add it, and show on data the fit never saw that the updated model predicts the robot better —
each kind of effect judged in the units it acts in.

:func:`diagnose` takes logged runs (any source: :mod:`odomgym.data`) and a robot model and returns
a :class:`~odomgym.diagnose.results.Diagnosis`. This module holds the orchestration — the order
of the steps and what passes between them — and the split; each step's work lives where the list
below points. :func:`_diagnose` reads as this list, one call per step, numbered as in
``docs/diagnose.md`` (which gives each in full):

1. **Split** (:func:`split_runs`): whole sessions are held out, or with one session, per
   experiment family a contiguous block of runs in time. Nothing is fitted on them.
2. **Measurement nuisances** (:mod:`odomgym.diagnose.nuisances`): each session's time offset
   (and, with several sessions, tracked point and yaw misalignment), fitted open loop jointly
   with E_d, E_b, E_s (:func:`odomgym.diagnose.openloop.fit_open_loop`) and removed from the
   runs.
3. **Where** (:mod:`odomgym.diagnose.where`) the model as given disagrees.
4. **The rounds** (:func:`odomgym.diagnose.rounds.run_round`), the likelihood's proposals:
   systematic catalogue effects first, each beside the wheel noise as nuisance, scored by the
   Kalman filter's cross-validated likelihood; when none is left, the grammar's score test and
   the discovery's sparse regression (:mod:`odomgym.diagnose.discover`); the noise model last.
5. **Backward check** (:func:`odomgym.diagnose.rounds._backward_check`): a named systematic
   effect the final model no longer needs is removed (``absorbed``) — also the partner whose
   mean a noise effect named later took over (the distance scale beside floor bumps).
6. **Noise effects' signature and size** (:func:`odomgym.diagnose.physical.check_bumps`): floor
   bumps only with heavy-tailed jumps in steady driving and a size the floor can produce. A kept
   noise effect's mean part (bumps shorten the travel) belongs to it from here on: it is in the
   robot every later open-loop fit starts from.
7. **Physical sizes** (:func:`odomgym.diagnose.physical.term_size`): a discovered term too large
   for what the robot did is a stand-in, reported and not kept.
8. **The open-loop gate** (:func:`odomgym.diagnose.gate.open_loop_gate`): each systematic
   proposal is kept only if it lowers the error of predicting left-out folds (sessions, or
   blocks) open loop; effects tied in a last ``ambiguous`` round are resolved here when the
   folds need every one of them.
9. **The estimator** of the kept model's values (:mod:`odomgym.diagnose.gate`) — the filter's,
   unless the open-loop fit's predicts the left-out folds better by one standard error.
10. **A kept term is a real size** (:func:`odomgym.diagnose.verdict.real_size`): at least two
    standard errors from zero with the sign the discovery proposed, or it is refused and steps
    8–10 run again without it.
11. **The noise model refitted** on the final systematic model (maximum likelihood).
12. **Held out, open loop** (:mod:`odomgym.diagnose.heldout`): the held-out runs predicted by the
    model as given, the diagnosed model and a baseline calibration, in mm and degrees — the
    yardstick of systematic effects and terms.
13. **Held out, spread** (:mod:`odomgym.diagnose.spread`): each kept noise effect against the
    model without it, refitted, by the log predictive density of the held-out runs' open-loop
    errors and the coverage of its 50 % and 95 % regions — the yardstick of noise effects.
14. **Confounds** (:mod:`odomgym.diagnose.confounds`): the directions in which the kept robot
    parameters and measurement nuisances make the same logs, derived from the data's joint
    Jacobian, and whether the fitted values moved along one.
15. **Verdict** (:func:`odomgym.diagnose.verdict.verdict_of`): which yardstick confirmed what;
    never a plain ``explained`` along a confound; the grammar's score test and a whiteness test
    on the held-out runs.
16. **The whitened gap, a diagnostic** (:func:`odomgym.diagnose.verdict._shrink`).

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
from odomgym.diagnose.confounds import Confound, derive_confounds
from odomgym.diagnose.fit import (
    Dataset,
    Model,
    candidate_effects,
    fit_noise,
    fit_noise_model,
    folds_for,
    noise_stderr,
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
    HeldOut,
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
    ModelErrors,
    NuisanceOptions,
    OpenLoopData,
    OpenLoopFit,
    evaluate_open_loop,
    fit_open_loop,
    open_loop_folds,
)
from odomgym.diagnose.physical import TermSize, check_bumps, term_size

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
    _forward_check,
    run_round,
)
from odomgym.diagnose.screen import SkippedRun, usable_runs
from odomgym.diagnose.spread import SpreadCheck, judge_spread, model_without
from odomgym.diagnose.steps import (
    Backward,
    NoiseNamed,
    Recording,
    RunSplit,
    SystematicModel,
    TermRefusal,
)
from odomgym.diagnose.verdict import (
    _discovered_order,
    _geometry_moves,
    _kept_terms,
    _parameters,
    _shrink,
    _significant_effects,
    _terms_tried,
    _tied_effects,
    noise_parameters,
    real_size,
    verdict_of,
)
from odomgym.diagnose.where import Finding, localise, run_residuals
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


Report = Callable[[str, float], None]


def _diagnose(
    runs: Sequence[Run],
    robot: RobotSpec,
    cfg: DiagnoseConfig,
    baseline: Baseline | None,
    progress: Report | None,
    journal: FitJournal | None,
) -> Diagnosis:
    """:func:`diagnose` itself, its BLAS on one thread: the steps of the module docstring."""

    def report(stage: str, fraction: float) -> None:
        interrupt.check()  # a stop request a finalizer swallowed (odomgym.interrupt)
        if progress is not None:
            progress(stage, fraction)

    # Each run from its first full pose; runs with too little ground truth set aside.
    runs, skipped = usable_runs(runs, robot)
    rng = np.random.default_rng(cfg.seed)
    split = _split(runs, cfg, rng)  # 1
    rec = _measurement_nuisances(split, robot, cfg, report)  # 2
    as_given, findings = _where(split, rec, robot, cfg, report)  # 3
    state = _rounds(rec, robot, cfg, rng, report, journal)  # 4
    backward = _backward(rec, state, cfg)  # 5
    noise = _noise_effects(rec, state, cfg)  # 6
    sizes = _term_sizes(rec, state)  # 7
    found = _systematic(rec, robot, state, backward, noise, sizes, cfg, report)  # 8–10
    final, noise = _noise_refit(found, state, noise)  # 11
    held = _held_out(split, rec, robot, found, as_given, baseline, cfg, report)  # 12
    spread = _spread(split, held, final, noise, found, cfg, report)  # 13
    confounds = _confounds(rec, robot, found, noise, final, report)  # 14
    verdict, final_test = verdict_of(  # 15
        split.held, found, final, held, spread, confounds, state, cfg
    )
    report("shrink", 1.0)
    gaps = _shrink(held.corrected(split.held), robot, final, cfg)  # 16
    final_test["absorbed"] = backward.absorbed
    final_test["unsupported"] = backward.unsupported
    final_test["noise_carried_by_the_rest"] = noise.vanished
    return _diagnosis(runs, skipped, robot, split, rec, state, findings, noise, sizes, found,
                      final, held, spread, confounds, verdict, final_test, gaps)  # fmt: skip


def _split(runs: Sequence[Run], cfg: DiagnoseConfig, rng: np.random.Generator) -> RunSplit:
    """Step 1: :func:`split_runs`, and the runs on each side."""
    fit_index, held_index, kind = split_runs(runs, cfg.holdout, rng)
    if len(fit_index) < 2:
        raise SpecError("too few runs left to fit after the hold-out split", field="holdout")
    return RunSplit(
        fit_index,
        held_index,
        kind,
        [runs[j] for j in fit_index],
        [runs[j] for j in held_index],
    )


def _measurement_nuisances(
    split: RunSplit, robot: RobotSpec, cfg: DiagnoseConfig, report: Report
) -> Recording:
    """Step 2: the recording's nuisances, fitted jointly with the geometry (E_d, E_b, E_s) so
    that a curving straight is not read as a tilted frame, nor a scale as a clock. A time
    offset is removed only where the data show one (module docstring of
    :mod:`odomgym.diagnose.nuisances`): resampling the counts at a spurious offset adds the
    acceleration-correlated disagreement the filter is most sensitive to."""
    report("measurement nuisances", 0.0)
    frames_on = cfg.session_frames
    if frames_on is None:
        frames_on = len(set(sessions_of([*split.fit, *split.held]))) >= 2
    clock_options = NuisanceOptions(
        time_offset=cfg.time_offset, frames=frames_on, max_time_offset=cfg.max_time_offset
    )
    interval, length = cfg.checkpoint_interval, float(robot.wheelbase)
    geometry = model_effect(GEOMETRY, [])
    clock = {
        s: _significant_offset(n)
        for s, n in fit_open_loop(
            OpenLoopData(split.fit, interval, length), robot, geometry, clock_options
        ).nuisances.items()
    }
    timed = correct_runs(split.fit, clock)
    options = NuisanceOptions(time_offset=False, frames=frames_on)
    open_data = OpenLoopData(timed, interval, length)
    frames = (
        fit_open_loop(open_data, robot, geometry, options).nuisances
        if frames_on
        else {s: SessionNuisance(s, n.runs) for s, n in clock.items()}
    )
    corrected = correct_runs(timed, frames)
    # The model as given, open loop: its own nuisances (the held-out sessions' on their own).
    nominal = fit_open_loop(open_data, robot, None, options, frames)
    return Recording(
        clock=clock,
        frames=frames,
        timed=timed,
        corrected=corrected,
        data=Dataset.of(corrected, interval),
        open_data=open_data,
        options=options,
        clock_options=clock_options,
        nominal=nominal,
        frames_on=frames_on,
        pictured=pictured_runs(split.held),
    )


def _where(
    split: RunSplit, rec: Recording, robot: RobotSpec, cfg: DiagnoseConfig, report: Report
) -> tuple[ModelErrors, list[Finding]]:
    """Step 3: where the model as given disagrees, over the fit runs and the held-out ones —
    and, for the latter's nuisances, the held-out runs predicted open loop by the model as
    given (step 12's first row)."""
    as_given = evaluate_open_loop(
        AS_GIVEN,
        split.held,
        robot,
        _with_clock(rec.nominal.nuisances, rec.clock),
        rec.clock_options,
        rec.open_data.interval,
        rec.open_data.length,
        rec.pictured,
    )
    report("where", 0.0)
    shown = [*rec.corrected, *correct_runs(split.held, as_given.nuisances)]
    return as_given, localise(run_residuals(shown, robot), cfg.alpha)


def _rounds(
    rec: Recording,
    robot: RobotSpec,
    cfg: DiagnoseConfig,
    rng: np.random.Generator,
    report: Report,
    journal: FitJournal | None,
) -> DiagnosisState:
    """Step 4: the rounds — systematic effects first, then (once their structure is
    exhausted) discovery, then the noise model: a noise effect may stand for nothing a
    systematic term explains. A noise effect whose signature no systematic effect can make
    (floor bumps' jumps during steady driving) competes with the systematic effects where its
    signature is in the data: a systematic effect named before it would stand in for its
    realised jumps. With the sessions' frames fitted, the catalogue effects they make
    unidentifiable (:data:`~odomgym.diagnose.nuisances.SESSION_EFFECTS`) are no candidates."""
    names = cfg.candidates or tuple(EFFECTS)
    if rec.frames_on:
        names = tuple(n for n in names if n not in SESSION_EFFECTS)
    model = fit_noise_model(rec.data, Model(robot, SensorNoise(*cfg.initial_sensor)))
    nuisance = EFFECTS.get(NUISANCE)
    excluded = (NUISANCE, DISCOVERED)
    systematic = [e.name for e in candidate_effects(excluded) if not e.noise and e.name in names]
    noise = [e.name for e in candidate_effects(excluded) if e.noise and e.name in names]
    ctx = RoundContext(
        data=rec.data,
        folds=folds_for(rec.corrected, min(cfg.folds, len(rec.corrected)), rng),
        nuisance=nuisance,
        stages=[
            ("mean", systematic + [n for n in noise if EFFECTS[n].with_systematic], nuisance),
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
    return state


def _backward(rec: Recording, state: DiagnosisState, cfg: DiagnoseConfig) -> Backward:
    """Step 5: a systematic effect named early may have stood in for what a later one (or a
    discovered term, or a noise effect) explains better; each must still be significant in the
    final model, or it is removed (``absorbed``). An effect an earlier round found significant
    but never named is proposed to the gate only if it is significant added to the final model
    (``unsupported`` otherwise: :func:`odomgym.diagnose.rounds._forward_check`)."""
    absorbed = _backward_check(rec.data, state.model, state.named, cfg.alpha)
    for name in absorbed:
        spec = EFFECTS[name].write(state.model.spec, EFFECTS[name].absent_values())
        state.model = Model(spec, state.model.sensor)
        state.named.remove(name)
        state.parameters.pop(name, None)
    last = state.rounds[-1] if state.rounds else None
    in_last = {c.name for c in last.candidates if c.significant} if last is not None else set()
    earlier = [
        n
        for n in _significant_effects(state, tied=True)
        if n not in state.named and n not in absorbed and n not in in_last
    ]
    return Backward(absorbed, _forward_check(rec.data, state.model, earlier, cfg.alpha))


def _noise_effects(rec: Recording, state: DiagnosisState, cfg: DiagnoseConfig) -> NoiseNamed:
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


def _term_sizes(rec: Recording, state: DiagnosisState) -> list[TermSize]:
    """Step 7: every discovered term of the rounds judged at the data's operating range: one
    too large for what the robot did is a stand-in (for a clock, a frame or a mechanism the
    grammar lacks), reported, not proposed."""
    present = state.model.spec.effect_values(DISCOVERED) or {}
    return [
        term_size(rec.corrected, state.model.spec, t, present[t]) for t in _discovered_order(state)
    ]


MAX_SIZE_PASSES = 4
"""Most passes of steps 8–10: each pass after the first has refused at least one term."""


def _systematic(
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
    for _ in range(MAX_SIZE_PASSES):
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
        )

    out = {*noise.took_over, *backward.unsupported}
    pool = [n for n in _significant_effects(state, tied=True) if n not in out]
    gate = gated(pool)
    resolved = bool(tied) and set(tied) <= set(gate.effects)
    if tied and not resolved:
        gate = gated([n for n in _significant_effects(state, tied=False) if n in pool])
    return gate, tied, resolved


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


def _noise_refit(
    found: SystematicModel, state: DiagnosisState, noise: NoiseNamed
) -> tuple[Model, NoiseNamed]:
    """Step 11: the final model — the chosen systematic values and the kept noise effects,
    whose parameters and the sensor noise are refitted by maximum likelihood on the fit runs
    under it (the rounds fitted them beside a systematic model the gate may since have
    changed), with their standard errors there. A noise effect the refit takes to the floor of
    its range (the fit's "absent": a tenth of its parameters' scale) was carried by the rest of
    the model and leaves it."""
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


def _final_nuisances(rec: Recording, found: SystematicModel) -> dict[str, SessionNuisance]:
    """The fit sessions' nuisances under the diagnosed model: the gate's frames, the clock of
    step 2."""
    return _with_clock(found.gate.fit.nuisances, rec.clock)


def _held_out(
    split: RunSplit,
    rec: Recording,
    robot: RobotSpec,
    found: SystematicModel,
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
        found.chosen.spec,
        _final_nuisances(rec, found),
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
            _with_clock(base_fit.nuisances, rec.clock),
            rec.clock_options,
            interval,
            length,
            rec.pictured,
        )
        baseline_name = baseline.name
        baseline_geometry = {"E_d": base_spec.e_d, "E_b": base_spec.e_b, "E_s": base_spec.e_s}
    truth = {
        _run_id(split.held[j], j): np.column_stack(
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


def _spread(
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


def _confounds(
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


def _in_order_added(
    state: DiagnosisState, effects: Sequence[str], noise: Sequence[str]
) -> list[str]:
    """The kept catalogue effects — systematic ``effects`` and ``noise`` effects — in the order
    the rounds named them (an effect named again after others joined keeps its first place),
    then those the gate kept that the rounds found significant without naming them: the order
    in which the diagnosis added them to the model."""
    kept = {*effects, *noise}
    first = [n for n in state.named if n in kept]
    return first + [n for n in effects if n not in first]


def _diagnosis(
    runs: Sequence[Run],
    skipped: Sequence[SkippedRun],
    robot: RobotSpec,
    split: RunSplit,
    rec: Recording,
    state: DiagnosisState,
    findings: list[Finding],
    noise: NoiseNamed,
    sizes: Sequence[TermSize],
    found: SystematicModel,
    final: Model,
    held: HeldOut,
    spread: Sequence[SpreadCheck],
    confounds: Sequence[Confound],
    verdict: str,
    final_test: dict[str, Any],
    gaps: dict[str, Any],
) -> Diagnosis:
    """The :class:`~odomgym.diagnose.results.Diagnosis` of the steps' results."""
    gate, chosen = found.gate, found.chosen
    kept = list(gate.effects)
    fit_nuisances = _final_nuisances(rec, found)
    parameters = _parameters(chosen, kept)
    for name in noise.kept:
        parameters[name] = noise_parameters(noise.errors.get(name, {}), name, final.spec)
    return Diagnosis(
        verdict=verdict,
        named_effects=_in_order_added(state, kept, noise.kept),
        parameters=parameters,
        initial=robot,
        model=final.spec,
        sensor=final.sensor,
        rounds=state.rounds,
        candidates=state.candidates,
        findings=findings,
        discovered=_kept_terms(state, gate.terms, chosen, found.corrected),
        discovery=_discovery_record(state.passes),
        final_test=final_test,
        nuisances=[
            *fit_nuisances.values(),
            *(
                dataclasses.replace(n, held_out=True)
                for s, n in held.models[DIAGNOSED].nuisances.items()
                if s not in fit_nuisances
            ),
        ],
        estimators={
            "chosen": chosen.estimator,
            "held_out_fold_rms_mm": {k: 1e3 * math.sqrt(v) for k, v in found.estimators.items()},
        },
        held_out=held,
        gate=gate.steps,
        stand_ins=[size.as_dict() for size in sizes if not size.plausible],
        refused_terms=[r.as_dict() for r in found.refused],
        noise_checks=noise.checks,
        spread=[check.as_dict() for check in spread],
        confounds=[c.as_dict() for c in confounds],
        geometry_check=_geometry_moves(final.spec, spread, chosen.entries),
        filter_parameters={
            name: {key: entry["value"] for key, entry in state.parameters[name].items()}
            for name in state.named
            if name in state.parameters
        },
        terms_tried=_terms_tried(state.passes),
        fit_runs=[_run_id(runs[j], j) for j in split.fit_index],
        holdout_runs=[_run_id(runs[j], j) for j in split.held_index],
        skipped_runs=[s.as_dict() for s in skipped],
        **gaps,
    )

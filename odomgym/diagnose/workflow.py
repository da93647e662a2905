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
   mean a noise effect named later took over (the distance scale beside floor bumps) — and a
   noise effect named beside an absorbed one must pass its test again without it.
6. **Noise effects' signature and size** (:func:`odomgym.diagnose.keep.noise_effects`,
   :func:`odomgym.diagnose.physical.check_bumps`): floor
   bumps only with heavy-tailed jumps in steady driving and a size the floor can produce. A kept
   noise effect's mean part (bumps shorten the travel) belongs to it from here on: it is in the
   robot every later open-loop fit starts from.
7. **Physical sizes** (:func:`odomgym.diagnose.keep.term_sizes`): a discovered term too large
   for what the robot did is a stand-in, reported and not kept.
8. **The open-loop gate** (:func:`odomgym.diagnose.keep.systematic`, over
   :func:`odomgym.diagnose.gate.open_loop_gate`): each systematic
   proposal is kept only if it lowers the error of predicting left-out folds (sessions, or
   blocks) open loop; effects tied in a last ``ambiguous`` round are resolved here when the
   folds need every one of them.
9. **The estimator** of the kept model's values (:mod:`odomgym.diagnose.gate`) — the filter's,
   unless the open-loop fit's predicts the left-out folds better by one standard error.
10. **A kept term is a real size** (:func:`odomgym.diagnose.verdict.real_size`): at least two
    standard errors from zero with the sign the discovery proposed, or it is refused and steps
    8–10 run again without it.
11. **The noise model refitted** on the final systematic model (maximum likelihood;
    :func:`odomgym.diagnose.keep.noise_refit`).
12. **Held out, open loop** (:func:`odomgym.diagnose.confirm.held_out`): the held-out runs
    predicted by the model as given, the diagnosed model and a baseline calibration, in mm and
    degrees — the yardstick of systematic effects and terms.
13. **Held out, spread** (:func:`odomgym.diagnose.confirm.spread`): each kept noise effect
    against the model without it, refitted, by the log predictive density of the held-out runs'
    open-loop errors and the coverage of its 50 % and 95 % regions — the yardstick of noise
    effects.
14. **Confounds** (:func:`odomgym.diagnose.confirm.confounds`): the directions in which the kept
    robot parameters and measurement nuisances make the same logs, derived from the data's joint
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
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from odomgym import interrupt
from odomgym.diagnose import confirm, keep
from odomgym.diagnose.config import DiagnoseConfig
from odomgym.diagnose.confounds import Confound
from odomgym.diagnose.fit import (
    Dataset,
    Model,
    candidate_effects,
    fit_noise_model,
    folds_for,
    strata,
)
from odomgym.diagnose.gate import (
    model_effect,
)
from odomgym.diagnose.heldout import (
    AS_GIVEN,
    DIAGNOSED,
    Baseline,
    HeldOut,
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
    with_clock,
)
from odomgym.diagnose.openloop import (
    ModelErrors,
    NuisanceOptions,
    OpenLoopData,
    evaluate_open_loop,
    fit_open_loop,
)
from odomgym.diagnose.physical import TermSize

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
from odomgym.diagnose.spread import SpreadCheck
from odomgym.diagnose.steps import (
    Backward,
    NoiseNamed,
    Recording,
    RunSplit,
    SystematicModel,
    run_id,
)
from odomgym.diagnose.verdict import (
    _geometry_moves,
    _kept_terms,
    _parameters,
    _shrink,
    _significant_effects,
    _terms_tried,
    noise_parameters,
    verdict_of,
)
from odomgym.diagnose.where import Finding, localise, run_residuals
from odomgym.effects import EFFECTS
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

AT_STARTS = ("backlash",)
"""Catalogue effects that act where a clock offset acts — at every start and reversal of a
wheel, whose travel lags the encoder's by the play — fitted beside the geometry when the time
offset is (step 2): without them a robot's backlash was taken for a clock offset of a few
milliseconds, six standard errors from zero, and the backlash then fitted on the re-timed logs
came out a quarter short, its remainder picked up by acceleration terms (the hidden-effect
matrix's backlash robots, both generators)."""


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
    report("backward check, noise effects, term sizes", 0.0)
    backward = _backward(rec, state, cfg)  # 5
    noise = keep.noise_effects(rec, state, cfg)  # 6
    sizes = keep.term_sizes(rec, state)  # 7
    found = keep.systematic(rec, robot, state, backward, noise, sizes, cfg, report)  # 8–10
    final, noise = keep.noise_refit(found, state, noise)  # 11
    held = confirm.held_out(split, rec, robot, found, final, as_given, baseline, cfg, report)  # 12
    spread = confirm.spread(split, held, final, noise, found, cfg, report)  # 13
    confounds = confirm.confounds(rec, robot, found, noise, final, report)  # 14
    verdict, final_test = verdict_of(  # 15
        split.held, found, noise, final, held, spread, confounds, state, cfg
    )
    report("shrink", 1.0)
    gaps = _shrink(held.corrected(split.held), robot, final, cfg)  # 16
    final_test["absorbed"] = backward.absorbed
    final_test["unsupported"] = backward.unsupported
    final_test["noise_carried_by_the_rest"] = noise.vanished
    final_test["taken_over"] = noise.took_over
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
    that a curving straight is not read as a tilted frame, nor a scale as a clock — the clock
    also beside the effects that act at starts (:data:`AT_STARTS`), nor gear play as a clock. A
    time
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
    names = cfg.candidates or tuple(EFFECTS)
    at_starts = model_effect([*GEOMETRY, *(n for n in AT_STARTS if n in names)], [])
    clock = {
        s: _significant_offset(n)
        for s, n in fit_open_loop(
            OpenLoopData(split.fit, interval, length), robot, at_starts, clock_options
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
        with_clock(rec.nominal.nuisances, rec.clock),
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


def _in_order_added(
    state: DiagnosisState, effects: Sequence[str], noise: Sequence[str]
) -> list[str]:
    """The kept catalogue effects — systematic ``effects`` and ``noise`` effects — in the order
    the rounds named them (an effect named again after others joined keeps its first place),
    then those the gate kept that the rounds found significant without naming them: the order
    in which the diagnosis added them to the model, with two exceptions.

    The first: an effect kept beside a partner it extends
    (:attr:`~odomgym.effects.Effect.partners`: the skid track over ``wheelbase``, its
    asymptote; floor bumps over the distance scale, their mean loss) takes the place of the
    partner if the partner comes first by the rule above (named earlier, or named where the
    effect was only kept by the gate), the partner right after it: the pair is one law, and
    the effect names it. The report's table says so in its header. A first round, far
    from the robot, may name the constant part alone (the World's Husky against its preset,
    ``benchmarks/skid_field.py`` without lost samples: ``wheelbase`` in round 1, the marker's
    offset in round 2, the skid track in round 3, all kept).

    The second: an error of the measurement (:attr:`~odomgym.effects.Effect.measurement`, the
    tracked point's offset) comes after the robot's own effects, whatever round named it. A
    marker far from the axle of a small robot moves the tracked point more than any effect of
    the robot does, and so wins the first round (the World's Jackal and Pioneer 3-AT with the
    marker 0.29 m ahead: ``benchmarks/skid_field.py``); the report is read for what is wrong
    with the robot, and the offset is the tracker's."""
    kept = {*effects, *noise}
    first = [n for n in state.named if n in kept]
    order = first + [n for n in effects if n not in first]
    for name in list(order):
        places = [order.index(p) for p in EFFECTS[name].partners if p in order]
        if places and min(places) < order.index(name):
            order.remove(name)
            order.insert(min(places), name)
    robot = [n for n in order if not EFFECTS[n].measurement]
    return robot + [n for n in order if EFFECTS[n].measurement]


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
    fit_nuisances = confirm.final_nuisances(rec, found)
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
        fit_runs=[run_id(runs[j], j) for j in split.fit_index],
        holdout_runs=[run_id(runs[j], j) for j in split.held_index],
        skipped_runs=[s.as_dict() for s in skipped],
        **gaps,
    )

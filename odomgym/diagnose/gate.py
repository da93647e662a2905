"""The open-loop gate: keep only what predicts the robot better on data the fit never saw.

The rounds (:mod:`odomgym.diagnose.rounds`) name catalogue effects and discover grammar terms
by likelihood, whose noise model can absorb what the systematic part lacks: on real logs the
whitened gap then "closes" while the model predicts the robot worse (a real-robot diagnosis went
from 108 to 163 mm of open-loop error on held-out sessions while its whitened gap said 99 %
closed). The gate keeps a proposal only if the model with it predicts the held-out folds better
*open loop, in plain units* than the model without it
(:func:`odomgym.diagnose.openloop.cross_validate_open_loop`: whole sessions left out, or
contiguous blocks of runs with one session). It works backwards from the model with every
proposal (backward elimination): each proposal is tested against the model without it, the least
useful one that fails goes, and the rest are tested again — tested one at a time on a model
missing the others, a real effect can look useless (a scale fitted while a large diameter ratio
is missing takes part of the curvature and predicts worse than nothing). In the workflow's
default order (``order="catalogue first"``) the catalogue effects are eliminated on their own
first and the discovered terms then on top of the effects kept, which stay fixed: eliminated
together, a term could displace a mechanism it resembles, and on the June OptiOdom sessions 7 of
14 leave-one-session-out folds kept another model (all 14 keep the same five effects in this
order). The rules:

* a catalogue effect the rounds named stays if the mean held-out error over the folds is lower
  with it; one they found significant but did not name (beaten by another in the filter's
  likelihood — on the June OptiOdom sessions the wheelbase, behind a turn skid) must lower it by
  more than one standard error, as a term must;
* a discovered term (a sinusoid's sine and cosine together) stays if it lowers the error by more
  than one standard error of the folds' differences —
  the one-standard-error rule (Breiman, Friedman, Olshen & Stone 1984, §3.4.3; Hastie,
  Tibshirani & Friedman 2009, §7.10): a term must earn its place against the smaller model;
* and only if the open-loop fit can tell it from the rest of the model: a term whose variance
  inflation factor in the fit exceeds :data:`MAX_INFLATION` is a combination of the geometry
  and the sessions' nuisances (a constant crab angle with the sessions' frames fitted),
  whatever it does to the error: it would only make the parameters a user copies arbitrary
  (rule ``"not identifiable"``; :func:`odomgym.diagnose.openloop.variance_inflation`);
* a catalogue effect the fit cannot tell from the other robot effects (the same bound on its
  variance inflation among the robot's parameters alone: :func:`_inflation`) must lower the
  error by more than one standard error and by a real share of it (:data:`REAL_SIZE`),
  whatever the rounds named (rule :data:`UNIDENTIFIED`): two robot effects that are one law
  split in two (a turn skid and a speed-dependent track, one-sided laws of |v·ω| of opposite
  signs) must earn the split. Where
  such an effect stays and a term was refused as not identifiable beside it, the gate runs
  again without it, and the model that predicts the folds better is kept (rule ``"not
  identifiable beside wheelbase"``, :func:`_exchange`): a skid track whose half-point lies
  beyond the logged turns, one more constant track factor, had blocked a yaw-rate term. An
  extension the fit can identify, kept beside its base, is exchanged the same way for the
  terms it blocked, but only for a model better by more than one standard error (rule
  ``"blocked the terms beside wheelbase"``);
* once the terms are kept, the catalogue effects are judged again beside them, each under the
  rule it had among the effects (:func:`_beside_terms`; rules ending ``"beside the kept
  terms"``): an effect the rounds named before discovery proposed the terms must still lower
  the error in the final model (a speed-dependent skid track had stayed beside the speed terms
  that describe a shrinking wheel, predicting nothing more).

Two rules make the elimination stepwise rather than one-way. A base an extension builds on
(``wheelbase``, which a ``skid_track`` widens in tight turns: its :attr:`~odomgym.effects.Effect.
partners`) does not leave while the extension is in the model — the principle of marginality
(Nelder 1977) — and if it fails its rule there it stays, its rule ``"held by skid_track"``. And
once no proposal fails, each catalogue effect removed on the way is fitted back into the model
left, and the one that lowers the folds' error most under its rule returns (the forward step of
a stepwise selection; Efroymson 1960), the elimination then running again; an effect returns at
most once. Both for one failure: where two proposals trade along a ridge (a skid track's excess
against E_b on a differential-drive robot) the model with every proposal is not identifiable,
its fold refits predict badly, and the proposal removed first takes the blame (one June
OptiOdom fold lost the wheelbase and the diameter ratio that way, and kept a skid track).

A model is never fitted worse than a model nested in it (:func:`fit_nested`): a fit that stops
above the smaller model's error is fitted again from it, and the model left when the last of
the proposals under test goes *is* that smaller model's fit, not a refit of it from the last
proposal's values.

Every model is fitted two ways, and judged by whichever predicts the folds better: by least
squares on the open-loop error (:func:`odomgym.diagnose.openloop.fit_open_loop`, jointly with the
sessions' nuisances; robust to a wrong noise model) and by the filter's generalised least
squares, linearised at the rounds' model (:class:`FilterLinearisation`; efficient when the noise
model is right — on simulated robots with wheel noise the open-loop fit alone cannot resolve
effects the filter pins down, a 1.3 mrad wheel toe or a 0.015 rad backlash, and would drop
them).
"""

from __future__ import annotations

import functools
import io
import math
import pickle
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.diagnose.config import GATE_ORDERS
from odomgym.diagnose.fit import (
    Dataset,
    Joint,
    Model,
    build_within,
    fit_candidate,
    forks,
    gauss_newton_step,
    run_forked,
    systematic_vector,
    whitened_stack,
)
from odomgym.diagnose.nuisances import SessionNuisance
from odomgym.diagnose.openloop import (
    NuisanceOptions,
    OpenLoopData,
    OpenLoopFit,
    cross_validate_open_loop,
    fit_open_loop,
    run_errors,
)
from odomgym.effects import EFFECTS, DiscoveredTerms, Effect
from odomgym.robot import RobotSpec
from odomgym.workers import TaskFailed

__all__ = [
    "FilterLinearisation",
    "GateResult",
    "GateStep",
    "SystematicFit",
    "filter_estimate",
    "fit_nested",
    "model_effect",
    "open_loop_estimate",
    "open_loop_gate",
    "spec_with",
    "term_proposals",
]

FloatArray = NDArray[np.float64]
DISCOVERED = "discovered"
MAX_INFLATION = 1e6
"""The largest variance inflation factor a discovered term may have in the open-loop fit, and
the one above which an extension beside its base is exchanged for a term it blocked for any
better model (below it, for one better by a standard error: module docstring). VIF =
1 / (1 − R²) with R² of the term's column regressed on the others (Kutner, Nachtsheim, Neter
& Li 2005, §10.5), so 10⁶ is a column within 10⁻³ (relative norm) of the others' span: the
bound :func:`odomgym.diagnose.discover.library_jacobian` drops a term at. Not the textbook 10
for *harmful* collinearity: the geometry is itself that collinear (on the June OptiOdom
sessions E_d's VIF is ≈ 700 beside a turn skid) and still well determined; this bound refuses
only what the data cannot determine at all."""


UNIDENTIFIED = "one standard error and a real size, not identifiable beside the other effects"
"""The rule of a catalogue effect the open-loop fit cannot tell from the other robot effects
(variance inflation above :data:`MAX_INFLATION`, :func:`_inflation`): whatever the rounds
named, it must lower the folds' error by more than one standard error, as a term must, and by
at least :data:`REAL_SIZE` of it.

Why a size as well: the one-standard-error rule weighs the improvement against its noise,
which can be tiny. An unidentified effect adds parameters the data do not determine (its
values, which a user would copy, are arbitrary along a ridge), and two robot effects that are
one law split in two can always fit a little more than one. Seen on a June OptiOdom fold with
``skid_speed`` offered to every robot: ``skid_speed`` beside ``turn_skid`` (VIF 2.6·10⁶ each)
lowered the folds' mean square error by 0.0020 ± 0.0011 mm², 0.009 % of it (held-out RMS
4.78546 → 4.78538 mm). A skid track at 5 × its detection limit beside ``wheelbase``, as
unidentified (VIF 4·10⁷; its shape λ½ is not resolved), lowered it by 1.8 ± 1.0 mm², 26 %
(2.63 → 2.07 mm). A two-standard-error margin instead refused both (1.85 and 1.77 standard
errors)."""

REAL_SIZE = 0.01
"""The least share of the folds' mean square error an unidentified effect must remove
(:data:`UNIDENTIFIED`): 1 %, half a percent of the RMS error. Not fitted: on the cases
measured (docstring of :data:`UNIDENTIFIED`) every bound from 0.01 % to 25 % decides the same."""


@dataclass(frozen=True)
class GateStep:
    """One proposal tried by the gate.

    Attributes:
        kind: ``"effect"`` (catalogue) or ``"term"`` (discovered; a sinusoid's sine and cosine
            are one proposal, ``"right_sin1+right_cos1"``).
        name: the effect's or term's name.
        kept: whether it joined the model.
        before_mm, after_mm: held-out RMS combined open-loop error without and with it [mm]
            (runs weigh equally).
        difference, stderr: mean over the folds of the change of their mean square error, and
            its standard error [mm²].
        rule: the rule it had to pass (``"lower"``, ``"one standard error"`` or, for an
            effect the fit cannot tell from the other robot effects, :data:`UNIDENTIFIED`),
            or ``"not identifiable"``: a term whose variance inflation exceeded
            :data:`MAX_INFLATION`; or ``"not identifiable beside BASE"``: an effect as
            inflated, exchanged for the terms it blocked (:func:`_exchange`), or
            ``"blocked the terms beside BASE"``: an identified extension exchanged for them
            (:data:`BLOCKING`); or ``"held by EFFECT"``: a base that failed its rule while an
            effect that extends it stayed (module docstring); an effect's rule judged again
            beside the kept terms ends ``" beside the kept terms"`` (:data:`BESIDE_TERMS`).
        estimator: whose fold refits predicted the folds better, and so were compared:
            ``"open loop"`` or ``"filter"`` (:class:`FilterLinearisation`).
        inflation: the largest variance inflation factor of its parameters in the open-loop
            fit of the model with it (a term's by the rest and the nuisances, an effect's by
            the other robot effects alone: :func:`_inflation`).
    """

    kind: str
    name: str
    kept: bool
    before_mm: float
    after_mm: float
    difference: float
    stderr: float
    rule: str
    estimator: str = "open loop"
    inflation: float = math.nan

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class GateResult:
    """What the gate kept, and the exact fit of the kept model.

    Attributes:
        steps: every proposal tried, in order.
        effects: the catalogue effects kept (in order); terms: the discovered terms kept.
        fit: the kept model's open-loop fit (the robot as given when nothing was kept).
        cv_error: each fit run's held-out mean square combined error under the kept model [m²].
        nominal_cv_error: the same under the model as given (its nuisances fitted) [m²].
        folds: the cross-validation folds (indices of the fit runs).
    """

    steps: list[GateStep]
    effects: list[str]
    terms: list[str]
    fit: OpenLoopFit
    cv_error: FloatArray
    nominal_cv_error: FloatArray
    folds: list[list[int]]


def model_effect(effects: Sequence[str], terms: Sequence[str]) -> Effect | None:
    """The systematic parameters of a model as one effect: the catalogue ``effects`` and the
    grammar ``terms`` side by side (None when there are none)."""
    parts: list[Effect] = [EFFECTS[name] for name in effects]
    if terms:
        parts.append(DiscoveredTerms(list(terms)))
    return Joint(parts) if parts else None


def spec_with(
    robot: RobotSpec, proposed: RobotSpec, effects: Sequence[str], terms: Sequence[str]
) -> RobotSpec:
    """``robot`` with ``effects`` and ``terms`` at their values in ``proposed``."""
    spec = robot
    for name in effects:
        spec = EFFECTS[name].write(spec, EFFECTS[name].read(proposed))
    if terms:
        chosen = DiscoveredTerms(list(terms))
        spec = chosen.write(spec, chosen.read(proposed))
    return spec


def fit_nested(
    data: OpenLoopData,
    begin: RobotSpec,
    effect: Effect | None,
    options: NuisanceOptions,
    nuisances: Mapping[str, SessionNuisance] | None,
    base: OpenLoopFit,
) -> OpenLoopFit:
    """The open-loop fit of ``effect`` from ``begin`` (and ``nuisances``), never ending above
    ``base``, the fit of a model nested in it.

    Why: ``base``'s robot and nuisances are a point of the larger model (the gate gives every
    proposal a model lacks the robot's given value, in ``base`` and ``begin`` alike), so a
    least-squares fit of the larger model that stops above ``base``'s error stopped in a worse
    basin than one it could reach; it is fitted again from ``base`` and the lower of the two
    kept. Without it a term-laden start could leave a model far from its own optimum: in one
    June OptiOdom leave-one-session-out fold the catalogue effects, refitted from the last
    term's model after that term was eliminated, came out at E_b 0.93 (50 mm of held-out error)
    where the same effects fitted alone gave E_b 1.0014 (2.5 mm) — and which of the two came out
    was decided by the last digits of the arithmetic."""
    fit = fit_open_loop(data, begin, effect, options, nuisances)
    if effect is not None and fit.error > base.error:
        again = fit_open_loop(data, base.spec, effect, options, base.nuisances)
        if again.error < fit.error:
            return again
    return fit


def _fold_means(per_run: FloatArray, folds: Sequence[Sequence[int]]) -> FloatArray:
    return np.array([float(np.mean(per_run[list(f)])) for f in folds])


def _fold_difference(
    a: FloatArray, b: FloatArray, folds: Sequence[Sequence[int]]
) -> tuple[float, float]:
    """Mean over the folds of (fold mean of ``a`` − fold mean of ``b``) and its standard error
    (inf with one fold): the paired comparison both the gate and the estimator choice use."""
    diff = _fold_means(a, folds) - _fold_means(b, folds)
    mean = float(np.mean(diff))
    spread = float(np.std(diff, ddof=1) / math.sqrt(len(diff))) if len(diff) > 1 else math.inf
    return mean, spread


class FilterLinearisation:
    """The filter's view of every proposal at once, for the gate's cheap filter estimates.

    The whitened innovations of the rounds' final model (``base``: every proposal at the
    rounds' values, its wheel noise and sensor noise as fitted) and their derivatives with
    respect to every proposal's parameters (central differences, in units of each parameter's
    scale). A sub-model's parameters — some proposals kept, the others at their absent values —
    are then one Gauss–Newton step from there on the runs of a fold's complement: the filter's
    generalised least squares, linearised, as the rounds' own cross-validation does it.
    """

    def __init__(
        self,
        data: Dataset,
        base: Model,
        effects: Sequence[str],
        terms: Sequence[str],
        step: float = 0.05,
    ) -> None:
        joint = model_effect(effects, terms)
        self.keys: list[str] = [p.name for p in joint.parameters] if joint is not None else []
        self.whitened: list[FloatArray] = whitened_stack(data, base.spec, base.sensor)[1]
        self.columns: list[FloatArray] = [np.zeros((len(w), 0)) for w in self.whitened]
        self.current = np.zeros(len(self.keys))
        self.absent = np.zeros(len(self.keys))
        self.build: Callable[[FloatArray], RobotSpec] = lambda u: base.spec
        if joint is None:
            return
        u0, _, _, build = systematic_vector(base.spec, joint)
        self.build = build
        values = joint.read(base.spec)
        self.current = np.array([values[k] for k in self.keys])
        self.absent = np.array([p.absent for p in joint.parameters])
        self.scale = np.array([p.scale for p in joint.parameters])
        columns: list[list[FloatArray]] = [[] for _ in self.whitened]
        for k in range(len(u0)):
            du = np.zeros_like(u0)
            du[k] = step
            _, plus = whitened_stack(data, build(u0 + du), base.sensor)
            _, minus = whitened_stack(data, build(u0 - du), base.sensor)
            for j in range(len(self.whitened)):
                columns[j].append((plus[j] - minus[j]) / (2.0 * step))
        self.columns = [np.stack(c, axis=1) for c in columns]

    def spec_for(self, kept: Sequence[str], train: Sequence[int]) -> RobotSpec:
        """The robot with the parameters ``kept`` (``EFFECT.PARAMETER`` keys) fitted on the runs
        ``train`` by one Gauss–Newton step, every other proposal at its absent value."""
        u = np.zeros(len(self.keys))
        if not self.keys:
            return self.build(u)
        inside = np.array([k in set(kept) for k in self.keys])
        u[~inside] = (self.absent[~inside] - self.current[~inside]) / self.scale[~inside]
        if inside.any():
            a = np.zeros((int(inside.sum()),) * 2)
            b = np.zeros(int(inside.sum()))
            for j in train:
                cols = self.columns[j]
                rest = self.whitened[j] + cols[:, ~inside] @ u[~inside]
                a += cols[:, inside].T @ cols[:, inside]
                b += cols[:, inside].T @ rest
            u[inside] = gauss_newton_step(a, b)
        return build_within(self.build, np.zeros(len(self.keys)), u)

    def cross_validate(
        self, kept: Sequence[str], open_data: OpenLoopData, folds: Sequence[Sequence[int]]
    ) -> FloatArray:
        """Each run's held-out mean square combined open-loop error [m²] under the filter's
        fit of ``kept`` without its fold (``open_data``: the same runs, nuisances removed)."""
        out = np.empty(len(open_data))
        for fold in folds:
            held = set(fold)
            spec = self.spec_for(kept, [j for j in range(len(open_data)) if j not in held])
            out[list(fold)] = run_errors(open_data.subset(list(fold)), spec)
        return out


def term_proposals(terms: Sequence[str]) -> list[str]:
    """The discovered ``terms`` as the gate's proposals, in order: a sine and a cosine of the
    same channel and harmonic are one sinusoid (``"right_sin1+right_cos1"``), proposed together
    where the first of the two stood — alone, either is a sinusoid at a phase the data did not
    choose."""
    out: list[str] = []
    for name in terms:
        channel, _, modulator = name.rpartition("_")
        if modulator[:3] in ("sin", "cos"):
            other = f"{channel}_{'cos' if modulator.startswith('sin') else 'sin'}{modulator[3:]}"
            if other in terms:
                pair = "+".join(sorted((name, other), key=lambda t: "cos" in t))
                if pair not in out:
                    out.append(pair)
                continue
        out.append(name)
    return out


Member = tuple[str, str]
"""A proposal of the gate: (``"effect"`` or ``"term"``, its name)."""

Scored = tuple[OpenLoopFit, FloatArray, str]
"""A model's open-loop fit, each fit run's held-out mean square error under it [m²], and the
estimator whose fold refits gave those errors."""


def _parts(members: Sequence[Member]) -> tuple[list[str], list[str]]:
    """The catalogue effects and the grammar terms of ``members`` (a sinusoid's two terms)."""
    return (
        [n for k, n in members if k == "effect"],
        [t for k, n in members if k == "term" for t in n.split("+")],
    )


def _keys_of(members: Sequence[Member]) -> list[str]:
    """The ``EFFECT.PARAMETER`` keys of ``members``' joint effect."""
    joint = model_effect(*_parts(members))
    return [p.name for p in joint.parameters] if joint is not None else []


@dataclass
class _Elimination:
    """What every backward elimination of :func:`open_loop_gate` shares: the data, the folds,
    the robot as given and the rounds' values, how each model is fitted and judged."""

    data: OpenLoopData
    robot: RobotSpec
    proposed: RobotSpec
    options: NuisanceOptions
    folds: Sequence[Sequence[int]]
    start: Mapping[str, SessionNuisance] | None
    lenient: set[str]
    report: Callable[[str, float], None] | None
    filtered: FilterLinearisation | None
    corrected: OpenLoopData | None
    jobs: int = 1
    unidentified: frozenset[str] | None = None
    """The effects judged as not identifiable beside the other robot effects, where given;
    else those whose variance inflation exceeds :data:`MAX_INFLATION` in the model tried
    (:func:`_beside_terms` keeps each effect's rule of the catalogue stage: beside the terms
    the robot's inflation counts their parameters too)."""

    def each(
        self, members: Sequence[Member], call: Callable[[Member], Any], stage: str
    ) -> list[Any]:
        """``call(member)`` for every one of ``members``, in order: side by side in
        ``jobs`` forked worker processes (:func:`odomgym.diagnose.fit.run_forked`) when there
        are several of each, else one after the other; ``stage`` names them in the progress.

        Why: a backward elimination's trials of one pass are independent open-loop fits (on
        the 14 June OptiOdom sessions 12 of them, 27 s on one core), and the gate ran them on
        one core while the rounds used both. Each trial is a deterministic function of the
        members, the model and the data, so where it ran changes no result.

        A trial's fit comes back pickled, effects included, but not the data it was fitted
        on: the gate's own data (:attr:`data`, :attr:`corrected`) travel by reference
        (:func:`_by_reference`), so the fits refer to the very objects a serial pass's would,
        and twelve trials do not bring back twelve copies of every run. Where a worker's trial
        fails — an error in the fit, or a user-registered effect that cannot be pickled (a
        class defined inside a function) — the pass runs again here, one trial after the
        other: the same results, and a real error raised with its own traceback."""
        count = len(members)
        shared = [self.data, self.corrected]

        def serial() -> list[Any]:
            out = []
            for k, member in enumerate(members):
                if self.report is not None:
                    self.report(f"{stage}: {member[1]}", k / count)
                out.append(call(member))
            return out

        if not forks(self.jobs, count):
            return serial()
        if self.report is not None:  # the stage starts (the reports below come as trials end)
            self.report(f"{stage}: {count} trials", 0.0)
        done: dict[int, Any] = {}

        def finished(k: int, blob: bytes) -> None:
            done[k] = _from_reference(blob, shared)
            if self.report is not None:
                self.report(f"{stage}: {members[k][1]}", len(done) / count)

        try:
            run_forked(
                lambda k, attempt: _by_reference(call(members[k]), shared),
                ((k, k) for k in range(count)),
                self.jobs,
                finished,
                lambda k: f"checking {members[k][1]} open loop",
            )
        except TaskFailed:
            return serial()
        return [done[k] for k in range(count)]

    def held_out(self, fit: OpenLoopFit, keys: Sequence[str]) -> tuple[FloatArray, str]:
        """The fold errors of a model by the better of the two estimators: the open-loop fit
        (``fit``) or the filter's, linearised (``filtered``, on ``corrected``)."""
        by_open_loop = cross_validate_open_loop(self.data, fit, self.folds)
        if self.filtered is None or self.corrected is None:
            return by_open_loop, "open loop"
        by_filter = self.filtered.cross_validate(keys, self.corrected, self.folds)
        if np.mean(_fold_means(by_filter, self.folds)) < np.mean(
            _fold_means(by_open_loop, self.folds)
        ):
            return by_filter, "filter"
        return by_open_loop, "open loop"

    def fitted(
        self,
        members: Sequence[Member],
        begin: RobotSpec,
        nuisances: Mapping[str, SessionNuisance] | None,
        base: OpenLoopFit,
    ) -> Scored:
        """``members`` fitted from ``begin`` (never worse than ``base``, :func:`fit_nested`)
        and judged on the folds."""
        joint = model_effect(*_parts(members))
        fit = fit_nested(self.data, begin, joint, self.options, nuisances, base)
        cv, estimator = self.held_out(fit, _keys_of(members))
        return fit, cv, estimator

    def without(self, members: Sequence[Member], current: OpenLoopFit) -> RobotSpec:
        """Where the model without ``members`` starts: the larger model's fit with those
        proposals back at the robot's given values (absent for a robot that carries none) —
        "without" is the robot as given in that respect, as the empty model is the robot as
        given, so the fit of the fixed proposals alone is a point of every model tested
        (:func:`fit_nested`)."""
        effect_names, term_names = _parts(members)
        begin = current.spec
        for e in effect_names:
            begin = EFFECTS[e].write(begin, EFFECTS[e].read(self.robot))
        if term_names:
            chosen = DiscoveredTerms(term_names)
            begin = chosen.write(begin, chosen.read(self.robot))
        return begin

    def trial(
        self,
        member: Member,
        model: Sequence[Member],
        fixed: Sequence[Member],
        current: Scored,
        base: Scored,
    ) -> tuple[GateStep, OpenLoopFit, FloatArray]:
        """``member`` tested against the model without it (the rest of ``model`` and
        ``fixed``): its step, and the smaller model's fit and fold errors."""
        fit, cv, estimator = current
        rest = [*fixed, *(m for m in model if m != member)]
        if len(rest) > len(fixed):
            smaller, smaller_cv, _ = self.fitted(
                rest, self.without([member], fit), fit.nuisances, base[0]
            )
        else:
            smaller, smaller_cv, _ = base  # the model without it is ``fixed`` alone: known
        step = self.judge(member, (fit, cv, estimator), smaller_cv)
        return step, smaller, smaller_cv

    def judge(self, member: Member, larger: Scored, smaller_cv: FloatArray) -> GateStep:
        """``member``'s step: the model with it (``larger``: its fit, fold errors and
        estimator) against the model without it (``smaller_cv``), under its rule."""
        kind, name = member
        fit, cv, estimator = larger
        mean, spread = _fold_difference(cv, smaller_cv, self.folds)
        inflation = _inflation(member, fit)
        confounded = kind == "term" and inflation > MAX_INFLATION
        unidentified = kind == "effect" and (
            inflation > MAX_INFLATION if self.unidentified is None else name in self.unidentified
        )
        lenient = kind == "effect" and name in self.lenient and not unidentified
        if confounded:
            rule = "not identifiable"
        elif lenient:
            rule = "lower"
        else:
            rule = UNIDENTIFIED if unidentified else "one standard error"
        # an unidentified effect must also remove a real share of the folds' error
        real = not unidentified or -mean >= REAL_SIZE * float(
            np.mean(_fold_means(smaller_cv, self.folds))
        )
        return GateStep(
            kind=kind,
            name=name,
            kept=False if confounded else (mean < 0.0 if lenient else mean + spread < 0.0 and real),
            before_mm=1e3 * math.sqrt(float(np.mean(smaller_cv))),
            after_mm=1e3 * math.sqrt(float(np.mean(cv))),
            difference=1e6 * mean,
            stderr=1e6 * spread,
            rule=rule,
            estimator=estimator,
            inflation=inflation,
        )

    def readmit(
        self, candidates: Sequence[Member], model: Sequence[Member], current: Scored
    ) -> tuple[Member, GateStep, Scored] | None:
        """The forward step of a stepwise selection (Efroymson 1960): each removed catalogue
        effect of ``candidates`` fitted back into the kept ``model`` (from ``current``, its fit,
        with the effect at the rounds' values) and judged under its rule against ``current``;
        the one that lowers the folds' error most among those that pass, with its step and the
        larger model's fit, or None.

        Why: backward elimination judges each proposal on the model with every other one, and
        where two of them trade along a ridge (a skid track's excess beside E_b, on data that
        cannot separate them) that model is not identifiable, and its fold refits predict
        badly. The proposal removed first then took the blame for the ridge (on one June
        OptiOdom fold: the diameter ratio, 105 mm with everything against 19 mm without it,
        while the five-effect model of every other fold gives 6 mm)."""
        best: tuple[Member, GateStep, Scored] | None = None
        fit, cv, _ = current
        effects = [m for m in candidates if m[0] == "effect"]

        def refitted(member: Member) -> Scored:
            begin = spec_with(fit.spec, self.proposed, *_parts([member]))
            return self.fitted([*model, member], begin, fit.nuisances, fit)

        for member, larger in zip(
            effects, self.each(effects, refitted, "open-loop check, readmitting"), strict=True
        ):
            step = self.judge(member, larger, cv)
            if step.kept and (best is None or step.difference < best[1].difference):
                best = (member, step, larger)
        return best

    def eliminate(
        self,
        model: list[Member],
        fixed: list[Member],
        base: Scored,
        start: Scored | None = None,
    ) -> tuple[Scored, list[GateStep], list[GateStep]]:
        """Backward elimination of ``model``'s proposals, ``fixed`` always in the model and
        never tested, ``base`` the fit, fold errors and estimator of ``fixed`` alone, ``start``
        the model of both already fitted (else fitted here from the rounds' values); returns
        the final model's, the kept steps and the removed ones (``model`` is left holding the
        kept proposals)."""
        everything = fixed + model
        if start is not None:
            current = start
        elif model:
            current = self.fitted(
                everything,
                spec_with(self.robot, self.proposed, *_parts(everything)),
                self.start,
                base[0],
            )
        else:
            current = base
        removed: dict[Member, GateStep] = {}
        tested: dict[Member, GateStep] = {}
        readmitted: set[Member] = set()
        round_number = 0
        while True:
            while model:
                round_number += 1
                trial = functools.partial(
                    self.trial, model=model, fixed=fixed, current=current, base=base
                )
                results = self.each(model, trial, f"open-loop check {round_number}")
                trials: dict[Member, tuple[GateStep, OpenLoopFit, FloatArray]] = dict(
                    zip(model, results, strict=True)
                )
                for member in model:
                    tested[member] = trials[member][0]
                failing = [
                    m for m in model if not trials[m][0].kept and not _extended(m, fixed + model)
                ]
                if not failing:
                    break
                worst = max(failing, key=lambda m: _removal_order(trials[m][0]))
                removed[worst] = trials[worst][0]
                model.remove(worst)
                smaller = trials[worst][1]
                current = (
                    (smaller, *self.held_out(smaller, _keys_of(fixed + model))) if model else base
                )
            back = self.readmit([m for m in removed if m not in readmitted], fixed + model, current)
            if back is None:
                break
            member, tested[member], current = back
            del removed[member]
            readmitted.add(member)
            model.append(member)
        kept = [_held(tested[m], fixed + model) for m in model]
        return current, kept, list(removed.values())


def _by_reference(value: object, shared: Sequence[object]) -> bytes:
    """``value`` pickled with each of ``shared`` (objects the receiving process holds too: a
    forked worker's parent) written as its index instead of its contents
    (:func:`_from_reference` puts the receiver's own object back)."""
    buffer = io.BytesIO()
    pickler = pickle.Pickler(buffer, protocol=pickle.HIGHEST_PROTOCOL)
    ids = {id(obj): k for k, obj in enumerate(shared) if obj is not None}
    pickler.persistent_id = lambda obj: ids.get(id(obj))  # type: ignore[method-assign]
    pickler.dump(value)
    return buffer.getvalue()


def _from_reference(blob: bytes, shared: Sequence[object]) -> Any:
    """The value :func:`_by_reference` pickled, with ``shared``'s objects put back in place."""
    unpickler = pickle.Unpickler(io.BytesIO(blob))
    unpickler.persistent_load = lambda k: shared[k]  # type: ignore[method-assign]
    return unpickler.load()


def _inflation(member: Member, fit: OpenLoopFit) -> float:
    """The largest variance inflation factor of ``member``'s parameters in the open-loop fit
    of the model with it: a discovered term's by the rest of the model and the sessions'
    nuisances (:attr:`OpenLoopFit.inflation`), a catalogue effect's by the other robot
    effects alone (:attr:`OpenLoopFit.robot_inflation`).

    Why the robot's alone for an effect: an effect may be exactly a measurement nuisance the
    fit also carries (a tracked-point offset against ``gt_sensor_offset``), which the report
    states as a confound with both readings (:mod:`odomgym.diagnose.confounds`); two robot
    effects the data cannot tell apart are one law split in two, and neither reading is the
    robot's. Seen: a turn skid and a speed-dependent track (``skid_speed``), one-sided laws of
    |v·ω| of opposite signs, kept together on a June OptiOdom fold; and a skid track whose
    half-point lies beyond the logged turns, one more constant track factor beside E_b, kept at
    ε 0.05 ± 0.28, λ½ 18 ± 63, E_b 0.97 ± 0.25 on a differential-drive robot carrying a
    yaw-rate scrub (``tests/alien_robot.py``), where the grammar's yaw-rate term could then not
    be identified beside it."""
    kind, name = member
    if kind == "term":
        _, term_names = _parts([member])
        return max(fit.inflation.get(f"{DISCOVERED}.{t}", math.inf) for t in term_names)
    found = [fit.robot_inflation.get(f"{name}.{p.name}") for p in EFFECTS[name].parameters]
    known = [v for v in found if v is not None and not math.isnan(v)]
    return max(known) if known else math.nan


def _extenders(member: Member, members: Sequence[Member]) -> list[str]:
    """The effects of ``members`` that extend ``member``: list it among their
    :attr:`~odomgym.effects.Effect.partners` (``skid_track`` extends ``wheelbase``: its track
    factor is E_b's, changed with the turn radius)."""
    kind, name = member
    if kind != "effect":
        return []
    return [
        other
        for other_kind, other in members
        if other_kind == "effect" and other != name and name in EFFECTS[other].partners
    ]


def _extended(member: Member, members: Sequence[Member]) -> bool:
    """Whether ``member`` may not leave the model yet: an effect of ``members`` extends it
    (:func:`_extenders`). The principle of marginality (Nelder 1977): a model keeps the term an
    extension builds on, as a regression keeps the main effects of an interaction it keeps;
    the extension is tested against the model with its base, and the base against the model
    without both. Tested first beside its extension, the base looks useless where the two trade
    along a ridge (E_b beside a skid track's excess): on one June OptiOdom fold the wheelbase
    and the diameter ratio went first, and the skid track stood in for E_b."""
    return bool(_extenders(member, members))


def _held(step: GateStep, members: Sequence[Member]) -> GateStep:
    """``step`` of a proposal still in the model: as it is, or, for a base that failed its
    rule while an extension of it stayed (:func:`_extended`), kept under the rule that held
    it (``"held by skid_track"``)."""
    if step.kept:
        return step
    extenders = _extenders((step.kind, step.name), members)
    if not extenders:
        return step
    return replace(step, kept=True, rule=f"held by {', '.join(extenders)}")


def _removal_order(step: GateStep) -> tuple[bool, float, float]:
    """Which failing proposal goes first: a term the fit cannot identify (the most inflated),
    else the least useful one (the largest change, a term's counted with its standard error);
    the rest are tested again without it."""
    unidentifiable = step.rule == "not identifiable"
    return (
        unidentifiable,
        step.inflation if unidentifiable else 0.0,
        step.difference + (step.stderr if step.rule != "lower" else 0.0),
    )


def open_loop_gate(
    data: OpenLoopData,
    robot: RobotSpec,
    proposed: RobotSpec,
    effects: Sequence[str],
    terms: Sequence[str],
    options: NuisanceOptions,
    folds: Sequence[Sequence[int]],
    start: Mapping[str, SessionNuisance] | None = None,
    nominal: OpenLoopFit | None = None,
    report: Callable[[str, float], None] | None = None,
    filtered: FilterLinearisation | None = None,
    corrected: OpenLoopData | None = None,
    named: Sequence[str] | None = None,
    order: str = "joint",
    jobs: int = 1,
) -> GateResult:
    """Keep those of ``effects`` and ``terms`` (their values in ``proposed``, the rounds'
    model) that the held-out folds confirm, by backward elimination from all of them on
    ``robot`` (the model as given) (module docstring). ``named``: the effects the rounds named
    (default: all of ``effects``); the others must pass the one-standard-error rule, as terms do.
    ``nominal``: the model as given already fitted (its nuisances) on ``data``; ``start``:
    nuisances to start from; ``filtered`` and ``corrected``: the filter's linearisation and the
    runs it was made on, nuisances removed (without them, the open-loop fit alone). ``order``:
    ``"joint"`` eliminates effects and terms together; ``"catalogue first"`` the catalogue
    effects alone, then the terms with the kept effects fixed (:class:`odomgym.diagnose.config.
    DiagnoseConfig`'s ``gate_order``). ``jobs``: worker processes for each pass's trials
    (:meth:`_Elimination.each`; the same result with any number)."""
    if order not in GATE_ORDERS:
        raise ValueError(f"order must be one of {GATE_ORDERS}, got {order!r}")
    gate = _Elimination(
        data,
        robot,
        proposed,
        options,
        folds,
        start,
        set(effects if named is None else named),
        report,
        filtered,
        corrected,
        jobs,
    )
    effect_members: list[Member] = [("effect", n) for n in effects]
    term_members: list[Member] = [("term", n) for n in term_proposals(terms)]
    nominal_fit = (
        nominal if nominal is not None else fit_open_loop(data, robot, None, options, start)
    )
    nominal_cv, nominal_estimator = gate.held_out(nominal_fit, [])
    as_given: Scored = (nominal_fit, nominal_cv, nominal_estimator)
    if order == "catalogue first":
        # The catalogue effects on their own, then the discovered terms on the model they kept
        # (those effects fixed): a term must earn its place beside the named mechanisms and
        # cannot displace one it merely resembles.
        kept_model, steps, model = _catalogue_first(gate, effect_members, term_members, as_given)
        exchanged = _exchange(gate, kept_model, steps, effect_members, term_members, as_given)
        if exchanged is not None:
            kept_model, steps, model = exchanged
    else:
        model = effect_members + term_members
        kept_model, kept_steps, removed = gate.eliminate(model, [], as_given)
        steps = kept_steps + removed
    effect_names, term_names = _parts(model)
    current, current_cv, _ = kept_model
    return GateResult(
        steps,
        effect_names,
        term_names,
        current,
        current_cv,
        nominal_cv,
        [list(f) for f in folds],
    )


def _catalogue_first(
    gate: _Elimination, effects: Sequence[Member], terms: Sequence[Member], as_given: Scored
) -> tuple[Scored, list[GateStep], list[Member]]:
    """The ``"catalogue first"`` order: ``effects`` eliminated on their own from ``as_given``,
    then ``terms`` on the model they kept, those effects fixed; the final model's fit, every
    step, and the members kept.

    The kept effects are then judged again beside the kept terms (:func:`_beside_terms`). Where
    that removes one, every proposed term is judged again beside the effects left, from the
    model of those effects alone, and the effects once more beside the terms kept then, until
    no effect leaves (each pass removes one at least, so there are at most as many passes as
    effects). Why: a term refused beside an effect that has since left was judged on a model
    that is not the final one (refused as not identifiable beside it, or as adding nothing to
    what it described), and the kept terms' rows would describe a model with it. Where an
    effect left and terms stand, the rows of the effects and terms kept then describe the
    final model, as in a backward elimination; an effect removed in an earlier pass keeps the
    row of its removal and is not offered again. Where no term stands beside the effects left
    (in any pass), nothing describes the error of those that left: the model before the first
    check beside the terms stands, with its rows (the effects judged without terms, the terms
    beside them). Where no effect leaves, the effects' rows are those of the catalogue
    stage."""
    effect_members, term_members = list(effects), list(terms)
    kept_model, kept_effects, removed_effects = gate.eliminate(effect_members, [], as_given)
    judged = list(kept_effects)
    kept_terms: list[GateStep] = []
    removed_terms: list[GateStep] = []
    if term_members:
        kept_model, kept_terms, removed_terms = gate.eliminate(
            term_members, effect_members, kept_model
        )
    before = (kept_model, list(effect_members), list(term_members))
    steps_before = (kept_effects, kept_terms, removed_effects, removed_terms)
    rechecked = _beside_terms(gate, effect_members, term_members, kept_model, as_given, judged)
    while rechecked is not None:
        kept_model, kept_effects, absorbed = rechecked
        removed_effects = removed_effects + absorbed
        effects_alone = _effects_alone(gate, effect_members, kept_model, term_members, as_given)
        term_members = list(terms)
        kept_model, kept_terms, removed_terms = gate.eliminate(
            term_members, effect_members, effects_alone
        )
        if not term_members:
            # No term stands beside the effects left: nothing describes the error of those
            # that left, so the model before the first check beside the terms stands, with its rows
            # (the effects judged without terms, the terms beside them).
            kept_model, effect_members, term_members = before
            kept_effects, kept_terms, removed_effects, removed_terms = steps_before
            break
        rechecked = _beside_terms(
            gate, effect_members, term_members, kept_model, as_given, judged, settled=True
        )
        if rechecked is not None and not rechecked[2]:
            # every effect stays beside the terms judged again: their rows, beside those terms
            kept_model, kept_effects, _ = rechecked
            break
    steps = kept_effects + kept_terms + removed_effects + removed_terms
    return kept_model, steps, effect_members + term_members


def _effects_alone(
    gate: _Elimination,
    effects: Sequence[Member],
    larger: Scored,
    terms: Sequence[Member],
    as_given: Scored,
) -> Scored:
    """The model of ``effects`` alone, where the terms are judged again once an effect has left
    beside them (:func:`_catalogue_first`): fitted from the ``larger`` model (the effects left
    beside ``terms``) with the terms back at the robot's values, and from the rounds' values,
    as the elimination starts; the fit with the smaller error (the former on a tie), never
    worse than ``as_given`` (:func:`fit_nested`). ``as_given`` itself without effects.

    Why two starts: a fit started from a larger model's values, with some set back, can stop
    in another valley than one started afresh (E_b 0.93 at 50 mm against 1.0014 at 2.5 mm,
    :func:`fit_nested`), and a poor fit of the effects alone would make any term look useful
    beside them."""
    if not effects:
        return as_given
    fit = larger[0]
    nested = gate.fitted(effects, gate.without(terms, fit), fit.nuisances, as_given[0])
    afresh = gate.fitted(
        effects, spec_with(gate.robot, gate.proposed, *_parts(effects)), gate.start, as_given[0]
    )
    return afresh if afresh[0].error < nested[0].error else nested


BESIDE_TERMS = "beside the kept terms"
"""The end of the rule of a catalogue effect tested again once the gate has kept discovered
terms (:func:`_beside_terms`): ``"lower beside the kept terms"``."""


def _beside_terms(
    gate: _Elimination,
    effects: list[Member],
    terms: Sequence[Member],
    current: Scored,
    as_given: Scored,
    judged: Sequence[GateStep],
    settled: bool = False,
) -> tuple[Scored, list[GateStep], list[GateStep]] | None:
    """The kept catalogue ``effects`` eliminated again beside the kept discovered ``terms``
    (``current``: the model of both), each under the rule it had in the catalogue stage
    (``judged``, their steps there): the final model's fit, the kept effects' steps and the
    removed ones (their rules ending :data:`BESIDE_TERMS`), or None where every effect stays
    (the steps of the catalogue stage then stand) and ``settled`` is false; None too without
    terms or effects. ``effects`` is left holding the kept ones. ``settled``: the terms were
    already judged again after an effect left (:func:`_catalogue_first`), so the steps are
    returned even where every effect stays, as the rows of the final model.

    Why: in the ``"catalogue first"`` order the effects are judged before any term is in the
    model, and the terms then join with them fixed, so nothing asked whether an effect still
    earns its place beside the terms. A backward elimination's every proposal must pass its
    rule in the final model, as the rounds' backward check asks of the filter's likelihood.
    On differential-drive robots carrying effects outside the catalogue
    (``tests/alien_robot.py``, ``benchmarks/bench_discover.py``) a speed-dependent skid track
    (``skid_speed``) was named beside the terms that describe the mechanism and predicted
    nothing more: beside ``left_speed`` and ``right_speed`` (a wheel radius that shrinks with
    speed; 1.74 → 1.72 mm held out without it) and beside ``yaw_rate`` (a spin that scrubs;
    1.82 → 1.80 mm). Each effect keeps its rule of the catalogue stage — ``"lower"`` for one
    the rounds named, and identified or not as it was among the effects (beside the terms the
    robot's variance inflation counts their parameters too) — so a term that resembles a
    mechanism cannot displace it unless the mechanism makes the predictions worse.

    Once an effect leaves, :func:`_catalogue_first` judges the terms again beside the effects
    left."""
    if not terms or not effects:
        return None
    fit = current[0]
    base = gate.fitted(list(terms), gate.without(effects, fit), fit.nuisances, as_given[0])
    if fit.error > base[0].error:
        # Fitted from the effects alone, the model of both may have stopped above the terms
        # alone, a point of it: fitted again, never worse than the smaller model (fit_nested).
        current = gate.fitted([*effects, *terms], fit.spec, fit.nuisances, base[0])
    model = list(effects)
    rules = replace(gate, unidentified=frozenset(s.name for s in judged if s.rule == UNIDENTIFIED))
    final, kept, removed = rules.eliminate(model, list(terms), base, current)
    if not removed and not settled:
        return None
    effects[:] = model

    def marked(step: GateStep) -> GateStep:
        held = step.rule.startswith("held by")
        return step if held else replace(step, rule=f"{step.rule} {BESIDE_TERMS}")

    return final, [marked(s) for s in kept], [marked(s) for s in removed]


def _exchange(
    gate: _Elimination,
    kept_model: Scored,
    steps: Sequence[GateStep],
    effects: Sequence[Member],
    terms: Sequence[Member],
    as_given: Scored,
) -> tuple[Scored, list[GateStep], list[Member]] | None:
    """The gate run again on the proposed ``effects`` and ``terms`` without a kept effect the
    open-loop fit cannot tell from the other robot effects (its rule :data:`UNIDENTIFIED`, as
    judged among the effects; the most inflated by :func:`_inflation`) or, failing one,
    without an extension kept beside its base, where a discovered term was refused as not
    identifiable beside it; that model, its steps and its members if it predicts the folds
    better than ``kept_model`` (for an identified extension: by more than one standard error
    of the folds' differences), else None.

    Why: a skid track whose half-point lies beyond the logged turns is one more constant track
    factor beside E_b (variance inflation above :data:`MAX_INFLATION`), and once it is in the
    model a discovered term that describes the same yaw can no longer be identified. On a
    differential-drive robot carrying a yaw-rate scrub (outside the catalogue,
    ``tests/alien_robot.py``) the first round named the skid track (ε 0.04, λ½ 15), the gate
    kept it beside the wheelbase at ε 0.05 ± 0.28, λ½ 18 ± 63, and refused the yaw-rate term
    (VIF ∞): held-out heading error 4.17°, against 0.13° for the wheelbase with that term.
    Where no term competes, an unidentified effect that predicts better by a standard error
    and a real size stays, and the report's confounds say that its values are not determined
    (a skid track at 5 × its detection limit, whose shape the rich protocol does not
    resolve). The exchange of one
    member for another is the replacement step of stepwise selection (Miller 2002, *Subset
    Selection in Regression*, 2nd ed., chapter 3: sequential replacement).

    An identified extension is tried too (since stop 74): on a differential-drive robot whose
    wheels shrink with speed (``benchmarks/bench_discover.py``, seed 7802) the skid track was
    kept beside the wheelbase at ε 0.025 ± 0.41 (variance inflation 2·10⁵, below the bound),
    and every speed term was then refused as not identifiable (VIF ∞). Without it the gate
    keeps the wheelbase with the two wheels' speed² terms: 21.2 mm held out against 30.9 mm
    (the gate run after a tie), better by more than a standard error. The stricter margin is
    the rule a term passes: an effect the fit identifies is replaced only by clearly better
    terms, and only by a model that keeps a term it had blocked (else it blocked nothing)."""
    blocked_terms = {
        s.name for s in steps if s.kind == "term" and not s.kept and s.rule == "not identifiable"
    }
    kept = {s.name for s in steps if s.kind == "effect" and s.kept}
    own = [s for s in steps if s.kind == "effect" and s.kept and not s.rule.startswith("held by")]
    # Unidentified as among the effects (its rule), not by the inflation beside kept terms,
    # whose parameters count there too (:func:`_beside_terms`).
    weak = [s for s in own if s.rule.startswith(UNIDENTIFIED)]
    # An extension kept beside its base, identified or not: its excess trades with the base's
    # value along a ridge (a skid track's ε against E_b), which a term then cannot join.
    ridge = [s for s in own if set(EFFECTS[s.name].partners) & kept]
    if not blocked_terms or not (weak or ridge):
        return None

    def order(step: GateStep) -> tuple[bool, float]:
        # Marginality (Nelder 1977): of a pair that is one law split in two, an extension
        # goes before the base it builds on (a skid track before E_b), then the most inflated.
        return bool(set(EFFECTS[step.name].partners) & kept), step.inflation

    extension = max(weak or ridge, key=order)
    member: Member = ("effect", extension.name)
    beside = [p for p in EFFECTS[extension.name].partners if ("effect", p) in effects]
    others = [m for m in effects if m != member]
    alternative, alt_steps, alt_model = _catalogue_first(gate, others, terms, as_given)
    mean, spread = _fold_difference(kept_model[1], alternative[1], gate.folds)
    # An effect the fit cannot identify goes for any better model; one it can identify only
    # for a model better by a standard error of the folds, the rule every term passes.
    if not (mean > 0.0 if weak else mean - spread > 0.0):
        return None
    if not weak and not any(
        s.kept and s.name in blocked_terms for s in alt_steps if s.kind == "term"
    ):
        return None
    rule = "not identifiable beside" if weak else BLOCKING
    refused = replace(
        extension,
        kept=False,
        before_mm=1e3 * math.sqrt(float(np.mean(alternative[1]))),
        after_mm=1e3 * math.sqrt(float(np.mean(kept_model[1]))),
        difference=1e6 * mean,
        stderr=1e6 * spread,
        rule=f"{rule} {', '.join(beside) or 'the other effects'}",
    )
    return alternative, [*alt_steps, refused], alt_model


BLOCKING = "blocked the terms beside"
"""The start of the rule of an extension kept beside its base, identified, and exchanged for
the terms it blocked (:func:`_exchange`): ``"blocked the terms beside wheelbase"``."""


@dataclass
class SystematicFit:
    """The kept systematic model's parameters by one estimator, and how well its fold refits
    predict the folds they left out.

    Attributes:
        estimator: ``"filter"`` (generalised least squares on the Kalman filter's whitened
            innovations: efficient when the noise model is right) or ``"open loop"`` (least
            squares on the open-loop error itself: what the held-out comparison measures, and
            robust to a noise model that is wrong — on a real robot's logs the filter's E_d
            predicted the held-out sessions worse than nominal, the open-loop one 3× better).
        spec: the robot with the fitted values.
        entries: ``{"EFFECT.PARAMETER": {value, stderr, stderr_runs, stderr_sessions}}``.
        cv_error: each fit run's held-out mean square combined open-loop error [m²].
    """

    estimator: str
    spec: RobotSpec
    entries: dict[str, dict[str, float]]
    cv_error: FloatArray

    def fold_error(self, folds: Sequence[Sequence[int]]) -> float:
        """Mean over the folds of their mean square error [m²] (folds weigh equally)."""
        return float(np.mean(_fold_means(self.cv_error, folds)))

    def better_than(self, other: SystematicFit, folds: Sequence[Sequence[int]]) -> bool:
        """Whether this fit predicts the left-out folds better than ``other`` by more than one
        standard error of the folds' paired differences (one fold: never)."""
        mean, spread = _fold_difference(self.cv_error, other.cv_error, folds)
        return mean + spread < 0.0


def _quoted(by_session: float, by_run: float) -> float:
    """The standard error to quote: session-clustered where there are sessions, else
    run-clustered (errors along a run are correlated; model-based ones are far too small)."""
    return by_session if math.isfinite(by_session) else by_run


def open_loop_estimate(fit: OpenLoopFit, cv_error: FloatArray) -> SystematicFit:
    """The open-loop fit as a :class:`SystematicFit` (its cross-validated errors given)."""
    entries = {
        key: {
            "value": value,
            "stderr": _quoted(fit.stderr_sessions.get(key, math.nan), fit.stderr_runs[key]),
            "stderr_runs": fit.stderr_runs.get(key, math.nan),
            "stderr_sessions": fit.stderr_sessions.get(key, math.nan),
        }
        for key, value in fit.values.items()
    }
    return SystematicFit("open loop", fit.spec, entries, cv_error)


def filter_estimate(
    data: Dataset,
    start: Model,
    effect: Effect,
    nuisance: Effect | None,
    open_data: OpenLoopData,
    folds: Sequence[Sequence[int]],
    base: RobotSpec,
) -> SystematicFit:
    """``effect`` fitted by the filter (:func:`odomgym.diagnose.fit.fit_candidate`, the wheel
    noise ``nuisance`` beside it) from ``start`` on ``data``, and cross-validated open loop:
    each fold's parameters one Gauss–Newton step on the whitened system without it, its runs
    (``open_data``: the same runs, nuisances removed) replayed open loop. The values are
    written onto ``base`` (the nuisance's fitted wheel noise is not a finding)."""
    fit = fit_candidate(data, start.spec, start.sensor, effect, nuisance)
    u0, _, _, build = systematic_vector(fit.spec, effect)
    cv = np.empty(len(data))
    for fold in folds:
        held = set(fold)
        train = [j for j in range(len(data)) if j not in held]
        step = np.zeros(len(u0))
        # A fold holding every run (one fit run per experiment family: every family's block
        # falls in the last fold) leaves nothing to step on: its parameters stay at the full
        # fit, as the open-loop fold step leaves columns no training run touches.
        if train:
            a = np.sum([fit.jacobian[j].T @ fit.jacobian[j] for j in train], axis=0)
            b = np.sum([fit.jacobian[j].T @ fit.whitened[j] for j in train], axis=0)
            step = gauss_newton_step(a, b)
        cv[list(fold)] = run_errors(
            open_data.subset(list(fold)), build_within(build, np.zeros(len(step)), step)
        )
    spec = effect.write(base, fit.values)
    entries = {}
    for key, value in fit.values.items():
        entry = fit.entry(key, value)
        entry["stderr"] = _quoted(entry["stderr_sessions"], entry["stderr"])
        entries[key] = entry
    return SystematicFit("filter", spec, entries, cv)

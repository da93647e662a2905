"""The discrepancy workflow: where the model and the robot disagree, which effect is missing,
add it, and show on data the fit never saw that the updated model predicts the robot better.

:func:`diagnose` takes logged runs (any source: :mod:`odomgym.data`) and a robot model and returns
a :class:`Diagnosis`. The steps (``docs/diagnose.md`` gives each in full):

1. **Split** (:func:`split_runs`): whole sessions are held out, or with one session, per
   experiment family a contiguous block of runs in time. Nothing is fitted on them.
2. **Measurement nuisances** (:mod:`odomgym.diagnose.nuisances`): each session's time offset
   (and, with several sessions, tracked point and yaw misalignment), fitted open loop jointly
   with E_d, E_b, E_s (:mod:`odomgym.diagnose.openloop`) and removed from the runs.
3. **Where** (:mod:`odomgym.diagnose.where`) the model as given disagrees.
4. **Rounds** (:func:`run_round`): catalogue effects scored by the Kalman filter's
   cross-validated likelihood and tested family-wise (:mod:`odomgym.diagnose.fit`); when the
   catalogue leaves structure, sparse discovery over the error grammar
   (:mod:`odomgym.diagnose.discover`); the noise model last; a backward check.
5. **Physical sizes** (:mod:`odomgym.diagnose.physical`): a discovered term too large for what
   the robot did is a stand-in, reported and not kept.
6. **The open-loop gate** (:mod:`odomgym.diagnose.gate`): each proposal in turn is kept only if
   it lowers the error of predicting left-out folds (sessions, or blocks) open loop.
7. **The estimator** of the kept model's values — the filter's, unless the open-loop fit's
   predicts the left-out folds better by one standard error.
8. **Noise effects**: floor bumps only with their signature and a size the floor can produce;
   how far a noise effect with a mean part moved E_d, E_b, E_s is reported.
9. **Held-out verdict** (:mod:`odomgym.diagnose.heldout`): the held-out runs predicted open loop
   by the model as given, the diagnosed model and a baseline calibration, in mm and degrees —
   the headline; the grammar's score test and a whiteness test on the held-out runs decide
   ``explained`` / ``partly explained``; a model that does not predict the held-out runs better
   than the model as given, or proposals of which the open-loop gate kept none, are
   ``unconfirmed``. The whitened gap stays as a diagnostic.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import pickle
import shutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym import interrupt
from odomgym.diagnose.discover import (
    Discovery,
    StructureTest,
    channel_evidence,
    discover,
    library_jacobian,
    structure_test,
    term_sentence,
)
from odomgym.diagnose.experiments import separating_experiment
from odomgym.diagnose.fit import (
    CandidateFit,
    Dataset,
    FitJob,
    Joint,
    Model,
    candidate_effects,
    cross_validate,
    evaluate,
    fit_candidate,
    fit_noise,
    fit_noise_model,
    folds_for,
    run_fit_jobs,
    strata,
)
from odomgym.diagnose.gate import (
    FilterLinearisation,
    GateResult,
    GateStep,
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
from odomgym.diagnose.likelihood import (
    SensorNoise,
    expected_square_gap,
    measurement_mask,
    run_likelihood,
)
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
from odomgym.diagnose.replay import replay_run
from odomgym.diagnose.stats import (
    bootstrap_ci,
    combine_bonferroni,
    likelihood_ratio,
    lr_test,
    max_t_test,
    reducible_fraction,
    rms,
    whiteness_p,
)
from odomgym.diagnose.where import Finding, localise, run_residuals
from odomgym.effects import EFFECTS, TERMS, DiscoveredTerms, Effect
from odomgym.errors import SpecError
from odomgym.io import atomic_write_bytes
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

NUISANCE = "floor_roughness"
"""The noise effect fitted as a nuisance beside every systematic candidate (see the module
docstring, step 3)."""

DISCOVERED = "discovered"
"""The grammar's effect: never a catalogue candidate, only the discovery pass adds to it."""

GEOMETRY = ("wheel_diameter_ratio", "wheelbase", "distance_scale")
"""The catalogue's geometric effects (E_d, E_b, E_s): fitted beside the measurement nuisances,
the baseline's parameters."""

FloatArray = NDArray[np.float64]
GAP_METRIC = (
    "root-mean-square whitened innovation of the held-out runs (runs weighted equally): each "
    "run's logged wheel motions are replayed through the model and its disagreement with the "
    "measured poses is Kalman-filtered under the model's noise effects and the last fitted "
    "sensor noise; every innovation is divided by its predicted standard deviation. A model "
    "that explains the data gives 1 (the noise floor); a missing effect makes it larger. "
    "gap_position_mm, gap_heading_deg and gap_open_loop_sigma give the plain (unfiltered) "
    "disagreement over every measured sample after the first"
)


@dataclass(frozen=True)
class DiagnoseConfig:
    """Settings of :func:`diagnose`.

    Attributes:
        holdout: fraction of runs held out for the gap report (0 < holdout < 1).
        seed: seeds the split, the folds and the sign-flip tests.
        alpha: bound on the false-alarm rate of the verdict on data the model explains: half
            goes to the selection test (family-wise over the candidates), half to the
            whiteness test behind ``unexplained`` (Bonferroni over the two).
        max_rounds: most effects added one after the other.
        checkpoint_interval: least time between two samples entering the likelihood [s]
            (dense ground truth is thinned; its sensor noise is then closer to white).
        folds: most cross-validation folds.
        candidates: effect names to consider (default: the whole catalogue).
        initial_sensor: starting guess of the sensor noise (position [m], heading [rad]).
        tie_nats: candidates whose held-out log-likelihood gains differ by less than this
            [nats] are tied (2·3 = 6 on the deviance scale: below "strong" evidence in Kass &
            Raftery 1995, §3.2).
        jobs: worker processes fitting candidates side by side (results do not depend on it).
        session_frames: fit a tracked-point offset and a yaw misalignment per session
            (:mod:`odomgym.diagnose.sessions`); None: when the runs come from two or more
            sessions (``Run.meta["session"]``).
        discover: run the discovery pass (:mod:`odomgym.diagnose.discover`) when the catalogue
            leaves structure.
        time_offset: fit each session's time offset between the encoder log and the ground
            truth (:mod:`odomgym.diagnose.nuisances`; needs dense ground truth).
        max_time_offset: the largest time offset searched [s].
        max_obstacle: the largest obstacle the floor is assumed to hold [m] — the bound on
            what named floor bumps may do (:mod:`odomgym.diagnose.physical`).
        max_bump_rate: the most obstacle crossings per metre of a wheel's travel the floor is
            assumed to hold [1/m].
    """

    holdout: float = 0.3
    seed: int = 0
    alpha: float = 0.05
    max_rounds: int = 8
    checkpoint_interval: float = 0.25
    folds: int = 10
    candidates: tuple[str, ...] | None = None
    initial_sensor: tuple[float, float] = (0.002, 0.005)
    tie_nats: float = 3.0
    jobs: int = 1
    discover: bool = True
    session_frames: bool | None = None
    time_offset: bool = True
    max_time_offset: float = 1.0
    max_obstacle: float = 0.02
    max_bump_rate: float = 1.0

    def __post_init__(self) -> None:
        if not 0.0 < self.holdout < 1.0:
            raise SpecError(f"holdout must lie in (0, 1), got {self.holdout!r}", field="holdout")
        if not 0.0 < self.alpha < 1.0:
            raise SpecError(f"alpha must lie in (0, 1), got {self.alpha!r}", field="alpha")
        if not 0.0 < self.max_time_offset <= 10.0:
            raise SpecError(
                f"max_time_offset must lie in (0, 10] s, got {self.max_time_offset!r}",
                field="max_time_offset",
            )
        if not 0.0 < self.max_obstacle <= 1.0:
            raise SpecError(
                f"max_obstacle must lie in (0, 1] m, got {self.max_obstacle!r}",
                field="max_obstacle",
            )
        if not 0.0 < self.max_bump_rate <= 100.0:
            raise SpecError(
                f"max_bump_rate must lie in (0, 100] per metre, got {self.max_bump_rate!r}",
                field="max_bump_rate",
            )
        if self.max_rounds < 1 or self.folds < 2:
            raise SpecError("max_rounds must be >= 1 and folds >= 2", field="max_rounds")
        for name in self.candidates or ():
            if name not in EFFECTS:
                raise SpecError(
                    f"unknown effect {name!r}; known: {', '.join(EFFECTS)}", field="candidates"
                )


@dataclass
class Candidate:
    """One candidate of one round."""

    round: int
    stage: str  # "mean" (systematic effects) or "noise"
    name: str
    values: dict[str, float]
    stderr: dict[str, float]
    cv_gain: float  # held-out log-likelihood gain over the current model, all fit runs [nats]
    cv_improvement: float  # the same per run [nats]
    lr: float  # in-sample likelihood-ratio statistic 2·Δℓ
    p_family: float  # its χ² p-value, Bonferroni-corrected over the candidates
    t: float  # studentised mean of the per-run held-out gains
    p_sign_flip: float  # family-wise max-T sign-flip p-value of t (robustness across runs)
    significant: bool

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class Round:
    """One round of Which/Add."""

    number: int
    verdict: str
    winner: str | None
    tied: list[str]
    separating: dict[str, Any] | None
    candidates: list[Candidate]
    consistency_p: float
    structure: dict[str, Any] | None = None


@dataclass
class Diagnosis:
    """What :func:`diagnose` found (``as_dict`` is ``report.json``).

    The headline is :attr:`held_out`: the open-loop prediction of the held-out runs (whole
    sessions when there are several) by the model as given, the diagnosed model and a baseline
    calibration, in mm and degrees (:mod:`odomgym.diagnose.heldout`). The whitened gap
    (``gap_*``) is a diagnostic of the noise model beside it.
    """

    verdict: str
    named_effects: list[str]
    parameters: dict[str, dict[str, dict[str, float]]]
    initial: RobotSpec
    model: RobotSpec
    sensor: SensorNoise
    gap_before: float
    gap_after: float
    gap_ci: dict[str, list[float]]
    noise_floor: float
    fraction_closed: float
    fraction_ci: list[float]
    rounds: list[Round]
    candidates: list[Candidate]
    findings: list[Finding]
    fit_runs: list[str]
    holdout_runs: list[str]
    held_out: HeldOut | None = None
    holdout_gaps: dict[str, list[float]] = field(default_factory=dict)
    physical: dict[str, list[float]] = field(default_factory=dict)
    discovered: list[dict[str, Any]] = field(default_factory=list)
    discovery: list[dict[str, Any]] = field(default_factory=list)
    final_test: dict[str, Any] = field(default_factory=dict)
    nuisances: list[SessionNuisance] = field(default_factory=list)
    gate: list[GateStep] = field(default_factory=list)
    stand_ins: list[dict[str, Any]] = field(default_factory=list)
    noise_checks: dict[str, dict[str, Any]] = field(default_factory=dict)
    geometry_check: dict[str, dict[str, Any]] = field(default_factory=dict)
    filter_parameters: dict[str, dict[str, float]] = field(default_factory=dict)
    estimators: dict[str, Any] = field(default_factory=dict)
    terms_tried: int = 0

    @property
    def systematic_effects(self) -> list[str]:
        """The named catalogue effects that move the mean (in the order named)."""
        return [n for n in self.named_effects if not EFFECTS[n].noise]

    @property
    def noise_model(self) -> list[str]:
        """The named noise effects (zero-mean; named only once no systematic structure is left)."""
        return [n for n in self.named_effects if EFFECTS[n].noise]

    def as_dict(self) -> dict[str, Any]:
        """The JSON report (``report.json``): the held-out open-loop comparison first."""
        return {
            "verdict": self.verdict,
            "held_out_open_loop": self.held_out.as_dict() if self.held_out else None,
            "systematic_effects": self.systematic_effects,
            "discovered": self.discovered,
            "noise_model": self.noise_model,
            "named_effects": self.named_effects,
            "parameters": self.parameters,
            "measurement_nuisances": [n.as_dict() for n in self.nuisances],
            "open_loop_check": [step.as_dict() for step in self.gate],
            "terms_tried": self.terms_tried,
            "terms_kept": len(self.discovered),
            "stand_ins": self.stand_ins,
            "noise_checks": self.noise_checks,
            "geometry_with_and_without_noise": self.geometry_check,
            "filter_parameters": self.filter_parameters,
            "estimator": self.estimators,
            "gap_metric": GAP_METRIC,
            "gap_before": self.gap_before,
            "gap_after": self.gap_after,
            "gap_ci": self.gap_ci,
            "noise_floor": self.noise_floor,
            "fraction_of_reducible_gap_closed": self.fraction_closed,
            "fraction_ci": self.fraction_ci,
            "sensor_noise": {"position": self.sensor.position, "heading": self.sensor.heading},
            "candidates": [c.as_dict() for c in self.candidates],
            "rounds": [
                {
                    "round": r.number,
                    "verdict": r.verdict,
                    "winner": r.winner,
                    "tied": r.tied,
                    "separating_experiment": r.separating,
                    "consistency_p": r.consistency_p,
                    "structure": r.structure,
                }
                for r in self.rounds
            ],
            "final_test": self.final_test,
            "discovery": self.discovery,
            "where": [f.as_dict() for f in self.findings],
            "fit_runs": self.fit_runs,
            "holdout_runs": self.holdout_runs,
            "holdout_gaps": self.holdout_gaps,
            **{key: {"before": v[0], "after": v[1]} for key, v in self.physical.items()},
            "model": self.model.to_dict(),
        }


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


def _consistency(data: Dataset, model: Model) -> float:
    """p-value that ``model``'s whitened innovations on ``data`` are white noise
    (:func:`odomgym.diagnose.stats.whiteness_p`: per-run means and pooled lag-1 correlation,
    Bonferroni-combined)."""
    ev = evaluate(data, model.spec, model.sensor)
    return whiteness_p(ev.whitened, data.masks)


def _gaps(
    runs: Sequence[Run], spec: RobotSpec, sensor: SensorNoise, interval: float
) -> dict[str, FloatArray]:
    """Per run: mean square of the whitened innovations (:data:`GAP_METRIC`), and of the open-loop
    disagreement (position [m²], heading [rad²], normalised by the sensor σ, and what noise
    alone predicts for the normalised one)."""
    keys = ("whitened", "position", "heading", "normalised", "floor")
    out = {k: np.empty(len(runs)) for k in keys}
    for j, run in enumerate(runs):
        rep = replay_run(run, spec)
        filtered = run_likelihood(
            run, rep, spec, sensor, measurement_mask(run, interval), gaussian_jumps=True
        )
        out["whitened"][j] = float(filtered.whitened @ filtered.whitened) / max(filtered.count, 1)
        measured: NDArray[np.bool_] = np.asarray(np.isfinite(run.true_pose[:, :2]).all(axis=1))
        measured[np.flatnonzero(measured)[0]] = False
        d = run.true_pose[measured] - rep.tracked[measured]
        heading = np.mod(d[:, 2] + math.pi, 2 * math.pi) - math.pi
        has_heading = np.isfinite(heading)
        pos2 = np.sum(d[:, :2] ** 2, axis=1)
        head2 = np.where(has_heading, heading**2, 0.0)
        mask = np.zeros_like(run.true_pose, dtype=bool)
        mask[measured] = True
        expected = expected_square_gap(run, rep, spec, sensor, mask)[measured]
        sp2, sh2 = sensor.position**2, sensor.heading**2
        dims = 2.0 + has_heading
        out["position"][j] = float(np.mean(pos2))
        out["heading"][j] = float(np.mean(head2[has_heading])) if has_heading.any() else 0.0
        out["normalised"][j] = float(np.mean((pos2 / sp2 + head2 / sh2) / dims))
        out["floor"][j] = float(
            np.mean((expected[:, 0] / sp2 + np.where(has_heading, expected[:, 1], 0) / sh2) / dims)
        )
    return out


class FitJournal:
    """The candidate fits a diagnosis has finished, one file each, so that an interrupted
    diagnosis (``odomgym diagnose --resume``) goes on where it stopped.

    A fit is a deterministic function of its job (the fit runs, the current model and sensor
    noise, the candidate's and nuisance's names, the folds), so a fit is stored under the
    SHA-256 of the pickled job and odomgym's version, and a resumed diagnosis is identical to
    an uninterrupted one (tests/test_bench_resume.py). Each file is written whole (a temporary
    file renamed). A changed dataset or setting only misses the stored fits. The files are
    pickles: resume only from a journal you wrote. An effect is known by its name: after
    changing the code of an effect you registered, start afresh rather than resume.
    """

    def __init__(self, folder: str | Path, *, resume: bool = False) -> None:
        self.folder = Path(folder)
        self.reused = 0
        if not resume:
            self.clear()

    def key(self, job: FitJob) -> str:
        """The file name of ``job``'s fit: the hash of its :meth:`FitJob.key_parts`."""
        from odomgym import __version__

        return hashlib.sha256(pickle.dumps((__version__, job.key_parts()), protocol=5)).hexdigest()

    def get(self, key: str) -> CandidateFit | None:
        """The stored fit, or ``None`` (none stored, or a file that does not load)."""
        path = self.folder / f"{key}.pkl"
        try:
            fit = pickle.loads(path.read_bytes())
        except FileNotFoundError:
            return None
        except Exception:  # a damaged entry (any unpickling error) is refitted, not fatal
            path.unlink(missing_ok=True)
            return None
        if not isinstance(fit, CandidateFit):
            return None
        self.reused += 1
        return fit

    def record(self, key: str, fit: CandidateFit) -> None:
        atomic_write_bytes(self.folder / f"{key}.pkl", pickle.dumps(fit, protocol=5))

    def clear(self) -> None:
        """Forget every stored fit (after a finished diagnosis, or at a fresh start)."""
        shutil.rmtree(self.folder, ignore_errors=True)


@dataclass(frozen=True)
class RoundContext:
    """What every round of Which/Add shares: fixed once the runs are split and the folds drawn.

    Attributes:
        data: the fit runs.
        folds: cross-validation folds (indices into ``data``).
        nuisance: the wheel-noise effect fitted beside every systematic candidate
            (:data:`NUISANCE`; None if it is not registered).
        stages: the candidate stages of a round in order — (stage name, effect names, the
            nuisance fitted beside them) — module docstring, step 3.
        config: the settings.
        rng: the workflow's random stream (it drew the split and the folds; the max-T tests
            continue it, so a round's numbers depend on the rounds before it, as they always
            have).
        report: progress callback; also where a swallowed stop request is raised.
        journal: where finished candidate fits are stored and found (None: nowhere).
    """

    data: Dataset
    folds: list[list[int]]
    nuisance: Effect | None
    stages: list[tuple[str, list[str], Effect | None]]
    config: DiagnoseConfig
    rng: np.random.Generator
    report: Callable[[str, float], None]
    journal: FitJournal | None = None


@dataclass
class DiagnosisState:
    """What the rounds have found so far; :func:`run_round` updates it.

    Attributes:
        model: the current model (robot with the effects added so far, fitted sensor noise).
        before_discovery: the robot model before the first discovered term joined (what the
            discovered terms' evidence is shown against).
        named: the catalogue effects named, in the order first named.
        parameters: each named effect's parameters, ``{effect: {parameter: entry}}``
            (:meth:`odomgym.diagnose.fit.CandidateFit.entry`).
        passes: every discovery pass.
        rounds: every finished round.
    """

    model: Model
    before_discovery: RobotSpec
    named: list[str] = field(default_factory=list)
    parameters: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    passes: list[Discovery] = field(default_factory=list)
    rounds: list[Round] = field(default_factory=list)

    @property
    def candidates(self) -> list[Candidate]:
        """Every candidate scored, round after round."""
        return [c for r in self.rounds for c in r.candidates]


def _score_candidates(
    ctx: RoundContext,
    effects: Sequence[Effect],
    base: Model,
    nuisance: Effect | None,
    where: tuple[int, str],
) -> tuple[list[Candidate], list[CandidateFit]]:
    """Fit, cross-validate and test ``effects`` against the current model ``base`` (in round and
    stage ``where``): each candidate's likelihood-ratio test (Bonferroni over ``effects``), its
    held-out gain, and the max-T sign-flip test over runs."""
    number, stage = where
    data, cfg, journal = ctx.data, ctx.config, ctx.journal
    spec, sensor = base.spec, base.sensor
    current = CandidateFit(
        "(current model)", spec, sensor, {}, evaluate(data, spec, sensor, whitened=False).loglik
    )
    base_cv = cross_validate(data, current, None, ctx.folds)
    jobs = [
        FitJob(
            data, base, e.name, nuisance.name if nuisance and nuisance is not e else None, ctx.folds
        )
        for e in effects
    ]
    keys = [journal.key(job) for job in jobs] if journal is not None else []
    stored = {k: journal.get(keys[k]) for k in range(len(jobs))} if journal is not None else {}
    done = {k: fit for k, fit in stored.items() if fit is not None}

    def finished(k: int, fit: CandidateFit) -> None:
        if journal is not None:
            journal.record(keys[k], fit)
        done[k] = fit
        ctx.report(f"round {number}: {effects[k].name}", len(done) / len(effects))

    # Each fit is recorded as soon as it is done, in whatever order they finish.
    todo = {k: jobs[k] for k in range(len(jobs)) if k not in done}
    run_fit_jobs(todo, cfg.jobs, finished)
    fits = [done[k] for k in range(len(jobs))]
    improvements = np.array([f.cv_loglik - base_cv for f in fits])
    t, p_flip = max_t_test(improvements, ctx.rng)
    candidates = []
    for k, f in enumerate(fits):
        lr = likelihood_ratio(float(np.sum(f.loglik - current.loglik)))
        dof = len(EFFECTS[f.name].parameters) + sum(
            len(EFFECTS[p].parameters) for p in EFFECTS[f.name].partners
        )
        p_family = lr_test(lr, dof, len(fits))
        gain = float(improvements[k].sum())
        candidates.append(
            Candidate(
                round=number,
                stage=stage,
                name=f.name,
                values=f.values,
                stderr=f.stderr,
                cv_gain=gain,
                cv_improvement=float(improvements[k].mean()),
                lr=lr,
                p_family=p_family,
                t=float(t[k]),
                p_sign_flip=float(p_flip[k]),
                significant=bool(p_family < 0.5 * cfg.alpha and gain > 0.0),
            )
        )
    return candidates, fits


def _refit_named(
    data: Dataset,
    model: Model,
    named: Sequence[str],
    parameters: dict[str, dict[str, dict[str, float]]],
    nuisance: Effect | None,
) -> RobotSpec:
    """Every named systematic effect refitted jointly (``fit.Joint``; the wheel noise as
    nuisance beside them) once a second one has joined: each keeps its own share, not what it
    absorbed while it was alone. ``parameters`` takes the joint values and standard errors."""
    systematic = [EFFECTS[n] for n in named if not EFFECTS[n].noise]
    if len(systematic) < 2:
        return model.spec
    joint = Joint(systematic)
    fit = fit_candidate(data, model.spec, model.sensor, joint, nuisance)
    for name, values in joint.split(fit.values).items():
        parameters[name] = {key: fit.entry(f"{name}.{key}", value) for key, value in values.items()}
    return joint.write(model.spec, fit.values)


def _backward_check(data: Dataset, model: Model, named: Sequence[str], alpha: float) -> list[str]:
    """Named systematic effects that the final model no longer needs: the likelihood-ratio test
    of the final model against it without the effect (sensor noise refitted) does not pass α/2
    after a Bonferroni correction over the named effects."""
    spec, sensor = model.spec, model.sensor
    systematic = [n for n in named if not EFFECTS[n].noise]
    if len(systematic) + (1 if spec.effect_values(DISCOVERED) else 0) < 2:
        return []
    full = float(evaluate(data, spec, sensor, whitened=False).loglik.sum())
    out = []
    for name in systematic:
        effect = EFFECTS[name]
        reduced, reduced_sensor, _ = fit_noise(
            data, effect.write(spec, effect.absent_values()), sensor
        )
        without = float(evaluate(data, reduced, reduced_sensor, whitened=False).loglik.sum())
        p = lr_test(likelihood_ratio(full - without), len(effect.parameters), len(systematic))
        if p >= 0.5 * alpha:
            out.append(name)
    return out


def _discovery_record(passes: Sequence[Discovery]) -> list[dict[str, Any]]:
    """Every discovery pass for ``report.json`` (empty if the structure never called for one)."""
    return [
        {
            "structure": found.structure.as_dict(),
            "threshold": found.threshold,
            "cv_sse_by_threshold": found.cv_path,
            "selected": found.selected,
            "rejected": found.rejected,
            "kept": found.terms,
            "cv_gain": found.cv_gain,
            "not_identifiable": found.dropped,
        }
        for found in passes
    ]


ROUND_GOES_ON = ("explained", "discovered")
"""Round verdicts after which another round follows (something joined the model)."""


def run_round(number: int, ctx: RoundContext, state: DiagnosisState) -> Round:
    """One round of Which/Add (module docstring, steps 3–4): score the stages' candidates
    against ``state.model``, decide the round's verdict, and — when an effect is named or a
    term discovered — add it to ``state.model``. The round is appended to ``state.rounds`` and
    returned; another round follows if its verdict is in :data:`ROUND_GOES_ON`."""
    cfg, data, report = ctx.config, ctx.data, ctx.report
    model = state.model
    candidates: list[Candidate] = []
    fits: list[CandidateFit] = []
    round_candidates: list[Candidate] = []
    base = model
    structure: StructureTest | None = None
    stopped: str | None = None
    for stage, stage_names, helper in ctx.stages:
        if stage == "noise" and structure is None:
            # Is the systematic structure exhausted? Score test of the whole grammar on the
            # innovations of the model with its wheel noise (the nuisance) fitted.
            report(f"round {number}: structure", 0.0)
            lib = fit_noise_model(data, model, ctx.nuisance)
            library = library_jacobian(data, lib.spec, lib.sensor)
            structure = structure_test(library, seed=cfg.seed + number)
            # Discovery runs again only after a pass that found terms.
            again = not state.passes or bool(state.passes[-1].terms)
            if structure.p_value < 0.5 * cfg.alpha and cfg.discover and again:
                report(f"round {number}: discovery", 0.0)
                latest = discover(
                    data,
                    lib.spec,
                    lib.sensor,
                    ctx.folds,
                    alpha=cfg.alpha,
                    nuisance=ctx.nuisance,
                    library=library,
                    structure=structure,
                )
                state.passes.append(latest)
                if latest.terms and latest.fit is not None:
                    stopped = "discovered"
                    break
            if structure.p_consistent < 0.5 * cfg.alpha:
                # Structure shared by the runs: no noise effect may stand in for it.
                stopped = "structured"
                break
        effects = [EFFECTS[n] for n in stage_names]
        if not effects:
            continue
        base = fit_noise_model(data, model, helper)
        candidates, fits = _score_candidates(ctx, effects, base, helper, (number, stage))
        round_candidates.extend(candidates)
        if any(c.significant for c in candidates):
            break
    consistency = _consistency(data, base)
    structure_info = structure.as_dict() if structure is not None else None

    def finish(
        verdict: str,
        winner: str | None = None,
        tied: list[str] | None = None,
        separating: dict[str, Any] | None = None,
    ) -> Round:
        done = Round(
            number,
            verdict,
            winner,
            tied if tied is not None else [],
            separating,
            round_candidates,
            consistency,
            structure_info,
        )
        state.rounds.append(done)
        return done

    found = state.passes[-1] if state.passes else None
    if stopped == "discovered" and found is not None and found.fit is not None:
        if not model.spec.effect_values(DISCOVERED):
            state.before_discovery = model.spec
        spec = DiscoveredTerms(found.terms).write(model.spec, found.fit.values)
        state.model = fit_noise_model(data, Model(spec, model.sensor))
        return finish("discovered", DISCOVERED)
    significant = [k for k, c in enumerate(candidates) if c.significant]
    if stopped == "structured" or not significant:
        p_struct = structure.p_value if structure is not None else 1.0
        p_left = combine_bonferroni(consistency, p_struct)
        return finish("none" if p_left >= 0.5 * cfg.alpha else "unexplained")
    best = max(significant, key=lambda k: candidates[k].cv_gain)
    tied = [best] + [
        k
        for k in significant
        if k != best and candidates[best].cv_gain - candidates[k].cv_gain < cfg.tie_nats
    ]
    if len(tied) > 1:
        runner = max((k for k in tied if k != best), key=lambda k: candidates[k].cv_gain)
        found_experiment, _ = separating_experiment(
            fits[best].spec, fits[runner].spec, model.sensor
        )
        separating = {
            "between": [fits[best].name, fits[runner].name],
            "experiment": found_experiment.experiment,
            "separation_mm": 1e3 * found_experiment.position,
            "separation_deg": math.degrees(found_experiment.heading),
            "separation_sigma": found_experiment.sigma,
        }
        return finish("ambiguous", None, [fits[k].name for k in tied], separating)
    winner = fits[best]
    # An effect already in the model may win again (refitted once others joined): its
    # parameters are updated, it is listed once, where it was first added.
    if winner.name not in state.named:
        state.named.append(winner.name)
    state.parameters[winner.name] = {
        key: winner.entry(key, value) for key, value in winner.values.items()
    }
    done = finish("explained", winner.name)
    # Only the named effect joins the model (not the nuisance wheel noise fitted beside a
    # systematic effect); the sensor noise is refitted for it. A noise effect fitted jointly
    # with a systematic partner (bumps with the distance scale) brings the partner's refit.
    spec = EFFECTS[winner.name].write(model.spec, winner.values)
    spec = _refit_named(
        data, Model(spec, model.sensor), state.named, state.parameters, ctx.nuisance
    )
    for partner_name in EFFECTS[winner.name].partners:
        partner = EFFECTS[partner_name]
        refit = partner.read(winner.spec)
        spec = partner.write(spec, refit)
        if partner_name in state.parameters:
            state.parameters[partner_name] = {
                key: {**state.parameters[partner_name][key], "value": value}
                for key, value in refit.items()
            }
    state.model = fit_noise_model(data, Model(spec, model.sensor))
    return done


def _check_runs(runs: Sequence[Run]) -> None:
    """At least three runs, each with a measured pose after its first sample."""
    if len(runs) < 3:
        raise SpecError(f"diagnose needs at least 3 runs, got {len(runs)}", field="runs")
    for run in runs:
        if not measurement_mask(run, 0.0).any():
            raise SpecError(
                f"run {run.meta.get('run', '?')} has no measured pose after its first sample",
                field="x",
                source=run.source,
            )


def _final_test(
    held_data: Dataset, model: Model, found_anything: bool, last: str, alpha: float, seed: int
) -> tuple[str, dict[str, Any]]:
    """The verdict on the held-out runs (step 9 of docs/diagnose.md) and the ``final_test``
    record: the grammar's score test and the whiteness test under the final ``model``,
    Bonferroni-combined. ``last``: the verdict of the last round."""
    held_structure = structure_test(
        library_jacobian(held_data, model.spec, model.sensor), seed=seed
    )
    held_white = _consistency(held_data, model)
    held_p = combine_bonferroni(held_structure.p_value, held_white)
    if not found_anything:
        verdict = last if last not in ROUND_GOES_ON else "none"
        if verdict == "none" and held_p < 0.5 * alpha:
            verdict = "unexplained"
    elif held_p >= 0.5 * alpha and last not in ("unexplained", "ambiguous"):
        verdict = "explained"
    else:
        verdict = "partly explained"
    return verdict, {
        "held_out_structure": held_structure.as_dict(),
        "held_out_whiteness_p": held_white,
        "held_out_p": held_p,
        "residual_follows": held_structure.follows,
        "residual_follows_z": held_structure.z,
    }


def _shrink(
    held_runs: Sequence[Run], robot: RobotSpec, model: Model, cfg: DiagnoseConfig
) -> dict[str, Any]:
    """The gap report (module docstring, step 5) as :class:`Diagnosis` fields: the held-out
    runs under the model as given and the final one, with bootstrap intervals over runs."""
    # The model as given keeps its own noise effects; both are filtered with the sensor noise
    # fitted last (the best estimate of the measurement's own noise).
    before = _gaps(held_runs, robot, model.sensor, cfg.checkpoint_interval)
    after = _gaps(held_runs, model.spec, model.sensor, cfg.checkpoint_interval)
    ms_before, ms_after = before["whitened"], after["whitened"]
    ms_floor = np.ones(len(held_runs))
    boot = np.random.default_rng(cfg.seed + 1)
    # The draws come from one stream in this order: before, after, difference, fraction.
    gap_ci = {
        "before": bootstrap_ci([ms_before], rms, boot),
        "after": bootstrap_ci([ms_after], rms, boot),
        "difference": bootstrap_ci([ms_before, ms_after], lambda b, a: rms(b) - rms(a), boot),
    }
    fraction_ci = bootstrap_ci([ms_before, ms_after, ms_floor], reducible_fraction, boot)
    return {
        "gap_before": rms(ms_before),
        "gap_after": rms(ms_after),
        "gap_ci": gap_ci,
        "noise_floor": rms(ms_floor),
        "fraction_closed": reducible_fraction(ms_before, ms_after, ms_floor),
        "fraction_ci": fraction_ci,
        "holdout_gaps": {
            "before": np.sqrt(ms_before).tolist(),
            "after": np.sqrt(ms_after).tolist(),
            "noise": np.sqrt(ms_floor).tolist(),
        },
        "physical": {
            "gap_position_mm": [1e3 * rms(before["position"]), 1e3 * rms(after["position"])],
            "gap_heading_deg": [
                math.degrees(rms(before["heading"])),
                math.degrees(rms(after["heading"])),
            ],
            "gap_open_loop_sigma": [rms(before["normalised"]), rms(after["normalised"])],
            "noise_floor_open_loop_sigma": [rms(before["floor"]), rms(after["floor"])],
        },
    }


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


def _tied_effects(state: DiagnosisState) -> list[str]:
    """The systematic effects tied in a last round that ended ``ambiguous`` (none otherwise)."""
    last = state.rounds[-1] if state.rounds else None
    if last is None or last.verdict != "ambiguous":
        return []
    return [n for n in last.tied if not EFFECTS[n].noise]


def _significant_effects(state: DiagnosisState, *, tied: bool) -> list[str]:
    """Every systematic catalogue effect some round found significant (named, absorbed or
    beaten by another), in the order first found: the open-loop gate's pool. With ``tied``
    false, those tied in a last round that ended ``ambiguous`` (:func:`_tied_effects`) stay
    out."""
    found = [c.name for c in state.candidates if c.significant]
    out = set(_tied_effects(state)) if not tied else set()
    return [
        n for n in dict.fromkeys([*state.named, *found]) if not EFFECTS[n].noise and n not in out
    ]


def _terms_tried(passes: Sequence[Discovery]) -> int:
    """How many grammar terms the discovery tried: the library's identifiable terms (0 when no
    pass ran)."""
    if not passes:
        return 0
    return len(TERMS) - len(passes[-1].dropped)


def _discovered_order(state: DiagnosisState) -> list[str]:
    """The discovered terms of the rounds' final model, in the order the passes found them."""
    present = state.model.spec.effect_values(DISCOVERED) or {}
    order = [t for found in state.passes for t in found.terms]
    return [t for t in dict.fromkeys(order) if present.get(t, 0.0) != 0.0]


def _kept_terms(
    state: DiagnosisState,
    terms: Sequence[str],
    chosen: SystematicFit,
    runs: Sequence[Run],
) -> list[dict[str, Any]]:
    """``report.json``'s ``discovered`` list for the kept ``terms``: each at its final value
    with its standard error, and the binned channel data behind it."""
    merged: dict[str, dict[str, Any]] = {}
    for found in state.passes:
        for entry in found.entries():
            merged[entry["term"]] = entry
    values = {t: chosen.entries[f"{DISCOVERED}.{t}"]["value"] for t in terms}
    errors = {t: chosen.entries[f"{DISCOVERED}.{t}"]["stderr"] for t in terms}
    out = []
    for t in terms:
        entry = dict(merged[t])
        entry["discovery_coefficient"] = entry["coefficient"]
        entry["coefficient"] = values[t]
        entry["stderr"] = errors[t]
        entry["sentence"] = term_sentence(t, values, errors)
        entry["evidence"] = channel_evidence(runs, state.before_discovery, t)
        out.append(entry)
    return out


def _parameters(
    chosen: SystematicFit, effects: Sequence[str]
) -> dict[str, dict[str, dict[str, float]]]:
    """Each kept catalogue effect's parameters (value and standard errors) from ``chosen``."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for name in effects:
        prefix = f"{name}."
        out[name] = {
            key[len(prefix) :]: entry
            for key, entry in chosen.entries.items()
            if key.startswith(prefix)
        }
    return out


def _geometry_moves(
    without: SystematicFit, with_noise: SystematicFit, noise: Sequence[str]
) -> dict[str, dict[str, Any]]:
    """E_d, E_b, E_s fitted without and with the noise effects that move the mean: each value,
    the change, its standard error and whether the change is within it, naming the noise
    effects that moved it."""
    out: dict[str, dict[str, Any]] = {}
    for name, key in (
        ("wheel_diameter_ratio", "e_d"),
        ("wheelbase", "e_b"),
        ("distance_scale", "e_s"),
    ):
        before = float(getattr(without.spec, key))
        after = float(getattr(with_noise.spec, key))
        se = without.entries.get(f"{name}.{key}", {}).get("stderr", math.nan)
        out[f"E_{key[-1]}"] = {
            "without_noise_effects": before,
            "with_noise_effects": after,
            "change": after - before,
            "stderr": se,
            "within_errors": bool(abs(after - before) <= se) if math.isfinite(se) else None,
            "moved_by": list(noise) if before != after else [],
        }
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
    (:class:`FitJournal`: an interrupted diagnosis resumed gives the same result)."""
    cfg = config if config is not None else DiagnoseConfig()

    def report(stage: str, fraction: float) -> None:
        interrupt.check()  # a stop request a finalizer swallowed (odomgym.interrupt)
        if progress is not None:
            progress(stage, fraction)

    _check_runs(runs)
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
    # 1. The recording's nuisances, fitted jointly with the geometry (E_d, E_b, E_s) so that a
    # curving straight is not read as a tilted frame, nor a scale as a clock. A time offset is
    # removed only where the data show one (module docstring of odomgym.diagnose.nuisances):
    # resampling the counts at a spurious offset adds the acceleration-correlated disagreement
    # the filter is most sensitive to.
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
    # 2. Physical sizes: a discovered term implausible at the data's operating range is a
    # stand-in (for a clock, a frame or a mechanism the grammar lacks), reported, not kept.
    proposed_terms = _discovered_order(state)
    present = state.model.spec.effect_values(DISCOVERED) or {}
    sizes = [term_size(fit_corrected, state.model.spec, t, present[t]) for t in proposed_terms]
    plausible_terms = [size.term for size in sizes if size.plausible]
    # 3. The open-loop gate: each proposal in turn must lower the error of predicting the
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
        )

    gate = gated(_significant_effects(state, tied=True))
    resolved = bool(tied) and set(tied) <= set(gate.effects)
    if tied and not resolved:
        gate = gated(_significant_effects(state, tied=False))
    # 4. The estimator of the kept model's values: the filter's (efficient when its noise model
    # is right), unless the open-loop fit's (what the held-out comparison measures, robust to a
    # wrong noise model) predicts the left-out folds better by one standard error. Between two
    # estimators that predict equally well the efficient one wins: an open-loop estimate chosen
    # on fold noise leaves the filter a residual it can see (E_d 3e-5 off on a simulated robot).
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
    # 5. Noise effects: named by the rounds' held-out likelihood; floor bumps only with their
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
    # 5. The held-out runs: the model as given, the diagnosed one and the baseline, open loop.
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
        **gaps,
    )

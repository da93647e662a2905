"""What a diagnosis returns: :class:`Diagnosis` (its ``as_dict`` is ``report.json``), the
:class:`Round` records and :class:`Candidate` scores it is made of, and :data:`GAP_METRIC`, the
report's definition of the whitened gap.

Plain records, apart from the code that fills them (:mod:`odomgym.diagnose.rounds`,
:mod:`odomgym.diagnose.verdict`, :func:`odomgym.diagnose.workflow.diagnose`), so that what reads
a diagnosis — the report (:mod:`odomgym.diagnose.report`), the tests, the benchmarks — depends on
the records alone and not on the workflow that computes them. Units as in the report:
log-likelihoods in nats, open-loop errors in mm and degrees (``held_out``, ``physical``), effect
parameters in the catalogue's own SI units.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from odomgym.diagnose.gate import GateStep
from odomgym.diagnose.heldout import HeldOut
from odomgym.diagnose.likelihood import SensorNoise
from odomgym.diagnose.nuisances import SessionNuisance
from odomgym.diagnose.where import Finding
from odomgym.effects import EFFECTS
from odomgym.robot import RobotSpec

__all__ = ["GAP_METRIC", "Candidate", "Diagnosis", "Round"]


GAP_METRIC = (
    "root-mean-square whitened innovation of the held-out runs (runs weighted equally): each "
    "run's logged wheel motions are replayed through the model and its disagreement with the "
    "measured poses is Kalman-filtered under the model's noise effects and the last fitted "
    "sensor noise; every innovation is divided by its predicted standard deviation. A model "
    "that explains the data gives 1 (the noise floor); a missing effect makes it larger. "
    "gap_position_mm, gap_heading_deg and gap_open_loop_sigma give the plain (unfiltered) "
    "disagreement over every measured sample after the first"
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
    # Noise effects a stage of the round did not fit (refused whatever their fit), with the reason.
    screened: dict[str, str] = field(default_factory=dict)


@dataclass
class Diagnosis:
    """What :func:`~odomgym.diagnose.workflow.diagnose` found (``as_dict`` is ``report.json``).

    The headline is :attr:`held_out`: the open-loop prediction of the held-out runs (whole
    sessions when there are several) by the model as given, the diagnosed model and a baseline
    calibration, in mm and degrees (:mod:`odomgym.diagnose.heldout`). The whitened gap
    (``gap_*``) is a diagnostic of the noise model beside it. :attr:`skipped_runs`: the runs
    set aside for too little ground truth (:mod:`odomgym.diagnose.screen`), each ``run``,
    ``source`` and ``reason``.
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
    refused_terms: list[dict[str, Any]] = field(default_factory=list)
    noise_checks: dict[str, dict[str, Any]] = field(default_factory=dict)
    spread: list[dict[str, Any]] = field(default_factory=list)
    confounds: list[dict[str, Any]] = field(default_factory=list)
    geometry_check: dict[str, dict[str, Any]] = field(default_factory=dict)
    filter_parameters: dict[str, dict[str, float]] = field(default_factory=dict)
    estimators: dict[str, Any] = field(default_factory=dict)
    terms_tried: int = 0
    skipped_runs: list[dict[str, str]] = field(default_factory=list)

    @property
    def systematic_effects(self) -> list[str]:
        """The named catalogue effects that move the mean, in the order reported
        (:func:`odomgym.diagnose.workflow._in_order_added`)."""
        return [n for n in self.named_effects if not EFFECTS[n].noise]

    @property
    def noise_model(self) -> list[str]:
        """The named noise effects (they widen the spread; floor bumps also shorten the mean
        travel)."""
        return [n for n in self.named_effects if EFFECTS[n].noise]

    def as_dict(self) -> dict[str, Any]:
        """The JSON report (``report.json``): the held-out open-loop comparison first."""
        return {
            "verdict": self.verdict,
            "confirmations": self.final_test.get("confirmations", []),
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
            "refused_terms": self.refused_terms,
            "noise_checks": self.noise_checks,
            "spread_check": self.spread,
            "confounds": self.confounds,
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
                    "screened": r.screened,
                }
                for r in self.rounds
            ],
            "final_test": self.final_test,
            "discovery": self.discovery,
            "where": [f.as_dict() for f in self.findings],
            "fit_runs": self.fit_runs,
            "holdout_runs": self.holdout_runs,
            "skipped_runs": self.skipped_runs,
            "holdout_gaps": self.holdout_gaps,
            **{key: {"before": v[0], "after": v[1]} for key, v in self.physical.items()},
            "model": self.model.to_dict(),
        }

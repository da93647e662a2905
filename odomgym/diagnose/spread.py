"""The yardstick of a noise effect: how well the model predicts the *spread* of the open-loop
errors of runs the fit never saw.

A noise effect (floor roughness, floor bumps, any the catalogue gains) does not move the
prediction of a run; it says how far the robot may stray from it. Open-loop RMS cannot confirm
it — a model with the right spread predicts every run exactly as badly as one without — so a
noise effect is judged in the units it acts in, by a **proper scoring rule** on the held-out
runs' open-loop errors (Gneiting & Raftery 2007):

* **The score: the log predictive density of each held-out run's open-loop errors**, all of
  its measured samples jointly (:func:`odomgym.diagnose.likelihood.run_predictive`: the Kalman
  filter's prediction-error decomposition of the joint density, Schweppe 1965; the bumps'
  Poisson mixture of jumps kept as a mixture, not a variance). Why this score and not the end
  pose alone or an energy score over Monte Carlo replays: it is strictly proper, so no widened
  or narrowed spread can beat the right one on average; it uses every measured sample of a run
  rather than its last, which gives the power a handful of held-out runs needs; it sees the
  heavy tails of sudden jumps, where a Gaussian score on the end pose sees only a variance that
  wheel noise can match; and it is the density the rounds fitted the noise by, so nothing new
  has to be trusted.
* **The comparison:** the model with the effect against the model *without* it, refitted on
  the same fit runs — the remaining noise effects, the wheel noise (as beside every candidate
  of the rounds) and the sensor noise by maximum likelihood, and an effect's systematic
  partner (the distance scale beside floor bumps, whose losses shorten the mean travel) by
  the filter's least squares. The effect is better when the mean over the held-out units
  (sessions — each its mean per run — where there are two or more, else runs) of the paired
  score difference exceeds one standard error of it.
* **Calibration:** the model's 50 % and 95 % predictive regions must hold 40–60 % and 90–98 %
  of the held-out errors (:data:`REGIONS`). Each measured sample is judged by its one-step
  predictive distribution given the run's earlier errors (the factors of the joint density):
  those levels are independent and uniform when the model is right (Rosenblatt 1952), where
  errors from a run's start are correlated along it and a few held-out runs would leave the
  coverage to chance. A covariance that is merely widened covers too much and fails here even
  where its score beats a model without any noise.

An effect is **confirmed** when it is better and calibrated.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.diagnose.fit import Dataset, Joint, Model, fit_candidate, fit_noise
from odomgym.diagnose.likelihood import measurement_mask, run_predictive
from odomgym.diagnose.nuisances import sessions_of
from odomgym.diagnose.replay import replay_run
from odomgym.diagnose.rounds import NUISANCE
from odomgym.effects import EFFECTS, Effect
from odomgym.odometry.runs import Run

__all__ = [
    "MIN_SAMPLES",
    "REGIONS",
    "SpreadCheck",
    "judge_spread",
    "model_without",
    "score_runs",
]

FloatArray = NDArray[np.float64]

REGIONS: tuple[tuple[float, float, float], ...] = ((0.50, 0.40, 0.60), (0.95, 0.90, 0.98))
"""(region probability, lowest and highest share of held-out errors it must hold)."""

MIN_SAMPLES = 30
"""The fewest held-out samples on which a region's coverage is judged: below it, a share
is too coarse to fall within 40–60 % by anything but chance (binomial standard error
≥ 9 % at 50 %)."""


@dataclass(frozen=True)
class RunScores:
    """Held-out runs scored by one model: each run's log predictive density [nats] and the
    coverage levels of all their measured samples."""

    loglik: FloatArray
    levels: FloatArray


def score_runs(runs: Sequence[Run], model: Model, interval: float) -> RunScores:
    """Every run of ``runs`` (nuisances removed) scored by ``model``'s predictive distribution
    (:func:`odomgym.diagnose.likelihood.run_predictive`), one sample per ``interval`` seconds."""
    loglik = np.empty(len(runs))
    levels: list[FloatArray] = []
    for j, run in enumerate(runs):
        mask = measurement_mask(run, interval)
        scored = run_predictive(run, replay_run(run, model.spec), model.spec, model.sensor, mask)
        loglik[j] = scored.loglik
        levels.append(scored.levels)
    return RunScores(loglik, np.concatenate(levels) if levels else np.zeros(0))


@dataclass(frozen=True)
class SpreadCheck:
    """A noise effect judged on the held-out runs (module docstring).

    Attributes:
        effect: the noise effect's name.
        score_with, score_without: summed log predictive density of the held-out runs under
            the model with it and the model without it, refitted [nats].
        difference: mean over the held-out units of the paired score difference [nats].
        stderr: its standard error [nats] (inf with one unit).
        units: ``"sessions"`` or ``"runs"``; unit_count: how many.
        coverage: the share of held-out samples inside the model's 50 % and 95 % regions,
            keyed ``"50"`` and ``"95"``.
        samples: how many held-out samples the coverage is over.
        better: the score beats the model without it by more than one standard error.
        calibrated: both coverages within :data:`REGIONS` (on at least :data:`MIN_SAMPLES`).
        without: what the model without it carried instead, refitted (``EFFECT.PARAMETER``:
            value).
        reason: why it is not confirmed, in words ("" when it is).
    """

    effect: str
    score_with: float
    score_without: float
    difference: float
    stderr: float
    units: str
    unit_count: int
    coverage: dict[str, float]
    samples: int
    better: bool
    calibrated: bool
    without: dict[str, float] = field(default_factory=dict)
    reason: str = ""

    @property
    def confirmed(self) -> bool:
        """Better than the model without it, and calibrated."""
        return self.better and self.calibrated

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "confirmed": self.confirmed, "yardstick": "spread"}

    def sentence(self) -> str:
        """One line for the report: the score difference and the coverage."""
        cover = ", ".join(
            f"its {region} % region holds {100 * share:.0f} %"
            for region, share in self.coverage.items()
        )
        score = (
            f"log score {self.difference:+.1f} ± {self.stderr:.1f} nats per held-out "
            f"{self.units[:-1]} against the model without it"
        )
        return f"{score}; {cover} of {self.samples} held-out errors"


def model_without(data: Dataset, model: Model, name: str, noise: Sequence[str]) -> Model:
    """``model`` without the noise effect ``name``, refitted on ``data``: its systematic
    partners (the mean travel floor bumps' losses shortened) by the filter's least squares with
    the remaining noise effects, then every remaining noise effect of ``noise`` — and the wheel
    noise (:data:`odomgym.diagnose.rounds.NUISANCE`) where it is not the effect judged — and
    the sensor noise by maximum likelihood (module docstring). Wheel noise stands beside every
    judged effect as it stood beside every candidate of the rounds: floor bumps must beat the
    best wheel noise by their tails, not a model with no process noise at all."""
    effect = EFFECTS[name]
    spec = effect.write(model.spec, effect.absent_values())
    rest: list[Effect] = [EFFECTS[n] for n in noise if n != name]
    if name != NUISANCE and NUISANCE not in noise and NUISANCE in EFFECTS:
        rest.append(EFFECTS[NUISANCE])
    sensor = model.sensor
    moving = [EFFECTS[p] for p in effect.partners if type(effect).replay is not Effect.replay]
    if moving:
        refit = fit_candidate(data, spec, sensor, Joint(moving), rest[0] if rest else None)
        spec, sensor = refit.spec, refit.sensor
    spec, sensor, _ = fit_noise(data, spec, sensor, *rest)
    return Model(spec, sensor)


def _paired(
    with_scores: FloatArray, without_scores: FloatArray, labels: Sequence[str]
) -> tuple[float, float, str, int]:
    """Mean and standard error of the per-unit score differences [nats per run]: units are
    sessions (each its mean over its runs) where there are two or more, else runs."""
    sessions = list(dict.fromkeys(labels))
    diff = with_scores - without_scores
    if len(sessions) >= 2:
        # A session's mean per run, so that a session of many runs does not weigh as many.
        per = np.array(
            [float(np.mean([diff[j] for j, s in enumerate(labels) if s == u])) for u in sessions]
        )
        units = "sessions"
    else:
        per, units = diff, "runs"
    mean = float(np.mean(per)) if len(per) else math.nan
    se = float(np.std(per, ddof=1) / math.sqrt(len(per))) if len(per) > 1 else math.inf
    return mean, se, units, len(per)


def judge_spread(
    name: str,
    held: Sequence[Run],
    with_model: Model,
    without_model: Model,
    interval: float,
) -> SpreadCheck:
    """Noise effect ``name`` judged on the ``held`` runs (nuisances removed): ``with_model``
    against ``without_model`` (module docstring)."""
    scored = score_runs(held, with_model, interval)
    reference = score_runs(held, without_model, interval)
    mean, se, units, count = _paired(scored.loglik, reference.loglik, sessions_of(held))
    better = math.isfinite(se) and mean > se
    levels = scored.levels[np.isfinite(scored.levels)]
    samples = int(levels.size)
    coverage = {
        f"{round(100 * q)}": float(np.mean(levels <= q)) if samples else math.nan
        for q, _, _ in REGIONS
    }
    enough = samples >= MIN_SAMPLES
    inside = [low <= coverage[f"{round(100 * q)}"] <= high for q, low, high in REGIONS]
    calibrated = enough and all(inside)
    reasons = []
    if not better:
        reasons.append(
            f"the held-out log score is not better than without it by one standard error "
            f"({mean:+.1f} ± {se:.2g} nats per {units[:-1]})"
        )
    if not enough:
        reasons.append(f"too few held-out samples ({samples}) to check its regions")
    else:
        for (q, low, high), ok in zip(REGIONS, inside, strict=True):
            share = coverage[f"{round(100 * q)}"]
            if not ok:
                wide = "too wide" if share > high else "too narrow"
                reasons.append(
                    f"its {round(100 * q)} % region holds {100 * share:.1f} % of the held-out "
                    f"errors ({100 * low:.0f}–{100 * high:.0f} % required: {wide})"
                )
    effect = EFFECTS[name]
    replaced = [EFFECTS[n] for n in (*effect.partners, *(e for e in EFFECTS if EFFECTS[e].noise))]
    without = {
        f"{e.name}.{k}": v
        for e in dict.fromkeys(replaced)
        if e.name != name and not e.is_absent(e.read(without_model.spec))
        for k, v in e.read(without_model.spec).items()
    }
    return SpreadCheck(
        effect=name,
        score_with=float(np.sum(scored.loglik)),
        score_without=float(np.sum(reference.loglik)),
        difference=mean,
        stderr=se,
        units=units,
        unit_count=count,
        coverage=coverage,
        samples=samples,
        better=better,
        calibrated=calibrated,
        without=without,
        reason="; ".join(reasons),
    )

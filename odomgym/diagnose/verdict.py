"""The steps after the rounds (``docs/diagnose.md``, steps 7–16) that have no module of their
own: what the rounds' proposals become, and the verdict on the held-out runs.

* the open-loop gate's pool (:func:`_significant_effects`), the discovered terms in the order
  the passes found them (:func:`_discovered_order`) and how many grammar terms were tried
  (:func:`_terms_tried`) — steps 7–8;
* the real-size rule for kept terms (:func:`real_size`) — step 10;
* the kept model's parameters (:func:`_parameters`, :func:`noise_parameters`), its discovered
  terms with their evidence and their size at the data's operating range (:func:`_kept_terms`),
  and how far a noise effect with a mean part moved E_d, E_b, E_s (:func:`_geometry_moves`);
* the verdict (:func:`verdict_of`): which yardstick confirmed what — the open-loop error for
  the systematic model, the spread for each noise effect — whether the values moved along a
  confound, and the grammar's score test and the whiteness test on the held-out runs
  (:func:`_final_test`, Bonferroni-combined) — step 15;
* the whitened gap, a diagnostic (:func:`_shrink` over :func:`_gaps`: the held-out runs' RMS
  whitened innovation under the model as given and the diagnosed one, with bootstrap intervals,
  and their open-loop disagreement in mm and degrees beside it) — step 16.

Only :func:`odomgym.diagnose.workflow.diagnose` calls them, in the order of the steps; they live
here so that the orchestration reads as the list of steps. Each is a function of its arguments
(seeded where it draws). The headline comparison in plain units is
:mod:`odomgym.diagnose.heldout`; the gate and the two estimators, :mod:`odomgym.diagnose.gate`;
the spread, :mod:`odomgym.diagnose.spread`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.diagnose.config import DiagnoseConfig
from odomgym.diagnose.confounds import Confound
from odomgym.diagnose.discover import (
    Discovery,
    catalogue_equivalent,
    channel_evidence,
    library_jacobian,
    structure_test,
    term_sentence,
)
from odomgym.diagnose.fit import Dataset, Model
from odomgym.diagnose.gate import SystematicFit, term_proposals
from odomgym.diagnose.heldout import AS_GIVEN, DIAGNOSED, HeldOut
from odomgym.diagnose.likelihood import (
    SensorNoise,
    expected_square_gap,
    measurement_mask,
    run_likelihood,
)
from odomgym.diagnose.physical import term_size
from odomgym.diagnose.replay import replay_run
from odomgym.diagnose.rounds import DISCOVERED, ROUND_GOES_ON, DiagnosisState, _consistency
from odomgym.diagnose.spread import SpreadCheck
from odomgym.diagnose.stats import bootstrap_ci, combine_bonferroni, reducible_fraction, rms
from odomgym.diagnose.steps import NoiseNamed, SystematicModel, TermRefusal
from odomgym.effects import EFFECTS, TERMS
from odomgym.effects.discovered import operating_phrase, term_by_name
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = ["noise_parameters", "real_size", "verdict_of"]


FloatArray = NDArray[np.float64]


def _gaps(
    runs: Sequence[Run], spec: RobotSpec, sensor: SensorNoise, interval: float
) -> dict[str, FloatArray]:
    """Per run: mean square of the whitened innovations
    (:data:`~odomgym.diagnose.results.GAP_METRIC`), and of the open-loop disagreement (position
    [m²], heading [rad²], normalised by the sensor σ, and what noise alone predicts for the
    normalised one)."""
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


def _final_test(
    held_data: Dataset, model: Model, found_anything: bool, last: str, alpha: float, seed: int
) -> tuple[str, dict[str, Any]]:
    """The verdict on the held-out runs (step 15 of docs/diagnose.md) and the ``final_test``
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
    """The gap report (:mod:`odomgym.diagnose.workflow`, step 16) as
    :class:`~odomgym.diagnose.results.Diagnosis` fields: the held-out runs under the model as
    given and the final one, with bootstrap intervals over runs."""
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
    with its standard error, its size at the data's operating range (the change it makes at the
    95th percentile of its modulator, :func:`odomgym.diagnose.physical.term_size`) and the
    binned channel data behind it."""
    merged: dict[str, dict[str, Any]] = {}
    for found in state.passes:
        for entry in found.entries():
            merged[entry["term"]] = entry
    values = {t: chosen.entries[f"{DISCOVERED}.{t}"]["value"] for t in terms}
    errors = {t: chosen.entries[f"{DISCOVERED}.{t}"]["stderr"] for t in terms}
    out = []
    for t in terms:
        entry = dict(merged[t])
        size = term_size(runs, chosen.spec, t, values[t])
        entry["discovery_coefficient"] = entry["coefficient"]
        entry["coefficient"] = values[t]
        entry["stderr"] = errors[t]
        entry["catalogue_equivalent"] = catalogue_equivalent(t, values[t])
        entry["operating"] = size.operating
        entry["change_at_operating"] = size.change
        entry["sentence"] = (
            f"{term_sentence(t, values, errors)}; "
            f"{operating_phrase(t, size.change, size.operating)}"
        )
        entry["evidence"] = channel_evidence(runs, state.before_discovery, t)
        out.append(entry)
    return out


def _largest_stderr(entry: dict[str, float]) -> float:
    """The largest of the standard errors the report gives for a parameter (model-based, run-
    and session-clustered), NaN when none is finite."""
    finite = [
        float(entry[k])
        for k in ("stderr", "stderr_runs", "stderr_sessions")
        if k in entry and math.isfinite(float(entry[k]))
    ]
    return max(finite) if finite else math.nan


_SINUSOID_BOUND = math.sqrt(-2.0 * math.log(1.0 - math.erf(2.0 / math.sqrt(2.0))))
"""√χ²₂ at the one-coefficient rule's level (P(|z| < 2) = 95.45 %): 2.49 standard errors."""


def real_size(
    chosen: SystematicFit, terms: Sequence[str], passes: Sequence[Discovery]
) -> list[TermRefusal]:
    """Step 10: the kept ``terms`` that are not a real size. A term stays only if its final
    coefficient is at least two of its largest standard errors (:func:`_largest_stderr`:
    session-clustered where there are sessions) from zero and has the sign the discovery
    proposed; a sinusoid (sine and cosine together) by its amplitude, at least 2.49 of them
    (the same level for two degrees of freedom), its phase within 90° of the proposed one. A
    term that fails only moved the fit within its noise — or moved it the other way than the
    data it was discovered on said (on real logs a crab angle was kept at +16.7° ± 19.2° per
    m²/s² after the discovery proposed −13.3°)."""
    proposed: dict[str, float] = {}
    for found in passes:
        for entry in found.entries():
            proposed[entry["term"]] = float(entry["coefficient"])
    out = []
    for proposal in term_proposals(terms):
        parts = proposal.split("+")
        entries = [chosen.entries[f"{DISCOVERED}.{t}"] for t in parts]
        value = np.array([float(e["value"]) for e in entries])
        given = np.array([proposed.get(t, math.nan) for t in parts])
        errors = [_largest_stderr(e) for e in entries]
        se = max(errors) if all(math.isfinite(e) for e in errors) else math.nan
        size, given_size = float(np.hypot.reduce(value)), float(np.hypot.reduce(given))
        if len(parts) == 1:
            size, given_size = float(value[0]), float(given[0])
        agrees = float(value @ given) > 0.0
        unit = term_by_name(parts[0]).unit
        # A sinusoid's amplitude √(a² + b²) is ≥ 2σ by chance more often than one
        # coefficient (a Rayleigh variable: e^(−2) = 13.5 % against 4.6 %): it must pass the
        # two-degree-of-freedom χ² at the same 95.4 %, √χ²₂(0.9545) = 2.49 standard errors.
        bound = 2.0 if len(parts) == 1 else _SINUSOID_BOUND
        reasons = []
        if not math.isfinite(se):
            reasons.append("it has no finite standard error")
        elif not abs(size) >= bound * se:
            reasons.append(
                f"within {bound:.3g} standard errors of zero ({size:+.3g} ± {se:.2g} {unit})"
            )
        if not agrees:
            reasons.append(
                f"the opposite {'phase' if len(parts) > 1 else 'sign'} to the one the "
                f"discovery proposed ({given_size:+.3g} {unit})"
            )
        if reasons:
            out.append(TermRefusal(proposal, size, se, given_size, "; ".join(reasons)))
    return out


def noise_parameters(
    errors: dict[str, dict[str, float]], name: str, spec: RobotSpec
) -> dict[str, dict[str, float]]:
    """A kept noise effect's parameters at their final values in ``spec`` (refitted on the
    final systematic model, step 11) with their standard errors there (``errors``:
    :func:`odomgym.diagnose.fit.noise_stderr`; the quoted one is the run-clustered)."""
    out: dict[str, dict[str, float]] = {}
    for key, value in EFFECTS[name].read(spec).items():
        entry = errors.get(key, {})
        runs = float(entry.get("stderr_runs", math.nan))
        out[key] = {
            "value": value,
            "stderr": runs,
            "stderr_model": float(entry.get("stderr", math.nan)),
            "stderr_runs": runs,
            "stderr_sessions": math.nan,
        }
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


_GEOMETRY_KEYS = {
    "wheel_diameter_ratio.e_d": "E_d",
    "wheelbase.e_b": "E_b",
    "distance_scale.e_s": "E_s",
}


def _geometry_moves(
    spec: RobotSpec, spread: Sequence[SpreadCheck], entries: dict[str, dict[str, float]]
) -> dict[str, dict[str, Any]]:
    """E_d, E_b, E_s of the final model (``spec``) and of each model without a noise effect
    that moves the mean (its partners refitted, :func:`odomgym.diagnose.spread.model_without`):
    each value, the change, the standard error of the kept value (``entries``; NaN where the
    gate did not keep the parameter: it is the value given) and whether the change is within
    it, naming the noise effect that moved it."""
    out: dict[str, dict[str, Any]] = {}
    for check in spread:
        for key, label in _GEOMETRY_KEYS.items():
            if key not in check.without:
                continue
            with_noise = float(getattr(spec, label.lower()))
            without = float(check.without[key])
            se = float(entries.get(key, {}).get("stderr", math.nan))
            out[f"{label} ({check.effect})" if len(spread) > 1 else label] = {
                "without_noise_effects": without,
                "with_noise_effects": with_noise,
                "change": with_noise - without,
                "stderr": se,
                "within_errors": bool(abs(with_noise - without) <= se)
                if math.isfinite(se)
                else None,
                "moved_by": [check.effect] if with_noise != without else [],
            }
    return out


def _confirmations(
    found: SystematicModel, held: HeldOut, spread: Sequence[SpreadCheck]
) -> list[dict[str, Any]]:
    """Which yardstick confirmed what on the held-out runs: the kept systematic model (effects
    and terms together) by the open-loop error against the model as given; each kept noise
    effect by its spread (:class:`odomgym.diagnose.spread.SpreadCheck`)."""
    out: list[dict[str, Any]] = []
    names = [*found.gate.effects, *found.gate.terms]
    if names:
        models = held.as_dict()["models"]
        out.append(
            {
                "kind": "systematic",
                "names": names,
                "yardstick": "open-loop error",
                "confirmed": held.better_than_as_given,
                "as_given_mm": models[AS_GIVEN]["combined_rms_mm"],
                "diagnosed_mm": models[DIAGNOSED]["combined_rms_mm"],
            }
        )
    for check in spread:
        out.append({"kind": "noise", "names": [check.effect], **check.as_dict()})
    return out


def verdict_of(
    held_runs: Sequence[Run],
    found: SystematicModel,
    noise: NoiseNamed,
    final: Model,
    held: HeldOut,
    spread: Sequence[SpreadCheck],
    confounds: Sequence[Confound],
    state: DiagnosisState,
    cfg: DiagnoseConfig,
) -> tuple[str, dict[str, Any]]:
    """Step 15: the verdict and the ``final_test`` record. Each finding is judged by the
    yardstick of its kind (:func:`_confirmations`); the held-out runs' score and whiteness
    tests (:func:`_final_test`) say whether structure is left. ``unconfirmed``: nothing kept
    is confirmed, or the rounds proposed effects, terms or noise effects and the later checks
    kept none (the model stays as given — never ``explained`` or ``none`` on a proposal a check
    refused); ``partly confirmed``: some findings confirmed, others not (the report says
    which); ``confounded``:
    everything confirmed and no structure left, but the fitted values moved along a confound
    (:mod:`odomgym.diagnose.confounds`) — the logs read equally as a measurement error, and
    the report names both readings and what would separate them."""
    gate = found.gate
    found_anything = bool(gate.effects) or bool(gate.terms) or bool(spread)
    last = state.rounds[-1].verdict if state.rounds else "none"
    if found.resolved:
        last = "explained"  # the open-loop gate told the tied effects apart
    held_data = Dataset.of(held.corrected(held_runs), cfg.checkpoint_interval)
    verdict, final_test = _final_test(held_data, final, found_anything, last, cfg.alpha, cfg.seed)
    confirmations = _confirmations(found, held, spread)
    confirmed = [c for c in confirmations if c["confirmed"]]
    if found_anything and not confirmed:
        verdict = "unconfirmed"
    elif found_anything and len(confirmed) < len(confirmations):
        verdict = "partly confirmed"
    elif not found_anything and (gate.steps or found.refused or noise.refused or noise.vanished):
        verdict = "unconfirmed"
    if verdict == "explained" and any(c.moved for c in confounds):
        verdict = "confounded"
    final_test["confirmations"] = confirmations
    final_test["tie_resolved_open_loop"] = found.tied if found.resolved else []
    return verdict, final_test

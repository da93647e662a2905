"""The steps after the rounds (``docs/diagnose.md``, steps 9–15) that have no module of their
own: what the rounds' proposals become, and the verdict on the held-out runs.

* the open-loop gate's pool (:func:`_significant_effects`), the discovered terms in the order
  the passes found them (:func:`_discovered_order`) and how many grammar terms were tried
  (:func:`_terms_tried`) — steps 10–11;
* the kept model's parameters (:func:`_parameters`), its discovered terms with their evidence
  (:func:`_kept_terms`), and how far a noise effect with a mean part moved E_d, E_b, E_s
  (:func:`_geometry_moves`) — steps 12–13;
* the verdict on the held-out runs (:func:`_final_test`: the grammar's score test and the
  whiteness test, Bonferroni-combined) — step 9, which step 14 may turn into ``unconfirmed``;
* the whitened gap, a diagnostic (:func:`_shrink` over :func:`_gaps`: the held-out runs' RMS
  whitened innovation under the model as given and the diagnosed one, with bootstrap intervals,
  and their open-loop disagreement in mm and degrees beside it) — step 15.

Only :func:`odomgym.diagnose.workflow.diagnose` calls them, in the order of the steps, hence
private; they live here so that the orchestration reads as the list of steps. Each is a function
of its arguments (seeded where it draws). The headline comparison in plain units is
:mod:`odomgym.diagnose.heldout`; the gate and the two estimators, :mod:`odomgym.diagnose.gate`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.diagnose.config import DiagnoseConfig
from odomgym.diagnose.discover import (
    Discovery,
    channel_evidence,
    library_jacobian,
    structure_test,
    term_sentence,
)
from odomgym.diagnose.fit import Dataset, Model
from odomgym.diagnose.gate import SystematicFit
from odomgym.diagnose.likelihood import (
    SensorNoise,
    expected_square_gap,
    measurement_mask,
    run_likelihood,
)
from odomgym.diagnose.replay import replay_run
from odomgym.diagnose.rounds import DISCOVERED, ROUND_GOES_ON, DiagnosisState, _consistency
from odomgym.diagnose.stats import bootstrap_ci, combine_bonferroni, reducible_fraction, rms
from odomgym.effects import EFFECTS, TERMS
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__: list[str] = []  # private helpers of odomgym.diagnose.workflow.diagnose


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
    """The gap report (:mod:`odomgym.diagnose.workflow`, step 15) as
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

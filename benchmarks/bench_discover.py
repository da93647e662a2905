"""``diagnose`` on robots whose effects odomgym's catalogue does not hold: a blind matrix.

    python benchmarks/bench_discover.py [--trials 2] [--jobs 2] [--classes NAME ...] [--json]
                                        [--out FILE.md]

The robots come from ``tests/alien_robot.py`` (a generator that shares nothing with the World,
the replay or the catalogue's formulas): every catalogue effect in another functional form,
seven effects outside the catalogue, two pairs, and no effect. Each trial draws a magnitude,
sign and seed, simulates the independent generator's rich protocol (24 runs, 10 Hz logs) and
runs ``diagnose`` against the nominal model, blind. Scored:

* catalogue effects in another form: the first systematic effect named (or, for a noise effect,
  the first noise effect named) is the right one — **top-1**;
* out-of-catalogue effects: a discovered term has the right channel and modulator
  (``EXPECTED_TERMS``); a trial **fails honesty** if the verdict is ``explained`` without it;
* no effect: any verdict but ``none`` is a **false alarm**;
* pairs: both named (the catalogue name and the expected discovered term);
* beyond the grammar (three lobes per wheel revolution): right when the verdict is not
  ``explained`` and no noise effect stands in.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from alien_robot import ALIEN_EFFECTS, EXPECTED_TERMS

from odomgym.effects import catalogue

# The generator's effects, grouped: its forms of catalogue effects, those outside the catalogue
# (each with the grammar terms that describe it), and those outside the grammar too.
CATALOGUE_FORMS = [n for n in ALIEN_EFFECTS if n in catalogue()]
OUTSIDE = list(EXPECTED_TERMS)
BEYOND = [n for n in ALIEN_EFFECTS if n not in CATALOGUE_FORMS and n not in OUTSIDE]
PAIRS = ["wheelbase+out_of_round", "wheel_diameter_ratio+sideslip"]
CLASSES = [*CATALOGUE_FORMS, *OUTSIDE, *BEYOND, *PAIRS, "none"]


def trial(job: tuple[str, int]) -> dict[str, Any]:
    """One blind trial of class ``job[0]`` with seed ``job[1]``."""
    from alien_robot import draw_effect, generate_session

    from odomgym.diagnose.workflow import DiagnoseConfig, diagnose
    from odomgym.effects import EFFECTS
    from odomgym.robot import RobotSpec

    label, seed = job
    rng = np.random.default_rng(seed)
    names = [] if label == "none" else label.split("+")
    effects = {n: draw_effect(n, rng) for n in names}
    runs = generate_session(effects, rng)
    model = RobotSpec(wheel_diameter=0.084, wheelbase=0.2, ticks_per_rev=2796.8)
    start = time.perf_counter()
    d = diagnose(runs, model, DiagnoseConfig(seed=seed))
    elapsed = time.perf_counter() - start
    terms = [e["term"] for e in d.discovered]
    right: dict[str, bool] = {}
    for n in names:
        if n in BEYOND:  # no term can name it: right is an honest verdict, no stand-in
            right[n] = d.verdict != "explained" and not d.noise_model
        elif n in EXPECTED_TERMS:
            right[n] = any(t in EXPECTED_TERMS[n] for t in terms)
        elif EFFECTS[n].noise:
            right[n] = bool(d.noise_model) and d.noise_model[0] == n
        else:
            right[n] = bool(d.systematic_effects) and (
                d.systematic_effects[0] == n or (len(names) > 1 and n in d.systematic_effects)
            )
    return {
        "class": label,
        "seed": seed,
        "truth": effects,
        "verdict": d.verdict,
        "systematic": d.systematic_effects,
        "discovered": [
            {k: e[k] for k in ("term", "coefficient", "stderr", "sentence")} for e in d.discovered
        ],
        "noise": d.noise_model,
        "right": right,
        "all_right": all(right.values()) if names else d.verdict == "none",
        "follows": d.final_test.get("residual_follows"),
        "gap_before": d.gap_before,
        "gap_after": d.gap_after,
        "seconds": elapsed,
    }


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    def rate(selected: list[dict[str, Any]]) -> float:
        return sum(r["all_right"] for r in selected) / max(len(selected), 1)

    catalogue = [r for r in rows if r["class"] in CATALOGUE_FORMS]
    outside = [r for r in rows if r["class"] in OUTSIDE]
    pairs = [r for r in rows if r["class"] in PAIRS]
    beyond = [r for r in rows if r["class"] in BEYOND]
    none = [r for r in rows if r["class"] == "none"]
    dishonest = [
        r
        for r in rows
        if r["class"] != "none" and r["verdict"] == "explained" and not r["all_right"]
    ]
    return {
        "top1_catalogue_forms": rate(catalogue),
        "discovered_right_outside": rate(outside),
        "pairs_both_named": rate(pairs),
        "honest_beyond_grammar": rate(beyond),
        "false_alarm_rate": sum(r["verdict"] != "none" for r in none) / max(len(none), 1),
        "explained_on_wrong_name": len(dishonest),
        "trials": len(rows),
    }


def markdown(rows: list[dict[str, Any]], summary: dict[str, Any], elapsed: float) -> str:
    lines = [
        f"{summary['trials']} blind trials, {elapsed:.0f} s.",
        "",
        "| hidden | trial | verdict | systematic | discovered | noise model | right |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        disc = ", ".join(f"{e['term']} {e['coefficient']:.3g}" for e in r["discovered"]) or "—"
        lines.append(
            f"| {r['class']} | {r['seed'] % 1000} | {r['verdict']} | "
            f"{', '.join(r['systematic']) or '—'} | {disc} | {', '.join(r['noise']) or '—'} | "
            f"{'yes' if r['all_right'] else 'no'} |"
        )
    lines += [
        "",
        f"Top-1 on catalogue effects in other forms: {summary['top1_catalogue_forms']:.0%}; "
        f"discovered term right (channel and modulator) outside the catalogue: "
        f"{summary['discovered_right_outside']:.0%}; pairs both named: "
        f"{summary['pairs_both_named']:.0%}; honest verdict beyond the grammar: "
        f"{summary['honest_beyond_grammar']:.0%}; false alarms: {summary['false_alarm_rate']:.0%}; "
        f"'explained' on a wrong or missing name: {summary['explained_on_wrong_name']}.",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=2, help="trials per class (default 2)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    parser.add_argument("--classes", nargs="*", default=None, help=f"subset of {CLASSES}")
    parser.add_argument("--json", action="store_true", help="print JSON instead of markdown")
    parser.add_argument("--out", type=Path, default=None, help="also write the markdown here")
    args = parser.parse_args()
    classes = args.classes or CLASSES
    unknown = [c for c in classes if c not in CLASSES]
    if unknown:
        parser.error(f"unknown classes {unknown}; known: {CLASSES}")
    work = [(c, 7000 + 100 * CLASSES.index(c) + i) for c in classes for i in range(args.trials)]
    start = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(trial, work))
    elapsed = time.perf_counter() - start
    summary = summarise(rows)
    if args.json:
        print(json.dumps({"summary": summary, "rows": rows, "elapsed_s": elapsed}, indent=1))
    else:
        text = markdown(rows, summary, elapsed)
        print(text)
        if args.out is not None:
            args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()

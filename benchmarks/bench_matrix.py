"""The hidden-effect matrix: every catalogue effect, two sizes, two generators, blind.

    python benchmarks/bench_matrix.py [--trials 5] [--none-trials 20] [--jobs 2]
                                      [--generators independent world] [--sizes small large]
                                      [--effects NAME ...] [--results matrix.jsonl]
                                      [--table FILE.md] [--table-only]

Each trial hides one effect of the catalogue (``docs/effects.md``) in a robot, logs the rich
characterisation protocol (24 runs: squares both ways, straights out and back and one way,
spins of 90°/180°/360° both ways at two speeds, half circles both ways at two speeds) and runs
``odomgym diagnose`` against the nominal robot with its default options, blind. Two generators:

* **independent** — ``tests/independent_robot.py``: no code of the World, the replay or the
  catalogue's formulas (continuous exact-arc integration, S-curve speed profiles, 10 Hz logs);
  every effect injected as ``docs/effects.md`` writes it;
* **world** — the project's pymunk World (:func:`odomgym.diagnose.generate.simulate_protocol`,
  20 Hz logs): systematic effects carried by the robot spec; the noise effects come from the
  **floor** — floor roughness from a rough floor (the ``rough`` preset's kind, roughness k),
  floor bumps from a floor strewn with cables of a chosen diameter, a fresh layout under every
  run (0.29 crossings per metre of a wheel's travel, the benchmark's ``cables`` density), the
  over-count of a rigid wheel over a cylinder (:func:`odomgym.sim.cables.bump_extra_rotation`).

Sizes, in multiples of the effect's detection limit (``docs/effects.md``, three Cramér–Rao
standard errors under the rich protocol; :func:`odomgym.diagnose.generate.detection_limit`):
**small** 5 × (the bound the issue sets), **large** drawn in 10–20 ×, each trial with its own
seed and sign (and direction, for the sensor offset). For the
World's bumps the size is the heading jump of one crossing, e/b with e the over-count.

Scored per trial (``score``):

* **named first** — the first effect the report names (in its order: the rounds', an extension
  before its partner, the tracker's offset after the robot's effects) is the hidden one, or
  the hidden one is named too and the report states a confound in which both stand (the table
  counts these apart: "by a confound");
* **its gap shrank** — by the yardstick of its kind: a systematic effect's held-out open-loop
  error below the model as given's (``held_out_open_loop.better_than_as_given``); a noise
  effect's spread check confirmed it (held-out log score better than the model without it by a
  standard error, its 50 % and 95 % regions within 40–60 % and 90–98 %);
* a **success** is both;
* robots with no effect: a **false alarm** is anything kept (an effect or a term named).

Results go to ``--results`` as JSON lines, one per trial; a rerun skips the trials already there
(resume after an interruption; change ``--results`` to start afresh). ``--table`` writes the
docs table.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from odomgym.effects import catalogue

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

EFFECT_NAMES = tuple(catalogue())
"""The whole catalogue (``docs/effects.md``), in its order: an effect it gains joins the matrix."""

LATER_EFFECTS = ("skid_track", "skid_speed")
"""Effects that joined the catalogue after the matrix's seeds were fixed: their seeds come from
a block of their own (:func:`_seed`), so every earlier trial keeps its seed (a re-run shows what
a change of the diagnosis did, not a new draw) and no two trials share one."""

_SEED_ORDER = (*(n for n in EFFECT_NAMES if n not in LATER_EFFECTS), "none", *LATER_EFFECTS)
"""Effects in the order of the table (and of their seeds within each block)."""

SIZES = {"small": (5.0, 5.0), "large": (10.0, 20.0)}
"""Each size's range of multiples of the detection limit: small at 5 ×, the bound issue 42
sets for the smaller size; large drawn in 10–20 ×."""

GENERATORS = ("independent", "world")
CABLE_DENSITY = 1.5
"""Cables per square metre of the World's bump floor (0.3 m long: 0.29 crossings per metre of a
wheel's travel, Buffon's 2·D·L/π)."""
CABLE_LENGTH = 0.3


def _cable_diameter(jump: float, wheel_radius: float, wheelbase: float) -> float:
    """The cable diameter [m] whose crossing turns the robot by ``jump`` [rad]: the over-count
    e = jump·b of a rigid wheel over a cylinder, inverted by bisection."""
    from odomgym.sim.cables import bump_extra_rotation

    low, high = 1e-4, 0.1
    target = jump * wheelbase
    for _ in range(80):
        mid = 0.5 * (low + high)
        if bump_extra_rotation(wheel_radius, 0.5 * mid) < target:
            low = mid
        else:
            high = mid
    return 0.5 * (low + high)


def _seed(generator: str, effect: str, size: str, trial: int) -> int:
    """A trial's seed: from its cell's place in the whole matrix, so a subset repeats exactly
    the trials of the full run."""
    g = GENERATORS.index(generator)
    s = (*SIZES, "none").index(size)
    if effect in LATER_EFFECTS:
        return 1_000_000 + 100_000 * g + 1000 * LATER_EFFECTS.index(effect) + 100 * s + trial
    e = _SEED_ORDER.index(effect)  # at most 9: inside the generator's block of 10 000
    return 100_000 + 10_000 * g + 1000 * e + 100 * s + trial


def simulate(generator: str, effect: str, size: str, seed: int) -> tuple[list[Any], dict[str, Any]]:
    """The logs of one trial and what was hidden in them."""
    from odomgym.diagnose.generate import NOMINAL_ROBOT, detection_limit, hidden_effect
    from odomgym.effects import EFFECTS

    rng = np.random.default_rng(seed)
    truth: dict[str, Any] = {"effect": effect, "size": size, "generator": generator, "seed": seed}
    values: dict[str, float] = {}
    factor = 0.0
    if effect != "none":
        factor = float(rng.uniform(*SIZES[size]))
        values = hidden_effect(effect, factor, "rich", rng)
    truth["factor"] = factor
    truth["values"] = values
    if generator == "independent":
        from independent_robot import IndependentRobot, generate, rich_protocol

        robot = IndependentRobot(effects={effect: values} if values else {})
        return generate(robot, rich_protocol(), rng), truth
    from odomgym.diagnose.generate import simulate_protocol
    from odomgym.floor import FloorSpec

    spec = NOMINAL_ROBOT
    floor: Any = None
    if effect == "floor_roughness":
        floor = FloorSpec(friction=0.8, roughness=values["k_left"], name="matrix-rough")
    elif effect == "floor_bumps":
        jump = factor * detection_limit("floor_bumps", "rich")
        diameter = _cable_diameter(
            jump, 0.5 * NOMINAL_ROBOT.wheel_diameter, NOMINAL_ROBOT.wheelbase
        )
        truth["cable_diameter_m"] = diameter
        truth["values"] = {"rate": CABLE_DENSITY * CABLE_LENGTH * 2 / math.pi, "jump": jump}

        def floor(draw: np.random.Generator) -> FloorSpec:
            return FloorSpec.scattered_cables(
                draw,
                half_size=6.0,
                per_square_metre=CABLE_DENSITY,
                diameter=diameter,
                length=CABLE_LENGTH,
                name="matrix-cables",
            )

    elif values:
        spec = EFFECTS[effect].write(NOMINAL_ROBOT, values)
    return simulate_protocol(spec, "rich", rng, floor=floor), truth


def score(truth: dict[str, Any], report: dict[str, Any]) -> dict[str, Any]:
    """Named first, its gap shrank, success (module docstring), from ``report.json``'s dict."""
    effect = truth["effect"]
    named = list(report["named_effects"])
    terms = [e["term"] for e in report.get("discovered", [])]
    out: dict[str, Any] = {
        "verdict": report["verdict"],
        "named": named,
        "terms": terms,
        "kept_anything": bool(named or terms),
    }
    if effect == "none":
        out.update(named_first=None, gap_shrank=None, success=not out["kept_anything"])
        return out
    first = bool(named) and named[0] == effect
    by_confound = False
    if not first and effect in named:
        for confound in report.get("confounds", []):
            members = {c["name"].split(".")[0] for c in confound["components"]}
            if named[0] in members and effect in members:
                by_confound = True
    out["by_confound"] = by_confound
    first = first or by_confound
    from odomgym.effects import EFFECTS

    if EFFECTS[effect].noise:
        checks = [c for c in report.get("spread_check", []) if c["effect"] == effect]
        shrank = bool(checks) and bool(checks[0]["confirmed"])
    else:
        held = report.get("held_out_open_loop") or {}
        shrank = bool(held.get("better_than_as_given"))
    out.update(named_first=first, gap_shrank=shrank, success=first and shrank)
    return out


def run_trial(job: tuple[str, str, str, int]) -> dict[str, Any]:
    """One blind trial: simulate, diagnose with the default options, score."""
    import json as _json

    from odomgym.diagnose.generate import NOMINAL_ROBOT
    from odomgym.diagnose.report import report_json
    from odomgym.diagnose.workflow import DiagnoseConfig, diagnose

    generator, effect, size, trial = job
    seed = _seed(generator, effect, size, trial)
    runs, truth = simulate(generator, effect, size, seed)
    start = time.perf_counter()
    result = diagnose(runs, NOMINAL_ROBOT, DiagnoseConfig(seed=seed, jobs=1))
    elapsed = time.perf_counter() - start
    report = _json.loads(report_json(result))
    return {
        "key": list(job),
        "truth": truth,
        "elapsed_s": elapsed,
        **score(truth, report),
        "parameters": report["parameters"],
        "confirmations": report.get("confirmations", []),
    }


def jobs_for(args: argparse.Namespace) -> list[tuple[str, str, str, int]]:
    """Every trial the options ask for."""
    out: list[tuple[str, str, str, int]] = []
    for generator in args.generators:
        for effect in args.effects:
            if effect == "none":
                out += [(generator, "none", "none", t) for t in range(args.none_trials)]
                continue
            for size in args.sizes:
                out += [(generator, effect, size, t) for t in range(args.trials)]
    return out


def read_results(path: Path) -> list[dict[str, Any]]:
    """The trials already in ``path`` (a JSON line each)."""
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _rate(rows: Sequence[dict[str, Any]], key: str) -> str:
    values = [bool(r[key]) for r in rows if r.get(key) is not None]
    return f"{sum(values)}/{len(values)}" if values else "—"


def table(rows: Sequence[dict[str, Any]]) -> str:
    """The docs table: per generator, effect and size, trials named first, gap shrank,
    successes; the false alarms; the totals."""
    lines = [
        "| generator | hidden effect | size (× detection limit) | named first | gap of its kind "
        "shrank | both | verdicts |",
        "|---|---|---|---|---|---|---|",
    ]
    cells: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for row in rows:
        generator, effect, size, _ = row["key"]
        cells.setdefault((generator, effect, size), []).append(row)
    order = {name: k for k, name in enumerate(_SEED_ORDER)}
    for key in sorted(
        cells, key=lambda k: (GENERATORS.index(k[0]), order[k[1]], (*SIZES, "none").index(k[2]))
    ):
        group = cells[key]
        generator, effect, size = key
        verdicts: dict[str, int] = {}
        for row in group:
            verdicts[row["verdict"]] = verdicts.get(row["verdict"], 0) + 1
        words = ", ".join(f"{v} {k}" for k, v in sorted(verdicts.items()))
        if effect == "none":
            alarms = sum(bool(r["kept_anything"]) for r in group)
            lines.append(
                f"| {generator} | none | — | — | — | false alarms {alarms}/{len(group)} | {words} |"
            )
            continue
        low, high = SIZES[size]
        lines.append(
            f"| {generator} | {effect} | {size} ({low:g}{'' if low == high else f'–{high:g}'}) "
            f"| {_rate(group, 'named_first')}"
            f" | {_rate(group, 'gap_shrank')} | {_rate(group, 'success')} | {words} |"
        )
    effects = [r for r in rows if r["truth"]["effect"] != "none"]
    nones = [r for r in rows if r["truth"]["effect"] == "none"]
    success = sum(bool(r["success"]) for r in effects)
    confounded = sum(bool(r.get("by_confound")) and bool(r["success"]) for r in effects)
    alarms = sum(bool(r["kept_anything"]) for r in nones)
    elapsed = sum(float(r["elapsed_s"]) for r in rows)
    lines += [
        "",
        f"Hidden effects named first with the gap of their kind shrinking: {success} of "
        f"{len(effects)} ({100 * success / max(len(effects), 1):.0f} %; target ≥ 95 %; "
        f"{confounded} of them named first by a confound the report states). False "
        f"alarms on robots without an effect: {alarms} of {len(nones)} "
        f"({100 * alarms / max(len(nones), 1):.0f} %; target ≤ 5 %). {elapsed:.0f} s of "
        "diagnosis.",
    ]
    return "\n".join(lines)


def run_pending(
    jobs: Sequence[Any],
    trial: Callable[[Any], dict[str, Any]],
    results: Path,
    workers: int,
    done: list[dict[str, Any]],
) -> None:
    """Run the ``jobs`` whose key is not among ``done`` (the rows already in ``results``) on
    ``workers`` processes; each row is appended to ``results`` and to ``done`` as it finishes,
    so an interrupted run resumes where it stopped."""
    finished = {tuple(r["key"]) for r in done}
    todo = [job for job in jobs if tuple(job) not in finished]
    print(f"{len(todo)} trials to run ({len(finished)} already in {results})", flush=True)
    with ProcessPoolExecutor(max_workers=workers) as pool, results.open("a") as out:
        futures = [pool.submit(trial, job) for job in todo]
        for k, future in enumerate(as_completed(futures), 1):
            row = future.result()
            out.write(json.dumps(row) + "\n")
            out.flush()
            done.append(row)
            mark = "ok" if row["success"] else "MISS"
            print(
                f"[{k}/{len(todo)}] {' '.join(map(str, row['key']))}: {mark} "
                f"{row['verdict']} {row['named']} ({row['elapsed_s']:.0f} s)",
                flush=True,
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=5, help="trials per cell (default 5)")
    parser.add_argument(
        "--none-trials", type=int, default=20, help="robots without an effect per generator (20)"
    )
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    parser.add_argument("--generators", nargs="+", default=list(GENERATORS), choices=GENERATORS)
    parser.add_argument("--sizes", nargs="+", default=list(SIZES), choices=list(SIZES))
    parser.add_argument(
        "--effects",
        nargs="+",
        default=[*EFFECT_NAMES, "none"],
        choices=[*EFFECT_NAMES, "none"],
        help="hidden effects (default: the catalogue and none)",
    )
    parser.add_argument("--results", type=Path, default=Path("matrix.jsonl"))
    parser.add_argument("--table", type=Path, default=None, help="write the markdown table here")
    parser.add_argument("--table-only", action="store_true", help="only print the table")
    args = parser.parse_args()
    done = read_results(args.results)
    if not args.table_only:
        run_pending(jobs_for(args), run_trial, args.results, args.jobs, done)
    wanted = set(jobs_for(args))
    rows = [r for r in done if tuple(r["key"]) in wanted]
    text = table(rows)
    print(text)
    if args.table is not None:
        args.table.write_text(text + "\n")


if __name__ == "__main__":
    main()

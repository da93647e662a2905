"""The discrepancy workflow on hidden effects: a confusion matrix, false alarms, and its speed.

    python benchmarks/bench_diagnose.py [--trials 10] [--protocol rich|umbmark] [--jobs 2]
                                        [--classes none ...] [--speed] [--json] [--out FILE.md]

Accuracy: for every effect of the catalogue and for "none", ``--trials`` blind trials
(:func:`odomgym.diagnose.generate.hidden_effect_trial`: a random magnitude of 3–10 × the effect's
detection limit under the protocol, random sign/direction and seed, simulated in the pymunk
World, diagnosed against the nominal model). Prints the confusion matrix (rows: the hidden
effect; columns: the first effect named, or the verdict when none was named), top-1 accuracy
over the effects, the false-alarm rate on "none", and whether the gap shrank when an effect was
named.

Speed (``--speed``): diagnose on 40 runs of about two minutes each (the independent generator of
``tests/independent_robot.py``, 20 Hz logs, a wheelbase error hidden), wall time against the
60 s target.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from odomgym.diagnose.generate import hidden_effect_trial
from odomgym.effects import catalogue

SPEED_TARGET_S = 60.0


def _trial(job: tuple[str | None, str, int]) -> dict[str, Any]:
    return hidden_effect_trial(job[0], job[1], job[2])  # type: ignore[arg-type]


def accuracy(
    trials: int, protocol: str, jobs: int, only: list[str] | None = None
) -> dict[str, Any]:
    classes: list[str | None] = [*catalogue(), None]
    if only:
        classes = [c for c in classes if (c or "none") in only]
    # Seeds depend on the class's place in the whole catalogue, so a --classes subset repeats
    # exactly the trials of the full run.
    everything: list[str | None] = [*catalogue(), None]
    work = [
        (name, protocol, 1000 * everything.index(name) + i)
        for name in classes
        for i in range(trials)
    ]
    start = time.perf_counter()
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        rows = list(pool.map(_trial, work))
    elapsed = time.perf_counter() - start
    columns = [*catalogue(), "ambiguous", "partly explained", "unexplained", "none"]
    matrix = {str(n or "none"): dict.fromkeys(columns, 0) for n in classes}
    for row in rows:
        matrix[row["truth"]][row["top1"]] += 1
    effect_rows = [r for r in rows if r["truth"] != "none"]
    correct = sum(r["top1"] == r["truth"] for r in effect_rows)
    none_rows = [r for r in rows if r["truth"] == "none"]
    alarms = sum(r["verdict"] not in ("none",) for r in none_rows)
    named = [r for r in rows if r["named"]]
    shrank = sum(r["gap_after"] < r["gap_before"] for r in named)
    return {
        "protocol": protocol,
        "trials_per_class": trials,
        "elapsed_s": elapsed,
        "columns": columns,
        "matrix": matrix,
        "top1_accuracy": correct / max(len(effect_rows), 1),
        "false_alarm_rate": alarms / max(len(none_rows), 1),
        "gap_shrank_when_named": f"{shrank}/{len(named)}",
        "rows": rows,
    }


def speed() -> dict[str, Any]:
    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    from independent_robot import IndependentRobot, Manoeuvre, generate

    from odomgym.diagnose.workflow import DiagnoseConfig, diagnose
    from odomgym.robot import RobotSpec

    robot = IndependentRobot(effects={"wheelbase": {"e_b": 1.01}})
    # One 8 m square at 0.3 m/s (with its stops and corner turns) is a run of about two minutes.
    laps = [
        Manoeuvre(kind="square", direction=d, size=8.0, speed=0.3, label=f"square_{d}")
        for d in ("cw", "ccw")
    ]
    runs = generate(robot, laps * 20, np.random.default_rng(0), log_rate_hz=20.0)
    duration = sum(r.time[-1] for r in runs) / len(runs)
    model = RobotSpec(wheel_diameter=0.084, wheelbase=0.2, ticks_per_rev=2796.8)
    start = time.perf_counter()
    diagnosis = diagnose(runs, model, DiagnoseConfig(jobs=os.cpu_count() or 1))
    elapsed = time.perf_counter() - start
    return {
        "runs": len(runs),
        "mean_run_duration_s": duration,
        "diagnose_s": elapsed,
        "target_s": SPEED_TARGET_S,
        "named": diagnosis.named_effects,
        "cpu_count": os.cpu_count(),
    }


def markdown(result: dict[str, Any]) -> str:
    cols = result["columns"]
    short = [c.replace("_", " ") for c in cols]
    lines = [
        f"Protocol {result['protocol']}, {result['trials_per_class']} trials per row, "
        f"{result['elapsed_s']:.0f} s.",
        "",
        "| hidden \\ named | " + " | ".join(short) + " |",
        "|---|" + "---|" * len(cols),
    ]
    for truth, counts in result["matrix"].items():
        lines.append(f"| {truth} | " + " | ".join(str(counts[c]) for c in cols) + " |")
    lines += [
        "",
        f"Top-1 accuracy over effects: {result['top1_accuracy']:.0%}; false alarms on 'none': "
        f"{result['false_alarm_rate']:.0%}; gap shrank when an effect was named: "
        f"{result['gap_shrank_when_named']}.",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=10, help="blind trials per row (default 10)")
    parser.add_argument(
        "--protocol",
        choices=["rich", "umbmark"],
        default="rich",
        help="characterisation protocol, or UMBmark end points only (default rich)",
    )
    parser.add_argument(
        "--classes",
        nargs="+",
        choices=[*catalogue(), "none"],
        help="only these rows (hidden effects, or 'none' for false alarms); default all",
    )
    parser.add_argument(
        "--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: cores)"
    )
    parser.add_argument("--speed", action="store_true", help="only the 40-run speed figure")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--out", help="also write the Markdown table here")
    args = parser.parse_args()
    if args.speed:
        result = speed()
        print(
            json.dumps(result)
            if args.json
            else (
                f"diagnose on {result['runs']} runs of {result['mean_run_duration_s']:.0f} s: "
                f"{result['diagnose_s']:.1f} s (target < {SPEED_TARGET_S:.0f} s, "
                f"{result['cpu_count']} cores); named {result['named']}"
            )
        )
        return
    result = accuracy(args.trials, args.protocol, args.jobs, args.classes)
    text = markdown(result)
    if args.out:
        Path(args.out).write_text(text + "\n", encoding="utf-8")
    print(json.dumps(result) if args.json else text)


if __name__ == "__main__":
    main()

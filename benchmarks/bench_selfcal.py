"""The self-calibration comparison: the learned policy against UMBmark and the classical methods.

    python benchmarks/bench_selfcal.py --budget 16 8 4 --picks  # 100 robots, 3 floors
    python benchmarks/bench_selfcal.py --robots 20 --json  # quicker; JSON lines for scripts
    python benchmarks/bench_selfcal.py --noise             # re-measure ACTION_MENU's floor scatter
    python benchmarks/bench_selfcal.py --error-budget      # what a parameter error costs

Every method runs in the calibrator benchmark (:mod:`odomgym.baselines.benchmark`): the same
robots, floors, random streams and budget, validated on the same fresh 4×4 m squares (5 cw +
5 ccw, E_max,syst of Borenstein & Feng 1994, Eq. 3.3). Besides the benchmark's table it prints,
per floor and budget, the paired comparison of ``selfcal`` with UMBmark: the median of the
per-robot ratio of improvements and the Wilcoxon signed-rank test of its logarithm (robots are
paired: same robot, same floor noise), and the travel each needed.

``selfcal_scripted`` (the same estimator with a fixed schedule) is the policy's ablation: what
the estimator achieves without the learned policy; ``selfcal_end_pose`` (that schedule, the
estimator restricted to end poses) is the trajectory's ablation. ``selfcal``,
``selfcal_scripted``, ``least_squares`` and ``trajectory`` use the whole ground-truth
trajectory (motion capture), the others only end poses. The benchmark's ``oracle`` row (the
robots' true parameters) is the ceiling; every method's *of oracle* is, per robot, the
oracle's E_max,syst after over the method's, and its median.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from typing import Any

import numpy as np
from scipy.stats import wilcoxon

from odomgym.baselines.benchmark import BenchConfig, run_benchmark, summarize
from odomgym.lab.population import BENCH_FLOORS

METHODS = (
    "selfcal",
    "selfcal_scripted",
    "selfcal_end_pose",
    "umbmark",
    "jung_chung",
    "lee",
    "ivanjko",
    "least_squares",
    "trajectory",
)
CLASSICAL = ("umbmark", "jung_chung", "lee", "ivanjko", "least_squares", "trajectory")


def best_classical(rows: list[dict[str, Any]], floor: str, budget: int) -> str | None:
    """The classical method with the highest median improvement on ``floor`` at ``budget``."""
    medians = {}
    for method in CLASSICAL:
        values = [
            r["improvement"]
            for r in rows
            if r["floor"] == floor
            and r["budget"] == budget
            and r["method"].split("@")[0] == method
            and not r["failed"]
        ]
        if values:
            medians[method] = float(np.median(values))
    return max(medians, key=lambda m: medians[m]) if medians else None


def paired(rows: list[dict[str, Any]], a: str, b: str) -> list[dict[str, Any]]:
    """Per floor and budget: ``a`` against ``b`` on the same robots."""
    out = []
    keys = sorted({(r["floor"], r["budget"]) for r in rows}, key=lambda k: (k[0], -k[1]))
    for floor, budget in keys:

        def of(method: str, floor: str = floor, budget: int = budget) -> dict[int, dict[str, Any]]:
            return {
                r["robot"]: r
                for r in rows
                if r["floor"] == floor
                and r["budget"] == budget
                and r["method"].split("@")[0] == method
                and not r["failed"]
            }

        ra, rb = of(a), of(b)
        common = sorted(set(ra) & set(rb))
        if not common:
            continue
        logs = np.array([math.log(ra[i]["improvement"] / rb[i]["improvement"]) for i in common])
        p = float(wilcoxon(logs).pvalue) if len(common) >= 6 and np.any(logs != 0) else math.nan
        out.append(
            {
                "floor": floor,
                "budget": budget,
                "robots": len(common),
                f"{a}_median": float(np.median([ra[i]["improvement"] for i in common])),
                f"{b}_median": float(np.median([rb[i]["improvement"] for i in common])),
                "ratio_median": float(np.exp(np.median(logs))),
                "better_share": float(np.mean(logs > 0)),
                "wilcoxon_p": p,
                f"{a}_travel_m": float(np.mean([ra[i]["distance_m"] for i in common])),
                f"{b}_travel_m": float(np.mean([rb[i]["distance_m"] for i in common])),
            }
        )
    return out


def menu_picks(config: BenchConfig) -> list[dict[str, Any]]:
    """What the learned policy drives, per floor and budget: how often it picks each menu item
    over ``config``'s robots, in the benchmark's own sessions (same robots, floors and random
    streams as its ``selfcal`` rows)."""
    from odomgym.baselines.benchmark import bench_floor, calibration_streams, configure, population
    from odomgym.baselines.selfcal import SelfCal
    from odomgym.lab.lockstep import run_lockstep
    from odomgym.selfcal.menu import ACTION_MENU

    robots = population(config)
    indices = list(range(config.robots))
    out = []
    for floor_name in config.floors:
        floor, start_region, floor_index = bench_floor(config, floor_name)
        for budget in config.budgets:
            outcomes = run_lockstep(
                lambda lab, _i, budget=budget: configure(SelfCal, budget).calibrate(lab),
                robots,
                floor,
                calibration_streams(config, indices, floor_index),
                start_region=start_region,
            )
            counts = dict.fromkeys((item.name for item in ACTION_MENU[1:]), 0)
            for outcome in outcomes:
                if outcome.value is None:
                    continue
                listed = outcome.value.notes[0].removeprefix("experiments: ")
                for name in listed.split(", "):
                    if name in counts:
                        counts[name] += 1
            total = sum(counts.values())
            out.append(
                {
                    "floor": floor_name,
                    "budget": budget,
                    "runs": total,
                    "share": {k: v / total for k, v in counts.items() if v} if total else {},
                }
            )
    return out


def measure_noise(runs: int = 24) -> None:
    """The end-pose scatter of every menu item on the concrete floor (MenuItem.floor_std)."""
    from odomgym.floor import FLOORS
    from odomgym.lab.simulated import experiment_route, random_start_poses
    from odomgym.odometry.runs import end_error
    from odomgym.robot import PRESETS
    from odomgym.selfcal.menu import ACTION_MENU
    from odomgym.sim.route_runs import simulate_runs

    robot = PRESETS["labmate"].ideal()
    print(f"{'item':<16} {'σx [mm]':>8} {'σy [mm]':>8} {'σθ [°]':>7}   (concrete, {runs} runs)")
    for item in ACTION_MENU[1:]:
        assert item.experiment is not None
        rng = np.random.default_rng(5)
        sim, odom = simulate_runs(
            [robot] * runs,
            FLOORS["concrete"],
            [experiment_route(item.experiment)] * runs,
            rng=list(rng.spawn(runs)),
            start_poses=random_start_poses(rng, runs, 12.0),
        )
        err = np.array([end_error(r, o) for r, o in zip(sim, odom, strict=True)])
        sx, sy = 1e3 * err[:, :2].std(axis=0)
        print(f"{item.name:<16} {sx:8.1f} {sy:8.1f} {math.degrees(err[:, 2].std()):7.3f}")


#: (σ of E_d, E_b, E_s) [-] the error budget tries: each alone, then the filter's errors at 8 runs.
ERROR_CASES = (
    (2e-5, 0.0, 0.0),
    (5e-5, 0.0, 0.0),
    (1e-4, 0.0, 0.0),
    (0.0, 1e-4, 0.0),
    (0.0, 3e-4, 0.0),
    (0.0, 0.0, 1e-4),
    (0.0, 0.0, 5e-4),
    (5e-5, 2.5e-4, 4.5e-5),
)


def error_budget(robots: int, seed: int = 0) -> list[dict[str, Any]]:
    """What a given parameter error costs on ``concrete``: every robot calibrated with its true
    E_d, E_b, E_s plus Gaussian errors of the stated σ, validated on the benchmark's own
    squares (same streams as the oracle); the median per-robot ratio of the oracle's
    E_max,syst to the perturbed one's (*of oracle*)."""
    from odomgym.baselines import benchmark as bench
    from odomgym.odometry.calibration import Calibration

    config = BenchConfig(robots=robots, floors=("concrete",), seed=seed)
    fleet = bench.population(config)
    floor, start_region, floor_index = bench.bench_floor(config, "concrete")
    rng = np.random.default_rng(np.random.SeedSequence([seed, 77]))
    calibrations = [
        [bench.oracle_calibration(robot)]
        + [
            Calibration.from_errors(
                robot.e_d + sd * rng.standard_normal(),
                robot.e_b + sb * rng.standard_normal(),
                robot.e_s + ss * rng.standard_normal(),
            )
            for sd, sb, ss in ERROR_CASES
        ]
        for robot in fleet
    ]
    errors = bench.validate_calibrations(  # the benchmark's own: same squares, same noise
        config, floor, start_region, floor_index, list(range(robots)), fleet, calibrations
    )
    out = []
    for c, (sd, sb, ss) in enumerate(ERROR_CASES, start=2):
        ratios = bench.oracle_fractions(errors, 1, c)
        out.append(
            {
                "sigma_E_d": sd,
                "sigma_E_b": sb,
                "sigma_E_s": ss,
                "of_oracle": float(np.median(ratios)),
            }
        )
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=int, default=100, help="robots per floor (100)")
    parser.add_argument("--budget", type=int, nargs="+", default=[16, 4], help="budgets (16 4)")
    parser.add_argument("--floor", nargs="+", default=list(BENCH_FLOORS), help="floors (all)")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), help="methods")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (2)")
    parser.add_argument("--seed", type=int, default=0, help="benchmark seed (0)")
    parser.add_argument("--json", action="store_true", help="JSON lines instead of tables")
    parser.add_argument("--noise", action="store_true", help="measure ACTION_MENU's floor scatter")
    parser.add_argument(
        "--error-budget",
        action="store_true",
        help="what a parameter error of a given size costs, as a fraction of the oracle",
    )
    parser.add_argument("--save", help="also write the benchmark's rows to this JSON file")
    parser.add_argument("--load", help="analyse the rows of an earlier --save instead of running")
    parser.add_argument(
        "--picks", action="store_true", help="also count the menu items the policy drives"
    )
    args = parser.parse_args()
    if args.noise:
        measure_noise()
        return 0
    if args.error_budget:
        for record in error_budget(args.robots, args.seed):
            if args.json:
                print(json.dumps({"error_budget": record}))
            else:
                print(
                    f"σ(E_d) {record['sigma_E_d']:.0e}  σ(E_b) {record['sigma_E_b']:.1e}  "
                    f"σ(E_s) {record['sigma_E_s']:.1e}  of oracle {record['of_oracle']:.1%}"
                )
        return 0
    config = BenchConfig(
        robots=args.robots,
        floors=tuple(args.floor),
        methods=tuple(args.methods),
        budget=args.budget[0],
        extra_budgets=tuple(args.budget[1:]),
        seed=args.seed,
    )
    start = time.perf_counter()
    if args.load:
        with open(args.load, encoding="utf-8") as f:
            saved = json.load(f)
        rows, wall = saved["rows"], float(saved["wall_time_s"])  # the run's, not the loading's
    else:
        rows = run_benchmark(config, jobs=args.jobs)
        wall = time.perf_counter() - start
    if args.save:
        with open(args.save, "w", encoding="utf-8") as f:
            json.dump({"wall_time_s": wall, "rows": rows}, f, default=float)
    summary = summarize(rows)
    comparison = paired(rows, "selfcal", "umbmark") if "selfcal" in args.methods else []
    ablation = (
        paired(rows, "selfcal", "selfcal_scripted")
        if {"selfcal", "selfcal_scripted"} <= set(args.methods)
        else []
    )
    trajectory_gain = (
        paired(rows, "selfcal_scripted", "selfcal_end_pose")
        if {"selfcal_scripted", "selfcal_end_pose"} <= set(args.methods)
        else []
    )
    against_best = []
    if "selfcal" in args.methods:
        for floor in config.floors:
            for budget in config.budgets:
                best = best_classical(rows, floor, budget)
                if best is None:
                    continue
                for record in paired(rows, "selfcal", best):
                    if record["floor"] == floor and record["budget"] == budget:
                        against_best.append({"best": best, **record})
    picks = menu_picks(config) if args.picks else []
    if args.json:
        for record in summary:
            print(json.dumps({"summary": record}))
        for record in comparison:
            print(json.dumps({"selfcal_vs_umbmark": record}))
        for record in ablation:
            print(json.dumps({"selfcal_vs_scripted": record}))
        for record in against_best:
            print(json.dumps({"selfcal_vs_best_classical": record}))
        for record in trajectory_gain:
            print(json.dumps({"trajectory_vs_end_pose": record}))
        for record in picks:
            print(json.dumps({"menu_picks": record}))
        print(json.dumps({"wall_time_s": round(wall, 1), "robots": args.robots}))
        return 0
    print(f"{args.robots} robots per floor, budgets {args.budget}, {wall:.0f} s\n")
    print(
        f"{'floor':<9} {'method':<22} {'improvement [q25-q75]':<24} {'of oracle':>9} "
        f"{'E_after mm':>10} {'travel m':>9} {'runs':>5} {'fail':>4}"
    )
    for s in sorted(summary, key=lambda s: (s["floor"], s["method"])):
        iqr = (
            f"{s['improvement_median']:.1f} [{s['improvement_q25']:.1f}-{s['improvement_q75']:.1f}]"
        )
        print(
            f"{s['floor']:<9} {s['method']:<22} {iqr:<24} {s['of_oracle_median']:9.0%} "
            f"{s['e_max_after_median_mm']:10.1f} "
            f"{s['distance_m_mean']:9.1f} {s['runs_mean']:5.1f} {s['failures']:4d}"
        )
    groups = [
        ("selfcal against UMBmark (paired by robot)", comparison, "selfcal", "umbmark"),
        ("selfcal against its scripted ablation", ablation, "selfcal", "selfcal_scripted"),
        (
            "the trajectory against end poses (same schedule)",
            trajectory_gain,
            "selfcal_scripted",
            "selfcal_end_pose",
        ),
    ]
    for best in sorted({r["best"] for r in against_best}):
        records = [r for r in against_best if r["best"] == best]
        groups.append(
            (f"selfcal against the best classical method ({best})", records, "selfcal", best)
        )
    for title, records, a, b in groups:
        if not records:
            continue
        print(f"\n{title}")
        print(
            f"{'floor':<9} {'budget':>6} {a:>16} {b:>17} {'ratio':>6} {'better':>7} "
            f"{'p':>8} {'travel a/b m':>14}"
        )
        for r in records:
            print(
                f"{r['floor']:<9} {r['budget']:6d} {r[f'{a}_median']:16.1f} "
                f"{r[f'{b}_median']:17.1f} "
                f"{r['ratio_median']:6.2f} {r['better_share']:7.0%} {r['wilcoxon_p']:8.2g} "
                f"{r[f'{a}_travel_m']:6.0f}/{r[f'{b}_travel_m']:<6.0f}"
            )
    if picks:
        print("\nWhat the learned policy drives (share of its runs)")
        for record in picks:
            shares = ", ".join(f"{k} {v:.0%}" for k, v in record["share"].items())
            print(f"{record['floor']:<9} {record['budget']:3d} runs: {shares}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

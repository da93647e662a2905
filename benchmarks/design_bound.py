"""The best fixed schedule of the self-calibration menu, and how much a policy could add to it.

    python benchmarks/design_bound.py                      # 100 robots, 3 floors, 16/8/4 runs
    python benchmarks/design_bound.py --robots 20 --floor concrete --budget 8 --json

The learned policy of ``selfcal`` chooses each run from :data:`odomgym.selfcal.menu.ACTION_MENU`.
Whether a better choice exists is a question of experiment design, and the trajectory filter
answers most of it without driving a single schedule:

1. **Information of one run of each item.** On each floor, the first ``--info-robots`` robots
   of the benchmark drive every item twice; a :class:`~odomgym.selfcal.session.
   TrajectoryEstimator` takes all of them in (so its estimate and roughness factor settle) and
   gives each run's information matrix (:meth:`~odomgym.selfcal.estimators.TrajectoryEstimator.
   run_information`). In the linearised model, given the floor's roughness, the matrix does
   not depend on the measured values — only on the item, the floor and the sensor — which is
   why a fixed schedule loses little to an adaptive policy: *room over best* is, per robot and
   under its own matrices, the best fixed schedule's predicted miss over the least that
   robot's own best schedule reaches (what adapting to the robot and its floor could gain);
   *room over scripted* the same for the scripted schedule.
2. **Every schedule, ranked.** A schedule of n runs is a multiset of items; its posterior
   covariance P is the inverse of the prior's information plus its runs' (Pukelsheim 2006,
   Ch. 1), and its expected validation loss is tr(W·P), where W = Σ Jᵀ·J over the cw and ccw
   4×4 m validation squares and J is the odometry's end position's derivative with respect
   to the parameters (:func:`~odomgym.odometry.runs.replay_with_jacobian`): the squares miss by
   about J·δ for an estimate δ off. All C(n+8, 8) multisets are ranked (735 471 at n = 16).
3. **The best and the benchmark's schedules, driven.** The best-ranked schedule, the
   scripted schedule (``selfcal_scripted``'s) and 4 m squares only, cw and ccw alternating
   (the item the learned policy drives, though in its own mix of directions), run as
   ``selfcal_scripted --schedule`` on the benchmark's robots, floors and random streams and
   are validated on its squares next to the oracle (the true parameters), as every row of
   ``bench_selfcal.py``: *of oracle* is the median per-robot ratio of the oracle's
   E_max,syst to the schedule's (Borenstein & Feng 1994, Eq. 3.3). A Wilcoxon
   (1945) signed-rank test pairs the best schedule with the scripted one by robot:
   *best_over_scripted* is the median per-robot ratio E_max,syst(scripted) / E_max,syst(best)
   (> 1: the best-ranked schedule did better).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from collections import Counter
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import wilcoxon

from odomgym.baselines import benchmark as bench
from odomgym.baselines.base import perform
from odomgym.baselines.selfcal import SelfCalScripted, scripted_policy
from odomgym.lab.experiment import Experiment, ExperimentKind, Lab, SensorAccuracy
from odomgym.lab.lockstep import run_lockstep
from odomgym.lab.population import BENCH_FLOORS
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import replay_with_jacobian
from odomgym.selfcal.estimators import TrajectoryEstimator
from odomgym.selfcal.menu import ACTION_MENU

FloatArray = NDArray[np.float64]
ITEMS = tuple(item.name for item in ACTION_MENU[1:])
REPEATS = 2  # runs of each item per robot for the information matrices
MAX_DESIGN_BUDGET = 20


def item_information(
    config: bench.BenchConfig, floor_name: str, robots: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per robot: the information matrix (3, 3) of one run of every menu item, the validation
    weight W (3, 3) and the prior's information (3, 3), on ``floor_name``.

    Returns arrays of shape (robots, items, 3, 3), (robots, 3, 3) and (3, 3).
    """
    fleet = bench.population(config)[:robots]
    floor, start_region, floor_index = bench.bench_floor(config, floor_name)
    # A stream of its own (key 9): the design's runs are not the benchmark's calibration runs.
    rngs = [
        np.random.default_rng(np.random.SeedSequence([config.seed, i, floor_index, 9]))
        for i in range(robots)
    ]

    def procedure(lab: Lab, _index: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        # the lockstep labs measure with the default sensor, as the benchmark's
        estimator = TrajectoryEstimator(lab.robot, getattr(lab, "sensor", SensorAccuracy()))
        nominal = Calibration()
        taken = []
        for i, item in enumerate(ACTION_MENU[1:], start=1):
            assert item.experiment is not None
            for _ in range(REPEATS):
                (run,) = perform(lab, item.experiment, nominal, method="design")
                estimator.add(run, i)
                taken.append((i, run))
        info = np.zeros((len(ITEMS), 3, 3))
        for i, run in taken:
            info[i - 1] += estimator.run_information(run) / REPEATS
        weight = np.zeros((3, 3))
        for direction in ("cw", "ccw"):
            experiment = Experiment(ExperimentKind.SQUARE, direction, 1, 4.0)
            (run,) = perform(lab, experiment, estimator.calibration, method="design")
            _, jac = replay_with_jacobian(run, lab.robot, estimator.calibration)
            weight += jac[-1, :2].T @ jac[-1, :2]
        return info, weight, estimator.prior_information

    outcomes = run_lockstep(procedure, fleet, floor, rngs, start_region=start_region)
    for outcome in outcomes:
        if outcome.error is not None:
            raise outcome.error
    values = [o.value for o in outcomes if o.value is not None]
    infos = np.array([v[0] for v in values])
    weights = np.array([v[1] for v in values])
    return infos, weights, values[0][2]


def all_designs(budget: int) -> NDArray[np.int64]:
    """Every multiset of ``budget`` menu items, as item counts (designs, items)."""
    combos = np.fromiter(
        itertools.chain.from_iterable(
            itertools.combinations_with_replacement(range(len(ITEMS)), budget)
        ),
        dtype=np.int64,
    ).reshape(-1, budget)
    counts = np.zeros((len(combos), len(ITEMS)), dtype=np.int64)
    for column in range(budget):
        np.add.at(counts, (np.arange(len(combos)), combos[:, column]), 1)
    return counts


def design_loss(
    counts: NDArray[np.int64], info: FloatArray, weight: FloatArray, prior: FloatArray
) -> FloatArray:
    """tr(W·P) of every design: P = (prior + Σ counts·info)⁻¹ (linearised model) [m²]."""
    total = prior + np.einsum("di,ijk->djk", counts.astype(float), info)
    cov = np.linalg.inv(total)
    loss: FloatArray = np.einsum("jk,dkj->d", weight, cov)
    return loss


def counts_of(schedule: list[str]) -> NDArray[np.int64]:
    """Item counts (items,) of a schedule given as item names."""
    tally = Counter(schedule)
    return np.array([tally[name] for name in ITEMS], dtype=np.int64)


def interleaved(counts: NDArray[np.int64]) -> list[str]:
    """A schedule with these counts, the items taken in turn (in menu order, one of each
    item left per round)."""
    left = counts.copy()
    out: list[str] = []
    while left.any():
        for i in np.flatnonzero(left):
            out.append(ITEMS[i])
            left[i] -= 1
    return out


def scripted_schedule(budget: int) -> list[str]:
    """The runs :func:`scripted_policy` drives with ``budget`` runs, by name."""
    return [
        ACTION_MENU[scripted_policy(np.zeros(1, np.float32), budget, k)].name for k in range(budget)
    ]


def drive(
    config: bench.BenchConfig, floor_name: str, budget: int, schedules: dict[str, list[str]]
) -> dict[str, list[float]]:
    """Every schedule on the benchmark's robots and streams, validated with the oracle on its
    squares: per schedule, the per-robot ratio oracle E_max,syst / schedule's."""
    fleet = bench.population(config)
    indices = list(range(config.robots))
    floor, start_region, floor_index = bench.bench_floor(config, floor_name)
    calibrations: list[list[Calibration]] = [[bench.oracle_calibration(r)] for r in fleet]
    for schedule in schedules.values():
        calibrator = SelfCalScripted(budget, schedule=tuple(schedule))
        outcomes = run_lockstep(
            lambda lab, _i, c=calibrator: c.calibrate(lab),  # type: ignore[misc]
            fleet,
            floor,
            bench.calibration_streams(config, indices, floor_index),
            start_region=start_region,
        )
        for k, outcome in enumerate(outcomes):
            if outcome.value is None:  # a failed session would skew the medians unseen
                raise RuntimeError(f"{floor_name}, robot {k}: {outcome.error}")
            calibrations[k].append(outcome.value.calibration)
    errors = bench.validate_calibrations(
        config, floor, start_region, floor_index, indices, fleet, calibrations
    )
    return {name: bench.oracle_fractions(errors, 1, c) for c, name in enumerate(schedules, start=2)}


def study(
    config: bench.BenchConfig,
    floor_name: str,
    budgets: list[int],
    info_robots: int,
    drive_schedules: bool = True,
) -> list[dict[str, Any]]:
    """The design study of one floor (see the module docs); one record per budget."""
    infos, weights, prior = item_information(config, floor_name, info_robots)
    info, weight = infos.mean(axis=0), weights.mean(axis=0)
    records = []
    for budget in budgets:
        counts = all_designs(budget)
        loss = design_loss(counts, info, weight, prior)
        order = np.argsort(loss)
        best = interleaved(counts[order[0]])
        squares = ["square4-cw", "square4-ccw"] * (budget // 2) + ["square4-cw"] * (budget % 2)
        schedules = {"best": best, "scripted": scripted_schedule(budget), "squares": squares}
        predicted = {
            name: float(design_loss(counts_of(s)[None, :], info, weight, prior)[0])
            for name, s in schedules.items()
        }
        # The room a policy has over the scripted schedule: on each robot, under its own
        # matrices, the scripted schedule's predicted loss over the best any schedule of that
        # robot's (even one chosen knowing the robot and floor exactly) reaches.
        scripted_counts = counts_of(schedules["scripted"])
        room, room_best = [], []
        for r in range(len(infos)):
            own = design_loss(counts, infos[r], weights[r], prior)
            mine = design_loss(scripted_counts[None, :], infos[r], weights[r], prior)[0]
            room.append(math.sqrt(float(mine / own.min())))
            room_best.append(math.sqrt(float(own[order[0]] / own.min())))
        index_of_scripted = int(np.flatnonzero((counts == scripted_counts).all(axis=1))[0])
        ratios = drive(config, floor_name, budget, schedules) if drive_schedules else {}
        record: dict[str, Any] = {
            "floor": floor_name,
            "budget": budget,
            "designs": len(counts),
            "best": dict(Counter(best)),
            # per validation direction: tr(W·P) sums the cw and ccw squares
            "predicted_rms_mm": {k: 1e3 * math.sqrt(v / 2) for k, v in predicted.items()},
            "rank_of_scripted": 1 + int((loss < loss[index_of_scripted]).sum()),
            "room_over_best_median": float(np.median(room_best)),
            "room_over_best_max": float(np.max(room_best)),
            "room_over_scripted_median": float(np.median(room)),
            "room_over_scripted_max": float(np.max(room)),
            "of_oracle": {k: float(np.median(v)) for k, v in ratios.items()},
        }
        if ratios:
            log_ratio = np.log(np.array(ratios["best"]) / np.array(ratios["scripted"]))
            record["best_over_scripted"] = float(np.exp(np.median(log_ratio)))
            record["wilcoxon_p"] = float(wilcoxon(log_ratio).pvalue) if log_ratio.any() else 1.0
        records.append(record)
    return records


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=int, default=100, help="robots driven per floor (100)")
    parser.add_argument(
        "--info-robots", type=int, default=20, help="robots for the information matrices (20)"
    )
    parser.add_argument("--budget", type=int, nargs="+", default=[16, 8, 4], help="(16 8 4)")
    parser.add_argument(
        "--floor", nargs="+", choices=list(BENCH_FLOORS), default=list(BENCH_FLOORS), help="(all)"
    )
    parser.add_argument("--seed", type=int, default=0, help="benchmark seed (0)")
    parser.add_argument(
        "--predict-only", action="store_true", help="rank the schedules without driving them"
    )
    parser.add_argument("--json", action="store_true", help="JSON lines instead of a table")
    args = parser.parse_args(argv)
    if not 1 <= args.info_robots <= args.robots:
        parser.error("--info-robots must be between 1 and --robots")
    if not all(1 <= b <= MAX_DESIGN_BUDGET for b in args.budget):
        # C(n+8, 8) designs are held in memory: 3.1 M at 20 runs, 10.5 M at 24
        parser.error(f"--budget must be between 1 and {MAX_DESIGN_BUDGET}")
    config = bench.BenchConfig(robots=args.robots, floors=tuple(args.floor), seed=args.seed)
    start = time.perf_counter()
    for floor_name in config.floors:
        for r in study(config, floor_name, args.budget, args.info_robots, not args.predict_only):
            if args.json:
                print(json.dumps(r), flush=True)
                continue
            best = ", ".join(f"{n}×{k}" for k, n in r["best"].items())
            print(f"{r['floor']} @ {r['budget']} runs ({r['designs']} designs): best {best}")
            print(
                "  predicted RMS miss [mm]: "
                + ", ".join(f"{k} {v:.1f}" for k, v in r["predicted_rms_mm"].items())
                + f"; scripted ranks {r['rank_of_scripted']}"
            )
            print(
                f"  room (predicted RMS miss / each robot's own best): over the best "
                f"{r['room_over_best_median']:.3f} (max {r['room_over_best_max']:.3f}), over "
                f"scripted {r['room_over_scripted_median']:.3f} "
                f"(max {r['room_over_scripted_max']:.3f})"
            )
            if not args.predict_only:
                print(
                    "  driven, of oracle: "
                    + ", ".join(f"{k} {v:.0%}" for k, v in r["of_oracle"].items())
                    + f"; best/scripted {r['best_over_scripted']:.3f} (p = {r['wilcoxon_p']:.2g})",
                    flush=True,
                )
    print(json.dumps({"wall_time_s": round(time.perf_counter() - start, 1)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

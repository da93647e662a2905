"""The room for a learned experiment-choosing policy over the effect catalogue (issue 45, step 2).

Does the best next experiment depend on what the robot carries? Measured before any training,
on robots drawn from the prior of :mod:`odomgym.design.prior` (the ranges fixed before
this was first run) with the menu of :mod:`odomgym.design.menu`, all at one travel
budget:

* **best fixed schedule** — one schedule for every robot (:func:`~odomgym.design.
  schedules.best_fixed_schedule`: the least Monte Carlo Bayes risk on ``--design-robots``
  robots of their own stream), estimated with the Bayes model average over effect subsets, so
  it is not handicapped by a naive estimator;
* **oracle** — knows which effects the robot carries: drives the schedule best for that subset
  and fits only that subset (:func:`~odomgym.design.schedules.oracle_schedules`);
* **greedy EIG** (``--greedy``) — the greedy expected-information-gain policy of step 3;
* **tree** (``--tree``) — the scripted decision tree of step 3
  (:mod:`odomgym.design.tree`);
* **none** — the uncalibrated nominal robot, for scale.

Each robot drives each method's runs in the linear-Gaussian model (its k-th run of an item
measures the same noise under every method: paired), and each method's final estimate is
validated by replaying fresh runs — two 2 m squares (E_max,syst) and a free path (RMS position
miss) — through the estimate and through the true robot (:func:`~odomgym.design.model.
validation_errors`). The room is 1 − mean(oracle)/mean(fixed) of the combined validation error
(the mean of the two figures); it counts when ≥ 20 %. Paired Wilcoxon (1945) signed-rank tests
of the per-robot log ratios.

    python benchmarks/effect_room.py --robots 200 --budget 10 --greedy --json room.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import wilcoxon

from odomgym.design import (
    DESIGN_MENU,
    DesignRobots,
    ModelPosterior,
    SessionRobot,
    SubsetPrior,
    best_fixed_schedule,
    bma_risk,
    build_model,
    greedy_session,
    menu_items,
    oracle_loss,
    oracle_schedules,
    run_schedule,
    select,
    validation_errors,
    validation_runs,
)
from odomgym.design.menu import DesignItem
from odomgym.design.nonlinear import ReplayModel, laplace_estimate
from odomgym.design.prior import OPTIONAL_EFFECTS
from odomgym.design.tree import tree_session

FloatArray = NDArray[np.float64]
METHODS = ("fixed", "oracle", "greedy", "tree", "none")


def with_overhead(menu: tuple[DesignItem, ...], overhead_m: float) -> tuple[DesignItem, ...]:
    """The menu with ``overhead_m`` [m] added to every item's travel (a run's set-up: driving
    back to the measured area, re-homing the ground truth)."""
    return tuple(DesignItem(i.name, i.experiment, i.travel_m + overhead_m, i.time_s) for i in menu)


def paired(a: list[float], b: list[float]) -> dict[str, float]:
    """Median per-robot ratio b/a and the Wilcoxon p of log(b/a) (a, b: errors per robot)."""
    r = np.log(np.array(b)) - np.log(np.array(a))
    p = float(wilcoxon(r).pvalue) if np.any(r != 0) else 1.0
    return {"median_ratio": float(np.exp(np.median(r))), "wilcoxon_p": p}


def describe(names: tuple[str, ...], counts: NDArray[np.int64]) -> dict[str, int]:
    return {n: int(c) for n, c in zip(names, counts, strict=True) if c}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=int, default=200, help="evaluation robots (200)")
    parser.add_argument("--design-robots", type=int, default=200, help="for the fixed search")
    parser.add_argument("--budget", type=float, default=10.0, help="travel budget [m] (10)")
    parser.add_argument("--seed", type=int, default=0, help="(0)")
    parser.add_argument("--greedy", action="store_true", help="also the greedy EIG policy")
    parser.add_argument("--tree", action="store_true", help="also the scripted decision tree")
    parser.add_argument("--draws", type=int, default=8, help="greedy: predictive draws (8)")
    parser.add_argument(
        "--greedy-absolute",
        action="store_true",
        help="greedy: the largest expected fall of the loss, not per metre of travel",
    )
    parser.add_argument(
        "--menu", nargs="+", default=None, help="item names (default: the whole menu)"
    )
    parser.add_argument(
        "--overhead", type=float, default=0.0, help="travel added to every run [m] (0)"
    )
    parser.add_argument(
        "--data",
        choices=("linear", "replay"),
        default="linear",
        help="measurements from the linear model (J·θ + noise) or the replay of the true "
        "robot (+ the same noise), estimates then relinearised (linear)",
    )
    parser.add_argument("--json", default=None, help="write the results to this JSON file")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    menu = DESIGN_MENU if args.menu is None else select(args.menu, menu_items())
    if args.overhead:
        menu = with_overhead(menu, args.overhead)
    model = build_model(menu)
    prior = SubsetPrior.of(model)
    names = model.names
    log = sys.stderr
    print(f"model of {len(names)} items built ({time.perf_counter() - start:.1f} s)", file=log)

    design_rng = np.random.default_rng(np.random.SeedSequence([args.seed, 45, 1]))
    design = DesignRobots.draw(model, args.design_robots, args.budget, design_rng)
    fixed = best_fixed_schedule(model, prior, args.budget, design)
    oracles = oracle_schedules(model, prior, args.budget, fixed)
    print(
        f"best fixed schedule ({fixed @ model.costs:.2f} m): {describe(names, fixed)}; "
        f"predicted RMS loss {1e3 * math.sqrt(bma_risk(model, prior, design, fixed)):.2f} mm "
        f"({time.perf_counter() - start:.1f} s)",
        file=log,
    )

    runs = validation_runs()
    replay = ReplayModel(model) if args.data == "replay" else None

    bits = np.array([[s >> k & 1 for k in range(len(OPTIONAL_EFFECTS))] for s in range(16)])

    def final(
        post: ModelPosterior, robot: SessionRobot, subset: int | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """The estimate handed to the robot and p(effect present): the posterior's own in the
        linear model; on replayed data, relinearised around itself (Gauss–Newton)."""
        if replay is None:
            theta = post.estimate() if subset is None else post.subset_mean(subset)
            return theta, post.effect_probability()
        theta, prob = laplace_estimate(
            replay, prior, robot.taken, robot.measurements, subset=subset
        )
        return theta, prob @ bits

    methods = [m for m in METHODS if (m != "greedy" or args.greedy) and (m != "tree" or args.tree)]
    errors: dict[str, dict[str, list[float]]] = {
        m: {"combined": [], "e_max_syst": [], "free_rms": []} for m in methods
    }
    identified: dict[str, list[float]] = {"fixed": [], "greedy": [], "tree": []}
    travel: dict[str, list[float]] = {m: [] for m in methods}
    picks: dict[str, int] = {n: 0 for n in names}
    tree_picks: dict[str, int] = {n: 0 for n in names}
    predicted_oracle, predicted_fixed = [], []
    subsets = []
    update_ms: list[float] = []
    for r in range(args.robots):
        rng = np.random.default_rng(np.random.SeedSequence([args.seed, 45, 2, r]))
        subset, theta = model.prior.draw(rng)
        subsets.append(subset)
        seed = (args.seed, 45, 3, r)
        estimates: dict[str, FloatArray] = {"none": np.zeros_like(theta)}
        posts: dict[str, ModelPosterior] = {}
        said: dict[str, FloatArray] = {}
        robot = SessionRobot(model, theta, seed, replay)
        posts["fixed"] = run_schedule(model, prior, robot, fixed)
        estimates["fixed"], said["fixed"] = final(posts["fixed"], robot)
        robot = SessionRobot(model, theta, seed, replay)
        posts["oracle"] = run_schedule(model, prior, robot, oracles[subset])
        estimates["oracle"], _ = final(posts["oracle"], robot, subset)
        predicted_oracle.append(oracle_loss(model, prior, subset, oracles[subset]))
        predicted_fixed.append(oracle_loss(model, prior, subset, fixed))
        if args.greedy:
            plan_rng = np.random.default_rng(np.random.SeedSequence([args.seed, 45, 4, r]))
            robot = SessionRobot(model, theta, seed, replay)
            posts["greedy"] = greedy_session(
                model,
                prior,
                robot,
                args.budget,
                plan_rng,
                draws=args.draws,
                per_metre=not args.greedy_absolute,
            )
            estimates["greedy"], said["greedy"] = final(posts["greedy"], robot)
            for i in posts["greedy"].taken:
                picks[names[i]] += 1
        if args.tree:
            robot = SessionRobot(model, theta, seed, replay)
            posts["tree"] = tree_session(model, prior, robot, args.budget)
            estimates["tree"], said["tree"] = final(posts["tree"], robot)
            for i in posts["tree"].taken:
                tree_picks[names[i]] += 1
        for m in methods:
            e = validation_errors(estimates[m], theta, runs)
            errors[m]["combined"].append(e.combined)
            errors[m]["e_max_syst"].append(e.e_max_syst)
            errors[m]["free_rms"].append(e.free_rms)
            travel[m].append(posts[m].travel_m if m in posts else 0.0)
        truth = np.array([subset >> k & 1 for k in range(len(OPTIONAL_EFFECTS))], dtype=bool)
        for m in identified:
            if m in said:
                identified[m].append(float(np.mean((said[m] > 0.5) == truth)))
        # the per-update time, measured on this robot's fixed session
        probe = ModelPosterior(model, prior)
        probe_robot = SessionRobot(model, theta, (args.seed, 45, 5, r))
        for i in np.flatnonzero(fixed):
            y = probe_robot.measure(int(i))
            t0 = time.perf_counter()
            probe.update(int(i), y)
            probe.estimate()
            update_ms.append(1e3 * (time.perf_counter() - t0))
        if (r + 1) % 10 == 0 or r + 1 == args.robots:
            means = ", ".join(f"{m} {1e3 * np.mean(errors[m]['combined']):.2f}" for m in methods)
            print(
                f"[{r + 1}/{args.robots}] mean validation error [mm]: {means} "
                f"({time.perf_counter() - start:.0f} s)",
                file=log,
                flush=True,
            )

    def mean(m: str, key: str = "combined") -> float:
        return float(np.mean(errors[m][key]))

    result: dict[str, Any] = {
        "robots": args.robots,
        "budget_m": args.budget,
        "seed": args.seed,
        "menu": {
            n: {"travel_m": i.item.travel_m, "time_s": i.item.time_s}
            for n, i in zip(names, model.items, strict=True)
        },
        "overhead_m": args.overhead,
        "data": args.data,
        "greedy_rate": "absolute" if args.greedy_absolute else "per metre",
        "fixed_schedule": describe(names, fixed),
        "oracle_schedules": {
            "+".join(model.prior.subset_names(s)) or "none": describe(names, c)
            for s, c in enumerate(oracles)
        },
        "mean_error_mm": {
            m: {k: 1e3 * mean(m, k) for k in ("combined", "e_max_syst", "free_rms")}
            for m in methods
        },
        "room": {
            k: 1.0 - mean("oracle", k) / mean("fixed", k)
            for k in ("combined", "e_max_syst", "free_rms")
        },
        "room_counts": 1.0 - mean("oracle") / mean("fixed") >= 0.20,
        "oracle_vs_fixed": paired(errors["fixed"]["combined"], errors["oracle"]["combined"]),
        "predicted_rms_loss_mm": {
            "fixed_known_subset": 1e3 * math.sqrt(float(np.mean(predicted_fixed))),
            "oracle": 1e3 * math.sqrt(float(np.mean(predicted_oracle))),
            "fixed_bma_design_robots": 1e3 * math.sqrt(bma_risk(model, prior, design, fixed)),
        },
        "mean_travel_m": {m: float(np.mean(v)) for m, v in travel.items()},
        "effects_identified": {m: float(np.mean(v)) for m, v in identified.items() if v},
        "update_ms": {"median": float(np.median(update_ms)), "max": float(np.max(update_ms))},
        "subset_counts": {
            "+".join(model.prior.subset_names(s)) or "none": int(np.sum(np.array(subsets) == s))
            for s in range(model.prior.subsets)
        },
        "wall_time_s": round(time.perf_counter() - start, 1),
    }
    if args.greedy:
        result["greedy_vs_fixed"] = paired(
            errors["fixed"]["combined"], errors["greedy"]["combined"]
        )
        result["greedy_vs_oracle"] = paired(
            errors["oracle"]["combined"], errors["greedy"]["combined"]
        )
        result["greedy_picks"] = {n: k for n, k in picks.items() if k}
    if args.tree:
        result["tree_vs_fixed"] = paired(errors["fixed"]["combined"], errors["tree"]["combined"])
        result["tree_vs_oracle"] = paired(errors["oracle"]["combined"], errors["tree"]["combined"])
        if args.greedy:
            result["tree_vs_greedy"] = paired(
                errors["greedy"]["combined"], errors["tree"]["combined"]
            )
        result["tree_picks"] = {n: k for n, k in tree_picks.items() if k}
    text = json.dumps(result, indent=1)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            f.write(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

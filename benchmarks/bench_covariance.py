"""Time the paper-size Monte Carlo of Chong & Kleeman §6.1: vectorised numpy versus a plain loop.

The paper ran 10 000 runs × 10 000 partitions per table column. This times
:func:`odomgym.noise.montecarlo.monte_carlo` on the full size and :func:`monte_carlo_loop` (one run
and one partition at a time in Python) on a subset of runs, extrapolated linearly to the full
run count — the loop costs the same per run, and the full loop would take minutes.

    python benchmarks/bench_covariance.py [--runs 10000] [--partitions 10000] [--json]
"""

from __future__ import annotations

import os

# One core: the comparison is per core, so keep any BLAS pool out of it (before numpy loads).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from odomgym.noise.montecarlo import monte_carlo, monte_carlo_loop  # noqa: E402

# Table 2, column (III): L = 15 m, R = 10 m, B = 0.4 m, k_L = 0.01, k_R = 0.02 m^½.
CASE = (15.0, 10.0, 0.4, 0.01, 0.02)
CASE_NAMES = ("left_m", "right_m", "wheelbase_m", "kl_sqrt_m", "kr_sqrt_m")


def run(runs: int, partitions: int, loop_runs: int, seed: int) -> dict[str, object]:
    """Both timings [s] and what they were measured on, as a JSON-ready dict."""
    t0 = time.perf_counter()
    fast = monte_carlo(*CASE, n_runs=runs, n_partitions=partitions, rng=np.random.default_rng(seed))
    vectorised_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    monte_carlo_loop(
        *CASE, n_runs=loop_runs, n_partitions=partitions, rng=np.random.default_rng(seed)
    )
    loop_subset_s = time.perf_counter() - t0
    loop_s = loop_subset_s * runs / loop_runs
    return {
        "case": dict(zip(CASE_NAMES, CASE, strict=True)),
        "runs": runs,
        "partitions": partitions,
        "vectorised_s": vectorised_s,
        "vectorised_ns_per_partition": vectorised_s / (runs * partitions) * 1e9,
        "loop_runs_timed": loop_runs,
        "loop_subset_s": loop_subset_s,
        "loop_extrapolated_s": loop_s,
        "speedup": loop_s / vectorised_s,
        "cpu_count": os.cpu_count(),
        "std_m_rad": [float(v) for v in fast.std],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10_000, help="Monte Carlo runs (paper: 10 000)")
    parser.add_argument("--partitions", type=int, default=10_000, help="partitions per path")
    parser.add_argument("--loop-runs", type=int, default=50, help="runs timed for the loop")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args()
    loop_runs = max(2, min(args.loop_runs, args.runs))
    result = run(args.runs, args.partitions, loop_runs, args.seed)
    if args.json:
        print(json.dumps(result, indent=2))
        return
    size = f"{args.runs} runs × {args.partitions} partitions"
    print(f"Chong & Kleeman Monte Carlo, Table 2 (III), {size}; os.cpu_count() = {os.cpu_count()}")
    print(
        f"  vectorised : {result['vectorised_s']:8.2f} s "
        f"({result['vectorised_ns_per_partition']:.0f} ns per run-partition)"
    )
    print(
        f"  loop       : {result['loop_extrapolated_s']:8.2f} s "
        f"(extrapolated from {loop_runs} runs timed in {result['loop_subset_s']:.2f} s)"
    )
    print(f"  speed-up   : {result['speedup']:8.1f} ×")


if __name__ == "__main__":
    main()

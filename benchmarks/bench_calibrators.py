"""Wall time of the default calibrator benchmark (issue #3 target: < 5 minutes on 2 cores).

    python benchmarks/bench_calibrators.py [--robots 100] [--jobs N] [--json]

Runs ``odomgym bench calibrators``' default workload — every calibrator × 100 robots × the
concrete, rough and cables floors, validated on fresh squares — and prints the wall time next to
the target, with the machine's core count. Outputs go to a temporary folder.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from odomgym.baselines import CALIBRATORS
from odomgym.baselines.bench_report import write_outputs
from odomgym.baselines.benchmark import BenchConfig, run_benchmark, summarize

TARGET_S = 300.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=100)
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    config = BenchConfig(robots=args.robots, methods=tuple(CALIBRATORS))
    start = time.perf_counter()
    rows = run_benchmark(config, jobs=args.jobs)
    elapsed = time.perf_counter() - start
    with tempfile.TemporaryDirectory() as folder:
        write_outputs(config, rows, Path(folder), elapsed)
    result = {
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "jobs": args.jobs,
        "calibrators": len(config.methods),
        "robots": config.robots,
        "floors": len(config.floors),
        "results": len(rows),
        "wall_s": elapsed,
        "target_s": TARGET_S,
        "umbmark_concrete_median_improvement": next(
            s["improvement_median"]
            for s in summarize(rows)
            if s["method"] == "umbmark" and s["floor"] == "concrete"
        ),
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(
        f"machine: {result['cpu_count']} cores, Python {result['python']}, {args.jobs} jobs\n"
        f"{len(config.methods)} calibrators x {config.robots} robots x {len(config.floors)} "
        f"floors ({len(rows)} results): {elapsed:.1f} s   [target < {TARGET_S:.0f} s]"
    )


if __name__ == "__main__":
    main()

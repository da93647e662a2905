"""The property-based tests with a larger profile: how many examples ran, and whether all held.

    python benchmarks/bench_fuzz.py                 # 20 000 examples per property
    python benchmarks/bench_fuzz.py --examples 5000

CI runs the same properties (``tests/test_fuzz.py``) with 1000 fixed examples each; this draws
new examples on every run (hypothesis's own randomness) and prints, per property, the examples
run and the outcome, from hypothesis's statistics.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--examples", type=int, default=20_000, help="per property (20000)")
    args = parser.parse_args()
    env = dict(os.environ, ODOMGYM_FUZZ_EXAMPLES=str(args.examples))
    start = time.perf_counter()
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "tests/test_fuzz.py",
            "--hypothesis-show-statistics",
        ],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - start
    name = None
    total = 0
    for line in result.stdout.splitlines():
        match = re.match(r"tests/test_fuzz.py::(\w+):", line)
        if match:
            name = match.group(1)
        counts = re.search(r"(\d+) passing, (\d+) failing", line)
        if name and counts:
            passing = int(counts.group(1))
            failing = int(counts.group(2) or 0)
            total += passing + failing
            print(f"{name:<32} {passing:7d} passing {failing:5d} failing")
    tail = result.stdout.strip().splitlines()[-1] if result.stdout.strip() else result.stderr
    print(f"{total} examples in {wall:.0f} s: {tail}")
    return result.returncode


if __name__ == "__main__":
    sys.exit(main())

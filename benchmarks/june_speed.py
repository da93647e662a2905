"""The June OptiOdom diagnosis timed, side by side with another revision (issue 44's ≤ 60 s).

    python benchmarks/june_speed.py [--against REV] [--runs 3] [--jobs 2] [--json] [--keep DIR]

Runs the command of docs/diagnose.md on the 14 June sessions of the OptiOdom robot (gathered by
``diagnose_loso.gather_june``)::

    odomgym diagnose JUNE --format optiodom --robot examples/optiodom_nominal.toml --jobs 2

``--runs`` times for this checkout and, with ``--against``, as often for a git revision checked
out in a temporary worktree, alternating (this, REV, this, REV, …), so that a slow spell of the
machine weighs on both alike. Why side by side: the same code took 52–56 s and 59–63 s for this
command on one day (docs/diagnose.md, "Measured on stop 69" and "Measured on stop 70"); only a
ratio measured in one sitting compares two versions. Each tree first runs once untimed, so that
numba compiles its kernels into that tree's own cache before the clock starts.

Each run is a fresh process (Python's start-up, reading the logs, the diagnosis, the report and
its figures: what a user waits for). It starts in its tree's folder with ``PYTHONPATH`` set to
it: Python puts the working folder first on its path, so a process started elsewhere would
import whatever ``odomgym/`` sits there. The header prints the files each tree imported
``odomgym`` and ``odomgym.baselines`` from (``odomgym._source_tree``). A revision older than
stop 70 takes ``odomgym.envs`` and ``odomgym.baselines`` from an editable install when there is
one (its finder went last on ``sys.meta_path``), and the header then names that install's
``baselines``.

Prints every run's wall time [s], the medians, their ratio (this / REV) and whether the two
trees' ``report.json`` are byte for byte the same; ``--json`` prints the same as one JSON
object. A benchmark, not a test: it exits 0 whatever the times, and 2 with one line when the
data, the revision or a run fails.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
TARGET_S = 60.0
"""Issue 44: the 14 June sessions diagnosed together in at most a minute on 2 idle cores."""


@dataclass
class Tree:
    """One checkout under test: its label, its root folder and its runs' wall times [s]."""

    label: str
    root: Path
    times: list[float] = field(default_factory=list)
    report: bytes = b""

    def env(self) -> dict[str, str]:
        return {**os.environ, "PYTHONPATH": str(self.root)}

    def imported(self) -> str:
        """The files this tree's process imports ``odomgym`` and the baselines from."""
        probe = (
            "import odomgym, odomgym.baselines; print(odomgym.__file__, odomgym.baselines.__file__)"
        )
        done = subprocess.run(
            [sys.executable, "-c", probe],
            cwd=self.root,
            env=self.env(),
            capture_output=True,
            text=True,
        )
        if done.returncode != 0:
            raise RuntimeError(f"{self.label}: cannot import odomgym: {done.stderr.strip()}")
        return done.stdout.strip()

    def run(self, data: Path, out: Path, jobs: int) -> float:
        """One diagnosis of ``data`` into ``out``; its wall time [s]."""
        command = [
            sys.executable,
            "-m",
            "odomgym",
            "diagnose",
            str(data),
            "--format",
            "optiodom",
            "--robot",
            str(ROOT / "examples" / "optiodom_nominal.toml"),
            "--jobs",
            str(jobs),
            "--out",
            str(out),
        ]
        start = time.perf_counter()
        done = subprocess.run(
            command, cwd=self.root, env=self.env(), capture_output=True, text=True
        )
        elapsed = time.perf_counter() - start
        if done.returncode != 0:
            tail = (done.stderr.strip().splitlines() or ["(no message)"])[-1]
            raise RuntimeError(f"{self.label}: the diagnosis failed: {tail}")
        self.report = (out / "report.json").read_bytes()
        return elapsed


def _gather_june(folder: Path) -> Path:
    spec = importlib.util.spec_from_file_location(
        "diagnose_loso", ROOT / "benchmarks" / "diagnose_loso.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    gathered: Path = module.gather_june(folder)
    return gathered


def _worktree(rev: str, folder: Path) -> Path:
    """``rev`` checked out (detached) in ``folder``; raises with git's message."""
    done = subprocess.run(
        ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(folder), rev],
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        raise RuntimeError(f"--against {rev}: {done.stderr.strip()}")
    return folder


def summary(trees: list[Tree]) -> dict[str, Any]:
    """Medians, the ratio of the first tree's median to the second's, and the target's verdict
    per tree (every timed run ≤ :data:`TARGET_S`)."""
    out: dict[str, Any] = {"target_s": TARGET_S, "trees": {}}
    for tree in trees:
        out["trees"][tree.label] = {
            "root": str(tree.root),
            "times_s": tree.times,
            "median_s": statistics.median(tree.times),
            "every_run_within_target": all(t <= TARGET_S for t in tree.times),
        }
    if len(trees) == 2:
        a, b = (out["trees"][t.label]["median_s"] for t in trees)
        out["ratio"] = a / b
        out["same_report"] = trees[0].report == trees[1].report
    return out


def table(trees: list[Tree], result: dict[str, Any]) -> str:
    """The runs side by side, the medians and the ratio, as Markdown."""
    lines = ["| run | " + " | ".join(t.label for t in trees) + " |"]
    lines.append("|---" * (len(trees) + 1) + "|")
    for k in range(len(trees[0].times)):
        lines.append(f"| {k + 1} | " + " | ".join(f"{t.times[k]:.1f}" for t in trees) + " |")
    medians = " | ".join(f"**{result['trees'][t.label]['median_s']:.1f}**" for t in trees)
    lines.append(f"| median | {medians} |")
    lines.append("")
    for t in trees:
        ok = result["trees"][t.label]["every_run_within_target"]
        lines.append(f"- {t.label}: every run ≤ {TARGET_S:g} s: {'yes' if ok else 'no'}")
    if "ratio" in result:
        lines.append(f"- ratio {trees[0].label} / {trees[1].label}: {result['ratio']:.3f}")
        same = "the same bytes" if result["same_report"] else "different"
        lines.append(f"- report.json of the two trees: {same}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--against", metavar="REV", help="a git revision to time beside this tree")
    parser.add_argument("--runs", type=int, default=3, help="timed runs per tree (default 3)")
    parser.add_argument("--jobs", type=int, default=2, help="diagnose --jobs (default 2)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument("--keep", type=Path, help="keep the last reports in this folder")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    # A SIGTERM unwinds like Ctrl-C, so the temporary worktree is removed (``finally`` below).
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGTERM))
    with tempfile.TemporaryDirectory(prefix="june-speed-") as tmp:
        work = Path(tmp)
        trees = [Tree("this tree", ROOT)]
        try:
            data = _gather_june(work / "june")
            if args.against:
                trees.append(Tree(args.against, _worktree(args.against, work / "against")))
            for tree in trees:
                print(f"{tree.label}: {tree.imported()}", file=sys.stderr)
                print(f"{tree.label}: compiling (untimed run)…", file=sys.stderr)
                tree.run(data, work / "warm", args.jobs)
            for k in range(args.runs):
                for tree in trees:
                    out = (args.keep or work) / f"{'ab'[trees.index(tree)]}-report"
                    tree.times.append(tree.run(data, out, args.jobs))
                    print(
                        f"run {k + 1}/{args.runs} {tree.label}: {tree.times[-1]:.1f} s",
                        file=sys.stderr,
                    )
        except RuntimeError as exc:
            print(f"june_speed: error: {exc}", file=sys.stderr)
            return 2
        finally:
            if args.against and (work / "against").exists():
                remove = ["worktree", "remove", "--force", str(work / "against")]
                subprocess.run(["git", "-C", str(ROOT), *remove], capture_output=True)
    result = summary(trees)
    print(json.dumps(result, indent=2) if args.json else table(trees, result))
    return 0


if __name__ == "__main__":
    sys.exit(main())

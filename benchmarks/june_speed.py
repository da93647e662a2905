"""The June OptiOdom diagnosis timed, side by side with another revision (issue 44's ≤ 60 s).

    python benchmarks/june_speed.py [--against REV] [--runs 3] [--jobs 2] [--json] [--keep DIR]
    python benchmarks/june_speed.py --stages [--jobs 2] [--json]

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
its figures: what a user waits for), started in its tree's folder with ``PYTHONPATH`` set to
it (Python puts the working folder first on its path). Its ``odomgym.envs`` and
``odomgym.baselines`` are its tree's too: before the command runs, a bootstrap puts this
checkout's ``odomgym._source_tree`` finder for that tree first on ``sys.meta_path``, because a
revision older than stop 70 added its own finder last, behind an editable install's, and would
have run the installed checkout's baselines. The header prints each tree's commit and the files
its process imported; a tree whose files are not its own stops the benchmark. Both trees read
this checkout's ``examples/optiodom_nominal.toml`` (the same input).

Before the timed runs, a machine probe in this tree (:data:`_PROBE`, one thread): the compiled
filter of every June run, against its 2.50 ms on the machine of stop 69, where this command took
52–66 s that day. It says how far this machine is from the one the 60 s target was measured on
(a rough guide: on stop 71 the probe read 1.6–2.1× and the command took about 2×).

``--stages`` times where one diagnosis of this tree spends its wall time instead (after an
untimed run that compiles the kernels): the same diagnosis through the API in a fresh process,
its progress callback's stages timed (:func:`stage_times`; a round's candidate fits as one
stage, its structure test and discovery as two). Why: "profile before optimising" — docs/speed.md
gives this table for stop 76, and a change meant to speed the diagnosis up should say which
stage it shortened.

Prints every run's wall time [s], the medians, their ratio (this / REV), the probe and whether
the two trees' ``report.json`` are byte for byte the same; with ``--stages``, each stage's wall
time [s], the total and the probe; ``--json`` prints the same as one JSON object. A benchmark,
not a test: it exits 0 whatever the times, 2 with one line when the data, the revision or a run
fails or the options conflict, and 130 on Ctrl-C or SIGTERM (the worktree removed either way).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
TARGET_S = 60.0
"""Issue 44: the 14 June sessions diagnosed together in at most a minute on 2 idle cores."""
NOMINAL = ROOT / "examples" / "optiodom_nominal.toml"
"""The robot both trees diagnose the June sessions against (and the probe filters them with)."""
REFERENCE_FILTER_MS = 2.50
"""The machine probe's figure (:data:`_PROBE`) on the machine of stop 69 (2026-12-01), where
this command took 52–66 s that day: the plain filter of every June run on one thread
(docs/diagnose.md, "Measured on stop 69")."""

_PROBE = """
import time
from pathlib import Path
import numpy as np
from odomgym.data.logs import read_log
from odomgym.diagnose import fit
from odomgym.diagnose.likelihood import SensorNoise, filter_runs, process_noise
from odomgym.robot import load_robot
robot = load_robot({robot!r})
runs, _ = read_log(Path({data!r}), robot=robot, format="optiodom")
data = fit.Dataset.of(runs, 0.25)
kept = fit._fixed_replays(data, robot, [])
noise = process_noise(robot, kept.travel)
logs = np.empty(len(data))
sensor = SensorNoise(0.002, 0.01)
every = range(len(data))
filter_runs(kept.stacked, noise, sensor, every, logs)
best = []
for _ in range(5):
    start = time.perf_counter()
    for _ in range(50):
        filter_runs(kept.stacked, noise, sensor, every, logs)
    best.append((time.perf_counter() - start) / 50)
print(1e3 * min(best))
"""
"""The machine probe: the compiled filter of every June run (102 runs, 133 391 samples) on the
robot as given, one thread, the best of five means of 50 calls [ms]. Why: the machine's speed
moves between sessions (±10 % within an hour; on stop 71 a machine whose probe read 1.6–2.1×
stop 69's), and a 60 s target holds only on the machine it was set on; the probe beside the
runs says how far this machine is from it. A rough guide, not a forecast: the probe itself
moved by a quarter within an hour on stop 71, and the whole command ran about 2× slower. It
times this tree's compiled filter, so it is comparable with the reference only while that
filter is stop 69's (it is, on stop 71)."""


_BOOTSTRAP = """
import importlib.util, runpy, sys
from pathlib import Path
spec = importlib.util.spec_from_file_location("_june_source_tree", {finder!r})
module = importlib.util.module_from_spec(spec)
spec.loader.exec_module(module)
sys.meta_path.insert(0, module._SourceTreeFinder(Path({root!r})))
sys.argv[0] = "odomgym"
{body}
"""
"""Run in each tree's process before anything imports odomgym: this checkout's source-tree
finder (``odomgym/_source_tree.py`` imports nothing of odomgym) mapping ``odomgym.envs`` and
``odomgym.baselines`` to the tree's folders, first on ``sys.meta_path``."""


_STAGES = """
import json, time
from pathlib import Path
from odomgym.baselines.trajectory import TrajectoryBaseline
from odomgym.data.logs import read_log
from odomgym.diagnose.workflow import DiagnoseConfig, diagnose
from odomgym.robot import load_robot
robot = load_robot({robot!r})
runs, _ = read_log(Path({data!r}), robot=robot, format="optiodom")
events = []
def progress(stage, fraction):
    events.append((time.perf_counter(), stage))
start = time.perf_counter()
diagnose(runs, robot, DiagnoseConfig(jobs={jobs}), baseline=TrajectoryBaseline(), progress=progress)
print(json.dumps({{"start": start, "end": time.perf_counter(), "events": events}}))
"""
"""One diagnosis of the June sessions through the API (the command's defaults: the trajectory
baseline, ``jobs``), every progress report timed; printed as JSON for :func:`stage_times`."""


def stage_of(label: str) -> str:
    """The stage a progress report belongs to: ``round 4: mean candidates`` (the round's stage
    starting) and ``round 4: wheelbase`` (one candidate's fit ending) are
    ``round 4: candidate fits``, ``round 5: structure`` and ``round 5: discovery`` stay as they
    are, and so does every report without a colon; ``open-loop check 1: wheelbase`` is
    ``open-loop check 1``."""
    head, colon, tail = label.partition(":")
    if not colon:
        return label
    tail = tail.strip()
    if head.startswith("round "):
        return (
            f"{head}: {tail}" if tail in ("structure", "discovery") else f"{head}: candidate fits"
        )
    return head


def stage_times(start: float, end: float, events: list[tuple[float, str]]) -> dict[str, float]:
    """Wall time [s] per stage (:func:`stage_of`), in the order the stages first came: each
    report's stage lasts until the next report of another stage (or ``end``); the time before
    the first report is ``before the first report`` (the runs screened and split).

    A stage is timed from its first report. The diagnosis reports a round's candidate stage,
    the open-loop gate's passes and the backward check when they start (since stop 76); a step
    that reports only as its parts end would have its first part credited to the stage
    before it."""
    out: dict[str, float] = {}
    current, since = "before the first report", start
    for at, label in events:
        stage = stage_of(label)
        if stage != current:
            out[current] = out.get(current, 0.0) + at - since
            current, since = stage, at
    out[current] = out.get(current, 0.0) + end - since
    return out


def stage_table(times: dict[str, float]) -> str:
    """:func:`stage_times` as Markdown, with the total."""
    lines = ["| stage | wall [s] |", "|---|---|"]
    lines += [f"| {stage} | {seconds:.1f} |" for stage, seconds in times.items()]
    lines.append(f"| **total** | **{sum(times.values()):.1f}** |")
    return "\n".join(lines)


@dataclass
class Tree:
    """One checkout under test: its label, its root folder, its timed runs' wall times [s] and
    the bytes of its last ``report.json``."""

    label: str
    root: Path
    times: list[float] = field(default_factory=list)
    report: bytes = b""

    def env(self) -> dict[str, str]:
        """The environment of this tree's processes: ``PYTHONPATH`` is its root."""
        return {**os.environ, "PYTHONPATH": str(self.root)}

    def python(self, body: str) -> list[str]:
        """The command that runs ``body`` after the bootstrap (:data:`_BOOTSTRAP`)."""
        finder = str(ROOT / "odomgym" / "_source_tree.py")
        code = _BOOTSTRAP.format(finder=finder, root=str(self.root), body=body)
        return [sys.executable, "-c", code]

    def call(self, body: str, **env: str) -> subprocess.CompletedProcess[str]:
        """``body`` run to its end in this tree's process (its output captured), with ``env``
        added to the tree's environment."""
        return subprocess.run(
            self.python(body),
            cwd=self.root,
            env={**self.env(), **env},
            capture_output=True,
            text=True,
        )

    def probe(self, data: Path) -> float:
        """The machine probe (:data:`_PROBE`) on ``data``, in this tree's process [ms]."""
        done = self.call(_PROBE.format(robot=str(NOMINAL), data=str(data)), ODOMGYM_THREADS="1")
        if done.returncode != 0:
            raise RuntimeError(f"{self.label}: the machine probe failed: {_last(done.stderr)}")
        try:
            return float(done.stdout.split()[-1])
        except (IndexError, ValueError):
            raise RuntimeError(
                f"{self.label}: the machine probe printed no time: {done.stdout.strip()!r}"
            ) from None

    def stages(self, data: Path, jobs: int) -> dict[str, float]:
        """One diagnosis of ``data`` through the API in this tree's process, timed stage by
        stage (:func:`stage_times`) [s]."""
        done = self.call(_STAGES.format(robot=str(NOMINAL), data=str(data), jobs=jobs))
        if done.returncode != 0:
            raise RuntimeError(f"{self.label}: the timed diagnosis failed: {_last(done.stderr)}")
        try:
            timed = json.loads(done.stdout.splitlines()[-1])
            events = [(float(at), str(label)) for at, label in timed["events"]]
            return stage_times(float(timed["start"]), float(timed["end"]), events)
        except (IndexError, KeyError, TypeError, ValueError):
            raise RuntimeError(
                f"{self.label}: the timed diagnosis printed no stages: {done.stdout[-200:]!r}"
            ) from None

    def commit(self) -> str:
        """The tree's commit, with ``+changes`` when its files differ from it."""
        git = ["git", "-C", str(self.root)]
        head = subprocess.run(
            [*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True
        )
        dirty = subprocess.run([*git, "status", "--porcelain"], capture_output=True, text=True)
        return head.stdout.strip() + (" +changes" if dirty.stdout.strip() else "")

    def imported(self) -> str:
        """The files this tree's process imports ``odomgym`` and the baselines from; raises if
        they are not the tree's own."""
        probe = (
            "import odomgym, odomgym.baselines; "
            "print(odomgym.__file__); print(odomgym.baselines.__file__)"
        )
        done = self.call(probe)
        if done.returncode != 0:
            raise RuntimeError(f"{self.label}: cannot import odomgym: {done.stderr.strip()}")
        files = done.stdout.splitlines()
        root = self.root.resolve()
        if not all(Path(f).resolve().is_relative_to(root) for f in files):
            raise RuntimeError(f"{self.label}: imported code outside its tree: {files}")
        return " ".join(files)

    def run(self, data: Path, out: Path, jobs: int) -> float:
        """One diagnosis of ``data`` into ``out``; its wall time [s]. Interrupted, the
        diagnosis is asked to stop (SIGTERM, which odomgym turns into a clean stop) before it
        is killed."""
        argv = [
            "diagnose",
            str(data),
            "--format",
            "optiodom",
            "--robot",
            str(NOMINAL),
            "--jobs",
            str(jobs),
            "--out",
            str(out),
        ]
        body = f"sys.argv[1:] = {argv!r}\nrunpy.run_module('odomgym', run_name='__main__')"
        start = time.perf_counter()
        process = subprocess.Popen(
            self.python(body),
            cwd=self.root,
            env=self.env(),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            _, stderr = process.communicate()
        except BaseException:
            process.terminate()
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
            raise
        elapsed = time.perf_counter() - start
        if process.returncode != 0:
            raise RuntimeError(f"{self.label}: the diagnosis failed: {_last(stderr)}")
        self.report = (out / "report.json").read_bytes()
        return elapsed


def _last(stderr: str) -> str:
    """The last line a failed process wrote (its error), for a one-line message."""
    return (stderr.strip().splitlines() or ["(no message)"])[-1]


def _gather_june(folder: Path) -> Path:
    """The 14 June sessions in ``folder`` (``diagnose_loso.gather_june``, beside this script:
    run as a script, its folder is first on ``sys.path``)."""
    from diagnose_loso import gather_june

    gathered: Path = gather_june(folder)
    sessions = [p for p in gathered.glob("*/*") if p.is_dir()]
    if len(sessions) != 14:
        raise RuntimeError(f"gathered {len(sessions)} June sessions in {gathered}, not 14")
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


def summary(trees: list[Tree], probe_ms: float | None = None) -> dict[str, Any]:
    """Medians, the ratio of the first tree's median to the second's, and the target's verdict
    per tree (every timed run ≤ :data:`TARGET_S`); with ``probe_ms`` (the machine probe), that
    figure and its ratio to :data:`REFERENCE_FILTER_MS`."""
    out: dict[str, Any] = {"target_s": TARGET_S, "trees": {}}
    if probe_ms is not None:
        out["machine"] = {
            "filter_ms": probe_ms,
            "reference_ms": REFERENCE_FILTER_MS,
            "factor": probe_ms / REFERENCE_FILTER_MS,
        }
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
    if "machine" in result:
        machine = result["machine"]
        lines.append(
            f"- machine probe: the filter of every June run on one thread "
            f"{machine['filter_ms']:.2f} ms against {machine['reference_ms']:.2f} ms on the "
            f"machine of stop 69 (52–66 s there): {machine['factor']:.2f}× as slow"
        )
    if "ratio" in result:
        lines.append(f"- ratio {trees[0].label} / {trees[1].label}: {result['ratio']:.3f}")
        same = "the same bytes" if result["same_report"] else "different"
        lines.append(f"- report.json of the two trees: {same}")
    return "\n".join(lines)


def _remove(worktree: Path) -> None:
    """Remove the temporary worktree (twice forced: also one that ``git worktree add`` left
    locked when it was interrupted) and prune git's record of it; warn if that fails."""
    git = ["git", "-C", str(ROOT), "worktree"]
    gone = subprocess.run([*git, "remove", "-f", "-f", str(worktree)], capture_output=True)
    subprocess.run([*git, "prune"], capture_output=True)
    if gone.returncode != 0 and worktree.exists():
        print(f"june_speed: warning: could not remove the worktree {worktree}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--against", metavar="REV", help="a git revision to time beside this tree")
    parser.add_argument("--runs", type=int, help="timed runs per tree (default 3)")
    parser.add_argument("--jobs", type=int, default=2, help="diagnose --jobs (default 2)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument(
        "--keep",
        type=lambda text: Path(text).resolve(),
        help="keep each tree's last report in DIR/report-this-tree and DIR/report-against",
    )
    parser.add_argument(
        "--stages",
        action="store_true",
        help="time one diagnosis of this tree stage by stage instead (not with --against, "
        "--runs, --keep)",
    )
    args = parser.parse_args(argv)
    if args.stages and (args.against or args.keep or args.runs is not None):
        parser.error(
            "--stages times one diagnosis of this tree: not with --against, --runs, --keep"
        )
    if args.runs is None:
        args.runs = 3
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    # A SIGTERM unwinds like Ctrl-C, so the temporary worktree is removed (``finally`` below).
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGINT))
    with tempfile.TemporaryDirectory(prefix="june-speed-") as tmp:
        work = Path(tmp)
        trees = [Tree("this tree", ROOT)]
        folders = {"this tree": "report-this-tree"}
        times: dict[str, float] = {}
        try:
            data = _gather_june(work / "june")
            if args.against:
                trees.append(Tree(args.against, _worktree(args.against, work / "against")))
                folders[args.against] = "report-against"
            for tree in trees:
                print(f"{tree.label} ({tree.commit()}): {tree.imported()}", file=sys.stderr)
                print(f"{tree.label}: compiling (untimed run)…", file=sys.stderr)
                tree.run(data, work / "warm", args.jobs)
            probe_ms = trees[0].probe(data)
            print(f"machine probe: {probe_ms:.2f} ms", file=sys.stderr)
            if args.stages:
                times = trees[0].stages(data, args.jobs)
            for k in range(0 if args.stages else args.runs):
                # Each round in the other order, so neither tree always runs after the other.
                for tree in trees if k % 2 == 0 else trees[::-1]:
                    out = (args.keep or work) / folders[tree.label]
                    tree.times.append(tree.run(data, out, args.jobs))
                    print(
                        f"run {k + 1}/{args.runs} {tree.label}: {tree.times[-1]:.1f} s",
                        file=sys.stderr,
                    )
        except (RuntimeError, OSError, tarfile.TarError, ImportError) as exc:
            print(f"june_speed: error: {exc}", file=sys.stderr)
            return 2
        except (KeyboardInterrupt, SystemExit):
            print("june_speed: interrupted", file=sys.stderr)
            return 130
        finally:
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            if args.against:
                _remove(work / "against")
            signal.signal(signal.SIGINT, signal.default_int_handler)
    if args.stages:
        staged = {"probe_ms": probe_ms, "stages_s": times, "total_s": sum(times.values())}
        text = f"{stage_table(times)}\n\n- machine probe: {probe_ms:.2f} ms"
        print(json.dumps(staged, indent=2) if args.json else text)
        return 0
    result = summary(trees, probe_ms)
    print(json.dumps(result, indent=2) if args.json else table(trees, result))
    return 0


if __name__ == "__main__":
    sys.exit(main())

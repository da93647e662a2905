"""Record odomgym's observable behaviour, to prove a refactoring changed none of it.

Runs a fixed set of seeded jobs — the benchmark's tables, calibrations (simulated and on the
shipped OptiOdom sessions), the leaderboard, a self-calibration session, a short training run,
the CLAPPER runs, the covariance and noise reports, two ``diagnose`` reports and a trace of
every registered env and the native vector env — and writes each job's output into one folder
with a ``MANIFEST.txt`` of SHA-256 digests. Wall-clock fields (seconds, dates, versions,
temporary paths) are removed first, so two snapshots of the same behaviour are byte-identical::

    python scripts/behaviour_snapshot.py /tmp/before       # on the old commit
    python scripts/behaviour_snapshot.py /tmp/after        # on the new one
    diff -r /tmp/before /tmp/after && echo unchanged

Takes about ten minutes on two cores. ``--only NAME ...`` runs a subset.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent

# Keys whose values are wall-clock time, machine facts or output paths: they change between two
# runs of identical behaviour and are dropped from every JSON document before hashing. A key is
# volatile if it *is* one of VOLATILE_KEYS, or if one of its words (split at ``_``, ``-``, ``/``,
# ``.`` and spaces) is one of VOLATILE_WORDS — never by a substring, so that ``candidates``
# (``date``) or ``held_out_lr`` (``out``) keep their values.
VOLATILE_KEYS = {
    "out",
    "path",
    "paths",
    "folder",
    "file",
    "files",
    "written",
    "wrote",
    "policy_file",
    "model_file",
    "version",
    "versions",
    "python",
    "platform",
    "host",
    "hostname",
    "machine",
    "cpu",
    "cpus",
    "cores",
    "jobs",
    "command",
}
VOLATILE_WORDS = {"seconds", "elapsed", "wall", "duration", "date", "created", "git", "fps"}


def volatile(key: str) -> bool:
    """True for a key whose value is a fact of this machine or this moment, not of behaviour."""
    if key in VOLATILE_KEYS:
        return True
    return any(word in VOLATILE_WORDS for word in re.split(r"[_\-/. ]+", key.lower()))


def scrub(value: Any, work: str = "") -> Any:
    """Drop volatile keys recursively (and the temporary folder from strings), keeping
    everything a behaviour change would move."""
    if isinstance(value, dict):
        return {k: scrub(v, work) for k, v in value.items() if not volatile(str(k))}
    if isinstance(value, list):
        return [scrub(v, work) for v in value]
    if isinstance(value, str) and work:
        return value.replace(work, "<work>")
    return value


def scrub_text(text: str, work: Path) -> str:
    """Remove temporary paths and timing figures from a text report."""
    text = text.replace(str(work), "<work>")
    text = re.sub(r"\d+(\.\d+)? ?(s|min|ms)\b(?! *[A-Za-z(])", "<time>", text)
    text = re.sub(r"(?i)(took|in|time|elapsed)[: ]+[\d.]+ ?s\b", r"\1 <time>", text)
    return text


TIMED_COLUMN = re.compile(r"(wall|time_s|fps|time_elapsed|\[s\])", re.IGNORECASE)


def scrub_csv(text: str) -> str:
    """Drop the columns of a CSV file that hold wall-clock time."""
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        return text
    keep = [i for i, name in enumerate(rows[0]) if not TIMED_COLUMN.search(name)]
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    for row in rows:
        writer.writerow([row[i] for i in keep if i < len(row)])
    return buffer.getvalue()


def scrub_markdown(text: str) -> str:
    """Blank the cells of Markdown table columns that hold wall-clock time."""
    out: list[str] = []
    drop: set[int] = set()
    for line in text.splitlines():
        if not line.startswith("|"):
            drop = set()
            out.append(line)
            continue
        cells = line.split("|")
        if not drop and not set(line) <= set("|-: "):
            found = {i for i, cell in enumerate(cells) if TIMED_COLUMN.search(cell)}
            if found:
                drop = found
                out.append(line)
                continue
        out.append("|".join("" if i in drop else c for i, c in enumerate(cells)))
    return "\n".join(out) + "\n"


def odomgym(*args: str, cwd: Path) -> str:
    env = dict(os.environ, ODOMGYM_PROGRESS="0", PYTHONHASHSEED="0")
    proc = subprocess.run(
        [sys.executable, "-m", "odomgym.cli", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"odomgym {' '.join(args)} failed:\n{proc.stderr[-3000:]}")
    return proc.stdout


def dump_json(text: str, work: str = "") -> str:
    """One JSON document, or JSON lines, scrubbed and printed in a stable form."""
    try:
        docs = [json.loads(text)]
    except json.JSONDecodeError:
        docs = [json.loads(line) for line in text.splitlines() if line.strip()]
    return "".join(json.dumps(scrub(doc, work), indent=1, sort_keys=True) + "\n" for doc in docs)


def job_cli(args: list[str], *, as_json: bool, files: tuple[str, ...] = ()) -> Any:
    def run(work: Path, out: Path) -> None:
        stdout = odomgym(*args, cwd=work)
        (out / "stdout").write_text(
            dump_json(stdout, str(work)) if as_json else scrub_text(stdout, work)
        )
        for name in files:
            for path in sorted(work.glob(name)):
                rel = path.relative_to(work).as_posix().replace("/", "__")
                if path.suffix in (".json",):
                    data = dump_json(path.read_text(), str(work))
                elif path.suffix == ".jsonl":
                    data = "".join(
                        json.dumps(scrub(json.loads(line), str(work)), sort_keys=True) + "\n"
                        for line in path.read_text().splitlines()
                        if line.strip()
                    )
                elif path.suffix == ".csv":
                    data = scrub_csv(path.read_text())
                elif path.suffix == ".md":
                    data = scrub_markdown(scrub_text(path.read_text(), work))
                elif path.suffix in (".txt", ".toml", ".yaml"):
                    data = scrub_text(path.read_text(), work)
                else:
                    continue
                (out / rel).write_text(data)

    return run


def job_env_traces(work: Path, out: Path) -> None:
    """Step every registered env (and the native vector env) with seeded random actions."""
    import gymnasium as gym
    import numpy as np

    import odomgym.envs  # noqa: F401  (registers the ids)

    lines = []
    for env_id in sorted(
        k for k in gym.registry if k.startswith(("UMBmark", "Straight", "Clapper", "SelfCal"))
    ):
        env = gym.make(env_id)
        env.action_space.seed(7)
        obs, info = env.reset(seed=3)
        digest = hashlib.sha256()
        digest.update(np.asarray(obs, dtype=np.float64).tobytes())
        total = 0.0
        steps = 0
        for _ in range(400 if not env_id.startswith("SelfCal") else 12):
            obs, reward, term, trunc, info = env.step(env.action_space.sample())
            digest.update(np.asarray(obs, dtype=np.float64).tobytes())
            digest.update(repr(sorted((k, repr(v)) for k, v in info.items())).encode())
            total += float(reward)
            steps += 1
            if term or trunc:
                obs, info = env.reset()
        env.close()
        lines.append(f"{env_id} steps={steps} reward_sum={total!r} sha={digest.hexdigest()}")
    env = gym.make_vec("UMBmarkSquare-v0", num_envs=4, vectorization_mode="vector_entry_point")
    env.action_space.seed(7)
    obs, info = env.reset(seed=5)
    digest = hashlib.sha256(np.asarray(obs).tobytes())
    for _ in range(300):
        obs, reward, term, trunc, info = env.step(env.action_space.sample())
        digest.update(np.asarray(obs).tobytes())
        digest.update(np.asarray(reward).tobytes())
        digest.update(repr(sorted((k, repr(v)) for k, v in info.items())).encode())
    env.close()
    lines.append(f"vector UMBmarkSquare-v0 x4 sha={digest.hexdigest()}")
    (out / "traces.txt").write_text("\n".join(lines) + "\n")


def job_diagnose_synthetic(work: Path, out: Path) -> None:
    """Logs of a robot with a hidden wheel-diameter error, diagnosed against the nominal model."""
    odomgym(
        "run",
        "square",
        "--robot",
        "labmate",
        "--ed",
        "1.003",
        "--runs",
        "3",
        "--side",
        "2",
        "--log",
        "runs.csv",
        cwd=work,
    )
    job_cli(
        ["diagnose", "runs.csv", "--robot", "labmate", "--out", "diag", "--json"],
        as_json=True,
        files=("diag/*.json", "diag/*.md"),
    )(work, out)


JOBS: dict[str, Any] = {
    "bench": job_cli(
        [
            "bench",
            "calibrators",
            "--robots",
            "6",
            "--jobs",
            "2",
            "--budget",
            "16",
            "8",
            "--out",
            "bench",
            "--json",
        ],
        as_json=True,
        files=("bench/*.json", "bench/*.md", "bench/*.csv", "bench/journal.jsonl"),
    ),
    "calibrate-umbmark": job_cli(
        ["calibrate", "umbmark", "--robot", "labmate", "--floor", "concrete", "--json"],
        as_json=True,
    ),
    "calibrate-umbmark-data": job_cli(
        [
            "calibrate",
            "umbmark",
            "--data",
            "optiodom:square/230620202042",
            "--conventions",
            "optiodom",
            "--json",
        ],
        as_json=True,
    ),
    "calibrate-selfcal": job_cli(
        ["calibrate", "selfcal", "--robot", "labmate", "--floor", "rough", "--json"], as_json=True
    ),
    "calibrate-selfcal-scripted": job_cli(
        [
            "calibrate",
            "selfcal",
            "--policy",
            "scripted",
            "--robot",
            "labmate",
            "--floor",
            "concrete",
            "--json",
        ],
        as_json=True,
    ),
    "calibrate-trajectory": job_cli(
        ["calibrate", "trajectory", "--robot", "labmate", "--floor", "concrete", "--json"],
        as_json=True,
    ),
    "leaderboard": job_cli(["leaderboard", "--data", "optiodom:", "--json"], as_json=True),
    "run-square": job_cli(
        [
            "run",
            "square",
            "--robot",
            "labmate",
            "--ed",
            "1.002",
            "--direction",
            "both",
            "--runs",
            "3",
            "--json",
            "--log",
            "runs.csv",
        ],
        as_json=True,
        files=("runs.csv",),
    ),
    "run-straight": job_cli(
        [
            "run",
            "straight",
            "--robot",
            "labmate",
            "--floor",
            "bumpy",
            "--distance",
            "6",
            "--return-trip",
            "--json",
        ],
        as_json=True,
    ),
    "clapper-straight": job_cli(["run", "clapper-straight", "--json"], as_json=True),
    "clapper-rectangle-trailer": job_cli(
        ["run", "clapper-rectangle", "--vehicle", "trailer", "--runs", "2", "--json"],
        as_json=True,
    ),
    "covariance": job_cli(
        [
            "covariance",
            "--left",
            "3",
            "--right",
            "1",
            "--wheelbase",
            "0.4",
            "--kl",
            "0.001",
            "--kr",
            "0.001",
            "--montecarlo",
            "2000",
            "--json",
        ],
        as_json=True,
    ),
    "fit-noise": job_cli(["fit-noise", "--data", "optiodom:", "--json"], as_json=True),
    "diagnose-data": job_cli(
        [
            "diagnose",
            "optiodom:square/230620202042",
            "--robot",
            str(REPO / "examples/optiodom_nominal.toml"),
            "--out",
            "diag",
            "--json",
        ],
        as_json=True,
        files=("diag/*.json", "diag/*.md"),
    ),
    "diagnose-synthetic": job_diagnose_synthetic,
    "train": job_cli(
        [
            "train",
            "selfcal",
            "--steps",
            "256",
            "--envs",
            "4",
            "--workers",
            "2",
            "--out",
            "tr",
            "--json",
        ],
        as_json=True,
        files=("tr/*.json", "tr/progress.csv"),
    ),
    "env-traces": job_env_traces,
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="snapshot folder (replaced)")
    parser.add_argument("--only", nargs="+", choices=sorted(JOBS), help="run just these jobs")
    args = parser.parse_args()
    names = args.only or list(JOBS)
    args.out.mkdir(parents=True, exist_ok=True)
    for name in names:
        target = args.out / name
        shutil.rmtree(target, ignore_errors=True)
        target.mkdir()
        start = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            JOBS[name](Path(tmp), target)
        print(f"{name:28s} {time.perf_counter() - start:6.1f} s", flush=True)
    manifest = []
    for path in sorted(args.out.rglob("*")):
        if path.is_file() and path.name != "MANIFEST.txt":
            sha = hashlib.sha256(path.read_bytes()).hexdigest()
            manifest.append(f"{sha}  {path.relative_to(args.out).as_posix()}")
    (args.out / "MANIFEST.txt").write_text("\n".join(manifest) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

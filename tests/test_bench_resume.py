"""Interrupted and failing benchmark runs: SIGTERM stops every worker within seconds and exits
143, the finished robots are recorded, ``--resume`` gives the tables of an uninterrupted run;
a worker that dies is retried once, and one that dies twice marks its robots failed."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterable
from pathlib import Path

import pytest

from odomgym.baselines.benchmark import (
    FAULT_VARIABLE,
    BenchConfig,
    Journal,
    run_benchmark,
)
from odomgym.cli import main
from odomgym.errors import SpecError

ARGS = ["--robots", "4", "--floor", "concrete", "--methods", "umbmark", "--budget", "4"]
CONFIG = BenchConfig(robots=4, floors=("concrete",), methods=("umbmark",), budget=4)


def _comparable(rows: list[dict]) -> list[dict]:
    """Rows without the wall time (the only entry that depends on the machine's load)."""
    return [{k: v for k, v in r.items() if k != "wall_time_s"} for r in rows]


@pytest.fixture(scope="module")
def reference() -> list[dict]:
    return _comparable(run_benchmark(CONFIG, jobs=1))


def _children(pid: int) -> list[int]:
    found = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        text = (task / "children").read_text().split()
        found += [int(t) for t in text]
    return found


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")
    except OSError:
        return ""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    status = Path(f"/proc/{pid}/status")
    return status.exists() and "State:\tZ" not in status.read_text()


def _terminate(process: subprocess.Popen[str], workers: Iterable[int], timeout: float) -> str:
    """SIGTERM ``process``: it must exit 143 within 10 s and leave none of ``workers`` alive.
    Returns its stderr."""
    process.send_signal(signal.SIGTERM)
    start = time.monotonic()
    _, err = process.communicate(timeout=timeout)
    assert process.returncode == 143, err
    assert time.monotonic() - start < 10
    time.sleep(1.0)  # multiprocessing's resource tracker exits when it sees the parent gone
    survivors = {pid: _cmdline(pid) for pid in workers if _alive(pid)}
    assert not survivors, f"outlived the command: {survivors}"
    return err


@pytest.mark.slow
def test_sigterm_stops_the_workers_and_resume_gives_the_same_tables(
    tmp_path: Path, reference: list[dict], capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "bench"
    command = [sys.executable, "-m", "odomgym", "bench", "calibrators", *ARGS]
    process = subprocess.Popen(
        [*command, "--jobs", "2", "--chunk", "1", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    journal = out / "journal.jsonl"
    deadline = time.monotonic() + 120
    workers: list[int] = []
    while time.monotonic() < deadline:  # wait for the first finished robot
        if journal.exists() and len(journal.read_text().splitlines()) >= 2:
            break
        workers = _children(process.pid) or workers
        time.sleep(0.1)
    else:
        process.kill()
        pytest.fail("no robot finished within 120 s")
    workers = _children(process.pid) or workers
    err = _terminate(process, workers, timeout=20)
    assert "--resume" in err.strip().splitlines()[-1]
    assert not (out / "results.json").exists()  # no half-written outputs
    recorded = len(journal.read_text().splitlines()) - 1
    assert 1 <= recorded < 4

    assert main(["bench", "calibrators", *ARGS, "--jobs", "2", "--out", str(out), "--resume"]) == 0
    capsys.readouterr()
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert _comparable(rows) == [{k: v for k, v in r.items() if k != "scatter"} for r in reference]
    assert not journal.exists()


@pytest.mark.slow
def test_a_dead_worker_is_retried_once_then_its_robots_are_marked_failed(
    monkeypatch: pytest.MonkeyPatch, reference: list[dict]
) -> None:
    said: list[str] = []
    monkeypatch.setenv(FAULT_VARIABLE, "exit-once:1")
    rows = run_benchmark(CONFIG, jobs=2, chunk=1, notify=said.append)
    assert _comparable(rows) == reference
    assert said == ["worker for robots 1-1 died (exit code 86); retrying once"]

    said.clear()
    monkeypatch.setenv(FAULT_VARIABLE, "exit-always:2")
    rows = run_benchmark(CONFIG, jobs=2, chunk=1, notify=said.append)
    failed = [r for r in rows if r["failed"]]
    assert [r["robot"] for r in failed] == [2]
    assert "worker died twice (exit code 86)" in failed[0]["failed"]
    assert _comparable([r for r in rows if r["robot"] != 2]) == [
        r for r in reference if r["robot"] != 2
    ]
    assert len(said) == 2 and said[1].endswith("died again; marked failed")


def test_a_journal_of_another_configuration_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "journal.jsonl"
    Journal(path, CONFIG).start()
    other = BenchConfig(robots=5, floors=("concrete",), methods=("umbmark",), budget=4)
    with pytest.raises(SpecError, match="another benchmark configuration"):
        Journal(path, other).read()
    with path.open("a") as f:
        f.write('{"robots": [0], "rows": [')  # cut short by an interruption: ignored
    assert Journal(path, CONFIG).read() == {}
    with path.open("a") as f:
        f.write("\n{}\n")
    with pytest.raises(SpecError, match=r"journal.jsonl:2: damaged entry"):
        Journal(path, CONFIG).read()


@pytest.mark.slow
def test_sigterm_stops_diagnose_and_its_workers(tmp_path: Path) -> None:
    """``diagnose --jobs 2`` killed while fitting: exit 143 within seconds, its forked workers
    gone, no output folder."""
    repo = Path(__file__).resolve().parents[1]
    out = tmp_path / "diag"
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "odomgym",
            "diagnose",
            "optiodom:square/230620202042",
            "--robot",
            "examples/optiodom_nominal.toml",
            "--out",
            str(out),
            "--jobs",
            "2",
        ],
        cwd=repo,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    workers: set[int] = set()
    deadline = time.monotonic() + 60
    while len(workers) < 2 and time.monotonic() < deadline:  # until both workers fit
        workers |= set(_children(process.pid)) if _alive(process.pid) else set()
        time.sleep(0.1)
    assert len(workers) >= 2, "diagnose never started its workers"
    _terminate(process, workers, timeout=30)
    assert not out.exists()


@pytest.mark.slow
def test_sigterm_stops_training_and_its_workers(tmp_path: Path) -> None:
    """``train selfcal --workers 2`` killed while training: exit 143 within seconds, both
    simulation workers gone, no policy or model written."""
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "train"
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "odomgym",
            "train",
            "selfcal",
            "--steps",
            "100000",
            "--envs",
            "4",
            "--workers",
            "2",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    workers: set[int] = set()
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:  # until the first rollout is logged
        workers |= set(_children(process.pid)) if _alive(process.pid) else set()
        if (out / "progress.csv").exists() and (out / "progress.csv").stat().st_size > 0:
            break
        time.sleep(0.2)
    else:
        process.kill()
        pytest.fail("training logged nothing within 90 s")
    _terminate(process, workers, timeout=30)
    assert not (out / "policy.npz").exists() and not (out / "model.zip").exists()

"""Interrupted and failing benchmark runs: SIGTERM stops every worker within seconds and exits
143, the finished robots are recorded, ``--resume`` gives the tables of an uninterrupted run;
a worker that dies is retried once, and one that dies twice marks its robots failed."""

from __future__ import annotations

import functools
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterable
from pathlib import Path

import pytest
from faults import exiting_chunk

from odomgym.baselines.benchmark import (
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
        try:
            text = (task / "children").read_text().split()
        except OSError:  # the thread or process has just ended
            continue
        found += [int(t) for t in text]
    return found


def _descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (Ray's are grandchildren: the raylet starts the workers)."""
    found: list[int] = []
    todo = [pid]
    while todo:
        for child in _children(todo.pop()):
            if child not in found:
                found.append(child)
                todo.append(child)
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


def _bench_until_a_robot_is_recorded(
    out: Path, extra: list[str], timeout: float
) -> tuple[subprocess.Popen[str], list[int]]:
    """Start ``bench calibrators`` (2 jobs, chunks of one robot) and return it, with its worker
    processes, once the journal records a finished robot."""
    command = [sys.executable, "-m", "odomgym", "bench", "calibrators", *ARGS, *extra]
    process = subprocess.Popen(
        [*command, "--jobs", "2", "--chunk", "1", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    journal = out / "journal.jsonl"
    deadline = time.monotonic() + timeout
    workers: list[int] = []
    while time.monotonic() < deadline:
        if journal.exists() and len(journal.read_text().splitlines()) >= 2:
            return process, _children(process.pid) or workers
        workers = _children(process.pid) or workers
        time.sleep(0.1)
    process.kill()
    pytest.fail(f"no robot finished within {timeout:g} s")


@pytest.mark.slow
def test_sigterm_stops_the_workers_and_resume_gives_the_same_tables(
    tmp_path: Path, reference: list[dict], capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "bench"
    process, workers = _bench_until_a_robot_is_recorded(out, [], timeout=120)
    journal = out / "journal.jsonl"
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
def test_sigterm_stops_the_ray_workers_and_resume_gives_the_same_tables(
    tmp_path: Path, reference: list[dict], capsys: pytest.CaptureFixture[str]
) -> None:
    """The same on ``--backend ray``: exit 143 within seconds (not Ray's own exit or its
    stack dump), every process of the local Ray it started gone (GCS, raylet, agents, the
    workers running chunks), and the resumed tables equal an uninterrupted run's."""
    ray = pytest.importorskip("ray")
    out = tmp_path / "bench"
    process, _ = _bench_until_a_robot_is_recorded(out, ["--backend", "ray"], timeout=180)
    journal = out / "journal.jsonl"
    ray_processes = _descendants(process.pid)
    assert any("raylet" in _cmdline(pid) for pid in ray_processes), ray_processes
    err = _terminate(process, ray_processes, timeout=20)
    assert "--resume" in err.strip().splitlines()[-1] and "SIGTERM received" not in err
    assert not (out / "results.json").exists()
    assert 1 <= len(journal.read_text().splitlines()) - 1 < 4

    resume = ["bench", "calibrators", *ARGS, "--backend", "ray", "--jobs", "2", "--resume"]
    try:
        assert main([*resume, "--out", str(out)]) == 0
    finally:
        ray.shutdown()
    capsys.readouterr()
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert _comparable(rows) == [{k: v for k, v in r.items() if k != "scatter"} for r in reference]


@pytest.mark.slow
def test_a_dead_worker_is_retried_once_then_its_robots_are_marked_failed(
    reference: list[dict],
) -> None:
    said: list[str] = []
    once = functools.partial(exiting_chunk, robot=1, always=False)
    rows = run_benchmark(CONFIG, jobs=2, chunk=1, notify=said.append, task=once)
    assert _comparable(rows) == reference
    assert said == ["worker for robots 1-1 died (exit code 86); retrying once"]

    said.clear()
    always = functools.partial(exiting_chunk, robot=2, always=True)
    rows = run_benchmark(CONFIG, jobs=2, chunk=1, notify=said.append, task=always)
    failed = [r for r in rows if r["failed"]]
    assert [r["robot"] for r in failed] == [2] * len(CONFIG.labels())  # every row of robot 2
    assert "worker died twice (exit code 86)" in failed[0]["failed"]
    assert _comparable([r for r in rows if r["robot"] != 2]) == [
        r for r in reference if r["robot"] != 2
    ]
    assert len(said) == 2 and said[1].endswith("died again; marked failed")


def test_a_journal_of_another_configuration_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "journal.jsonl"
    Journal(path, CONFIG).start()
    other = BenchConfig(robots=5, floors=("concrete",), methods=("umbmark",), budget=8)
    # Named setting by setting (a dump of the whole configuration before).
    with pytest.raises(
        SpecError, match=r"configuration \(budget 4 then, 8 now; robots 4 then, 5 now\)"
    ):
        Journal(path, other).read()
    with path.open("a") as f:
        f.write('{"robots": [0], "rows": [')  # cut short by an interruption: ignored
    assert Journal(path, CONFIG).read() == {}
    with path.open("a") as f:
        f.write("\n{}\n")
    with pytest.raises(SpecError, match=r"journal.jsonl:2: damaged entry"):
        Journal(path, CONFIG).read()


def test_bench_refuses_what_it_would_run_wrongly_before_any_robot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Three inputs that ran: ``--resume`` without a journal started over (a finished
    benchmark's ran every robot again), a method named twice ran twice and counted as twice
    the robots, and a budget beyond selfcal's 64 runs failed robot by robot after the other
    methods had driven it. Each is one line now, before any robot."""
    from cli_errors import one_line_error

    out = tmp_path / "out"
    base = ["bench", "calibrators", "--robots", "1", "--floor", "concrete", "--out", str(out)]
    assert main([*base, "--resume"]) == 2
    one_line_error(capsys, "journal.jsonl: no journal to resume from")
    assert main([*base, "--methods", "umbmark", "lee", "umbmark"]) == 2
    one_line_error(capsys, "'umbmark' given twice")
    assert main([*base, "--budget", "4", "1000"]) == 2
    one_line_error(capsys, "selfcal takes a budget of at most 64 runs, got 1000")
    assert not out.exists()


def test_a_journal_of_another_format_is_refused_in_one_line(tmp_path: Path) -> None:
    """A journal an older or newer odomgym wrote (another format version, or none) is refused
    with one line naming both formats, never read as this one's."""
    path = tmp_path / "journal.jsonl"
    for header in ('{"journal": 0, "config": {}}', '{"config": {}}', "[1, 2]"):
        path.write_text(header + '\n{"robots": [0], "rows": []}\n')
        with pytest.raises(SpecError, match="format") as caught:
            Journal(path, CONFIG).read()
        assert "\n" not in str(caught.value)
        assert "run without --resume" in str(caught.value)


DIAGNOSE = [
    "diagnose",
    "optiodom:square/230620202042",
    "--robot",
    "examples/optiodom_nominal.toml",
    "--jobs",
    "2",
    "--max-rounds",
    "2",  # two rounds: a resumed second round, at half the time of the full diagnosis
    "--json",
]


def _fits(journal: Path) -> list[Path]:
    """The stored fits (not the writer's hidden temporaries)."""
    return [p for p in journal.glob("*.pkl") if not p.name.startswith(".")]


@pytest.mark.slow
def test_sigterm_stops_diagnose_and_resume_gives_the_same_report(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``diagnose --jobs 2`` killed while fitting: exit 143 within seconds, its forked workers
    gone, no output folder, the finished fits kept in OUT.journal; ``--resume`` takes them and
    writes the report an uninterrupted run writes."""
    repo = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(repo)
    out = tmp_path / "diag"
    journal = tmp_path / "diag.journal"
    process = subprocess.Popen(
        [sys.executable, "-m", "odomgym", *DIAGNOSE, "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    workers: set[int] = set()
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # until the workers have finished two fits
        workers |= set(_children(process.pid)) if _alive(process.pid) else set()
        if len(_fits(journal)) >= 2:
            break
        time.sleep(0.1)
    else:
        process.kill()
        pytest.fail("diagnose stored no fit within 120 s")
    assert len(workers) >= 2, "diagnose never started its workers"
    _terminate(process, workers, timeout=30)
    assert not out.exists()
    assert not [p.name for p in journal.iterdir() if p.name.startswith(".")], "a temporary left"
    kept = len(_fits(journal))

    capsys.readouterr()
    assert main([*DIAGNOSE, "--out", str(out), "--resume"]) == 0
    assert f"resumed: {kept} candidate fits taken from" in capsys.readouterr().err
    assert not journal.exists(), "the journal outlived the finished diagnosis"
    fresh = tmp_path / "fresh"
    assert main([*DIAGNOSE, "--out", str(fresh)]) == 0
    resumed = json.loads((out / "report.json").read_text())
    assert resumed == json.loads((fresh / "report.json").read_text())
    assert kept >= 2 and resumed["rounds"], resumed


@pytest.mark.slow
def test_sigterm_stops_training_and_resume_goes_on_from_the_checkpoint(tmp_path: Path) -> None:
    """``train selfcal --workers 2`` killed while training: exit 143 within seconds, both
    simulation workers gone, no policy or model written, the last checkpoint whole;
    ``--resume`` trains on from it to the total, and one learning curve covers both."""
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "train"
    args = ["train", "selfcal", "--envs", "4", "--workers", "2", "--checkpoint-every", "128"]
    args += ["--eval-sessions", "2"]  # the evaluation after training is not what is tested
    process = subprocess.Popen(
        [sys.executable, "-m", "odomgym", *args, "--steps", "100000", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    record = out / "checkpoint.json"
    workers: set[int] = set()
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # until a checkpoint is written
        workers |= set(_children(process.pid)) if _alive(process.pid) else set()
        if record.exists():
            break
        time.sleep(0.2)
    else:
        process.kill()
        pytest.fail("training wrote no checkpoint within 120 s")
    time.sleep(1.0)  # into the next rollout
    _terminate(process, workers, timeout=30)
    assert not (out / "policy.npz").exists() and not (out / "model.zip").exists()
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")], "a temporary was left"
    steps = json.loads(record.read_text())["steps"]
    assert steps >= 128 and steps % 128 == 0

    total = steps + 128
    assert main([*args, "--steps", str(total), "--out", str(out), "--resume", "--json"]) == 0
    meta = json.loads((out / "policy.json").read_text())
    assert meta["steps"] == total and meta["resumed_at_steps"] == [steps]
    curve = (out / "progress.csv").read_text().splitlines()[1:]
    header = (out / "progress.csv").read_text().splitlines()[0].split(",")
    logged = [int(row.split(",")[header.index("time/total_timesteps")]) for row in curve]
    assert logged == list(range(128, total + 1, 128))
    assert not record.exists() and not (out / "checkpoint.zip").exists()


def test_resume_refuses_a_missing_or_different_checkpoint(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--resume`` with no checkpoint, or one made with another seed: one line, no work."""
    pytest.importorskip("stable_baselines3")
    from odomgym.baselines.selfcal_checkpoints import Checkpoints

    out = tmp_path / "train"
    args = ["train", "selfcal", "--steps", "256", "--envs", "4", "--out", str(out), "--resume"]
    assert main(args) == 2
    assert "no checkpoint to resume from" in capsys.readouterr().err
    out.mkdir()
    (out / "checkpoint.zip").write_bytes(b"")
    settings = {"algo": "ppo", "n_envs": 4, "seed": 7, "policy": "MlpPolicy"}
    record = {"steps": 128, "wall_time_s": 1.0, "resumed_at": [], "settings": settings}
    (out / "checkpoint.json").write_text(json.dumps(record))
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "seed 7 then, 0 now" in err[0], err
    (out / "checkpoint.json").write_text("{not json")
    with pytest.raises(SpecError, match="not a checkpoint record"):
        Checkpoints(out).read(settings)


class _Swallowing:
    """What a finalizer does to an exception: a stop raised in ``__del__`` is printed and
    dropped (pymunk frees its bodies from such callbacks, where a SIGTERM was lost)."""

    def __del__(self) -> None:
        from odomgym import interrupt

        interrupt.stop(143, "stopped by SIGTERM")


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # the dropped raise
def test_a_stop_swallowed_by_a_finalizer_still_stops_the_command(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The request is recorded: the next unit of progress raises it again (diagnose stops at
    its next candidate, exit 143), and one that comes after the last check is still reported
    as 143 (covariance, which has no loop)."""
    import odomgym.diagnose.workflow as workflow

    real = workflow.localise

    def localise_then_signal(*args: object, **kwargs: object) -> object:
        _Swallowing()  # created and collected at once: its raise is dropped
        return real(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(workflow, "localise", localise_then_signal)
    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    out = tmp_path / "diag"
    assert main([*DIAGNOSE[:4], "--jobs", "1", "--out", str(out)]) == 143
    err = capsys.readouterr().err
    assert err.strip().endswith("odomgym: stopped by SIGTERM")
    assert not out.exists()

    from odomgym.cli import covariance

    real_covariance = covariance.run

    def covariance_then_signal(args: object) -> int:
        code = real_covariance(args)  # type: ignore[arg-type]
        _Swallowing()
        return code

    monkeypatch.setattr(covariance, "run", covariance_then_signal)
    argv = ["covariance", "--left", "1", "--right", "1", "--wheelbase", "0.5", "--kl", "0.01"]
    assert main([*argv, "--kr", "0.01"]) == 143
    assert capsys.readouterr().err.strip().endswith("odomgym: stopped by SIGTERM")

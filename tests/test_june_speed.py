"""``benchmarks/june_speed.py``: its summary and table of two trees' timed runs (the timing
itself is the benchmark's, never a test's)."""

from __future__ import annotations

from pathlib import Path

import pytest
from benchmark_module import load_benchmark

ROOT = Path(__file__).resolve().parent.parent


def test_the_side_by_side_benchmark_reports_medians_ratio_and_the_target() -> None:
    """``benchmarks/june_speed.py``'s summary of two trees' runs: each median, the ratio of the
    first tree's to the second's, whether every run of a tree met the 60 s target, and whether
    the two reports were the same bytes."""
    bench = load_benchmark("june_speed")
    this = bench.Tree("this tree", ROOT, [58.0, 61.0, 55.0], b"{}")
    other = bench.Tree("v0.3.0", ROOT, [60.0, 64.0, 62.0], b"{}")
    result = bench.summary([this, other])
    assert result["trees"]["this tree"]["median_s"] == 58.0
    assert result["trees"]["v0.3.0"]["median_s"] == 62.0
    assert result["ratio"] == 58.0 / 62.0
    assert result["trees"]["this tree"]["every_run_within_target"] is False
    assert result["same_report"] is True
    text = bench.table([this, other], result)
    assert "| median | **58.0** | **62.0** |" in text
    assert "ratio this tree / v0.3.0: 0.935" in text
    other.report = b"[]"
    assert bench.summary([this, other])["same_report"] is False
    alone = bench.summary([bench.Tree("this tree", ROOT, [50.0], b"")])
    assert "ratio" not in alone and alone["trees"]["this tree"]["every_run_within_target"]
    assert "machine" not in alone


def test_the_machine_probe_is_set_beside_the_reference_machine() -> None:
    """With the machine probe's figure, the summary gives it, the reference machine's and their
    ratio, and the table says how much slower this machine is."""
    bench = load_benchmark("june_speed")
    tree = bench.Tree("this tree", ROOT, [120.0], b"{}")
    result = bench.summary([tree], probe_ms=4.0)
    assert result["machine"] == {"filter_ms": 4.0, "reference_ms": 2.5, "factor": 1.6}
    assert "4.00 ms against 2.50 ms" in bench.table([tree], result)
    assert "1.60× as slow" in bench.table([tree], result)
    # The probe's script is valid Python once its paths are filled in.
    compile(bench._PROBE.format(robot="robot.toml", data="june"), "probe", "exec")


def test_a_diagnosis_is_timed_stage_by_stage() -> None:
    """``--stages``: each progress report's stage lasts until a report of another stage; a
    round's candidates are one stage, its structure test and discovery two more; time before
    the first report is its own stage; a stage that comes back adds up."""
    bench = load_benchmark("june_speed")
    compile(bench._STAGES.format(robot="robot.toml", data="june", jobs=2), "stages", "exec")
    assert bench.stage_of("round 4: wheelbase") == "round 4: candidate fits"
    assert bench.stage_of("round 4: mean candidates") == "round 4: candidate fits"
    assert bench.stage_of("round 5: structure") == "round 5: structure"
    assert bench.stage_of("round 5: discovery") == "round 5: discovery"
    assert bench.stage_of("open-loop check 1: backlash") == "open-loop check 1"
    assert bench.stage_of("held-out test") == "held-out test"
    events = [
        (1.0, "measurement nuisances"),
        (3.0, "round 1: wheelbase"),
        (4.5, "round 1: backlash"),
        (6.0, "round 1: structure"),
        (7.0, "round 2: wheelbase"),
        (9.0, "measurement nuisances"),
        (9.5, "shrink"),
    ]
    times = bench.stage_times(0.0, 10.0, events)
    assert list(times) == [
        "before the first report",
        "measurement nuisances",
        "round 1: candidate fits",
        "round 1: structure",
        "round 2: candidate fits",
        "shrink",
    ]
    assert times["before the first report"] == 1.0
    assert times["measurement nuisances"] == 2.0 + 0.5
    assert times["round 1: candidate fits"] == 3.0
    assert times["shrink"] == 0.5
    assert sum(times.values()) == 10.0
    text = bench.stage_table(times)
    assert "| round 1: candidate fits | 3.0 |" in text
    assert text.endswith("| **total** | **10.0** |")


def test_stages_are_timed_alone(capsys: pytest.CaptureFixture[str]) -> None:
    """``--stages`` times one diagnosis of this tree: with ``--against``, ``--runs`` or
    ``--keep`` it stops at once with one line (before gathering any data)."""
    bench = load_benchmark("june_speed")
    for extra in (["--against", "HEAD"], ["--runs", "2"], ["--keep", "out"]):
        with pytest.raises(SystemExit) as stopped:
            bench.main(["--stages", *extra])
        assert stopped.value.code == 2
        assert "--stages times one diagnosis of this tree" in capsys.readouterr().err

"""The command line: tables, JSON lines, plots, and clean failures on bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from odomgym.cli import main


def test_run_square_table_and_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plot = tmp_path / "scatter.png"
    code = main(
        ["run", "square", "--robot", "labmate", "--runs", "2", "--side", "2", "--plot", str(plot)]
    )
    out = capsys.readouterr().out
    assert code == 0
    assert "E_max,syst" in out and "centre of gravity cw" in out
    assert plot.exists() and plot.stat().st_size > 1000
    assert not list(tmp_path.glob(".*"))  # no temporary files left behind


def test_run_json_lines(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["run", "square", "--runs", "1", "--side", "1", "--json", "--eb", "1.01"])
    assert code == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    runs = [line for line in lines if "run" in line]
    assert [r["direction"] for r in runs] == ["cw", "ccw"]
    assert set(runs[0]["return_error"]) == {"x", "y", "theta"}
    summary = lines[-1]["summary"]
    assert summary["e_max_syst"] > 0.0


def test_run_straight_with_bumps(capsys: pytest.CaptureFixture[str]) -> None:
    assert (
        main(["run", "straight", "--floor", "bumpy", "--runs", "1", "--distance", "4", "--json"])
        == 0
    )
    record = json.loads(capsys.readouterr().out.splitlines()[0])
    assert record["direction"] is None


def test_bad_inputs_exit_2_with_a_message(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", "square", "--robot", "no-such-robot"]) == 2
    assert "unknown robot preset" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text("wheel_diameter = 0.1\nwheelbase = 0.3\nticks_per_rev = -5\n")
    plot = tmp_path / "never.png"
    assert main(["run", "square", "--robot", str(bad), "--plot", str(plot)]) == 2
    assert f"{bad}:3" in capsys.readouterr().err
    assert not plot.exists()
    with pytest.raises(SystemExit):
        main(["run", "square", "--ed", "nan"])
    with pytest.raises(SystemExit):
        main(["run", "square", "--runs", "0"])

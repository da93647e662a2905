"""``odomgym run clapper-straight|clapper-rectangle``: JSON lines, table, figure."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from odomgym.cli import main


@pytest.mark.slow
def test_clapper_straight_json_lines_and_plot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plot = tmp_path / "fig8.png"
    code = main(
        ["run", "clapper-straight", "--bumps", "4", "--runs", "1", "--json", "--plot", str(plot)]
    )
    assert code == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    runs, summary = lines[:-1], lines[-1]["summary"]
    assert [r["ipec"] for r in runs] == [False, True]
    for record in runs:
        assert set(record["return_error"]) == {"x", "y", "theta"}
        assert set(record["trucks"]) == {"A", "B"} and record["finished"]
    # Four bumps: without IPEC ~4 x 0.58 deg of heading error, with IPEC a small fraction.
    assert abs(runs[0]["return_error"]["theta"]) > 0.03
    assert summary["reduction"]["theta_truck_a"] > 5.0
    assert runs[0]["cable_crossings"] == {"A": 4, "B": 4}
    assert plot.stat().st_size > 0


def test_clapper_rectangle_no_ipec_table(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(
        ["run", "clapper-rectangle", "--bumps", "0", "--runs", "1", "--no-ipec",
         "--direction", "ccw", "--floor", "smooth"]
    )  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out
    assert "without IPEC" in out and "with IPEC" not in out
    assert "IPEC reduces" not in out


@pytest.mark.slow
def test_clapper_straight_runs_the_papers_conditions(capsys: pytest.CaptureFixture[str]) -> None:
    """Without --bumps/--ipec the command runs §6.1's conditions a–d (three runs each by
    default; one here) and prints each one's distribution and the reduction per truck."""
    code = main(["run", "clapper-straight", "--runs", "1"])
    assert code == 0
    out = capsys.readouterr().out
    assert "floor concrete" in out and "IPEC recommended" in out and "steering psi" in out
    for label in ("a: IPEC off, 0 cables", "b: IPEC off, 10 cables", "d: IPEC on, 20 cables"):
        assert label in out
    assert "fold (truck A)" in out

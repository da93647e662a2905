"""``odomgym fleet``: the fleet layout, the comparison across robots, and the command.

The comparison is checked on reports written here with known values (the robust statistics
by hand); one slow test runs the whole command on a small simulated fleet and resumes it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from odomgym.cli import main
from odomgym.diagnose.fleet import (
    MIN_NAMING,
    ROBUST_SD,
    FleetRobot,
    find_fleet,
    format_fleet,
    inputs_digest,
    plot_fleet,
    summarise_fleet,
)
from odomgym.errors import SpecError
from odomgym.robot import PRESETS


def _robot_folder(root: Path, name: str, logs: list[str]) -> Path:
    folder = root / name
    folder.mkdir(parents=True)
    PRESETS["labmate"].save(folder / "robot.toml")
    for log in logs:
        path = folder / log
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("run,experiment,t,ticks_left,ticks_right,x,y,theta\n")
    return folder


def test_the_layout_gives_robots_sessions_and_periods(tmp_path: Path) -> None:
    _robot_folder(tmp_path, "b-robot", ["s1.csv", "s2.csv"])
    _robot_folder(tmp_path, "a-robot", ["2026-10/s1.csv", "2026-11/s1.csv", "2026-11/s2.csv"])
    robots = find_fleet(tmp_path)
    assert [r.name for r in robots] == ["a-robot", "b-robot"]
    assert robots[0].periods == ("2026-10", "2026-11") and len(robots[0].logs) == 3
    assert robots[1].periods == ("",) and len(robots[1].logs) == 2


def test_a_fleet_of_bags_is_read_with_the_bag_options(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ROS 2 bags need their topics: ``fleet --pose-topic …`` hands them to every robot's
    reading (until 0.3.x the command had no such option, and a fleet of bags stopped with
    "reading ROS 2 bags needs --pose-topic"). They enter the inputs' digest only when given,
    so that the digests of a fleet of CSV logs stay as they were."""
    import odomgym.data.logs as logs

    _robot_folder(tmp_path, "r1", ["s1.csv"])
    (plain,) = find_fleet(tmp_path)
    (bags,) = find_fleet(tmp_path, {"pose_topic": "/mocap/pose", "joint_topic": "/js"})
    assert plain.reading == ()
    assert bags.reading == (("joint_topic", "/js"), ("pose_topic", "/mocap/pose"))
    assert inputs_digest(plain, "", None, None) != inputs_digest(bags, "", None, None)
    seen: list[dict[str, object]] = []
    monkeypatch.setattr(
        logs, "read_log", lambda path, **options: seen.append(options) or ([], None)
    )
    from odomgym.diagnose.fleet import read_robot_runs

    read_robot_runs(bags)
    assert seen[0]["pose_topic"] == "/mocap/pose" and seen[0]["joint_topic"] == "/js"
    # The command hands on only what was given: a fleet of CSV logs keeps its digest.
    from odomgym.cli import build_parser
    from odomgym.cli.diagnose import bag_options

    assert bag_options(build_parser().parse_args(["fleet", str(tmp_path)])) == {}
    given = build_parser().parse_args(["fleet", str(tmp_path), "--left-joint", "wl"])
    assert bag_options(given) == {"left_joint": "wl"}


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda root: None, "ROBOTS"),
        (lambda root: (root / "r1").mkdir(), "robot.toml"),
        (lambda root: _robot_folder(root, "r1", []), "logs"),
    ],
)
def test_a_bad_fleet_folder_is_named_in_one_line(tmp_path: Path, make, field: str) -> None:  # type: ignore[no-untyped-def]
    make(tmp_path)
    with pytest.raises(SpecError) as caught:
        find_fleet(tmp_path)
    assert caught.value.field == field and "\n" not in str(caught.value)


def test_logs_both_loose_and_in_period_folders_are_refused(tmp_path: Path) -> None:
    """Loose logs beside period sub-folders made a period named "" whose report folder held
    the others' (on Ray one overwrote the other): one line instead."""
    _robot_folder(tmp_path, "a1", ["s1.csv", "2026-11/s2.csv"])
    with pytest.raises(SpecError) as caught:
        find_fleet(tmp_path)
    assert caught.value.field == "logs" and str(caught.value).startswith(f"{tmp_path / 'a1'}: ")
    assert "both directly (s1.csv) and in period sub-folders (2026-11/)" in str(caught.value)


def test_the_command_refuses_an_out_inside_robots_and_an_example_over_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``fleet .`` from inside the fleet wrote ./fleet-fleet, which every later call took for a
    robot without its robot.toml; ``--example`` over an earlier fleet mixed old robots with the
    new and listed only the new in truth.json. Both are one line now, nothing written; the
    default output of ``fleet .`` lies beside the fleet's folder."""
    from cli_errors import one_line_error

    from odomgym.cli.fleet import _beside

    fleet = tmp_path / "fleet"
    _robot_folder(fleet, "r1", ["s1.csv"])
    monkeypatch.chdir(fleet)
    before = sorted(tmp_path.rglob("*"))
    assert main(["fleet", ".", "--out", "reports"]) == 2
    one_line_error(capsys, "--out reports lies inside ROBOTS (.)")
    assert main(["fleet", "--example", "2", "."]) == 2
    one_line_error(capsys, "ROBOTS . is not empty: --example writes a fleet into a new or empty")
    assert main(["fleet", "--example", "2", "new", "--resume"]) == 2  # silently dropped before
    one_line_error(capsys, "--resume is an option of the fleet's diagnosis; --example only")
    assert sorted(tmp_path.rglob("*")) == before
    assert _beside(Path(".")) == tmp_path / "fleet-fleet"
    assert _beside(Path("..")) == tmp_path.parent / f"{tmp_path.name}-fleet"
    assert _beside(Path("a/fleet")) == Path("a/fleet-fleet")
    # A robot's report folder that holds anything but a report (here the robot's own folder:
    # ROBOTS named "robots", --out its parent) is refused before any work, not after its
    # robot's diagnosis.
    robots = tmp_path / "robots"
    _robot_folder(robots, "r1", ["s1.csv"])
    monkeypatch.chdir(tmp_path)
    assert main(["fleet", "robots", "--out", "."]) == 2
    one_line_error(capsys, "--out robots/r1: holds robot.toml, s1.csv, which diagnose did not")
    # Every robot's logs are read before the first diagnosis: a bad log stops the command at
    # once (it came only when its robot's turn did, after the robots before it).
    import odomgym.diagnose.fleet as fleet_module

    def never(*_: object, **__: object) -> None:
        raise AssertionError("a diagnosis started before every log was read")

    monkeypatch.setattr(fleet_module, "diagnose_fleet", never)
    monkeypatch.chdir(tmp_path)
    assert main(["fleet", "fleet", "--out", "out"]) == 2
    one_line_error(capsys, "fleet/r1/s1.csv:1: no data rows after the header")
    assert not (tmp_path / "out").exists()
    # ... and screened as `diagnose` screens them: a robot whose logs read but hold no heading
    # (too few usable runs) stops the command before any diagnosis, naming the robot.
    blind = _robot_folder(tmp_path / "blind", "r2", ["s1.csv"]) / "s1.csv"
    rows = [f"{run},square,{0.1 * k:.1f},{10 * k},{10 * k},{0.01 * k},0.0," for run in (1, 2, 3)
            for k in range(5)]  # fmt: skip
    blind.write_text(blind.read_text() + "\n".join(rows) + "\n")
    assert main(["fleet", "blind", "--out", "out"]) == 2
    one_line_error(capsys, "robot r2: diagnose needs at least 3 runs with enough ground truth")
    assert not (tmp_path / "out").exists()


def _write_report(
    folder: Path, named: dict[str, dict[str, tuple[float, float]]], terms: tuple[str, ...] = ()
) -> None:
    """A report.json with the keys the fleet reads, as ``DiagnoseResult.as_dict`` writes them
    (the kept terms under ``discovered``, their count as ``terms_kept``)."""
    folder.mkdir(parents=True, exist_ok=True)
    report = {
        "verdict": "explained",
        "named_effects": list(named),
        "discovered": [{"term": term, "value": 0.01, "stderr": 0.001} for term in terms],
        "terms_kept": len(terms),
        "parameters": {
            effect: {p: {"value": v, "stderr": s} for p, (v, s) in values.items()}
            for effect, values in named.items()
        },
    }
    (folder / "report.json").write_text(json.dumps(report))


def test_odd_robots_are_those_beyond_three_robust_standard_deviations(tmp_path: Path) -> None:
    e_b = [1.000, 1.002, 0.998, 1.001, 0.999, 1.003, 0.997, 1.030]  # the last one planted
    robots = []
    for k, value in enumerate(e_b):
        name = f"r{k}"
        named = {"wheelbase": {"e_b": (value, 1e-4)}}
        if k < MIN_NAMING - 1:  # backlash in too few robots for a distribution
            named["backlash"] = {"angle": (0.01 * (k + 1), 1e-3)}
        _write_report(tmp_path / "robots" / name, named, ("yaw_rate",) if k in (2, 5) else ())
        robots.append(FleetRobot(name, tmp_path, PRESETS["labmate"], ((("", tmp_path / "x.csv")),)))
    summary = summarise_fleet(tmp_path, robots)
    median = float(np.median(e_b))
    robust = ROBUST_SD * float(np.median(np.abs(np.array(e_b) - median)))
    stats = summary.fleet[("wheelbase", "e_b")]
    assert stats["median"] == pytest.approx(median) and stats["robust_sd"] == pytest.approx(robust)
    assert [(r, e, p) for r, e, p, _, _ in summary.odd] == [("r7", "wheelbase", "e_b")]
    assert summary.odd[0][4] == pytest.approx((1.030 - median) / robust)
    assert ("backlash", "angle") not in summary.fleet  # named by 4 < MIN_NAMING robots
    assert summary.named["wheelbase"] == [f"r{k}" for k in range(8)]
    assert len(summary.named["backlash"]) == MIN_NAMING - 1
    # A kept term is counted like an effect (until 0.3.x the fleet read the report's count
    # of terms as their list and stopped with an internal error).
    assert summary.terms == {"yaw_rate": ["r2", "r5"]}
    text = format_fleet(summary, "here")
    assert "yaw_rate" in text
    assert "| r7 | `wheelbase.e_b` |" in text
    stale = tmp_path / "fleet_floor_roughness.png"  # an earlier call's effect, named no more
    stale.write_bytes(b"png")
    written = plot_fleet(summary, tmp_path)
    assert sorted(p.name for p in written) == ["fleet_backlash.png", "fleet_wheelbase.png"]
    assert sorted(p.name for p in tmp_path.glob("fleet_*.png")) == sorted(p.name for p in written)


def test_what_moved_between_a_robots_periods(tmp_path: Path) -> None:
    folder = tmp_path / "robots" / "r0"
    _write_report(folder, {"wheelbase": {"e_b": (1.01, 1e-3)}})
    _write_report(tmp_path / "periods" / "r0" / "2026-10", {"wheelbase": {"e_b": (1.000, 1e-3)}})
    _write_report(tmp_path / "periods" / "r0" / "2026-11", {"wheelbase": {"e_b": (1.020, 1e-3)}})
    logs = (("2026-10", tmp_path / "a.csv"), ("2026-11", tmp_path / "b.csv"))
    summary = summarise_fleet(tmp_path, [FleetRobot("r0", tmp_path, PRESETS["labmate"], logs)])
    ((robot, effect, name, first, last, change, z),) = summary.moved
    assert (robot, effect, name, first, last) == ("r0", "wheelbase", "e_b", "2026-10", "2026-11")
    assert change == pytest.approx(0.02) and z == pytest.approx(0.02 / np.hypot(1e-3, 1e-3))


@pytest.mark.slow
def test_the_command_diagnoses_an_example_fleet_and_resumes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two simulated LabMates, one session each (one of them with a planted E_b 5 % off):
    every robot gets its report folder, the fleet its report and a figure per effect named;
    a second run with --resume keeps them."""
    fleet = tmp_path / "fleet"
    assert main(["fleet", "--example", "2", str(fleet), "--sessions", "1"]) == 0
    truth = json.loads((fleet / "truth.json").read_text())
    assert sorted(truth["robots"]) == ["robot-1", "robot-2"]
    out = tmp_path / "out"
    assert main(["fleet", str(fleet), "--out", str(out), "--jobs", "1", "--no-baseline"]) == 0
    for name in ("robot-1", "robot-2"):
        assert (out / "robots" / name / "report.json").exists()
    data = json.loads((out / "fleet.json").read_text())
    assert data["robots"] == ["robot-1", "robot-2"]
    assert "wheelbase" in data["named"]  # the planted robot's E_b at least
    assert (out / "fleet_wheelbase.png").exists()
    before = (out / "fleet.md").read_text()
    capsys.readouterr()
    assert main(["fleet", str(fleet), "--out", str(out), "--resume", "--no-baseline"]) == 0
    assert "robot-1: done before, kept" in capsys.readouterr().out  # status: stdout without --json
    assert (out / "fleet.md").read_text() == before


@pytest.mark.slow
def test_loso_gives_each_robot_its_folds_and_the_report_their_stability(tmp_path: Path) -> None:
    """``--loso``: a robot of two sessions gets one fold file per session in ``loso/<robot>/``
    and a row of the stability table; a second call keeps the fold files (resume). Two
    candidate effects and no discovery keep it short."""
    from odomgym.diagnose.config import DiagnoseConfig
    from odomgym.diagnose.fleet import diagnose_fleet

    fleet = tmp_path / "fleet"
    assert main(["fleet", "--example", "2", str(fleet), "--sessions", "2"]) == 0
    robots = find_fleet(fleet)
    out = tmp_path / "out"
    config = DiagnoseConfig(candidates=("wheelbase", "distance_scale"), discover=False, jobs=1)
    lines: list[str] = []
    diagnose_fleet(robots, out, config=config, loso=True, status=lines.append)
    for robot in ("robot-1", "robot-2"):
        assert sorted(p.name for p in (out / "loso" / robot).iterdir()) == [
            "fold-session-1.json",
            "fold-session-2.json",
        ]
    summary = summarise_fleet(out, robots)
    assert sorted(summary.stability) == ["robot-1", "robot-2"]
    for checks in summary.stability.values():
        assert checks["folds"] == 2 and set(checks["intervals_overlap"]) == {"e_d", "e_b", "e_s"}
    assert "seconds" not in json.dumps(summary.to_json())  # the same wherever the folds ran
    text = format_fleet(summary, "fleet")
    assert "## Stability: leave one session out" in text and "| robot-2 | 2 |" in text
    stamps = {p: p.stat().st_mtime_ns for p in (out / "loso").rglob("fold-*.json")}
    diagnose_fleet(robots, out, config=config, loso=True, resume=True, status=lines.append)
    assert {p: p.stat().st_mtime_ns for p in (out / "loso").rglob("fold-*.json")} == stamps


def test_resume_keeps_only_reports_made_from_the_same_inputs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``resume`` kept a robot's report after its logs were replaced, and the fleet reported
    its old values without a word. Now a report is kept only when ``inputs.json`` records it
    as made from the same logs, robot.toml and options; the diagnosis itself is stubbed here
    (its reports are tested above), so the test is about the bookkeeping alone."""
    import odomgym.diagnose.fleet as fleet_module
    from odomgym.diagnose.config import DiagnoseConfig
    from odomgym.diagnose.fleet import INPUTS_FILE, diagnose_fleet, inputs_digest

    root = tmp_path / "fleet"
    for name in ("r0", "r1"):
        _robot_folder(root, name, ["s1.csv", "s2.csv"])
    robots = find_fleet(root)
    made: list[str] = []

    def diagnosed(runs: object, robot: object, config: object, *rest: object) -> object:
        made.append(str(rest[1]))  # the robot's folder
        return "verdict", {"report.json": b"{}\n"}

    monkeypatch.setattr(fleet_module, "_diagnose_files", diagnosed)
    monkeypatch.setattr(fleet_module, "read_robot_runs", lambda robot: [])
    out = tmp_path / "out"
    config = DiagnoseConfig(jobs=1)
    lines: list[str] = []

    def again(**options: object) -> list[str]:
        made.clear()
        lines.clear()
        diagnose_fleet(robots, out, status=lines.append, **{"config": config, **options})
        return sorted(Path(folder).name for folder in made)

    assert again() == ["r0", "r1"]
    record = json.loads((out / INPUTS_FILE).read_text())["units"]
    assert record == {r.name: inputs_digest(r, "", config, None) for r in robots}
    assert again(resume=True) == [] and "r0: done before, kept" in lines
    # jobs changes no result; a log's bytes, robot.toml, a result-moving option or the
    # baseline do, each for the robots it touches.
    assert again(resume=True, config=DiagnoseConfig(jobs=2)) == []
    (root / "r1" / "s2.csv").write_text("run,experiment,t,ticks_left,ticks_right,x,y\n")
    assert again(resume=True) == ["r1"]
    assert any(line.startswith("r1: its logs, robot.toml or the options changed") for line in lines)
    assert again(resume=True) == []
    (root / "r0" / "robot.toml").write_text(
        (root / "r0" / "robot.toml").read_text() + "# recalibrated\n"
    )
    assert again(resume=True) == ["r0"]
    assert again(resume=True, config=DiagnoseConfig(jobs=1, seed=1)) == ["r0", "r1"]
    assert again(resume=True, config=DiagnoseConfig(jobs=1, seed=1), baseline=dict) == [
        "r0",
        "r1",
    ]
    # An output without the record (an older odomgym's, or a damaged one) is made again.
    (out / INPUTS_FILE).write_text("not json")
    assert again(resume=True) == ["r0", "r1"]
    assert again() == ["r0", "r1"]  # without resume, always


def test_fold_stability_is_read_only_when_asked(tmp_path: Path) -> None:
    """A fresh report without ``--loso`` showed the stability of folds an earlier call had
    left in OUT/loso/: ``odomgym fleet`` now reads them only with ``--loso``."""
    _write_report(tmp_path / "robots" / "r0", {"wheelbase": {"e_b": (1.01, 1e-3)}})
    fold = tmp_path / "loso" / "r0" / "fold-s1.json"
    fold.parent.mkdir(parents=True)
    fold.write_text("{}")
    robots = [FleetRobot("r0", tmp_path, PRESETS["labmate"], (("", tmp_path / "s1.csv"),))]
    assert summarise_fleet(tmp_path, robots, loso=False).stability == {}
    assert "Stability" not in format_fleet(summarise_fleet(tmp_path, robots, loso=False), "f")

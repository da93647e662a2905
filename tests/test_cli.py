"""The command line: tables, JSON lines, plots, and clean failures on bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_errors import one_line_error as _one_line_error
from conftest import OPTIODOM

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
    # Valid alone, but slower than the experiments drive: the robot file's line, before any
    # work (until 0.3.x an internal error from deep in the driver).
    slow = tmp_path / "slow.toml"
    slow.write_text("[robot]\nwheel_diameter = 0.1\nwheelbase = 0.3\nticks_per_rev = 500\n"
                    "max_wheel_speed = 0.1\n")  # fmt: skip
    for command in (["run", "square"], ["calibrate", "umbmark"]):
        assert main([*command, "--robot", str(slow), "--plot", str(plot)]) == 2
        _one_line_error(capsys, f"{slow}:5: ", "max_wheel_speed of 0.1 m/s")
    assert not plot.exists()
    # A calibration the file allows but far from this robot (x_ICR in mm read as m) sends the
    # driver in circles: the file named, not an internal error; one beyond reach is refused
    # at its line.
    far = tmp_path / "far.toml"
    far.write_text("[calibration]\nicr_x = 3.6\n")
    assert main(["run", "square", "--robot", "scout2", "--calibration", str(far)]) == 2
    _one_line_error(capsys, f"{far}: driving by this calibration", "x_ICR = 3.600000 m")
    far.write_text("[calibration]\nicr_x = 1e300\n")
    assert main(["run", "square", "--robot", "scout2", "--calibration", str(far)]) == 2
    _one_line_error(capsys, f"{far}:2: icr_x must be within ±100 m")
    # Named as the options typed, not as the derived field or the experiments' `size`.
    assert main(["calibrate", "umbmark", "--robot", "scout2", "--eb", "3"]) == 2
    _one_line_error(capsys, "--eb: true_wheelbase must lie within")
    assert main(["calibrate", "umbmark", "--side", "0.0001"]) == 2
    _one_line_error(capsys, "--side 0.0001 makes a run's path 0.0004 m")
    with pytest.raises(SystemExit):
        main(["run", "square", "--ed", "nan"])
    with pytest.raises(SystemExit):
        main(["run", "square", "--runs", "0"])


def _numbers(value: object) -> list[float]:
    if isinstance(value, dict):
        return [n for v in value.values() for n in _numbers(v)]
    if isinstance(value, list):
        return [n for v in value for n in _numbers(v)]
    return [float(value)] if isinstance(value, int | float) and not isinstance(value, bool) else []


def test_covariance_command_worked_example(capsys: pytest.CaptureFixture[str]) -> None:
    """Chong & Kleeman 1997, Table 1, first column (worked example of shared/seeds/README.md)."""
    args = ["covariance", "--left", "3", "--right", "1", "--wheelbase", "0.4"]
    assert main([*args, "--kl", "0.001", "--kr", "0.001", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    numbers = _numbers(report)
    assert any(abs(v - 1.4376e-3) < 1e-7 for v in numbers)  # σ_x = 1.4376e-3 m (Table 1)


def test_covariance_command_rejects_bad_input() -> None:
    with pytest.raises(SystemExit):
        main(
            [
                "covariance",
                "--left",
                "3",
                "--right",
                "1",
                "--wheelbase",
                "0",
                "--kl",
                "0.001",
                "--kr",
                "0.001",
            ]
        )
    with pytest.raises(SystemExit):
        main(
            [
                "covariance",
                "--left",
                "nan",
                "--right",
                "1",
                "--wheelbase",
                "0.4",
                "--kl",
                "0",
                "--kr",
                "0",
            ]
        )


def test_fit_noise_command_on_simulated_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plot = tmp_path / "noise.png"
    assert main(["fit-noise", "--runs", "12", "--distance", "4", "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    assert "k_L" in out and plot.exists()


def test_calibrate_saves_and_exports(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    calib, ros = tmp_path / "calib.toml", tmp_path / "dd.yaml"
    args = [
        "calibrate",
        "umbmark",
        "--robot",
        "navbot",
        "--eb",
        "1.03",
        "--side",
        "1",
        "--runs",
        "2",
    ]
    code = main(
        [*args, "--save", str(calib), "--export", "ros2", "--export-path", str(ros), "--json"]
    )
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    assert report["estimate"]["E_b"] == pytest.approx(1.03, abs=0.006)
    assert "wheel_separation_multiplier" in ros.read_text()
    # The saved calibration is accepted by `odomgym run`.
    assert (
        main(
            [
                "run",
                "square",
                "--robot",
                "navbot",
                "--eb",
                "1.03",
                "--side",
                "1",
                "--runs",
                "1",
                "--calibration",
                str(calib),
                "--json",
            ]
        )
        == 0
    )


@pytest.mark.parametrize(
    "data",
    ["optiodom:square/230620202042", str(OPTIODOM / "square" / "230620202042")],
    ids=["shipped-name", "folder"],
)
def test_calibrate_on_measured_session_reproduces_published(
    data: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["calibrate", "umbmark", "--data", data, "--conventions", "optiodom", "--json"])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    # published_results.csv: umbmark, 230620202042: b = 0.201458, D_R = 0.083954, D_L = 0.084046
    assert report["b"] == pytest.approx(0.201458, rel=0.002)
    assert report["dr"] == pytest.approx(0.083954, rel=0.002)
    assert report["dl"] == pytest.approx(0.084046, rel=0.002)


def test_cli_rejects_bad_seed_plot_format_and_method(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit):
        main(["run", "square", "--seed", "-1"])
    assert main(["run", "square", "--runs", "1", "--plot", str(tmp_path / "x.foo")]) == 2
    assert "cannot write a plot" in capsys.readouterr().err
    assert main(["leaderboard", "--data", str(tmp_path), "--methods", "nosuch"]) == 2
    assert "unknown method" in capsys.readouterr().err


def test_output_files_get_ordinary_permissions(tmp_path: Path) -> None:
    import os

    from odomgym.odometry.calibration import Calibration

    umask = os.umask(0o022)
    try:
        Calibration().save(tmp_path / "calib.toml")
    finally:
        os.umask(umask)
    assert (tmp_path / "calib.toml").stat().st_mode & 0o777 == 0o644


def test_version_and_python_dash_m() -> None:
    import subprocess
    import sys

    from odomgym import __version__

    out = subprocess.run(
        [sys.executable, "-m", "odomgym", "--version"], capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == f"odomgym {__version__}"


def test_a_reader_that_left_the_pipe_stops_the_command_quietly() -> None:
    """``odomgym … | head``: the reader closes the pipe before the results are written. A
    user got ``odomgym: error: Broken pipe`` (exit 1), as if the command had failed; now no
    word and exit 141 (128 + SIGPIPE), as a shell's own tools stop. The pipe is closed before
    the command writes, so the test does not depend on timing."""
    import subprocess
    import sys

    from odomgym.cli import BROKEN_PIPE

    command = [sys.executable, "-m", "odomgym", "run", "square", "--json"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert process.stdout is not None and process.stderr is not None
    process.stdout.close()
    err = process.stderr.read().decode()
    process.stderr.close()
    assert process.wait(timeout=120) == BROKEN_PIPE == 141
    assert err == ""


def test_envs_and_baselines_import_from_the_repository_root() -> None:
    """Python started in the checkout's root sees the source folder ``odomgym/`` first; the
    package-dir folders envs/ and baselines/ must still be found as odomgym.envs/.baselines."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    code = (
        "import odomgym, odomgym.envs.umbmark, odomgym.baselines; "
        "print(odomgym.__file__); print(odomgym.envs.umbmark.__file__)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True
    )
    package, envs = out.stdout.split()
    assert Path(package).resolve() == root / "odomgym" / "__init__.py"
    assert Path(envs).resolve() == root / "envs" / "umbmark.py"


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["square", "ivanjko", "circular"])
def test_every_method_on_every_shipped_session_kind(
    kind: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """A result, or one line saying what the method needs: never a traceback. Trajectory
    optimisation fits runs of any shape, so it gives a result on circular sessions too."""
    from odomgym.baselines import CALIBRATORS
    from odomgym.data import sample_sessions

    session = next(name for name in sample_sessions() if name.startswith(f"{kind}/"))
    for method in sorted(CALIBRATORS):
        code = main(["calibrate", method, "--data", f"optiodom:{session}", "--json"])
        out, err = capsys.readouterr()
        if (kind, method) in {("square", "trajectory"), ("circular", "trajectory")}:
            assert code == 0, err
        if code == 0:
            assert json.loads(out)["method"]
        else:
            assert code == 2
            lines = err.strip().splitlines()
            assert len(lines) == 1 and lines[0].startswith(f"odomgym: error: {method} cannot")


# ---------------------------------------------------------------------------------- outputs
def _output_cases(tmp: Path) -> list[tuple[list[str], str, str]]:
    """(argv, option named in the error, words of the reason) for every output option."""
    existing_file = tmp / "a-file.txt"
    existing_file.write_text("not a folder\n", encoding="utf-8")
    folder = tmp / "a-folder"
    folder.mkdir(exist_ok=True)
    under_a_file = existing_file / "x.png"
    plot_folder = tmp / "scatter.png"
    plot_folder.mkdir(exist_ok=True)
    calibrate = ["calibrate", "umbmark", "--side", "1", "--runs", "1"]
    session = ["optiodom:square/230620202042", "--robot", "examples/optiodom_nominal.toml"]
    return [
        (["bench", "calibrators", "--robots", "1", "--out", "/proc/x"], "--out", "cannot create"),
        (["bench", "calibrators", "--out", str(existing_file)], "--out", "is not a folder"),
        ([*calibrate, "--save", str(folder)], "--save", "is a folder"),
        ([*calibrate, "--save", "/proc/calib.toml"], "--save", "cannot create"),
        (
            [*calibrate, "--export", "ros2", "--export-path", "/proc/d.yaml"],
            "--export-path",
            "/proc",
        ),
        ([*calibrate, "--export-path", str(tmp / "d.yaml")], "--export-path", "needs --export"),
        ([*calibrate, "--plot", str(under_a_file)], "--plot", "is a file, not a folder"),
        (["leaderboard", "--data", "optiodom:", "--out", "/proc/board.md"], "--out", "cannot"),
        (["leaderboard", "--data", "optiodom:", "--out", str(folder)], "--out", "is a folder"),
        (["fit-noise", "--runs", "2", "--plot", "/proc/noise.png"], "--plot", "cannot create"),
        (["diagnose", *session, "--out", "/proc/diag"], "--out", "cannot create"),
        (["diagnose", *session, "--out", str(existing_file)], "--out", "is not a folder"),
        (["run", "square", "--runs", "1", "--log", "/proc/runs.csv"], "--log", "cannot create"),
        (["run", "square", "--runs", "1", "--plot", str(plot_folder)], "--plot", "is a folder"),
        (["run", "straight", "--runs", "1", "--log", str(folder)], "--log", "is a folder"),
        ([*calibrate, "--save", "/dev/full"], "--save", "is not a regular file"),
        (["leaderboard", "--data", "optiodom:", "--out", "/dev/null"], "--out", "not a regular"),
    ]


@pytest.mark.parametrize("case", range(17))
def test_unwritable_outputs_fail_before_the_work_in_one_line(
    case: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Each output option is checked before any simulation or fit: one line naming the option,
    exit 2, nothing created. (/proc stands for an unwritable place: it refuses new files even
    to root, for whom a read-only folder would still be writable.)"""
    cases = _output_cases(tmp_path)
    assert len(cases) == 17
    argv, option, reason = cases[case]
    monkeypatch.chdir(Path(__file__).resolve().parents[1])  # examples/ for diagnose
    before = sorted(tmp_path.rglob("*"))
    assert main(argv) == 2
    _one_line_error(capsys, f"error: {option} ", reason)
    assert sorted(tmp_path.rglob("*")) == before


def test_a_full_disk_is_one_line_and_leaves_no_partial_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Writing fails with ENOSPC (what /dev/full or a full disk gives): exit 1, one line, and
    neither the target nor a temporary file is left behind."""
    import errno

    real = Path.write_text

    def full(self: Path, *args: object, **kwargs: object) -> int:
        if self.parent == tmp_path:
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return real(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(Path, "write_text", full)
    target = tmp_path / "calib.toml"
    assert main(["calibrate", "umbmark", "--side", "1", "--runs", "1", "--save", str(target)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No space left on device" in err[0], err
    assert list(tmp_path.iterdir()) == []


def test_atomic_writer_refuses_to_replace_a_device(tmp_path: Path) -> None:
    from odomgym.io import atomic_write_text

    with pytest.raises(OSError, match="not a regular file"):
        atomic_write_text(Path("/dev/null"), "x")
    assert Path("/dev/null").is_char_device()


@pytest.mark.parametrize("out", [".", "..", "/"])
def test_diagnose_refuses_to_replace_the_working_folder(
    out: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``diagnose --out .`` raised ValueError (PosixPath('.') has an empty name) building the
    journal's path, and ``--out ..`` would have replaced the folder holding the working one:
    now one line before any work."""
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    session = "optiodom:square/230620202042"
    assert main(["diagnose", session, "--robot", "optiodom", "--out", out]) == 2
    _one_line_error(capsys, "error: --out ", "holds the working folder")


def test_diagnose_refuses_an_out_folder_holding_anything_but_a_report(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--out`` is replaced whole. A user gave the folder holding the logs, the robot file
    and notes as ``--out`` and was left with the report alone (exit 0). Now one line naming
    what the folder holds, exit 2, before any work, and every file untouched; an earlier
    report's folder (``report.json`` and figures only) is still taken."""
    import odomgym.diagnose.workflow as workflow
    from odomgym.diagnose.report import REPORT_FILES, foreign_entries

    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    session = "optiodom:square/230620202042"
    folder = tmp_path / "mine"
    (folder / "sub").mkdir(parents=True)
    for name in ("notes.txt", "robot.toml", "report.md", "sub/thesis.tex"):
        (folder / name).write_text(name, encoding="utf-8")
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    assert main(["diagnose", session, "--robot", "optiodom", "--out", str(folder)]) == 2
    _one_line_error(capsys, "error: --out ", "notes.txt, report.md, robot.toml, sub, which")
    assert {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()} == before
    # With a report.json beside them, the report's own files pass and the rest do not.
    (folder / "report.json").write_text("{}", encoding="utf-8")
    assert foreign_entries(folder) == ["notes.txt", "robot.toml", "sub"]
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    for name in (*REPORT_FILES, "discovered-yaw_rate.png"):
        (earlier / name).write_text(name, encoding="utf-8")
    assert foreign_entries(earlier) == [] and foreign_entries(tmp_path / "new") == []
    # A desktop's own files (a user opened the report in Finder) are no one's data.
    (earlier / ".DS_Store").write_bytes(b"\x00\x00\x00\x01Bud1")
    finder = tmp_path / "finder"
    finder.mkdir()
    (finder / "Thumbs.db").write_bytes(b"")
    assert foreign_entries(earlier) == [] and foreign_entries(finder) == []
    (finder / "desktop.ini").mkdir()  # a folder of that name is not the desktop's file
    assert foreign_entries(finder) == ["desktop.ini"]

    def stop(*_: object, **__: object) -> None:
        raise KeyboardInterrupt  # past the checks: the earlier report was taken

    monkeypatch.setattr(workflow, "diagnose", stop)
    assert main(["diagnose", session, "--robot", "optiodom", "--out", str(earlier)]) == 130


def test_writing_a_report_over_a_folder_of_other_files_is_refused(tmp_path: Path) -> None:
    """The library's writer refuses the same folders as the command (``odomgym fleet`` writes
    each robot's report through the same check), and writes nothing."""
    from odomgym.diagnose.fleet import _write_folder
    from odomgym.diagnose.report import write_outputs
    from odomgym.errors import SpecError

    (tmp_path / "logs.csv").write_text("t\n", encoding="utf-8")
    with pytest.raises(SpecError, match=r"^out .*: holds logs\.csv, which diagnose did not"):
        write_outputs(None, tmp_path, "data")  # type: ignore[arg-type]
    with pytest.raises(SpecError, match=r"holds logs\.csv"):
        _write_folder(tmp_path, {"report.json": b"{}"})
    assert [p.name for p in tmp_path.iterdir()] == ["logs.csv"]


def test_diagnose_gate_order_reaches_the_workflow(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--gate-order joint`` sets ``DiagnoseConfig.gate_order`` to "joint" (the default:
    "catalogue first"); an unknown order is refused by the parser, before any work."""
    import odomgym.diagnose.workflow as workflow

    seen: list[str] = []

    def stop(runs: object, robot: object, config: workflow.DiagnoseConfig, **_: object) -> None:
        seen.append(config.gate_order)
        raise KeyboardInterrupt

    monkeypatch.setattr(workflow, "diagnose", stop)
    session = "optiodom:square/230620202042"
    for option, expected in ([], "catalogue first"), (["--gate-order", "joint"], "joint"):
        out = tmp_path / expected.replace(" ", "-")
        code = main(["diagnose", session, "--robot", "optiodom", "--out", str(out), *option])
        assert code == 130 and seen[-1] == expected and not out.exists()  # stopped: no output
    with pytest.raises(SystemExit) as stopped:
        main(["diagnose", session, "--robot", "optiodom", "--gate-order", "terms-first"])
    assert stopped.value.code == 2 and "--gate-order" in capsys.readouterr().err


def test_output_check_accepts_new_nested_paths_and_leaves_nothing(tmp_path: Path) -> None:
    """A path whose folders do not exist yet is fine (they are created when writing); the
    check's probe file is removed again."""
    from odomgym.cli import _check_output

    _check_output(tmp_path / "new" / "deeper" / "file.toml", option="--save")
    _check_output(tmp_path / "out", option="--out", folder=True)
    _check_output(tmp_path, option="--out", folder=True, swap=True)
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------- internal errors
def _three_straight_runs(folder: Path) -> Path:
    """A native log of three short straight runs, every pose measured."""
    import numpy as np

    from odomgym.data.native import write_native
    from odomgym.odometry.runs import Run

    steps = np.arange(6)
    runs = [
        Run(
            kind="straight",
            time=0.1 * steps,
            counts=np.column_stack([40 * steps, 40 * steps]),
            true_pose=np.column_stack([0.01 * steps + k, np.zeros(6), np.full(6, 0.1 * k)]),
            meta={"run": f"r{k}"},
        )
        for k in range(3)
    ]
    path = folder / "straight.csv"
    write_native(path, runs)
    return path


def _failing_split(error: Exception) -> object:
    def fail(*args: object, **kwargs: object) -> None:
        raise error

    return fail


@pytest.mark.parametrize(
    "error", [RuntimeError("boom,\n  over two lines"), ValueError("x must be finite")]
)
def test_an_internal_error_is_one_line_naming_it_a_bug_exit_3(
    error: Exception,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A failure inside the library that no input check raised (here the workflow's split
    fails) is odomgym's bug, and said to be: exit 3, one line naming the exception, no
    traceback, no output. A ValueError included: diagnose used to present every ValueError as
    the user's input error (exit 2)."""
    import odomgym.diagnose.workflow as workflow

    monkeypatch.setattr(workflow, "split_runs", _failing_split(error))
    out = tmp_path / "out"
    argv = ["diagnose", str(_three_straight_runs(tmp_path)), "--robot", "labmate"]
    assert main([*argv, "--out", str(out)]) == 3
    stdout, stderr = capsys.readouterr()
    assert stdout == "" and "Traceback" not in stderr and not out.exists()
    lines = stderr.strip().splitlines()
    kind, text = type(error).__name__, " ".join(str(error).split())
    assert lines == [
        f"odomgym: internal error: {kind}: {text} — a bug in odomgym, not in your input; please "
        "report it with the command line and the output of odomgym --debug diagnose …"
    ]


def test_debug_shows_an_internal_errors_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``odomgym --debug COMMAND`` shows the full traceback of an internal error instead of
    the one line (still exit 3); an input error stays one line."""
    import odomgym.diagnose.workflow as workflow

    monkeypatch.setattr(workflow, "split_runs", _failing_split(RuntimeError("boom")))
    data = str(_three_straight_runs(tmp_path))
    argv = ["--debug", "diagnose", data, "--robot", "labmate", "--out", str(tmp_path / "o")]
    assert main(argv) == 3
    stderr = capsys.readouterr().err
    assert stderr.startswith("Traceback (most recent call last):")
    assert "in _diagnose" in stderr and stderr.rstrip().endswith("RuntimeError: boom")
    assert "internal error" not in stderr
    assert main(["--debug", "diagnose", data, "--robot", "no-such-robot"]) == 2
    _one_line_error(capsys, "unknown robot")


# ---------------------------------------------------------------------------------- bench
def test_bench_backend_ray_without_ray_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Without Ray installed, ``--backend ray`` stops before any work, naming the extra."""
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)  # what `import ray` sees when it is missing
    out = tmp_path / "bench"
    assert main(["bench", "calibrators", "--backend", "ray", "--out", str(out)]) == 2
    _one_line_error(capsys, "--backend ray needs Ray", "odomgym[distributed]")
    assert not out.exists()


def test_benchmark_backend_is_an_enum() -> None:
    from odomgym.baselines.benchmark import Backend, BenchConfig, run_benchmark
    from odomgym.errors import SpecError

    assert [b.value for b in Backend] == ["local", "ray"]
    assert Backend("ray") is Backend.RAY
    config = BenchConfig(robots=1, floors=("concrete",), methods=("umbmark",), budget=2)
    with pytest.raises(SpecError) as caught:
        run_benchmark(config, backend="spark")
    assert caught.value.field == "backend"


def test_a_floor_name_means_one_floor_everywhere() -> None:
    """A benchmark floor either is the preset of the same name, exactly, or has a name no
    preset has; a preset that is not a benchmark floor is refused, naming the floors."""
    import numpy as np

    from odomgym.baselines.benchmark import BenchConfig
    from odomgym.errors import SpecError
    from odomgym.floor import FLOORS
    from odomgym.lab.population import BENCH_FLOORS

    for name, bench_floor in BENCH_FLOORS.items():
        floor, _ = bench_floor.make(np.random.default_rng(0))
        assert floor.name == name
        if name in FLOORS:
            assert floor == FLOORS[name], name
    for other in sorted(set(FLOORS) - set(BENCH_FLOORS)):
        with pytest.raises(SpecError, match=f"unknown benchmark floor '{other}'") as caught:
            BenchConfig(floors=(other,))
        assert caught.value.field == "floor" and "\n" not in str(caught.value)


def test_bench_refuses_a_preset_that_is_no_benchmark_floor_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["bench", "calibrators", "--robots", "1", "--out", str(tmp_path / "b")]
    assert main([*argv, "--floor", "smooth"]) == 2
    _one_line_error(capsys, "unknown benchmark floor 'smooth'; floors: concrete, rough, cables")
    assert main([*argv, "--floor", "concrete", "bumpy"]) == 2
    _one_line_error(capsys, "unknown benchmark floor 'bumpy'")


def test_bench_writes_its_floors_and_says_what_it_wrote(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "bench"
    argv = ["bench", "calibrators", "--robots", "1", "--methods", "umbmark", "--budget", "2"]
    assert main([*argv, "--floor", "concrete", "--jobs", "1", "--out", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert "## Floor: concrete (the concrete preset" in stdout
    (wrote,) = [line for line in stdout.splitlines() if line.startswith("wrote: ")]
    listed = [Path(p) for p in wrote.removeprefix("wrote: ").split(", ")]
    assert out / "summary.md" in listed and all(p.is_file() for p in listed)
    results = json.loads((out / "results.json").read_text(encoding="utf-8"))
    assert {row["floor"] for row in results["rows"]} == {"concrete"}


# ---------------------------------------------------------------------------------- help
def _parsers(parser: object, prefix: str = "odomgym") -> list[tuple[str, object]]:
    import argparse

    assert isinstance(parser, argparse.ArgumentParser)
    found: list[tuple[str, object]] = [(prefix, parser)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found += _parsers(sub, f"{prefix} {name}")
    return found


def test_every_option_of_every_command_has_help() -> None:
    import argparse

    from odomgym.cli import build_parser

    parsers = _parsers(build_parser())
    assert {name for name, _ in parsers} >= {
        "odomgym run square",
        "odomgym run straight",
        "odomgym calibrate",
        "odomgym bench",
        "odomgym leaderboard",
        "odomgym covariance",
        "odomgym fit-noise",
        "odomgym diagnose",
    }
    missing = [
        f"{name}: {'/'.join(action.option_strings) or action.dest}"
        for name, parser in parsers
        for action in parser._actions  # type: ignore[attr-defined]
        if not isinstance(action, argparse._HelpAction)
        and not (action.help and action.help.strip() and action.help != argparse.SUPPRESS)
    ]
    assert missing == []


def test_floor_help_lists_every_floor_each_command_accepts() -> None:
    from odomgym.cli import build_parser
    from odomgym.floor import FLOORS
    from odomgym.lab.population import BENCH_FLOORS

    checked = 0
    for name, parser in _parsers(build_parser()):
        for action in parser._actions:  # type: ignore[attr-defined]
            if "--floor" in action.option_strings:
                accepted = BENCH_FLOORS if name == "odomgym bench" else FLOORS
                assert all(floor in action.help for floor in accepted), (name, action.help)
                checked += 1
    # run square, straight, clapper-straight and clapper-rectangle; calibrate; bench
    assert checked == 6
    assert "concrete" in FLOORS  # the README calibrates on it


def test_run_square_and_straight_take_only_their_own_options() -> None:
    for argv in (
        ["run", "straight", "--side", "2"],
        ["run", "straight", "--direction", "cw"],
        ["run", "straight", "--plot", "x.png"],
        ["run", "square", "--distance", "3"],
        ["run", "square", "--return-trip"],
        ["calibrate", "umbmark", "--calibration", "c.toml"],  # calibrate starts uncalibrated
    ):
        with pytest.raises(SystemExit):
            main(argv)


def test_run_says_which_calibration_it_applied_and_what_it_wrote(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from odomgym.data.native import read_native
    from odomgym.odometry.calibration import Calibration

    calib = tmp_path / "calib.toml"
    Calibration(c_left=0.999, c_right=1.001, wheelbase_scale=1.02).save(calib)
    log = tmp_path / "runs.csv"
    argv = ["run", "straight", "--runs", "2", "--distance", "1", "--log", str(log)]
    assert main([*argv, "--calibration", str(calib)]) == 0
    out = capsys.readouterr().out
    assert f"applied calibration: {calib} (c_L = 0.999000, c_R = 1.001000, E_b = 1.020000" in out
    assert f"wrote: {log}" in out
    assert len(read_native(log)) == 2
    assert main(["run", "straight", "--runs", "1", "--distance", "1", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out.splitlines()[0])["run"] == 1  # stdout stays JSON lines
    assert "applied calibration: none" in err


def test_run_plans_are_a_library_the_command_only_prints(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``odomgym run`` prints what :func:`odomgym.lab.plans.drive_plans` returns."""
    import numpy as np

    from odomgym.floor import FLOORS
    from odomgym.lab.plans import drive_plans, square_plans
    from odomgym.robot import PRESETS

    robot = PRESETS["labmate"].with_errors(None, 1.02, None)  # as --eb 1.02 does
    batch = drive_plans(
        robot, FLOORS["smooth"], square_plans(1.0, runs=1), rng=np.random.default_rng(3)
    )
    assert batch.directions == ["cw", "ccw"]
    assert [run.meta["experiment"] for run in batch.runs] == ["square_cw", "square_ccw"]
    assert main(["run", "square", "--runs", "1", "--side", "1", "--eb", "1.02", "--seed", "3",
                 "--json"]) == 0  # fmt: skip
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    for record, error in zip(lines[:2], batch.errors, strict=True):
        assert [record["return_error"][k] for k in ("x", "y", "theta")] == error.tolist()
    summary = batch.summary()
    assert summary is not None
    assert lines[2]["summary"]["e_max_syst"] == summary.e_max_syst


# ---------------------------------------------------------------------------------- leaderboard
def test_leaderboard_optiodom_conventions_reproduce_the_published_rows(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """With ``--conventions optiodom`` the in-session column reproduces the authors' rows
    shipped with the sessions (Sousa et al. 2022, ``published_results.csv``) for every method
    they published and odomgym implements with their conventions: UMBmark and Jung & Chung on
    the square sessions, Ivanjko et al. on the straight-and-spin sessions. The measures are
    printed to 1 µm and 1e-6°; tolerance: two units of that last digit (measured ≤ 0.94 µm,
    ≤ 0.49e-6°). Without the flag, the corrected Jung & Chung is far from the published rows
    (its final errors 3-7-fold smaller), so the flag is what makes them agree."""
    methods = ["umbmark", "jung_chung", "ivanjko"]
    argv = ["leaderboard", "--data", "optiodom:", "--methods", *methods, "--json"]
    assert main([*argv, "--conventions", "optiodom"]) == 0
    board = json.loads(capsys.readouterr().out)
    assert board["conventions"] == "optiodom"
    compared = sorted(set(board["in_session"]) & set(board["published"]))
    assert {key.split("/")[0] for key in compared} == set(methods)
    assert len(compared) >= 6
    for key in compared:
        ours, theirs = board["in_session"][key], board["published"][key]
        for measure in ("max_pos", "final_pos", "max_th_deg", "final_th_deg"):
            assert ours[measure] == pytest.approx(theirs[measure], abs=2e-6), (key, measure)
    assert main(argv) == 0
    own = json.loads(capsys.readouterr().out)
    for key in (k for k in compared if k.startswith("jung_chung/")):
        assert own["in_session"][key]["final_pos"] < 0.5 * board["published"][key]["final_pos"]

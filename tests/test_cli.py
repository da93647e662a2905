"""The command line: tables, JSON lines, plots, and clean failures on bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
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

    from odomgym.odometry import Calibration

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
    """A result, or one line saying what the method needs: never a traceback."""
    from odomgym.baselines import CALIBRATORS
    from odomgym.data import sample_sessions

    session = next(name for name in sample_sessions() if name.startswith(f"{kind}/"))
    for method in sorted(CALIBRATORS):
        code = main(["calibrate", method, "--data", f"optiodom:{session}", "--json"])
        out, err = capsys.readouterr()
        if code == 0:
            assert json.loads(out)["method"]
        else:
            assert code == 2
            lines = err.strip().splitlines()
            assert len(lines) == 1 and lines[0].startswith(f"odomgym: error: {method} cannot")

"""The command line after a new user's review: outputs that would overwrite a user's files or
each other are refused before any work, options that would be ignored are refused, user input
that ended in an internal error or a numpy message is one line naming the option, repeated
list options accumulate, and help and docs say what the code does."""

from __future__ import annotations

import argparse
import json
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_errors import one_line_error
from conftest import OPTIODOM

from odomgym.cli import build_parser, main
from odomgym.errors import SpecError

ROOT = Path(__file__).resolve().parents[1]


class Reached(SpecError):
    """Raised by a stand-in for the expensive work: the command got past its checks."""


def _stop_at_work(monkeypatch: pytest.MonkeyPatch, module: str, name: str) -> list[Any]:
    """Replace ``module.name`` by a function that records its arguments and raises
    :class:`Reached` (exit 2 with its message); returns the record."""
    import importlib

    calls: list[Any] = []

    def stand_in(*args: Any, **kwargs: Any) -> Any:
        calls.append((args, kwargs))
        raise Reached("REACHED THE WORK")

    monkeypatch.setattr(importlib.import_module(module), name, stand_in)
    return calls


def _no_work(monkeypatch: pytest.MonkeyPatch, module: str, name: str) -> None:
    """Fail the test if ``module.name`` (the command's work) is called at all."""
    import importlib

    def refuse(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError(f"{module}.{name} ran: the check came after the work")

    monkeypatch.setattr(importlib.import_module(module), name, refuse)


# ------------------------------------------------------------- 1. bench's output folder
BENCH = ["bench", "calibrators", "--robots", "1", "--methods", "umbmark", "--budget", "2"]


def _earlier_bench(folder: Path, *scatters: str) -> None:
    """An earlier `bench calibrators` run's files (its results.json in the layout it writes)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "results.json").write_text(
        json.dumps({"config": {}, "elapsed_s": 1.0, "summary": [], "rows": []}), encoding="utf-8"
    )
    for name in ("summary.md", "summary.csv", "results.csv", "improvement.png"):
        (folder / name).write_text("earlier\n", encoding="utf-8")
    for method in scatters:
        (folder / f"scatter_{method}.png").write_bytes(b"png")


def test_bench_refuses_an_out_folder_holding_a_users_files_before_any_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    _no_work(monkeypatch, "odomgym.baselines.benchmark", "run_benchmark")
    out = tmp_path / "A"
    out.mkdir()
    (out / "summary.md").write_text("my notes\n", encoding="utf-8")  # no results.json: mine
    (out / "data.csv").write_text("1,2\n", encoding="utf-8")
    assert main([*BENCH, "--out", str(out)]) == 2
    line = one_line_error(capsys, "--out", "data.csv", "summary.md")
    assert "did not write" in line
    assert (out / "summary.md").read_text(encoding="utf-8") == "my notes\n"


def test_bench_names_the_first_few_foreign_entries_and_counts_the_rest(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    _no_work(monkeypatch, "odomgym.baselines.benchmark", "run_benchmark")
    out = tmp_path / "full"
    _earlier_bench(out, "umbmark")
    for k in range(7):
        (out / f"user{k}.txt").write_text("x", encoding="utf-8")
    (out / "sub").mkdir()
    assert main([*BENCH, "--out", str(out)]) == 2
    line = one_line_error(capsys, "--out", "sub, user0.txt, user1.txt, user2.txt, user3.txt")
    assert "and 3 more" in line and "summary.md" not in line and "scatter_umbmark" not in line


def test_bench_skid_refuses_a_users_folder_too(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    _no_work(monkeypatch, "odomgym.baselines.skid_bench", "run_skid_bench")
    (tmp_path / "robot.toml").write_text("[robot]\n", encoding="utf-8")
    argv = ["bench", "skid", "--presets", "scout2", "--floor", "smooth", "--out", str(tmp_path)]
    assert main(argv) == 2
    one_line_error(capsys, "--out", "robot.toml")


def test_bench_accepts_an_earlier_benchmarks_folder_desktop_files_and_a_journal(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from odomgym.cli.bench import foreign_entries

    calls = _stop_at_work(monkeypatch, "odomgym.baselines.benchmark", "run_benchmark")
    out = tmp_path / "bench-out"
    _earlier_bench(out, "umbmark", "oracle")
    for name in ("skid_models.md", "skid_models.png"):  # bench skid writes there too
        (out / name).write_text("earlier\n", encoding="utf-8")
    (out / "skid_models.json").write_text(
        json.dumps({"robots": [], "floors": [], "seed": 0, "seconds": 1.0, "results": []}),
        encoding="utf-8",
    )
    (out / ".DS_Store").write_bytes(b"\0")
    (out / "Thumbs.db").write_bytes(b"\0")
    (out / "journal.jsonl").write_text(json.dumps({"journal": 1, "config": {}}) + "\n")
    assert foreign_entries(out) == []
    assert main([*BENCH, "--out", str(out), "--resume"]) == 2
    assert "REACHED THE WORK" in capsys.readouterr().err and len(calls) == 1
    assert calls[0][1]["resume"] is True  # the journal reaches the run
    # An interrupted first run: only its journal (or an empty one, cut before its header).
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    (fresh / "journal.jsonl").write_text("")
    assert foreign_entries(fresh) == []


def test_files_named_like_outputs_are_a_users_without_the_benchmarks_record(
    tmp_path: Path,
) -> None:
    from odomgym.cli.bench import foreign_entries

    out = tmp_path / "out"
    out.mkdir()
    (out / "results.json").write_text('{"mine": 1}', encoding="utf-8")
    (out / "summary.md").write_text("mine", encoding="utf-8")
    (out / "journal.jsonl").write_text("my diary\n", encoding="utf-8")
    (out / "skid_models.md").write_text("mine", encoding="utf-8")
    assert foreign_entries(out) == sorted(p.name for p in out.iterdir())
    _earlier_bench(tmp_path / "ok", "umbmark")
    (tmp_path / "ok" / "scatter_x.png").unlink(missing_ok=True)
    (tmp_path / "ok" / "scatter_lee.png").mkdir()  # a folder is never the benchmark's file
    (tmp_path / "ok" / "summary.csv").unlink()
    (tmp_path / "ok" / "summary.csv").symlink_to(out / "summary.md")  # nor a link
    assert foreign_entries(tmp_path / "ok") == ["scatter_lee.png", "summary.csv"]


def test_write_outputs_removes_the_scatters_of_methods_not_in_this_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from odomgym.baselines import bench_report

    def fake_plot(path: Path, *args: Any, **kwargs: Any) -> None:
        Path(path).write_bytes(b"new")

    def fake_improvements(config: Any, rows: Any, path: Path) -> Path:
        path.write_bytes(b"new")
        return path

    monkeypatch.setattr(bench_report, "summarize", lambda rows: [])
    monkeypatch.setattr(bench_report, "markdown_summary", lambda config, rows: "summary\n")
    monkeypatch.setattr(bench_report, "config_record", lambda config: {})
    monkeypatch.setattr(bench_report, "plot_return_errors", fake_plot)
    monkeypatch.setattr(bench_report, "_plot_improvements", fake_improvements)
    out = tmp_path / "out"
    _earlier_bench(out, "umbmark", "jung_chung", "oracle")
    errors = {"cw": [[0.0, 0.0, 0.0]], "ccw": [[0.0, 0.0, 0.0]]}
    rows = [
        {"method": "umbmark", "robot": 0, "floor": "concrete", "improvement": 2.0,
         "scatter": {"before": errors, "after": errors}},
        {"method": "umbmark", "robot": 1, "floor": "concrete", "improvement": 2.0},
    ]  # fmt: skip
    written = bench_report.write_outputs(object(), rows, out, 1.0)  # type: ignore[arg-type]
    assert sorted(p.name for p in out.glob("scatter_*.png")) == ["scatter_umbmark.png"]
    assert (out / "scatter_umbmark.png").read_bytes() == b"new"
    assert out / "scatter_umbmark.png" in written


# ------------------------------------------------------------- 2. calibrate's outputs collide
@pytest.mark.parametrize(
    ("outputs", "named"),
    [
        (["--save", "H.toml", "--export", "ros2", "--export-path", "./H.toml"],
         ("--save", "--export-path")),
        (["--save", "diff_drive_controller.yaml", "--export", "ros2"], ("--save", "--export-path")),
        (["--save", "H.png", "--plot", "sub/../H.png"], ("--save", "--plot")),
        (["--export", "ros2", "--export-path", "e.svg", "--plot", "e.svg"],
         ("--export-path", "--plot")),
    ],
)  # fmt: skip
def test_calibrate_refuses_two_outputs_at_one_file_before_any_work(
    outputs: list[str],
    named: tuple[str, ...],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    _no_work(monkeypatch, "odomgym.baselines.validation", "calibrate_in_simulation")
    assert main(["calibrate", "umbmark", "--runs", "1", "--side", "1", *outputs]) == 2
    one_line_error(capsys, *named, "same file")
    assert list(tmp_path.iterdir()) == [tmp_path / "sub"]


# ------------------------------------------------- 3. simulation options given with --data
def test_calibrate_refuses_simulation_options_with_data_naming_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    _no_work(monkeypatch, "odomgym.data", "read_session")
    argv = ["calibrate", "umbmark", "--data", "optiodom:square/230620202042"]
    assert main([*argv, "--plot", "G.png", "--ed", "1.05", "--runs", "1"]) == 2
    line = one_line_error(capsys, "--plot", "--ed", "--runs", "--data")
    assert "--seed" not in line and "--floor" not in line  # only what was given
    # A value equal to the default is still given, and still ignored with --data.
    for option, value in (("--floor", "smooth"), ("--seed", "0"), ("--side", "4"),
                          ("--robot", "labmate"), ("--policy", "learned")):  # fmt: skip
        assert main([*argv, option, value]) == 2
        one_line_error(capsys, option)
    assert not (tmp_path / "G.png").exists()


def test_calibrate_in_simulation_keeps_its_defaults(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    calls = _stop_at_work(monkeypatch, "odomgym.baselines.validation", "calibrate_in_simulation")
    assert main(["calibrate", "umbmark"]) == 2
    assert "REACHED THE WORK" in capsys.readouterr().err
    (calibrator, robot, floor), options = calls[0]
    assert robot.name == "labmate" and floor.name == "smooth"
    assert options == {"seed": 0, "validation_side": 4.0, "validation_runs": 5}
    assert calibrator.options.side == 4.0 and calibrator.options.runs_per_direction == 5


# ------------------------------------------------------------- 4. every plot of fit-noise
def test_fit_noise_checks_every_group_plot_before_fitting(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    _no_work(monkeypatch, "odomgym.noise.experiment", "fit_noise")
    blocked = tmp_path / "n-ivanjko-spin.png"
    blocked.mkdir()
    plot = tmp_path / "n.png"
    assert main(["fit-noise", "--data", str(OPTIODOM / "ivanjko"), "--plot", str(plot)]) == 2
    one_line_error(capsys, "--plot", "n-ivanjko-spin.png", "is a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["n-ivanjko-spin.png"]


# ------------------------------------------------------------- 5. fit-noise's simulation
@pytest.mark.parametrize("runs", ["1", "2", "4"])
def test_fit_noise_refuses_too_few_runs_before_simulating(
    runs: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from odomgym.noise.fit import MIN_RUNS

    _no_work(monkeypatch, "odomgym.noise.experiment", "simulate_noise_experiment")
    assert main(["fit-noise", "--runs", runs, "--distance", "1"]) == 2
    one_line_error(capsys, "--runs", f"at least {MIN_RUNS} runs")


def test_fit_noise_k_beyond_a_floors_roughness_names_k(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    _no_work(monkeypatch, "odomgym.noise.experiment", "simulate_noise_experiment")
    with pytest.raises(SystemExit) as stopped:
        main(["fit-noise", "--k", "0.5"])
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert "argument --k" in err and "0.1" in err and "roughness must" not in err


@pytest.mark.slow  # about 3 s: the simulation's first run compiles its kernels
def test_fit_noise_without_noise_reports_its_checks_as_not_applicable(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # scipy's RuntimeWarnings had reached the terminal
        assert main(["fit-noise", "--k", "0", "--runs", "5", "--distance", "0.5", "--json"]) == 0
    out, err = capsys.readouterr()
    assert "Warning" not in err
    (fit,) = json.loads(out)["fits"]
    for component in fit["components"]:
        assert component["chi2"] is None and component["p_value"] is None, component
        assert component["ratio"] is None


def test_the_fit_noise_table_says_n_a_where_the_checks_are_undefined() -> None:
    from odomgym.noise.experiment import format_noise_report

    component = {"name": "x", "unit": "m", "measured_var": 0.0, "predicted_var": 1e-26,
                 "ratio": float("nan"), "chi2": None, "dof": 4, "p_value": None}  # fmt: skip
    fit = {"name": "simulation", "runs": 5, "groups": 1, "k_left_sqrt_m": 0.0,
           "k_right_sqrt_m": 0.0, "k_left_interval": [0.0, 0.0], "k_right_interval": [0.0, 0.0],
           "components": [component], "measured_corr": dict.fromkeys(("x_y", "x_theta",
           "y_theta")), "predicted_corr": dict.fromkeys(("x_y", "x_theta", "y_theta")),
           "dropped_single_run_groups": []}  # fmt: skip
    report = {"source": "simulation", "inputs": {"robot": "labmate", "runs": 5, "distance_m": 1.0,
              "k_true_sqrt_m": 0.0, "seed": 0}, "systematic": "group-mean", "confidence": 0.95,
              "interval": "profile", "fits": [fit], "skipped": []}  # fmt: skip
    row = next(line for line in format_noise_report(report).splitlines() if " x " in line)
    assert row.split()[-3:] == ["n/a", "n/a", "n/a"]


def test_component_checks_are_nan_only_when_the_runs_did_not_differ() -> None:
    from odomgym.noise.fit import NoiseSamples, fit_noise

    rng = np.random.default_rng(0)
    n = 8
    basis = np.tile(np.diag([1.0, 2.0, 3.0]), (n, 1, 1))
    same = NoiseSamples(np.tile([1e-3, 2e-3, 1e-4], (n, 1)), basis, basis, ("g",) * n,
                        tuple(map(str, range(n))))  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        silent = fit_noise(same)
    assert all(np.isnan([c.chi2, c.p_value, c.ratio]).all() for c in silent.components)
    noisy = NoiseSamples(rng.normal(0.0, 1e-3, (n, 3)), basis, basis, ("g",) * n,
                         tuple(map(str, range(n))))  # fmt: skip
    assert all(np.isfinite([c.chi2, c.p_value, c.ratio]).all() for c in fit_noise(noisy).components)


# ------------------------------------------------------------- 6. selfcal's --policy
@pytest.mark.parametrize(
    ("make", "said"),
    [
        ("folder", "is a folder"),
        ("missing", "no such file"),
        ("text", "not a selfcal policy file (an .npz written by odomgym train selfcal)"),
    ],
)
def test_calibrate_selfcal_policy_that_is_no_policy_file(
    make: str,
    said: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.chdir(tmp_path)
    policy = {"folder": "adir", "missing": "nofile.npz", "text": "robot.toml"}[make]
    if make == "folder":
        Path(policy).mkdir()
    elif make == "text":
        Path(policy).write_text("[robot]\nwheelbase = 0.34\n", encoding="utf-8")
    argv = ["calibrate", "selfcal", "--policy", policy, "--runs", "1", "--side", "1"]
    assert main(argv) == 2
    line = one_line_error(capsys, policy, said)
    assert "allow_pickle" not in line and "is none" not in line


# ------------------------------------------------------------- 7. Lee's model and --side
def test_calibrate_lee_on_squares_too_small_names_side(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", "lee", "--side", "0.01", "--runs", "1"]) == 2
    line = one_line_error(capsys, "--side 0.01", "Lee et al.")
    assert "internal error" not in line


# ------------------------------------------------------------- 8. run straight --return-trip
def test_return_trip_help_says_what_the_route_does() -> None:
    from odomgym.sim.routes import straight_route

    straight = _subparser(_subparser(build_parser(), "run"), "straight")
    (action,) = [a for a in straight._actions if "--return-trip" in a.option_strings]
    assert action.help is not None
    assert "reverse" in action.help and "turn on the spot" not in action.help
    route = straight_route(2.0, return_trip=True)
    assert [s.reverse for s in route.segments] == [False, True]
    assert all(s.kind == "drive" for s in route.segments)  # no turn: what the help says
    for doc in [ROOT / "README.md", *(ROOT / "docs").glob("**/*.md")]:
        assert "turn on the spot at the end" not in doc.read_text(encoding="utf-8"), doc


def _subparser(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    """The sub-command ``name`` of ``parser``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and name in action.choices:
            found: argparse.ArgumentParser = action.choices[name]
            return found
    raise KeyError(name)


# ------------------------------------------------------------- 9. docs/specs.md's quote
def test_specs_md_quotes_the_roughness_error_the_loader_raises(tmp_path: Path) -> None:
    from odomgym.floor import load_floor

    text = (ROOT / "docs" / "specs.md").read_text(encoding="utf-8")
    (quoted,) = re.findall(r"`(roughness must lie in [^`]*)`", text)
    floor = tmp_path / "rough.toml"
    floor.write_text("roughness = 2.0\n", encoding="utf-8")
    with pytest.raises(SpecError) as raised:
        load_floor(str(floor))
    assert str(raised.value).endswith(quoted)


# ------------------------------------------------------------- 10. repeated list options
def test_bench_repeated_list_options_accumulate(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    calls = _stop_at_work(monkeypatch, "odomgym.baselines.benchmark", "run_benchmark")
    argv = ["bench", "calibrators", "--robots", "1", "--out", str(tmp_path / "b"),
            "--floor", "concrete", "--floor", "rough", "--methods", "umbmark",
            "--methods", "lee", "--budget", "4", "--budget", "2"]  # fmt: skip
    assert main(argv) == 2 and "REACHED" in capsys.readouterr().err
    config = calls[0][0][0]
    assert config.floors == ("concrete", "rough")
    assert config.methods == ("umbmark", "lee")
    assert config.budgets == (4, 2)
    assert main(["bench", "calibrators", "--robots", "1", "--out", str(tmp_path / "c")]) == 2
    assert calls[1][0][0].budgets == (16,)  # the default, when --budget is not given


def test_bench_skid_repeated_presets_accumulate(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    calls = _stop_at_work(monkeypatch, "odomgym.baselines.skid_bench", "run_skid_bench")
    argv = ["bench", "skid", "--presets", "scout2", "--presets", "husky", "--floor", "smooth",
            "--floor", "slippery", "--out", str(tmp_path / "s")]  # fmt: skip
    assert main(argv) == 2 and "REACHED" in capsys.readouterr().err
    config = calls[0][0][0]
    assert config.robots == ("scout2", "husky") and config.floors == ("smooth", "slippery")

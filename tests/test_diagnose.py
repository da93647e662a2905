"""The discrepancy workflow (``odomgym diagnose``) on data whose missing effect it is not told.

Two sources of logs:

* the independent generator of ``tests/independent_robot.py`` — continuous-time exact-arc
  integration, S-curve speed profiles, 10 Hz logs, no odomgym simulator code — so the workflow is
  shown not to depend on odomgym's own World;
* the pymunk World itself (:func:`odomgym.diagnose.generate.hidden_effect_trial`), at magnitudes
  of 3–10 × each effect's detection limit (three Cramér–Rao standard errors, see
  :func:`odomgym.diagnose.generate.detection_limit`).

The confusion matrix over many seeds is ``benchmarks/bench_diagnose.py``; these tests pin a
fixed set of seeds.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import threadpoolctl
from independent_robot import IndependentRobot, generate, rich_protocol

from odomgym.cli import main
from odomgym.data.native import write_native
from odomgym.diagnose import workflow
from odomgym.diagnose.generate import NOMINAL_ROBOT, hidden_effect_trial
from odomgym.diagnose.report import report_json
from odomgym.diagnose.workflow import DiagnoseConfig, diagnose
from odomgym.effects import catalogue
from odomgym.robot import RobotSpec, load_robot

MODEL = RobotSpec(wheel_diameter=0.084, wheelbase=0.2, ticks_per_rev=2796.8, max_wheel_speed=0.6)


def _independent(effects: dict[str, dict[str, float]], seed: int) -> list:  # type: ignore[type-arg]
    return generate(IndependentRobot(effects=effects), rich_protocol(), np.random.default_rng(seed))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "values", "verdict"),
    [
        # A toe and an offset of the tracked point are a frame yaw and a tracked point of the
        # ground truth (which one session does not fit): the verdict names both readings
        # ("confounded") where the fit moved along them. For the toe the direction's relative
        # singular value is 9.9e-4 on these logs (not exactly zero: the open-loop replay starts
        # from the measured heading of the first second, which a frame yaw also turns), inside
        # the 1e-3 rule, and the fit moved 18 standard errors along it.
        ("wheel_toe", {"angle": 0.005}, "confounded"),
        # 15 mrad of wheel slack: once the clock was fitted beside the geometry alone, the
        # slack's lag at every start was taken for a clock offset, and the backlash fitted on
        # the re-timed logs predicted the held-out runs no better than the model as given
        # (2.92 against 2.88 mm, "unconfirmed"); with the clock fitted beside backlash too,
        # the held-out runs confirm it.
        ("backlash", {"angle": 0.015}, "explained"),
        ("gt_sensor_offset", {"dx": 0.006, "dy": -0.004}, "confounded"),
        ("turn_skid", {"gain": 0.2}, "explained"),
        # Its mirror image, a robot over-turning in fast turns: offered to a differential-drive
        # robot too (issue 43: no candidate filtered by the robot's class).
        ("skid_speed", {"gain": 0.2}, "explained"),
    ],
)
def test_independent_generator_effect_is_named_and_fitted(
    name: str, values: dict[str, float], verdict: str
) -> None:
    result = diagnose(_independent({name: values}, seed=11), MODEL, DiagnoseConfig(seed=1))
    assert result.verdict == verdict, result.verdict
    if verdict == "confounded":
        moved = [c for c in result.confounds if c["moved"]]
        assert moved and all(
            any(part["name"].startswith(name) for part in c["components"]) for c in moved
        )
        if name == "wheel_toe":
            assert any(part["name"] == "frame_yaw" for c in moved for part in c["components"])
    assert result.held_out is not None
    assert result.held_out.better_than_as_given == (verdict != "unconfirmed")
    assert result.named_effects[0] == name
    for key, truth in values.items():
        fitted = result.parameters[name][key]
        # Within 5 standard errors or 5 % of the truth (the independent generator's continuous
        # motion is not the replay's sampled one: a small model difference remains).
        assert abs(fitted["value"] - truth) < max(5 * fitted["stderr"], 0.05 * abs(truth)), key
    assert result.gap_after < result.gap_before


@pytest.mark.slow
def test_bumps_refused_by_their_signature_are_not_fitted_and_nothing_else_changes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """On logs without heavy-tailed heading jumps the mean stage does not fit ``floor_bumps``
    (the signature check refuses it whatever its fit): every round says so with the kurtosis
    test's reason, and the diagnosis is the one the fitted-and-refused bumps gave — the same
    effects, values, verdict and the same likelihood-ratio p-values (the Bonferroni family
    still counts the bumps)."""
    from odomgym.diagnose import rounds

    # Seed 7: the kurtosis test finds no jumps in either round (on seeds 5 and 6 of this
    # generator it does, p < 0.025, and the bumps are fitted as before).
    runs = _independent({"wheelbase": {"e_b": 1.004}}, seed=7)
    screened = diagnose(runs, MODEL, DiagnoseConfig(seed=7))
    assert [bool(r.screened) for r in screened.rounds] == [True, True]
    for r in screened.rounds:
        assert "no heavy-tailed heading jumps" in r.screened["floor_bumps"], r.screened
        assert "floor_bumps" not in {c.name for c in r.candidates if c.stage == "mean"}
    monkeypatch.setattr(rounds, "_screened", lambda *args: {})
    fitted = diagnose(runs, MODEL, DiagnoseConfig(seed=7))
    assert all(not r.screened for r in fitted.rounds)
    assert any(c.name == "floor_bumps" and c.stage == "mean" for c in fitted.candidates)
    assert screened.named_effects == fitted.named_effects == ["wheelbase"]
    assert screened.verdict == fitted.verdict
    same = json.dumps(screened.parameters, sort_keys=True)  # NaN-aware: 'NaN' == 'NaN'
    assert same == json.dumps(fitted.parameters, sort_keys=True)
    before = {(c.round, c.name): c for c in fitted.candidates}
    for c in screened.candidates:
        was = before[(c.round, c.name)]
        assert (c.p_family, c.cv_gain, c.significant) == (
            was.p_family,
            was.cv_gain,
            was.significant,
        )
    assert [(r.verdict, r.winner, r.tied) for r in screened.rounds] == [
        (r.verdict, r.winner, r.tied) for r in fitted.rounds
    ]
    assert json.loads(report_json(screened))["rounds"][0]["screened"] == screened.rounds[0].screened


@pytest.mark.slow
def test_independent_generator_without_effect_is_none() -> None:
    result = diagnose(_independent({}, seed=12), MODEL, DiagnoseConfig(seed=2))
    assert result.verdict == "none"
    assert result.named_effects == []


# Each case's seed: its place in the catalogue as it stood when the test was written (sorted),
# an effect that joined later after them, so that the earlier cases keep their seeds.
_SEED_ORDER = (*sorted(n for n in catalogue() if n != "skid_speed"), "skid_speed")


@pytest.mark.slow
@pytest.mark.parametrize("name", [*catalogue(), None])
def test_world_hidden_effect_at_three_times_the_detection_limit(name: str | None) -> None:
    """One blind trial per effect (and one without) at 3-10 x the detection limit.

    The detection limit is the filter's (three Cramér–Rao standard errors); the open-loop gate
    keeps an effect only where it lowers the error of predicting left-out runs open loop, which
    has less power for the smallest effects (E_s = 1.0005, 9.6x the filter's limit, moves a
    2-m run by 1 mm). So the effect must be either named, or proposed first by the likelihood
    and reported ``unconfirmed`` — never another name."""
    trial = hidden_effect_trial(name, "rich", seed=100 + (_SEED_ORDER.index(name) if name else 99))
    if name is None:
        assert trial["verdict"] == "none", trial
    elif trial["top1"] == "unconfirmed":
        assert trial["proposed"] == name, trial
        assert trial["named"] == [], trial
    else:
        assert trial["top1"] == name, trial
        assert trial["gap_after"] <= trial["gap_before"], trial


@pytest.mark.slow
def test_umbmark_end_points_cannot_separate_wheelbase_from_its_look_alikes() -> None:
    """Squares measured at their end points only: a wheelbase error (E_b = 1.01) under-turns
    every corner, and so does a mean-diameter scale E_s = 1/E_b (it scales the wheel travel of
    the turns too), while the scaled legs of a closed square leave its end point where it was.
    The verdict must be ambiguous, wheelbase among the tied, and the separating experiment a
    straight run (E_s stretches it by 1 %, E_b does not)."""
    from odomgym.diagnose.generate import simulate_protocol

    robot = NOMINAL_ROBOT.with_errors(e_b=1.01)
    runs = simulate_protocol(robot, "umbmark", np.random.default_rng(3))
    result = diagnose(runs, NOMINAL_ROBOT, DiagnoseConfig(seed=3))
    last = result.rounds[-1]
    assert result.verdict == "ambiguous", [(c.name, c.cv_gain) for c in last.candidates]
    assert "wheelbase" in last.tied
    assert last.separating is not None
    if set(last.separating["between"]) == {"wheelbase", "distance_scale"}:
        assert last.separating["experiment"].startswith("straight")
        assert last.separating["separation_mm"] > 20  # 1 % of 4 m


@pytest.mark.slow
def test_cli_diagnose_native_log_writes_the_report_and_a_loadable_model(tmp_path: Path) -> None:
    runs = _independent({"wheel_diameter_ratio": {"e_d": 1.004}}, seed=13)
    data = tmp_path / "robot_logs.csv"
    write_native(data, runs)
    robot = tmp_path / "robot.toml"
    MODEL.save(robot)
    out = tmp_path / "out"
    assert main(["diagnose", str(data), "--robot", str(robot), "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    for key in (
        "verdict",
        "named_effects",
        "parameters",
        "gap_before",
        "gap_after",
        "gap_metric",
        "candidates",
    ):
        assert key in report
    # The open-loop fit's E_d (1.003968; truth 1.004) predicts the left-out blocks better by
    # one standard error than the filter's, so it is the one reported; the held-out whiteness
    # test still sees its 3e-5 as structure (z = 8): ``partly explained``, honestly.
    assert report["verdict"] in ("explained", "partly explained")
    assert report["held_out_open_loop"]["better_than_as_given"]
    assert report["named_effects"] == ["wheel_diameter_ratio"]
    assert report["gap_after"] < report["gap_before"]
    assert {"report.md", "model.toml", "gap_before_after.png", "where.png"} <= {
        p.name for p in out.iterdir()
    }
    model = load_robot(out / "model.toml")
    assert model.e_d == pytest.approx(1.004, rel=2e-4)
    env = gym.make("UMBmarkSquare-v0", robot=str(out / "model.toml"))
    assert env.unwrapped.robot.e_d == pytest.approx(model.e_d)


def test_cli_run_log_round_trips_through_the_native_reader(tmp_path: Path) -> None:
    from odomgym.data.native import read_native

    log = tmp_path / "runs.csv"
    code = main(
        [
            "run",
            "square",
            "--robot",
            "optiodom",
            "--side",
            "0.5",
            "--runs",
            "1",
            "--log",
            str(log),
            "--json",
        ]
    )
    assert code == 0
    runs = read_native(log)
    assert [r.meta["experiment"] for r in runs] == ["square_cw", "square_ccw"]
    assert np.isfinite(runs[0].true_pose).all()


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("[robot.effects.wheel_wobble]\namount = 1.0\n", r"robot\.toml:\d+: unknown effect"),
        ("[robot.effects.backlash]\nangle = -1.0\n", r"robot\.toml:\d+: effects\.backlash"),
    ],
)
def test_cli_bad_robot_toml_is_one_line_and_leaves_no_output(
    tmp_path: Path, text: str, pattern: str
) -> None:
    data = tmp_path / "logs.csv"
    write_native(data, _independent({}, seed=1)[:4])
    robot = tmp_path / "robot.toml"
    robot.write_text(
        "[robot]\nwheel_diameter = 0.084\nwheelbase = 0.2\nticks_per_rev = 2796.8\n" + text
    )
    out = tmp_path / "out"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "odomgym.cli",
            "diagnose",
            str(data),
            "--robot",
            str(robot),
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    import re

    assert re.search(pattern, lines[0]), lines[0]
    assert not out.exists()


def test_cli_bad_log_names_file_line_and_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = tmp_path / "logs.csv"
    data.write_text(
        "run,experiment,t,ticks_left,ticks_right,x,y,theta\n"
        "1,straight,0,0,0,0,0,0\n1,straight,0.1,5,5,,,\n1,straight,0.05,9,9,0.01,0,0\n"
    )
    robot = tmp_path / "robot.toml"
    MODEL.save(robot)
    assert main(["diagnose", str(data), "--robot", str(robot), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "logs.csv:4" in err and "t" in err
    assert not (tmp_path / "o").exists()


def test_too_few_runs_with_ground_truth_is_one_line_naming_the_runs_set_aside() -> None:
    """A run without a measured pose after its start is set aside (odomgym.diagnose.screen);
    with fewer than three usable runs left the diagnosis stops in one line that names it."""
    runs = _independent({}, seed=2)[:3]
    runs[0].true_pose[1:] = math.nan
    from odomgym.errors import SpecError

    with pytest.raises(SpecError, match="only 2 of 3 have it; set aside: run 000 ") as caught:
        diagnose(runs, MODEL, DiagnoseConfig(holdout=0.25))
    assert "no measured position after its first full pose" in str(caught.value)
    assert "\n" not in str(caught.value) and caught.value.field == "x"


def _blas_threads() -> list[int]:
    return [int(lib["num_threads"]) for lib in threadpoolctl.threadpool_info()
            if lib["user_api"] == "blas"]  # fmt: skip


def test_diagnose_runs_its_blas_on_one_thread_and_gives_the_threads_back(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Inside :func:`diagnose` every BLAS library numpy and scipy loaded runs on one thread
    (OpenBLAS's spinning idle threads took a third of a diagnosis's CPU on 2 cores, and a
    threaded dot product's rounding depends on the thread count); after it, error or not, the
    caller's setting is back."""
    runs = _independent({}, seed=4)[:4]
    seen: list[list[int]] = []

    class Stop(Exception):
        pass

    def spy(*args: object, **kwargs: object) -> None:
        seen.append(_blas_threads())
        raise Stop

    monkeypatch.setattr(workflow, "split_runs", spy)
    if not _blas_threads():
        pytest.skip("threadpoolctl finds no BLAS library in this process")
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        outside = _blas_threads()
        with pytest.raises(Stop):
            diagnose(runs, MODEL)
        after = _blas_threads()
    assert seen == [[1] * len(outside)]
    assert after == outside

"""The checks that keep a diagnosis to what a robot physically does and to data it never saw:
the held-out split, the physical size of discovered terms, the floor bumps' signature and
magnitude, and the open-loop gate's rules.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import pickle
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from independent_robot import IndependentRobot, generate, rich_protocol

from odomgym.diagnose import gate as gate_module
from odomgym.diagnose import openloop as openloop_module
from odomgym.diagnose.config import DiagnoseConfig
from odomgym.diagnose.fit import (
    at_nothing,
    bounded_gauss_newton_step,
    cross_validate,
    gauss_newton_step,
)
from odomgym.diagnose.gate import (
    MAX_INFLATION,
    GateResult,
    fit_nested,
    model_effect,
    open_loop_gate,
)
from odomgym.diagnose.generate import NOMINAL_ROBOT, simulate_protocol
from odomgym.diagnose.openloop import (
    NuisanceOptions,
    OpenLoopData,
    fit_open_loop,
    open_loop_folds,
    variance_inflation,
)
from odomgym.diagnose.physical import (
    PLAUSIBLE_CHANGE,
    bump_size_reasons,
    check_bumps,
    term_size,
)
from odomgym.diagnose.report import _rule as report_rule
from odomgym.diagnose.workflow import split_runs
from odomgym.effects import EFFECTS
from odomgym.errors import SpecError
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec
from odomgym.sim.cables import bump_extra_rotation
from odomgym.workers import TaskFailed

ROBOT = RobotSpec(wheel_diameter=0.084, wheelbase=0.2, ticks_per_rev=2796.8, max_wheel_speed=0.6)


@pytest.fixture(scope="module")
def runs() -> list[Run]:
    return generate(IndependentRobot(), rich_protocol(), np.random.default_rng(21))


def _tagged(runs: list[Run], sessions: list[tuple[str, str]]) -> list[Run]:
    """Copies of the first runs, labelled with (session, path type) in turn."""
    out = []
    for k, (session, kind) in enumerate(sessions):
        for run in runs[3 * k : 3 * k + 3]:
            out.append(
                Run(
                    run.kind,
                    run.time,
                    run.counts,
                    run.true_pose,
                    run.direction,
                    meta={**run.meta, "session": session, "path_type": kind},
                )
            )
    return out


def test_sessions_are_held_out_whole_and_every_kind_keeps_one_to_fit(runs: list[Run]) -> None:
    labelled = _tagged(
        runs,
        [("a", "square"), ("b", "square"), ("c", "square"), ("d", "ivanjko"), ("e", "ivanjko")],
    )
    fit, held, split = split_runs(labelled, 0.3, np.random.default_rng(0))
    assert split == "sessions"
    sessions = [str(r.meta["session"]) for r in labelled]
    held_sessions = {sessions[j] for j in held}
    fit_sessions = {sessions[j] for j in fit}
    assert held_sessions and not held_sessions & fit_sessions
    assert {"a", "b", "c"} & fit_sessions and {"d", "e"} & fit_sessions
    assert len(held_sessions & {"a", "b", "c"}) == 1  # round(0.3 × 3)


def test_one_session_holds_out_a_contiguous_block_of_each_family(runs: list[Run]) -> None:
    fit, held, split = split_runs(runs, 0.3, np.random.default_rng(1))
    assert split == "blocks"
    families: dict[str, list[int]] = {}
    for j, run in enumerate(runs):
        families.setdefault(str(run.meta["experiment"]).split("_")[0], []).append(j)
    for members in families.values():
        chosen = [members.index(j) for j in held if j in members]
        assert len(chosen) == min(round(0.3 * len(members)), len(members) - 1)
        assert chosen == list(range(chosen[0], chosen[0] + len(chosen))) if chosen else True
    assert sorted(fit + held) == list(range(len(runs)))


def test_folds_are_sessions_or_blocks(runs: list[Run]) -> None:
    labelled = _tagged(runs, [("a", "square"), ("b", "square"), ("c", "ivanjko")])
    assert [len(f) for f in open_loop_folds(labelled)] == [3, 3, 3]
    folds = open_loop_folds(runs, blocks=5)
    assert len(folds) == 5 and sorted(j for f in folds for j in f) == list(range(len(runs)))


def test_a_term_is_judged_at_the_data_operating_range(runs: list[Run]) -> None:
    """left_one = 0.3 % is a wheel 0.3 % large: plausible. left_accel = 2 per m/s² changes the
    travel by tens of percent at the accelerations of these runs: a stand-in. A crab of 0.2 rad
    (11°) constant: a stand-in (beyond 5°)."""
    assert term_size(runs, ROBOT, "left_one", 0.003).plausible
    accel = term_size(runs, ROBOT, "left_accel", 2.0)
    assert not accel.plausible and accel.change > PLAUSIBLE_CHANGE
    assert accel.change == pytest.approx(2.0 * accel.operating)
    crab = term_size(runs, ROBOT, "crab_one", 0.2)
    assert not crab.plausible and "crab" in crab.reason
    huge = term_size(runs, ROBOT, "right_speed", -50.0)
    assert not huge.plausible and "backwards" in huge.reason


def test_bumps_need_their_signature_and_a_size_the_floor_can_make() -> None:
    """A robot whose wheels cross bumps (0.5 per metre, 1.5° jumps) shows heavy-tailed heading
    increments in steady driving; one without shows none. A 10° jump on a 42 mm wheel would lose
    35 mm of travel per bump, more than crossing a 20 mm obstacle can (Borenstein's
    rigid-wheel-over-cylinder geometry)."""
    rng = np.random.default_rng(8)
    bumpy = EFFECTS["floor_bumps"].write(
        NOMINAL_ROBOT, {"rate": 0.5, "heading_jump": math.radians(1.5)}
    )
    with_bumps = simulate_protocol(bumpy, "rich", rng)
    without = simulate_protocol(NOMINAL_ROBOT, "rich", rng)
    values = {"rate": 0.5, "heading_jump": math.radians(1.5)}

    def check(runs: list[Run], values: dict[str, float]) -> Any:
        return check_bumps(
            runs,
            NOMINAL_ROBOT,
            values,
            max_obstacle=0.02,
            max_rate=1.0,
            interval=0.25,
            alpha=0.025,
        )

    found = check(with_bumps, values)
    assert found.signature and found.plausible and found.accepted, found
    absent = check(without, values)
    assert not absent.signature and not absent.accepted, absent
    ten_degrees = {"rate": 0.75, "heading_jump": math.radians(10.0)}
    huge = check(with_bumps, ten_degrees)
    radius = 0.5 * NOMINAL_ROBOT.wheel_diameter
    assert huge.largest_loss == pytest.approx(bump_extra_rotation(radius, 0.02))
    assert not huge.plausible and "obstacle" in huge.reason
    frequent = check(with_bumps, {"rate": 3.5, "heading_jump": math.radians(0.57)})
    assert not frequent.plausible and "per metre" in frequent.reason
    first = with_bumps[0]  # its first seconds: too few steady intervals to test
    cut = dataclasses.replace(
        first, time=first.time[:40], counts=first.counts[:40], true_pose=first.true_pose[:40]
    )
    short = check([cut], values)
    assert short.steady_intervals < 20 and not short.accepted
    assert "too little steady driving" in short.reason and "nan" not in short.reason, short


@pytest.fixture(scope="module")
def wheelbase_case() -> tuple[list[Run], RobotSpec]:
    """Runs of a robot with a 1 % wheelbase error, and the model the rounds would propose for
    them: that wheelbase and a made-up term (right_sin1 at 1 %)."""
    robot = IndependentRobot(effects={"wheelbase": {"e_b": 1.01}})
    runs = generate(robot, rich_protocol(), np.random.default_rng(31))
    proposed = EFFECTS["wheelbase"].write(ROBOT, {"e_b": 1.01})
    proposed = model_effect((), ("right_sin1",)).write(  # type: ignore[union-attr]
        proposed, {"discovered.right_sin1": 0.01}
    )
    return runs, proposed


def test_the_gate_keeps_a_real_effect_and_drops_a_made_up_term(
    wheelbase_case: tuple[list[Run], RobotSpec],
) -> None:
    """A robot with a 1 % wheelbase error: the wheelbase lowers the held-out open-loop error and
    is kept; a term that is not there (right_sin1 at 1 %) raises it and is dropped."""
    runs, proposed = wheelbase_case
    data = OpenLoopData(runs, 0.25, ROBOT.wheelbase)
    gate = open_loop_gate(
        data,
        ROBOT,
        proposed,
        ["wheelbase"],
        ["right_sin1"],
        NuisanceOptions(),
        open_loop_folds(runs),
    )
    assert gate.effects == ["wheelbase"] and gate.terms == []
    first, second = gate.steps
    assert first.kept and first.after_mm < first.before_mm
    assert not second.kept and second.rule == "one standard error"
    assert abs(gate.fit.spec.e_b - 1.01) < 0.001


def test_the_gate_in_worker_processes_is_the_serial_gate_bit_for_bit(
    wheelbase_case: tuple[list[Run], RobotSpec],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``jobs=2``: each pass's trials, and the readmission's refits, run in forked worker
    processes, and the result is the serial gate's to the last bit — the same steps, the same
    fitted values and held-out errors — with two proposals removed and both tried back in (a
    1 % wheelbase error, a distance scale and a diameter ratio it does not have, a made-up
    term). A pass whose worker fails runs again in the caller: the same result."""
    runs, proposed = wheelbase_case
    proposed = EFFECTS["distance_scale"].write(proposed, {"e_s": 1.004})
    proposed = EFFECTS["wheel_diameter_ratio"].write(proposed, {"e_d": 1.003})
    data = OpenLoopData(runs, 0.25, ROBOT.wheelbase)
    folds = open_loop_folds(runs)
    said: list[str] = []
    forked: list[int] = []
    real_run_forked = gate_module.run_forked

    def spy(task: Any, items: Any, processes: int, finished: Any, doing: Any) -> None:
        listed = list(items)
        forked.append(len(listed))
        real_run_forked(task, listed, processes, finished, doing)

    monkeypatch.setattr(gate_module, "run_forked", spy)

    def gate(jobs: int) -> GateResult:
        return open_loop_gate(
            data,
            ROBOT,
            proposed,
            ["wheelbase", "distance_scale", "wheel_diameter_ratio"],
            ["right_sin1"],
            NuisanceOptions(),
            folds,
            report=lambda stage, fraction: said.append(stage),
            jobs=jobs,
        )

    serial = gate(1)
    stages = list(said)
    assert not forked
    assert any("readmitting" in stage for stage in stages)
    said.clear()
    parallel = gate(2)
    assert len(forked) >= 2 and all(count >= 2 for count in forked)
    assert sum("readmitting" in stage for stage in said) >= 2  # both refits, forked
    assert len([s for s in serial.steps if not s.kept]) >= 2
    assert parallel.steps == serial.steps
    assert parallel.effects == serial.effects and parallel.terms == serial.terms
    assert pickle.dumps(parallel.fit.values) == pickle.dumps(serial.fit.values)
    assert parallel.fit.spec == serial.fit.spec
    assert parallel.cv_error.tobytes() == serial.cv_error.tobytes()
    assert parallel.fit.problem.data is data  # the caller's runs, not a copy of them
    # Every trial's progress, in whatever order; and each forked pass says when it starts,
    # with its number of trials (the serial pass names each trial as it starts instead).
    starts = [stage for stage in said if stage.endswith(" trials")]
    assert sorted(stage for stage in said if stage not in starts) == sorted(stages)
    assert [int(stage.split(": ")[1].split()[0]) for stage in starts] == forked

    def fails(task: Any, items: Any, processes: int, finished: Any, doing: Any) -> None:
        raise TaskFailed(0, "PicklingError: a user effect defined inside a function")

    monkeypatch.setattr(gate_module, "run_forked", fails)
    again = gate(2)
    assert again.steps == serial.steps
    assert again.cv_error.tobytes() == serial.cv_error.tobytes()


def test_catalogue_first_decides_the_effects_without_the_terms(
    wheelbase_case: tuple[list[Run], RobotSpec],
) -> None:
    """``gate_order="catalogue first"``: the catalogue effects are eliminated on their own —
    the same effects and the same held-out errors as a gate offered no terms at all — and a term
    is then judged against the model of those effects, which it cannot remove (a 1 % wheelbase
    error, a made-up right_sin1: the wheelbase stays, the term goes by the one-standard-error
    rule, its "without" error the effects-only model's)."""
    runs, proposed = wheelbase_case
    data = OpenLoopData(runs, 0.25, ROBOT.wheelbase)
    folds = open_loop_folds(runs)

    def gate(terms: list[str], order: str) -> GateResult:
        return open_loop_gate(
            data, ROBOT, proposed, ["wheelbase"], terms, NuisanceOptions(), folds, order=order
        )

    staged, alone = gate(["right_sin1"], "catalogue first"), gate([], "joint")
    assert staged.effects == alone.effects == ["wheelbase"] and staged.terms == []
    effect, term = staged.steps
    assert effect == alone.steps[0]
    assert term.name == "right_sin1" and not term.kept and term.rule == "one standard error"
    assert term.before_mm == alone.steps[0].after_mm
    # the model left when the term goes is the effects-only fit itself, not a refit of it from
    # the term's model (gate.fit_nested)
    assert staged.fit.values == alone.fit.values
    assert np.array_equal(staged.cv_error, alone.cv_error)
    assert abs(staged.fit.spec.e_b - 1.01) < 0.001
    with pytest.raises(ValueError, match="order"):
        gate([], "terms first")
    with pytest.raises(SpecError, match="gate_order"):
        DiagnoseConfig(gate_order="terms first")


def test_a_term_the_sessions_frames_absorb_is_not_identifiable(runs: list[Run]) -> None:
    """With every session's frame fitted, a constant crab angle only trades against the frames'
    yaw and the tracked heading, so its variance inflation is unbounded: the gate refuses it as
    "not identifiable" whatever it does to the held-out error (on June OptiOdom sessions such a
    term made E_s and E_b 1.00 ± 2.4), and the wheelbase keeps a finite standard error."""
    robot = IndependentRobot(effects={"wheelbase": {"e_b": 1.01}})
    tagged = _tagged(
        generate(robot, rich_protocol(), np.random.default_rng(31)),
        [(f"s{k}", "square") for k in range(4)],
    )
    proposed = EFFECTS["wheelbase"].write(ROBOT, {"e_b": 1.01})
    proposed = model_effect((), ("crab_one",)).write(  # type: ignore[union-attr]
        proposed, {"discovered.crab_one": 0.01}
    )
    gate = open_loop_gate(
        OpenLoopData(tagged, 0.25, ROBOT.wheelbase),
        ROBOT,
        proposed,
        ["wheelbase"],
        ["crab_one"],
        NuisanceOptions(frames=True),
        open_loop_folds(tagged),
    )
    assert gate.effects == ["wheelbase"] and gate.terms == []
    crab = next(s for s in gate.steps if s.name == "crab_one")
    assert not crab.kept and crab.rule == "not identifiable" and crab.inflation > MAX_INFLATION
    assert report_rule(crab).startswith("not identifiable (VIF ")  # report.md says why
    wheelbase = next(s for s in gate.steps if s.name == "wheelbase")
    assert wheelbase.kept and wheelbase.inflation < MAX_INFLATION
    assert gate.fit.stderr_sessions["wheelbase.e_b"] < 1e-3
    assert abs(gate.fit.spec.e_b - 1.01) < 0.001


def test_variance_inflation_is_one_over_one_minus_r_squared() -> None:
    """Two columns of correlation ρ inflate each other's variance by 1 / (1 − ρ²) (Kutner et al.
    2005, §10.5), whatever their scales; an orthogonal column is not inflated; a column that is a
    combination of others is infinitely inflated."""
    rng = np.random.default_rng(5)
    a, b, c = rng.standard_normal((3, 400))
    a -= a.mean()
    b -= b.mean()
    c -= c.mean()
    b -= (a @ b) / (a @ a) * a  # orthogonal to a
    rho = 0.8
    mixed = rho * a / np.linalg.norm(a) + math.sqrt(1 - rho**2) * b / np.linalg.norm(b)
    jac = np.column_stack([3.0 * a, 0.01 * mixed])
    normal = jac.T @ jac
    vif = variance_inflation(normal, np.linalg.inv(normal))
    assert vif == pytest.approx([1 / (1 - rho**2)] * 2, rel=1e-9)
    ortho = np.column_stack([a, b])
    assert variance_inflation(ortho.T @ ortho, np.linalg.inv(ortho.T @ ortho)) == pytest.approx(
        [1.0, 1.0], rel=1e-9
    )
    singular = np.column_stack([a, b, a - 2.0 * b, c])
    normal = singular.T @ singular
    vif = variance_inflation(normal, np.linalg.pinv(normal))
    assert np.all(np.isinf(vif[:3])) and vif[3] == pytest.approx(1.0, abs=0.2)


def test_a_fit_stopped_above_the_model_it_nests_is_fitted_again_from_that_model(
    wheelbase_case: tuple[list[Run], RobotSpec], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A least-squares fit of wheelbase + right_sin1 that stops where it started, far from the
    optimum (e_b 1.2), ends above the fit of the wheelbase alone, a point it could reach (the
    term at zero); :func:`fit_nested` fits it again from there and lands on the robot's 1 %."""
    runs, _ = wheelbase_case
    data = OpenLoopData(runs, 0.25, ROBOT.wheelbase)
    options = NuisanceOptions()
    base = fit_open_loop(data, ROBOT, EFFECTS["wheelbase"], options)
    joint = model_effect(["wheelbase"], ["right_sin1"])
    assert joint is not None
    far = joint.write(ROBOT, {"wheelbase.e_b": 1.2, "discovered.right_sin1": 0.0})
    real = openloop_module._levenberg_marquardt
    calls: list[int] = []

    def stops_first_time(problem: Any, x0: Any, max_iterations: int = 30) -> Any:
        calls.append(max_iterations)
        return real(problem, x0, 0 if len(calls) == 1 else max_iterations)

    monkeypatch.setattr(openloop_module, "_levenberg_marquardt", stops_first_time)
    stopped = fit_open_loop(data, far, joint, options)
    assert stopped.error > base.error  # the premise: stuck above the smaller model
    calls.clear()
    fit = fit_nested(data, far, joint, options, None, base)
    assert len(calls) == 2  # stopped, then fitted again from the wheelbase alone
    assert fit.error <= base.error
    assert abs(fit.spec.e_b - 1.01) < 0.001
    calls.clear()
    assert fit_nested(data, base.spec, joint, options, base.nuisances, base).error <= base.error
    assert len(calls) == 1  # a fit that ends at or below it is not redone


def test_a_proposal_left_out_takes_the_robots_given_value(
    wheelbase_case: tuple[list[Run], RobotSpec], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A robot given with a calibrated wheelbase (E_b 1.0095): the gate's model "without the
    wheelbase" keeps that E_b — the robot as given, as the empty model is — not the effect's
    absent value 1; so the fit of a smaller model is a point of every larger one
    (:func:`fit_nested`)."""
    runs, _ = wheelbase_case
    data = OpenLoopData(runs, 0.25, ROBOT.wheelbase)
    given = EFFECTS["wheelbase"].write(ROBOT, {"e_b": 1.0095})
    proposed = EFFECTS["distance_scale"].write(
        EFFECTS["wheelbase"].write(ROBOT, {"e_b": 1.01}), {"e_s": 1.001}
    )
    real = gate_module.fit_open_loop
    starts: list[tuple[float, list[str]]] = []

    def spy(data: Any, spec: RobotSpec, effect: Any = None, *args: Any) -> Any:
        names = [p.name for p in effect.parameters] if effect is not None else []
        starts.append((EFFECTS["wheelbase"].read(spec)["e_b"], names))
        return real(data, spec, effect, *args)

    monkeypatch.setattr(gate_module, "fit_open_loop", spy)
    open_loop_gate(
        data,
        given,
        proposed,
        ["wheelbase", "distance_scale"],
        [],
        NuisanceOptions(),
        open_loop_folds(runs),
    )
    without = [e_b for e_b, names in starts if "wheelbase.e_b" not in names]
    assert without and all(e_b == pytest.approx(1.0095, abs=1e-12) for e_b in without)


def _four_fold_gate(cls: Any, lenient: set[str]) -> Any:
    """A gate of class ``cls`` (the elimination, or a scripted subclass) over four one-run
    folds of no data, on the nominal robot, with the effects ``lenient`` named by the rounds."""
    return cls(
        data=None,
        robot=ROBOT,
        proposed=ROBOT,
        options=NuisanceOptions(),
        folds=[[0], [1], [2], [3]],
        start=None,
        lenient=lenient,
        report=None,
        filtered=None,
        corrected=None,
    )


def test_a_base_stays_while_its_extension_is_tested_and_a_wrongly_removed_effect_returns() -> None:
    """The gate's stepwise rules on scripted fold errors (the June OptiOdom fold without
    230620202317, in miniature): the model with a skid track (S), the wheelbase it extends (W)
    and a diameter ratio (D) is not identifiable (105 mm), and a fit started from it goes astray
    (W and D from there: 25 mm; from a sound start: 4.8 mm). W may not leave while S, which
    extends it, is in the model (the principle of marginality); D, removed first for the ridge,
    returns in the forward step (Efroymson 1960) and S stays out."""
    ridge = EFFECTS["wheelbase"].write(ROBOT, {"e_b": 0.7})
    table = {"": 12.0, "S": 7.0, "W": 6.0, "D": 11.0, "SW": 19.0, "SD": 30.0, "SWD": 105.0}
    names = {"skid_track": "S", "wheelbase": "W", "wheel_diameter_ratio": "D"}

    class Scripted(gate_module._Elimination):
        def fitted(self, members: Any, begin: RobotSpec, nuisances: Any, base: Any) -> Any:
            key = "".join(sorted((names[n] for _, n in members), key="SWD".index))
            astray = EFFECTS["wheelbase"].read(begin)["e_b"] < 0.8
            mm = (25.0 if astray else 4.8) if key == "WD" else table[key]
            cv = np.full(4, (mm / 1e3) ** 2)
            fit = SimpleNamespace(
                spec=ridge if "S" in key else ROBOT,
                nuisances={},
                inflation={},
                robot_inflation={},
                cv=cv,
            )
            return fit, cv, "open loop"

        def held_out(self, fit: Any, keys: Any) -> tuple[Any, str]:
            return fit.cv, "open loop"

    gate = _four_fold_gate(Scripted, set(names))
    base = gate.fitted([], ROBOT, None, None)
    model = [("effect", "skid_track"), ("effect", "wheelbase"), ("effect", "wheel_diameter_ratio")]
    (_, cv, _), kept, removed = gate.eliminate(model, [], base)
    assert model == [("effect", "wheelbase"), ("effect", "wheel_diameter_ratio")]
    assert [s.name for s in kept] == ["wheelbase", "wheel_diameter_ratio"]
    assert all(s.kept and s.rule == "lower" for s in kept)
    assert [s.name for s in removed] == ["skid_track"] and not removed[0].kept
    assert 1e3 * math.sqrt(float(np.mean(cv))) == pytest.approx(4.8)


def test_effects_are_judged_again_beside_the_kept_terms_under_their_own_rules() -> None:
    """Once the gate keeps a term (Y, a yaw-rate term), the catalogue effects it kept before
    (W, the wheelbase; K, a speed-dependent skid track, both named by the rounds) are eliminated
    again beside it, each under the rule it had among the effects: K, which predicts nothing
    more beside Y (1.82 mm with it, 1.80 without), goes; W, which still lowers the error, stays
    — though beside the term the robot's variance inflation counts the term's parameter and
    reads W as unidentified (10⁹), it keeps its rule ``lower``. Where both still lower the
    error nothing changes (None: the catalogue stage's steps stand)."""
    names = {"wheelbase": "W", "skid_speed": "K", "yaw_rate": "Y"}
    table = {"": 12.0, "Y": 1.81, "WY": 1.80, "KY": 1.83, "WKY": 1.82}  # held out [mm]
    e_b = f"wheelbase.{EFFECTS['wheelbase'].parameters[0].name}"

    class Scripted(gate_module._Elimination):
        def fitted(self, members: Any, begin: RobotSpec, nuisances: Any, base: Any) -> Any:
            key = "".join(sorted((names[n] for _, n in members), key="WKY".index))
            mm = table[key]
            cv = np.full(4, (mm / 1e3) ** 2)
            fit = SimpleNamespace(
                spec=ROBOT,
                nuisances={},
                inflation={},
                robot_inflation={e_b: 1e9} if "Y" in key else {},
                cv=cv,
                error=float(cv[0]),
            )
            return fit, cv, "open loop"

        def held_out(self, fit: Any, keys: Any) -> tuple[Any, str]:
            return fit.cv, "open loop"

    judged = [
        gate_module.GateStep("effect", "wheelbase", True, 12.0, 11.49, -5.0, 1.0, "lower"),
        gate_module.GateStep("effect", "skid_speed", True, 11.6, 11.49, -2.0, 1.0, "lower"),
    ]
    gate = _four_fold_gate(Scripted, {"wheelbase", "skid_speed"})
    effects = [("effect", "wheelbase"), ("effect", "skid_speed")]
    terms = [("term", "yaw_rate")]
    as_given = gate.fitted([], ROBOT, None, None)
    current = gate.fitted([*effects, *terms], ROBOT, None, None)
    done = gate_module._beside_terms(gate, effects, terms, current, as_given, judged)
    assert done is not None
    (_, cv, _), kept, removed = done
    assert effects == [("effect", "wheelbase")]
    assert 1e3 * math.sqrt(float(np.mean(cv))) == pytest.approx(1.80)
    assert [(s.name, s.kept, s.rule) for s in kept] == [
        ("wheelbase", True, f"lower {gate_module.BESIDE_TERMS}")
    ]
    assert [(s.name, s.kept, s.rule) for s in removed] == [
        ("skid_speed", False, f"lower {gate_module.BESIDE_TERMS}")
    ]
    assert kept[0].inflation == 1e9  # reported as measured, judged as in the catalogue stage
    # Both still needed beside the term: nothing moves.
    table["WKY"] = 1.79
    effects = [("effect", "wheelbase"), ("effect", "skid_speed")]
    current = gate.fitted([*effects, *terms], ROBOT, None, None)
    assert gate_module._beside_terms(gate, effects, terms, current, as_given, judged) is None
    assert effects == [("effect", "wheelbase"), ("effect", "skid_speed")]


def test_terms_are_judged_again_once_an_effect_leaves_beside_them() -> None:
    """``"catalogue first"`` on scripted fold errors: the rounds named the wheelbase (W) and a
    speed-dependent skid track (K), both kept among the effects; beside them the gate keeps a
    yaw-rate term (Y) and refuses a speed term (Z, 1.83 mm with it against 1.82 without). K then
    leaves beside Y (1.81 mm without it against 1.82). Judged again beside W alone, Z now earns
    its place (1.70 mm with both terms against 1.81 with Y alone), and W, judged beside the two
    terms (1.85 mm without it), stays: the rows describe the final model W, Y, Z. Where no term
    stands beside the effects left — after the first removal, or after a second one (D, a
    distance scale, leaving beside Y and Z) — nothing describes the error of those that left,
    and the model before the first check beside the terms stands, with its rows."""
    names = {"wheelbase": "W", "skid_speed": "K", "distance_scale": "D"}
    names.update({"yaw_rate": "Y", "left_speed": "Z"})
    table: dict[str, Any] = {}

    class Scripted(gate_module._Elimination):
        def fitted(self, members: Any, begin: RobotSpec, nuisances: Any, base: Any) -> Any:
            key = "".join(sorted((names[n] for _, n in members), key="WKDYZ".index))
            cv = (np.broadcast_to(np.asarray(table[key], dtype=float), (4,)) / 1e3) ** 2
            inflation = {f"{gate_module.DISCOVERED}.{t}": 1.0 for t in ("yaw_rate", "left_speed")}
            fit = SimpleNamespace(spec=ROBOT, nuisances={}, inflation=inflation, cv=cv)
            fit.robot_inflation, fit.error = {}, cv[0]
            return fit, cv, "open loop"

        def held_out(self, fit: Any, keys: Any) -> tuple[Any, str]:
            return fit.cv, "open loop"

    def staged(named: str) -> tuple[float, list[Any], list[Any]]:
        effects = [("effect", n) for n in names if names[n] in named]
        gate = _four_fold_gate(Scripted, {n for _, n in effects})
        as_given = gate.fitted([], ROBOT, None, None)
        terms = [("term", "yaw_rate"), ("term", "left_speed")]
        (_, cv, _), steps, model = gate_module._catalogue_first(gate, effects, terms, as_given)
        mm = 1e3 * math.sqrt(float(np.mean(cv)))
        rows = [
            (s.name, s.kept, s.rule, round(s.before_mm, 2), round(s.after_mm, 2)) for s in steps
        ]
        return mm, rows, [n for _, n in model]

    table.update({"": 12.0, "W": 6.0, "K": 8.0, "WK": 5.0})  # the catalogue stage [mm held out]
    table.update({"WKY": 1.82, "WKZ": 4.0, "WKYZ": 1.83})  # the terms beside W and K
    table.update({"Y": 1.90, "KY": 1.95, "WY": 1.81})  # the effects beside Y
    table.update({"WZ": 1.90, "WYZ": 1.70, "YZ": 1.85})  # the terms again beside W; W beside them
    mm, rows, model = staged("WK")
    beside = gate_module.BESIDE_TERMS
    assert model == ["wheelbase", "yaw_rate", "left_speed"]
    assert mm == pytest.approx(1.70)
    assert rows == [
        ("wheelbase", True, f"lower {beside}", 1.85, 1.70),
        ("yaw_rate", True, "one standard error", 1.90, 1.70),
        ("left_speed", True, "one standard error", 1.81, 1.70),
        ("skid_speed", False, f"lower {beside}", 1.81, 1.82),
    ]
    # Y lowers the folds' error beside W, but by less than a standard error (one fold of four
    # is worse), though more than K adds beside it (7.40 mm against 7.5 with K); Z lowers
    # nothing beside W. Judged again beside W alone, neither term stands.
    table.clear()
    table.update({"": 12.0, "W": 8.0, "K": 9.0, "WK": 7.9})
    table.update({"WKY": 7.5, "WKZ": 7.95, "WKYZ": 7.6})
    table.update({"Y": 9.0, "KY": 9.0, "WY": [1.0, 1.0, 1.0, 14.7]})
    table.update({"WZ": 8.05, "WYZ": 8.1, "YZ": 9.0})
    first_pass = [
        ("wheelbase", True, "lower", 9.0, 7.9),
        ("skid_speed", True, "lower", 8.0, 7.9),
        ("yaw_rate", True, "one standard error", 7.9, 7.5),
        ("left_speed", False, "one standard error", 7.5, 7.6),
    ]
    mm, rows, model = staged("WK")
    assert model == ["wheelbase", "skid_speed", "yaw_rate"]
    assert mm == pytest.approx(7.5)
    assert rows == first_pass
    # A second pass: K leaves beside Y; beside W and D both terms stand (1.70 mm); D then
    # leaves beside them (1.69 mm without it); beside W alone Y goes (1.68 mm without it) and
    # Z with it (W alone 1.67 mm): the model before the first check stands.
    table.clear()
    table.update({"": 12.0, "KD": 7.0, "WD": 6.0, "WK": 6.5, "WKD": 5.0})
    table.update({"WKDY": 1.82, "WKDZ": 4.0, "WKDYZ": 1.83})
    table.update({"Y": 9.0, "KDY": 1.95, "WDY": 1.81, "WKY": 1.90, "DY": 1.95, "WY": 1.85})
    table.update({"WDZ": 1.90, "WDYZ": 1.70, "YZ": 9.0, "DYZ": 1.95, "WYZ": 1.69})
    table.update({"WZ": 1.68, "W": 1.67})
    mm, rows, model = staged("WKD")
    assert model == ["wheelbase", "skid_speed", "distance_scale", "yaw_rate"]
    assert mm == pytest.approx(1.82)
    assert rows == [
        ("wheelbase", True, "lower", 7.0, 5.0),
        ("skid_speed", True, "lower", 6.0, 5.0),
        ("distance_scale", True, "lower", 6.5, 5.0),
        ("yaw_rate", True, "one standard error", 5.0, 1.82),
        ("left_speed", False, "one standard error", 1.82, 1.83),
    ]
    # Every effect leaves: K alone was kept among the effects and leaves beside Y (1.80 mm
    # without it against 1.82); judged again on the model as given, both terms stand.
    table.clear()
    table.update({"": 12.0, "K": 8.0, "KY": 1.82, "KZ": 4.0, "KYZ": 1.83})
    table.update({"Y": 1.80, "Z": 5.0, "YZ": 1.70})
    mm, rows, model = staged("K")
    assert model == ["yaw_rate", "left_speed"]
    assert mm == pytest.approx(1.70)
    assert rows == [
        ("yaw_rate", True, "one standard error", 5.0, 1.70),
        ("left_speed", True, "one standard error", 1.80, 1.70),
        ("skid_speed", False, f"lower {beside}", 1.80, 1.82),
    ]


def test_the_effects_alone_are_fitted_from_two_starts() -> None:
    """Where the terms are judged again once an effect has left beside them, the model of the
    effects left is fitted from the larger model (the terms set back, its nuisances) and afresh
    from the rounds' values (the gate's start): the fit with the smaller error is the terms'
    base, whichever start gave it (a fit from a larger model's values can stop in another
    valley); without effects it is the model as given."""
    errors: dict[bool, float] = {}

    class Scripted(gate_module._Elimination):
        def fitted(self, members: Any, begin: RobotSpec, nuisances: Any, base: Any) -> Any:
            afresh = nuisances is self.start
            cv = np.full(4, errors[afresh] * 1e-6)
            fit = SimpleNamespace(spec=ROBOT, nuisances={}, cv=cv, error=float(cv[0]))
            return fit, cv, "afresh" if afresh else "nested"

    gate = _four_fold_gate(Scripted, {"wheelbase"})
    as_given: Any = (SimpleNamespace(spec=ROBOT, error=1.0), np.ones(4), "as given")
    larger: Any = (SimpleNamespace(spec=ROBOT, nuisances={}, error=0.0), np.zeros(4), "larger")
    effects = [("effect", "wheelbase")]
    terms = [("term", "yaw_rate")]
    for nested, afresh, chosen in [
        (2.0, 1.0, "afresh"),
        (1.0, 2.0, "nested"),
        (1.0, 1.0, "nested"),
    ]:
        errors.update({False: nested, True: afresh})
        assert gate_module._effects_alone(gate, effects, larger, terms, as_given)[2] == chosen
    assert gate_module._effects_alone(gate, [], larger, terms, as_given) is as_given


def test_a_failing_base_beside_its_extension_is_held_and_says_so() -> None:
    """A wheelbase that fails its rule while the skid track that extends it stays is kept,
    and its rule says which effect held it; terms and effects nothing extends are as they
    were."""
    step = gate_module.GateStep("effect", "wheelbase", False, 5.0, 6.0, 11.0, 2.0, "lower")
    members = [("effect", "skid_track"), ("effect", "wheelbase")]
    held = gate_module._held(step, members)
    assert held.kept and held.rule == "held by skid_track"
    assert gate_module._held(step, [("effect", "wheelbase")]) == step
    assert gate_module._extenders(("term", "wheelbase"), members) == []
    assert gate_module._extenders(("effect", "skid_track"), members) == []
    assert report_rule(held) == "held by skid_track"


def test_a_candidate_fitted_back_to_nothing_beside_its_partners_is_at_nothing() -> None:
    """A skid track whose excess came back at its bound (1.2e-12: the bounded least squares
    starts strictly inside) is absent, whatever its half-point: the rounds then do not call it
    significant, since its likelihood ratio is its partner's (E_b's refit; one README
    diagnosis had ticked it)."""
    skid = EFFECTS["skid_track"]
    assert at_nothing(skid, {"excess": 1.242e-12, "lambda_half": 2.0})
    assert at_nothing(skid, {"excess": 0.0, "lambda_half": 40.0})
    assert not at_nothing(skid, {"excess": 1e-4, "lambda_half": 2.0})
    assert not at_nothing(EFFECTS["wheelbase"], {"e_b": 1.0 + 1e-6})
    assert at_nothing(EFFECTS["wheelbase"], {"e_b": 1.0 + 1e-12})


def test_the_report_says_why_a_held_base_was_kept() -> None:
    """A wheelbase kept only because the skid track extending it stayed: the report's
    decisions say so, and do not claim it lowered the error (one story)."""
    from odomgym.diagnose.report import _decision_lines

    held = gate_module.GateStep(
        "effect", "wheelbase", True, 5.0, 6.0, 11.0, 2.0, "held by skid_track"
    )
    passed = gate_module.GateStep("effect", "skid_track", True, 9.0, 5.0, -20.0, 2.0, "lower")
    d = SimpleNamespace(
        final_test={}, gate=[passed, held], named_effects=["skid_track"], noise_checks={},
        noise_model=[], refused_terms=[],
    )  # fmt: skip
    lines = "\n".join(_decision_lines(d))  # type: ignore[arg-type]
    wheelbase = next(line for line in lines.splitlines() if "**wheelbase**" in line)
    assert "skid_track extends it" in wheelbase and "did not lower" in wheelbase
    assert "it lowered the error" not in wheelbase
    assert "**skid_track** (effect): it lowered the error" in lines


def test_the_report_says_an_exchanged_effect_gave_way_to_the_terms_it_blocked() -> None:
    """A skid track exchanged for the terms it blocked lowered the error on its own: the
    report's decisions say that the model without it, with those terms, predicted better, not
    that it failed to lower the error (the row of bench_discover's seed 7802)."""
    from odomgym.diagnose.report import _decision_lines

    for rule in (f"{gate_module.BLOCKING} wheelbase", "not identifiable beside wheelbase"):
        exchanged = gate_module.GateStep(
            "effect", "skid_track", False, 21.22, 30.90, 343.0, 316.0, rule
        )
        d = SimpleNamespace(
            final_test={}, gate=[exchanged], named_effects=[], noise_checks={},
            noise_model=[], refused_terms=[],
        )  # fmt: skip
        line = next(x for x in _decision_lines(d) if "**skid_track**" in x)  # type: ignore[arg-type]
        assert "the model without it, with the terms it had blocked" in line, line
        assert "did not lower" not in line and rule in line


def test_an_effect_is_judged_among_the_robot_effects_and_a_term_with_the_nuisances() -> None:
    """The identification rule reads a catalogue effect's variance inflation among the robot's
    parameters alone (a tracked-point offset that is exactly a measurement nuisance is a
    confound the report states, not an unidentified robot effect), and a term's with the
    sessions' nuisances (a constant crab angle is the frames' yaw)."""
    fit: Any = SimpleNamespace(
        inflation={"skid_track.excess": 1e12, "gt_sensor_offset.dx": math.inf},
        robot_inflation={
            "skid_track.excess": 4e7,
            "skid_track.lambda_half": 2e5,
            "wheelbase.e_b": 4.2e7,
            "gt_sensor_offset.dx": 3.0,
            "gt_sensor_offset.dy": 2.0,
        },
    )
    fit.inflation["discovered.yaw_rate"] = 12.0
    assert gate_module._inflation(("effect", "skid_track"), fit) == 4e7
    assert gate_module._inflation(("effect", "wheelbase"), fit) == 4.2e7
    assert gate_module._inflation(("effect", "gt_sensor_offset"), fit) == 3.0
    assert math.isnan(gate_module._inflation(("effect", "backlash"), fit))  # not in the fit
    assert gate_module._inflation(("term", "yaw_rate"), fit) == 12.0


def test_an_unidentified_effect_must_beat_one_standard_error_by_a_real_size() -> None:
    """A named effect passes if the folds' error falls; one the fit cannot tell from the other
    robot effects must lower it by more than a standard error and by at least 1 % of it,
    whatever the rounds named, and the report says why (a turn skid and a speed-dependent
    track, one law of |v·ω| split in two, had both been kept on a June OptiOdom fold: the
    split removed 0.009 % of the folds' error, by 1.85 standard errors)."""

    gate = _four_fold_gate(gate_module._Elimination, {"skid_speed", "turn_skid"})
    cv = np.array([1.00, 1.02, 0.97, 1.01]) * 1e-6
    smaller = np.array([1.01, 1.01, 0.99, 1.00]) * 1e-6  # with it: 0.5 % lower, within noise
    identified: Any = SimpleNamespace(inflation={}, robot_inflation={"skid_speed.gain": 40.0})
    step = gate.judge(("effect", "skid_speed"), (identified, cv, "open loop"), smaller)
    assert step.kept and step.rule == "lower"
    split: Any = SimpleNamespace(inflation={}, robot_inflation={"skid_speed.gain": math.inf})
    step = gate.judge(("effect", "skid_speed"), (split, cv, "open loop"), smaller)
    assert not step.kept and step.rule == gate_module.UNIDENTIFIED
    assert report_rule(step) == f"{gate_module.UNIDENTIFIED} (VIF ∞)"
    # Lower in every fold, by 0.1 % of the error and six standard errors: an identified
    # effect the rounds did not name passes the one-standard-error rule; an unidentified one
    # removes too small a share.
    gate = _four_fold_gate(gate_module._Elimination, set())
    base = np.array([1.00, 1.02, 0.98, 1.00]) * 1e-6
    tiny = base - np.array([1.0, 1.1, 0.9, 1.0]) * 1e-9
    step = gate.judge(("effect", "skid_speed"), (identified, tiny, "open loop"), base)
    assert step.kept and step.rule == "one standard error"
    assert -step.difference > 5 * step.stderr
    step = gate.judge(("effect", "skid_speed"), (split, tiny, "open loop"), base)
    assert not step.kept and step.rule == gate_module.UNIDENTIFIED
    # By a fifth of the error (a skid track at 5 × its detection limit beside E_b): kept.
    fifth = base * np.array([0.78, 0.82, 0.80, 0.79])
    step = gate.judge(("effect", "skid_speed"), (split, fifth, "open loop"), base)
    assert step.kept and step.rule == gate_module.UNIDENTIFIED


def test_an_extension_is_exchanged_only_for_a_term_it_blocked(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Without a term refused as not identifiable, a kept skid track stays whatever its
    inflation (it predicts better and nothing competes; the report's confounds say its values
    are not determined): the gate is not run again. With one, the gate runs again without it,
    and the other model is kept if it predicts the folds better — by anything for a skid track
    the fit cannot identify, by more than a standard error of the folds' differences for one
    it can (the rule a term passes), and only where that model keeps a term it had blocked.
    The exchange itself is tested end to end on the alien yaw-rate scrub and speed shrink
    (tests/test_discover.py); the effects' second judgement beside the kept terms has its own
    test above."""

    def step(kind: str, name: str, kept: bool, rule: str, inflation: float) -> Any:
        return gate_module.GateStep(
            kind, name, kept, 3.0, 2.0, -5.0, 1.0, rule, "open loop", inflation
        )

    class NoGate:
        folds = ((0,), (1,), (2,))

        def eliminate(self, *args: object) -> None:
            raise AssertionError("the gate must not run again")

    kept = (None, np.full(3, 4e-6), "open loop")
    steps = [
        step("effect", "skid_track", True, "lower", 4e7),
        step("effect", "wheelbase", True, "held by skid_track", math.nan),
        step("term", "yaw_rate", False, "one standard error", 3.0),
    ]
    effects = [("effect", "skid_track"), ("effect", "wheelbase")]
    terms = [("term", "yaw_rate")]
    args: Any = (NoGate(), kept, steps, effects, terms, kept)
    assert gate_module._exchange(*args) is None

    class Again:
        """The gate without the skid track: the wheelbase kept, the term kept (``keeps``) or
        refused, and the folds' errors ``cv`` [m²]."""

        folds = ((0,), (1,), (2,))

        def __init__(self, cv: list[float], keeps: bool = True) -> None:
            self.cv = np.array(cv) * 1e-6
            self.keeps = keeps

        def eliminate(self, model: list[Any], fixed: list[Any], base: Any) -> Any:
            scored = (None, self.cv, "open loop")
            if not fixed:
                return scored, [step("effect", "wheelbase", True, "lower", 1.0)], []
            if self.keeps:
                return scored, [step("term", "yaw_rate", True, "one standard error", 3.0)], []
            model.clear()
            return scored, [], [step("term", "yaw_rate", False, "one standard error", 3.0)]

    monkeypatch.setattr(gate_module, "_beside_terms", lambda *args: None)

    steps[2] = step("term", "yaw_rate", False, "not identifiable", math.inf)
    # Better in two folds of three, by less than its standard error (0.17 ± 0.60 mm²).
    close = Again([3.0, 5.0, 3.5])
    better = Again([3.0, 3.1, 2.9])  # better in every fold: 1.0 ± 0.06 mm²
    unblocked = Again([3.0, 3.1, 2.9], keeps=False)  # as much better, the term still out
    unidentified_rule = gate_module.UNIDENTIFIED
    beside = f"lower {gate_module.BESIDE_TERMS}"
    for rule, inflation, gate, exchanged in [
        (unidentified_rule, 4e7, close, True),  # unidentified: any better model
        ("lower", 50.0, close, False),  # identified: better by a standard error
        ("lower", 50.0, better, True),
        ("lower", 50.0, unblocked, False),  # and keeping a term it blocked
        # identified among the effects, inflated only beside the kept terms (whose parameters
        # count there): still identified, as its rule says
        (beside, 4e7, close, False),
        (beside, 4e7, better, True),
        # unidentified among the effects, judged again beside the terms (less inflated there):
        # still unidentified, as its rule says
        (f"{unidentified_rule} {gate_module.BESIDE_TERMS}", 50.0, close, True),
    ]:
        steps[0] = step("effect", "skid_track", True, rule, inflation)
        args = (gate, kept, steps, effects, terms, kept)
        done = gate_module._exchange(*args)
        assert (done is not None) == exchanged, (rule, gate.cv)
        if done is None:
            continue
        refused = done[1][-1]
        assert refused.name == "skid_track" and not refused.kept
        unidentified = rule.startswith(unidentified_rule)
        start = "not identifiable beside" if unidentified else gate_module.BLOCKING
        assert refused.rule == f"{start} wheelbase"
        assert done[2][0] == ("effect", "wheelbase")


def test_the_size_half_of_the_bump_check_needs_no_replay() -> None:
    """``bump_size_reasons`` is the magnitude half of ``check_bumps``, on values alone (the
    rounds use it to stop refitting a bump field a floor cannot make): at the bounds nothing is
    said; a jump losing more than a 20 mm obstacle's extra rotation (rigid wheel over a
    cylinder) and a rate above one per metre are each named, with ``check_bumps``' words."""
    radius = 0.5 * NOMINAL_ROBOT.wheel_diameter
    largest = bump_extra_rotation(radius, 0.02)
    at_bound = {"rate": 1.0, "heading_jump": largest / NOMINAL_ROBOT.true_wheelbase}
    assert bump_size_reasons(NOMINAL_ROBOT, at_bound, max_obstacle=0.02, max_rate=1.0) == []
    beyond = {"rate": 3.5, "heading_jump": 1.01 * largest / NOMINAL_ROBOT.true_wheelbase}
    reasons = bump_size_reasons(NOMINAL_ROBOT, beyond, max_obstacle=0.02, max_rate=1.0)
    assert len(reasons) == 2
    assert "obstacle" in reasons[0] and "3.5 bumps per metre" in reasons[1]
    assert bump_size_reasons(NOMINAL_ROBOT, {}, max_obstacle=0.02, max_rate=1.0) == []


def test_a_round_asks_for_the_bump_signature_only_of_effects_not_refused_for_size(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A round does not fit a noise effect refused for its size in an earlier round (its
    reason stays that one) nor one whose signature the logs lack; the signature, a replay of
    every fit run, is computed only when some noise effect is left to ask about. The reasons
    come in the candidates' order. A noise stage leaves out what it is told was refused for
    its size (:func:`test_a_noise_stage_refits_no_bump_field_the_model_carries_beyond_a_floors_size`
    says what), and asks for no signature."""
    from odomgym.diagnose import rounds

    asked: list[list[str]] = []

    def check(ctx: object, spec: RobotSpec, values: object) -> SimpleNamespace:
        asked.append([])
        return SimpleNamespace(signature=False, reason="no heavy-tailed heading jumps")

    monkeypatch.setattr(rounds, "_bump_check", check)
    ctx: Any = SimpleNamespace()
    refused = {"floor_bumps": "3.5 bumps per metre"}
    wheelbase, bumps, rough = (EFFECTS[n] for n in ("wheelbase", "floor_bumps", "floor_roughness"))
    out = rounds._not_fitted(ctx, NOMINAL_ROBOT, [wheelbase, bumps, rough], "mean", refused)
    assert list(out.items()) == [
        ("floor_bumps", "3.5 bumps per metre"),
        ("floor_roughness", "no heavy-tailed heading jumps"),
    ]
    assert len(asked) == 1
    out = rounds._not_fitted(ctx, NOMINAL_ROBOT, [wheelbase, bumps], "mean", refused)
    assert out == {"floor_bumps": "3.5 bumps per metre"}
    assert len(asked) == 1  # every noise effect refused for its size: no replay
    out = rounds._not_fitted(ctx, NOMINAL_ROBOT, [wheelbase, bumps, rough], "noise", refused)
    assert out == {"floor_bumps": "3.5 bumps per metre"}
    assert rounds._not_fitted(ctx, NOMINAL_ROBOT, [bumps, rough], "noise", {}) == {}
    assert len(asked) == 1


def test_a_noise_stage_refits_no_bump_field_the_model_carries_beyond_a_floors_size() -> None:
    """What each stage of the next round leaves out for its size: a mean stage, a bump field
    whose latest fit among the systematic candidates was beyond a floor's bounds (whatever the
    noise stage fitted since); a noise stage, one the model carries at values beyond them (the
    values the final model judges), whatever a losing refit gave. A noise stage still fits one
    the model does not carry, so that it may be named as the rounds' heavy-tailed noise
    model."""
    from odomgym.diagnose import rounds
    from odomgym.diagnose.results import Candidate, Round

    largest = bump_extra_rotation(0.5 * float(NOMINAL_ROBOT.wheel_diameter), 0.02)
    jump = 0.5 * largest / NOMINAL_ROBOT.true_wheelbase
    bumps = EFFECTS["floor_bumps"]

    def fitted(number: int, stage: str, rate: float) -> Round:
        values = {"rate": rate, "heading_jump": jump}
        c = Candidate(number, stage, "floor_bumps", values, {}, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, False)
        return Round(number, "none", None, [], None, [c], 1.0)

    def carrying(rate: float) -> Any:
        spec = bumps.write(NOMINAL_ROBOT, {"rate": rate, "heading_jump": jump})
        return SimpleNamespace(spec=spec)

    cfg = SimpleNamespace(max_obstacle=0.02, max_bump_rate=1.0)
    ctx: Any = SimpleNamespace(config=cfg)
    state: Any = SimpleNamespace(model=SimpleNamespace(spec=NOMINAL_ROBOT), named=[], rounds=[])

    def refused(stage: str) -> dict[str, str]:
        state.candidates = [c for r in state.rounds for c in r.candidates]
        return rounds._refused_for_size(ctx, state, stage)

    state.rounds = [fitted(1, "mean", 3.5)]
    assert "fitted in round 1" in refused("mean")["floor_bumps"]
    assert "3.5 bumps per metre" in refused("mean")["floor_bumps"]
    assert refused("noise") == {}  # the model does not carry them: the noise stage fits them
    state.rounds.append(fitted(6, "noise", 3.9))  # round 6's noise stage names them
    state.named, state.model = ["floor_bumps"], carrying(3.9)
    assert "carried by the model" in refused("noise")["floor_bumps"]
    assert "3.9 bumps per metre" in refused("noise")["floor_bumps"]
    assert "3.5 bumps per metre" in refused("mean")["floor_bumps"]  # the mean stage's own fit
    # Carried at a floor's size, a losing refit beyond it does not stop the noise stage.
    state.model = carrying(0.4)
    state.rounds.append(fitted(7, "noise", 3.9))
    assert refused("noise") == {}
    state.rounds = [fitted(1, "mean", 0.4), fitted(6, "noise", 3.9)]
    assert refused("mean") == {}


# ------------------------------------------------------------------ bounded fold steps
def _box_minimum(a: np.ndarray, b: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """½·δᵀAδ + bᵀδ minimised over the box by brute force: every coordinate free, at its low
    or at its high bound (3ᵏ active sets), the free ones solved exactly; the feasible best."""
    best, best_value = np.zeros(len(b)), math.inf
    for pattern in itertools.product((0, 1, 2), repeat=len(b)):
        delta = np.where(np.array(pattern) == 1, low, np.where(np.array(pattern) == 2, high, 0.0))
        free = [k for k, p in enumerate(pattern) if p == 0]
        if free:
            fixed = [k for k, p in enumerate(pattern) if p != 0]
            rhs = -(b[free] + a[np.ix_(free, fixed)] @ delta[fixed])
            delta[free] = np.linalg.solve(a[np.ix_(free, free)], rhs)
        if np.all(delta >= low - 1e-12) and np.all(delta <= high + 1e-12):
            value = 0.5 * delta @ a @ delta + b @ delta
            if value < best_value:
                best, best_value = delta, value
    return best


def test_a_bounded_fold_step_is_the_minimum_inside_the_box() -> None:
    """The step of a bounded refit is the model's minimum over the box — not the unbounded
    step clipped, which differs as soon as the parameters are correlated — and the plain
    Gauss–Newton step, to the bit, when the box does not bind."""
    rng = np.random.default_rng(7)
    clipped_differs = 0
    for _ in range(40):
        root = rng.normal(size=(6, 3))
        a = root.T @ root
        b = rng.normal(size=3) * 3.0
        low, high = -rng.uniform(0.0, 1.0, 3), rng.uniform(0.0, 1.0, 3)
        step = bounded_gauss_newton_step(a, b, low, high)
        assert step == pytest.approx(_box_minimum(a, b, low, high), rel=1e-6, abs=1e-8)
        clipped = np.clip(gauss_newton_step(a, b), low, high)
        clipped_differs += not np.allclose(step, clipped, atol=1e-6)
        # Inside the box the unbounded step is returned bit for bit.
        wide = bounded_gauss_newton_step(a, b, low - 100.0, high + 100.0)
        assert np.array_equal(wide, gauss_newton_step(a, b))
    assert clipped_differs > 10
    # A direction the normal equations do not determine stays where the full fit put it.
    assert bounded_gauss_newton_step(
        np.diag([2.0, 0.0]), np.array([-1.0, 5.0]), np.array([-9.0, -9.0]), np.array([9.0, 9.0])
    ) == pytest.approx([0.5, 0.0], abs=1e-8)


def test_a_fold_without_the_runs_that_carry_a_parameter_keeps_it_within_its_bounds() -> None:
    """The likelihood's cross-validation refits each fold by one Gauss–Newton step inside the
    parameters' bounds. ``skid_speed``'s gain cannot go below 0 (a track that widens with
    speed is another effect); a fold that leaves out the one run carrying it has almost no
    curvature in the gain, and the unbounded step went to −0.37 s²/m: the held-out run was
    scored −1.7 × 10⁶ nats for a value the fit can never take. Bounded, it stays at 0 and the
    held-out run scores what the full fit does."""
    effect = EFFECTS["skid_speed"]
    spec = effect.write(RobotSpec(0.084, 0.2, 2796.8), {"gain": 0.0})
    # Run 0 carries the gain; runs 1 and 2 barely do, and their residuals pull it down.
    jacobian = [np.array([[40.0], [30.0]]), np.array([[0.01], [0.02]]), np.array([[0.02], [0.01]])]
    whitened = [np.array([0.0, 0.0]), np.array([1.0, 0.5]), np.array([0.4, 0.9])]
    fit = SimpleNamespace(
        spec=spec,
        loglik=np.array([-1.0, -2.0, -3.0]),
        jacobian=jacobian,
        whitened=whitened,
    )
    out = cross_validate([0, 1, 2], fit, effect, [[0], [1, 2]])  # type: ignore[arg-type]
    assert out[0] == fit.loglik[0]  # the training runs want a negative gain: it stays at 0
    # Runs 1 and 2 held out: run 0's residual is 0 at the fit, so the step is 0 too.
    assert out[1:] == pytest.approx(fit.loglik[1:])

"""The Python API's answers to what a researcher passes in a notebook: effects given to a
robot's constructor, NumPy scalars, specs passed where names are expected, options as strings.
Each case is one a new user's review hit (a silent wrong simulation, a false message, or a
traceback from deep inside), and each test fails on the code before the fix."""

from __future__ import annotations

import os
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import odomgym
from odomgym.errors import SpecError
from odomgym.noise import covariance
from odomgym.odometry.calibration import Calibration
from odomgym.robot import PRESETS, RobotSpec, load_robot

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

BASE = {"wheel_diameter": 0.15, "wheelbase": 0.34, "ticks_per_rev": 2048}


@pytest.mark.parametrize(
    ("effects", "field", "message"),
    [
        ({"backlash": {"angle": float("nan")}}, "effects.backlash.angle", "must be finite"),
        ({"wheel_toe": {"angle": 3.0}}, "effects.wheel_toe.angle", r"\[-0.2, 0.2\] rad"),
        ({"backlash": {"angle": -0.3}}, "effects.backlash.angle", r"\[0, 0.5\] rad"),
        ({"backlsh": {"angle": 0.1}}, "effects.backlsh", "unknown effect 'backlsh'"),
        ({"backlash": {"angel": 0.1}}, "effects.backlash.angel", "unknown parameter"),
        ([1], "effects", r"must be a mapping \{name: \{parameter: value\}\}"),
        ("backlash", "effects", "got str"),
        ({"backlash": 3}, "effects", "must be a mapping"),
    ],
)
def test_the_constructor_checks_the_effects_it_is_given(
    effects: object, field: str, message: str
) -> None:
    """A backlash of NaN stopped the World's robot without a word, a toe of 3 rad drove it
    backwards, a misspelt name was ignored: each is now refused, naming the field."""
    with pytest.raises(SpecError, match=message) as caught:
        RobotSpec(**BASE, effects=effects)  # type: ignore[arg-type]
    assert caught.value.field == field


def test_a_geometric_effect_given_to_the_constructor_is_the_robot_it_saves(
    tmp_path: Path,
) -> None:
    """``effects={"wheel_diameter_ratio": {"e_d": 1.05}}`` was stored and not applied: the
    robot drove with E_d = 1, and the file it saved loaded back as E_d = 1.05, another robot.
    It is now written into the true diameters, as a robot file's table is."""
    robot = RobotSpec(**BASE, effects={"wheel_diameter_ratio": {"e_d": 1.05}})
    assert robot.e_d == pytest.approx(1.05) and robot.effects == ()
    robot.save(tmp_path / "r.toml")
    assert load_robot(tmp_path / "r.toml") == robot
    kept = RobotSpec(**BASE, effects={"backlash": {"angle": 0.01}})
    assert kept.effect_dict() == {"backlash": {"angle": 0.01}}
    assert RobotSpec(**BASE, effects=kept.effects) == kept  # the stored form, as replace() passes
    with pytest.raises(SpecError, match="lives in the true diameters") as caught:
        RobotSpec(**BASE, effects=(("wheelbase", (("e_b", 1.1),)),))
    assert caught.value.field == "effects.wheelbase"


def test_numpy_scalars_are_numbers_and_are_stored_as_floats(tmp_path: Path) -> None:
    """Values computed with NumPy were refused as "must be a number, got float32"; now taken
    and stored as Python numbers (so the spec saves as TOML). NumPy's bool is still no number."""
    robot = RobotSpec(
        wheel_diameter=np.float32(0.15), wheelbase=np.float64(0.34), ticks_per_rev=np.int64(2048)
    )
    assert type(robot.wheel_diameter) is float and type(robot.ticks_per_rev) is int
    assert robot.chassis_width == pytest.approx(1.3 * 0.34)  # the derived defaults too
    robot.save(tmp_path / "r.toml")
    assert load_robot(tmp_path / "r.toml") == robot
    calibration = Calibration(c_left=np.float32(1.0), wheelbase_scale=np.float64(1.01))
    assert type(calibration.c_left) is float and calibration.wheelbase_scale == 1.01
    with pytest.raises(SpecError, match="wheel_diameter must be a number, got bool"):
        RobotSpec(wheel_diameter=np.bool_(True), wheelbase=0.3, ticks_per_rev=100)


def test_a_spec_is_taken_where_a_name_is_and_anything_else_is_refused_in_one_line() -> None:
    """``load_robot(spec)`` made the spec's repr a file name ("File name too long");
    ``gym.make(..., robot=5)`` ended in ``TypeError: expected str, bytes or os.PathLike``."""
    labmate = PRESETS["labmate"]
    assert load_robot(labmate) is labmate
    refusal = r"robot must be a preset name, a \.toml file or a RobotSpec"
    with pytest.raises(SpecError, match=refusal):
        load_robot(5)  # type: ignore[arg-type]
    with pytest.raises(SpecError, match="got int 5"):
        gym.make("UMBmarkSquare-v0", robot=5)
    with pytest.raises(SpecError, match="floor must be a preset name"):
        gym.make("UMBmarkSquare-v0", floor=0.5)
    with pytest.raises(SpecError, match="calibration must be a Calibration"):
        gym.make("UMBmarkSquare-v0", calibration=1.0)
    # The CLAPPER envs said "unknown floor '123'" (the number made a name).
    with pytest.raises(SpecError, match=r"floor must be a preset name.* got int 123"):
        gym.make("ClapperStraight-v0", floor=123)
    with pytest.raises(SpecError, match=r"vehicle must be a preset name.* got float 1\.5"):
        gym.make("ClapperRectangle-v0", vehicle=1.5)


def test_options_are_checked_by_type_and_name() -> None:
    """``ipec="no"`` meant IPEC on and ``return_trip="no"`` drove back (``bool("no")`` is
    True); a misspelt reset option was ignored; ``reward_weights`` as a dict and
    ``covariance_k`` as one number ended in an AttributeError and a TypeError."""
    for make in (
        lambda: gym.make("ClapperRectangle-v0", ipec="no"),
        lambda: gym.make("StraightLine-v0", return_trip="yes"),
        lambda: gym.make("StraightLine-v0").reset(options={"return_trip": "no"}),
    ):
        with pytest.raises(SpecError, match="must be True or False, got str"):
            make()
    env = gym.make("StraightLine-v0", distance=1.0, return_trip=np.bool_(True))
    assert env.unwrapped.return_trip is True
    with pytest.raises(SpecError, match="unknown reset option 'drection' of UMBmarkSquare-v0"):
        gym.make("UMBmarkSquare-v0").reset(options={"drection": "ccw"})
    with pytest.raises(SpecError, match="reset options must be a dict, got list"):
        gym.make("UMBmarkSquare-v0").reset(options=["ccw"])
    vector = gym.make_vec("StraightLine-v0", num_envs=2, distance=1.0)
    vector.reset(seed=0)
    with pytest.raises(SpecError, match="unknown reset option 'return_trp' of StraightLine-v0"):
        vector.reset(options={"return_trp": True})
    weighted = gym.make("UMBmarkSquare-v0", reward_weights={"progress": 2.0})
    assert weighted.unwrapped.weights.progress == 2.0 and weighted.unwrapped.weights.time == 0.001
    with pytest.raises(SpecError, match="unknown reward weight 'progres'"):
        gym.make("UMBmarkSquare-v0", reward_weights={"progres": 1.0})
    with pytest.raises(ValueError, match=r"covariance_k must be two k \(k_L, k_R\)"):
        gym.make("UMBmarkSquare-v0", covariance_k=0.001)


def test_no_validation_gives_no_improvement() -> None:
    """``validation_runs=0`` skips the validation (E_max,syst NaN), and the improvement was
    reported as infinite; now NaN. A negative count was taken as 0; now refused."""
    from odomgym.baselines import UMBmark
    from odomgym.baselines.validation import calibrate_in_simulation

    method = UMBmark(side=1.0, runs_per_direction=1, scale_phases=0)
    report = calibrate_in_simulation(method, "labmate", validation_runs=0)
    assert np.isnan(report.e_max_after) and np.isnan(report.improvement)
    with pytest.raises(SpecError, match="validation_runs must be >= 0"):
        calibrate_in_simulation(method, odomgym.PRESETS["labmate"], validation_runs=-1)


def test_the_covariance_model_names_a_bad_argument() -> None:
    """A zero wheelbase gave ``ZeroDivisionError`` in ``end_pose`` and ``propagate_path``
    (``motion_covariance`` checked it); a two-value pose or a one-value segment a bare
    unpacking error; ``nodes=0`` NumPy's own message."""
    with pytest.raises(SpecError, match="wheelbase must be > 0"):
        covariance.propagate_path([(1.0, 1.0)], 0.0, 1e-3, 1e-3)
    with pytest.raises(SpecError, match="wheelbase must be > 0"):
        covariance.end_pose([0.0, 0.0, 0.0], 1.0, 2.0, 0.0)
    with pytest.raises(ValueError, match=r"start must be a finite pose \(x, y, theta\)"):
        covariance.end_pose([0.0, 0.0], 1.0, 1.0, 0.4)
    with pytest.raises(ValueError, match=r"segments\[1\] must be a pair \(left, right\)"):
        covariance.propagate_path([(1.0, 1.0), (1.0,)], 0.4, 1e-3, 1e-3)  # type: ignore[list-item]
    with pytest.raises(ValueError, match="nodes must be a whole number >= 1, got 0"):
        covariance.quadrature_motion_covariance(3.0, 1.0, 0.4, 1e-3, 1e-3, nodes=0)


def test_a_segment_whose_covariance_overflows_is_named_in_one_line() -> None:
    """A travel of 1e200 m was Python's bare ``OverflowError`` from inside Eq. 25's powers,
    and a k of 1e160 m^½ the same; now one ``ValueError`` giving the segment and the units."""
    for segment in ((1e200, 0.5, 0.5, 1e-3, 1e-3), (1.0, -1.0, 0.5, 1e160, 1e-3)):
        overflow = r"too large for the closed forms \(a power in its covariance overflows a float\)"
        with pytest.raises(ValueError, match=overflow):
            covariance.motion_covariance(*segment)
    with pytest.raises(ValueError, match=r"left = 1e\+200 m"):
        covariance.propagate_path([(1e200, 1e200)], 0.5, 1e-3, 1e-3)
    ordinary = covariance.motion_covariance(1.0, 0.9, 0.5, 1e-3, 1e-3)
    assert np.all(np.isfinite(ordinary)) and ordinary[0, 0] > 0.0


def test_every_calibrator_refuses_a_wrong_lab_or_initial_before_driving() -> None:
    """``calibrate(lab, initial="x")`` was a bare ``AttributeError`` ("'str' object has no
    attribute 'is_skid_steer'"), a number as the lab another. Every registered method now
    refuses both in one line naming the method and the argument, and books no run."""
    from odomgym.baselines import CALIBRATORS
    from odomgym.lab.simulated import SimLab

    lab = SimLab("labmate")
    for name, cls in CALIBRATORS.items():
        method = cls()
        with pytest.raises(SpecError, match=rf"^{name}\.calibrate: initial must be a Calibration"):
            method.calibrate(lab, initial="x")  # type: ignore[arg-type]
        with pytest.raises(SpecError, match=rf"^{name}\.calibrate: initial must be a Calibration"):
            method.calibrate(lab, "x")  # type: ignore[arg-type]
        with pytest.raises(SpecError, match=rf"^{name}\.calibrate: lab must be a Lab.*got int"):
            method.calibrate(5)  # type: ignore[arg-type]
    assert lab.runs_used == 0


def test_a_users_calibrator_keeps_its_own_signature_under_the_check() -> None:
    """The check wraps a user's subclass too (``Calibrator.__init_subclass__``), handing every
    argument on as it came: extra parameters, a keyword-only ``initial`` and the method's own
    default survive; a class without ``name`` is named by its class."""
    from odomgym.baselines import CALIBRATORS, Calibrator
    from odomgym.lab.simulated import SimLab

    default = Calibration.from_errors(e_d=1.01)

    class Mine(Calibrator):
        name = "mine"
        reference = "none"
        options_type = type(CALIBRATORS["umbmark"]().options)

        def experiments(self) -> list:  # type: ignore[type-arg]
            return []

        def calibrate(self, lab, initial=default, verbose=False):  # type: ignore[no-untyped-def]
            return (initial, verbose)

    class KeywordOnly(Mine):
        def calibrate(self, lab, *, initial=None):  # type: ignore[no-untyped-def]
            return initial

    class Nameless(Calibrator):
        reference = "none"
        options_type = Mine.options_type

        def experiments(self) -> list:  # type: ignore[type-arg]
            return []

        def calibrate(self, lab, initial=None):  # type: ignore[no-untyped-def]
            return initial

    lab = SimLab("labmate")
    mine = Mine.__new__(Mine)
    assert mine.calibrate(lab) == (default, False)
    assert mine.calibrate(lab, None, True) == (None, True)
    assert mine.calibrate(lab, verbose=True) == (default, True)
    assert KeywordOnly.__new__(KeywordOnly).calibrate(lab, initial=default) is default
    with pytest.raises(SpecError, match=r"^mine\.calibrate: initial must be"):
        mine.calibrate(lab, Calibration)  # the class, not an instance
    with pytest.raises(SpecError, match=r"^Nameless\.calibrate: initial must be"):
        Nameless.__new__(Nameless).calibrate(lab, "x")


def test_the_leaderboard_judges_every_method_on_the_same_sessions() -> None:
    """A method that cannot calibrate on some sessions was judged on its own, fewer pairs: on
    the shipped sessions least squares ranked first on 10 pairs against the others' 15. The
    ranking now takes, per evaluation session all methods have, the mean over each method's
    calibration sessions, then the mean over those sessions."""
    from odomgym.baselines.leaderboard import Leaderboard, format_leaderboard
    from odomgym.odometry.optiodom_measures import EvaluationMeasures

    def measures(final: float) -> EvaluationMeasures:
        return EvaluationMeasures(2 * final, 0.01, final, 0.01)

    board = Leaderboard()
    # "wide" calibrates on s1 and s2; "narrow" only on s1, and is never evaluated on s1.
    for source, target, final in (("s1", "s2", 0.010), ("s1", "s3", 0.030), ("s2", "s1", 0.5)):
        board.cross[("wide", source, target)] = measures(final)
    for target, final in (("s2", 0.020), ("s3", 0.020)):
        board.cross[("narrow", "s1", target)] = measures(final)
    assert board.evaluation_sessions() == ["s2", "s3"]
    rows = {row["method"]: row for row in board.ranking()}
    assert rows["wide"]["final_pos_mm"] == pytest.approx(20.0)  # s2: 10, s3: 30 (s1 not judged)
    assert rows["narrow"]["final_pos_mm"] == pytest.approx(20.0)
    assert (rows["wide"]["pairs"], rows["wide"]["calibrated_on"]) == (2, 2)  # s2→s1 not judged
    text = format_leaderboard(board)
    assert "judged on the same 2 evaluation sessions" in text
    assert "## In-session results (no published_results.csv" in text  # a user's own data


def test_a_floor_takes_its_cables_and_patches_as_objects_or_tables() -> None:
    """``FloorSpec(bumps=[{"x": 1, "y": 0}])`` was stored as given and ended in
    ``AttributeError: 'dict' object has no attribute 'x'`` at the first step on it; a single
    patch in ``TypeError: not iterable``. Tables are now built (as a floor file's are) and
    anything else refused, naming the entry."""
    from odomgym.floor import CableBump, FloorSpec, FrictionPatch

    floor = FloorSpec(bumps=[{"x": 1.0, "y": 0.0}], patches=[FrictionPatch(0, 0, 1, 1, 0.5)])
    assert floor.bumps == (CableBump(x=1.0, y=0.0),)
    assert floor.bump_arrays()[0].tolist() == [1.0]
    with pytest.raises(SpecError, match="patches must be a list of FrictionPatch") as caught:
        FloorSpec(patches=FrictionPatch(0, 0, 1, 1, 0.5))  # type: ignore[arg-type]
    assert caught.value.field == "patches"
    with pytest.raises(SpecError, match=r"bumps\[1\] must be a CableBump") as caught:
        FloorSpec(bumps=[CableBump(x=0.0, y=0.0), 3])  # type: ignore[list-item]
    with pytest.raises(SpecError, match=r"unknown field 'z' in bumps\[0\]"):
        FloorSpec(bumps=[{"x": 1.0, "z": 0.0}])  # type: ignore[list-item]


def test_a_robot_names_a_name_that_is_no_string_and_a_spec_that_is_no_table() -> None:
    """``name=5`` was taken (the docs quote "name must be a string", which only a file got);
    ``RobotSpec.from_dict([1])`` ended in ``AttributeError: 'list' object has no attribute
    'get'``."""
    with pytest.raises(SpecError, match="name must be a string, got int"):
        RobotSpec(**BASE, name=5)  # type: ignore[arg-type]
    with pytest.raises(SpecError, match="a robot spec is a table of fields, got list"):
        RobotSpec.from_dict([1])  # type: ignore[arg-type]


def test_the_clapper_envs_read_their_reset_options_and_refuse_others() -> None:
    """``ClapperRectangle-v0`` ignored ``reset(options={"direction": "ccw"})`` and drove cw;
    now the option sets the episode's direction, and an option no CLAPPER env reads is
    refused."""
    from odomgym.vehicle.paths import rectangle_path

    def driven(env: gym.Env, direction: str) -> bool:
        legs = env.unwrapped._trial.path.legs
        expected = rectangle_path(direction=direction).legs
        return len(legs) == len(expected) and all(
            np.array_equal(a.points, b.points) for a, b in zip(legs, expected, strict=True)
        )

    env = gym.make("ClapperRectangle-v0")
    env.reset(seed=0, options={"direction": "ccw"})
    assert driven(env, "ccw") and not driven(env, "cw")
    env.reset(seed=0)
    assert driven(env, "cw")
    with pytest.raises(SpecError, match=r"options\['direction'\] must be 'cw' or 'ccw'"):
        env.reset(options={"direction": "left"})
    with pytest.raises(SpecError, match="unknown reset option 'direction' of ClapperStraight-v0"):
        gym.make("ClapperStraight-v0").reset(options={"direction": "ccw"})


def test_an_env_refuses_a_route_size_or_control_period_that_is_no_number() -> None:
    """``side="4"`` was taken by ``float``, where the robot's own fields refuse a string; a
    control period of 10 s was taken and a 1 m straight ended at 2 m after three steps, called
    done; ``dt="0.05"`` ended in numpy's ``isfinite`` TypeError. NumPy numbers still pass."""
    from odomgym.envs.base import MAX_DT

    with pytest.raises(SpecError, match="side must be a number of metres, got '4'"):
        gym.make("UMBmarkSquare-v0", side="4")
    with pytest.raises(SpecError, match="distance must be a number of metres"):
        gym.make("StraightLine-v0", distance=None)
    for dt in (10.0, 0.0, "0.05", True):
        with pytest.raises(SpecError, match=r"dt must be a number of seconds in \(0, 1\]"):
            gym.make("StraightLine-v0", dt=dt)
        with pytest.raises(SpecError, match=r"dt must be a number of seconds in \(0, 1\]"):
            gym.make_vec("StraightLine-v0", num_envs=2, dt=dt)
    env = gym.make("UMBmarkSquare-v0", side=np.float32(2.0), dt=np.float64(MAX_DT))
    assert env.unwrapped.side == 2.0 and env.unwrapped.dt == 1.0

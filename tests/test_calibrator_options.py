"""Typed calibrator options: one frozen dataclass per method, unknown options refused by name,
string switches parsed into enums with the field named when they are wrong."""

from __future__ import annotations

import dataclasses
import inspect

import pytest

from odomgym.baselines import CALIBRATORS, Ivanjko, JungChung, LeastSquares, Trajectory, UMBmark
from odomgym.baselines.base import Calibrator, option_names
from odomgym.baselines.jung_chung import JungChungConventions
from odomgym.baselines.umbmark import UMBmarkConventions
from odomgym.baselines.validation import (
    calibrator_for_session,
    calibrator_for_squares,
    make_calibrator,
)
from odomgym.data import read_session, resolve_data
from odomgym.errors import SpecError
from odomgym.lab.experiment import Experiment, ExperimentKind

METHODS = sorted(CALIBRATORS)


@pytest.mark.parametrize("method", METHODS)
def test_constructor_takes_exactly_the_options(method: str) -> None:
    """The constructor's keywords mirror the options dataclass, names and defaults alike, so
    ``from_options`` and the constructor cannot drift apart."""
    cls = CALIBRATORS[method]
    assert dataclasses.is_dataclass(cls.options_type)
    assert cls.options_type.__dataclass_params__.frozen  # type: ignore[attr-defined]
    parameters = inspect.signature(cls.__init__).parameters
    keywords = {k: p.default for k, p in parameters.items() if k != "self"}
    defaults = {f.name: f.default for f in dataclasses.fields(cls.options_type)}
    assert keywords == defaults


@pytest.mark.parametrize("method", METHODS)
def test_default_options_round_trip(method: str) -> None:
    cls = CALIBRATORS[method]
    made = cls.from_options(cls.options_type())
    assert isinstance(made, cls)
    assert made.options == cls.options_type() == cls().options


@pytest.mark.parametrize("method", METHODS)
def test_an_option_the_method_does_not_take_is_refused_by_name(method: str) -> None:
    cls = CALIBRATORS[method]
    with pytest.raises(SpecError) as caught:
        make_calibrator(cls, sides=4.0)
    message = str(caught.value)
    assert caught.value.field == "sides"
    assert "\n" not in message
    assert message.startswith(f"{method} takes no option 'sides'; it takes ")
    assert all(name in message for name in option_names(cls.options_type))


def test_generic_options_are_not_dropped_silently() -> None:
    """Ivanjko drives no squares: a square side given to it is an error, not ignored."""
    with pytest.raises(SpecError) as caught:
        make_calibrator(Ivanjko, side=4.0, runs_per_direction=5)
    assert caught.value.field == "side"
    assert "ivanjko takes no option 'side'" in str(caught.value)


@pytest.mark.parametrize(
    ("cls", "option", "value"),
    [
        (UMBmark, "side", -1.0),
        (UMBmark, "straight_runs", 0),
        (UMBmark, "runs_per_direction", 2.5),
        (Ivanjko, "spin_runs", 0),
        (Ivanjko, "residuals", "every"),
        (LeastSquares, "weighting", "equal"),
        (Trajectory, "radius", 0.0),
        (Trajectory, "loss", "l2"),
    ],
)
def test_an_invalid_value_names_its_option(
    cls: type[Calibrator], option: str, value: object
) -> None:
    with pytest.raises(SpecError) as caught:
        make_calibrator(cls, **{option: value})
    assert caught.value.field == option
    assert option in str(caught.value)


def test_options_given_are_the_options_used() -> None:
    umbmark = make_calibrator(UMBmark, side=2.0, runs_per_direction=3, scale_phases=0)
    assert [(e.kind, e.direction, e.runs, e.size) for e in umbmark.experiments()] == [
        (ExperimentKind.SQUARE, "cw", 3, 2.0),
        (ExperimentKind.SQUARE, "ccw", 3, 2.0),
    ]
    circles = make_calibrator(Trajectory, path="circular", radius=0.5, laps=2.0)
    assert [(e.kind, e.direction, e.size, e.laps) for e in circles.experiments()] == [
        (ExperimentKind.CIRCULAR, "cw", 0.5, 2.0),
        (ExperimentKind.CIRCULAR, "ccw", 0.5, 2.0),
    ]


def test_conventions_parse_into_enums() -> None:
    """The TOML/CLI spellings land on the enum members; an unknown spelling lists the choices."""
    umbmark = make_calibrator(UMBmark, conventions="optiodom")
    assert umbmark.options.conventions is UMBmarkConventions.OPTIODOM
    assert make_calibrator(JungChung, conventions="optiodom").options.conventions is (
        JungChungConventions.OPTIODOM
    )
    assert UMBmark(conventions=UMBmarkConventions.OPTIODOM).use == "x"
    with pytest.raises(SpecError) as caught:
        make_calibrator(UMBmark, conventions="jung_chung")
    assert caught.value.field == "conventions"
    assert "'umbmark', 'optiodom'" in str(caught.value)


def test_trajectory_paths_are_the_kinds_that_turn_while_moving() -> None:
    with pytest.raises(SpecError) as caught:
        Trajectory(path="spin")
    assert caught.value.field == "path"
    with pytest.raises(SpecError) as caught:
        Trajectory(path="cirlce")
    assert caught.value.field == "path" and "'circular'" in str(caught.value)


def test_experiment_kind_parses_spellings_and_names_the_field() -> None:
    experiment = Experiment("circular", "cw", 2, 1.0, laps=1.5)
    assert experiment.kind is ExperimentKind.CIRCULAR and experiment.kind == "circular"
    assert f"{experiment.kind}" == "circular"  # a string enum formats as its spelling
    with pytest.raises(SpecError) as caught:
        Experiment("circle", "cw")
    assert caught.value.field == "kind"
    assert all(f"'{kind.value}'" in str(caught.value) for kind in ExperimentKind)
    with pytest.raises(SpecError) as caught:
        Experiment(ExperimentKind.CIRCULAR)
    assert caught.value.field == "direction"
    with pytest.raises(SpecError) as caught:
        Experiment(ExperimentKind.FREE, "cw")
    assert caught.value.field == "direction"


# ------------------------------------------------------------------ callers say what applies
@pytest.mark.parametrize("method", METHODS)
def test_command_line_square_settings_configure_every_method(method: str) -> None:
    """``calibrate METHOD --side L --runs N`` works for every method, sizing those that drive
    squares (and only those)."""
    calibrator = calibrator_for_squares(CALIBRATORS[method], side=2.0, runs_per_direction=4)
    squares = [e for e in calibrator.experiments() if e.kind is ExperimentKind.SQUARE]
    if method == "ivanjko":
        assert not squares and calibrator.options == Ivanjko.options_type()
    elif method.startswith("selfcal"):  # a fixed menu; it gets UMBmark's budget for these settings
        assert calibrator.options.budget == 2 * 4 + 6
    else:
        assert {(e.size, e.runs) for e in squares} == {(2.0, 4)}


@pytest.mark.parametrize("method", METHODS)
def test_every_built_in_method_sizes_itself_from_a_session(method: str) -> None:
    """Each method owns its session rule: a method that drives anything sizes itself from what
    a session holds (the base class's rule sizes nothing), or says it cannot run on one."""
    cls = CALIBRATORS[method]
    for rule in ("session_options", "budget_options"):
        assert getattr(cls, rule).__func__ is not getattr(Calibrator, rule).__func__, rule


def test_session_conventions_only_for_methods_that_take_them() -> None:
    session = read_session(resolve_data("optiodom:square/230620202042", session=True))
    umbmark = calibrator_for_session(UMBmark, session, "optiodom")
    assert umbmark.options.conventions is UMBmarkConventions.OPTIODOM
    assert umbmark.options.side == 0.75
    assert umbmark.options.runs_per_direction == len(session.select("square", "cw"))
    with pytest.raises(SpecError) as caught:
        calibrator_for_session(CALIBRATORS["lee"], session, "optiodom")
    assert caught.value.field == "conventions"
    assert "lee takes no option 'conventions'" in str(caught.value)


def test_session_sizing_asks_trajectory_for_the_circles_a_session_holds() -> None:
    session = read_session(resolve_data("optiodom:circular/250620202104", session=True))
    trajectory = calibrator_for_session(Trajectory, session)
    assert [(e.kind, e.direction, e.runs) for e in trajectory.experiments()] == [
        (ExperimentKind.CIRCULAR, "cw", 3),
        (ExperimentKind.CIRCULAR, "ccw", 3),
    ]
    with pytest.raises(LookupError, match=r"holding 3 circular cw, 3 circular ccw.*squares"):
        calibrator_for_session(LeastSquares, session)

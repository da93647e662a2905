"""The interface every calibrator implements.

A calibrator is a procedure that talks to a :class:`odomgym.lab.experiment.Lab`: it performs the
experiments it needs (with the calibration it wants active while driving), measures what a
person would measure, and returns corrected odometry parameters as a
:class:`odomgym.odometry.calibration.Calibration`. Because labs serve simulated and recorded runs
alike, the same calibrator object calibrates a simulated robot and a real robot's recorded session.

**Options.** Every method declares its settings as a frozen dataclass (``UMBmarkOptions``,
``TrajectoryOptions``, …) registered with it as :attr:`Calibrator.options_type`. The dataclass
validates every value and names the field that is wrong (:class:`~odomgym.errors.SpecError`);
the method's constructor takes the same keywords and builds its options from them, and
:meth:`Calibrator.from_options` builds a method from options. A caller that configures several
methods from one set of settings (a command line, the benchmark, a recorded session) says per
method which settings apply (:mod:`odomgym.baselines.validation`); an option a method does not
take is an error, never silently dropped.
"""

from __future__ import annotations

import dataclasses
import functools
from abc import ABC, abstractmethod
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Self, TypeVar

from odomgym.errors import SpecError, require_count, require_positive
from odomgym.lab.experiment import Experiment, ExperimentKind, Lab
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Direction, Run

__all__ = [
    "CALIBRATORS",
    "CalibrationResult",
    "Calibrator",
    "Holdings",
    "SquareCalibrator",
    "SquareOptions",
    "SquaresSizing",
    "check_calibrate_arguments",
    "check_square_settings",
    "default_methods",
    "option_names",
    "perform",
    "register_calibrator",
    "require_choice",
    "square_experiments",
]

C = TypeVar("C", bound="type[Calibrator]")


def require_choice(name: str, value: object, choices: Collection[str]) -> None:
    """:class:`SpecError` naming ``name`` unless ``value`` is one of ``choices``."""
    if value not in choices:
        allowed = ", ".join(repr(c) for c in choices)
        raise SpecError(f"{name} must be one of {allowed}, got {value!r}", field=name)


def check_square_settings(side: float, runs_per_direction: int) -> None:
    """Raise :class:`SpecError` unless the square side [m] is positive and there is at least
    one run per direction."""
    require_positive("side", side)
    require_count("runs_per_direction", runs_per_direction, 1)


def square_experiments(side: float, runs_per_direction: int) -> list[Experiment]:
    """The bi-directional square experiment: ``runs_per_direction`` cw, then as many ccw."""
    return [
        Experiment(ExperimentKind.SQUARE, "cw", runs_per_direction, side),
        Experiment(ExperimentKind.SQUARE, "ccw", runs_per_direction, side),
    ]


def option_names(options_type: type[Any]) -> tuple[str, ...]:
    """The options a method takes: the fields of its options dataclass, in order."""
    return tuple(f.name for f in dataclasses.fields(options_type))


@dataclass(frozen=True)
class SquareOptions:
    """Options of a method that needs only the bi-directional square experiment.

    Attributes:
        side: square side L [m] (Borenstein & Feng 1994, §6.3: 4 m).
        runs_per_direction: squares per direction (Borenstein & Feng 1994, §6.3: 5).
    """

    side: float = 4.0
    runs_per_direction: int = 5

    def __post_init__(self) -> None:
        check_square_settings(self.side, self.runs_per_direction)


def perform(
    lab: Lab, experiment: Experiment, calibration: Calibration, *, method: str, hint: str = ""
) -> list[Run]:
    """``lab.perform``, with a ``LookupError`` saying which method needed which runs.

    Recorded labs refuse experiments their session does not hold; the message then names the
    method, the runs it needed and what the lab said (``hint`` adds method-specific advice).
    """
    try:
        return lab.perform(experiment, calibration)
    except LookupError as exc:
        what = f"{experiment.direction or ''} {experiment.kind}".strip()
        raise LookupError(
            f"{method} needs {experiment.runs} {what} runs of size {experiment.size:g} that "
            f"this lab cannot provide{hint}: {exc}"
        ) from exc


@dataclass
class CalibrationResult:
    """What a calibrator found.

    Attributes:
        calibration: the corrected parameters, absolute (relative to the uncalibrated robot).
        estimates: the method's intermediate quantities (α, β [rad], R [m], E_d, E_b, …), named
            as in the method's paper, for reports and tests.
        runs_used: runs the method performed.
        distance_used: distance travelled [m].
        notes: anything a user should know (e.g. "second compensation advised").
    """

    calibration: Calibration
    estimates: dict[str, float] = field(default_factory=dict)
    runs_used: int = 0
    distance_used: float = 0.0
    notes: list[str] = field(default_factory=list)


class Calibrator(ABC):
    """Base class of calibration methods.

    Subclasses set ``name`` (the command-line name), ``reference`` (the paper) and
    ``options_type`` (the frozen dataclass of their options; the constructor takes its fields
    as keywords and keeps the validated options in :attr:`options`), and implement
    :meth:`experiments` (what they will ask for, for budgeting and documentation) and
    :meth:`calibrate`.
    """

    name: ClassVar[str]
    reference: ClassVar[str]
    options_type: ClassVar[type[Any]]
    options: Any
    min_budget: ClassVar[int] = 2
    """Fewest runs the method can calibrate with (default: one square each way); the benchmark
    refuses smaller budgets."""
    max_budget: ClassVar[int | None] = None
    """Most runs the method can calibrate with (``None``: no limit; the learned self-calibration
    sessions stop at 64); the benchmark refuses larger budgets before any robot runs."""
    skid_steer: ClassVar[bool] = False
    """Whether the method is made for skid-steer robots (its calibration moves the ICRs):
    such a method runs on any robot, but the commands that compare every method on
    differential-drive robots (``odomgym bench calibrators``, ``odomgym leaderboard``) leave it
    out unless it is named (:func:`default_methods`)."""

    # ------------------------------------------------------------------ sizing: the method's own
    # rules for the callers that configure every method alike. Each returns constructor options
    # (checked against :attr:`options_type` by the caller); the defaults size nothing, and the
    # method then runs with its defaults.
    @classmethod
    def budget_options(cls, runs: int) -> dict[str, Any]:
        """How the method spends a budget of ``runs`` runs (the benchmark's ``--budget``)."""
        del runs
        return {}

    @classmethod
    def square_options(cls, side: float, runs_per_direction: int) -> dict[str, Any]:
        """What the command line's square settings — side L [m] and squares per direction
        (``odomgym calibrate METHOD --side L --runs N``) — mean for the method."""
        del side, runs_per_direction
        return {}

    @classmethod
    def session_options(cls, held: Holdings) -> dict[str, Any]:
        """The method sized from what a recorded session holds; counts the session lacks keep
        the method's defaults (and the method then says what is missing). Raises LookupError
        if the method cannot run on a recorded session at all."""
        del held
        return {}

    @classmethod
    def from_options(cls, options: Any) -> Self:
        """The method configured by ``options`` (an instance of :attr:`options_type`)."""
        if not isinstance(options, cls.options_type):
            raise TypeError(
                f"{cls.name} is configured by {cls.options_type.__name__}, "
                f"got {type(options).__name__}"
            )
        return cls(**{name: getattr(options, name) for name in option_names(cls.options_type)})

    @abstractmethod
    def experiments(self) -> list[Experiment]:
        """The experiments one call of :meth:`calibrate` performs, in order."""

    @abstractmethod
    def calibrate(self, lab: Lab, initial: Calibration | None = None) -> CalibrationResult:
        """Run the method in ``lab``, starting from ``initial`` (default: uncalibrated)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Wrap a subclass's own :meth:`calibrate` in :func:`check_calibrate_arguments`, so that
        every method, a user's too, refuses a wrong ``lab`` or ``initial`` in one line naming
        the method before any experiment (``initial="x"`` was a bare ``AttributeError``, "'str'
        object has no attribute 'is_skid_steer'"). The wrapper hands every argument on as it
        came, so a method with more parameters, a keyword-only or renamed ``initial`` or its
        own default keeps them; ``initial`` is checked where it is given by that name or as
        the second argument."""
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("calibrate")
        if own is None or getattr(own, "__isabstractmethod__", False):
            return

        @functools.wraps(own)
        def calibrate(self: Calibrator, lab: Lab, *args: Any, **kwargs: Any) -> CalibrationResult:
            initial = args[0] if args else kwargs.get("initial")
            name = getattr(self, "name", type(self).__name__)
            check_calibrate_arguments(name, lab, initial)
            return own(self, lab, *args, **kwargs)  # type: ignore[no-any-return]

        cls.calibrate = calibrate  # type: ignore[method-assign]


_LAB_MEMBERS = ("robot", "perform", "runs_used", "distance_used")


def check_calibrate_arguments(name: str, lab: object, initial: object) -> None:
    """Raise :class:`~odomgym.errors.SpecError` unless ``lab`` has the members of a
    :class:`~odomgym.lab.experiment.Lab` and ``initial`` is a
    :class:`~odomgym.odometry.calibration.Calibration` or ``None``; the message names the
    method and the argument."""
    if initial is not None and not isinstance(initial, Calibration):
        raise SpecError(
            f"{name}.calibrate: initial must be a Calibration or None, "
            f"got {type(initial).__name__} {initial!r:.60}"
        )
    missing = [member for member in _LAB_MEMBERS if not hasattr(lab, member)]
    if missing:
        raise SpecError(
            f"{name}.calibrate: lab must be a Lab (a SimLab, a RecordedLab or an object with "
            f"{', '.join(_LAB_MEMBERS)}), got {type(lab).__name__} without {', '.join(missing)}"
        )


@dataclass(frozen=True)
class Holdings:
    """What a recorded session holds, as the methods ask for it.

    Attributes:
        side: square side L [m] (0 when the session states none).
        counts: runs per (experiment kind, direction), see
            :meth:`odomgym.lab.recorded.RecordedLab.holdings`.
    """

    side: float
    counts: Mapping[tuple[ExperimentKind, Direction | None], int]

    def runs(self, kind: ExperimentKind, direction: Direction | None = None) -> int:
        """How many runs of ``kind`` (and ``direction``) the session holds."""
        return int(self.counts.get((kind, direction), 0))

    def square_options(self) -> dict[str, Any]:
        """The side and squares per direction the session holds (for methods that drive the
        bi-directional square)."""
        out: dict[str, Any] = {}
        if self.side > 0.0:
            out["side"] = self.side
        if self.runs(ExperimentKind.SQUARE, "cw"):
            out["runs_per_direction"] = self.runs(ExperimentKind.SQUARE, "cw")
        return out


CALIBRATORS: dict[str, type[Calibrator]] = {}
"""The registry: command-line name → calibrator class. The benchmark, the leaderboard and the
command line offer every method in it; add one with :func:`register_calibrator`."""


def default_methods(*, skid_steer: bool = False) -> list[str]:
    """The registered methods a comparison runs when none are named: every method made for
    differential-drive robots, and with ``skid_steer`` those made for skid-steer robots too
    (:attr:`Calibrator.skid_steer`), in registration order."""
    return [name for name, cls in CALIBRATORS.items() if skid_steer or not cls.skid_steer]


def register_calibrator(cls: C, *, replace: bool = False) -> C:
    """Add calibrator class ``cls`` under ``cls.name`` (usable as a class decorator), so that
    ``odomgym calibrate``, ``bench`` and ``leaderboard`` offer it: a new method is one file.

    Raises ValueError for a name that is not letters, digits and ``_``, a name already taken
    (unless ``replace``), or a class without ``reference`` or ``options_type``.
    """
    name = getattr(cls, "name", "")
    if not isinstance(name, str) or not name or not name.replace("_", "").isalnum():
        raise ValueError(f"a calibrator needs a name of letters, digits and '_', got {name!r}")
    if name in CALIBRATORS and CALIBRATORS[name] is not cls and not replace:
        raise ValueError(f"a calibrator named {name!r} is already registered")
    for attribute in ("reference", "options_type"):
        if not hasattr(cls, attribute):
            raise ValueError(f"calibrator {name!r} has no {attribute}")
    if not dataclasses.is_dataclass(cls.options_type):
        raise ValueError(f"calibrator {name!r}: options_type must be a dataclass")
    if isinstance(cls.min_budget, bool) or not isinstance(cls.min_budget, int):
        raise ValueError(f"calibrator {name!r}: min_budget must be a whole number")
    most = cls.max_budget
    if most is not None and (isinstance(most, bool) or not isinstance(most, int) or most < 1):
        raise ValueError(f"calibrator {name!r}: max_budget must be None or a whole number >= 1")
    CALIBRATORS[name] = cls
    return cls


class SquaresSizing(Calibrator):
    """The sizing of a method that drives the bi-directional square (``side``,
    ``runs_per_direction``): half a budget each way, the command line's square settings as
    they are, and the squares a recorded session holds. A method with other experiments
    besides overrides what differs."""

    @classmethod
    def budget_options(cls, runs: int) -> dict[str, Any]:
        """Half the runs each way."""
        return {"runs_per_direction": max(1, runs // 2)}

    @classmethod
    def square_options(cls, side: float, runs_per_direction: int) -> dict[str, Any]:
        return {"side": side, "runs_per_direction": runs_per_direction}

    @classmethod
    def session_options(cls, held: Holdings) -> dict[str, Any]:
        return held.square_options()


class SquareCalibrator(SquaresSizing):
    """Base of methods that need only the bi-directional square experiment.

    Args:
        side: square side L [m] (Borenstein & Feng 1994: 4 m).
        runs_per_direction: squares per direction (Borenstein & Feng 1994: 5).

    Subclasses with further options build them (a subclass of :class:`SquareOptions`) and
    pass them to :meth:`_set_squares`.
    """

    options_type: ClassVar[type[Any]] = SquareOptions

    def __init__(self, side: float = 4.0, runs_per_direction: int = 5) -> None:
        self._set_squares(SquareOptions(side, runs_per_direction))

    def _set_squares(self, options: SquareOptions) -> None:
        self.options = options
        self.side = options.side
        self.runs_per_direction = options.runs_per_direction

    def experiments(self) -> list[Experiment]:
        """The cw and the ccw squares."""
        return square_experiments(self.side, self.runs_per_direction)

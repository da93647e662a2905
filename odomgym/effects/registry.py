"""The effect interface and its registry — dependency-free (numpy and :mod:`odomgym.errors`).

The robot spec and the World both consult this registry, so it must not import either: it
reaches them through two small protocols, :class:`SpecView` (what an effect reads from and writes
to a robot spec) and :class:`WorldView` (what a hook reads and changes in the World's step). That
keeps the dependencies one way — ``robot`` and ``physics`` import ``effects``, never the reverse.

An :class:`Effect` is a named physical mechanism with a few named :class:`Parameter` s. It has up
to four faces, each optional:

* **spec** — how its values live in a :class:`~odomgym.robot.RobotSpec` (by default in
  ``spec.effects[name]``; the geometric effects map onto the true diameters and wheelbase);
* **world** — a :class:`WorldHook` that the pymunk :class:`~odomgym.sim.world.World` calls at fixed
  stages of its step (transmission, contact velocities, perturbations, the tracked point), so an
  env built from the spec *behaves* like the robot;
* **replay** — the same equations applied to a logged run's encoder counts (:class:`ReplayArrays`,
  all samples of a run at once), which is what the discrepancy workflow fits;
* **noise** — for zero-mean effects: per-sample wheel-travel variance and heading-jump rates that
  enter the workflow's likelihood.

The World and the workflow ask the registry (:data:`EFFECTS`); neither knows effect names, so
:func:`register_effect` adds a user's effect without editing either (worked example in
``docs/effects.md``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from odomgym.errors import SpecError, require_finite

__all__ = [
    "EFFECTS",
    "Effect",
    "Parameter",
    "ReplayArrays",
    "SpecView",
    "WorldHook",
    "WorldView",
    "get_effect",
    "register_effect",
    "run_bounds",
    "scale_columns",
]

FloatArray = NDArray[np.float64]

Spec = TypeVar("Spec", bound="SpecView")


class SpecView(Protocol):
    """What an effect needs of a robot spec (:class:`odomgym.robot.RobotSpec` is one).

    ``e_d``, ``e_b``, ``e_s`` are the true geometry's systematic errors (Borenstein & Feng 1994,
    Eqs. 6.24–6.32), where the geometric effects keep their values; every other effect keeps a
    table of its parameters, stored with :meth:`store_effect_table` by :meth:`Effect.write` only.
    """

    @property
    def e_d(self) -> float: ...

    @property
    def e_b(self) -> float: ...

    @property
    def e_s(self) -> float: ...

    def effect_values(self, name: str) -> dict[str, float] | None: ...

    def with_errors(
        self: Spec, e_d: float | None = None, e_b: float | None = None, e_s: float | None = None
    ) -> Spec: ...

    def store_effect_table(self: Spec, name: str, values: Mapping[str, float] | None) -> Spec: ...


class WorldView(Protocol):
    """What a :class:`WorldHook` reads and changes in the World's step
    (:class:`odomgym.sim.world.World` is one). Arrays are per robot, N rows."""

    n: int

    @property
    def time(self) -> float:
        """Simulated time since the World's start [s]."""

    pose: FloatArray
    """True axle-midpoint poses (N, 3) [m, m, rad]."""
    half_track: FloatArray
    """Half the true wheelbase (N,) [m]."""
    true_radius: FloatArray
    """True wheel radii (N, 2) [m] (left, right)."""
    wheel_angle: FloatArray
    """Each wheel's rotation since the robot's reset (N, 2) [rad]."""
    wheel_roughness: FloatArray
    """Each wheel's Chong & Kleeman noise constant k (N, 2) [m^½]; hooks may raise it."""

    @property
    def substep(self) -> float:
        """Length of one physics substep [s]."""
        ...

    @property
    def rim_speed(self) -> FloatArray:
        """Rim speed of each wheel in the current substep (N, 2) [m/s]."""
        ...

    @property
    def ground_velocity(self) -> FloatArray:
        """No-slip velocity of each wheel contact (N, 2, 2) [m/s], changed in place by hooks."""
        ...


@dataclass(frozen=True)
class Parameter:
    """One named parameter of an effect.

    Attributes:
        name: the key in the TOML table ``[robot.effects.EFFECT]``.
        unit: SI unit, for tables and docs.
        absent: the value at which the effect does nothing (the nesting point).
        low, high: the values a spec may hold (validation).
        scale: a typical small magnitude, used as the finite-difference step and initial scale
            when fitting (same unit).
        doc: one line on what it means.
    """

    name: str
    unit: str
    absent: float
    low: float
    high: float
    scale: float
    doc: str = ""

    def at_limit(self, value: float) -> bool:
        """True if ``value`` sits on ``low`` or ``high`` (within a millionth of ``scale``: a fit
        clipped to a limit comes back through a change of units, not always bit-exact) — a fit
        that ran into a limit is a stand-in for something else, not a measurement."""
        tolerance = 1e-6 * self.scale
        return abs(value - self.low) <= tolerance or abs(value - self.high) <= tolerance


class Effect:
    """Base class of the catalogue's entries; subclasses set the class attributes and override
    the faces they have (see the module docstring)."""

    name: ClassVar[str] = ""
    parameters: ClassVar[tuple[Parameter, ...]] = ()
    noise: ClassVar[bool] = False
    """True for zero-mean effects that change the spread, not the mean, of the disagreement."""
    summary: ClassVar[str] = ""
    reveals: ClassVar[str] = ""
    """Which experiments make it visible (for reports and the docs)."""
    in_table: ClassVar[bool] = True
    """False for effects whose values live in the spec's own fields (the true geometry: E_d,
    E_b, E_s) rather than in ``spec.effects``."""
    partners: ClassVar[tuple[str, ...]] = ()
    """Systematic effects whose parameters are fitted jointly with this one, because its replay
    moves the mean along the same direction (bumps shorten the travel as a distance scale
    does): the workflow refits them beside it, so each named value is right, not only their
    sum."""
    body_after: ClassVar[tuple[str, ...]] = ()
    """Effects whose ``"body"`` replay stage this one's must follow when both are in a spec
    (the replay otherwise applies a stage in the spec's order, alphabetical). ``skid_track``
    scales the yaw by a factor of the wheel travels alone, while ``turn_skid`` reads the
    incoming yaw (ω₀ = dθ₀/Δt): applied first, the skid track would shrink the turn skid's
    ω₀, which the World (both hooks read the rim speeds) and ``docs/effects.md`` do not."""
    with_systematic: ClassVar[bool] = False
    """A noise effect whose signature no systematic effect can make (floor bumps' sudden jumps
    during steady driving): it competes with the systematic effects from the first round of
    ``diagnose`` where that signature is in the data, so that a systematic effect named before
    it cannot stand in for its realised jumps (:func:`odomgym.diagnose.rounds.run_round`)."""
    measurement: ClassVar[bool] = False
    """True for an error of the measurement, not of the robot (the ground-truth system's
    tracked point): ``diagnose`` fits it like any effect, and reports it after the robot's
    own effects, since a report is read for what is wrong with the robot
    (:func:`odomgym.diagnose.workflow._in_order_added`)."""
    confounded: ClassVar[str] = ""
    """What else, outside the catalogue, produces exactly the same logs (the report repeats it
    whenever the effect is named, so a reader does not take the name for more than the data
    can say)."""
    stacked_replay: ClassVar[bool] = False
    """Whether :meth:`replay` may be handed several runs' arrays stacked end to end
    (:attr:`ReplayArrays.bounds` says where each run starts): true of a replay that acts
    sample by sample, or run by run through ``bounds`` (backlash's play restarts at every
    run). ``diagnose`` then replays all of a fit's runs in one pass
    (:func:`odomgym.diagnose.replay.replay_stacked`), where a run at a time pays the stages'
    numpy calls once per run; a spec carrying an effect without it is replayed run by run.
    An effect that does not override :meth:`replay` has nothing to stack and counts as true.
    False by default, so a user's effect that reads a whole run (a cumulative sum, a
    gradient) keeps its own run."""

    # ------------------------------------------------------------------ values
    @classmethod
    def absent_values(cls) -> dict[str, float]:
        """The values at which the effect is absent."""
        return {p.name: p.absent for p in cls.parameters}

    @classmethod
    def shape_identified(cls, values: Mapping[str, float], travel: Sequence[FloatArray]) -> bool:
        """Whether logs whose wheel travels per interval are ``travel`` (per run (n, 2) [m]) can
        tell this effect at the fitted ``values`` from its :attr:`partners` alone. True unless
        an effect says otherwise: ``skid_track`` whose half-point lies beyond every turn the data
        holds is one more constant track factor over those turns, i.e. ``wheelbase``. ``diagnose``
        does not call such a fit significant."""
        return True

    @classmethod
    def skid_steer_refusal(cls, values: Mapping[str, float]) -> str:
        """Why the World cannot apply this effect at ``values`` to a skid-steer robot, or ""
        when it can. A skid-steer robot's contacts take each side's no-slip speed along the
        heading (:func:`odomgym.sim.world.skid_contacts`), so an effect that turns the contacts'
        velocity sideways (a wheel toe, a crab term) would be dropped without a word: refused."""
        del values
        return ""

    @classmethod
    def profile(
        cls, values: Mapping[str, float], travel: Sequence[FloatArray]
    ) -> tuple[str, list[dict[str, float]]] | None:
        """Where a candidate fit of this effect may start, for data whose wheel travels per
        interval are ``travel``: the name of a parameter held at each start while the others
        are fitted (a profile over it), and the starts (``values`` with the held parameter,
        and any other the start needs, changed); or None to start at ``values`` alone.
        None unless an effect says otherwise: ``skid_track``'s fall with the turn radius.
        ``diagnose`` profiles only a fit that came back at nothing."""
        return None

    @classmethod
    def is_absent(cls, values: Mapping[str, float]) -> bool:
        """True if every parameter sits at its absent value."""
        return all(float(values.get(p.name, p.absent)) == p.absent for p in cls.parameters)

    @classmethod
    def validate(cls, values: Mapping[str, Any], *, source: str | None = None) -> dict[str, float]:
        """Check names and ranges; missing parameters take their absent values.

        Raises :class:`SpecError` naming ``effects.NAME.PARAM``.
        """
        known = {p.name: p for p in cls.parameters}
        for key in values:
            if key not in known:
                raise SpecError(
                    f"unknown parameter {key!r} of effect {cls.name!r}; parameters: "
                    f"{', '.join(known)}",
                    field=f"effects.{cls.name}.{key}",
                    source=source,
                )
        out: dict[str, float] = {}
        for p in cls.parameters:
            label = f"effects.{cls.name}.{p.name}"
            value = require_finite(label, values.get(p.name, p.absent), source=source)
            if not p.low <= value <= p.high:
                raise SpecError(
                    f"{label} must lie in [{p.low:g}, {p.high:g}] {p.unit}, got {value!r}",
                    field=label,
                    source=source,
                )
            out[p.name] = value
        return out

    # ------------------------------------------------------------------ spec face
    def read(self, spec: SpecView) -> dict[str, float]:
        """The effect's current values in ``spec`` (absent values if it does not carry it)."""
        stored = spec.effect_values(self.name)
        return dict(stored) if stored is not None else self.absent_values()

    def write(self, spec: Spec, values: Mapping[str, float]) -> Spec:
        """A copy of ``spec`` carrying ``values``, validated (dropping the effect if they are
        absent). The one way a value reaches a spec: :meth:`RobotSpec.apply_effect` calls it,
        and an effect that keeps its values elsewhere (the true geometry) overrides it."""
        clean = self.validate(values)
        return spec.store_effect_table(self.name, None if self.is_absent(clean) else clean)

    # ------------------------------------------------------------------ world face
    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        """The hook the World installs; ``values`` (N, P) holds every robot's parameters in
        :attr:`parameters` order (absent values for robots that lack the effect)."""
        del world, values
        return None

    # ------------------------------------------------------------------ replay face
    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        """Apply the effect to one run's arrays at ``stage`` (in place), or to several runs'
        stacked if :attr:`stacked_replay`; see :class:`ReplayArrays` for the stages."""
        del stage, values, arrays

    @classmethod
    def replays_stacked(cls) -> bool:
        """Whether this effect's replay takes several runs stacked: the class that defines its
        :meth:`replay` says so itself (:attr:`stacked_replay` in its own body), or there is no
        replay but :class:`Effect`'s. A subclass that overrides a stacking effect's replay
        without saying so again is replayed run by run."""
        for klass in cls.__mro__:
            if "replay" in vars(klass):
                return klass is Effect or bool(vars(klass).get("stacked_replay", False))
        return True

    # ------------------------------------------------------------------ noise face
    def wheel_variance(self, values: Mapping[str, float], travel: FloatArray) -> FloatArray | None:
        """Extra variance of each wheel's ground travel per sample (n, 2) [m²], or None.

        Each row must depend on that sample's ``travel`` alone (element by element): a noise
        fit passes the travel of all its runs stacked in one array
        (:func:`odomgym.diagnose.likelihood.stacked_process_noise`)."""
        del values, travel
        return None

    def wheel_jumps(
        self, values: Mapping[str, float], travel: FloatArray, wheelbase: float
    ) -> tuple[FloatArray, float] | None:
        """Sparse losses of wheel travel: (expected number per sample and wheel (n, 2), travel
        lost per jump [m]), or None. A loss e on one wheel moves the pose by −e/2 along the
        track and turns it by ±e/b: the heading jumps of bumps. As for
        :meth:`wheel_variance`, each row must depend on that sample's ``travel`` alone."""
        del values, travel, wheelbase
        return None


def scale_columns(matrix: FloatArray, factors: Sequence[float] | FloatArray) -> FloatArray:
    """``matrix`` (n, k) with column j multiplied by ``factors[j]``: the products of
    ``matrix * np.array(factors)``, element by element the same, computed column by column.

    Why: numpy broadcasts a row of two over thousands of rows slowly (~20 µs for (2450, 2),
    ~5 µs column by column), and the replay and the wheel noise do it for every run of every
    likelihood evaluation (wheel rotations times radii, |travel| times k²)."""
    out = np.empty(matrix.shape)
    for j, factor in enumerate(factors):
        np.multiply(matrix[:, j], factor, out=out[:, j])
    return out


@dataclass
class ReplayArrays:
    """One run's arrays as the kinematic replay transforms them, stage by stage.

    Stages, in order (``docs/effects.md``):

    ``"transmission"``  ``wheel`` (n, 2) [rad]: wheel rotation per sample, initially the motor
                        rotation the encoders counted;
    ``"body"``          ``ds`` (n,) [m], ``dtheta`` (n,) [rad] and ``crab`` (n,) [rad], the angle
                        between the heading and the direction of translation, after the true
                        geometry turned ``wheel`` into ``travel`` (n, 2) [m];
    ``"measurement"``   ``tracked`` (T, 3): the pose the ground-truth system reports, initially the
                        axle-midpoint ``pose`` (T, 3) [m, m, rad].

    ``dt`` (n,) [s] holds the sample intervals, ``wheelbase`` the model's true wheelbase [m],
    ``radius`` (2,) the model's true wheel radii [m] (left, right), ``angle`` (n, 2) each wheel's
    angle at the interval's middle [rad] (from the session's start when the run says where it
    began, ``Run.meta["wheel_angle0"]``, else from the run's start) and ``time`` (n,) the time at
    the interval's middle since the session started [s] (``Run.meta["session_time"]`` at the
    run's first sample, else 0).

    ``bounds`` (R + 1,), when not None, says that the arrays hold R runs stacked end to end:
    run r's intervals are rows ``bounds[r]:bounds[r + 1]`` of the (n,) and (n, 2) arrays and its
    poses rows ``bounds[r] + r:bounds[r + 1] + r + 1`` of the (T, 3) ones (only effects with
    :attr:`Effect.stacked_replay` see such arrays; :func:`run_bounds` gives the bounds of
    either kind).

    ``memo`` holds what an effect derives from a run's inputs alone (``angle``, ``time``,
    ``dt``), kept between replays of the same run (the diagnose fits replay every run hundreds
    of times with different parameters): each entry is ``(input, derived)``, reused only while
    ``input is`` the array of the current replay. The input arrays of such replays are shared
    and read-only: an effect replaces the arrays of its stage, never writes into them.
    """

    dt: FloatArray
    wheel: FloatArray
    wheelbase: float = 0.0
    radius: FloatArray = field(default_factory=lambda: np.zeros(2))
    angle: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    time: FloatArray = field(default_factory=lambda: np.zeros(0))
    travel: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    ds: FloatArray = field(default_factory=lambda: np.zeros(0))
    dtheta: FloatArray = field(default_factory=lambda: np.zeros(0))
    crab: FloatArray = field(default_factory=lambda: np.zeros(0))
    pose: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    tracked: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    memo: dict[str, tuple[FloatArray, FloatArray]] = field(default_factory=dict)
    bounds: NDArray[np.int64] | None = None


def run_bounds(arrays: ReplayArrays) -> NDArray[np.int64]:
    """Where each run's intervals start in ``arrays`` and where the last ends (R + 1,):
    :attr:`ReplayArrays.bounds`, or ``[0, n]`` for one run's arrays."""
    if arrays.bounds is not None:
        return arrays.bounds
    return np.array([0, len(arrays.dt)], dtype=np.int64)


class WorldHook:
    """What an effect does inside the World's step. Override the stages used and set the
    matching ``has_*`` flag, so the World skips the others at no cost.

    Stages of one physics substep of length h [s]:

    1. ``transmission(motor_step)`` — (N, 2) motor rotation this substep [rad], in place to the
       wheel rotation (the encoders count the motor);
    2. ``shape(world, h)`` — change ``world.ground_velocity`` (N, 2, 2) [m/s], the no-slip
       velocities of the wheel contacts, before the floor acts;
    3. ``perturb(world, h)`` — after the floor (cables, roughness) acted, same array;
    and outside the step: ``tracked(pose)`` — the pose a tracking system reports.

    ``configure(world)`` runs once when the World is built (e.g. to add wheel roughness),
    ``reset(indices)`` when robots are reset. Hooks that draw random numbers set
    ``needs_rng`` and receive one Generator per robot in ``bind_rng``.
    """

    has_transmission: ClassVar[bool] = False
    has_shape: ClassVar[bool] = False
    has_perturb: ClassVar[bool] = False
    has_tracked: ClassVar[bool] = False
    needs_rng: ClassVar[bool] = False

    def configure(self, world: WorldView) -> None:
        """Adjust the World's per-robot parameter arrays once, before the first step."""
        del world

    def bind_rng(self, streams: Sequence[np.random.Generator]) -> None:
        """Receive one random stream per robot (only if ``needs_rng``)."""
        del streams

    def rebind_rng(self, index: int, stream: np.random.Generator) -> None:
        """Robot ``index`` gets a new stream (a vector env's sub-env reset with a seed); a
        hook that draws at binding time draws again, as :meth:`bind_rng` would."""
        del index, stream

    def reset(self, indices: NDArray[np.intp]) -> None:
        """Robots ``indices`` were put back at rest."""
        del indices

    def transmission(self, motor_step: FloatArray) -> None:
        """Motor rotation → wheel rotation this substep, in place (N, 2) [rad]."""
        del motor_step

    def shape(self, world: WorldView, h: float) -> None:
        """Change the no-slip contact velocities before the floor acts."""
        del world, h

    def perturb(self, world: WorldView, h: float) -> None:
        """Change the contact velocities after the floor acted."""
        del world, h

    def tracked(self, pose: FloatArray) -> FloatArray:
        """The pose (N, 3) a tracking system would report for true poses ``pose``."""
        return pose


EFFECTS: dict[str, Effect] = {}
"""The registry: effect name → instance. Add to it with :func:`register_effect`."""


def register_effect(effect: Effect, *, replace: bool = False) -> Effect:
    """Add ``effect`` to the catalogue (so robot TOMLs, the World and ``diagnose`` know it).

    Raises ValueError for a nameless effect, a parameter list that does not nest (absent value
    outside its range) or a name already taken (unless ``replace``).
    """
    name = effect.name
    if not name or not name.replace("_", "").isalnum():
        raise ValueError(f"an effect needs a name of letters, digits and '_', got {name!r}")
    if name in EFFECTS and not replace:
        raise ValueError(f"an effect named {name!r} is already registered")
    if not effect.parameters:
        raise ValueError(f"effect {name!r} has no parameters")
    for p in effect.parameters:
        if not (p.low <= p.absent <= p.high) or not (math.isfinite(p.scale) and p.scale > 0):
            raise ValueError(
                f"effect {name!r}: parameter {p.name!r} must have low <= absent <= high and a "
                "positive scale"
            )
    EFFECTS[name] = effect
    return effect


def get_effect(name: str, *, source: str | None = None) -> Effect:
    """The registered effect ``name``; :class:`SpecError` listing the known ones otherwise."""
    try:
        return EFFECTS[name]
    except KeyError:
        raise SpecError(
            f"unknown effect {name!r}; known effects: {', '.join(sorted(EFFECTS))}",
            field=f"effects.{name}",
            source=source,
        ) from None

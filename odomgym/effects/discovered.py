"""The grammar of odometry errors, and ``discovered``: effects found by sparse regression.

Every systematic error of a differential-drive robot's dead reckoning is, over one sampling
interval, a change of one of four **channels** — the left wheel's ground travel, the right
wheel's ground travel, the *crab* angle between the heading and the direction of translation,
and the yaw increment — by an amount that depends on how the robot is moving: a **modulator**.
A term of the grammar is one channel times one modulator times a coefficient:

===========  ============================================  ======================================
channel      what the term does in one interval            coefficient unit
===========  ============================================  ======================================
``left``     left wheel travel × (1 + c·m)                 1/[m]
``right``    right wheel travel × (1 + c·m)                1/[m]
``crab``     crab angle += c·m                             rad/[m]
``yaw``      yaw increment × (1 + c·m)                     1/[m]
===========  ============================================  ======================================

Modulators of the wheel channels are each wheel's own motion: ``one`` (1), ``speed`` (|v_w|
[m/s], the wheel's rim speed), ``speed2`` (v_w² [m²/s²]), ``direction`` (sign of v_w),
``accel`` (d|v_w|/dt [m/s²]: positive while speeding up), ``sin1``/``cos1`` (sin/cos of the
wheel's angle φ: once per revolution), ``sin2``/``cos2`` (of 2φ: twice per revolution), and
``time`` (seconds since the session started). Modulators of the body channels are the body's
motion: ``one``, ``speed`` (|v|), ``speed2``, ``rate`` (|ω| [rad/s]), ``lateral`` (|v·ω|
[m/s²], the lateral acceleration), ``lateral_signed`` (v·ω), ``direction`` (sign of v),
``time`` and ``spin`` (1/(1 + λ²) [-] with the path parameter λ = (d_L + d_R)/(d_R − d_L) of the
interval's wheel travels: 1 in a spin, ½ with the inner wheel at rest, 0 on a straight path — the
turn-radius modulator of a skid-steer robot's scrub, Wang et al. 2015).

The catalogue's systematic effects are points of this grammar (``docs/diagnose.md``): E_s is
``left_one`` = ``right_one`` (both wheels' travel × 1), E_d the differential travel × 1
(``right_one`` = −``left_one``), E_b ``yaw_one`` (every turn scaled), ``turn_skid``
``yaw_lateral`` (negative), ``wheel_toe`` ``crab_one``, ``skid_track`` near ``yaw_spin``
(negative; exactly its shape at λ½ = 1 to first order), and on skid-steer robots ``skid_speed``
``yaw_lateral`` (positive). Backlash (a hysteresis) and the
tracked-point offset (a measurement) are not; the noise effects are not systematic.

The ``discovered`` effect carries any set of terms as parameters named ``CHANNEL_MODULATOR``
(``right_sin1 = 0.018``) in ``[robot.effects.discovered]``; only non-zero terms are stored. The
World applies them per physics substep (wheel channels to the motor rotation as a transmission
stage, body channels to the contact velocities as a shape stage) and the replay per logged
interval, with the same modulators, so an env built from a diagnosed robot behaves like it.

Why these modulators: they are the mechanisms a roboticist checks first — tyre compression
and centrifugal growth (speed), out-of-round wheels and bent axles (wheel angle), traction slip
(acceleration), direction-dependent gear or tyre behaviour (direction), lateral tyre slip in
arcs (v·ω), wear or warming during a session (time), a skid-steer robot's scrub that grows as
the turn tightens (spin) — and each is computable from the logged
wheel motions alone, which is what a term needs to be replayed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.effects.registry import (
    Effect,
    Parameter,
    ReplayArrays,
    Spec,
    SpecView,
    WorldHook,
    WorldView,
    run_bounds,
)
from odomgym.effects.term_replay import replay_body_terms, replay_wheel_terms

__all__ = [
    "BODY_MODULATORS",
    "CATALOGUE_POINTS",
    "CHANNELS",
    "TERMS",
    "WHEEL_MODULATORS",
    "Discovered",
    "DiscoveredTerms",
    "Term",
    "describe_term",
    "operating_phrase",
    "spin_share",
    "term_by_name",
]

FloatArray = NDArray[np.float64]

CHANNELS = ("left", "right", "crab", "yaw")
WHEEL_MODULATORS = (
    "one",
    "speed",
    "speed2",
    "direction",
    "accel",
    "sin1",
    "cos1",
    "sin2",
    "cos2",
    "time",
)
BODY_MODULATORS = (
    "one",
    "speed",
    "speed2",
    "rate",
    "lateral",
    "lateral_signed",
    "direction",
    "time",
    "spin",
)
_MOD_UNIT = {
    "one": "",
    "speed": "m/s",
    "speed2": "m²/s²",
    "direction": "",
    "accel": "m/s²",
    "sin1": "",
    "cos1": "",
    "sin2": "",
    "cos2": "",
    "time": "s",
    "rate": "rad/s",
    "lateral": "m/s²",
    "lateral_signed": "m/s²",
    "spin": "",
}
# A typical modulator size on a small indoor robot: the fit's step and scale is 1e-3 of the
# channel over this size (a 0.1 % travel change, 1 mrad of crab).
_MOD_SIZE = {
    "one": 1.0,
    "speed": 0.3,
    "speed2": 0.1,
    "direction": 1.0,
    "accel": 0.3,
    "sin1": 1.0,
    "cos1": 1.0,
    "sin2": 1.0,
    "cos2": 1.0,
    "time": 600.0,
    "rate": 1.0,
    "lateral": 0.3,
    "lateral_signed": 0.3,
    "spin": 1.0,
}
_MOD_WORDS = {
    "one": "constantly",
    "speed": "with speed",
    "speed2": "with the square of speed",
    "direction": "with the direction of travel (forward vs reverse)",
    "accel": "with acceleration",
    "sin1": "once per wheel revolution",
    "cos1": "once per wheel revolution",
    "sin2": "twice per wheel revolution",
    "cos2": "twice per wheel revolution",
    "time": "over the session",
    "rate": "with the turn rate",
    "lateral": "with lateral acceleration |v·ω|",
    "lateral_signed": "with the signed lateral acceleration v·ω (opposite in left and right arcs)",
    "spin": "with the tightness of the turn 1/(1 + λ²) (1 in a spin, 0 on a straight path)",
}
_MECHANISM = {
    ("wheel", "one"): "an effective wheel diameter off nominal",
    ("wheel", "speed"): "a tyre that compresses or grows with speed, or speed-dependent slip",
    ("wheel", "speed2"): "centrifugal tyre growth or slip growing with speed",
    ("wheel", "direction"): "tyre or gear behaviour that differs forward and in reverse",
    ("wheel", "accel"): "traction slip while accelerating and braking",
    ("wheel", "sin1"): "an out-of-round wheel or a bent axle",
    ("wheel", "cos1"): "an out-of-round wheel or a bent axle",
    ("wheel", "sin2"): "an oval wheel or tyre",
    ("wheel", "cos2"): "an oval wheel or tyre",
    ("wheel", "time"): "a wheel that changes during the session (wear, warming, pressure)",
    ("crab", "one"): "misaligned wheels (toe) or a ground-truth frame misalignment",
    ("crab", "lateral_signed"): "tyre sideslip in arcs (slip angle growing with v·ω)",
    ("crab", "lateral"): "sideslip in arcs",
    ("yaw", "one"): "an effective wheelbase off nominal",
    ("yaw", "lateral"): "yaw skid in fast arcs (under- or over-steer)",
    ("yaw", "rate"): "scrub in fast turns",
    ("yaw", "spin"): "skid-steer scrub: an apparent track that widens as the turn tightens",
}

CATALOGUE_POINTS: dict[str, str] = {
    "wheel_diameter_ratio": "left_one = −right_one ≈ −(E_d − 1)/2 (differential travel × 1)",
    "distance_scale": "left_one = right_one = E_s − 1 (both wheels' travel × 1)",
    "wheelbase": "yaw_one = 1/E_b − 1 (every turn scaled)",
    "turn_skid": "yaw_lateral = −κ (yaw × |v·ω|, the linear law)",
    "wheel_toe": "crab_one = τ (crab × 1)",
    "skid_track": "yaw_spin = −ε at λ½ = 1 (the yaw increment × (1 − ε/(1 + λ²)), small ε)",
    "skid_speed": "yaw_lateral = +g (yaw × |v·ω|, the linear law)",
}
"""The catalogue's systematic effects as points of the grammar (to first order)."""


@dataclass(frozen=True)
class Term:
    """One channel × modulator of the grammar."""

    channel: str
    modulator: str

    @property
    def name(self) -> str:
        """The parameter name, ``CHANNEL_MODULATOR``."""
        return f"{self.channel}_{self.modulator}"

    @property
    def wheel(self) -> bool:
        """True for the wheel-travel channels."""
        return self.channel in ("left", "right")

    @property
    def unit(self) -> str:
        """The coefficient's unit: channel unit per modulator unit."""
        mod = _MOD_UNIT[self.modulator]
        base = "rad" if self.channel == "crab" else "1"
        return base if not mod else f"{base}/({mod})"

    @property
    def scale(self) -> float:
        """A small coefficient: 1e-3 of the channel at a typical modulator size."""
        return 1e-3 / _MOD_SIZE[self.modulator]


TERMS: tuple[Term, ...] = tuple(
    [Term(c, m) for c in ("left", "right") for m in WHEEL_MODULATORS]
    + [Term(c, m) for c in ("crab", "yaw") for m in BODY_MODULATORS]
)
"""Every term of the grammar, in parameter order."""

_BY_NAME = {t.name: t for t in TERMS}


def term_by_name(name: str) -> Term:
    """The term called ``name`` (``KeyError`` listing none; callers check names first)."""
    return _BY_NAME[name]


def describe_term(name: str, value: float, stderr: float = math.nan) -> str:
    """A sentence a roboticist reads, e.g. "the right wheel's travel varies once per
    revolution, amplitude 1.8 % (± 0.1 %) — an out-of-round wheel or a bent axle"."""
    term = _BY_NAME[name]
    err = f" (± {_fmt(term, stderr)})" if math.isfinite(stderr) else ""
    words = _MOD_WORDS[term.modulator]
    key = ("wheel" if term.wheel else term.channel, term.modulator)
    mechanism = _MECHANISM.get(key, "")
    tail = f" — {mechanism}" if mechanism else ""
    if term.wheel:
        who = f"the {term.channel} wheel's travel"
        if term.modulator in ("sin1", "cos1", "sin2", "cos2"):
            return f"{who} varies {words}, amplitude {_fmt(term, value)}{err}{tail}"
        if term.modulator == "one":
            return f"{who} is {_fmt(term, value, signed=True)}{err} of nominal{tail}"
        verb = "grows" if value > 0 else "shrinks"
        return f"{who} {verb} {words}, {_fmt(term, abs(value))} {_per(term)}{err}{tail}"
    if term.channel == "crab":
        return (
            f"the robot translates at an angle to its heading that changes {words}: "
            f"{_fmt(term, value, signed=True)} {_per(term)}{err}{tail}"
        )
    verb = "over-rotates" if value > 0 else "under-rotates"
    return f"the robot {verb} {words}: {_fmt(term, abs(value))} {_per(term)}{err}{tail}"


def operating_phrase(name: str, change: float, operating: float) -> str:
    """What term ``name`` does at the data's operating range, in words: the change ``change``
    it makes (a fraction of its channel, radians of crab) at ``operating``, the 95th percentile
    of its modulator's magnitude, e.g. "at |a| = 0.42 m/s² (95th percentile) it changes the
    left wheel's travel by 0.31 %"."""
    term = _BY_NAME[name]
    unit = _MOD_UNIT[term.modulator]
    where = (
        f"at |{term.modulator}| = {operating:.3g} {unit} (95th percentile of the data)"
        if unit
        else "wherever it acts"
    )
    if term.channel == "crab":
        what = f"turns the direction of travel by {math.degrees(change):.3g}°"
    elif term.wheel:
        what = f"changes the {term.channel} wheel's travel by {100 * change:.3g} %"
    else:
        what = f"changes the yaw increment by {100 * change:.3g} %"
    return f"{where} it {what}"


def _per(term: Term) -> str:
    unit = _MOD_UNIT[term.modulator]
    if not unit:
        return "" if term.modulator in ("one",) else "per unit"
    return f"per {unit}" if term.modulator != "time" else "per second"


def _fmt(term: Term, value: float, *, signed: bool = False) -> str:
    if term.channel == "crab":
        return f"{math.degrees(value):+.3g}°" if signed else f"{math.degrees(value):.3g}°"
    return f"{100 * value:+.3g} %" if signed else f"{100 * value:.3g} %"


# ---------------------------------------------------------------------------- modulators
def wheel_modulator(
    modulator: str, speed: FloatArray, accel: FloatArray, angle: FloatArray, time: FloatArray
) -> FloatArray:
    """A wheel modulator per interval and wheel (n, 2); ``speed`` the wheels' signed rim speeds
    [m/s], ``accel`` d|v|/dt [m/s²], ``angle`` their angles [rad], ``time`` (n,) [s]."""
    if modulator == "one":
        return np.ones_like(speed)
    if modulator == "speed":
        return np.abs(speed)
    if modulator == "speed2":
        return np.square(speed)
    if modulator == "direction":
        return np.sign(speed)
    if modulator == "accel":
        return accel
    if modulator in ("sin1", "cos1", "sin2", "cos2"):
        k = 1.0 if modulator.endswith("1") else 2.0
        return np.sin(k * angle) if modulator.startswith("sin") else np.cos(k * angle)
    if modulator == "time":
        return np.repeat(np.asarray(time, dtype=float)[:, None], 2, axis=1)
    raise KeyError(modulator)


def spin_share(travel: FloatArray) -> FloatArray:
    """The ``spin`` modulator 1/(1 + λ²) per interval (n,) of wheel travels (or rim speeds)
    ``travel`` (n, 2), λ = (d_L + d_R)/(d_R − d_L): (d_R − d_L)²/((d_R − d_L)² + (d_L + d_R)²),
    0 where neither wheel moved."""
    d = travel[:, 1] - travel[:, 0]
    s = travel[:, 0] + travel[:, 1]
    d2 = d * d
    total = d2 + s * s
    share: FloatArray = np.divide(d2, total, out=np.zeros_like(d2), where=total > 0.0)
    return share


def body_modulator(
    modulator: str,
    v: FloatArray,
    omega: FloatArray,
    time: FloatArray,
    travel: FloatArray | None = None,
) -> FloatArray:
    """A body modulator per interval (n,); ``v`` [m/s], ``omega`` [rad/s], ``time`` [s],
    ``travel`` (n, 2) the wheels' travel [m] (needed by ``spin`` only)."""
    if modulator == "spin":
        if travel is None:
            raise ValueError("the spin modulator needs the wheels' travel")
        return spin_share(travel)
    if modulator == "one":
        return np.ones_like(v)
    if modulator == "speed":
        return np.abs(v)
    if modulator == "speed2":
        return np.square(v)
    if modulator == "rate":
        return np.abs(omega)
    if modulator == "lateral":
        return np.abs(v * omega)
    if modulator == "lateral_signed":
        return v * omega
    if modulator == "direction":
        return np.sign(v)
    if modulator == "time":
        return np.asarray(time, dtype=float)
    raise KeyError(modulator)


# ---------------------------------------------------------------------------- the effect
def _parameter(term: Term) -> Parameter:
    bound = 1e3 * term.scale
    if term.modulator == "one" and term.channel != "crab":
        bound = 0.5
    return Parameter(
        term.name,
        term.unit,
        0.0,
        -bound,
        bound,
        term.scale,
        f"{term.channel} × {term.modulator}",
    )


class DiscoveredTerms(Effect):
    """A set of grammar terms as one effect (``discovered`` stores them in one TOML table).

    The registered ``discovered`` effect holds every term; fitting a subset uses an instance
    with only those terms as its parameters, which reads and writes the same table.
    """

    name = "discovered"
    summary = "terms of the odometry-error grammar found by sparse regression on the residuals"
    reveals = "whatever the terms' modulators vary: see each term's sentence in the report"
    confounded = (
        "a term names a channel and a modulator, not a mechanism: the sentence gives the likely "
        "mechanisms; an experiment that varies the modulator alone confirms it"
    )

    parameters = tuple(_parameter(t) for t in TERMS)

    def __init__(self, terms: Sequence[str] | None = None) -> None:
        names = list(terms) if terms is not None else [t.name for t in TERMS]
        unknown = [n for n in names if n not in _BY_NAME]
        if unknown:
            raise ValueError(f"unknown grammar terms {unknown}; known: {list(_BY_NAME)}")
        self.terms = tuple(_BY_NAME[n] for n in names)
        self.parameters = tuple(_parameter(t) for t in self.terms)  # type: ignore[misc]

    def read(self, spec: SpecView) -> dict[str, float]:
        stored = spec.effect_values(self.name) or {}
        return {p.name: float(stored.get(p.name, 0.0)) for p in self.parameters}

    def write(self, spec: Spec, values: Mapping[str, float]) -> Spec:
        merged = dict(spec.effect_values(self.name) or {})
        merged.update(self.validate(values))
        nonzero = {k: v for k, v in merged.items() if v != 0.0}
        return spec.store_effect_table(self.name, nonzero or None)

    @classmethod
    def validate(cls, values: Mapping[str, Any], *, source: str | None = None) -> dict[str, float]:
        """Check the given terms' names and ranges against the whole grammar; returns only the
        given terms (a stored table holds its non-zero terms only)."""
        checked = super().validate(values, source=source)
        return {k: checked[k] for k in values}

    @classmethod
    def is_absent(cls, values: Mapping[str, float]) -> bool:
        return all(float(v) == 0.0 for v in values.values())

    # ------------------------------------------------------------------ replay
    stacked_replay = True  # sample by sample; the acceleration modulator run by run

    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        # Compiled, bit-identical to the modulators' numpy expressions (term_replay.py).
        if stage not in ("transmission", "body"):
            return
        wheel = stage == "transmission"
        terms = [
            (_BY_NAME[k], float(v))
            for k, v in values.items()
            if v != 0.0 and k in _BY_NAME and _BY_NAME[k].wheel == wheel
        ]
        if not terms:
            return
        coefficients = np.array([c for _, c in terms])
        if wheel:
            sin1, cos1, sin2, cos2 = (
                _harmonic(arrays, m, terms) for m in ("sin1", "cos1", "sin2", "cos2")
            )
            arrays.wheel = replay_wheel_terms(
                np.asarray(arrays.wheel, dtype=np.float64),
                arrays.radius,
                arrays.dt,
                sin1,
                cos1,
                sin2,
                cos2,
                arrays.time,
                np.array([0 if t.channel == "left" else 1 for t, _ in terms]),
                np.array([_WHEEL_CODES[t.modulator] for t, _ in terms]),
                coefficients,
                run_bounds(arrays),
            )
        else:
            spin = _NO_SPIN
            if any(t.modulator == "spin" for t, _ in terms):
                if arrays.travel.shape[0] != arrays.dt.shape[0]:
                    raise ValueError("the spin modulator needs the wheels' travel per interval")
                spin = spin_share(np.asarray(arrays.travel, dtype=np.float64))
            arrays.crab, arrays.dtheta = replay_body_terms(
                np.asarray(arrays.ds, dtype=np.float64),
                np.asarray(arrays.dtheta, dtype=np.float64),
                np.asarray(arrays.crab, dtype=np.float64),
                arrays.dt,
                arrays.time,
                spin,
                np.array([t.channel == "yaw" for t, _ in terms]),
                np.array([_BODY_CODES[t.modulator] for t, _ in terms]),
                coefficients,
            )

    # ------------------------------------------------------------------ world
    @classmethod
    def skid_steer_refusal(cls, values: Mapping[str, float]) -> str:
        crab = sorted(k for k, v in values.items() if k.startswith("crab_") and float(v) != 0.0)
        if not crab:
            return ""
        return (
            f"its crab terms ({', '.join(crab)}) turn the contacts' no-slip velocity sideways, "
            "and a skid-steer robot's contacts take only their side's speed along the heading"
        )

    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        coefficients = np.zeros((values.shape[0], len(TERMS)))
        index = {t.name: k for k, t in enumerate(TERMS)}
        for j, p in enumerate(self.parameters):
            coefficients[:, index[p.name]] = values[:, j]
        if not np.any(coefficients):
            return None
        return _DiscoveredHook(world, coefficients)


class Discovered(DiscoveredTerms):
    """The registered effect: every term of the grammar (:data:`TERMS`)."""

    def __init__(self) -> None:
        super().__init__(None)


_WHEEL_CODES = {m: k for k, m in enumerate(WHEEL_MODULATORS)}
_BODY_CODES = {m: k for k, m in enumerate(BODY_MODULATORS)}
_NO_HARMONIC = np.zeros((0, 2))
_NO_SPIN = np.zeros(0)


def _harmonic(
    arrays: ReplayArrays, modulator: str, terms: Sequence[tuple[Term, float]]
) -> FloatArray:
    """The wheel-angle modulator ``modulator`` (``sin1``, ``cos2``, …) per interval and wheel
    (n, 2) if one of ``terms`` has it (else an empty array): from ``arrays.memo`` while the
    angles are the ones it was computed from (they depend on the run alone), else computed by
    numpy and kept there."""
    if all(t.modulator != modulator for t, _ in terms):
        return _NO_HARMONIC
    key = f"discovered.{modulator}"
    held = arrays.memo.get(key)
    if held is not None and held[0] is arrays.angle:
        return held[1]
    k = 1.0 if modulator.endswith("1") else 2.0
    angle = np.asarray(arrays.angle, dtype=np.float64)
    value = np.sin(k * angle) if modulator.startswith("sin") else np.cos(k * angle)
    arrays.memo[key] = (arrays.angle, value)
    return value


class _DiscoveredHook(WorldHook):
    """Applies the terms per substep: wheel channels to the motor rotation (transmission),
    body channels to the contact velocities (shape)."""

    has_transmission = True
    has_shape = True

    def __init__(self, world: WorldView, coefficients: FloatArray) -> None:
        self.world = world
        nw = len(WHEEL_MODULATORS)
        nb = len(BODY_MODULATORS)
        self.wheel = np.ascontiguousarray(coefficients[:, : 2 * nw].reshape(-1, 2, nw))
        self.body = np.ascontiguousarray(coefficients[:, 2 * nw :].reshape(-1, 2, nb))
        self.previous = np.zeros((coefficients.shape[0], 2))  # |v| of the last substep [m/s]
        self.has_wheel = bool(np.any(self.wheel))
        self.has_body = bool(np.any(self.body))

    def reset(self, indices: NDArray[np.intp]) -> None:
        self.previous[indices] = 0.0

    def transmission(self, motor_step: FloatArray) -> None:
        if self.has_wheel:
            w = self.world
            _wheel_terms(
                motor_step,
                w.true_radius,
                w.wheel_angle,
                w.substep,
                w.time,
                self.wheel,
                self.previous,
            )

    def shape(self, world: WorldView, h: float) -> None:
        if self.has_body:
            _body_terms(
                world.ground_velocity, world.rim_speed, world.half_track, world.time, self.body
            )


@kernel
def _wheel_terms(
    motor_step: FloatArray,
    radius: FloatArray,
    angle: FloatArray,
    h: float,
    time: float,
    coef: FloatArray,
    previous: FloatArray,
) -> None:
    for i in range(motor_step.shape[0]):
        for w in range(2):
            step = motor_step[i, w]
            v = step * radius[i, w] / h
            speed = math.fabs(v)
            accel = (speed - previous[i, w]) / h
            previous[i, w] = speed
            phi = angle[i, w] - 0.5 * step
            direction = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
            mods = (
                1.0,
                speed,
                v * v,
                direction,
                accel,
                math.sin(phi),
                math.cos(phi),
                math.sin(2.0 * phi),
                math.cos(2.0 * phi),
                time,
            )
            factor = 1.0
            for k in range(10):
                factor += coef[i, w, k] * mods[k]
            motor_step[i, w] = step * factor


@kernel
def _body_terms(
    ground_v: FloatArray, rim: FloatArray, half_track: FloatArray, time: float, coef: FloatArray
) -> None:
    for i in range(ground_v.shape[0]):
        v = 0.5 * (rim[i, 0] + rim[i, 1])
        omega = (rim[i, 1] - rim[i, 0]) / (2.0 * half_track[i])
        direction = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
        d = rim[i, 1] - rim[i, 0]
        s = rim[i, 0] + rim[i, 1]
        total = d * d + s * s
        spin = d * d / total if total > 0.0 else 0.0
        mods = (
            1.0,
            math.fabs(v),
            v * v,
            math.fabs(omega),
            math.fabs(v * omega),
            v * omega,
            direction,
            time,
            spin,
        )
        crab = 0.0
        yaw = 1.0
        for k in range(9):
            crab += coef[i, 0, k] * mods[k]
            yaw += coef[i, 1, k] * mods[k]
        mx = 0.5 * (ground_v[i, 0, 0] + ground_v[i, 1, 0])
        my = 0.5 * (ground_v[i, 0, 1] + ground_v[i, 1, 1])
        c = math.cos(crab)
        s = math.sin(crab)
        rx = c * mx - s * my
        ry = s * mx + c * my
        for w in range(2):
            ground_v[i, w, 0] = rx + yaw * (ground_v[i, w, 0] - mx)
            ground_v[i, w, 1] = ry + yaw * (ground_v[i, w, 1] - my)

"""Robot specifications: what the odometry *believes* versus what the hardware *is*.

A differential-drive robot's dead-reckoning drifts because its nominal parameters (the ones
programmed into the odometry) differ from the true, physical ones. Borenstein & Feng 1994
(the UMBmark report, §2.3 and §6) name the dominant systematic errors:

* ``E_d = D_R / D_L`` — the ratio of the true right and left effective wheel diameters;
* ``E_b = b_actual / b_nominal`` — the wheelbase error;
* ``E_s = D_a / D_nominal`` — the scaling error of the mean diameter (solderspot 2014).

:class:`RobotSpec` keeps the nominal parameters and the true ones side by side. The physics uses
the true values; :class:`odomgym.odometry.calibration.Odometry` sees only the nominal ones (plus
whatever :class:`odomgym.odometry.calibration.Calibration` a calibrator found).

All lengths are metres, masses kilograms, speeds m/s, accelerations m/s².
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from odomgym.effects import get_effect
from odomgym.errors import (
    SpecError,
    load_named,
    locate_key,
    plain_number,
    refuse_stray_keys,
    require_positive,
    require_range,
)
from odomgym.io import atomic_write_text

__all__ = ["PRESETS", "SKID_STEER_PRESETS", "EffectTable", "RobotSpec", "load_robot"]

EffectTable = tuple[tuple[str, tuple[tuple[str, float], ...]], ...]
"""Effects of a spec: ((name, ((parameter, value), ...)), ...), sorted by name."""


def _given(value: float | None, default: float) -> float:
    """``value`` unless it is ``None`` (then ``default``), unconverted so that validation can
    name a non-number."""
    return default if value is None else value


def _normalise_effects(effects: Any) -> EffectTable:
    """Accept a mapping {name: {parameter: value}} or the stored tuple form; drop empty ones."""
    items = effects.items() if isinstance(effects, Mapping) else effects
    table: dict[str, tuple[tuple[str, float], ...]] = {}
    for name, values in items:
        pairs = values.items() if isinstance(values, Mapping) else values
        table[str(name)] = tuple(sorted((str(k), float(v)) for k, v in pairs))
    return tuple(sorted(table.items()))


def _effects_form(got: str) -> str:
    """The refusal of an ``effects`` argument of the wrong shape."""
    return (
        "effects must be a mapping {name: {parameter: value}} of the catalogue's effects "
        f"(odomgym.effects.EFFECTS), got {got}"
    )


def _effects_argument(effects: Any) -> tuple[EffectTable, list[tuple[str, dict[str, float]]]]:
    """The constructor's ``effects``, checked: (the table of the effects kept in
    :attr:`RobotSpec.effects`, the geometric ones given in a mapping, to be written into the
    true geometry). Every name must be registered and every value in its range; a geometric
    effect in the stored tuple form is refused (that form holds the table only).

    Why: the constructor stored whatever it was given. A backlash of NaN stopped the World's
    robot without a word, a wheel toe of 3 rad (the range is ±0.2) drove it backwards, a
    misspelt name was ignored, and a geometric effect was stored but not applied, so the spec
    saved and loaded back was another robot."""
    if isinstance(effects, tuple):
        return _stored_table(effects), []
    return _check_effects(effects)


_STORED: dict[str, EffectTable] = {}
_STORED_MAX = 256


def _stored_table(effects: tuple[Any, ...]) -> EffectTable:
    """:func:`_check_effects` of a table in the stored tuple form, remembered: every
    ``dataclasses.replace`` of a spec passes its table again (a fit builds thousands of specs
    from a few tables), and checking it each time cost a third of a spec's construction.

    Keyed by the table's ``repr``, not the tuple: tuples compare ``-0.0 == 0.0`` and
    ``True == 1``, so a tuple key would hand a spec the table another call built, and what it
    stores would depend on the process's history."""
    key = repr(effects)
    table = _STORED.get(key)
    if table is None:
        table, _ = _check_effects(effects)
        if len(_STORED) >= _STORED_MAX:
            _STORED.clear()
        _STORED[key] = table
    return table


def _check_effects(effects: Any) -> tuple[EffectTable, list[tuple[str, dict[str, float]]]]:
    """:func:`_effects_argument`'s checks, uncached."""
    if isinstance(effects, str | bytes) or not isinstance(effects, Mapping | tuple | list):
        raise SpecError(_effects_form(type(effects).__name__), field="effects")
    given = isinstance(effects, Mapping)
    try:
        items = (
            list(effects.items())
            if isinstance(effects, Mapping)
            else [tuple(item) for item in effects]
        )
        if not all(len(item) == 2 for item in items):
            raise TypeError
        entries = [
            (str(name), {key: plain_number(value) for key, value in dict(values).items()})
            for name, values in items
        ]
    except (TypeError, ValueError):
        raise SpecError(_effects_form(repr(effects)[:60]), field="effects") from None
    table: dict[str, dict[str, float]] = {}
    geometric: list[tuple[str, dict[str, float]]] = []
    for name, values in entries:
        effect = get_effect(name)
        clean = effect.validate(values)  # every value a finite number in its range
        if effect.in_table:
            table[name] = {str(k): clean[str(k)] for k in values}  # the given keys only
        elif given:
            geometric.append((name, clean))
        else:
            raise SpecError(
                f"effects.{name} lives in the true diameters and wheelbase, not in the effects "
                "table: give effects as a mapping (it is then written there) or use "
                "RobotSpec.apply_effect",
                field=f"effects.{name}",
            )
    return _normalise_effects(table), geometric


ROBOT_RANGES: dict[str, tuple[float, float]] = {
    # What a wheeled mobile robot can physically be; beyond these the physics (a 10-step
    # controller, Chipmunk's solver) is not meant to work, so a spec outside is refused.
    "wheel_diameter": (0.005, 2.0),  # [m]
    "wheelbase": (0.02, 5.0),  # [m]
    "ticks_per_rev": (1.0, 1e7),  # [counts/rev]
    "true_left_diameter": (0.005, 2.0),  # [m]
    "true_right_diameter": (0.005, 2.0),  # [m]
    "true_wheelbase": (0.02, 5.0),  # [m]
    "mass": (0.01, 10_000.0),  # [kg] (the default mass of the smallest robot is 0.04 kg)
    "chassis_length": (0.01, 20.0),  # [m]
    "chassis_width": (0.01, 20.0),  # [m]
    "drive_load_fraction": (1e-3, 1.0),  # [-]
    "max_wheel_speed": (1e-3, 10.0),  # [m/s]
    "max_wheel_accel": (1e-3, 100.0),  # [m/s²]
    "axle_spacing": (0.0, 5.0),  # [m]; 0: one axle (differential drive)
    "com_x": (-5.0, 5.0),  # [m]; the load rule below decides what a robot can carry
    "com_y": (-5.0, 5.0),  # [m]
    "tyre_slip_stiffness": (0.0, 1000.0),  # [-] per unit slip ratio; 0: rigid contacts
    "tyre_cornering_stiffness": (0.0, 1000.0),  # [1/rad]; 0: rigid contacts
}
"""Allowed range [low, high] of each robot key (docs/specs.md, "allowed")."""

TYRE_CORNERING_STIFFNESS = 0.12 * 180.0 / math.pi
"""The skid-steer presets' cornering stiffness per unit load, C_α/N [1/rad]: 0.12 of the load
per degree of slip angle, the middle of the range Gillespie (1992, pp. 347–355) gives for
bias-ply tyres (0.08–0.18; radial 0.11–0.19). Measured on car tyres: no figure for these
robots' tyres is published."""

TYRE_SLIP_STIFFNESS = 20.0
"""The skid-steer presets' longitudinal slip stiffness per unit load, C_κ/N [-]: **assumed**
(a tyre reaching μ = 0.8 of its load at 4 % slip). No published figure was found for these
robots' tyres; docs/skid-steer.md shows how the apparent track's fall with radius depends on
the ratio C_α/C_κ, the one number that sets it."""

TRUE_TO_NOMINAL: tuple[float, float] = (0.5, 2.0)
"""A true diameter or wheelbase lies within this factor of its nominal value [-]: a robot
whose odometry is off by more is not miscalibrated but misdescribed."""


@dataclass(frozen=True, init=False)
class RobotSpec:
    """A differential-drive or skid-steer robot: nominal (believed) and true (hidden) parameters.

    **Which spacing is which.** ``wheelbase`` is the *side-to-side* spacing b of the left and
    right wheels' contact points (Borenstein & Feng's b, whose error is E_b; on a car it would
    be called the track). ``axle_spacing`` is the *front-to-back* spacing a of a skid-steer
    robot's front and rear axles (on a car: the wheelbase). A differential-drive robot has one
    axle: ``axle_spacing = 0``. A skid-steer robot (``axle_spacing > 0``) has two wheels per
    side at (±a/2, ±b/2) from the centre of its four contacts, each side's two wheels driven
    together (one rate, one encoder per side), no casters; it cannot turn without its wheels
    sliding sideways, and its apparent track emerges from the friction of its four contacts
    (:mod:`odomgym.sim.world`).

    Only ``wheel_diameter``, ``wheelbase`` and ``ticks_per_rev`` are required. The true
    parameters and the chassis are optional *arguments* (``float | None``): ``None`` means
    "derive it" — every true parameter defaults to its nominal value (an ideal robot), and the
    chassis defaults scale with the wheelbase. The stored *attributes* are always the resolved
    floats, so the physics, the reports and :meth:`to_dict` never meet ``None``.

    Attributes:
        wheel_diameter: nominal wheel diameter D_n [m] the odometry uses.
        wheelbase: nominal wheelbase b_n [m], distance between the wheel contact points.
        ticks_per_rev: encoder counts per wheel revolution [counts] (may be fractional, e.g. a
            64-count motor encoder behind a 43.7:1 gear gives 2796.8).
        true_left_diameter: true effective left wheel diameter D_L [m] (default D_n).
        true_right_diameter: true effective right wheel diameter D_R [m] (default D_n).
        true_wheelbase: true effective wheelbase b_actual [m] (default b_n).
        mass: chassis mass [kg] (default 60 kg/m² of a 1.3 b_n × 1.3 b_n footprint).
        chassis_length: chassis length along the direction of travel [m] (default 1.3 b_n).
        chassis_width: chassis width [m] (default 1.3 b_n).
        drive_load_fraction: share of the weight carried by the two drive wheels [-]; the rest
            rests on ideal (frictionless) casters. Sets each wheel's normal force and so its
            friction limit μ·N. Default 0.9; a skid-steer robot has no casters: 1.
        axle_spacing: front-to-back spacing a of a skid-steer robot's axles [m] (default 0: a
            differential-drive robot, one axle).
        com_x, com_y: a skid-steer robot's centre of mass ahead of and to the left of the centre
            of its four contacts [m] (default 0). It sets how the weight is shared over the four
            contacts (:meth:`contact_loads`) and is the point whose pose the World reports for
            a skid-steer robot (the body frame of Kozłowski & Pazderski 2004).
        tyre_slip_stiffness, tyre_cornering_stiffness: a skid-steer robot's tyre stiffnesses
            per unit load: the longitudinal force per unit slip ratio, C_κ/N [-], and the
            lateral force per radian of slip angle, C_α/N [1/rad] (default 0 and 0: rigid
            contacts, Coulomb's force from 5 mm/s of slip on). They set how far a contact
            slips before it slides (μ/C of its rim speed) and so how the apparent track moves
            with the turn radius (:func:`odomgym.sim.world.skid_contacts`, docs/skid-steer.md).
        max_wheel_speed: largest wheel rim speed the motor controller will command [m/s].
        max_wheel_accel: acceleration limit of each wheel's velocity controller [m/s²]. A hard
            controller (large value) asks for more force than friction gives, so wheels slip.
        name: a label for tables and plots.
        source: where the numbers come from (free text, for provenance).
        effects: further physical effects from the catalogue (:mod:`odomgym.effects`) and
            their parameters, as ``{name: {parameter: value}}`` (stored as sorted tuples so
            the spec stays hashable); the geometric ones (``wheel_diameter_ratio``,
            ``wheelbase``, ``distance_scale``) live in the true diameters and wheelbase
            instead: given in the mapping, they are written there, after the true fields
            given. Every name and value is checked (a :class:`SpecError` names
            ``effects.NAME.PARAM``). TOML: ``[robot.effects.NAME]`` tables.
    """

    wheel_diameter: float
    wheelbase: float
    ticks_per_rev: float
    true_left_diameter: float
    true_right_diameter: float
    true_wheelbase: float
    mass: float
    chassis_length: float
    chassis_width: float
    drive_load_fraction: float
    max_wheel_speed: float
    max_wheel_accel: float
    axle_spacing: float
    com_x: float
    com_y: float
    tyre_slip_stiffness: float
    tyre_cornering_stiffness: float
    name: str
    source: str
    effects: EffectTable

    def __init__(
        self,
        wheel_diameter: float,
        wheelbase: float,
        ticks_per_rev: float,
        true_left_diameter: float | None = None,
        true_right_diameter: float | None = None,
        true_wheelbase: float | None = None,
        mass: float | None = None,
        chassis_length: float | None = None,
        chassis_width: float | None = None,
        drive_load_fraction: float | None = None,
        max_wheel_speed: float = 0.5,
        max_wheel_accel: float = 0.5,
        axle_spacing: float = 0.0,
        com_x: float = 0.0,
        com_y: float = 0.0,
        tyre_slip_stiffness: float = 0.0,
        tyre_cornering_stiffness: float = 0.0,
        name: str = "robot",
        source: str = "",
        effects: EffectTable | Mapping[str, Mapping[str, float]] = (),
    ) -> None:
        # Written out rather than generated by @dataclass, so that the optional arguments can
        # be ``float | None`` while the attributes are the resolved floats. The derived
        # defaults need the nominal wheelbase, which a field default cannot see.
        # A non-number or out-of-range wheelbase gives NaN defaults here (no overflow in the
        # default mass of a 1e154 m robot) and is named by validate().
        wheelbase, axle_spacing = plain_number(wheelbase), plain_number(axle_spacing)  # type: ignore[assignment]
        low, high = ROBOT_RANGES["wheelbase"]
        sensible = isinstance(wheelbase, int | float) and low <= wheelbase <= high
        chassis = 1.3 * wheelbase if sensible else math.nan
        skid = isinstance(axle_spacing, int | float) and axle_spacing > 0.0
        # A skid-steer body spans its axles too (a non-number spacing is named by validate()).
        length = max(chassis, 1.2 * axle_spacing) if skid else chassis
        values: dict[str, object] = {
            "wheel_diameter": wheel_diameter,
            "wheelbase": wheelbase,
            "ticks_per_rev": ticks_per_rev,
            "true_left_diameter": _given(true_left_diameter, wheel_diameter),
            "true_right_diameter": _given(true_right_diameter, wheel_diameter),
            "true_wheelbase": _given(true_wheelbase, wheelbase),
            # ~ 60 kg/m² of footprint: a light indoor robot when nothing better is known.
            "mass": _given(mass, 60.0 * chassis**2),
            "chassis_length": _given(chassis_length, length),
            "chassis_width": _given(chassis_width, chassis),
            "drive_load_fraction": _given(drive_load_fraction, 1.0 if skid else 0.9),
            "max_wheel_speed": max_wheel_speed,
            "max_wheel_accel": max_wheel_accel,
            "axle_spacing": axle_spacing,
            "com_x": com_x,
            "com_y": com_y,
            "tyre_slip_stiffness": tyre_slip_stiffness,
            "tyre_cornering_stiffness": tyre_cornering_stiffness,
            "name": name,
            "source": source,
        }
        values = {key: plain_number(value) for key, value in values.items()}
        table, geometric = _effects_argument(effects)
        values["effects"] = table
        for key, value in values.items():
            object.__setattr__(self, key, value)
        self.validate()
        if geometric:
            # Written into the true geometry, after the fields given (as from_dict does).
            spec = dataclasses.replace(self)
            for name, given in geometric:
                spec = spec.apply_effect(name, given)
            for key in ("true_left_diameter", "true_right_diameter", "true_wheelbase"):
                object.__setattr__(self, key, getattr(spec, key))

    # ------------------------------------------------------------------ validation
    def validate(self, source: str | None = None) -> None:
        """Raise :class:`SpecError` naming the first invalid field."""
        for key in ("name", "source"):
            if not isinstance(getattr(self, key), str):
                raise SpecError(
                    f"{key} must be a string, got {type(getattr(self, key)).__name__}",
                    field=key,
                    source=source,
                )
        for name, (low, high) in ROBOT_RANGES.items():
            require_range(name, getattr(self, name), low, high, source=source)
        for true, nominal in (
            ("true_left_diameter", "wheel_diameter"),
            ("true_right_diameter", "wheel_diameter"),
            ("true_wheelbase", "wheelbase"),
        ):
            ratio = float(getattr(self, true)) / float(getattr(self, nominal))
            if not TRUE_TO_NOMINAL[0] <= ratio <= TRUE_TO_NOMINAL[1]:
                raise SpecError(
                    f"{true} must lie within {TRUE_TO_NOMINAL[0]}–{TRUE_TO_NOMINAL[1]} × "
                    f"{nominal} ({getattr(self, nominal)}), got {getattr(self, true)!r}",
                    field=true,
                    source=source,
                )
        if self.chassis_width < 0.5 * self.true_wheelbase:
            raise SpecError(
                "chassis_width must be at least half the wheelbase, got "
                f"{self.chassis_width} < {0.5 * self.true_wheelbase}",
                field="chassis_width",
                source=source,
            )
        if self.is_skid_steer:
            self._validate_skid(source)
        else:
            for keys, reason in (
                (("com_x", "com_y"), "centre of mass is at its axle midpoint"),
                (
                    ("tyre_slip_stiffness", "tyre_cornering_stiffness"),
                    "wheels are Chipmunk's capped pivot joints",
                ),
            ):
                for key in keys:
                    if getattr(self, key) != 0.0:
                        raise SpecError(
                            f"{key} applies to skid-steer robots (axle_spacing > 0); a "
                            f"differential-drive robot's {reason}",
                            field=key,
                            source=source,
                        )

    def _validate_skid(self, source: str | None) -> None:
        """A skid-steer body holds its wheels, has no casters, and loads every wheel.

        The body must hold the *nominal* track: a skid-steer robot's E_b is the error of an
        apparent track (its odometry's expansion factor, 1.2–1.9 on real robots;
        docs/skid-steer.md), which a diagnosis fits and which may take the true track past the
        body."""
        if self.wheelbase > self.chassis_width:
            raise SpecError(
                f"the track (wheelbase {self.wheelbase} m) is wider than the body "
                f"(chassis_width {self.chassis_width} m): give the body's full width, wheels "
                "included",
                field="wheelbase",
                source=source,
            )
        if self.axle_spacing > self.chassis_length:
            raise SpecError(
                f"axle_spacing {self.axle_spacing} m is longer than the body (chassis_length "
                f"{self.chassis_length} m)",
                field="axle_spacing",
                source=source,
            )
        if self.drive_load_fraction != 1.0:
            raise SpecError(
                "a skid-steer robot has no casters: all its weight rests on its four driven "
                f"wheels (drive_load_fraction 1), got {self.drive_load_fraction}",
                field="drive_load_fraction",
                source=source,
            )
        if (self.tyre_slip_stiffness > 0.0) != (self.tyre_cornering_stiffness > 0.0):
            key = (
                "tyre_slip_stiffness"
                if self.tyre_slip_stiffness == 0.0
                else ("tyre_cornering_stiffness")
            )
            raise SpecError(
                f"{key} is 0 while the other tyre stiffness is not: give both (elastic tyres) "
                "or neither (rigid contacts)",
                field=key,
                source=source,
            )
        x = abs(self.com_x) / self.axle_spacing
        y = abs(self.com_y) / self.true_wheelbase
        if x + y >= 0.5:
            key = "com_x" if x >= y else "com_y"
            raise SpecError(
                f"a wheel without load: with the centre of mass at ({self.com_x}, {self.com_y}) "
                "m the weight-sharing rule (equal springs, see contact_loads) leaves a wheel "
                f"with none; |com_x|/a + |com_y|/b must stay below 1/2, got {x + y:.3g}",
                field=key,
                source=source,
            )

    # ------------------------------------------------------------------ drive geometry
    @property
    def is_skid_steer(self) -> bool:
        """True for a four-wheel skid-steer robot (``axle_spacing > 0``)."""
        return float(self.axle_spacing) > 0.0

    @property
    def drive(self) -> str:
        """``"skid-steer"`` or ``"differential"``."""
        return "skid-steer" if self.is_skid_steer else "differential"

    def contacts(self) -> list[tuple[int, float, float]]:
        """Each wheel contact as (side, x, y) [m] in the frame of the point whose pose the World
        reports: side 0 left, 1 right.

        Differential drive: two contacts at (0, ±b/2) from the axle midpoint. Skid-steer: four,
        at (±a/2 − com_x, ±b/2 − com_y) from the centre of mass (front first)."""
        half = 0.5 * float(self.true_wheelbase)
        if not self.is_skid_steer:
            return [(0, 0.0, half), (1, 0.0, -half)]
        ahead = 0.5 * float(self.axle_spacing)
        return [
            (side, x - self.com_x, y - self.com_y)
            for side, y in ((0, half), (1, -half))
            for x in (ahead, -ahead)
        ]

    def contact_loads(self, gravity: float = 9.81) -> list[float]:
        """Normal force on each contact of :meth:`contacts`, in its order [N].

        Differential drive: ``drive_load_fraction`` of the weight shared equally by the two
        drive wheels (the rest on frictionless casters). Skid-steer: four contacts under a rigid
        body carry the weight in a statically indeterminate way; the rule here is equal,
        linear vertical compliance at each wheel (a suspension of four equal springs, the
        chassis rigid), under which the loads are the plane N_i = W·(1/4 + x_c·x_i/a² +
        y_c·y_i/b²) for wheels at (x_i, y_i) = (±a/2, ±b/2) and the centre of mass at (x_c, y_c):
        the least-energy distribution that balances the weight and its two moments. Static:
        the load transfer of acceleration and of a turn's centripetal force is not modelled."""
        weight = float(self.mass) * gravity
        if not self.is_skid_steer:
            share = 0.5 * weight * float(self.drive_load_fraction)
            return [share, share]
        a, b = float(self.axle_spacing), float(self.true_wheelbase)
        return [
            weight
            * (0.25 + self.com_x * (x + self.com_x) / a**2 + self.com_y * (y + self.com_y) / b**2)
            for _, x, y in self.contacts()
        ]

    # ------------------------------------------------------------------ systematic errors
    @property
    def e_d(self) -> float:
        """E_d = D_R / D_L, the wheel-diameter ratio (Borenstein & Feng 1994, Eq. 6.24) [-]."""
        return float(self.true_right_diameter) / float(self.true_left_diameter)

    @property
    def e_b(self) -> float:
        """E_b = b_actual / b_nominal, wheelbase error (Borenstein & Feng 1994, Eq. 6.29) [-]."""
        return float(self.true_wheelbase) / self.wheelbase

    @property
    def e_s(self) -> float:
        """E_s = D_a / D_n, the scaling error of the mean wheel diameter (solderspot 2014) [-]."""
        mean = 0.5 * (float(self.true_left_diameter) + float(self.true_right_diameter))
        return mean / self.wheel_diameter

    def with_errors(
        self, e_d: float | None = None, e_b: float | None = None, e_s: float | None = None
    ) -> RobotSpec:
        """Return a copy whose true parameters carry the given systematic errors.

        Unspecified errors keep their current values. The split of the mean diameter
        D_a = E_s·D_n into D_L and D_R follows Borenstein & Feng 1994, Eqs. 6.31–6.32:
        D_L = 2/(E_d + 1)·D_a, D_R = 2/(1/E_d + 1)·D_a.
        """
        ed = self.e_d if e_d is None else require_positive("e_d", e_d)
        eb = self.e_b if e_b is None else require_positive("e_b", e_b)
        es = self.e_s if e_s is None else require_positive("e_s", e_s)
        mean = es * self.wheel_diameter
        return dataclasses.replace(
            self,
            true_left_diameter=2.0 / (ed + 1.0) * mean,
            true_right_diameter=2.0 / (1.0 / ed + 1.0) * mean,
            true_wheelbase=eb * self.wheelbase,
        )

    def ideal(self) -> RobotSpec:
        """Return a copy whose true parameters equal the nominal ones (no systematic error)."""
        return self.with_errors(1.0, 1.0, 1.0)

    # ------------------------------------------------------------------ effects
    def effect_values(self, name: str) -> dict[str, float] | None:
        """The stored parameters of effect ``name``, or None if the spec does not carry it."""
        for key, values in self.effects:
            if key == name:
                return dict(values)
        return None

    def apply_effect(
        self, name: str, values: Mapping[str, float] | None, *, source: str | None = None
    ) -> RobotSpec:
        """A copy carrying effect ``name`` with ``values`` (None or absent values remove it).

        The one way a value reaches a spec: the registered effect validates ``values`` (a
        :class:`SpecError` names ``effects.NAME.PARAM`` and ``source``) and writes them where it
        keeps them — the true geometry for ``wheel_diameter_ratio``, ``wheelbase`` and
        ``distance_scale``, a table in :attr:`effects` for the others.
        """
        effect = get_effect(name, source=source)
        if values is None:
            values = effect.absent_values()
        effect.validate(values, source=source)
        return effect.write(self, values)

    def store_effect_table(self, name: str, values: Mapping[str, float] | None) -> RobotSpec:
        """A copy whose table for effect ``name`` holds ``values`` as given (None removes it).

        Storage only, for :meth:`odomgym.effects.Effect.write` (which validated them); use
        :meth:`apply_effect`.
        """
        table = {k: dict(v) for k, v in self.effects if k != name}
        if values is not None:
            table[name] = dict(values)
        return dataclasses.replace(self, effects=_normalise_effects(table))

    def effect_dict(self) -> dict[str, dict[str, float]]:
        """The stored effects as ``{name: {parameter: value}}``."""
        return {name: dict(values) for name, values in self.effects}

    # ------------------------------------------------------------------ derived physics
    @property
    def moment_of_inertia(self) -> float:
        """Chassis yaw moment of inertia [kg·m²], a uniform box m·(l² + w²)/12."""
        length = float(self.chassis_length)
        width = float(self.chassis_width)
        return float(self.mass) * (length**2 + width**2) / 12.0

    @property
    def metres_per_tick(self) -> float:
        """Nominal travel of one encoder count, π·D_n / counts_per_rev [m]."""
        return math.pi * self.wheel_diameter / self.ticks_per_rev

    # ------------------------------------------------------------------ TOML
    def to_dict(self) -> dict[str, Any]:
        """All fields as a plain dict (TOML-ready; the true parameters and chassis resolved,
        never ``None``; effects as ``{name: {parameter: value}}``, omitted when there are
        none)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        out.pop("effects")
        if not self.is_skid_steer:  # one axle: the skid-steer fields would only be zeros
            for key in (
                "axle_spacing",
                "com_x",
                "com_y",
                "tyre_slip_stiffness",
                "tyre_cornering_stiffness",
            ):
                out.pop(key)
        if self.effects:
            out["effects"] = self.effect_dict()
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, path: Path | None = None) -> RobotSpec:
        """Build from a mapping (e.g. parsed TOML), with errors naming field, file and line.

        Accepts either a flat table or one under ``[robot]``; ``e_d``/``e_b``/``e_s`` may be
        given instead of the true diameters and wheelbase.
        """
        if not isinstance(data, Mapping):
            raise SpecError(
                f"a robot spec is a table of fields, got {type(data).__name__}",
                field="robot",
                source=str(path) if path else None,
            )
        refuse_stray_keys(data, "robot", path, nested=("effects",))
        table = dict(data.get("robot", data))
        errors = {k: table.pop(k) for k in ("e_d", "e_b", "e_s") if k in table}
        effect_tables = table.pop("effects", {})
        if not isinstance(effect_tables, Mapping) or not all(
            isinstance(v, Mapping) for v in effect_tables.values()
        ):
            raise SpecError(
                "effects must be tables [robot.effects.NAME] of parameter = value",
                field="effects",
                source=locate_key(path, "effects") if path else None,
            )
        known = {f.name for f in dataclasses.fields(cls)}
        for key in table:
            if key not in known:
                where = locate_key(path, key) if path else None
                raise SpecError(
                    f"unknown robot field {key!r}; known fields: {', '.join(sorted(known))}",
                    field=key,
                    source=where,
                )
        for required in ("wheel_diameter", "wheelbase", "ticks_per_rev"):
            if required not in table:
                raise SpecError(
                    f"missing required field {required!r}",
                    field=required,
                    source=str(path) if path else None,
                )
        for key, value in table.items():
            if key in ("name", "source"):
                if not isinstance(value, str):
                    where = locate_key(path, key) if path else None
                    raise SpecError(f"{key} must be a string", field=key, source=where)
                continue
            where = locate_key(path, key) if path else None
            if key in ROBOT_RANGES:  # the line of the offending key, not just the file
                require_range(key, value, *ROBOT_RANGES[key], source=where)
            else:
                require_positive(key, value, source=where)
        for key, value in errors.items():
            require_positive(key, value, source=locate_key(path, key) if path else None)
        try:
            spec = cls(**table)
        except SpecError as exc:
            raise SpecError(str(exc), field=exc.field, source=str(path) if path else None) from None
        if errors:
            spec = spec.with_errors(errors.get("e_d"), errors.get("e_b"), errors.get("e_s"))
        if effect_tables:
            for name, values in effect_tables.items():
                where = _locate_table(path, f"effects.{name}") if path else None
                effect = get_effect(name, source=where)
                for key in values:
                    if path is not None:
                        where = _locate_table(path, f"effects.{name}", key)
                    effect.validate({key: values[key]}, source=where)
                spec = spec.apply_effect(name, values, source=where)
        return spec

    def save(self, path: str | Path) -> None:
        """Write the spec as TOML, atomically (temp file, then rename)."""
        import tomli_w

        atomic_write_text(Path(path), tomli_w.dumps({"robot": self.to_dict()}))


def _locate_table(path: Path, table: str, key: str | None = None) -> str:
    """``"file:line"`` of the header ``[robot.TABLE]`` (or ``[TABLE]``), or of ``key`` below
    it; falls back to the file name."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError:
        return str(path)
    headers = {f"[robot.{table}]", f"[{table}]"}
    inside = False
    for number, line in enumerate(lines, start=1):
        stripped = line.split("#", 1)[0].strip()
        if stripped.startswith("["):
            if inside and key is not None:
                break
            inside = stripped.replace(" ", "") in headers
            if inside and key is None:
                return f"{path}:{number}"
            continue
        if inside and key is not None and stripped.split("=", 1)[0].strip() == key:
            return f"{path}:{number}"
    return str(path)


def load_robot(spec: str | Path | RobotSpec) -> RobotSpec:
    """Return the preset called ``spec``, or load a robot TOML file (a spec is returned as it
    is).

    Raises :class:`SpecError` for an unknown preset, an unreadable file, malformed TOML (with
    its line) or an invalid field (with its line).
    """
    return load_named(
        spec,
        PRESETS,
        "robot",
        lambda text: (
            f"unknown robot preset {text!r}; presets: {', '.join(sorted(PRESETS))}, "
            "or give a path to a .toml file"
        ),
        RobotSpec.from_dict,
    )


# Presets. Nominal values are what the robot's designers programmed; the true values are the
# *calibrated* ones each paper reports, so a preset carries a realistic systematic error.
PRESETS: dict[str, RobotSpec] = {
    "labmate": RobotSpec(
        name="labmate",
        # wheel radius 75 mm: Borenstein 1995, Table I; Borenstein & Feng 1994, §6.3
        wheel_diameter=0.150,
        wheelbase=0.340,  # b = 340.00 mm nominal: Borenstein & Feng 1994, Fig. 6.5
        ticks_per_rev=2048.0,  # not given in the papers; a 512-line quadrature encoder (assumed)
        # b = 336.17 mm and D_R/D_L = 1.00084 after UMBmark calibration: Borenstein & Feng 1994,
        # Fig. 6.5
        true_wheelbase=0.33617,
        true_left_diameter=0.150 * 2.0 / (1.00084 + 1.0),
        true_right_diameter=0.150 * 2.0 / (1.0 / 1.00084 + 1.0),
        mass=70.0,  # assumed: a TRC LabMate base with payload, ~70 kg
        chassis_length=0.76,  # assumed: LabMate footprint ≈ 0.76 × 0.76 m
        chassis_width=0.76,
        max_wheel_speed=1.0,
        max_wheel_accel=1.0,  # assumed controller limit
        source="Borenstein & Feng 1994, §6.3 and Fig. 6.5; Borenstein 1995, Table I; mass, "
        "footprint, encoder and controller limits assumed",
    ),
    "navbot": RobotSpec(
        name="navbot",
        wheel_diameter=0.032,  # D = 32 mm: solderspot 2014
        wheelbase=0.078,  # b = 78 mm: solderspot 2014
        ticks_per_rev=909.0,  # 909 ticks/rev: solderspot 2014
        mass=0.6,  # assumed: a small hobby robot
        chassis_length=0.12,
        chassis_width=0.10,
        max_wheel_speed=0.3,
        max_wheel_accel=0.5,
        source="solderspot 2014 (b, D, ticks); mass and footprint assumed",
    ),
    "monash": RobotSpec(
        name="monash",
        wheel_diameter=2
        * 0.06890,  # left wheel radius 0.06890 m before calibration: Chong & Kleeman 1997, Table 8
        wheelbase=0.37100,  # B = 0.37100 m before calibration: Chong & Kleeman 1997, Table 8
        ticks_per_rev=4096.0,  # not given in Chong & Kleeman 1997 (assumed)
        true_left_diameter=2 * 0.068662,  # after calibration: Chong & Kleeman 1997, Table 8
        true_right_diameter=2 * 0.068871,
        true_wheelbase=0.36898,
        mass=20.0,  # assumed
        chassis_length=0.45,
        chassis_width=0.45,
        max_wheel_speed=0.5,
        max_wheel_accel=0.5,
        source="Chong & Kleeman 1997, Table 8 (before/after calibration); mass assumed",
    ),
    "optiodom": RobotSpec(
        name="optiodom",
        wheel_diameter=0.084,  # shared/data/optiodom-diff README
        wheelbase=0.200,
        ticks_per_rev=64 * 43.7,  # 64 counts/motor rev × 43.7 gear = 2796.8 counts/wheel rev
        true_wheelbase=0.200628,  # OptiOdom's own calibration, square session 230620202042
        true_right_diameter=0.083714,  # published_results.csv
        true_left_diameter=0.083780,
        mass=3.0,  # assumed
        chassis_length=0.26,
        chassis_width=0.26,
        max_wheel_speed=0.4,
        max_wheel_accel=0.5,
        source="optiodom-diff README and published_results.csv (optiodom, 230620202042)",
    ),
    # Skid-steer robots (axle_spacing > 0): four wheels, two per side, no casters. Nominal equals
    # true (no published calibration); what their odometry gets wrong is the apparent track,
    # which emerges from the four contacts' friction in the World (docs/skid-steer.md).
    "scout2": RobotSpec(
        name="scout2",
        # AgileX Scout 2.0. Wheel radius 0.165 m: westonrobot/scout_ros
        # scout_base/include/scout_base/scout_params.hpp @117f8de (the URDF has 0.16459)
        wheel_diameter=0.330,
        # "Right and left wheels separation 583 mm", "Front and rear wheels separation 498 mm",
        # 930 × 699 mm, 62 kg, ≤ 1.5 m/s: AgileX's specification table (distributor copy,
        # brightenlee/roas_docs _source/scout.rst @3b96c23); track 0.58306 and wheelbase 0.498
        # in scout_params.hpp and agilexrobotics/scout_ros scout_description/urdf/scout_v2.xacro
        wheelbase=0.583,
        axle_spacing=0.498,
        ticks_per_rev=4096.0,  # assumed: the driver reports wheel speeds, not a count per rev
        mass=62.0,
        chassis_length=0.930,
        chassis_width=0.699,
        max_wheel_speed=1.5,
        max_wheel_accel=1.0,  # assumed controller limit
        # Tyres (docs/skid-steer.md, "Tyres"): cornering 0.12 of the load per degree, Gillespie's
        # bias-ply figure; longitudinal slip stiffness assumed (no published value).
        tyre_slip_stiffness=TYRE_SLIP_STIFFNESS,
        tyre_cornering_stiffness=TYRE_CORNERING_STIFFNESS,
        source="AgileX Scout 2.0 specification (roas_docs scout.rst), scout_params.hpp, "
        "scout_v2.xacro; encoder resolution and acceleration limit assumed",
    ),
    "husky": RobotSpec(
        name="husky",
        # Clearpath Husky A200. Wheel radius 0.1651 m (13-in tyres): husky/husky
        # husky_description/urdf/husky_macro.urdf.xacro @da175a7
        wheel_diameter=0.3302,
        # Track 555 mm ("the effective track of the vehicle", Husky A200 User Manual 2011, p. 9;
        # the URDF's 0.5708 would not fit the 670 mm width with 114 mm tyres), wheelbase 512 mm,
        # 990 × 670 mm, 50 kg, 1.0 m/s: Clearpath's specification (roas_docs husky.rst @ee8192f)
        wheelbase=0.555,
        axle_spacing=0.512,
        # 78 000 counts per metre (roas_docs husky.rst) × π × 0.3302 m per revolution
        ticks_per_rev=78_000.0 * math.pi * 0.3302,
        mass=50.0,
        chassis_length=0.990,
        chassis_width=0.670,
        max_wheel_speed=1.0,
        max_wheel_accel=1.0,  # assumed controller limit
        # Tyres (docs/skid-steer.md, "Tyres"): cornering 0.12 of the load per degree, Gillespie's
        # bias-ply figure; longitudinal slip stiffness assumed (no published value).
        tyre_slip_stiffness=TYRE_SLIP_STIFFNESS,
        tyre_cornering_stiffness=TYRE_CORNERING_STIFFNESS,
        source="Clearpath Husky A200 specification (roas_docs husky.rst) and User Manual "
        "(2011) p. 9; husky_macro.urdf.xacro; acceleration limit assumed",
    ),
    "pioneer3at": RobotSpec(
        name="pioneer3at",
        # Adept MobileRobots Pioneer 3-AT. Wheel diameter 0.215 m, wheel centres at y = ±0.197
        # and axles at x = +0.135, −0.134: MobileRobots/amr-ros-config
        # description/urdf/pioneer3at.urdf.xacro @12dc9bc (Wang et al. 2015, Table 2: r =
        # 0.11 m, B = 0.40 m)
        wheel_diameter=0.215,
        wheelbase=0.394,
        axle_spacing=0.269,
        ticks_per_rev=2000.0,  # assumed: a 500-line quadrature encoder behind the gearbox
        # 12 kg, 508 × 497 mm, 0.7 m/s: cyberbotics/webots docs/guide/pioneer-3at.md @0247976
        mass=12.0,
        chassis_length=0.508,
        chassis_width=0.497,
        max_wheel_speed=0.7,
        max_wheel_accel=1.0,  # assumed controller limit
        # Tyres (docs/skid-steer.md, "Tyres"): cornering 0.12 of the load per degree, Gillespie's
        # bias-ply figure; longitudinal slip stiffness assumed (no published value).
        tyre_slip_stiffness=TYRE_SLIP_STIFFNESS,
        tyre_cornering_stiffness=TYRE_CORNERING_STIFFNESS,
        source="amr-ros-config pioneer3at.urdf.xacro (geometry), Webots Pioneer 3-AT guide "
        "(mass, size, speed), Wang et al. 2015; encoder and acceleration limit assumed",
    ),
    "jackal": RobotSpec(
        name="jackal",
        # Clearpath Jackal. Wheel radius 0.098 m, track 0.37559 m, wheelbase 0.262 m, wheels
        # 0.040 m wide: jackal/jackal jackal_description/urdf/jackal.urdf.xacro @15d5403
        wheel_diameter=0.196,
        wheelbase=0.37559,
        axle_spacing=0.262,
        ticks_per_rev=4096.0,  # assumed: no published encoder resolution
        # The URDF's masses: chassis 16.523 kg + 4 wheels × 0.477 kg
        mass=18.431,
        # The wheels' extent, from the same URDF: the chassis box is 0.420 × 0.310 m and the
        # wheels stand outside it (0.262 + 2 × 0.098 m long, 0.37559 + 0.040 m wide)
        chassis_length=0.458,
        chassis_width=0.41559,
        # 2.0 m/s: jackal_control/config/control.yaml @0aef021 (its 20 m/s² acceleration cap is
        # a software limit, far above what the tyres transmit)
        max_wheel_speed=2.0,
        max_wheel_accel=1.0,  # assumed controller limit
        # Tyres (docs/skid-steer.md, "Tyres"): cornering 0.12 of the load per degree, Gillespie's
        # bias-ply figure; longitudinal slip stiffness assumed (no published value).
        tyre_slip_stiffness=TYRE_SLIP_STIFFNESS,
        tyre_cornering_stiffness=TYRE_CORNERING_STIFFNESS,
        source="jackal_description jackal.urdf.xacro (geometry, masses), jackal_control "
        "control.yaml (speed); encoder resolution and acceleration limit assumed",
    ),
}

SKID_STEER_PRESETS: tuple[str, ...] = tuple(n for n, s in PRESETS.items() if s.is_skid_steer)
"""The skid-steer presets (:data:`PRESETS` with ``axle_spacing > 0``), in their order there:
the one list ``bench skid``, the command line's help and the benchmarks read."""

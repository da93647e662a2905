"""The prior over which catalogue effects a differential-drive robot carries, and their sizes.

A robot of the design problem (issue 45) is the OptiOdom-sized robot of
:data:`odomgym.diagnose.generate.NOMINAL_ROBOT` with the three always-present systematic errors
E_s, E_d, E_b (Borenstein & Feng 1994, Eqs. 6.24–6.32) and, each with its own probability, the
catalogue effects ``wheel_toe``, ``turn_skid``, ``backlash`` and ``gt_sensor_offset``
(``docs/effects.md``). The parameter vector θ (:data:`PARAMETERS`, 8 entries) holds every one of
them as an offset from its absent value: θ = 0 is the nominal robot.

**The ranges are fixed here, before the room was measured** (issue 45 forbids moving them to
make the room appear). An optional effect, when present, has a magnitude drawn uniformly
between its detection limit under the rich protocol (``docs/effects.md``, detection-limit
table; :func:`odomgym.diagnose.generate.detection_limit`) and the largest size a real robot was
measured to show (each :class:`EffectPrior` names the source of its upper bound).

The posterior (:mod:`odomgym.design.posterior`) is linear-Gaussian: it replaces each
uniform by the Gaussian of the same mean and variance (:meth:`DesignPrior.gaussian`). Robots are
drawn from the uniforms themselves (:meth:`DesignPrior.draw`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym.diagnose.generate import NOMINAL_ROBOT
from odomgym.effects import EFFECTS
from odomgym.errors import SpecError
from odomgym.robot import RobotSpec

__all__ = [
    "DEFAULT_PRIOR",
    "OPTIONAL_EFFECTS",
    "PARAMETERS",
    "DesignPrior",
    "EffectPrior",
    "GeometryPrior",
    "spec_of",
]

FloatArray = NDArray[np.float64]

#: The entries of θ: (effect, parameter) with θ_j = value − absent value [the parameter's unit].
PARAMETERS: tuple[tuple[str, str], ...] = (
    ("distance_scale", "e_s"),
    ("wheel_diameter_ratio", "e_d"),
    ("wheelbase", "e_b"),
    ("wheel_toe", "angle"),
    ("turn_skid", "gain"),
    ("backlash", "angle"),
    ("gt_sensor_offset", "dx"),
    ("gt_sensor_offset", "dy"),
)
#: The optional effects, in the order of the bits of a subset index (bit k: effect k present).
OPTIONAL_EFFECTS: tuple[str, ...] = ("wheel_toe", "turn_skid", "backlash", "gt_sensor_offset")
ALWAYS = (0, 1, 2)
"""Indices of θ that every robot carries (E_s, E_d, E_b)."""


def columns_of(effect: str) -> tuple[int, ...]:
    """The indices of θ that belong to ``effect``."""
    return tuple(j for j, (name, _) in enumerate(PARAMETERS) if name == effect)


@dataclass(frozen=True)
class GeometryPrior:
    """An always-present error: value − 1 uniform on [−half_range, half_range] [-]."""

    effect: str
    half_range: float
    source: str


@dataclass(frozen=True)
class EffectPrior:
    """An optional catalogue effect: present with ``probability``; if present, its magnitude is
    uniform on [``low``, ``high``] [the parameter's unit], with a random sign if ``two_sided``
    (for the two-parameter ``gt_sensor_offset`` the magnitude is the offset's length and its
    direction is uniform on the circle)."""

    effect: str
    probability: float
    low: float
    high: float
    two_sided: bool
    source: str

    def check(self) -> None:
        """Raise a one-line :class:`SpecError` naming the field if a value is out of range."""
        where = f"prior.{self.effect}"
        if self.effect not in OPTIONAL_EFFECTS:
            raise SpecError(
                f"{where}: unknown optional effect; known: {', '.join(OPTIONAL_EFFECTS)}",
                field=where,
            )
        if not 0.0 <= self.probability <= 1.0:
            raise SpecError(
                f"{where}.probability must lie in [0, 1], got {self.probability}",
                field=f"{where}.probability",
            )
        if not 0.0 <= self.low <= self.high or not math.isfinite(self.high):
            raise SpecError(
                f"{where}.low: need 0 ≤ low ≤ high < ∞, got low={self.low}, high={self.high}",
                field=f"{where}.low",
            )
        for j in columns_of(self.effect):
            effect, name = PARAMETERS[j]
            parameter = next(p for p in EFFECTS[effect].parameters if p.name == name)
            if self.high > max(abs(parameter.low), abs(parameter.high)):
                raise SpecError(
                    f"{where}.high = {self.high} exceeds what the catalogue allows for "
                    f"{effect}.{name} ([{parameter.low}, {parameter.high}] {parameter.unit})",
                    field=f"{where}.high",
                )

    def moments(self) -> tuple[float, float]:
        """Mean and variance of one parameter of the effect when present [unit, unit²]."""
        second = (self.high**3 - self.low**3) / (3.0 * (self.high - self.low or 1.0))
        if self.high == self.low:
            second = self.high**2
        if self.effect == "gt_sensor_offset":
            return 0.0, 0.5 * second  # uniform direction: each of dx, dy carries half
        if self.two_sided:
            return 0.0, second
        mean = 0.5 * (self.low + self.high)
        return mean, second - mean**2


@dataclass(frozen=True)
class DesignPrior:
    """The prior over robots: the always-present errors and the optional effects."""

    geometry: tuple[GeometryPrior, ...]
    effects: tuple[EffectPrior, ...]

    def __post_init__(self) -> None:
        names = [g.effect for g in self.geometry]
        if names != [PARAMETERS[j][0] for j in ALWAYS]:
            raise SpecError(
                f"prior.geometry must be {[PARAMETERS[j][0] for j in ALWAYS]}, got {names}",
                field="prior.geometry",
            )
        for g in self.geometry:
            if not 0.0 < g.half_range < 0.5:
                raise SpecError(
                    f"prior.{g.effect}.half_range must lie in (0, 0.5), got {g.half_range}",
                    field=f"prior.{g.effect}.half_range",
                )
        if [e.effect for e in self.effects] != list(OPTIONAL_EFFECTS):
            raise SpecError(
                f"prior.effects must be {list(OPTIONAL_EFFECTS)} in this order, got "
                f"{[e.effect for e in self.effects]}",
                field="prior.effects",
            )
        for e in self.effects:
            e.check()

    @property
    def subsets(self) -> int:
        """Number of effect subsets (2 to the number of optional effects)."""
        return 1 << len(OPTIONAL_EFFECTS)

    def subset_columns(self, subset: int) -> NDArray[np.intp]:
        """The indices of θ that subset ``subset`` (a bit mask over :data:`OPTIONAL_EFFECTS`)
        estimates: the always-present three and the present effects' parameters."""
        cols = list(ALWAYS)
        for k, effect in enumerate(OPTIONAL_EFFECTS):
            if subset >> k & 1:
                cols.extend(columns_of(effect))
        return np.array(cols, dtype=np.intp)

    def subset_names(self, subset: int) -> tuple[str, ...]:
        """The optional effects subset ``subset`` carries."""
        return tuple(e for k, e in enumerate(OPTIONAL_EFFECTS) if subset >> k & 1)

    def log_subset_prior(self) -> FloatArray:
        """ln π(S) of every subset (:attr:`subsets`,): the effects independent."""
        out = np.zeros(self.subsets)
        for s, k in itertools.product(range(self.subsets), range(len(OPTIONAL_EFFECTS))):
            p = self.effects[k].probability
            q = p if s >> k & 1 else 1.0 - p
            out[s] += math.log(q) if q > 0 else -math.inf
        return out

    def gaussian(self) -> tuple[FloatArray, FloatArray]:
        """Mean (8,) and variance (8,) of every parameter *given its effect is present*: the
        uniforms' first two moments (what the linear-Gaussian posterior uses as its prior)."""
        mean = np.zeros(len(PARAMETERS))
        var = np.zeros(len(PARAMETERS))
        for j, g in zip(ALWAYS, self.geometry, strict=True):
            var[j] = g.half_range**2 / 3.0
        for e in self.effects:
            m, v = e.moments()
            for j in columns_of(e.effect):
                mean[j], var[j] = m, v
        return mean, var

    def draw(self, rng: np.random.Generator) -> tuple[int, FloatArray]:
        """One robot: its subset (bit mask) and θ (8,), from the uniforms."""
        theta = np.zeros(len(PARAMETERS))
        for j, g in zip(ALWAYS, self.geometry, strict=True):
            theta[j] = rng.uniform(-g.half_range, g.half_range)
        subset = 0
        for k, e in enumerate(self.effects):
            present = rng.random() < e.probability
            size = rng.uniform(e.low, e.high)
            sign = 1.0 if rng.random() < 0.5 else -1.0
            angle = rng.uniform(0.0, 2.0 * math.pi)
            if not present:
                continue
            subset |= 1 << k
            cols = columns_of(e.effect)
            if e.effect == "gt_sensor_offset":
                theta[cols[0]], theta[cols[1]] = size * math.cos(angle), size * math.sin(angle)
            else:
                theta[cols[0]] = sign * size if e.two_sided else size
        return subset, theta


#: The prior of issue 45's room measurement, fixed before the room was measured (2026-11-28).
DEFAULT_PRIOR = DesignPrior(
    geometry=(
        GeometryPrior(
            "distance_scale",
            0.02,
            "the benchmark population's E_s ∈ [0.98, 1.02] (odomgym.lab.population; README)",
        ),
        GeometryPrior(
            "wheel_diameter_ratio",
            0.01,
            "the benchmark population's E_d ∈ [0.99, 1.01] (odomgym.lab.population; README)",
        ),
        GeometryPrior(
            "wheelbase",
            0.05,
            "the benchmark population's E_b ∈ [0.95, 1.05] (odomgym.lab.population; README)",
        ),
    ),
    effects=(
        EffectPrior(
            "wheel_toe",
            0.3,
            1.7e-4,
            0.010,
            True,
            "low: detection limit, rich protocol (docs/effects.md). high: the frame yaw "
            "misalignments diagnosed on the real OptiOdom June sessions reach 0.52° = 9.1 mrad "
            "(docs/diagnose.md), the toe's confounded twin in pose logs",
        ),
        EffectPrior(
            "turn_skid",
            0.3,
            5.2e-3,
            0.75,
            False,
            "low: detection limit, rich protocol (docs/effects.md). high: the real OptiOdom "
            "June sessions diagnosed κ = 0.71 ± 0.04 s²/m (docs/diagnose.md)",
        ),
        EffectPrior(
            "backlash",
            0.3,
            3.6e-3,
            0.040,
            False,
            "low: detection limit, rich protocol (docs/effects.md). high: the real OptiOdom "
            "June sessions diagnosed 0.036 ± 0.006 rad (docs/diagnose.md)",
        ),
        EffectPrior(
            "gt_sensor_offset",
            0.3,
            1.2e-4,
            0.020,
            True,
            "low: detection limit, rich protocol (docs/effects.md). high: an assumption, not a "
            "measurement — a motion-capture rigid body placed by eye within 2 cm of the axle "
            "midpoint of a 0.26 m chassis",
        ),
    ),
)
"""Issue 45's prior. Each optional effect is present with probability 0.3, the probability of
``odomgym fleet --example``'s prior (docs/fleet.md)."""


def spec_of(theta: FloatArray, base: RobotSpec = NOMINAL_ROBOT) -> RobotSpec:
    """The robot spec of parameters θ (8,): the true geometry and every non-absent effect,
    written through the catalogue (:meth:`odomgym.effects.Effect.write`). Values outside the
    catalogue's ranges (a posterior mean of a negative turn-skid gain) are clipped to them."""
    values = np.asarray(theta, dtype=float)
    spec = base.with_errors(
        e_s=1.0 + float(values[0]), e_d=1.0 + float(values[1]), e_b=1.0 + float(values[2])
    )
    for effect in OPTIONAL_EFFECTS:
        cols = columns_of(effect)
        if not np.any(values[list(cols)]):
            continue
        table = {}
        for j in cols:
            name = PARAMETERS[j][1]
            parameter = next(p for p in EFFECTS[effect].parameters if p.name == name)
            table[name] = float(
                np.clip(parameter.absent + values[j], parameter.low, parameter.high)
            )
        if EFFECTS[effect].is_absent(table):
            continue
        spec = EFFECTS[effect].write(spec, table)
    return spec

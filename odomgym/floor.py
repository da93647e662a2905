"""Floor specifications: friction, cable bumps, low-friction patches and roughness.

The floor is where non-systematic odometry errors come from (Borenstein & Feng 1994, §2.1;
Borenstein 1995, §3.1):

* **friction** μ limits the force each wheel can pass to the ground, so slip emerges when a
  manoeuvre asks for more (hard acceleration, fast turns, low μ);
* **cable bumps** make a wheel rotate more than it advances horizontally — computed here from the
  geometry of a rigid wheel rolling over a rigid cylinder (Borenstein 1995, Fig. 4, Table I);
* **patches** of lower friction (a wet or polished spot);
* **roughness** k [m^½]: each wheel's true ground travel differs from its rim travel by zero-mean
  white noise of variance k²·|d| (Chong & Kleeman 1997, Eq. 4).

Coordinates are the world frame [m] in which every env starts its robot at the origin, heading
along +x.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.errors import (
    SpecError,
    load_named,
    locate_key,
    refuse_stray_keys,
    require_finite,
    require_positive,
    require_range,
)
from odomgym.io import atomic_write_text

__all__ = [
    "FLOORS",
    "CableBump",
    "FloorSpec",
    "FrictionPatch",
    "load_floor",
]

FloatArray = NDArray[np.float64]


MAX_ROUGHNESS = 0.1
"""Largest floor roughness k [m^½]: 50 × the ``rough`` preset, a wheel-travel noise of ±10 cm
per metre; the ``floor_roughness`` effect has the same limit."""


@dataclass(frozen=True)
class CableBump:
    """A straight cable of circular cross-section lying on the floor.

    Attributes:
        x, y: centre of the cable [m].
        angle: direction of the cable's axis from +x [rad].
        diameter: cable diameter [m] (Borenstein 1995, §6, uses a 10 mm cable).
        length: cable length [m]; a short cable lies under one wheel only.
    """

    x: float
    y: float
    angle: float = math.pi / 2
    diameter: float = 0.010
    length: float = 0.3

    def __post_init__(self) -> None:
        require_finite("x", self.x)
        require_finite("y", self.y)
        require_finite("angle", self.angle)
        require_positive("diameter", self.diameter)
        require_positive("length", self.length)


@dataclass(frozen=True)
class FrictionPatch:
    """An axis-aligned rectangle of different friction [m]; μ is dimensionless."""

    x_min: float
    y_min: float
    x_max: float
    y_max: float
    friction: float

    def __post_init__(self) -> None:
        for name in ("x_min", "y_min", "x_max", "y_max"):
            require_finite(name, getattr(self, name))
        require_positive("friction", self.friction)
        if self.x_max <= self.x_min:
            raise SpecError(
                f"x_max must exceed x_min, got {self.x_max!r} <= {self.x_min!r}", field="x_max"
            )
        if self.y_max <= self.y_min:
            raise SpecError(
                f"y_max must exceed y_min, got {self.y_max!r} <= {self.y_min!r}", field="y_max"
            )


@dataclass(frozen=True)
class FloorSpec:
    """The floor a robot drives on.

    Attributes:
        friction: Coulomb friction coefficient μ between drive wheels and floor [-]
            (0.8 ≈ rubber on dry concrete).
        bumps: cables lying on the floor.
        patches: rectangles with their own friction coefficient.
        roughness: k [m^½] of Chong & Kleeman 1997, Eq. 4; per-wheel ground-travel noise variance
            k²·|d|.
        name: a label.
    """

    friction: float = 0.8
    bumps: tuple[CableBump, ...] = field(default_factory=tuple)
    patches: tuple[FrictionPatch, ...] = field(default_factory=tuple)
    roughness: float = 0.0
    name: str = "floor"

    def __post_init__(self) -> None:
        require_positive("friction", self.friction)
        require_range("roughness", self.roughness, 0.0, MAX_ROUGHNESS)
        object.__setattr__(self, "bumps", _items(CableBump, "bumps", self.bumps))
        object.__setattr__(self, "patches", _items(FrictionPatch, "patches", self.patches))

    # ------------------------------------------------------------------ vectorised queries
    def friction_at(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """Friction coefficient at the points (x, y) [m]; the last patch listed wins."""
        mu = np.full(np.shape(x), self.friction)
        for patch in self.patches:
            inside = (
                (x >= patch.x_min) & (x <= patch.x_max) & (y >= patch.y_min) & (y <= patch.y_max)
            )
            mu[inside] = patch.friction
        return mu

    def bump_arrays(self) -> tuple[FloatArray, ...]:
        """Cable centres, unit axes, normals, half-lengths and radii as arrays of shape (M,)."""
        if not self.bumps:
            empty = np.zeros(0)
            return empty, empty, empty, empty, empty, empty, empty
        cx = np.array([b.x for b in self.bumps])
        cy = np.array([b.y for b in self.bumps])
        angle = np.array([b.angle for b in self.bumps])
        return (
            cx,
            cy,
            np.cos(angle),
            np.sin(angle),
            np.array([0.5 * b.length for b in self.bumps]),
            np.array([0.5 * b.diameter for b in self.bumps]),
            angle,
        )

    # ------------------------------------------------------------------ TOML
    def to_dict(self) -> dict[str, Any]:
        """A TOML-ready dict."""
        return {
            "name": self.name,
            "friction": self.friction,
            "roughness": self.roughness,
            "bumps": [dataclasses.asdict(b) for b in self.bumps],
            "patches": [dataclasses.asdict(p) for p in self.patches],
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, path: Path | None = None) -> FloorSpec:
        """Build from a mapping (parsed TOML); errors name the field, file and line."""
        refuse_stray_keys(data, "floor", path)
        table = dict(data.get("floor", data))

        def where(key: str) -> str | None:
            return locate_key(path, key) if path else None

        known = {"name", "friction", "roughness", "bumps", "patches"}
        for key in table:
            if key not in known:
                raise SpecError(
                    f"unknown floor field {key!r}; known: {', '.join(sorted(known))}",
                    field=key,
                    source=where(key),
                )
        kwargs: dict[str, Any] = {}
        if "name" in table:
            kwargs["name"] = str(table["name"])
        if "friction" in table:
            kwargs["friction"] = require_positive(
                "friction", table["friction"], source=where("friction")
            )
        if "roughness" in table:
            kwargs["roughness"] = require_range(
                "roughness", table["roughness"], 0.0, MAX_ROUGHNESS, source=where("roughness")
            )
        kwargs["bumps"] = tuple(
            _build_item(CableBump, f"bumps[{i}]", item, path)
            for i, item in enumerate(_list_of_tables(table.get("bumps", []), "bumps", path))
        )
        kwargs["patches"] = tuple(
            _build_item(FrictionPatch, f"patches[{i}]", item, path)
            for i, item in enumerate(_list_of_tables(table.get("patches", []), "patches", path))
        )
        return cls(**kwargs)

    def save(self, path: str | Path) -> None:
        """Write the floor as TOML, atomically."""
        import tomli_w

        atomic_write_text(Path(path), tomli_w.dumps({"floor": self.to_dict()}))

    @classmethod
    def scattered_cables(
        cls,
        rng: np.random.Generator,
        *,
        half_size: float = 15.0,
        per_square_metre: float = 0.5,
        diameter: float = 0.010,
        length: float = 0.3,
        friction: float = 0.8,
        roughness: float = 0.0,
        name: str = "scattered-cables",
    ) -> FloorSpec:
        """A floor strewn with cables at uniformly random positions and orientations.

        Covers [−half_size, half_size]² [m]. A wheel path crosses on average
        ``per_square_metre`` · ``length`` · 2/π cables per metre (Buffon), e.g. 0.1 per metre
        with the defaults. Robots started at random poses on such a floor meet cables at random,
        which makes bumps a non-systematic error (the fixed ``bumpy`` floor, where every run
        crosses the same cables, makes them systematic).
        """
        require_positive("half_size", half_size)
        require_positive("per_square_metre", per_square_metre)
        count = round(per_square_metre * (2.0 * half_size) ** 2)
        xy = rng.uniform(-half_size, half_size, size=(count, 2))
        angles = rng.uniform(0.0, math.pi, size=count)
        bumps = tuple(
            CableBump(x=float(x), y=float(y), angle=float(a), diameter=diameter, length=length)
            for (x, y), a in zip(xy, angles, strict=True)
        )
        return cls(friction=friction, bumps=bumps, roughness=roughness, name=name)


def _list_of_tables(value: object, name: str, path: Path | None) -> Sequence[Mapping[str, Any]]:
    if not isinstance(value, list) or not all(isinstance(v, Mapping) for v in value):
        raise SpecError(
            f"{name} must be an array of tables ([[floor.{name}]])",
            field=name,
            source=locate_key(path, name) if path else None,
        )
    return value


def _items(kind: type[Any], name: str, given: Any) -> tuple[Any, ...]:
    """``bumps`` or ``patches`` as a tuple of ``kind``: each entry one already, or a mapping
    of its fields (as in a floor file); anything else refused, naming the entry. A dict had
    been stored as it was and ended in ``AttributeError: 'dict' object has no attribute 'x'``
    at the first step on the floor, and a single patch in ``TypeError: not iterable``."""
    if isinstance(given, str | bytes | Mapping | kind) or not isinstance(given, Iterable):
        raise SpecError(
            f"{name} must be a list of {kind.__name__} (or of tables of its fields), got "
            f"{type(given).__name__}",
            field=name,
        )
    out = []
    for index, item in enumerate(given):
        if isinstance(item, kind):
            out.append(item)
        elif isinstance(item, Mapping):
            out.append(_build_item(kind, f"{name}[{index}]", item, None))
        else:
            raise SpecError(
                f"{name}[{index}] must be a {kind.__name__} or a table of its fields, got "
                f"{type(item).__name__}",
                field=f"{name}[{index}]",
            )
    return tuple(out)


def _build_item(kind: type[Any], label: str, item: Mapping[str, Any], path: Path | None) -> Any:
    """Build the ``label`` entry (e.g. ``bumps[2]``) of an array of tables; errors point at the
    line inside that entry."""
    table, _, rest = label.partition("[")
    index = int(rest.rstrip("]")) if rest else 0

    def where(key: str) -> str | None:
        return locate_key(path, key, table=table, index=index) if path else None

    names = {f.name for f in dataclasses.fields(kind)}
    for key in item:
        if key not in names:
            raise SpecError(
                f"unknown field {key!r} in {label}; known: {', '.join(sorted(names))}",
                field=f"{label}.{key}",
                source=where(key),
            )
    try:
        return kind(**item)
    except TypeError as exc:
        raise SpecError(f"{label}: {exc}", field=label, source=where(label)) from None
    except SpecError as exc:
        key = exc.field or label
        raise SpecError(f"{label}.{exc}", field=f"{label}.{key}", source=where(key)) from None


def load_floor(spec: str | os.PathLike[str] | FloorSpec) -> FloorSpec:
    """Return a named floor (``smooth``, ``bumpy``, ``slippery``) or load a floor TOML file (a
    spec is returned as it is; anything else is refused in one line naming its type)."""
    return load_named(
        spec,
        FLOORS,
        "floor",
        lambda text: (
            f"unknown floor {text!r}; floors: {', '.join(sorted(FLOORS))}, or a .toml file"
        ),
        FloorSpec.from_dict,
    )


def _bumpy_floor() -> FloorSpec:
    """Cables strewn over the 4×4 m squares of both directions, a fixed layout.

    One 10 mm cable, 0.3 m long (under one wheel at a time), across every leg of the cw and
    ccw squares, placed at deterministic pseudo-random positions so the floor is a fixed fact
    and not a random draw.
    """
    rng = np.random.default_rng(1994)
    bumps: list[CableBump] = []
    side = 4.0
    # Leg segments of the ccw (+y) and cw (−y) squares, as (start, end) points.
    corners_ccw = [(0.0, 0.0), (side, 0.0), (side, side), (0.0, side)]
    corners_cw = [(0.0, 0.0), (side, 0.0), (side, -side), (0.0, -side)]
    for corners in (corners_ccw, corners_cw):
        for k in range(4):
            (x0, y0), (x1, y1) = corners[k], corners[(k + 1) % 4]
            heading = math.atan2(y1 - y0, x1 - x0)
            for _ in range(2):
                t = rng.uniform(0.2, 0.8)
                side_sign = rng.choice([-1.0, 1.0])
                # Offset sideways so the cable lies under one wheel only (± 0.15 m from the path).
                ox, oy = -math.sin(heading) * 0.15 * side_sign, math.cos(heading) * 0.15 * side_sign
                bumps.append(
                    CableBump(
                        x=x0 + t * (x1 - x0) + ox,
                        y=y0 + t * (y1 - y0) + oy,
                        angle=heading + math.pi / 2,
                        diameter=0.010,
                        length=0.12,
                    )
                )
    return FloorSpec(friction=0.8, bumps=tuple(bumps), name="bumpy")


FLOORS: dict[str, FloorSpec] = {
    "smooth": FloorSpec(friction=0.8, name="smooth"),
    "bumpy": _bumpy_floor(),
    "slippery": FloorSpec(friction=0.2, name="slippery"),
    "rough": FloorSpec(friction=0.8, roughness=0.002, name="rough"),
    # A lab's concrete floor: k chosen so that a LabMate's 4×4 m UMBmark return errors scatter
    # with σ ≈ 25 mm about their centre of gravity, as Borenstein & Feng 1994, §6.3, report
    # (measured: k = 0.0005 m^½ gives 31.5 mm over 200 runs; σ scales with k).
    "concrete": FloorSpec(friction=0.8, roughness=0.0004, name="concrete"),
}

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
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from odomgym._jit import kernel
from odomgym.errors import SpecError, locate_key, require_finite, require_positive, require_range
from odomgym.io import atomic_write_text

__all__ = [
    "FLOORS",
    "CableBump",
    "FloorSpec",
    "FrictionPatch",
    "apply_cable_deficits",
    "bump_extra_rotation",
    "cable_advance",
    "load_floor",
]

FloatArray = NDArray[np.float64]


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
        if self.x_max <= self.x_min or self.y_max <= self.y_min:
            raise SpecError("patch must have x_max > x_min and y_max > y_min", field="patch")


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
        require_range("roughness", self.roughness, 0.0, 1.0)
        object.__setattr__(self, "bumps", tuple(self.bumps))
        object.__setattr__(self, "patches", tuple(self.patches))

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
                "roughness", table["roughness"], 0.0, 1.0, source=where("roughness")
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

    def with_friction(self, friction: float) -> FloorSpec:
        """A copy with another base friction coefficient."""
        return dataclasses.replace(self, friction=friction)


def _list_of_tables(value: object, name: str, path: Path | None) -> Sequence[Mapping[str, Any]]:
    if not isinstance(value, list) or not all(isinstance(v, Mapping) for v in value):
        raise SpecError(
            f"{name} must be an array of tables ([[floor.{name}]])",
            field=name,
            source=locate_key(path, name) if path else None,
        )
    return value


def _build_item(kind: type[Any], label: str, item: Mapping[str, Any], path: Path | None) -> Any:
    names = {f.name for f in dataclasses.fields(kind)}
    for key in item:
        if key not in names:
            raise SpecError(
                f"unknown field {key!r} in {label}; known: {', '.join(sorted(names))}",
                field=f"{label}.{key}",
                source=locate_key(path, key) if path else None,
            )
    try:
        return kind(**item)
    except TypeError as exc:
        raise SpecError(
            f"{label}: {exc}", field=label, source=str(path) if path else None
        ) from None
    except SpecError as exc:
        key = exc.field or label
        raise SpecError(
            f"{label}.{exc}",
            field=f"{label}.{key}",
            source=locate_key(path, key) if path else None,
        ) from None


# ---------------------------------------------------------------------- bump geometry
def _profile(
    radius_wheel: float | FloatArray, radius_cable: float | FloatArray
) -> tuple[Any, Any, Any]:
    big_r = radius_wheel + radius_cable
    half_width = 2.0 * np.sqrt(radius_wheel * radius_cable)  # centre offset at first contact
    psi0 = np.arcsin(half_width / big_r)
    return big_r, half_width, psi0


def bump_extra_rotation(wheel_radius: float, cable_diameter: float) -> float:
    """Rim travel minus horizontal advance for one full crossing of a cable [m].

    A rigid wheel of radius r meets a rigid cylinder of radius ρ when their centres are
    w = 2·√(r·ρ) apart horizontally; from there the wheel centre moves on a circle of radius
    R = r + ρ around the cable axis, rolling without slip, so the wheel turns through an arc of
    R·2ψ₀ (ψ₀ = asin(w/R)) while advancing 2w. The excess R·2ψ₀ − 2w is what the encoder
    over-reports (Borenstein 1995, Eq. 1, uses the chord approximation of the same picture; LabMate,
    r = 75 mm, 10 mm cable: 3.40 mm (0.57° of heading on b = 340 mm), versus the paper's 2.63
    mm estimate).
    """
    big_r, half_width, psi0 = _profile(wheel_radius, 0.5 * cable_diameter)
    return float(2.0 * big_r * psi0 - 2.0 * half_width)


@kernel
def cable_advance_scalar(
    offset: float, rim_travel: float, wheel_radius: float, cable_radius: float
) -> float:
    """Horizontal advance of a wheel centre across a cable, for a given rim travel [m].

    ``offset`` is the signed horizontal distance of the wheel centre from the cable axis
    (perpendicular to the axis) at the start of the step, ``rim_travel`` the signed rim travel
    in the same direction. The map from horizontal position x to accumulated rim travel s(x) is
    x on the flat, −w + R·(asin(x/R) + ψ₀) over the cable, and x + 2Rψ₀ − 2w beyond it (R = r + ρ,
    w = 2√(rρ), ψ₀ = asin(w/R)); the advance is s⁻¹(s(x₀) + Δs) − x₀, exact for any step size
    and either direction of travel.
    """
    big_r = wheel_radius + cable_radius
    half_width = 2.0 * math.sqrt(wheel_radius * cable_radius)
    psi0 = math.asin(half_width / big_r)
    excess = 2.0 * big_r * psi0 - 2.0 * half_width
    x0 = offset
    # Entirely on the flat (before or beyond the cable): exactly the rim travel, with no
    # rounding, so testing a distant cable changes nothing.
    if (x0 <= -half_width and x0 + rim_travel <= -half_width) or (
        x0 >= half_width and x0 + rim_travel >= half_width
    ):
        return rim_travel
    if x0 <= -half_width:
        s0 = x0
    elif x0 >= half_width:
        s0 = x0 + excess
    else:
        s0 = -half_width + big_r * (math.asin(min(max(x0 / big_r, -1.0), 1.0)) + psi0)
    s1 = s0 + rim_travel
    if s1 <= -half_width:
        x1 = s1
    elif s1 >= half_width + excess:
        x1 = s1 - excess
    else:
        x1 = big_r * math.sin(min(max((s1 + half_width) / big_r - psi0, -psi0), psi0))
    return x1 - x0


@kernel
def _cable_advance_many(
    offset: FloatArray, rim_travel: FloatArray, wheel_radius: FloatArray, cable_radius: FloatArray
) -> FloatArray:
    out = np.empty(offset.size)
    for k in range(offset.size):
        out[k] = cable_advance_scalar(offset[k], rim_travel[k], wheel_radius[k], cable_radius[k])
    return out


def cable_advance(
    offset: ArrayLike, rim_travel: ArrayLike, wheel_radius: ArrayLike, cable_radius: ArrayLike
) -> FloatArray:
    """:func:`cable_advance_scalar` over broadcast arrays (same units, same result shape)."""
    arrays = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (offset, rim_travel, wheel_radius, cable_radius))
    )
    shape = arrays[0].shape
    flat = [np.ascontiguousarray(a).ravel() for a in arrays]
    return np.asarray(_cable_advance_many(*flat)).reshape(shape)


@dataclass(frozen=True)
class CableGrid:
    """A uniform grid over the floor listing, per cell, the cables a wheel there may touch.

    Why: a floor can hold thousands of cables, and a wheel meets at most one or two at a time.
    Each cable is entered in every cell its reach (half its length along the axis; the
    wheel-cable contact half-width 2√(rρ) plus one step's travel across) overlaps, so a wheel
    only tests the cables of
    its own cell. Arrays are CSR-style: cell ``c`` lists ``items[starts[c]:starts[c + 1]]``.
    """

    cable_x: FloatArray
    cable_y: FloatArray
    axis_x: FloatArray
    axis_y: FloatArray
    half_length: FloatArray
    radius: FloatArray
    origin_x: float
    origin_y: float
    cell: float
    nx: int
    ny: int
    starts: NDArray[np.int64]
    items: NDArray[np.int64]

    @classmethod
    def build(cls, floor: FloorSpec, max_wheel_radius: float, max_step: float) -> CableGrid:
        """Index ``floor``'s cables for wheels of radius up to ``max_wheel_radius`` [m] that
        travel at most ``max_step`` [m] per physics step (a step starting outside a cable's
        contact zone may end inside it, so the reach includes one step)."""
        cx, cy, ax, ay, half_len, radius, _ = floor.bump_arrays()
        if cx.size == 0:
            empty = np.zeros(0)
            return cls(
                empty,
                empty,
                empty,
                empty,
                empty,
                empty,
                0.0,
                0.0,
                1.0,
                0,
                0,
                np.zeros(1, dtype=np.int64),
                np.zeros(0, dtype=np.int64),
            )
        reach = 2.0 * np.sqrt(max_wheel_radius * radius) + max_step + 1e-6  # [m]
        extent_x = np.abs(ax) * half_len + np.abs(ay) * reach
        extent_y = np.abs(ay) * half_len + np.abs(ax) * reach
        cell = float(max(0.25, 2.0 * float(np.max(half_len))))
        origin_x = float(np.min(cx - extent_x)) - cell
        origin_y = float(np.min(cy - extent_y)) - cell
        nx = math.ceil((float(np.max(cx + extent_x)) - origin_x) / cell) + 1
        ny = math.ceil((float(np.max(cy + extent_y)) - origin_y) / cell) + 1
        buckets: list[list[int]] = [[] for _ in range(nx * ny)]
        for m in range(cx.size):
            x_lo = int((cx[m] - extent_x[m] - origin_x) // cell)
            x_hi = int((cx[m] + extent_x[m] - origin_x) // cell)
            y_lo = int((cy[m] - extent_y[m] - origin_y) // cell)
            y_hi = int((cy[m] + extent_y[m] - origin_y) // cell)
            for gy in range(y_lo, y_hi + 1):
                for gx in range(x_lo, x_hi + 1):
                    buckets[gy * nx + gx].append(m)
        starts = np.zeros(nx * ny + 1, dtype=np.int64)
        starts[1:] = np.cumsum([len(b) for b in buckets])
        items = np.array([m for b in buckets for m in b], dtype=np.int64)
        return cls(
            cx, cy, ax, ay, half_len, radius, origin_x, origin_y, cell, nx, ny, starts, items
        )


@kernel
def apply_cable_deficits(
    contact: FloatArray,
    pose: FloatArray,
    rim_speed: FloatArray,
    h: float,
    wheel_radius: FloatArray,
    cable_x: FloatArray,
    cable_y: FloatArray,
    axis_x: FloatArray,
    axis_y: FloatArray,
    half_length: FloatArray,
    cable_radius: FloatArray,
    origin_x: float,
    origin_y: float,
    cell: float,
    nx: int,
    ny: int,
    starts: NDArray[np.int64],
    items: NDArray[np.int64],
    ground_v: FloatArray,
) -> None:
    """Remove from each wheel's ground velocity the horizontal travel lost to cables.

    The wheel's rim travel along its heading has a component across each cable of its grid
    cell (along the cable's normal); :func:`odomgym.floor.cable_advance_scalar` maps it to the
    horizontal advance, and the difference, divided by h, leaves the ground velocity.
    """
    for i in range(contact.shape[0]):
        hx = math.cos(pose[i, 2])
        hy = math.sin(pose[i, 2])
        for w in range(2):
            wx = contact[i, w, 0]
            wy = contact[i, w, 1]
            gx = math.floor((wx - origin_x) / cell)
            gy = math.floor((wy - origin_y) / cell)
            if gx < 0 or gy < 0 or gx >= nx or gy >= ny:
                continue
            c = gy * nx + gx
            for k in range(starts[c], starts[c + 1]):
                m = items[k]
                rel_x = wx - cable_x[m]
                rel_y = wy - cable_y[m]
                if abs(rel_x * axis_x[m] + rel_y * axis_y[m]) > half_length[m]:
                    continue
                normal_x, normal_y = -axis_y[m], axis_x[m]
                offset = rel_x * normal_x + rel_y * normal_y
                across = rim_speed[i, w] * h * (hx * normal_x + hy * normal_y)
                lost = across - cable_advance_scalar(
                    offset, across, wheel_radius[i, w], cable_radius[m]
                )
                ground_v[i, w, 0] -= lost * normal_x / h
                ground_v[i, w, 1] -= lost * normal_y / h


def load_floor(spec: str | Path) -> FloorSpec:
    """Return a named floor (``smooth``, ``bumpy``, ``slippery``) or load a floor TOML file."""
    text = str(spec)
    if text in FLOORS:
        return FLOORS[text]
    path = Path(text)
    if path.suffix != ".toml" and not path.exists():
        raise SpecError(
            f"unknown floor {text!r}; floors: {', '.join(sorted(FLOORS))}, or a .toml file",
            field="floor",
        )
    try:
        raw = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise SpecError(f"cannot read floor file: {exc.strerror}", source=str(path)) from None
    try:
        data = tomllib.loads(raw)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"malformed TOML: {exc}", source=str(path)) from None
    return FloorSpec.from_dict(data, path=path)


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

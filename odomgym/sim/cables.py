"""Cables on the floor: the geometry of a rigid wheel rolling over a rigid cylinder, the spatial
index that finds the cables near a wheel, and the compiled kernel that takes the horizontal
travel a crossing loses out of a wheel's ground velocity.

Why a module of its own: the floor *spec* (:mod:`odomgym.floor`) says where cables lie; this
module is the physics of crossing one (Borenstein 1995, Fig. 4 and Table I), used by the World
(:mod:`odomgym.sim.world`) every step and by the bump effect (:mod:`odomgym.effects.noise`).

Units: metres, radians.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from odomgym._jit import inlined_kernel, kernel


class HasCables(Protocol):
    """What :meth:`CableGrid.build` needs of a floor (:class:`odomgym.floor.FloorSpec` is one):
    cables are geometry, and the floor's description imports nothing from here."""

    def bump_arrays(self) -> tuple[NDArray[np.float64], ...]:
        """Cable centres, unit axes, normals, half-lengths and radii as arrays of shape (M,)."""
        ...


__all__ = [
    "BumpError",
    "CableGrid",
    "apply_cable_deficits",
    "bump_extra_rotation",
    "cable_advance",
    "cable_advance_scalar",
    "paper_bump_error",
    "rim_travel_for_advance",
    "skid_cable_losses",
]

FloatArray = NDArray[np.float64]


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


class BumpError(NamedTuple):
    """The errors one bump leaves, in Borenstein's (1995) first-order picture."""

    overcount: float  # ΔD, rim travel minus horizontal advance [m] (Eqs. 1–3)
    heading: float  # α, the truck's orientation error [rad] (Eq. 4)
    lateral: float  # e_lat, lateral error after ``distance`` [m] (Eq. 5)


def paper_bump_error(
    wheel_radius: float, height: float, wheelbase: float, distance: float
) -> BumpError:
    """Borenstein 1995, Eqs. 1–5 (the paper's Table I): a wheel of radius R over a step of
    height h turns about the step's edge, so the encoder reports the chord
    D_meas ≈ √(2Rh) (Eq. 3, R ≫ h) for the horizontal D_hor = √(2Rh − h²) (Eq. 2), up and
    down: ΔD = 2(D_meas − D_hor) (Eq. 1); the truck turns by α = asin(ΔD/b) (Eq. 4) and drifts
    sideways by e_lat = D·sin α over ``distance`` D (Eq. 5). :func:`bump_extra_rotation` is the
    exact rigid-cylinder geometry the World uses instead (3.40 mm against the chord's 2.63 mm
    for a LabMate over a 10 mm cable)."""
    d_hor = math.sqrt(2.0 * wheel_radius * height - height**2)
    d_meas = math.sqrt(2.0 * wheel_radius * height)
    over = 2.0 * (d_meas - d_hor)
    alpha = math.asin(over / wheelbase)
    return BumpError(over, alpha, distance * math.sin(alpha))


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


def rim_travel_for_advance(
    offset: float, advance: float, wheel_radius: float, cable_radius: float
) -> float:
    """The rim travel that moves a wheel centre horizontally by ``advance`` across a cable [m]:
    the inverse of :func:`cable_advance_scalar` (same arguments and map s(x): rim travel
    s(x₀ + advance) − s(x₀)). A free-rolling wheel — an encoder trailer's (Borenstein 1995,
    §7) — is pulled across the cable and turns through the arc over it, so its encoder
    over-counts the horizontal advance by the cable's excess, as a driven wheel's does."""
    big_r = wheel_radius + cable_radius
    half_width = 2.0 * math.sqrt(wheel_radius * cable_radius)
    psi0 = math.asin(half_width / big_r)
    excess = 2.0 * big_r * psi0 - 2.0 * half_width

    def rim(x: float) -> float:
        if x <= -half_width:
            return x
        if x >= half_width:
            return x + excess
        return -half_width + big_r * (math.asin(min(max(x / big_r, -1.0), 1.0)) + psi0)

    return rim(offset + advance) - rim(offset)


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


class CableGrid(NamedTuple):
    """A uniform grid over the floor listing, per cell, the cables a wheel there may touch.

    Why: a floor can hold thousands of cables, and a wheel meets at most one or two at a time.
    Each cable is entered in every cell its reach (half its length along the axis; the
    wheel-cable contact half-width 2√(rρ) plus one step's travel across) overlaps, so a wheel
    only tests the cables of its own cell. Arrays are CSR-style: cell ``c`` lists
    ``items[starts[c]:starts[c + 1]]``.

    A named tuple, so that compiled kernels take the whole grid as one argument
    (:func:`apply_cable_deficits`). Cable centres ``cable_x/y`` and unit axes ``axis_x/y`` [m],
    ``half_length`` and ``radius`` [m] per cable; grid origin and ``cell`` size [m]; ``nx × ny``
    cells.
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
    def build(cls, floor: HasCables, max_wheel_radius: float, max_step: float) -> CableGrid:
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
        # Every (cell, cable) pair of each cable's block of cells, cables in index order, then
        # grouped by cell with a stable sort: each cell lists its cables in index order. (Numpy's
        # float floor division is Python's, so the blocks are the per-cable loop's to the bit.)
        x_lo = ((cx - extent_x - origin_x) // cell).astype(np.int64)
        x_hi = ((cx + extent_x - origin_x) // cell).astype(np.int64)
        y_lo = ((cy - extent_y - origin_y) // cell).astype(np.int64)
        y_hi = ((cy + extent_y - origin_y) // cell).astype(np.int64)
        width = x_hi - x_lo + 1
        count = width * (y_hi - y_lo + 1)
        cable = np.repeat(np.arange(cx.size, dtype=np.int64), count)
        first = np.cumsum(count) - count  # where each cable's block begins
        k = np.arange(cable.size, dtype=np.int64) - first[cable]  # row-major within the block
        cells = (y_lo[cable] + k // width[cable]) * nx + x_lo[cable] + k % width[cable]
        items = cable[np.argsort(cells, kind="stable")]
        starts = np.zeros(nx * ny + 1, dtype=np.int64)
        starts[1:] = np.cumsum(np.bincount(cells, minlength=nx * ny))
        return cls(
            cx, cy, ax, ay, half_len, radius, origin_x, origin_y, cell, nx, ny, starts, items
        )


@inlined_kernel
def _wheel_deficit(
    wx: float,
    wy: float,
    hx: float,
    hy: float,
    rim_travel: float,
    wheel_radius: float,
    grid: CableGrid,
    h: float,
    velocity: FloatArray,
) -> None:
    """Remove from ``velocity`` (2,) [m/s] the horizontal travel a wheel whose contact is at
    (``wx``, ``wy``), heading (``hx``, ``hy``), loses to the cables of its grid cell in a step of
    ``rim_travel`` [m] over ``h`` [s] (:func:`apply_cable_deficits`)."""
    gx = math.floor((wx - grid.origin_x) / grid.cell)
    gy = math.floor((wy - grid.origin_y) / grid.cell)
    if gx < 0 or gy < 0 or gx >= grid.nx or gy >= grid.ny:
        return
    c = gy * grid.nx + gx
    for k in range(grid.starts[c], grid.starts[c + 1]):
        m = grid.items[k]
        rel_x = wx - grid.cable_x[m]
        rel_y = wy - grid.cable_y[m]
        axis_x = grid.axis_x[m]
        axis_y = grid.axis_y[m]
        if abs(rel_x * axis_x + rel_y * axis_y) > grid.half_length[m]:
            continue
        normal_x, normal_y = -axis_y, axis_x
        offset = rel_x * normal_x + rel_y * normal_y
        across = rim_travel * (hx * normal_x + hy * normal_y)
        lost = across - cable_advance_scalar(offset, across, wheel_radius, grid.radius[m])
        velocity[0] -= lost * normal_x / h
        velocity[1] -= lost * normal_y / h


@kernel
def apply_cable_deficits(
    contact: FloatArray,
    pose: FloatArray,
    rim_speed: FloatArray,
    h: float,
    wheel_radius: FloatArray,
    grid: CableGrid,
    ground_v: FloatArray,
) -> None:
    """Remove from each wheel's ground velocity the horizontal travel lost to cables.

    The wheel's rim travel along its heading has a component across each cable of its grid
    cell (along the cable's normal); :func:`cable_advance_scalar` maps it to the horizontal
    advance, and the difference, divided by h, leaves the ground velocity. ``contact`` (N, 2, 2)
    wheel contact points [m], ``pose`` (N, 3), ``rim_speed`` (N, 2) [m/s], ``h`` the step [s],
    ``wheel_radius`` (N, 2) [m]; ``ground_v`` (N, 2, 2) [m/s] in place.
    """
    for i in range(contact.shape[0]):
        hx = math.cos(pose[i, 2])
        hy = math.sin(pose[i, 2])
        for w in range(2):
            _wheel_deficit(
                contact[i, w, 0],
                contact[i, w, 1],
                hx,
                hy,
                rim_speed[i, w] * h,
                wheel_radius[i, w],
                grid,
                h,
                ground_v[i, w],
            )


@kernel
def skid_cable_losses(
    robots: NDArray[np.intp],
    sides: NDArray[np.intp],
    points: FloatArray,
    pose: FloatArray,
    rim_speed: FloatArray,
    h: float,
    wheel_radius: FloatArray,
    grid: CableGrid,
    loss: FloatArray,
) -> None:
    """Each skid-steer wheel's loss of no-slip speed along the heading to cables [m/s], into
    ``loss`` (K, 4): the travel its own contact (``points`` (K, 4, 2) [m], world frame) loses
    crossing a cable, as a differential-drive wheel's (:func:`apply_cable_deficits`), at its
    side's rim speed. The two wheels of a side share their drive, so a wheel that climbs a
    cable turns as fast as the other and advances less: its contact is slower than its side's
    (:func:`odomgym.sim.world.skid_contacts` takes the difference). The loss across the heading
    is not kept: those contacts take a speed along the heading alone."""
    velocity = np.zeros(2)
    for k in range(robots.shape[0]):
        i = robots[k]
        hx = math.cos(pose[i, 2])
        hy = math.sin(pose[i, 2])
        for j in range(4):
            w = sides[k, j]
            velocity[0] = 0.0
            velocity[1] = 0.0
            _wheel_deficit(
                points[k, j, 0],
                points[k, j, 1],
                hx,
                hy,
                rim_speed[i, w] * h,
                wheel_radius[i, w],
                grid,
                h,
                velocity,
            )
            loss[k, j] = -(velocity[0] * hx + velocity[1] * hy)

"""Internal odometry of a two-truck vehicle: what a position estimator reads and returns.

The vehicle (Borenstein 1995, §2, Fig. 2) is two differential-drive trucks, A in front and B
behind, joined at their centres (the axle midpoints) by a compliant linkage. Besides each
truck's two wheel encoders it measures

* the centre distance l with a linear encoder, and
* the angle ψ_X of each truck relative to the link with an absolute rotary encoder at its centre:
  ψ_X = θ_X − θ_L, where θ_L = atan2(y_A − y_B, x_A − x_B) is the link direction *from B to A*
  (the orientation Borenstein 1995, Eq. 10 needs for Eqs. 11 and 16 to hold).

An :class:`InternalEstimator` turns these into the poses of both trucks, batched over N
vehicles. Array conventions (all float64, world frame, metres and radians, θ counter-clockwise):

* poses (N, 2, 3): `[vehicle][truck A, B][x, y, θ]`; θ is kept unwrapped (continuous);
* wheel travel (N, 2, 2): `[vehicle][truck][left, right]`, the travel of one sampling interval *as
  the odometry believes it* (encoder counts × calibrated metres per count);
* :class:`LinkReading`: the encoders' values at the end of the interval.

:class:`DeadReckoning` is the estimator without internal correction (two independent odometries,
the readings ignored); Internal Position Error Correction is
:class:`odomgym.vehicle.ipec.IPEC`. :func:`link_angles` gives the true link direction and
angles from true poses, for a simulator to quantise into readings.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from odomgym.odometry.calibration import wrap_angle

__all__ = [
    "DeadReckoning",
    "GrowthRate",
    "Heading",
    "InternalEstimator",
    "LinkReading",
    "check_heading",
    "check_poses",
    "check_reading",
    "check_travel",
    "check_wheelbase",
    "dead_reckon",
    "growth_rate",
    "link_angles",
    "link_geometry",
    "link_length",
]

FloatArray = NDArray[np.float64]

Heading = Literal["current", "midpoint"]
"""Which orientation a dead-reckoning step moves along: ``"current"`` — the orientation at the
end of the interval (Borenstein 1995, Eq. 9); ``"midpoint"`` — the mean of the orientations at
the start and end (the chord direction on arcs; :mod:`odomgym.odometry.calibration`'s choice)."""

_HEADINGS: tuple[Heading, ...] = ("current", "midpoint")


class LinkReading(NamedTuple):
    """The linkage encoders at the end of a sampling interval (Borenstein 1995, §2).

    Attributes:
        length: measured centre distance l (N,) [m].
        psi: measured angles ψ_A, ψ_B of the trucks relative to the link (N, 2) [rad],
            ψ_X = θ_X − θ_L with θ_L the link direction from B to A.
    """

    length: FloatArray
    psi: FloatArray


class InternalEstimator(Protocol):
    """A pose estimator for N two-truck vehicles (see the module docstring for the arrays)."""

    def reset(self, poses: FloatArray, reading: LinkReading) -> None:
        """Start from the known poses (N, 2, 3) and the readings taken there."""
        ...

    def update(self, wheel_travel: FloatArray, reading: LinkReading) -> FloatArray:
        """Integrate one sampling interval's wheel travel (N, 2, 2) [m] and the readings at its
        end; return the estimated poses (N, 2, 3) after the interval (a new array)."""
        ...

    @property
    def correction(self) -> FloatArray:
        """The last orientation corrections Δ_A, Δ_B (N, 2) [rad] (Borenstein 1995, Eq. 12);
        zero for an estimator that does not correct."""
        ...


class GrowthRate(NamedTuple):
    """What one bump does within one sampling interval (Borenstein 1995, §3.3)."""

    lateral: float  # e_lat, the largest lateral error the interval can grow [m] (Eq. 6)
    link: float  # δ, its effect on the link direction [rad] (Eq. 7)
    measured: float  # θ_m = α − δ, the orientation error IPEC measures [rad] (Eq. 8)


def growth_rate(alpha: float, interval_travel: float, link: float) -> GrowthRate:
    """Borenstein 1995, Eqs. 6–8, the *growth-rate concept* behind IPEC: a bump turns a truck
    by α at once (a fast-growing orientation error), but in the one interval before the rotary
    encoders show it the truck can move sideways only by e_lat = D_s·sin α (Eq. 6), which turns
    the link by δ = asin(e_lat/L) (Eq. 7); IPEC therefore measures θ_m = α − δ (Eq. 8), missing
    only δ/θ_m of it (the paper: 2.3 % for α = 0.44°, D_s = 20 mm, L = 1 m)."""
    lateral = interval_travel * math.sin(alpha)
    link_error = math.asin(lateral / link)
    return GrowthRate(lateral, link_error, alpha - link_error)


def link_angles(poses: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The link direction θ_L (N,) [rad] and the angles ψ (N, 2) [rad] of poses (N, 2, 3).

    θ_L = atan2(y_A − y_B, x_A − x_B) points from truck B to truck A (Borenstein 1995, Eq. 10);
    ψ_X = θ_X − θ_L wrapped to [−π, π) (Eq. 11). Applied to true poses this is what ideal rotary
    encoders read; a simulator adds bias and quantisation.
    """
    theta_link, psi, _ = link_geometry(poses)
    return theta_link, psi


def link_geometry(poses: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`link_angles` and the centre distance l (N,) [m] in one pass over poses
    (N, 2, 3): what a simulator's encoders read every sampling interval."""
    p = check_poses(poses, copy=False)
    dx = p[:, 0, 0] - p[:, 1, 0]
    dy = p[:, 0, 1] - p[:, 1, 1]
    theta_link = np.arctan2(dy, dx)
    psi = wrap_angle(p[:, :, 2] - theta_link[:, None])
    return theta_link, np.asarray(psi, dtype=np.float64), np.asarray(np.hypot(dx, dy))


def link_length(poses: ArrayLike) -> FloatArray:
    """The centre distance l (N,) [m] of truck poses (N, 2, 3): what an ideal linear encoder
    reads."""
    p = check_poses(poses, copy=False)
    return np.asarray(np.hypot(p[:, 0, 0] - p[:, 1, 0], p[:, 0, 1] - p[:, 1, 1]))


def check_wheelbase(wheelbase: ArrayLike) -> FloatArray:
    """``wheelbase`` as a positive (N, 2) float array [m], or :class:`ValueError`."""
    b = np.array(wheelbase, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] == 0:
        raise ValueError(f"wheelbase must have shape (N, 2) [vehicle][truck], got {b.shape}")
    if not np.all(np.isfinite(b) & (b > 0.0)):
        raise ValueError(f"wheelbase must be positive and finite, got {b.tolist()}")
    return b


def dead_reckon(
    poses: FloatArray,
    wheel_travel: FloatArray,
    wheelbase: FloatArray,
    heading: Heading = "midpoint",
) -> tuple[FloatArray, FloatArray]:
    """One dead-reckoning step of every truck; returns (new poses (N, 2, 3), U (N, 2) [m]).

    Per truck, with believed wheel travel Δs_L, Δs_R [m] and wheelbase b [m]
    (Borenstein & Feng 1994, Eqs. 2.1–2.4; Borenstein 1995, Eq. 9):

        U = (Δs_R + Δs_L)/2,   Δθ = (Δs_R − Δs_L)/b,   θ_i = θ_{i−1} + Δθ,
        x_i = x_{i−1} + U cos φ,   y_i = y_{i−1} + U sin φ,

    with φ = θ_i (``heading="current"``) or θ_{i−1} + Δθ/2 (``"midpoint"``). U is the signed
    centre travel of the interval.
    """
    left = wheel_travel[:, :, 0]
    right = wheel_travel[:, :, 1]
    travel = 0.5 * (left + right)
    dtheta = (right - left) / wheelbase
    out = np.empty_like(poses)
    out[:, :, 2] = poses[:, :, 2] + dtheta
    along = out[:, :, 2] if heading == "current" else poses[:, :, 2] + 0.5 * dtheta
    out[:, :, 0] = poses[:, :, 0] + travel * np.cos(along)
    out[:, :, 1] = poses[:, :, 1] + travel * np.sin(along)
    return out, travel


def check_heading(heading: object) -> Heading:
    """``heading`` if it is one of :data:`Heading`'s values, else :class:`ValueError`."""
    for choice in _HEADINGS:
        if heading == choice:
            return choice
    raise ValueError(f"heading must be one of {_HEADINGS}, got {heading!r}")


def check_poses(poses: ArrayLike, n: int | None = None, *, copy: bool = True) -> FloatArray:
    """``poses`` as a (N, 2, 3) float array (N = ``n`` if given), or :class:`ValueError`.
    ``copy`` False: a float64 array comes back as it is, for a caller that only reads it (the
    CLAPPER's every control step, where the copy was wasted)."""
    p = np.array(poses, dtype=np.float64) if copy else np.asarray(poses, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (2, 3) or (n is not None and p.shape[0] != n):
        want = f"({n}, 2, 3)" if n is not None else "(N, 2, 3)"
        raise ValueError(f"poses must have shape {want} [vehicle][truck][x, y, θ], got {p.shape}")
    return p


def check_travel(wheel_travel: ArrayLike, n: int) -> FloatArray:
    """``wheel_travel`` as an (n, 2, 2) float array [m], or :class:`ValueError`."""
    t = np.asarray(wheel_travel, dtype=np.float64)
    if t.shape != (n, 2, 2):
        raise ValueError(
            f"wheel_travel must have shape ({n}, 2, 2) [vehicle][truck][left, right], got {t.shape}"
        )
    return t


def check_reading(reading: LinkReading, n: int) -> tuple[FloatArray, FloatArray]:
    """The reading's (length (n,), psi (n, 2)) as float arrays, or :class:`ValueError`."""
    length = np.asarray(reading.length, dtype=np.float64)
    psi = np.asarray(reading.psi, dtype=np.float64)
    if length.shape != (n,) or psi.shape != (n, 2):
        raise ValueError(
            f"reading must have length ({n},) and psi ({n}, 2), got {length.shape} and {psi.shape}"
        )
    return length, psi


class DeadReckoning:
    """Two independent odometries per vehicle: IPEC switched off.

    Each truck integrates its own wheel travel with the midpoint equations of
    :mod:`odomgym.odometry.calibration`; the link readings are ignored and :attr:`correction` stays
    zero.

    Args:
        wheelbase: the odometry's effective wheelbase of each truck (N, 2) [m]
            (``Odometry.effective_wheelbase``).
    """

    def __init__(self, wheelbase: ArrayLike) -> None:
        self._wheelbase = check_wheelbase(wheelbase)
        self.n = self._wheelbase.shape[0]
        self._poses = np.zeros((self.n, 2, 3))
        self._correction = np.zeros((self.n, 2))

    def reset(self, poses: FloatArray, reading: LinkReading) -> None:
        """Start from ``poses`` (N, 2, 3); ``reading`` is not used."""
        self._poses = check_poses(poses, self.n)

    def update(self, wheel_travel: FloatArray, reading: LinkReading) -> FloatArray:
        """Dead-reckon both trucks through one interval; returns the poses (N, 2, 3)."""
        travel = check_travel(wheel_travel, self.n)
        self._poses, _ = dead_reckon(self._poses, travel, self._wheelbase, "midpoint")
        return self._poses.copy()

    @property
    def poses(self) -> FloatArray:
        """The current estimate (N, 2, 3) (a copy)."""
        return self._poses.copy()

    @property
    def correction(self) -> FloatArray:
        """Always zero (N, 2) [rad]: dead reckoning does not correct."""
        return self._correction.copy()

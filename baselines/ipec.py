"""Internal Position Error Correction (IPEC) of a two-truck compliant-linkage vehicle.

J. Borenstein, *Internal Correction of Dead-reckoning Errors With a Dual-Drive Compliant Linkage
Mobile Robot*, J. Robotic Systems 12(4):257–273, 1995 (the CLAPPER). Two differential-drive
trucks, A in front and B behind, are joined at their centres by a compliant linkage that measures
the centre distance l and each truck's angle ψ to the link (:mod:`odomgym.internal`). A bump under
one wheel turns a truck at once (a *fast-growing* orientation error) but moves it sideways only
slowly (§3.3), so the link direction computed from the two dead-reckoned *positions* is still
accurate when the rotary encoders show that a truck has turned relative to the link. Once per
sampling interval, for every vehicle (Borenstein 1995, §4.1):

    (9)   each truck dead-reckons:  x_X = x_X + U_X cos θ_X,  y_X = y_X + U_X sin θ_X
    (10)  θ_L = atan2(y_A − y_B, x_A − x_B)                       (the link, from B to A)
    (11)  ψ_X,exp = θ_X − θ_L
    (12)  Δ_X = ψ_X,act − ψ_X,exp                                (wrapped to [−π, π))
    (13)  θ'_X = θ_X + Δ_X                                       (so θ'_X = θ_L + ψ_X,act)
    (14)  ΔD = b sin(½ Δ_A)
    (15)  truck A's centre rotated by Δ_A about the contact point of its non-slipping wheel
    (16)  x'_B = x'_A − l cos θ_L,   y'_B = y'_A − l sin θ_L      (l as measured)

Choices the paper leaves open, made here:

* **Eq. 9's orientation.** The paper moves each truck along the orientation at the *end* of the
  interval (``heading="current"``, the default); ``"midpoint"`` moves along the mean orientation
  (the chord direction on arcs).
* **Eq. 15's wheel.** The paper picks the wheel only in its example (a bump under the right wheel
  while driving forwards: rotate about the left wheel, so the centre moves backwards), following
  Banta's assumption that an encoder over-reports and never under-reports. In general, a wheel
  whose true travel is shorter in magnitude than reported turns the truck so that Δ_A has the
  sign of −(its travel) for the right wheel and +(its travel) for the left one. With both wheels
  rolling the same way this names one wheel: with s the sign of the truck's travel, the right
  wheel lagged if s·Δ_A < 0 and the left one if s·Δ_A > 0. Rotating the centre by Δ_A about the
  other wheel's contact point moves it by b sin(|Δ_A|/2) along θ_A + Δ_A/2, against the travel
  (Eq. 14 is this chord; Eq. 15 writes it along θ_A — the difference is ≈ 0.01 mm for 0.44°).
  When the wheels roll in opposite directions (turning in place included) or stand still, the
  rule names no wheel or both, and the translation is skipped; so it is when the wheel it names
  reported no travel (it cannot have over-reported). Truck B needs no such correction:
  Eq. 16 re-places it from A every interval. ``translation_correction=False`` skips Eq. 15
  altogether (the paper found it has "only minimal effect on the overall accuracy", §4.2).
* **Eq. 16's anchor.** The corrected x'_A (the paper does not say whether x_A or x'_A).

Identities worth knowing (tested): after every update θ'_X − θ_L − ψ_X,act = 0 (mod 2π), and
truck B sits exactly l_meas behind A along θ_L. IPEC therefore keeps no heading of its own: the
heading is the link direction — propagated only through positions — plus the absolute encoders.
A bias of a rotary encoder is thus invisible to it (§5.2), and so is the encoders' quantisation,
which acts as a bias of up to half a step.

:func:`estimate_wheel_diameter_ratio` is the §5.1 auto-calibration of unequal wheel diameters
from the corrections IPEC makes during straight travel on a smooth floor.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from odomgym.internal import (
    FloatArray,
    Heading,
    LinkReading,
    check_heading,
    check_poses,
    check_reading,
    check_travel,
    check_wheelbase,
    dead_reckon,
    link_angles,
)
from odomgym.odometry import wrap_angle

__all__ = ["CONFIGURATIONS", "IPEC", "estimate_wheel_diameter_ratio", "ipec_configuration"]


CONFIGURATIONS: dict[str, dict[str, object]] = {
    "paper": {"heading": "current", "translation_correction": True},
    "recommended": {
        "heading": "midpoint",
        "translation_correction": True,
        "translation_gate": "one count",
        "straight_only": True,
    },
    "heading-only": {"heading": "midpoint", "translation_correction": False},
}
"""Named IPEC configurations. ``paper``: Eqs. 9–16 as printed (Eq. 9 along the orientation at
the end of the interval; Eq. 15 whenever Δ_A ≠ 0). ``recommended``: Eq. 9 along the mid-interval
heading, Eq. 15 only for a correction of at least one count of the rotary encoder while truck A
drives straight. ``heading-only``: the mid-interval heading without Eq. 15 (the paper: it has
"only minimal effect on the overall accuracy", §4.2). ``docs/clapper.md`` compares them."""


def ipec_configuration(
    name: str, rotary_resolution: float = 2.0 * np.pi / 1024
) -> Callable[[ArrayLike], IPEC]:
    """An estimator factory (wheelbases (N, 2) → :class:`IPEC`) for the configuration ``name``
    of :data:`CONFIGURATIONS`; ``rotary_resolution`` [rad] is one count of the vehicle's rotary
    encoders (the ``recommended`` gate; default the CLAPPER's 10 bits)."""
    if name not in CONFIGURATIONS:
        raise ValueError(
            f"unknown IPEC configuration {name!r}; choose from {', '.join(CONFIGURATIONS)}"
        )
    options = dict(CONFIGURATIONS[name])
    if options.get("translation_gate") == "one count":
        options["translation_gate"] = float(rotary_resolution)
    return functools.partial(IPEC, **options)  # type: ignore[arg-type]


class IPEC:
    """Internal Position Error Correction, Borenstein 1995, Eqs. 9–16, for N vehicles.

    Implements :class:`odomgym.internal.InternalEstimator`; the module docstring lists the
    equations and the choices the paper leaves open.

    Args:
        wheelbase: the odometry's effective wheelbase of each truck (N, 2) [m]; also the b of
            Eq. 14.
        heading: the orientation Eq. 9 moves along, ``"current"`` (the paper's, default) or
            ``"midpoint"``.
        translation_correction: apply Eqs. 14–15 (the composite translational correction of
            truck A) [default True].
        translation_gate: Eq. 15 fires only when |Δ_A| is at least this [rad] (default 0:
            whenever Δ_A ≠ 0, as printed). With quantised readings Δ_A is (nearly) a whole
            number of counts, and a count that flips because ψ drifted across a step boundary
            looks like a bump: one count (``2π/2^bits``) is the gate of the ``recommended``
            configuration, which with ``straight_only`` keeps the printed rule where it holds.
        straight_only: Eq. 15 fires only while truck A drives straight (its dead-reckoned turn
            in the interval is under ``translation_gate``, both wheels rolling the same way):
            the paper derives it for a bump under one wheel in straight travel (§4.2, Fig. 5);
            in a turn every count change of ψ_A would move A backwards.
    """

    def __init__(
        self,
        wheelbase: ArrayLike,
        *,
        heading: Heading = "current",
        translation_correction: bool = True,
        translation_gate: float = 0.0,
        straight_only: bool = False,
    ) -> None:
        self._wheelbase = check_wheelbase(wheelbase)
        self.heading: Heading = check_heading(heading)
        self.translation_correction = bool(translation_correction)
        gate = float(translation_gate)
        if not (gate >= 0.0 and gate < np.pi):
            raise ValueError(f"translation_gate must be in [0, π) rad, got {translation_gate!r}")
        self.translation_gate = gate
        self.straight_only = bool(straight_only)
        self.n = self._wheelbase.shape[0]
        self._poses = np.zeros((self.n, 2, 3))
        self._correction = np.zeros((self.n, 2))
        self._travel = np.zeros((self.n, 2))
        self._link_direction = np.zeros(self.n)

    def reset(self, poses: FloatArray, reading: LinkReading) -> None:
        """Start from the known poses (N, 2, 3); ``reading`` is not needed (the poses are
        known, and the first update reconciles them with the encoders)."""
        self._poses = check_poses(poses, self.n)
        self._correction = np.zeros((self.n, 2))
        self._travel = np.zeros((self.n, 2))
        self._link_direction = link_angles(self._poses)[0]

    def update(self, wheel_travel: FloatArray, reading: LinkReading) -> FloatArray:
        """One sampling interval of Eqs. 9–16; returns the corrected poses (N, 2, 3)."""
        travel = check_travel(wheel_travel, self.n)
        length, psi = check_reading(reading, self.n)
        b = self._wheelbase
        # Eq. 9: each truck's own dead reckoning.
        poses, centre_travel = dead_reckon(self._poses, travel, b, self.heading)
        x, y = poses[:, :, 0], poses[:, :, 1]  # views: Eq. 15 moves A's in place
        theta = poses[:, :, 2].copy()  # Eq. 9's θ_A, θ_B (Eq. 15 rotates about θ_A)
        # Eq. 10: the link direction from B to A.
        theta_link = np.arctan2(y[:, 0] - y[:, 1], x[:, 0] - x[:, 1])
        # Eqs. 11–12: expected angles and corrections; Eq. 13: corrected orientations.
        expected = theta - theta_link[:, None]
        delta = np.asarray(wrap_angle(psi - expected), dtype=np.float64)
        poses[:, :, 2] = theta + delta
        # Eqs. 14–15: truck A rotated by Δ_A about the non-slipping wheel's contact point.
        if self.translation_correction:
            delta_a = delta[:, 0]
            left = travel[:, 0, 0]
            right = travel[:, 0, 1]
            same_way = left * right >= 0.0
            if self.translation_gate > 0.0:
                same_way &= np.abs(delta_a) >= self.translation_gate * (1.0 - 1e-9)
            if self.straight_only:
                turn = (right - left) / b[:, 0]
                same_way &= (np.abs(turn) < max(self.translation_gate, 1e-12)) & (
                    left * right > 0.0
                )
            right_lagged = same_way & (delta_a * right < 0.0)  # pivot: the left wheel
            left_lagged = same_way & (delta_a * left > 0.0)  # pivot: the right wheel
            side = right_lagged.astype(np.float64) - left_lagged.astype(np.float64)
            shift = side * b[:, 0] * np.sin(0.5 * delta_a)  # signed chord, Eq. 14 [m]
            along = theta[:, 0] + 0.5 * delta_a
            poses[:, 0, 0] += shift * np.cos(along)
            poses[:, 0, 1] += shift * np.sin(along)
        # Eq. 16: truck B re-placed l behind the corrected truck A.
        poses[:, 1, 0] = poses[:, 0, 0] - length * np.cos(theta_link)
        poses[:, 1, 1] = poses[:, 0, 1] - length * np.sin(theta_link)
        self._poses = poses
        self._correction = delta
        self._travel = centre_travel
        self._link_direction = theta_link
        return poses.copy()

    @property
    def poses(self) -> FloatArray:
        """The current estimate (N, 2, 3) (a copy)."""
        return self._poses.copy()

    @property
    def correction(self) -> FloatArray:
        """The last interval's orientation corrections Δ_A, Δ_B (N, 2) [rad] (Eq. 12)."""
        return self._correction.copy()

    @property
    def travel(self) -> FloatArray:
        """The last interval's dead-reckoned centre travel U_A, U_B (N, 2) [m] (signed)."""
        return self._travel.copy()

    @property
    def link_direction(self) -> FloatArray:
        """θ_L of the last interval (N,) [rad] (Eq. 10), from the dead-reckoned positions."""
        return self._link_direction.copy()


def estimate_wheel_diameter_ratio(
    correction_sum: ArrayLike,
    distance: ArrayLike,
    wheelbase: ArrayLike,
    odometry_ratio: ArrayLike = 1.0,
) -> FloatArray:
    """E_d = D_R/D_L of each truck from IPEC's corrections over straight travel (§5.1).

    Args:
        correction_sum: C = Σ sign(U_i)·Δ_i over the straight intervals [rad] (``IPEC.correction``
            times the sign of ``IPEC.travel``, per truck).
        distance: D = Σ |U_i| over the same intervals [m], the odometry's centre travel.
        wheelbase: the b the estimator used [m].
        odometry_ratio: the ratio c_R/c_L the odometry already applies
            (:attr:`odomgym.odometry.Calibration.e_d`; 1 for the nominal odometry).

    Returns ``odometry_ratio · (D + b·C/2)/(D − b·C/2)`` with the broadcast shape of the inputs.

    The paper gives no equations for its procedure ("monitoring the corrective actions of the
    CLAPPER while traveling on smooth surfaces"). Derivation: on a smooth floor the truck's
    wheels do not slip, and if the truck does not turn (straight travel, held by the linkage)
    both wheels cover the same true distance s_i per interval. The odometry believes
    Δs_X = k_X·s_i with k_X = c_X·E_s·D_n/D_X, so k_R/k_L = (c_R/c_L)·(D_L/D_R) = e_0/E_d. It
    turns the truck by (Δs_R − Δs_L)/b, and IPEC undoes exactly that: Δ_i = −(Δs_R − Δs_L)/b.
    Summing over the intervals (taking |·| so that backward legs add, and noting that a
    backward interval flips the sign of both Δs and Δ_i):

        R − L = −b·C,   R + L = 2D,   with R = Σ|Δs_R|, L = Σ|Δs_L|,

    so R = D − b·C/2, L = D + b·C/2 and E_d = e_0·L/R. To first order E_d ≈ e_0·(1 + b·C/D):
    a right wheel larger than believed makes dead reckoning turn right, IPEC correct left
    (C > 0), E_d > e_0. The wheelbase does not enter (the true turn is zero); E_s cancels.

    Error terms: Δ_i also holds the change of the estimated link direction (Eq. 7's δ: the
    sum telescopes to θ_L's drift over the run) and the change of the quantised readings
    between the first and last interval (at most one encoder step q); each adds b·(error)/D to
    E_d. Straight travel with a different E_d in the two trucks drifts θ_L by about
    Σ U_i·(Δθ_A,i − Δθ_B,i)/l (heading ``"current"``; half of it with ``"midpoint"``).
    """
    c = np.asarray(correction_sum, dtype=np.float64)
    d = np.asarray(distance, dtype=np.float64)
    b = np.asarray(wheelbase, dtype=np.float64)
    e0 = np.asarray(odometry_ratio, dtype=np.float64)
    if np.any(d <= 0.0):
        raise ValueError("distance must be positive: no straight travel was monitored")
    return np.asarray(e0 * (d + 0.5 * b * c) / (d - 0.5 * b * c), dtype=np.float64)

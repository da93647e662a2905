"""Internal Position Error Correction (IPEC) of a two-truck compliant-linkage vehicle.

J. Borenstein, *Internal Correction of Dead-reckoning Errors With a Dual-Drive Compliant Linkage
Mobile Robot*, J. Robotic Systems 12(4):257–273, 1995 (the CLAPPER). Two differential-drive
trucks, A in front and B behind, are joined at their centres by a compliant linkage that measures
the centre distance l and each truck's angle ψ to the link (:mod:`odomgym.vehicle.estimator`). A
bump under one wheel turns a truck at once (a *fast-growing* orientation error) but moves it
sideways only slowly (§3.3), so the link direction computed from the two dead-reckoned *positions*
is still accurate when the rotary encoders show that a truck has turned relative to the link. Once
per sampling interval, for every vehicle (Borenstein 1995, §4.1):

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
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from odomgym._jit import kernel
from odomgym.vehicle.estimator import (
    FloatArray,
    Heading,
    LinkReading,
    check_heading,
    check_poses,
    check_reading,
    check_travel,
    check_wheelbase,
    link_angles,
)

__all__ = [
    "CONFIGURATIONS",
    "DEFAULT_IPEC",
    "IPEC",
    "estimate_wheel_diameter_ratio",
    "ipec_configuration",
    "ipec_estimator",
]


CONFIGURATIONS: dict[str, dict[str, object]] = {
    "paper": {"heading": "current", "translation_correction": True},
    "recommended": {
        "heading": "midpoint",
        "translation_correction": True,
        "quantum": "one count",
        "translation_gate": "one count",
        "straight_only": True,
    },
    "gated": {
        "heading": "midpoint",
        "translation_correction": True,
        "translation_gate": "one count",
        "straight_only": True,
    },
    "heading-only": {"heading": "midpoint", "translation_correction": False},
}
"""Named IPEC configurations (``docs/clapper.md`` compares them on the paper's experiments).

* ``paper``: Eqs. 9–16 as printed (Eq. 9 along the orientation at the end of the interval,
  Eq. 15 whenever Δ_A ≠ 0). Every one-count flip of ψ_A moves truck A back by b·sin(q/2), so
  the rectangle ends centimetres and degrees off.
* ``gated``: Eq. 9 along the mid-interval heading; Eq. 15 only for |Δ_A| of at least one count
  while truck A drives straight. A follower that holds its encoder at a count boundary still
  flips it, so Eq. 15 still over-corrects.
* ``heading-only``: the mid-interval heading without Eq. 15 (which, the paper found, has "only
  minimal effect on the overall accuracy", §4.2): each cable's travel loss stays.
* ``recommended`` (the default of the runs and envs): the mid-interval heading, corrections
  consistent with the quantised readings (``quantum``: a flip corrects nothing, a bump is
  corrected to within half a count) and Eq. 15, with Eq. 12's full Δ_A, only when the reading
  is inconsistent with the dead reckoning while truck A drives straight.
"""


DEFAULT_IPEC = "recommended"
"""The IPEC configuration every CLAPPER run and env uses unless told otherwise
(:data:`CONFIGURATIONS`; ``docs/clapper.md`` says why)."""


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
    for key in ("translation_gate", "quantum"):
        if options.get(key) == "one count":
            options[key] = float(rotary_resolution)
    return functools.partial(IPEC, **options)  # type: ignore[arg-type]


class IPEC:
    """Internal Position Error Correction, Borenstein 1995, Eqs. 9–16, for N vehicles.

    Implements :class:`odomgym.vehicle.estimator.InternalEstimator`; the module docstring lists the
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
        quantum: one count of the rotary encoders [rad] (default 0: the readings are taken as
            exact, Eq. 13 as printed). When given, a reading says only that ψ lies within half
            a count of it, so Eq. 12's Δ_X is the *least* correction that brings the expected
            angle into that interval (0 when it already lies inside): a reading that flips
            because ψ drifted across a count boundary corrects nothing, while a bump's turn is
            corrected down to half a count. The estimate's heading then no longer equals
            θ_L + ψ_act exactly but stays within half a count of it.
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
        quantum: float = 0.0,
    ) -> None:
        self._wheelbase = check_wheelbase(wheelbase)
        self.heading: Heading = check_heading(heading)
        self.translation_correction = bool(translation_correction)
        gate = float(translation_gate)
        if not (gate >= 0.0 and gate < np.pi):
            raise ValueError(f"translation_gate must be in [0, π) rad, got {translation_gate!r}")
        self.translation_gate = gate
        self.straight_only = bool(straight_only)
        step = float(quantum)
        if not (step >= 0.0 and step < np.pi):
            raise ValueError(f"quantum must be in [0, π) rad, got {quantum!r}")
        self.quantum = step
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
        poses = np.empty_like(self._poses)
        delta = np.empty((self.n, 2))
        centre_travel = np.empty((self.n, 2))
        theta_link = np.empty(self.n)
        _update(
            self._poses,
            travel,
            length,
            psi,
            self._wheelbase,
            self.heading == "current",
            self.translation_correction,
            self.translation_gate,
            self.straight_only,
            self.quantum,
            poses,
            delta,
            centre_travel,
            theta_link,
        )
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


@kernel
def _update(
    previous: FloatArray,
    travel: FloatArray,
    length: FloatArray,
    psi: FloatArray,
    b: FloatArray,
    current: bool,
    translation: bool,
    gate: float,
    straight_only: bool,
    quantum: float,
    poses: FloatArray,
    delta: FloatArray,
    centre_travel: FloatArray,
    theta_link: FloatArray,
) -> None:
    """Eqs. 9–16 for every vehicle (the class docstring's options), in place into ``poses``
    (N, 2, 3), ``delta`` (N, 2), ``centre_travel`` (N, 2) and ``theta_link`` (N,): one compiled
    loop, because the per-interval arithmetic on a few numbers is all interpreter overhead in
    numpy (a CLAPPER run calls it 25 times per simulated second)."""
    two_pi = 2.0 * math.pi
    for i in range(previous.shape[0]):
        # Eq. 9: each truck's own dead reckoning.
        for k in range(2):
            left = travel[i, k, 0]
            right = travel[i, k, 1]
            u = 0.5 * (left + right)
            turn = (right - left) / b[i, k]
            heading = previous[i, k, 2] + turn
            along = heading if current else previous[i, k, 2] + 0.5 * turn
            poses[i, k, 0] = previous[i, k, 0] + u * math.cos(along)
            poses[i, k, 1] = previous[i, k, 1] + u * math.sin(along)
            poses[i, k, 2] = heading
            centre_travel[i, k] = u
        # Eq. 10: the link direction from B to A.
        link = math.atan2(poses[i, 0, 1] - poses[i, 1, 1], poses[i, 0, 0] - poses[i, 1, 0])
        theta_link[i] = link
        theta_a = poses[i, 0, 2]  # Eq. 9's θ_A: Eq. 15 rotates about it
        raw_a = 0.0
        # Eqs. 11–13 (Δ as the least consistent correction when ``quantum`` > 0).
        for k in range(2):
            d = (psi[i, k] - (poses[i, k, 2] - link) + math.pi) % two_pi - math.pi
            raw = d
            if quantum > 0.0:
                excess = abs(d) - 0.5 * quantum
                d = math.copysign(excess, d) if excess > 0.0 else 0.0
                if d == 0.0:
                    raw = 0.0
            delta[i, k] = d
            poses[i, k, 2] += d
            if k == 0:
                raw_a = raw
        # Eqs. 14–15: truck A rotated by Δ_A about the non-slipping wheel's contact point.
        if translation:
            left = travel[i, 0, 0]
            right = travel[i, 0, 1]
            fire = left * right >= 0.0
            if gate > 0.0:
                fire = fire and abs(raw_a) >= gate * (1.0 - 1e-9)
            if straight_only:
                bound = max(gate, quantum, 1e-12)
                fire = fire and abs((right - left) / b[i, 0]) < bound and left * right > 0.0
            side = 0.0
            if fire:
                if raw_a * right < 0.0:
                    side += 1.0  # the right wheel lagged: pivot on the left one
                if raw_a * left > 0.0:
                    side -= 1.0  # the left wheel lagged: pivot on the right one
            shift = side * b[i, 0] * math.sin(0.5 * raw_a)  # signed chord, Eq. 14 [m]
            along = theta_a + 0.5 * raw_a
            poses[i, 0, 0] += shift * math.cos(along)
            poses[i, 0, 1] += shift * math.sin(along)
        # Eq. 16: truck B re-placed l behind the corrected truck A.
        poses[i, 1, 0] = poses[i, 0, 0] - length[i] * math.cos(link)
        poses[i, 1, 1] = poses[i, 0, 1] - length[i] * math.sin(link)


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
            (:attr:`odomgym.odometry.calibration.Calibration.e_d`; 1 for the nominal odometry).

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


def ipec_estimator(
    configuration: str = DEFAULT_IPEC, rotary_resolution: float = 2.0 * math.pi / 1024
) -> Callable[[ArrayLike], IPEC]:
    """The CLAPPER's IPEC (Borenstein 1995, Eqs. 9-16) in one of the named configurations of
    :data:`CONFIGURATIONS` (``recommended`` by default), as the estimator factory a
    :class:`~odomgym.vehicle.trial.VehicleTrial` takes; ``rotary_resolution`` [rad] is one count of
    the vehicle's rotary encoders."""
    return ipec_configuration(configuration, rotary_resolution)

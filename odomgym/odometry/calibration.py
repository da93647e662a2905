"""Dead reckoning from encoder counts, and the calibration that corrects it.

The odometry knows only the nominal robot (wheel diameter D_n, wheelbase b_n, counts per
revolution C_e) and a :class:`Calibration`. Per sampling period, with encoder increments N_L, N_R
(Borenstein & Feng 1994, Eqs. 2.1–2.4, with the corrections of Eq. 6.35 and of solderspot 2014):

    Δs_L = c_L · E_s · π·D_n/C_e · N_L,   Δs_R = c_R · E_s · π·D_n/C_e · N_R
    Δs = (Δs_R + Δs_L)/2,   Δθ = (Δs_R − Δs_L) / b_eff,   b_eff = E_b,est · b_n
    x += Δs·cos(θ + Δθ/2),  y += Δs·sin(θ + Δθ/2),  θ += Δθ

(midpoint integration, as in the OptiOdom authors' model). Everything is batched over N robots.

**Skid-steer robots: the ICR offsets.** A skid-steer robot's sides do not turn about the wheels'
contacts but about instantaneous centres of rotation (ICRs) of their own (Mandow et al. 2007,
Eqs. 4–6): the left side's at (x_ICR, y_L), the right side's at (x_ICR, y_R) in the body frame.
With y_L − y_R = b_eff (the apparent track, E_b's expansion factor) and the two ICRs' midpoint
y_ICR = (y_L + y_R)/2, Mandow's equations are the equations above with two more terms per
period,

    Δs_fwd = Δs + y_ICR·Δθ,   Δs_left = −x_ICR·Δθ,
    x += Δs_fwd·cos(θ + Δθ/2) − Δs_left·sin(θ + Δθ/2),
    y += Δs_fwd·sin(θ + Δθ/2) + Δs_left·cos(θ + Δθ/2),

so :class:`Calibration` carries them as ``icr_x`` and ``icr_y`` [m], 0 for a differential-drive
robot (whose odometry is then exactly the equations above, bit for bit).

**Skid-steer robots: an apparent track that moves with the turn.** Wang et al. (2015) measured
the ICR coefficient of a skid-steer robot fall as its path straightens; with the path parameter
λ = (Δs_L + Δs_R)/(Δs_R − Δs_L) of each period (λ = 0 in a spin, |λ| → ∞ on a straight), the
odometry may take

    b_eff(λ) = b_n · (E_b + α / (1 + (β·|λ|)^p))

(their form with a free asymptote E_b and power p, as :mod:`odomgym.odometry.icr`'s curvature
model), so :class:`Calibration` carries α, β, p as ``track_alpha``, ``track_beta`` and
``track_power``; α = 0 (the default) is the constant b_eff = E_b·b_n above.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym._kernels import integrate_odometry
from odomgym.errors import (
    SpecError,
    locate_key,
    plain_number,
    read_spec_toml,
    refuse_stray_keys,
    require_finite,
    require_positive,
)
from odomgym.io import atomic_write_text
from odomgym.robot import RobotSpec

__all__ = [
    "ICR_REACH",
    "SKID_TERMS",
    "Calibration",
    "Odometry",
    "load_calibration",
    "path_parameter",
    "skid_terms",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Calibration:
    """Correction factors applied by the odometry (all dimensionless).

    Attributes:
        c_left, c_right: wheel correction factors c_L, c_R (Borenstein & Feng 1994, Eqs. 6.33–6.35).
        wheelbase_scale: E_b as estimated; the odometry uses b_eff = wheelbase_scale · b_n
            (Borenstein & Feng 1994, Eq. 6.28).
        distance_scale: E_s as estimated; multiplies both wheels' travel (solderspot 2014).
        icr_x: x_ICR, the sides' instantaneous centres of rotation ahead of the tracked point
            [m] (Mandow et al. 2007, Eq. 6): the body slides sideways by −x_ICR per radian
            turned. 0 for a differential-drive robot.
        icr_y: y_ICR, the midpoint of the two sides' ICRs to the left of the tracked point
            [m] ((y_L + y_R)/2 in Mandow et al. 2007's Eqs. 4–5; their spread y_L − y_R is the
            apparent track ``wheelbase_scale`` · b_n): the body moves forward by y_ICR per
            radian turned. 0 for a differential-drive robot.
        track_alpha, track_beta, track_power: α [-] ≥ 0, β [-] > 0 and p [-] > 0 of an
            apparent track that widens as the turn tightens, b_eff(λ) = b_n·(E_b + α/(1 +
            (β·|λ|)^p)) (module docstring; Wang et al. 2015's form). α = 0: a constant track.

    The identity calibration (all ones, ICR offsets and α 0) is the uncalibrated robot. The
    four factors, β and p must be positive; the ICR offsets finite, of either sign; α ≥ 0.
    """

    c_left: float = 1.0
    c_right: float = 1.0
    wheelbase_scale: float = 1.0
    distance_scale: float = 1.0
    icr_x: float = 0.0
    icr_y: float = 0.0
    track_alpha: float = 0.0
    track_beta: float = 1.0
    track_power: float = 1.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = plain_number(getattr(self, f.name))  # a NumPy scalar stored as a float
            object.__setattr__(self, f.name, value)
            _check_field(f.name, value)
        if self.track_alpha == 0.0:
            # Without a curve β and p act on nothing; their defaults keep equal calibrations
            # equal (and a file, which omits them, reads back the same).
            object.__setattr__(self, "track_beta", 1.0)
            object.__setattr__(self, "track_power", 1.0)

    @property
    def has_icr(self) -> bool:
        """Whether the calibration moves the sides' ICRs: the odometry then adds the ICR
        terms of the module docstring."""
        return self.icr_x != 0.0 or self.icr_y != 0.0

    @property
    def has_track_curve(self) -> bool:
        """Whether the apparent track moves with the turn (α ≠ 0, module docstring)."""
        return self.track_alpha != 0.0

    @property
    def is_skid_steer(self) -> bool:
        """Whether the calibration holds a skid-steer term (ICR offsets or a track that moves
        with the turn), which the models of a differential-drive odometry cannot apply."""
        return self.has_icr or self.has_track_curve

    def body_steps(
        self, left: FloatArray, right: FloatArray, track: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Each step's motion in the body frame — forward [m], leftward [m], turn [rad] — for
        the wheels' travel ``left``, ``right`` [m] (already corrected by the wheels' factors)
        and the nominal track b_n ``track`` [m]: the module docstring's equations, every
        skid-steer term included. The one numpy form of them (the compiled odometry has its
        own, :func:`odomgym._kernels.integrate_odometry`)."""
        difference = right - left
        if self.has_track_curve:
            dtheta = difference / (self.track_factor(path_parameter(left, right)) * track)
        else:
            dtheta = difference / (self.wheelbase_scale * track)
        return 0.5 * (left + right) + self.icr_y * dtheta, -self.icr_x * dtheta, dtheta

    def track_factor(self, lam: Any) -> FloatArray:
        """b_eff(λ)/b_n at path parameters ``lam`` [-] (a float or an array): E_b, plus the
        curve's α/(1 + (β·|λ|)^p) when :attr:`has_track_curve` (module docstring)."""
        lam = np.asarray(lam, dtype=float)
        if not self.has_track_curve:
            return np.full_like(lam, self.wheelbase_scale)
        shape = (self.track_beta * np.abs(lam)) ** self.track_power
        return np.asarray(self.wheelbase_scale + self.track_alpha / (1.0 + shape))

    # ------------------------------------------------------------------ conversions
    @classmethod
    def from_errors(cls, e_d: float = 1.0, e_b: float = 1.0, e_s: float = 1.0) -> Calibration:
        """The calibration that exactly compensates E_d, E_b, E_s.

        Borenstein & Feng 1994, Eqs. 6.28–6.34.
        """
        return cls(
            c_left=2.0 / (e_d + 1.0),
            c_right=2.0 / (1.0 / e_d + 1.0),
            wheelbase_scale=e_b,
            distance_scale=e_s,
        )

    @classmethod
    def from_parameters(
        cls,
        robot: RobotSpec,
        wheelbase: float,
        right_diameter: float,
        left_diameter: float,
    ) -> Calibration:
        """The calibration equivalent to explicit parameters (b, D_R, D_L) [m].

        Calibrators that publish parameters (OptiOdom's ``published_results.csv``) state them
        this way; the mean diameter becomes E_s and the ratio becomes c_L, c_R.
        """
        mean = 0.5 * (right_diameter + left_diameter)
        return cls(
            c_left=left_diameter / mean,
            c_right=right_diameter / mean,
            wheelbase_scale=wheelbase / robot.wheelbase,
            distance_scale=mean / robot.wheel_diameter,
        )

    def parameters(self, robot: RobotSpec) -> dict[str, float]:
        """The effective parameters the calibrated odometry uses: b, D_R, D_L [m] (b on a
        straight path), for a calibration that moves the ICRs (:attr:`has_icr`) Mandow et al.
        2007's y_L, y_R and x_ICR [m], and for a track that moves with the turn
        (:attr:`has_track_curve`) the track in a spin, ``spin_wheelbase`` [m]."""
        out = {
            "wheelbase": self.wheelbase_scale * robot.wheelbase,
            "right_diameter": self.c_right * self.distance_scale * robot.wheel_diameter,
            "left_diameter": self.c_left * self.distance_scale * robot.wheel_diameter,
        }
        if self.has_icr:
            out["icr_y_left"] = self.icr_y + 0.5 * out["wheelbase"]
            out["icr_y_right"] = self.icr_y - 0.5 * out["wheelbase"]
            out["icr_x"] = self.icr_x
        if self.has_track_curve:
            out["spin_wheelbase"] = float(self.track_factor(0.0)) * robot.wheelbase
        return out

    @property
    def e_d(self) -> float:
        """The wheel-diameter ratio this calibration assumes, c_R / c_L."""
        return self.c_right / self.c_left

    def then(self, other: Calibration) -> Calibration:
        """Compose: ``other`` was estimated on a robot already corrected by ``self``.

        Used by iterated calibration (Borenstein & Feng 1994, §6.3 "second compensation";
        solderspot 2014): every factor multiplies. The ICR offsets [m] add: ``other``'s are
        what the robot still showed beyond ``self``'s (exact when ``other``'s factors are 1,
        to first order in them otherwise). A track curve's α scales with the other's E_b (to
        first order: the inner curve sees λ of the outer-corrected travels); two curves do
        not compose (ValueError).
        """
        if self.has_track_curve and other.has_track_curve:
            raise ValueError("two calibrations whose tracks both move with the turn do not compose")
        curve = self if self.has_track_curve else other
        return Calibration(
            c_left=self.c_left * other.c_left,
            c_right=self.c_right * other.c_right,
            wheelbase_scale=self.wheelbase_scale * other.wheelbase_scale,
            distance_scale=self.distance_scale * other.distance_scale,
            icr_x=self.icr_x + other.icr_x,
            icr_y=self.icr_y + other.icr_y,
            track_alpha=curve.track_alpha
            * (other.wheelbase_scale if curve is self else self.wheelbase_scale),
            track_beta=curve.track_beta,
            track_power=curve.track_power,
        )

    def ros2_parameters(self) -> dict[str, float]:
        """ros2_control ``diff_drive_controller`` multipliers equivalent to this calibration.

        diff_drive_controller computes wheel travel as ``radius · multiplier · Δφ`` and the
        heading change with ``wheel_separation · wheel_separation_multiplier``, so
        ``left_wheel_radius_multiplier = c_L·E_s``, ``right_wheel_radius_multiplier = c_R·E_s``
        and ``wheel_separation_multiplier = E_b``.
        """
        return {
            "wheel_separation_multiplier": self.wheelbase_scale,
            "left_wheel_radius_multiplier": self.c_left * self.distance_scale,
            "right_wheel_radius_multiplier": self.c_right * self.distance_scale,
        }

    def ros2_yaml(self) -> str:
        """A ros2_control ``diff_drive_controller`` parameter file equivalent to this
        calibration (the multipliers of :meth:`ros2_parameters`), what ``odomgym calibrate
        --export ros2`` writes; rename its top-level key to the controller's node name."""
        lines = [
            "# ros2_control diff_drive_controller parameters equivalent to an odomgym calibration.",
            "# Rename the top-level key to your controller's node name. "
            "Mapping (odomgym.odometry):",
            "#   wheel_separation_multiplier = E_b, "
            "{left,right}_wheel_radius_multiplier = c_{L,R}*E_s",
            "diff_drive_controller:",
            "  ros__parameters:",
        ]
        for key, value in self.ros2_parameters().items():
            lines.append(f"    {key}: {value:.9f}")
        if self.has_icr:
            lines.append(
                "# Not expressible in diff_drive_controller, which turns about the wheels' "
                f"midpoint: the ICR offsets icr_x = {self.icr_x:.6f} m, icr_y = {self.icr_y:.6f} m"
                " (Mandow et al. 2007)."
            )
        if self.has_track_curve:
            lines.append(
                "# Not expressible in diff_drive_controller, whose wheel separation is constant: "
                f"the track's curve alpha = {self.track_alpha:.6f}, beta = {self.track_beta:.6f}, "
                f"p = {self.track_power:.6f} (Wang et al. 2015); the multiplier above is its "
                "straight-path value."
            )
        return "\n".join(lines) + "\n"

    # ------------------------------------------------------------------ TOML
    def to_dict(self) -> dict[str, float]:
        """A TOML-ready dict; the skid-steer terms only when they act (ICR offsets not 0, a
        track curve's α not 0), so that a differential-drive calibration is written as it
        always was."""
        out = dataclasses.asdict(self)
        if not self.has_icr:
            del out["icr_x"], out["icr_y"]
        if not self.has_track_curve:
            del out["track_alpha"], out["track_beta"], out["track_power"]
        return out

    def save(self, path: str | Path) -> None:
        """Write ``[calibration]`` TOML atomically."""
        import tomli_w

        atomic_write_text(Path(path), tomli_w.dumps({"calibration": self.to_dict()}))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, path: Path | None = None) -> Calibration:
        """Build from a mapping; errors name the field, file and line."""
        refuse_stray_keys(data, "calibration", path)
        table = dict(data.get("calibration", data))
        names = {f.name for f in dataclasses.fields(cls)}
        for key, value in table.items():
            where = locate_key(path, key) if path else None
            if key not in names:
                raise SpecError(
                    f"unknown calibration field {key!r}; known: {', '.join(sorted(names))}",
                    field=key,
                    source=where,
                )
            _check_field(key, value, source=where)
        return cls(**table)


_OFFSETS = ("icr_x", "icr_y")
"""The fields of a :class:`Calibration` that are lengths of either sign, not factors."""


def _check_field(name: str, value: object, *, source: str | None = None) -> None:
    """A factor must be a positive number, an ICR offset a finite one within
    :data:`ICR_REACH`, α a finite one ≥ 0 (:class:`SpecError` naming the field, and the file
    and line when ``source`` says them)."""
    if name in _OFFSETS:
        if abs(require_finite(name, value, source=source)) > ICR_REACH:
            raise SpecError(
                f"{name} must be within ±{ICR_REACH:g} m of the tracked point, got {value!r} "
                "(a value in millimetres?)",
                field=name,
                source=source,
            )
    elif name == "track_alpha":
        if require_finite(name, value, source=source) < 0.0:
            raise SpecError(f"{name} must be >= 0, got {value!r}", field=name, source=source)
    else:
        require_positive(name, value, source=source)


ICR_REACH = 100.0
"""The farthest an ICR offset (x_ICR, y_ICR) may lie from the tracked point [m]. Why: the
offsets sit within a wheeled robot's body, or a marker's lever arm beyond it, a few metres at
most (``skid_icr`` fits them within ten tracks); a larger one is a unit slip (the command
line prints them in mm), and an offset of 1e300 m made the reference driver's wheel rates
overflow."""


def load_calibration(path: str | Path) -> Calibration:
    """Load a calibration TOML written by ``odomgym calibrate --save`` (or by hand)."""
    file = Path(path)
    return Calibration.from_dict(read_spec_toml(file, "calibration"), path=file)


def path_parameter(left: FloatArray, right: FloatArray) -> FloatArray:
    """Each step's path parameter λ = (L + R)/(R − L) [-] of the wheels' travel (0 in a spin);
    a step that does not turn (|R − L| ≤ 10⁻¹² m) gets a finite, huge λ: the straight-path
    track."""
    difference = right - left
    return np.asarray((right + left) / np.where(np.abs(difference) > 1e-12, difference, 1e-12))


SKID_TERMS = 5
"""Columns of :func:`skid_terms`."""


def skid_terms(calibration: Calibration) -> tuple[float, float, float, float, float]:
    """A calibration's skid-steer terms as :func:`odomgym._kernels.integrate_odometry` reads
    them: x_ICR, y_ICR [m], α/E_b (the track curve relative to the straight-path track), β, p
    [-]. All zeros for a differential-drive calibration, which the kernel tells by its first
    three."""
    if not calibration.is_skid_steer:
        return (0.0, 0.0, 0.0, 0.0, 0.0)
    return (
        calibration.icr_x,
        calibration.icr_y,
        calibration.track_alpha / calibration.wheelbase_scale,
        calibration.track_beta,
        calibration.track_power,
    )


class Odometry:
    """Batched dead reckoning for N robots from cumulative encoder counts.

    Args:
        robots: the robots' specs; only their *nominal* parameters are used.
        calibration: one calibration for all, or one per robot.
    """

    def __init__(
        self,
        robots: RobotSpec | Sequence[RobotSpec],
        calibration: Calibration | Sequence[Calibration] | None = None,
    ) -> None:
        specs = [robots] if isinstance(robots, RobotSpec) else list(robots)
        self.n = len(specs)
        self._metres_per_tick = np.array([s.metres_per_tick for s in specs])
        self._nominal_wheelbase = np.array([s.wheelbase for s in specs])
        # Allocated once and updated in place: a Trial's compiled step holds them
        # (odomgym._kernels.StepArrays).
        self._travel_per_tick = np.zeros((self.n, 2))
        self._wheelbase = np.zeros(self.n)
        self._skid = np.zeros((self.n, SKID_TERMS))
        self.pose = np.zeros((self.n, 3))
        self.last_counts = np.zeros((self.n, 2), dtype=np.int64)
        self.wheel_speed = np.zeros((self.n, 2))
        self.calibrations: list[Calibration] = [Calibration()] * self.n
        self.set_calibration(calibration if calibration is not None else Calibration())

    def set_calibration(
        self, calibration: Calibration | Sequence[Calibration], index: int | None = None
    ) -> None:
        """Change the correction factors, for all robots or robot ``index``; takes effect at
        the next update (the pose so far is kept)."""
        if isinstance(calibration, Calibration):
            if index is None:
                self.calibrations = [calibration] * self.n
            else:
                self.calibrations[index] = calibration
        else:
            cals = list(calibration)
            if len(cals) != self.n:
                raise ValueError(f"need {self.n} calibrations, got {len(cals)}")
            self.calibrations = cals
        cal = self.calibrations
        scale = np.array([c.distance_scale for c in cal])
        self._travel_per_tick[:] = np.stack(
            [
                np.array([c.c_left for c in cal]) * scale * self._metres_per_tick,
                np.array([c.c_right for c in cal]) * scale * self._metres_per_tick,
            ],
            axis=1,
        )
        self._wheelbase[:] = np.array([c.wheelbase_scale for c in cal]) * self._nominal_wheelbase
        self._skid[:] = np.array([skid_terms(c) for c in cal])

    @property
    def travel_per_tick(self) -> FloatArray:
        """Wheel travel per encoder count as the calibrated odometry believes it (N, 2) [m]."""
        return self._travel_per_tick

    @property
    def effective_wheelbase(self) -> FloatArray:
        """b_eff = E_b,est · b_n of each robot (N,) [m]."""
        return np.asarray(self._wheelbase)

    @property
    def skid_terms(self) -> FloatArray:
        """Each robot's skid-steer terms (N, :data:`SKID_TERMS`) as the compiled odometry reads
        them (:func:`skid_terms`; zeros for a differential-drive calibration)."""
        return self._skid

    def reset(
        self, poses: FloatArray | None = None, indices: NDArray[np.intp] | None = None
    ) -> None:
        """Restart the estimate at ``poses`` (K, 3) with encoder counts at zero."""
        if indices is None:
            indices = np.arange(self.n)
        self.pose[indices] = 0.0 if poses is None else poses
        self.last_counts[indices] = 0
        self.wheel_speed[indices] = 0.0

    def update(self, counts: NDArray[np.int64], dt: float) -> FloatArray:
        """Integrate the increment from the last cumulative ``counts`` (N, 2); returns ``pose``.

        ``pose`` and ``wheel_speed`` (N, 2) [m/s] are updated in place; copy them to keep a
        history. ``dt`` [s] only serves the wheel-speed estimate.
        """
        integrate_odometry(
            counts,
            self.last_counts,
            self._travel_per_tick,
            self._wheelbase,
            self._skid,
            1.0 / dt,
            self.pose,
            self.wheel_speed,
        )
        return self.pose


def wrap_angle(angle: Any) -> Any:
    """Wrap angles to [−π, π) [rad]; works on floats and arrays."""
    return np.mod(np.asarray(angle) + math.pi, 2.0 * math.pi) - math.pi

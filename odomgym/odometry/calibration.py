"""Dead reckoning from encoder counts, and the calibration that corrects it.

The odometry knows only the nominal robot (wheel diameter D_n, wheelbase b_n, counts per
revolution C_e) and a :class:`Calibration`. Per sampling period, with encoder increments N_L, N_R
(Borenstein & Feng 1994, Eqs. 2.1–2.4, with the corrections of Eq. 6.35 and of solderspot 2014):

    Δs_L = c_L · E_s · π·D_n/C_e · N_L,   Δs_R = c_R · E_s · π·D_n/C_e · N_R
    Δs = (Δs_R + Δs_L)/2,   Δθ = (Δs_R − Δs_L) / b_eff,   b_eff = E_b,est · b_n
    x += Δs·cos(θ + Δθ/2),  y += Δs·sin(θ + Δθ/2),  θ += Δθ

(midpoint integration, as in the OptiOdom authors' model). Everything is batched over N robots.
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
from odomgym.errors import SpecError, locate_key, read_spec_toml, require_positive
from odomgym.io import atomic_write_text
from odomgym.robot import RobotSpec

__all__ = ["Calibration", "Odometry", "load_calibration"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Calibration:
    """Correction factors applied by the odometry (all dimensionless).

    Attributes:
        c_left, c_right: wheel correction factors c_L, c_R (Borenstein & Feng 1994, Eqs. 6.33–6.35).
        wheelbase_scale: E_b as estimated; the odometry uses b_eff = wheelbase_scale · b_n
            (Borenstein & Feng 1994, Eq. 6.28).
        distance_scale: E_s as estimated; multiplies both wheels' travel (solderspot 2014).

    The identity calibration (all ones) is the uncalibrated robot.
    """

    c_left: float = 1.0
    c_right: float = 1.0
    wheelbase_scale: float = 1.0
    distance_scale: float = 1.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            require_positive(f.name, getattr(self, f.name))

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
        """The effective parameters the calibrated odometry uses: b, D_R, D_L [m]."""
        return {
            "wheelbase": self.wheelbase_scale * robot.wheelbase,
            "right_diameter": self.c_right * self.distance_scale * robot.wheel_diameter,
            "left_diameter": self.c_left * self.distance_scale * robot.wheel_diameter,
        }

    @property
    def e_d(self) -> float:
        """The wheel-diameter ratio this calibration assumes, c_R / c_L."""
        return self.c_right / self.c_left

    def then(self, other: Calibration) -> Calibration:
        """Compose: ``other`` was estimated on a robot already corrected by ``self``.

        Used by iterated calibration (Borenstein & Feng 1994, §6.3 "second compensation";
        solderspot 2014): every factor multiplies.
        """
        return Calibration(
            c_left=self.c_left * other.c_left,
            c_right=self.c_right * other.c_right,
            wheelbase_scale=self.wheelbase_scale * other.wheelbase_scale,
            distance_scale=self.distance_scale * other.distance_scale,
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
        return "\n".join(lines) + "\n"

    # ------------------------------------------------------------------ TOML
    def to_dict(self) -> dict[str, float]:
        """A TOML-ready dict."""
        return dataclasses.asdict(self)

    def save(self, path: str | Path) -> None:
        """Write ``[calibration]`` TOML atomically."""
        import tomli_w

        atomic_write_text(Path(path), tomli_w.dumps({"calibration": self.to_dict()}))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, path: Path | None = None) -> Calibration:
        """Build from a mapping; errors name the field, file and line."""
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
            require_positive(key, value, source=where)
        return cls(**table)


def load_calibration(path: str | Path) -> Calibration:
    """Load a calibration TOML written by ``odomgym calibrate --save`` (or by hand)."""
    file = Path(path)
    return Calibration.from_dict(read_spec_toml(file, "calibration"), path=file)


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

    @property
    def travel_per_tick(self) -> FloatArray:
        """Wheel travel per encoder count as the calibrated odometry believes it (N, 2) [m]."""
        return self._travel_per_tick

    @property
    def effective_wheelbase(self) -> FloatArray:
        """b_eff = E_b,est · b_n of each robot (N,) [m]."""
        return np.asarray(self._wheelbase)

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
            1.0 / dt,
            self.pose,
            self.wheel_speed,
        )
        return self.pose


def wrap_angle(angle: Any) -> Any:
    """Wrap angles to [−π, π) [rad]; works on floats and arrays."""
    return np.mod(np.asarray(angle) + math.pi, 2.0 * math.pi) - math.pi

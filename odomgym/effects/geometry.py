"""The geometric effects: wheel-diameter ratio, effective wheelbase, mean-diameter scale.

They are the systematic errors of Borenstein & Feng (1994, §2.3, Eqs. 6.24–6.32) and of the
scaling error E_s, and they already are physics: the :class:`~odomgym.robot.RobotSpec` holds the
true diameters and wheelbase the World simulates with. So these entries only translate between
the catalogue's parameters and those fields; they need no World hook and no replay stage (the
replay takes the geometry from the spec).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

from odomgym.effects.registry import Effect, Parameter, Spec, SpecView

__all__ = ["DistanceScale", "WheelDiameterRatio", "Wheelbase"]


class _Geometric(Effect):
    """An effect stored in the spec's true geometry rather than in ``spec.effects``."""

    error: ClassVar[str] = ""  # "e_d", "e_b" or "e_s": RobotSpec property and with_errors name
    in_table: ClassVar[bool] = False

    def read(self, spec: SpecView) -> dict[str, float]:
        return {self.error: float(getattr(spec, self.error))}

    def write(self, spec: Spec, values: Mapping[str, float]) -> Spec:
        value = self.validate(values)[self.error]
        return spec.with_errors(**{self.error: value})


class WheelDiameterRatio(_Geometric):
    """E_d = D_R/D_L ≠ 1 with the mean diameter unchanged (Borenstein & Feng 1994, Eq. 6.24)."""

    name = "wheel_diameter_ratio"
    error = "e_d"
    parameters = (
        Parameter("e_d", "-", 1.0, 0.5, 2.0, 1e-3, "right/left effective wheel diameter"),
    )
    summary = "unequal wheel diameters: the robot curves on straight runs"
    reveals = "straight runs (heading drift per metre); squares cw vs ccw"


class Wheelbase(_Geometric):
    """E_b = b_actual/b_nominal ≠ 1 (Borenstein & Feng 1994, Eq. 6.29)."""

    name = "wheelbase"
    error = "e_b"
    parameters = (Parameter("e_b", "-", 1.0, 0.5, 2.0, 1e-3, "effective/nominal wheelbase"),)
    summary = "effective wheelbase differs: every turn is over- or under-rotated in proportion"
    reveals = "in-place turns of several angles (error proportional to the angle); squares"


class DistanceScale(_Geometric):
    """E_s = D̄/D_n ≠ 1: the mean wheel diameter differs from the nominal one."""

    name = "distance_scale"
    error = "e_s"
    parameters = (Parameter("e_s", "-", 1.0, 0.5, 2.0, 1e-3, "mean/nominal wheel diameter"),)
    summary = "mean wheel diameter differs: distances are over- or under-counted"
    reveals = "long straight runs with ground truth along the track (not closed loops)"

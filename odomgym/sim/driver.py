"""Reference drivers: plain policy objects that perform the odometry experiments.

:class:`ReferenceDriver` maps an env observation (layout: :mod:`odomgym.sim.trial`,
:data:`odomgym.sim.trial.OBSERVATION_NAMES`)
to wheel-speed actions. It drives the UMBmark manoeuvres the way Borenstein & Feng 1994, §6.3,
describe — 0.2 m/s on the legs, a complete stop, an on-the-spot turn with the wheels at about
±0.2 m/s — with trapezoidal speed profiles that respect the robot's acceleration limit, so a
well-behaved robot does not slip. It steers by the robot's own odometry; it never sees the true
pose.

It is batched: ``act`` takes one observation (D,) or a batch (N, D).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.errors import SpecError
from odomgym.robot import RobotSpec

__all__ = ["ReferenceDriver"]

FloatArray = NDArray[np.float64]


class ReferenceDriver:
    """Follow a route of drives and in-place turns by odometry.

    Args:
        robot: the robot (its *nominal* wheelbase, speed and acceleration limits are used).
        cruise_speed: speed on straight legs [m/s] (UMBmark: 0.2 m/s).
        turn_wheel_speed: wheel rim speed during in-place turns [m/s]; default: the cruise
            speed (UMBmark: ≈ ±0.2 m/s at 0.2 m/s on the legs, Borenstein & Feng 1994, §6.3).
        accel_fraction: fraction of the robot's wheel acceleration limit used for planning
            the stops, so the velocity controller can always follow [-].
        approach_gain: final-approach gain [1/s]: speed = gain × remaining distance, so the
            robot creeps onto its target instead of overshooting by a control period.
        heading_gain: heading-hold gain on legs [1/s]; cross_gain: cross-track gain [1/m²].
    """

    def __init__(
        self,
        robot: RobotSpec,
        *,
        cruise_speed: float = 0.2,
        turn_wheel_speed: float | None = None,
        accel_fraction: float = 0.5,
        approach_gain: float = 2.0,
        heading_gain: float = 2.0,
        cross_gain: float = 5.0,
    ) -> None:
        if not 0 < cruise_speed:
            raise SpecError(
                f"cruise_speed must be > 0 m/s, got {cruise_speed!r}", field="cruise_speed"
            )
        if cruise_speed > robot.max_wheel_speed:
            # A robot spec may allow less than the experiments' speed (max_wheel_speed from
            # 1 mm/s): said as the robot's limit, the field a user set, not as a bug.
            raise SpecError(
                f"the experiments drive at {cruise_speed:g} m/s, above this robot's "
                f"max_wheel_speed of {robot.max_wheel_speed:g} m/s: raise max_wheel_speed in "
                "its spec if the motors allow it, or drive slower (cruise_speed)",
                field="max_wheel_speed",
            )
        self.robot = robot
        self.cruise_speed = cruise_speed
        turn = cruise_speed if turn_wheel_speed is None else turn_wheel_speed
        self.turn_wheel_speed = min(turn, robot.max_wheel_speed)
        self.accel = accel_fraction * robot.max_wheel_accel
        self.approach_gain = approach_gain
        self.heading_gain = heading_gain
        self.cross_gain = cross_gain
        self._half_b = 0.5 * robot.wheelbase

    def __call__(self, observation: FloatArray) -> FloatArray:
        """Alias of :meth:`act`, so the driver is a callable policy."""
        return self.act(observation)

    def act(self, observation: FloatArray) -> FloatArray:
        """Wheel-speed actions in [−1, 1] (fractions of ``max_wheel_speed``), left then right.

        ``observation`` is one row (D,) or a batch (N, D) in the layout of :mod:`odomgym.sim.trial`.
        """
        obs = np.asarray(observation)
        single = obs.ndim == 1
        batch = obs.reshape(1, -1) if single else obs
        actions = np.empty((batch.shape[0], 2))
        _drive(
            batch,
            self.cruise_speed,
            self.turn_wheel_speed,
            self.accel,
            self.approach_gain,
            self.heading_gain,
            self.cross_gain,
            self._half_b,
            self.robot.max_wheel_speed,
            actions,
        )
        return actions[0] if single else actions


@kernel
def _drive(
    obs: NDArray[np.floating],
    cruise_speed: float,
    turn_wheel_speed: float,
    accel: float,
    approach_gain: float,
    heading_gain: float,
    cross_gain: float,
    half_b: float,
    max_speed: float,
    actions: FloatArray,
) -> None:
    """The reference control law, one robot per row (see :class:`ReferenceDriver`)."""
    for i in range(obs.shape[0]):
        remaining = float(obs[i, 0])
        cross = float(obs[i, 1])
        heading_error = float(obs[i, 2])  # wrapped; a turn's rotation left is obs[i, 0]
        direction = float(obs[i, 6])
        if obs[i, 5] > 0.5:
            # Turn in place: trapezoid on the wheel arc (b/2)·|Δψ| left, then a final creep.
            arc = half_b * abs(remaining)
            wheel = min(turn_wheel_speed, math.sqrt(2.0 * accel * arc), approach_gain * arc)
            omega = math.copysign(wheel, remaining) / half_b
            v = 0.0
        else:
            # Straight leg: trapezoid on the distance left, final creep, heading hold. The
            # cross-track term scales with the signed speed, so it steers the right way when
            # reversing and fades out as the robot stops.
            ahead = max(remaining, 0.0)
            speed = min(cruise_speed, math.sqrt(2.0 * accel * ahead), approach_gain * ahead)
            v = speed * direction
            omega = heading_gain * heading_error - cross_gain * cross * v
        actions[i, 0] = min(max((v - omega * half_b) / max_speed, -1.0), 1.0)
        actions[i, 1] = min(max((v + omega * half_b) / max_speed, -1.0), 1.0)

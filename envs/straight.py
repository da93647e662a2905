"""``StraightLine-v0``: drive straight for D metres, optionally back again."""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from typing import Any

from odomgym.envs.base import RewardWeights, RouteEnv, route_size
from odomgym.errors import require_bool, require_known_options
from odomgym.floor import FloorSpec
from odomgym.odometry.calibration import Calibration
from odomgym.robot import RobotSpec
from odomgym.sim.routes import Route, straight_route

__all__ = ["StraightLineEnv", "StraightRoute"]


@dataclass(frozen=True)
class StraightRoute:
    """The episode's straight run from the ``reset`` options: ``distance`` [m] out, and back
    if ``return_trip`` (or ``options["return_trip"]``); shared by the single and vector env."""

    distance: float
    return_trip: bool

    def __post_init__(self) -> None:
        straight_route(self.distance, self.return_trip)  # validate now

    def __call__(self, options: dict[str, Any]) -> Route:
        require_known_options(options, ("return_trip",), "StraightLine-v0")
        back = require_bool("options['return_trip']", options.get("return_trip", self.return_trip))
        return straight_route(self.distance, back)


class StraightLineEnv(RouteEnv):
    """## Description

    The robot drives ``distance`` metres along +x by its own odometry and stops; with
    ``return_trip`` it then drives back to the start *backwards* without turning — the CLAPPER's
    straight-line experiment (Borenstein 1995, §6.1: 18 m out and back, cables under the right
    wheels on the return leg). Cable bumps and friction patches come from the floor spec, so a
    bump under one wheel turns the robot by the geometric amount while the odometry notices
    nothing (Borenstein 1995, Table I).

    ## Action Space

    ``Box(-1, 1, (2,), float32)``: left and right wheel speed commands as fractions of the
    robot's ``max_wheel_speed`` [m/s]; values outside [−1, 1] are clipped, NaN or ±inf raise
    ``ValueError``.

    ## Observation Space

    ``Box((8,), float32)`` in the odometry frame: distance left on the current leg [m], lateral
    offset from the leg's line (left +) [m], target heading − odometry heading [rad], left and
    right encoder wheel speed / max wheel speed, 0 (no turns on this route), +1 on the way out
    and −1 on the way back (driving backwards), share of the route completed.

    ## Rewards

    ``progress`` (share of the route completed this step, by odometry, × 1.0), ``time``
    (−0.001 per step), ``completion`` (+1.0 when done); terms in ``info["reward_terms"]``.

    ## Starting State

    At rest at the origin heading +x; the odometry starts there too.

    ## Episode End

    Terminated when the odometry says the last leg is done and both wheels stopped; truncated by
    ``max_episode_steps`` (4000 steps = 200 s by default).

    ## Info

    Every step: ``odom_pose``, ``true_pose`` (x, y [m], θ [rad]), ``pose_error`` (true −
    odometry, θ wrapped), ``encoder_counts``, ``segment``, ``time`` [s since the episode
    began], ``reward_terms``; at the end ``return_error``: true − odometry at the finish, in the
    start frame [m, m, rad]. With ``covariance_k``, ``odom_covariance`` (Chong & Kleeman 1997,
    Eqs. 23-28).

    ## Arguments

    ``robot`` (preset name, ``.toml`` path or :class:`~odomgym.robot.RobotSpec`; default
    ``"labmate"``), ``floor`` (a floor preset name, a ``.toml`` path or
    :class:`~odomgym.floor.FloorSpec`), ``calibration`` (a
    :class:`~odomgym.odometry.calibration.Calibration` or its ``.toml`` path), ``distance`` [m]
    (default 10.0), ``return_trip`` (default False; also a ``reset`` option ``{"return_trip":
    True}``), ``dt`` [s] (control period, default 0.05), ``reward_weights``, ``render_mode``,
    ``covariance_k`` (k_L, k_R [m^½] or None).

    ## Version History

    * v0: initial version.
    * v0, compatible addition (issue 43): ``robot`` may be a skid-steer robot (the presets
      ``"scout2"``, ``"husky"``, ``"pioneer3at"``, ``"jackal"`` or a spec with
      ``axle_spacing > 0``), on every floor (cables and friction patches act under each of its
      four wheels, ``docs/skid-steer.md``); the rendering draws the robot's wheels (two, or
      four).
    """

    def __init__(
        self,
        robot: RobotSpec | str | PathLike[str] = "labmate",
        floor: FloorSpec | str | PathLike[str] = "smooth",
        calibration: Calibration | str | PathLike[str] | None = None,
        *,
        distance: float = 10.0,
        return_trip: bool = False,
        dt: float = 0.05,
        reward_weights: RewardWeights | None = None,
        render_mode: str | None = None,
        covariance_k: tuple[float, float] | None = None,
    ) -> None:
        super().__init__(
            robot,
            floor,
            calibration,
            dt=dt,
            reward_weights=reward_weights,
            render_mode=render_mode,
            covariance_k=covariance_k,
        )
        self.distance = route_size("distance", distance)
        self.route_rule = StraightRoute(self.distance, require_bool("return_trip", return_trip))
        self.return_trip = bool(return_trip)

    def _route(self, options: dict[str, Any]) -> Route:
        return self.route_rule(options)

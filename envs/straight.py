"""``StraightLine-v0``: drive straight for D metres, optionally back again."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from odomgym.envs.base import RewardWeights, RouteEnv
from odomgym.floor import FloorSpec
from odomgym.odometry import Calibration
from odomgym.paths import Route, straight_route
from odomgym.robot import RobotSpec

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
        return straight_route(self.distance, bool(options.get("return_trip", self.return_trip)))


class StraightLineEnv(RouteEnv):
    """## Description

    The robot drives ``distance`` metres along +x by its own odometry and stops; with
    ``return_trip`` it then drives back to the start *backwards* without turning — the CLAPPER's
    straight-line experiment (seed 002 §6.1: 18 m out and back, cables under the right wheels on
    the return leg). Cable bumps and friction patches come from the floor spec, so a bump under
    one wheel turns the robot by the geometric amount while the odometry notices nothing (seed
    002 Table I).

    ## Action Space, Observation Space, Rewards, Info

    As :class:`odomgym.envs.umbmark.UMBmarkSquareEnv` (``return_error`` at the end is the
    true − odometry pose at the finish, in the start frame).

    ## Starting State

    At rest at the origin heading +x.

    ## Episode End

    Terminated when the odometry says the last leg is done and the wheels stopped; truncated by
    ``max_episode_steps`` (4000 steps = 200 s by default).

    ## Arguments

    ``robot``, ``floor``, ``calibration``, ``dt``, ``reward_weights``, ``render_mode`` as
    UMBmarkSquare, and ``covariance_k``; ``distance`` [m] (default 10.0); ``return_trip``
    (default False; also a ``reset`` option).

    ## Version History

    * v0: initial version.
    """

    def __init__(
        self,
        robot: RobotSpec | str = "labmate",
        floor: FloorSpec | str = "smooth",
        calibration: Calibration | str | None = None,
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
        self.route_rule = StraightRoute(float(distance), bool(return_trip))
        self.distance = float(distance)
        self.return_trip = bool(return_trip)

    def _route(self, options: dict[str, Any]) -> Route:
        return self.route_rule(options)

"""``UMBmarkSquare-v0``: the bi-directional square path of Borenstein & Feng's UMBmark."""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from typing import Any, Literal

from odomgym.envs.base import RewardWeights, RouteEnv, route_size
from odomgym.errors import require_known_options
from odomgym.floor import FloorSpec
from odomgym.odometry.calibration import Calibration
from odomgym.robot import RobotSpec
from odomgym.sim.routes import Route, square_route

__all__ = ["SquareRoute", "UMBmarkSquareEnv"]


@dataclass(frozen=True)
class SquareRoute:
    """The episode's square from the ``reset`` options: ``side`` [m], and ``direction`` unless
    ``options["direction"]`` names another (shared by the single and the vector env)."""

    side: float
    direction: Literal["cw", "ccw"]

    def __post_init__(self) -> None:
        square_route(self.side, self.direction)  # validate now, not at the first reset

    def __call__(self, options: dict[str, Any]) -> Route:
        require_known_options(options, ("direction",), "UMBmarkSquare-v0")
        return square_route(self.side, options.get("direction", self.direction))


class UMBmarkSquareEnv(RouteEnv):
    """## Description

    A robot (differential-drive, or skid-steer: Version History) drives the UMBmark square
    (Borenstein & Feng 1994, §3.2 and §6.3): four legs of ``side`` metres, a complete stop and
    a 90° turn in place at the end of each leg (the fourth turn restores the starting heading),
    clockwise or counter-clockwise. The robot steers by its *own odometry*; its true motion comes
    from a pymunk rigid-body simulation with friction-limited wheels, so systematic errors (E_d,
    E_b, E_s of the robot spec) and floor effects (slip, cable bumps, roughness) make the true
    path drift from the odometry path — which is what UMBmark measures. Run it with
    :class:`odomgym.sim.driver.ReferenceDriver` to perform the benchmark, or learn a policy.

    ## Action Space

    ``Box(-1, 1, (2,), float32)``: left and right wheel speed commands as fractions of the
    robot's ``max_wheel_speed`` [m/s]. Values outside [−1, 1] are clipped; NaN or ±inf raise
    ``ValueError``. A per-wheel velocity controller follows the command within the robot's
    acceleration limit.

    ## Observation Space

    ``Box((8,), float32)``, all in the odometry frame:

    | idx | name | unit |
    |-----|------|------|
    | 0 | distance left on a leg, or rotation left to turn (unwrapped) | m / rad |
    | 1 | lateral offset from the leg's line (left +) | m |
    | 2 | target heading − odometry heading, wrapped to [−π, π) | rad |
    | 3, 4 | left, right wheel speed from the encoders / max wheel speed | - |
    | 5 | 1 during a turn, 0 on a leg | - |
    | 6 | +1 driving forwards, −1 backwards | - |
    | 7 | share of the route completed | - |

    ## Rewards

    ``progress`` (share of the route completed this step, by odometry, × 1.0), ``time``
    (−0.001 per step) and ``completion`` (+1.0 when done); weights in ``reward_weights``, terms in
    ``info["reward_terms"]``.

    ## Starting State

    The robot rests at the origin heading +x; the odometry starts there too.

    ## Episode End

    Terminated when the robot's odometry says it completed the last turn and both wheels are
    stopped. Truncated by ``max_episode_steps`` (6000 steps = 300 s by default).

    ## Info

    Every step: ``odom_pose``, ``true_pose`` (x, y [m], θ [rad], unwrapped), ``pose_error``
    (true − odometry, θ wrapped), ``encoder_counts`` (left, right), ``segment``, ``time`` [s],
    ``reward_terms``. At the end: ``return_error`` (ε_x, ε_y [m], ε_θ [rad]) in the UMBmark
    convention (Borenstein & Feng 1994, §6.1): true − odometry in the start frame (origin at
    the start, +x the initial heading; cw squares go toward −y). With
    ``covariance_k=(k_L, k_R)``, also ``odom_covariance``: the 3×3 covariance [m², m·rad, rad²]
    the Chong & Kleeman model (Chong & Kleeman 1997, Eqs. 23-28) predicts for the odometry
    pose, so a 95 % error ellipse can be drawn next to the true error.

    ## Arguments

    ``robot`` (preset name, ``.toml`` path or :class:`~odomgym.robot.RobotSpec`; default
    ``"labmate"``), ``floor`` (``"smooth"``, ``"bumpy"``, ``"slippery"``, ``"rough"``, a ``.toml``
    path or :class:`~odomgym.floor.FloorSpec`), ``calibration`` (a
    :class:`~odomgym.odometry.calibration.Calibration` or its ``.toml`` path), ``side`` [m] (default
    4.0), ``direction`` (``"cw"``/``"ccw"``; also a ``reset`` option ``{"direction": ...}``), ``dt``
    [s] (control period in (0, 1], default 0.05), ``reward_weights`` (a
    :class:`~odomgym.envs.base.RewardWeights` or a dict of its fields), ``render_mode``,
    ``covariance_k`` (k_L, k_R [m^½] of the wheel-noise model, or None).

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
        side: float = 4.0,
        direction: Literal["cw", "ccw"] = "cw",
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
        self.side = route_size("side", side)
        self.route_rule = SquareRoute(self.side, direction)
        self.direction: Literal["cw", "ccw"] = direction

    def _route(self, options: dict[str, Any]) -> Route:
        return self.route_rule(options)

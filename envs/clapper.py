"""``ClapperStraight-v0`` and ``ClapperRectangle-v0``: the CLAPPER's experiments of Borenstein
1995, §6, as Gymnasium envs.

## Description

The vehicle (:mod:`odomgym.vehicle.spec`) is two LabMate trucks joined by a compliant linkage; it
drives a programmed path (:mod:`odomgym.vehicle.trial`) and knows where it is only through its
estimator: IPEC (``ipec=True``, :class:`odomgym.vehicle.ipec.IPEC`) or each truck's plain
wheel odometry (``ipec=False``), or any :class:`odomgym.vehicle.estimator.InternalEstimator` factory
passed as ``estimator``.

## Action Space

``Box(0, 1, (1,))``: the vehicle-level motion command, the speed along the programmed path as
a fraction of the cruise speed (0.45 m/s, §6: "slightly below 0.5 m/sec"). The low-level
controller steers the leading truck along the path by its estimated pose, holds the other's
rotary encoder at the path's expected angle and keeps the linkage near its centre; it slows for
curves and stops at the end of each leg whatever the action asks (a command cannot drive the
trucks into the bearing's stops).

## Observation Space

``Box((12,), float32)``:

| idx | name | unit |
|-----|------|------|
| 0–2 | truck A's estimated pose in the path's frame (x, y, θ) | m, m, rad |
| 3–5 | truck B's estimated pose (x, y, θ) | m, m, rad |
| 6 | link length l (internal linear encoder) | m |
| 7, 8 | ψ_A, ψ_B (internal rotary encoders) | rad |
| 9 | share of the path done | - |
| 10 | leg (0, 1, …) | - |
| 11 | reference speed | m/s |

## Rewards

The share of the path completed this step (1 in total), minus 0.001 per step; the truth is
reported in ``info``, never rewarded (the vehicle cannot know it).

## Starting State

Truck A at the path's first point facing along it (against it for a backward first leg), truck
B one link length behind (:meth:`odomgym.vehicle.paths.VehiclePath.start_poses`); the
estimator and each truck's odometry start at these true poses.

## Episode End

Terminated when the path is driven (the vehicle stops at its end); truncated by the registered
step limit (``max_episode_steps``).

## Info

``true_poses``, ``estimated_poses`` (IPEC-corrected with ``ipec=True``),
``odometry_poses`` (each truck's own wheel odometry) — each (2, 3) for trucks A, B;
``link_length`` [m] and ``psi`` (2,) [rad], the internal encoder readings;
``correction`` (2,), the estimator's orientation corrections this step [rad];
``vehicle_error`` (3,), true minus estimated pose of the vehicle (midpoint of the truck centres,
heading of the link); ``truck_errors`` (2, 3), the same for each truck's own pose;
``link_force`` [N], the force the bearing's end stops pass now (a trailer's: the hitch's
towing force), and ``link_force_max`` the largest so far; ``cable_crossings`` (2,), how
many times the wheels of truck A and of truck B have passed over a cable; and, on the last
step, ``return_error`` (the vehicle's) and ``truck_return_errors`` (2, 3).

## Arguments

Both envs: ``vehicle`` (a preset — ``clapper``, ``clapper-uncalibrated``, ``trailer`` for the
§7 encoder trailer —, a vehicle ``.toml`` path or a :class:`~odomgym.vehicle.spec.VehicleSpec`),
``floor`` (a floor preset, ``.toml`` path or :class:`~odomgym.floor.FloorSpec`; default
``concrete``), ``bumps`` (cables laid, default 10), ``ipec`` (True: IPEC's ``recommended``
configuration; False: each truck's plain dead reckoning), ``estimator`` (any
:class:`~odomgym.vehicle.estimator.InternalEstimator` factory, instead of IPEC),
``render_mode``; ``ClapperStraight-v0`` also ``length`` (of each leg [m], default 18);
``ClapperRectangle-v0`` also ``direction`` (``"cw"``/``"ccw"``; a ``reset`` option
``{"direction": …}`` too, for that episode) and ``side`` (which wheels cross the cables,
``"left"``/``"right"``); ``ClapperStraight-v0`` reads no ``reset`` option (any is
refused). Defaults: the ``clapper`` vehicle (two calibrated LabMates), the ``concrete``
floor (:data:`odomgym.vehicle.trial.CLAPPER_FLOOR`, the same as the CLI's and the tests') and
the ``recommended`` IPEC configuration.

## Rendering

``render_mode="rgb_array"`` (an (H, W, 3) uint8 frame per ``render()``) or ``"human"`` (a
pygame window), with the ``[render]`` extra; ``metadata["render_fps"]`` is 1/T_s (25
frames/s), so frames play back in real time. A frame shows the programmed path (grey), the
cables laid so far (brown), both trucks at their true poses (blue outlines, "A" and "B") and
at their estimated poses (thin green), the linkage between their centres with its current
length in the header (red when it is within 1 cm of an end stop; for the encoder trailer, the
rigid tongue), the true paths (blue), the estimator's paths (green: IPEC's, or plain dead
reckoning with ``ipec=False``) and each truck's own wheel odometry (orange for A, purple for
B). The view grows to keep every path on screen. With ``render_mode=None`` (the default)
nothing is drawn or kept for drawing.

## Version History

* v0: initial version. Rendering (``render_mode``, ``"human"`` and ``"rgb_array"``) was added
  in odomgym 0.2.0 without changing spaces, dynamics, reward or ``info``: a compatible
  addition, so the version stays v0.
"""

from __future__ import annotations

from os import PathLike
from typing import Any, Literal

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from odomgym.envs.base import DrawsLazily, describe_action, real_array, reset_options
from odomgym.errors import SpecError, require_bool, require_known_options
from odomgym.floor import CableBump, FloorSpec, load_floor
from odomgym.vehicle.cable_layout import CableLayer, evenly, rectangle_cable_positions
from odomgym.vehicle.ipec import ipec_estimator
from odomgym.vehicle.paths import VehiclePath, rectangle_path, straight_path
from odomgym.vehicle.spec import VehicleSpec, load_vehicle
from odomgym.vehicle.trial import CLAPPER_FLOOR, EstimatorFactory, VehicleTrial

__all__ = ["ClapperEnv", "ClapperRectangleEnv", "ClapperStraightEnv"]

FloatArray = NDArray[np.float64]


MAX_BUMPS = 1000
"""The most cables an env lays (one every 36 mm of the 36 m straight run)."""


def _whole(name: str, value: object) -> int:
    """``value`` as a whole number from 0 to :data:`MAX_BUMPS`, or a ValueError naming
    ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{name} must be a whole number >= 0, got {value!r}")
    if value > MAX_BUMPS:
        raise ValueError(f"{name} must be at most {MAX_BUMPS}, got {value!r}")
    return int(value)


class ClapperEnv(DrawsLazily, gym.Env[NDArray[np.float32], NDArray[np.float32]]):
    """Base of the CLAPPER envs (module docstring): subclasses give the path and the cables."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 25}  # noqa: RUF012

    def __init__(
        self,
        vehicle: VehicleSpec | str | PathLike[str] = "clapper",
        floor: FloorSpec | str | PathLike[str] = CLAPPER_FLOOR,
        *,
        ipec: bool = True,
        estimator: EstimatorFactory | None = None,
        render_mode: str | None = None,
    ) -> None:
        self._set_render_mode(render_mode)
        # Not str() first: a number (floor=123) became the name "123" ("unknown floor '123'")
        # where the route envs say what type they take.
        self.vehicle = load_vehicle(vehicle)
        self.floor = load_floor(floor)
        if estimator is not None and not callable(estimator):
            raise ValueError("estimator must build an InternalEstimator from wheelbases (N, 2)")
        if estimator is not None and not require_bool("ipec", ipec):
            raise ValueError(
                "give ipec=False or an estimator, not both (an estimator replaces IPEC)"
            )
        self.ipec = require_bool("ipec", ipec) and estimator is None
        self._estimator: EstimatorFactory | None = estimator or (
            ipec_estimator(rotary_resolution=self.vehicle.rotary_resolution) if self.ipec else None
        )
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / self.vehicle.sample_period}
        self.action_space = gym.spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float32)
        high = np.array([1e3, 1e3, 1e4, 1e3, 1e3, 1e4, 10.0, 4.0, 4.0, 1.0, 10.0, 10.0])
        low = -high
        low[[9, 10, 11]] = 0.0
        self.observation_space = gym.spaces.Box(
            low.astype(np.float32), high.astype(np.float32), dtype=np.float32
        )
        self._trial: VehicleTrial | None = None
        # Kept only when rendering (render_mode None: nothing is recorded for drawing).
        self._trace: Any = None

    # ------------------------------------------------------------------ to implement
    def _path(self, options: dict[str, Any]) -> VehiclePath:
        """The episode's path from the ``reset`` options (each env names the ones it reads and
        refuses any other)."""
        raise NotImplementedError

    def _cables(self, path: VehiclePath) -> CableLayer | None:
        raise NotImplementedError

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        super().reset(seed=seed)
        path = self._path(reset_options(options))
        self._trial = VehicleTrial(
            self.vehicle,
            self.floor,
            path,
            estimator=self._estimator,
            cables=self._cables(path),
            rng=self.np_random,  # a rough floor's wheel noise: the seed makes runs repeat
        )
        self._total = sum(leg.length for leg in path.legs)
        self._done_before = 0.0
        if self.render_mode is not None:
            from odomgym.envs.render import VehicleTrace

            self._trace = VehicleTrace.empty()
            self._record()
            if self.render_mode == "human":
                self.render()
        return self._observation(), self._info(np.zeros(2), final=False)

    def step(
        self, action: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        trial = self._trial
        if trial is None:
            raise RuntimeError("call reset() before step()")
        if trial.done.all():
            raise RuntimeError("the episode has terminated; call reset() first")
        command = real_array(action, "one finite number in [0, 1]").reshape(-1)
        if command.shape != (1,) or not np.isfinite(command).all():
            raise ValueError(
                f"action must be one finite number in [0, 1], got {describe_action(action)}"
            )
        trial.step(np.clip(command, 0.0, 1.0))
        done_now = self._path_done()
        reward = (done_now - self._done_before) / self._total - 0.001
        self._done_before = done_now
        terminated = bool(trial.done.all())
        info = self._info(trial.estimator.correction[0], final=terminated)
        if self.render_mode is not None:
            self._record()
            if self.render_mode == "human":
                self.render()
        return self._observation(), float(reward), terminated, False, info

    # ------------------------------------------------------------------ rendering
    def _record(self) -> None:
        """Keep this step's poses for drawing (only called when rendering)."""
        trial = self._trial
        assert trial is not None and self._trace is not None
        self._trace.add(
            trial.truth[0], trial.estimated[0], trial.odometry.pose.reshape(trial.n, 2, 3)[0]
        )

    def render(self) -> NDArray[np.uint8] | None:
        """Top-down view of the run so far (module docstring, "Rendering")."""
        mode = self._render_mode_or_warn()
        if mode is None:
            return None
        trial = self._trial
        if trial is None:
            raise RuntimeError("call reset() before render()")
        from odomgym.envs.render import VehicleRenderer

        if self._renderer is None:
            spec = self.vehicle
            if self.ipec:
                label = "IPEC estimate"
            elif self._estimator is not None:
                label = "estimate (given estimator)"
            else:
                label = "estimate (no IPEC)"
            self._renderer = VehicleRenderer(
                (spec.truck_a, spec.truck_b),
                self.floor,
                [leg.points for leg in trial.path.legs],
                mode,
                self.metadata["render_fps"],
                estimator_label=label,
                link_range=None if spec.trailer else (spec.link_min, spec.link_max),
                names=(
                    (("truck", "truck"), ("trailer", "trailer"))
                    if spec.trailer
                    else (("A", "truck A"), ("B", "truck B"))
                ),
            )
        legs = len(trial.path.legs)
        leg = min(int(trial.driver.leg_index[0]), legs - 1) + 1
        mode = "IPEC on" if self.ipec else "IPEC off"
        status = f"t = {trial.time:6.2f} s   leg {leg}/{legs}   {mode}"
        laid: tuple[CableBump, ...] = tuple(trial.cables.laid) if trial.cables else ()
        return self._renderer.draw(self._trace, laid, status)  # type: ignore[no-any-return]

    # ------------------------------------------------------------------ helpers
    def _path_done(self) -> float:
        trial = self._trial
        assert trial is not None
        driver = trial.driver
        legs = trial.path.legs
        k = int(driver.leg_index[0])
        before = sum(leg.length for leg in legs[:k])
        return before + (float(driver.reference_arc[0]) if k < len(legs) else 0.0)

    def _observation(self) -> NDArray[np.float32]:
        trial = self._trial
        assert trial is not None
        driver = trial.driver
        obs = np.concatenate(
            [
                trial.estimated[0].reshape(-1),
                [trial.reading.length[0]],
                trial.reading.psi[0],
                [
                    self._path_done() / self._total,
                    float(driver.leg_index[0]),
                    float(driver.reference_speed[0]),
                ],
            ]
        )
        return obs.astype(np.float32)

    def _info(self, correction: FloatArray, *, final: bool) -> dict[str, Any]:
        trial = self._trial
        assert trial is not None
        vehicle, trucks = trial.errors()
        info: dict[str, Any] = {
            "true_poses": trial.truth[0].copy(),
            "estimated_poses": trial.estimated[0].copy(),
            "odometry_poses": trial.odometry.pose.reshape(trial.n, 2, 3)[0].copy(),
            "link_length": float(trial.reading.length[0]),
            "psi": trial.reading.psi[0].copy(),
            "correction": np.asarray(correction, dtype=np.float64).copy(),
            "vehicle_error": vehicle[0],
            "truck_errors": trucks[0].copy(),
            "link_force": float(trial.current_link_force()[0]),
            "link_force_max": float(trial.link_force[0]),
            "cable_crossings": trial.cable_crossings[0].copy(),
            "time": trial.time,
        }
        if final:
            info["return_error"] = vehicle[0].copy()
            info["truck_return_errors"] = trucks[0].copy()
        return info


class ClapperStraightEnv(ClapperEnv):
    """``ClapperStraight-v0``: 18 m straight forwards and 18 m back *backwards* (Borenstein
    1995, §6.1), with ``bumps`` 10 mm cables laid under the right-side wheels on the return leg,
    evenly spaced from 1.5 m to 16.5 m. Spaces, reward, end and ``info``: module docstring."""

    def __init__(
        self,
        vehicle: VehicleSpec | str | PathLike[str] = "clapper",
        floor: FloorSpec | str | PathLike[str] = CLAPPER_FLOOR,
        *,
        bumps: int = 10,
        length: float = 18.0,
        ipec: bool = True,
        estimator: EstimatorFactory | None = None,
        render_mode: str | None = None,
    ) -> None:
        bumps = _whole("bumps", bumps)
        if not isinstance(length, (int, float)) or not 3.5 < length < 1e3:
            raise ValueError(
                f"length must be a number of metres in (3.5, 1000) (cables sit 1.5 m from "
                f"each end), got {length!r}"
            )
        self.bumps, self.length = int(bumps), float(length)
        super().__init__(vehicle, floor, ipec=ipec, estimator=estimator, render_mode=render_mode)

    def _path(self, options: dict[str, Any]) -> VehiclePath:
        require_known_options(options, (), "ClapperStraight-v0")
        return straight_path(self.length)

    def _cables(self, path: VehiclePath) -> CableLayer | None:
        return CableLayer(evenly(self.bumps, self.length), leg=1) if self.bumps else None


class ClapperRectangleEnv(ClapperEnv):
    """``ClapperRectangle-v0``: the 7×4 m rectangle with smooth 90° turns passing each corner
    within 0.2 m without stopping (Borenstein 1995, §6.2), ``direction`` cw or ccw, with
    ``bumps`` 10 mm cables under the ``side`` wheels on the straight parts. Spaces, reward, end
    and ``info``: module docstring."""

    def __init__(
        self,
        vehicle: VehicleSpec | str | PathLike[str] = "clapper",
        floor: FloorSpec | str | PathLike[str] = CLAPPER_FLOOR,
        *,
        direction: Literal["cw", "ccw"] = "cw",
        bumps: int = 10,
        side: Literal["left", "right"] = "right",
        ipec: bool = True,
        estimator: EstimatorFactory | None = None,
        render_mode: str | None = None,
    ) -> None:
        if direction not in ("cw", "ccw"):
            raise ValueError(f"direction must be 'cw' or 'ccw', got {direction!r}")
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        bumps = _whole("bumps", bumps)
        self.direction, self.bumps, self.side = direction, bumps, side
        super().__init__(vehicle, floor, ipec=ipec, estimator=estimator, render_mode=render_mode)

    def _path(self, options: dict[str, Any]) -> VehiclePath:
        require_known_options(options, ("direction",), "ClapperRectangle-v0")
        direction = options.get("direction", self.direction)
        if direction not in ("cw", "ccw"):
            raise SpecError(
                f"options['direction'] must be 'cw' or 'ccw', got {direction!r}",
                field="options.direction",
            )
        return rectangle_path(direction=direction)

    def _cables(self, path: VehiclePath) -> CableLayer | None:
        if not self.bumps:
            return None
        positions = rectangle_cable_positions(path, self.bumps, trailing=self.vehicle.link_length)
        return CableLayer(positions, leg=0, side=self.side)

"""Driving two-truck vehicles (the CLAPPER, Borenstein 1995) in the World, with or without
internal position error correction.

:func:`drive_vehicles` runs N vehicles in one :class:`~odomgym.sim.world.World` (2N trucks, N
links), sampling the encoders every T_s and feeding the estimator, and returns each vehicle's
true and estimated poses at the end. The paths are :mod:`odomgym.vehicle.paths`, the controller
:mod:`odomgym.vehicle.controller`, the cables laid on the way :mod:`odomgym.vehicle.cable_layout`.

Units: metres, radians, seconds.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from odomgym.floor import FloorSpec
from odomgym.odometry.calibration import Calibration, Odometry, wrap_angle
from odomgym.odometry.runs import require_differential
from odomgym.sim.world import World
from odomgym.vehicle.cable_layout import (
    CableLayer,
    cable_arrays,
    crossings,
    free_wheel_rim,
    wheel_sides,
)
from odomgym.vehicle.controller import VehicleDriver
from odomgym.vehicle.estimator import DeadReckoning, InternalEstimator, link_angles, link_length
from odomgym.vehicle.paths import VehiclePath
from odomgym.vehicle.spec import VehicleSpec, link_readings

__all__ = [
    "CLAPPER_FLOOR",
    "EstimatorFactory",
    "VehicleOutcome",
    "VehicleTrial",
    "drive_vehicles",
    "vehicle_pose",
]

FloatArray = NDArray[np.float64]

CLAPPER_FLOOR = "concrete"
"""The one floor of the CLAPPER experiments — the CLI's, the envs' and the tests' default: the
paper ran on "fairly smooth concrete floors" (Borenstein 1995, §6), and the ``concrete``
floor's wheel noise is what makes runs of one condition differ (``odomgym.floor``)."""


def vehicle_pose(poses: FloatArray) -> FloatArray:
    """The vehicle's pose (N, 3) from truck poses (N, 2, 3): the midpoint of the truck centres
    and the heading of the linkage (from B to A)."""
    mid = 0.5 * (poses[:, 0, :2] + poses[:, 1, :2])
    return np.column_stack([mid, link_angles(poses)[0]])


def wheel_contacts(pose: FloatArray, half_track: FloatArray) -> FloatArray:
    """Contact points (M, 2, 2) [m] of the left and right wheels of bodies at ``pose`` (M, 3),
    ``half_track`` (M,) [m] to either side of the heading (left at +y in the body frame)."""
    left = np.stack([-np.sin(pose[:, 2]), np.cos(pose[:, 2])], axis=1) * half_track[:, None]
    return np.stack([pose[:, :2] + left, pose[:, :2] - left], axis=1)


EstimatorFactory = Callable[[FloatArray], InternalEstimator]
"""Builds an estimator from the odometry's wheelbases (N, 2) [m] (e.g. ``DeadReckoning`` or
``odomgym.vehicle.ipec.IPEC``)."""


@dataclass(frozen=True)
class VehicleOutcome:
    """The end of a run of N vehicles (arrays with a leading vehicle axis).

    ``true_poses``, ``estimated`` and ``odometry`` are truck poses (N, 2, 3): the truth, the
    estimator's, and each truck's own wheel odometry. ``return_error`` (N, 3) is the vehicle's
    true minus estimated pose (:func:`vehicle_pose`: midpoint of the truck centres, heading of
    the link; heading wrapped), ``truck_errors`` (N, 2, 3) the same per truck. ``link_range``
    (N, 2) the shortest and longest true centre distance seen [m], ``link_force`` (N,) the
    largest force the bearing's end stops passed [N], ``corrections`` (N, 2) the summed
    orientation corrections of the estimator [rad], ``time`` the simulated duration [s],
    ``finished`` (N,) whether each vehicle drove the whole path, ``cable_crossings`` (N, 2)
    how many times the wheels of truck A and of truck B passed over a laid cable.
    """

    true_poses: FloatArray
    estimated: FloatArray
    odometry: FloatArray
    return_error: FloatArray
    truck_errors: FloatArray
    link_range: FloatArray
    link_force: FloatArray
    corrections: FloatArray
    time: float
    finished: NDArray[np.bool_]
    cable_crossings: NDArray[np.int64] = field(
        default_factory=lambda: np.zeros((0, 2), dtype=np.int64)
    )


class VehicleTrial:
    """N copies of a vehicle driving ``path`` on ``floor`` in one World (they start at the same
    place and never touch), steered by ``estimator``'s poses (default: plain dead reckoning,
    i.e. without IPEC), one sampling interval T_s per :meth:`step`. ``cables`` lays cables as
    the vehicle comes (one vehicle only: the floor is shared); ``rng`` feeds a rough floor's
    wheel noise."""

    def __init__(
        self,
        spec: VehicleSpec,
        floor: FloorSpec,
        path: VehiclePath,
        n: int = 1,
        *,
        estimator: EstimatorFactory | None = None,
        calibration: Calibration | None = None,
        driver: VehicleDriver | None = None,
        cables: CableLayer | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        if cables is not None and n != 1:
            raise ValueError("cables are laid under one vehicle: use n=1")
        # The estimators (dead reckoning, IPEC) take the trucks' wheelbases and wheel travel
        # only: a skid-steer calibration's ICR steps would reach the reported odometry but not
        # the poses the vehicle is steered by.
        require_differential(calibration, "CLAPPER's estimators (dead reckoning, IPEC)")
        self.spec, self.floor, self.path, self.n, self.cables = spec, floor, path, n, cables
        trucks = [spec.truck_a, spec.truck_b] * n
        links = [(2 * k, 2 * k + 1, spec.link_min, spec.link_max) for k in range(n)]
        hitches = [(2 * k, 2 * k + 1, spec.link_length) for k in range(n)]
        self.dt = spec.sample_period
        self.world = World(
            trucks,
            floor,
            dt=self.dt,
            links=[] if spec.trailer else links,
            hitches=hitches if spec.trailer else [],
            rng=rng,
        )
        start = np.tile(path.start_poses(spec.link_length), (n, 1, 1))
        self.world.reset(start.reshape(2 * n, 3))
        self.odometry = Odometry(trucks, calibration)
        self.odometry.reset(start.reshape(2 * n, 3))
        self.wheelbase = self.odometry.effective_wheelbase.reshape(n, 2)
        self.estimator = (estimator or DeadReckoning)(self.wheelbase)
        # The internal encoders' jitter has its own stream, so that switching it on does not
        # change the floor's noise of the same seed.
        self._reading_rng = (
            np.random.default_rng(rng.bit_generator.seed_seq.spawn(1)[0])  # type: ignore[attr-defined]
            if rng is not None
            else np.random.default_rng(0)
        )
        self._previous_truth = self.world.pose.reshape(n, 2, 3).copy()
        self.reading = link_readings(spec, self._previous_truth, self._reading_rng)
        self.estimator.reset(start.copy(), self.reading)
        self.estimated = start.copy()
        self.driver = driver or VehicleDriver()
        self.driver.plan(path, n)
        self._rate_per_speed = 1.0 / self.world.nominal_radius[:, None]
        self._last_counts = self.world.counts.copy()
        length = link_length(start)
        self.link_range = np.stack([length, length], axis=1)
        self.link_force = np.zeros(n)
        self.corrections = np.zeros((n, 2))
        self.cable_crossings = np.zeros((n, 2), dtype=np.int64)
        self._cable_geometry: tuple[FloatArray, ...] | None = None
        self._cable_side: FloatArray | None = None
        self.steps = 0

    @property
    def time(self) -> float:
        """Simulated time [s]."""
        return self.steps * self.dt

    @property
    def done(self) -> NDArray[np.bool_]:
        """Vehicles that have driven the whole path."""
        return self.driver.done()

    @property
    def truth(self) -> FloatArray:
        """True truck poses (N, 2, 3) [m, m, rad]."""
        return self.world.pose.reshape(self.n, 2, 3)

    def step(self, speed: FloatArray | None = None) -> None:
        """One sampling interval: lay a cable if one is due, steer, move, read the encoders
        and update the estimate. ``speed``: see :meth:`VehicleDriver.act`."""
        world, n = self.world, self.n
        if self.cables is not None:
            laid = self.cables(
                self.driver.leg,
                self.path,
                world.pose[:2],
                (self.spec.truck_a.true_wheelbase, self.spec.truck_b.true_wheelbase),
            )
            if laid is not None:  # the floor as it was, plus the cables laid so far
                squeeze = self.spec.tyre_compression
                felt = tuple(  # a compliant tyre swallows part of the cable's height
                    dataclasses.replace(c, diameter=max(c.diameter - squeeze, 1e-4)) for c in laid
                )
                world.lay_floor(dataclasses.replace(self.floor, bumps=self.floor.bumps + felt))
                self._cable_geometry = cable_arrays(laid)
                # Which side of every cable each wheel is on before this interval's motion,
                # so that a crossing in the interval a cable is laid counts too.
                self._cable_side = self._wheel_sides(self.truth)[0]
        speeds = self.driver.act(
            self.estimated,
            self.reading.length,
            self.spec.link_length,
            0.5 * self.wheelbase,
            self.dt,
            speed,
            self.reading.psi,
            towed=self.spec.trailer,
        )
        rates = speeds.reshape(2 * n, 2) * self._rate_per_speed
        if self.spec.trailer:
            rates[1::2] = self._free_rolling(speeds[:, 0])
        world.step(rates)
        counts = world.counts.copy()
        travel = ((counts - self._last_counts) * self.odometry.travel_per_tick).reshape(n, 2, 2)
        self._last_counts = counts
        self.odometry.update(counts, self.dt)
        truth = self.truth
        shown = truth
        if self.spec.read_skew > 0.0:  # the link encoders read read_skew before the wheels
            f = self.spec.read_skew / self.dt
            shown = truth + f * (self._previous_truth - truth)
            shown[:, :, 2] = truth[:, :, 2] + f * wrap_angle(
                self._previous_truth[:, :, 2] - truth[:, :, 2]
            )
            self._previous_truth = truth.copy()  # read only here
        self.reading = link_readings(self.spec, shown, self._reading_rng)
        self.estimated = self.estimator.update(travel, self.reading)
        if self._cable_geometry is not None:
            self._count_crossings(truth)
        self.corrections += self.estimator.correction
        length = link_length(truth)
        self.link_range[:, 0] = np.minimum(self.link_range[:, 0], length)
        self.link_range[:, 1] = np.maximum(self.link_range[:, 1], length)
        self.link_force = np.maximum(self.link_force, self.current_link_force())
        self.steps += 1

    def current_link_force(self) -> FloatArray:
        """The force each vehicle's linkage passed in the last interval (N,) [N]: the end stops'
        for the CLAPPER (0 inside its range), the hitch's towing force for a trailer."""
        world = self.world
        return np.asarray(world.hitch_forces() if self.spec.trailer else world.link_forces())

    def _free_rolling(self, towing: FloatArray) -> FloatArray:
        """Wheel rates (N, 2) [rad/s] of the trailers' free-rolling wheels in the coming
        interval. The World drives every wheel at a commanded rate through a friction-limited
        contact, which resists any other speed along the wheel as well as across it; a wheel
        commanded to the speed the tow gives it passes (nearly) no force along itself. That
        speed is the trailer's kinematics under the hitch (robot A's centre) moving at the
        robot's commanded speed ``towing`` (N, 2) [m/s, left and right wheel] along its heading:
        the trailer moves along its own heading at v·cos φ and turns at v·sin φ / L about its
        axle, φ the hitch angle, L the tongue. A limitation, measured: the hitch passes ≈ 0 N
        on a straight at steady speed, but up to ~60 N in and after the rectangle's tight turns,
        where the commanded and the actual motion of the 40 ms interval differ and the
        velocity-controlled contacts (not truly free wheels) take up the difference."""
        world = self.world
        robot = world.pose[0::2]
        pose = world.pose[1::2]
        v = 0.5 * (towing[:, 0] + towing[:, 1])
        phi = robot[:, 2] - pose[:, 2]
        along = v * np.cos(phi)
        omega = v * np.sin(phi) / self.spec.link_length
        turn = omega * world.half_track[1::2]
        ground = np.stack([along - turn, along + turn], axis=1)
        cables = self.world.floor.bumps
        if cables:  # over a cable the rim turns through the arc, not the horizontal advance
            radius = world.true_radius[1::2]
            contacts = wheel_contacts(pose, world.half_track[1::2])
            for k in range(len(pose)):
                c, s = math.cos(float(pose[k, 2])), math.sin(float(pose[k, 2]))
                for w in (0, 1):
                    px, py = (float(v) for v in contacts[k, w])
                    step = float(ground[k, w]) * self.dt
                    ground[k, w] = (
                        free_wheel_rim(cables, px, py, c, s, step, float(radius[k, w])) / self.dt
                    )
        return np.asarray(ground / world.true_radius[1::2])

    def _count_crossings(self, truth: FloatArray) -> None:
        """Count each truck's wheels passing a laid cable this interval: a wheel's contact point
        changed sides of a cable's axis while within the cable's length."""
        side, within = self._wheel_sides(truth)
        if self._cable_side is not None:
            truck_a, truck_b = crossings(side, self._cable_side, within)
            self.cable_crossings[0, 0] += truck_a
            self.cable_crossings[0, 1] += truck_b
        self._cable_side = side

    def _wheel_sides(self, truth: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
        """For each wheel (A left, A right, B left, B right) and laid cable: the side of the
        cable's axis its contact point is on (±1, 0 on the axis) and whether it lies within the
        cable's length (:func:`~odomgym.vehicle.cable_layout.wheel_sides`)."""
        assert self._cable_geometry is not None
        return wheel_sides(truth[0], self.world.half_track[:2], *self._cable_geometry)

    def errors(self) -> tuple[FloatArray, FloatArray]:
        """(vehicle error (N, 3), truck errors (N, 2, 3)): true minus estimated, headings
        wrapped; the vehicle's pose is :func:`vehicle_pose`."""
        truth = self.truth
        trucks = truth - self.estimated
        trucks[:, :, 2] = wrap_angle(trucks[:, :, 2])
        vehicle = vehicle_pose(truth) - vehicle_pose(self.estimated)
        vehicle[:, 2] = wrap_angle(vehicle[:, 2])
        return vehicle, trucks

    def outcome(self) -> VehicleOutcome:
        """The state now, as a :class:`VehicleOutcome`."""
        vehicle, trucks = self.errors()
        return VehicleOutcome(
            true_poses=self.truth.copy(),
            estimated=self.estimated.copy(),
            odometry=self.odometry.pose.reshape(self.n, 2, 3).copy(),
            return_error=vehicle,
            truck_errors=trucks,
            link_range=self.link_range.copy(),
            link_force=self.link_force.copy(),
            corrections=self.corrections.copy(),
            time=self.time,
            finished=self.done.copy(),
            cable_crossings=self.cable_crossings.copy(),
        )


def drive_vehicles(
    spec: VehicleSpec,
    floor: FloorSpec,
    path: VehiclePath,
    n: int = 1,
    *,
    estimator: EstimatorFactory | None = None,
    calibration: Calibration | None = None,
    driver: VehicleDriver | None = None,
    max_time: float | None = None,
    cables: CableLayer | None = None,
    rng: np.random.Generator | None = None,
) -> VehicleOutcome:
    """Drive a :class:`VehicleTrial` with the reference speed profile until every vehicle has
    driven the path (or ``max_time`` [s], default three times the nominal duration + 60 s)."""
    trial = VehicleTrial(
        spec,
        floor,
        path,
        n,
        estimator=estimator,
        calibration=calibration,
        driver=driver,
        cables=cables,
        rng=rng,
    )
    total = sum(leg.length for leg in path.legs)
    limit = max_time if max_time is not None else 3.0 * total / trial.driver.cruise_speed + 60.0
    while not trial.done.all() and trial.time < limit:
        trial.step()
    return trial.outcome()

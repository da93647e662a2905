"""The physics World: differential-drive robots as pymunk rigid bodies with friction-limited wheels.

One :class:`World` holds a *batch* of N robots in one pymunk space (they do not interact); the
single-robot envs are a batch of one. The per-wheel arithmetic of a step (wheel controllers,
encoders, contact velocities, floor effects) runs in numba-compiled loops over the robots
(:mod:`odomgym._kernels`), and body state crosses into Chipmunk and back once per physics
substep, from compiled code that calls Chipmunk's functions by address
(:mod:`odomgym.sim.chipmunk_link`): with no effect hooks on a plain floor a whole step, Chipmunk's
steps included, is one compiled call, which a :class:`~odomgym.sim.trial.Trial` makes part of its
own (measured in ``benchmarks/bench_speed.py``; docs/architecture.md, "Performance design").

Model, per robot (top-down, no gravity in the plane):

* **Chassis** — a dynamic body of the robot's mass and yaw inertia, its origin at the axle
  midpoint (the odometry reference point).
* **Wheel–floor contact** — the pymunk ``tank.py`` idiom: each drive wheel is a pivot joint
  between the chassis (at the wheel's contact point, ±b_true/2 to the side) and a per-wheel
  kinematic "ground" body that moves with the velocity the contact point *would* have if the
  wheel rolled without slipping. ``max_bias = 0`` makes the joint act on velocities only, and
  ``max_force = μ·N`` caps the force it may apply at Coulomb friction, isotropically (a friction
  circle). When a manoeuvre asks for more force than μ·N — hard acceleration, a fast turn, low
  μ — the joint saturates and the wheel slips: slip *emerges*, nothing scripts it. A saturated
  joint's force points along the velocity error weighted by the chassis' effective mass at the
  contact, not exactly against the slip: Coulomb's size, the solver's direction.
* **Skid-steer contacts** — a skid-steer robot (:class:`~odomgym.robot.RobotSpec`
  ``axle_spacing > 0``: two wheels per side, no casters) slides on all four contacts whenever
  it turns, where that direction would matter: its contacts are not joints but Coulomb forces
  opposite each contact's slip, solved implicitly after each Chipmunk step
  (:func:`skid_contacts`), its loads by :meth:`~odomgym.robot.RobotSpec.contact_loads`.
* **Wheel drive** — each wheel's angular rate follows its command through a velocity controller
  with an acceleration limit (a stiff motor: the rate does not depend on the ground force).
  The rim travels ``ω·r_true`` per second; the encoder counts the true wheel rotation,
  quantised to whole counts.
* **Floor** — the ground body's velocity is the rim velocity corrected by the floor: over a
  cable the horizontal advance follows the rigid-wheel-over-cylinder geometry
  (:func:`odomgym.sim.cables.cable_advance`), on a rough floor it carries white noise of variance
  k²·|d| (Chong & Kleeman 1997, Eq. 4), and friction patches change μ.
* **Effects** — the robot spec's further effects (:mod:`odomgym.effects`: backlash, wheel toe,
  turn skid, bumps, wheel roughness, a tracked point offset) act through hooks at fixed stages of
  the step (transmission, contact velocities before and after the floor, the tracked point). The
  World asks the registry for them and knows no effect by name.

Units: metres, radians, seconds, kilograms, newtons. Wheel index 0 is the left wheel, 1 the right.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pymunk
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym._kernels import (
    STEP_BAD_READ_BACK,
    STEP_NOT_FINITE,
    STEP_OK,
    check_step_status,
    drive_plain,
    drive_wheels,
    exchange,
    floor_kernel,
    midstep_translation,
    new_state,
    rim_from_wheel_step,
    state_parts,
    state_views,
    step_plain,
)
from odomgym.effects import EFFECTS, WorldHook
from odomgym.errors import SpecError
from odomgym.floor import FloorSpec
from odomgym.robot import RobotSpec
from odomgym.sim.cables import CableGrid, apply_cable_deficits, skid_cable_losses
from odomgym.sim.chipmunk_link import SpaceExchange

__all__ = ["GRAVITY", "World"]

GRAVITY = 9.81  # m/s²
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_NOISE_BLOCK = 256  # roughness draws per robot fetched at once


class World:
    """N differential-drive robots on one floor, stepped together.

    Args:
        robots: one :class:`RobotSpec` per robot (a single spec for a batch of one).
        floor: the floor all robots share.
        dt: control period [s]: commands are held and encoders sampled once per ``dt``.
            Default 0.05 s, the 20 Hz odometry rate of the OptiOdom robot whose measured
            sessions ship with the package (:mod:`odomgym.data.samples`; the CLAPPER sampled at
            40 ms, Borenstein 1995, §3.1).
        substeps: physics steps per control period (each of ``dt/substeps`` seconds).
        iterations: Chipmunk solver iterations per step. The wheel joints of a chassis (two, or
            four for a skid-steer robot) are coupled; with Chipmunk's warm start (last step's
            impulses applied first) they converge within a few iterations. Default 10: against
            20, the return errors of 4×4 m UMBmark squares (ideal robot; LabMate on the
            ``bumpy`` floor; LabMate at
            μ = 0.1, slipping by metres) differ by at most 0.01 mm and 0.0002°, far below one
            encoder count; 8 gives 0.05 mm, 6 gives 0.5 mm. The solver is most of a step's cost
            (256 robots: 230 µs at 20, 133 µs at 10), hence the choice.
        rng: source of floor-roughness noise, required when ``floor.roughness > 0``: one
            Generator (each robot gets its own child stream, ``rng.spawn``) or one Generator
            per robot. Per-robot streams make a robot's noise independent of which other robots
            share its batch.
        track_slip: accumulate each wheel's slip distance in ``slip`` (costs ~5 µs a step).
        links: compliant linkages ``(i, j, min, max)`` between the centres of robots i and j:
            free while the centre distance lies in [min, max] [m], a hard stop at either end
            (a pymunk ``SlideJoint``): the CLAPPER's linear bearing (Borenstein 1995, §2;
            :mod:`odomgym.vehicle.spec`). Without links the robots do not interact.
        hitches: towing hitches ``(i, j, length)``: robot j's point ``length`` [m] ahead of
            its axle midpoint (the end of a rigid tongue) pinned to robot i's axle midpoint, a
            free rotary joint (a pymunk ``PivotJoint``): the encoder trailer of Borenstein
            1995, §7, towed by robot i.

    State arrays (read them, do not write them; shapes use N robots):
        ``pose`` (N, 3) true x, y [m], θ [rad] of the axle midpoint;
        ``velocity`` (N, 3) true ẋ, ẏ [m/s], θ̇ [rad/s];
        ``wheel_rate`` (N, 2) wheel angular rates [rad/s];
        ``wheel_angle`` (N, 2) accumulated wheel rotation [rad];
        ``counts`` (N, 2) encoder counts (int64, quantised true rotation);
        ``slip`` (N, 2) accumulated |rim travel − ground travel| of each wheel [m];
        ``time`` simulated time [s].

    Arrays effect hooks may change during a step (:class:`odomgym.effects.WorldHook`):
        ``rim_speed`` (N, 2) rim speed of each wheel this substep [m/s];
        ``ground_velocity`` (N, 2, 2) no-slip velocity of each wheel contact [m/s];
        ``wheel_roughness`` (N, 2) k of each wheel [m^½] (set once, in ``configure``).
    """

    def __init__(
        self,
        robots: RobotSpec | Sequence[RobotSpec],
        floor: FloorSpec | None = None,
        *,
        dt: float = 0.05,
        substeps: int = 1,
        iterations: int = 10,
        rng: np.random.Generator | Sequence[np.random.Generator] | None = None,
        track_slip: bool = False,
        links: Sequence[tuple[int, int, float, float]] = (),
        hitches: Sequence[tuple[int, int, float]] = (),
    ) -> None:
        specs = [robots] if isinstance(robots, RobotSpec) else list(robots)
        if not specs:
            raise ValueError("World needs at least one robot")
        self.links = tuple((int(i), int(j), float(lo), float(hi)) for i, j, lo, hi in links)
        for i, j, lo, hi in self.links:
            if not (0 <= i < len(specs) and 0 <= j < len(specs) and i != j):
                raise ValueError(f"a link joins two different robots of the batch, got {i}, {j}")
            if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo < hi):
                raise ValueError(f"a link's range needs 0 <= min < max [m], got {lo}, {hi}")
        self.hitches = tuple((int(i), int(j), float(length)) for i, j, length in hitches)
        for i, j, length in self.hitches:
            if not (0 <= i < len(specs) and 0 <= j < len(specs) and i != j):
                raise ValueError(f"a hitch joins two different robots of the batch, got {i}, {j}")
            if not (math.isfinite(length) and length > 0.0):
                raise ValueError(f"a hitch's tongue must be a positive length [m], got {length}")
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        if isinstance(substeps, bool) or int(substeps) != substeps or substeps < 1:
            raise ValueError(f"substeps must be a whole number >= 1, got {substeps!r}")
        self.robots: tuple[RobotSpec, ...] = tuple(specs)
        self.floor = floor if floor is not None else FloorSpec()
        self._noise_streams: list[np.random.Generator] = []
        self._noise_block = np.zeros((len(specs), _NOISE_BLOCK, 2))
        self._noise_next = _NOISE_BLOCK  # forces a refill at the first use
        self.dt = float(dt)
        self.substeps = int(substeps)
        self.iterations = int(iterations)
        self.n = len(specs)

        # Per-robot parameters as arrays, shape (N,) or (N, 2) for [left, right].
        self.true_radius = np.array(
            [[0.5 * s.true_left_diameter, 0.5 * s.true_right_diameter] for s in specs]
        )
        self.nominal_radius = np.array([0.5 * s.wheel_diameter for s in specs])
        self.half_track = np.array([0.5 * s.true_wheelbase for s in specs])
        self.ticks_per_rad = np.array([s.ticks_per_rev / (2.0 * np.pi) for s in specs])
        self.max_rate = np.array([s.max_wheel_speed for s in specs]) / self.nominal_radius
        self.max_rate_step = (
            np.array([s.max_wheel_accel for s in specs]) / self.nominal_radius * self.dt / substeps
        )
        self._lateral = np.stack([self.half_track, -self.half_track], axis=1)  # (N, 2) [m]
        # Each robot's wheel contacts: (side, x, y) in its body frame and the normal force on
        # each [N] (two for differential drive, four for skid-steer; RobotSpec.contacts).
        self._contacts = [spec.contacts() for spec in specs]
        self._loads = [spec.contact_loads(GRAVITY) for spec in specs]
        # Skid-steer robots: their four contacts are solved here, not by Chipmunk's joints
        # (skid_contacts): indices, (x, y) of each contact, its side and load, mass, inertia.
        self._skid = np.array(
            [i for i, spec in enumerate(specs) if spec.is_skid_steer], dtype=np.intp
        )
        self._skid_xy = np.array(
            [[(x, y) for _, x, y in self._contacts[i]] for i in self._skid], dtype=float
        ).reshape(len(self._skid), 4, 2)
        self._skid_side = np.array(
            [[side for side, _, _ in self._contacts[i]] for i in self._skid], dtype=np.intp
        ).reshape(len(self._skid), 4)
        self._skid_load = np.array([self._loads[i] for i in self._skid], dtype=float).reshape(
            len(self._skid), 4
        )
        self._skid_mass = np.array([specs[i].mass for i in self._skid], dtype=float)
        self._skid_inertia = np.array([specs[i].moment_of_inertia for i in self._skid], dtype=float)
        # Each skid-steer robot's tyre stiffnesses per unit load (C_κ/N, C_α/N; 0, 0: rigid).
        self._skid_tyre = np.array(
            [(specs[i].tyre_slip_stiffness, specs[i].tyre_cornering_stiffness) for i in self._skid],
            dtype=float,
        ).reshape(len(self._skid), 2)
        # Each skid-steer wheel's contact in the world and the friction under it (_set_friction).
        self._skid_points = np.zeros((len(self._skid), 4, 2))
        self._skid_friction = np.zeros((len(self._skid), 4))
        self._skid_loss = np.zeros((len(self._skid), 4))  # to cables [m/s]
        for spec in specs:
            for name, values in spec.effects if spec.is_skid_steer else ():
                effect = EFFECTS.get(name)
                reason = effect.skid_steer_refusal(dict(values)) if effect is not None else ""
                if reason:
                    raise SpecError(
                        f"robot {spec.name!r} is skid-steer and carries {name}, which the World "
                        f"does not apply to skid-steer robots: {reason}",
                        field=f"effects.{name}",
                    )
        if track_slip and any(spec.is_skid_steer for spec in specs):
            raise SpecError(
                "track_slip measures two contacts at the axle midpoint's sides; a skid-steer "
                "robot's four contacts are not tracked yet",
                field="track_slip",
            )
        self._h = self.dt / self.substeps
        self._unit_scale = np.ones(self.n)
        self.track_slip = track_slip
        self._has_bumps = bool(self.floor.bumps)
        max_step = float(np.max(self.max_rate * self.true_radius.max(axis=1))) * self._h
        self._bump_grid = CableGrid.build(self.floor, float(self.true_radius.max()), 1.5 * max_step)
        self._has_patches = bool(self.floor.patches)
        self.wheel_roughness = np.full((self.n, 2), self.floor.roughness)
        self._hooks = self._effect_hooks()
        for hook in self._hooks:
            hook.configure(self)
        self._rough = bool(np.any(self.wheel_roughness > 0.0))
        self._transmission = [h for h in self._hooks if h.has_transmission]
        self._shape = [h for h in self._hooks if h.has_shape]
        self._perturb = [h for h in self._hooks if h.has_perturb]
        self._tracked = [h for h in self._hooks if h.has_tracked]
        self._classify()
        # The per-robot state in one array (one argument of a compiled call; pose, velocity,
        # wheel rates and angles are views of it) and the arrays of other shapes, all updated
        # in place from here on.
        # The params' half track is what the mid-step turn divides by (midstep_translation):
        # infinite for a skid-steer robot, which turns at no kinematic rate — skid_contacts
        # takes its heading from the yaw rate it solves — so its contact velocities stay along
        # the heading they were driven at.
        turn_half_track = np.where(
            [spec.is_skid_steer for spec in specs], math.inf, self.half_track
        )
        self._state = new_state(
            self.max_rate, self.max_rate_step, self.true_radius, self.ticks_per_rad, turn_half_track
        )
        self._bind_state()
        self.counts = np.zeros((self.n, 2), dtype=np.int64)
        self.slip = np.zeros((self.n, 2))
        self._ground_v = np.zeros((self.n, 2, 2))  # [robot, wheel, (vx, vy)] [m/s]
        self._contact = np.zeros((self.n, 2, 2))  # [robot, wheel, (x, y)] [m]
        self._no_noise = np.zeros((self.n, 2))
        self._clock = np.zeros(1)  # simulated time [s], an array so compiled steps advance it
        self._bind_noise(rng)

        self._build_space()
        self.reset()

    # ------------------------------------------------------------------ construction
    def _classify(self) -> None:
        """Which substep path the floor and the hooks allow: ``_plain`` (nothing acts between
        the wheels and Chipmunk: :func:`odomgym._kernels.step_plain`), ``_floor_only`` (the
        floor's roughness and cables act, no hook and no friction patch: :func:`step_floor`),
        else the staged path, stage by stage from Python."""
        self._modifies_ground = self._has_bumps or self._has_patches or self._rough
        hooked = bool(self._transmission or self._shape or self._perturb)
        self._plain = not (hooked or self._modifies_ground or self._skid.size)
        self._floor_only = not (self._plain or hooked or self._has_patches or self._skid.size)

    def _effect_hooks(self) -> list[WorldHook]:
        """One hook per registered effect that some robot of the batch carries."""
        hooks: list[WorldHook] = []
        for name, effect in EFFECTS.items():
            rows = [spec.effect_values(name) for spec in self.robots]
            if all(r is None for r in rows):
                continue
            absent = effect.absent_values()
            values = np.array(
                [[(r or absent).get(p, absent[p]) for p in absent] for r in rows], dtype=float
            )
            hook = effect.world_hook(self, values)
            if hook is not None:
                hooks.append(hook)
        return hooks

    def _bind_noise(self, rng: np.random.Generator | Sequence[np.random.Generator] | None) -> None:
        """Give each robot its own noise stream: roughness draws, then one child per hook."""
        random_hooks = [h for h in self._hooks if h.needs_rng]
        if not (self._rough or random_hooks):
            return
        if rng is None:
            raise ValueError(
                "a rough floor or a robot with noise effects needs rng=np.random.Generator"
            )
        streams = rng.spawn(self.n) if isinstance(rng, np.random.Generator) else list(rng)
        if len(streams) != self.n:
            raise ValueError(f"need one noise Generator per robot ({self.n})")
        self._noise_streams = streams
        if random_hooks:
            # Each robot's stream spawns one child per random hook, so a robot's draws depend
            # neither on its batch nor on the roughness draws.
            children = [stream.spawn(len(random_hooks)) for stream in streams]
            for k, hook in enumerate(random_hooks):
                hook.bind_rng([robot_children[k] for robot_children in children])

    @property
    def uses_noise(self) -> bool:
        """True if some robot draws random numbers (a rough floor or a random effect)."""
        return bool(self._noise_streams)

    def rebind_noise(
        self, indices: Sequence[int] | NDArray[np.intp], streams: Sequence[np.random.Generator]
    ) -> None:
        """Give robots ``indices`` new noise streams, as if each had a World of its own built
        with ``streams[k]``: a vector env's sub-env, reset with its own seed, draws what a
        single env reset with that seed would (call before :meth:`reset` of those robots).

        The roughness draws continue from the new stream at the shared block position (a
        stream's draws do not depend on how they are chunked); every random effect hook gets
        its children of the stream, in the order :meth:`_bind_noise` gives them.
        """
        random_hooks = [h for h in self._hooks if h.needs_rng]
        if not (self._rough or random_hooks):
            return
        if len(streams) != len(indices):
            raise ValueError("need one noise Generator per robot index")
        start = self._noise_next
        for i, stream in zip(indices, streams, strict=True):
            i = int(i)
            self._noise_streams[i] = stream
            if random_hooks:
                children = stream.spawn(len(random_hooks))
                for hook, child in zip(random_hooks, children, strict=True):
                    hook.rebind_rng(i, child)
            if start < _NOISE_BLOCK:
                self._noise_block[i, start:] = stream.standard_normal((_NOISE_BLOCK - start, 2))

    @property
    def substep(self) -> float:
        """Length of one physics substep [s] (``dt / substeps``)."""
        return self._h

    @property
    def rim_speed(self) -> FloatArray:
        """Rim speed of each wheel during the current substep (N, 2) [m/s]."""
        return self._rim_speed

    @property
    def ground_velocity(self) -> FloatArray:
        """No-slip velocity of each wheel contact (N, 2, 2) [m/s] for the current substep."""
        return self._ground_v

    @property
    def has_tracked_point(self) -> bool:
        """True if some robot's tracked point differs from its axle midpoint."""
        return bool(self._tracked)

    def tracked_pose(self) -> FloatArray:
        """The poses (N, 3) a tracking system reports: the true pose, moved to the tracked point
        by effects such as ``gt_sensor_offset``."""
        pose = self.pose.copy()
        for hook in self._tracked:
            pose = hook.tracked(pose)
        return pose

    def _build_space(self) -> None:
        space = pymunk.Space()
        space.iterations = self.iterations
        space.gravity = (0.0, 0.0)
        self.space = space
        self._chassis: list[pymunk.Body] = []
        self._ground: list[pymunk.Body] = []  # [2i] left, [2i+1] right
        # One joint per wheel of a differential-drive robot ([2i] left, [2i+1] right); None for
        # a skid-steer robot's sides, whose four contacts skid_contacts solves.
        self._joints: list[pymunk.PivotJoint | None] = []
        for spec, contacts in zip(self.robots, self._contacts, strict=True):
            chassis = pymunk.Body(spec.mass, spec.moment_of_inertia)
            space.add(chassis)
            self._chassis.append(chassis)
            for side in (0, 1):  # the left wheel at +y (body frame), the right at −y
                ground = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
                space.add(ground)
                joint = None
                if not spec.is_skid_steer:
                    _, x, y = contacts[side]
                    joint = pymunk.PivotJoint(chassis, ground, (x, y), (0.0, 0.0))
                    joint.max_bias = 0.0  # velocity-level only: friction, not a spring
                    joint.collide_bodies = False
                    space.add(joint)
                self._ground.append(ground)
                self._joints.append(joint)
        self._links: list[pymunk.SlideJoint] = []
        for i, j, lo, hi in self.links:
            link = pymunk.SlideJoint(self._chassis[i], self._chassis[j], (0, 0), (0, 0), lo, hi)
            link.collide_bodies = False
            space.add(link)
            self._links.append(link)
        self._hitches: list[pymunk.PivotJoint] = []
        for i, j, length in self.hitches:
            hitch = pymunk.PivotJoint(self._chassis[i], self._chassis[j], (0, 0), (length, 0))
            hitch.collide_bodies = False
            space.add(hitch)
            self._hitches.append(hitch)
        self._friction = np.full((self.n, 2), np.nan)
        self._set_friction(np.full((self.n, 2), self.floor.friction))
        self._io = SpaceExchange(space, self._chassis, self._ground)

    def _bind_state(self) -> None:
        """The World's arrays that are views of the packed state (``substep.STATE_COLUMNS``)."""
        views = state_views(self._state)
        self._params = views["params"]
        self.pose = views["pose"]
        self.velocity = views["velocity"]
        self.wheel_rate = views["wheel_rate"]
        self.wheel_angle = views["wheel_angle"]
        self._rim_speed = views["rim_speed"]
        self._motor_step = views["motor_step"]

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        del state["_io"]  # C structures pointing at this space; the unpickled one gets its own
        for name in ("_params", "pose", "velocity", "wheel_rate", "wheel_angle"):
            del state[name]  # views, which pickling would turn into copies
        del state["_rim_speed"], state["_motor_step"]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._bind_state()
        self._io = SpaceExchange(self.space, self._chassis, self._ground)

    # ------------------------------------------------------------------ reset
    def reset(
        self, poses: FloatArray | None = None, indices: NDArray[np.intp] | None = None
    ) -> None:
        """Place robots at rest at ``poses`` (K, 3) [m, m, rad] (default: the origin).

        ``indices`` selects which robots (default: all). Wheel rates, angles, encoder counts and
        accumulated slip of those robots restart from zero.
        """
        if indices is None:
            indices = np.arange(self.n)
            self._clock[0] = 0.0
            self._rim_speed[:] = 0.0
            self._motor_step[:] = 0.0
            self._contact[:] = 0.0
        indices = np.asarray(indices, dtype=np.intp)
        targets = np.zeros((len(indices), 3)) if poses is None else np.asarray(poses, dtype=float)
        if targets.shape != (len(indices), 3) or not np.all(np.isfinite(targets)):
            raise ValueError(f"poses must be a finite array of shape ({len(indices)}, 3)")
        for row, i in enumerate(indices):
            chassis = self._chassis[i]
            chassis.position = (float(targets[row, 0]), float(targets[row, 1]))
            chassis.angle = float(targets[row, 2])
            chassis.velocity = (0.0, 0.0)
            chassis.angular_velocity = 0.0
            for ground in self._ground[2 * i : 2 * i + 2]:
                ground.position = chassis.position
                ground.velocity = (0.0, 0.0)
        self.pose[indices] = targets
        self.velocity[indices] = 0.0
        self._ground_v[indices] = 0.0
        self.wheel_rate[indices] = 0.0
        self.wheel_angle[indices] = 0.0
        self.counts[indices] = 0
        self.slip[indices] = 0.0
        for hook in getattr(self, "_hooks", ()):
            hook.reset(indices)

    # ------------------------------------------------------------------ stepping
    def step(self, wheel_rate_cmd: FloatArray, scale: FloatArray | None = None) -> None:
        """Advance one control period with commanded wheel rates (N, 2) [rad/s].

        With ``scale`` (N,), robot i's wheel rates are ``wheel_rate_cmd[i] · scale[i]`` (the
        envs pass actions in [−1, 1] and each robot's top wheel rate). Commands beyond the
        robot's ``max_wheel_speed`` are clipped to it; a non-finite command raises ValueError
        (the envs check their actions before they get here).
        """
        command = self.commands(wheel_rate_cmd)
        if scale is None:
            scale = self._unit_scale
        h = self._h
        io = self._io
        # What both compiled substep paths take first.
        arrays = (
            command,
            scale,
            self._state,
            self.counts,
            self._ground_v,
            io.addresses,
            io.heads,
            io.buffer,
            io.bodies,
            h,
        )
        if self._plain and io.compiled:
            # No effect hooks, a plain floor: whole substeps (wheels, contact velocities, their
            # mid-step turn, Chipmunk's step and the read-back) in one compiled call, one per
            # substep only when the slip (numpy, see _accumulate_slip) is tracked in between.
            per_call = 1 if self.track_slip else self.substeps
            for _ in range(self.substeps // per_call):
                check_step_status(step_plain(*arrays, per_call))
                if self.track_slip:
                    self._accumulate_slip(h)
        elif self._floor_only and io.compiled and not self.track_slip:
            # Rough floors and cables without hooks (every benchmark floor, the
            # self-calibration env's): whole substeps in compiled calls, each as long as the
            # roughness draws fetched so far last, the stages' arithmetic in their order.
            left = self.substeps
            while left:
                if self._rough:
                    self._refill_noise()
                count = min(left, _NOISE_BLOCK - self._noise_next) if self._rough else left
                check_step_status(
                    step_floor(
                        *arrays,
                        count,
                        self._lateral,
                        self.wheel_roughness,
                        self._noise_block,
                        self._noise_next,
                        self._rough,
                        self._contact,
                        self._bump_grid,
                        self._has_bumps,
                        self.true_radius,
                    )
                )
                if self._rough:
                    self._noise_next += count
                left -= count
        else:
            for _ in range(self.substeps):
                # The wheels (and, on a plain floor, the mid-step turn), then every stage.
                drive = drive_plain if self._plain else drive_wheels
                if not drive(
                    command,
                    scale,
                    self._params,
                    self.pose,
                    h,
                    self.wheel_rate,
                    self.wheel_angle,
                    self.counts,
                    self._rim_speed,
                    self._ground_v,
                    self._motor_step,
                ):
                    check_step_status(STEP_NOT_FINITE)
                if not self._plain:
                    self._effect_stages(h)
                self._exchange(h)
                if self._skid.size:
                    self._skid_step(h)
                if self.track_slip:
                    self._accumulate_slip(h)
        self._clock[0] += self.dt

    def commands(self, wheel_rate_cmd: Any) -> FloatArray:
        """``wheel_rate_cmd`` as the (N, 2) float64 array a step takes (any array-like of N×2
        numbers, reshaped if need be); ValueError if it has another number of entries."""
        command = np.asarray(wheel_rate_cmd, dtype=np.float64)
        if command.shape != (self.n, 2):
            if command.size != 2 * self.n:
                raise ValueError(
                    f"wheel_rate_cmd must have shape ({self.n}, 2), got {command.shape}"
                )
            command = command.reshape(self.n, 2)
        return command

    @property
    def time(self) -> float:
        """Simulated time [s] since the World was built or last reset as a whole."""
        return float(self._clock[0])

    @property
    def fuses_substeps(self) -> bool:
        """True if a whole step runs as one compiled call (no effect hooks, a plain floor, the
        compiled Chipmunk link, slip not tracked), which a caller may then make part of a
        larger compiled step (:func:`odomgym._kernels.control_step`) with
        :meth:`step_arrays`."""
        return self._plain and self._io.compiled and not self.track_slip

    def step_arrays(
        self,
    ) -> tuple[
        FloatArray,
        IntArray,
        FloatArray,
        NDArray[np.uint64],
        NDArray[np.int32],
        FloatArray,
        NDArray[np.uint64],
        FloatArray,
    ]:
        """The arrays a fused step (:func:`odomgym._kernels.step_plain`) works on, in the
        order of :data:`odomgym._kernels.STEP_FIELDS`: packed state, encoder counts, contact
        velocities, the Chipmunk link's addresses, headers, buffer and bodies, and the clock
        (1,) [s]. They stay the same arrays for the World's life."""
        io = self._io
        return (
            self._state,
            self.counts,
            self._ground_v,
            io.addresses,
            io.heads,
            io.buffer,
            io.bodies,
            self._clock,
        )

    def _exchange(self, h: float) -> None:
        """The ground bodies take their contact velocities, Chipmunk steps by ``h`` [s], and
        ``pose``/``velocity`` take the chassis' new state.

        ``pose`` is the raw Chipmunk pose advanced by v·h: Chipmunk integrates positions at the
        *start* of its next step with the velocities just solved, so this is where the motion of
        this step (already counted by the encoders) puts the robot, and the configuration at
        which the next step's contact velocities will be solved.
        """
        io = self._io
        if not io.compiled:
            io.exchange_in_python(self._ground_v, h, self.pose, self.velocity)
        elif not exchange(
            io.addresses,
            io.heads,
            io.buffer,
            io.bodies,
            self._ground_v,
            h,
            self.pose,
            self.velocity,
        ):
            check_step_status(STEP_BAD_READ_BACK)

    def _effect_stages(self, h: float) -> None:
        """After the wheels, one substep's contact velocities through every stage: transmission
        hooks, shape hooks, the floor, perturbation hooks, then the mid-step turn."""
        if self._transmission:
            for hook in self._transmission:
                hook.transmission(self._motor_step)
            rim_from_wheel_step(
                self._motor_step,
                self._params,
                self.pose,
                h,
                self._rim_speed,
                self._ground_v,
            )
        for hook in self._shape:
            hook.shape(self, h)
        if self._modifies_ground:
            self._floor_effects(h)
        for hook in self._perturb:
            hook.perturb(self, h)
        midstep_translation(self._ground_v, self.pose, self._params, h)

    def _skid_step(self, h: float) -> None:
        """The skid-steer robots' contact forces for the step Chipmunk has just taken: their
        new velocities (:func:`skid_contacts`), set on their chassis for the next position
        integration, and their reported poses moved to match (raw pose + new v·h, the World's
        convention, see :meth:`_exchange`)."""
        old = self.velocity[self._skid].copy()
        skid_contacts(
            self._skid,
            self._skid_xy,
            self._skid_side,
            self._skid_load,
            self._skid_mass,
            self._skid_inertia,
            self._skid_tyre,
            self._skid_friction,
            self._ground_v,
            self._skid_loss,
            self.pose,
            self.velocity,
            h,
        )
        self._io.set_chassis_velocity(self._skid, self.velocity)
        self.pose[self._skid] += (self.velocity[self._skid] - old) * h

    def _accumulate_slip(self, h: float) -> None:
        """Contact point velocity v + ω × r = v − ω·l·(cos θ, sin θ) against its ground body's.

        Uses the heading at which the step was solved (pose − ω·h), like the ground velocity.
        """
        theta = self.pose[:, 2:3] - self.velocity[:, 2:3] * h
        cos_t, sin_t = np.cos(theta), np.sin(theta)
        omega_l = self.velocity[:, 2:3] * self._lateral
        slip = np.hypot(
            self.velocity[:, 0:1] - omega_l * cos_t - self._ground_v[:, :, 0],
            self.velocity[:, 1:2] - omega_l * sin_t - self._ground_v[:, :, 1],
        )
        self.slip += slip * h

    def _floor_effects(self, h: float) -> None:
        """Cables, friction patches and roughness acting on the no-slip ground velocity.

        Scalar kernels, not numpy: numpy's vectorised sin/cos and complex products may round
        differently with the array length (SIMD paths), which would make a robot's trajectory
        depend on how many robots share its batch.
        """
        noise = self._standard_normal() if self._rough else self._no_noise
        floor_kernel(
            self.pose,
            self._lateral,
            self._rim_speed,
            noise,
            self.wheel_roughness,
            h,
            self._contact,
            self._ground_v,
        )
        if self._skid.size and (self._has_bumps or self._has_patches):
            # The skid-steer wheels' contact points, once per substep for the cables and the
            # patches both (the pose does not move in between).
            skid_contact_points(self._skid, self._skid_xy, self.pose, self._skid_points)
        if self._has_bumps:
            # A skid-steer robot's side velocity stays its rims': its wheels meet the cables
            # one by one (skid_cable_losses), not at the side's mid-point.
            sides = self._ground_v[self._skid] if self._skid.size else None
            apply_cable_deficits(
                self._contact,
                self.pose,
                self._rim_speed,
                h,
                self.true_radius,
                self._bump_grid,
                self._ground_v,
            )
            if sides is not None:
                self._ground_v[self._skid] = sides
                skid_cable_losses(
                    self._skid,
                    self._skid_side,
                    self._skid_points,
                    self.pose,
                    self._rim_speed,
                    h,
                    self.true_radius,
                    self._bump_grid,
                    self._skid_loss,
                )
        if self._has_patches:
            self._set_friction(
                self.floor.friction_at(self._contact[:, :, 0], self._contact[:, :, 1]),
                points_current=True,
            )

    def _standard_normal(self) -> FloatArray:
        """Next (N, 2) standard normal draws, robot i's from its own stream.

        Drawn in blocks of ``_NOISE_BLOCK`` steps per robot, so the per-step cost does not grow
        with one Python call per robot.
        """
        self._refill_noise()
        draws = self._noise_block[:, self._noise_next, :]
        self._noise_next += 1
        return draws

    def _refill_noise(self) -> None:
        """Fetch the next block of roughness draws if every draw of this one was used."""
        if self._noise_next == _NOISE_BLOCK:
            for i, stream in enumerate(self._noise_streams):
                self._noise_block[i] = stream.standard_normal((_NOISE_BLOCK, 2))
            self._noise_next = 0

    def _set_friction(self, mu: FloatArray, points_current: bool = False) -> None:
        """Each wheel joint's friction limit μ·N [N] from the friction coefficient under each
        side (N, 2): the pivot joint's largest force, isotropic (a friction circle). A skid-steer
        robot has no joints: skid_contacts reads μ under each of its four wheels from
        ``_skid_friction``, the floor's at each wheel's contact where friction patches lie (a
        patch may hold one wheel of a side), else its side's. ``points_current``: the
        skid-steer contact points were already computed at this pose (by
        :meth:`_floor_effects`) and are not computed again."""
        changed = np.argwhere(mu != self._friction)
        for i, side in changed:
            joint = self._joints[2 * i + side]
            if joint is not None:
                joint.max_force = float(mu[i, side] * self._loads[i][side])
        self._friction = mu
        if self._skid.size:
            if self._has_patches:
                if not points_current:
                    skid_contact_points(self._skid, self._skid_xy, self.pose, self._skid_points)
                self._skid_friction = self.floor.friction_at(
                    self._skid_points[:, :, 0], self._skid_points[:, :, 1]
                )
            else:
                self._skid_friction = mu[self._skid[:, None], self._skid_side]

    def lay_floor(self, floor: FloorSpec) -> None:
        """Change the cables, patches and friction under the robots between steps, as an
        experimenter lays cables before a return leg (Borenstein 1995, §6.1). The roughness
        must stay as it was (each robot's noise stream was bound to it at construction)."""
        if floor.roughness != self.floor.roughness:
            raise ValueError(
                f"lay_floor keeps the roughness ({self.floor.roughness}), got {floor.roughness}"
            )
        self.floor = floor
        self._has_bumps = bool(floor.bumps)
        self._skid_loss[:] = 0.0  # no cable under a wheel until the floor's are met
        max_step = float(np.max(self.max_rate * self.true_radius.max(axis=1))) * self._h
        self._bump_grid = CableGrid.build(floor, float(self.true_radius.max()), 1.5 * max_step)
        self._has_patches = bool(floor.patches)
        self._classify()
        self._set_friction(np.full((self.n, 2), floor.friction))

    def link_forces(self) -> FloatArray:
        """Force of each link's last step [N] (zero while the linkage is inside its range)."""
        h = self.dt / self.substeps
        return np.array([link.impulse / h for link in self._links])

    def hitch_forces(self) -> FloatArray:
        """Force each hitch passed in the last step [N] (the towing force)."""
        h = self.dt / self.substeps
        return np.array([abs(hitch.impulse) / h for hitch in self._hitches])


SKID_CREEP = 0.005
"""Slip speed [m/s] below which a skid-steer contact's friction grows in proportion to its slip
instead of standing at μ·N: the creep of rigid contacts (tyre stiffnesses 0), the least creep
of elastic ones, and what keeps the implicit solve of :func:`skid_contacts` smooth where a
contact barely slides."""


@kernel
def skid_contacts(
    robots: NDArray[np.intp],
    contacts: FloatArray,
    sides: NDArray[np.intp],
    loads: FloatArray,
    mass: FloatArray,
    inertia: FloatArray,
    tyre: FloatArray,
    friction: FloatArray,
    ground_v: FloatArray,
    loss: FloatArray,
    pose: FloatArray,
    velocity: FloatArray,
    h: float,
) -> None:
    """New velocities (in place) of skid-steer robots under friction-limited contacts,
    implicitly.

    Contact i at body-frame (x_i, y_i) from the centre of mass slides at s_i = v + ω × r_i − g_i
    against its side's no-slip ground velocity g_i (the rim speed U along the heading).

    * **Rigid contacts** (``tyre`` 0, 0): f_i = −μ·N_i·s_i/max(|s_i|, SKID_CREEP), Coulomb's
      force opposite the slip (a pivot joint capped at μ·N would push along its
      effective-mass-weighted velocity error instead).
    * **Elastic tyres** (C_κ, C_α per unit load): each direction has a *creep speed*, the slip at
      which its linear force reaches μ·N: ε_x = μ·U/C_κ along the wheel (a slip ratio μ/C_κ of
      the rim speed), ε_y = μ·U/C_α across it (a slip angle of μ/C_α rad); both at least
      SKID_CREEP. With w = (s_x/ε_x, s_y/ε_y) and κ = |w|: while κ ≤ 1 the contact is elastic,
      f = −μ·N·w (the longitudinal and cornering stiffnesses, Pacejka 2012 §1.2); beyond it a
      share 1 − 1/κ slides, pushed opposite the slip as Coulomb's force, and the rest stays
      elastic: f = −μ·N·(w/κ² + (1 − 1/κ)·s/|s|) — the brush model's split of the contact
      patch into an adhesion and a sliding region (Pacejka 2012 §3.2), in one number. |f| ≤ μN;
      at κ → ∞ it is Coulomb's force, at κ = 1 both agree. With equal creep speeds it is the
      rigid law exactly.

    The force is linear in the slip with a diagonal coefficient taken at the step's start, and
    the velocities are solved implicitly, M·(q − q₀) = h·Σ A_iᵀ f_i(q) — a 3×3 system per
    robot, stable at any step. ``robots`` (K,) indexes the World's arrays; ``contacts`` (K, 4,
    2), ``loads`` (K, 4), ``mass``, ``inertia`` (K,); ``tyre`` (K, 2) C_κ/N [-] and C_α/N
    [1/rad]; ``sides`` (K, 4) each contact's side; ``friction`` (K, 4) μ under each contact
    (its wheel's own point of the floor: a friction patch may lie under one wheel of a side);
    ``ground_v`` (N, 2, 2) [m/s] the sides' no-slip velocities of the step (their speeds are
    used); ``loss`` (K, 4) [m/s] what each contact's no-slip speed falls short of its side's
    (a wheel climbing a cable: :func:`odomgym.sim.cables.skid_cable_losses`; zeros
    otherwise); ``pose`` (N, 3) as the World reports it after the step; ``velocity`` (N, 3)
    [m/s, m/s, rad/s], read and written."""
    for k in range(robots.shape[0]):
        i = robots[k]
        vx, vy, w = velocity[i, 0], velocity[i, 1], velocity[i, 2]
        # Each side's ground speed along the heading the wheels were driven at (the raw pose
        # Chipmunk has just reached; no mid-step turn for these robots, see World.__init__).
        theta_d = pose[i, 2] - w * h
        hx, hy = math.cos(theta_d), math.sin(theta_d)
        speed_l = ground_v[i, 0, 0] * hx + ground_v[i, 0, 1] * hy
        speed_r = ground_v[i, 1, 0] * hx + ground_v[i, 1, 1] * hy
        # Solved in the body frame, whose state carries over exactly from step to step: the
        # velocity in the frame of the heading it was solved at (the previous one), turned by
        # the rotating frame's term h·(ω·v, −ω·u) (d(u, v)/dt = f/m + (ω·v, −ω·u)), so that a
        # steady turn is the contacts' steady state at any step length; then back to the world
        # at the heading the chassis has now, for the next position integration.
        theta_p = theta_d - w * h
        cp, sp = math.cos(theta_p), math.sin(theta_p)
        u = cp * vx + sp * vy
        v = -sp * vx + cp * vy
        a00 = mass[k]
        a11 = mass[k]
        a22 = inertia[k]
        a01 = a02 = a12 = 0.0
        b0 = mass[k] * (u + h * w * v)
        b1 = mass[k] * (v - h * w * u)
        b2 = inertia[k] * w
        for j in range(4):
            rx = contacts[k, j, 0]
            ry = contacts[k, j, 1]
            gx = (speed_l if sides[k, j] == 0 else speed_r) - loss[k, j]
            sx = u - w * ry - gx
            sy = v + w * rx
            limit = h * friction[k, j] * loads[k, j]  # h·μ·N [N·s]
            if tyre[k, 0] > 0.0:
                mu = friction[k, j]
                ex = max(mu * abs(gx) / tyre[k, 0], SKID_CREEP)
                ey = max(mu * abs(gx) / tyre[k, 1], SKID_CREEP)
                kappa = math.hypot(sx / ex, sy / ey)
                if kappa <= 1.0:
                    dx = limit / ex
                    dy = limit / ey
                else:
                    sliding = (1.0 - 1.0 / kappa) / math.hypot(sx, sy)
                    dx = limit * (1.0 / (ex * kappa * kappa) + sliding)
                    dy = limit * (1.0 / (ey * kappa * kappa) + sliding)
            else:
                dx = dy = limit / max(math.hypot(sx, sy), SKID_CREEP)
            # A = [[1, 0, -ry], [0, 1, rx]], D = diag(dx, dy): add AᵀDA to the matrix, AᵀD·g
            # to the right (g = (gx, 0) in the body frame).
            a00 += dx
            a11 += dy
            a02 -= dx * ry
            a12 += dy * rx
            a22 += dx * ry * ry + dy * rx * rx
            b0 += dx * gx
            b2 -= dx * ry * gx
        # Solve the symmetric 3×3 system (Cramer's rule).
        det = (
            a00 * (a11 * a22 - a12 * a12)
            - a01 * (a01 * a22 - a12 * a02)
            + a02 * (a01 * a12 - a11 * a02)
        )
        bu = (
            b0 * (a11 * a22 - a12 * a12) - a01 * (b1 * a22 - a12 * b2) + a02 * (b1 * a12 - a11 * b2)
        ) / det
        bv = (
            a00 * (b1 * a22 - a12 * b2) - b0 * (a01 * a22 - a12 * a02) + a02 * (a01 * b2 - b1 * a02)
        ) / det
        velocity[i, 0] = hx * bu - hy * bv
        velocity[i, 1] = hy * bu + hx * bv
        velocity[i, 2] = (
            a00 * (a11 * b2 - b1 * a12) - a01 * (a01 * b2 - b1 * a02) + b0 * (a01 * a12 - a11 * a02)
        ) / det


@kernel
def skid_contact_points(
    robots: NDArray[np.intp], contacts: FloatArray, pose: FloatArray, out: FloatArray
) -> None:
    """Each skid-steer robot's four wheel contacts in the world frame (K, 4, 2) [m], into
    ``out``: ``contacts`` (K, 4, 2) in the body frame from the point whose ``pose`` (N, 3) the
    World reports. Scalar, like the floor's kernels: numpy's vectorised sin and cos may round
    differently with the array's length, and a robot's contacts must not depend on its batch."""
    for k in range(robots.shape[0]):
        i = robots[k]
        c = math.cos(pose[i, 2])
        s = math.sin(pose[i, 2])
        for j in range(4):
            x = contacts[k, j, 0]
            y = contacts[k, j, 1]
            out[k, j, 0] = pose[i, 0] + c * x - s * y
            out[k, j, 1] = pose[i, 1] + s * x + c * y


@kernel
def step_floor(
    command: FloatArray,
    scale: FloatArray,
    state: FloatArray,
    counts: IntArray,
    ground_v: FloatArray,
    addresses: NDArray[np.uint64],
    heads: NDArray[np.int32],
    buffer: FloatArray,
    bodies: NDArray[np.uint64],
    h: float,
    substeps: int,
    lateral: FloatArray,
    roughness: FloatArray,
    noise: FloatArray,
    first_draw: int,
    rough: bool,
    contact: FloatArray,
    grid: CableGrid,
    bumps: bool,
    true_radius: FloatArray,
) -> int:
    """``substeps`` whole substeps of a World whose floor alone acts between the wheels and
    Chipmunk (roughness, cables; no hook, no friction patch): the staged path's calls in its
    order — wheels (:func:`~odomgym._kernels.drive_wheels`), floor
    (:func:`~odomgym._kernels.floor_kernel` with substep s's draws ``noise[:, first_draw + s]``
    when ``rough``), cables (:func:`~odomgym.sim.cables.apply_cable_deficits` when ``bumps``),
    mid-step turn, Chipmunk — so the same arithmetic, without a Python round trip per stage.
    Returns ``STEP_OK``, ``STEP_NOT_FINITE`` or ``STEP_BAD_READ_BACK``."""
    params, pose, velocity, rate, angle, rim_speed, motor_step = state_parts(state)
    for s in range(substeps):
        if not drive_wheels(
            command, scale, params, pose, h, rate, angle, counts, rim_speed, ground_v, motor_step
        ):
            return STEP_NOT_FINITE
        draws = noise[:, first_draw + s, :] if rough else noise[:, 0, :]
        floor_kernel(pose, lateral, rim_speed, draws, roughness, h, contact, ground_v)
        if bumps:
            apply_cable_deficits(contact, pose, rim_speed, h, true_radius, grid, ground_v)
        midstep_translation(ground_v, pose, params, h)
        if not exchange(addresses, heads, buffer, bodies, ground_v, h, pose, velocity):
            return STEP_BAD_READ_BACK
    return STEP_OK

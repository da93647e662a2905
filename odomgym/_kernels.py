"""The compiled kernels of one control step: the World's physics substeps (wheels, contact
velocities, the exchange with Chipmunk), then dead reckoning, route progress, rewards and the
reported poses, and :func:`control_step`, which runs all of them in one call.

Why one module: a single robot's control step is a few dozen arithmetic operations around
Chipmunk's ``cpSpaceStep`` (0.7 µs on a 2-core machine), while every crossing of the Python
boundary costs about as much: a numba call ~0.1 µs per array argument, a pymunk property 1-2 µs.
So a step is one compiled call (:func:`control_step`) that takes its arrays in one
:class:`StepArrays` (numba's dispatch of that object costs about as much as of five arrays,
whatever it holds) and calls Chipmunk's C functions by address; the kernels it calls are
inlined into it (:func:`odomgym._jit.inlined_kernel`) and live here because numba's on-disk
cache notices edits to a kernel's own module only (:mod:`odomgym._jit`). The classes that own
the state (:class:`odomgym.sim.world.World`, :class:`odomgym.odometry.calibration.Odometry`,
:class:`odomgym.sim.routes.RouteProgress`, :class:`odomgym.sim.trial.Trial`, the envs'
``RouteEpisodes``) call them.

How Chipmunk is reached: pymunk's batch API (``pymunk.batch``) has two C iterator functions,
``pmSpaceBodySetIteratorFuncBatched`` and ``pmSpaceBodyGetIteratorFuncBatched``, that take a body
and a ``pmBatchedData`` block and copy the body's velocity from, or its position, angle,
velocity and angular velocity into, a ``pmFloatArray`` (pymunk calls them on every body of a
space through ``cpSpaceEachBody``). Every argument of these functions and of ``cpSpaceStep`` is a
pointer or a double, so compiled code calls them through their addresses (two small numba
intrinsics, :func:`_call_iterator` and :func:`_call_space_step`) on just the bodies it needs,
the ground bodies in and the chassis out, with the arithmetic of pymunk's own wrappers;
:class:`odomgym.sim.chipmunk_link.SpaceExchange` sets up the structures and checks them, and
pymunk's properties remain the World's fallback. The addresses are runtime values, so the kernels
stay cached.

Units: metres, radians, seconds. Wheel index 0 is the left wheel, 1 the right.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from llvmlite import ir
from numba import types
from numba.experimental import structref
from numba.extending import intrinsic
from numpy.typing import NDArray

from odomgym._jit import inlined_kernel, kernel

__all__ = [
    "BODY_STATE_WIDTH",
    "CHIPMUNK_FUNCTIONS",
    "REPORT_COLUMNS",
    "REPORT_WIDTH",
    "SPARE_ENTRIES",
    "STATE_COLUMNS",
    "STATE_WIDTH",
    "STEP_BAD_READ_BACK",
    "STEP_FIELDS",
    "STEP_NOT_FINITE",
    "STEP_OK",
    "StepArrays",
    "StepArraysType",
    "after_step",
    "check_step_status",
    "control_step",
    "drive_plain",
    "drive_wheels",
    "episode_report",
    "exchange",
    "floor_kernel",
    "integrate_odometry",
    "midstep_translation",
    "new_state",
    "pose_error_into",
    "read_chassis",
    "rim_from_wheel_step",
    "route_update",
    "start_frame",
    "state_parts",
    "state_views",
    "step_plain",
    "write_chassis_velocity",
    "write_ground",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: The World's per-robot state packed into one (N, ``STATE_WIDTH``) array, name -> (first,
#: stop) column: the constants of a substep (``params``: top wheel rate [rad/s], its largest
#: change in one substep [rad/s], true left and right wheel radius [m], encoder ticks per
#: radian, half the true track [m]), then pose, velocity, wheel rates and angles, rim speeds
#: and motor steps of the World's arrays of these names, which are views of it. One argument of
#: a compiled call instead of seven (numba's dispatch costs ~0.1 µs per array).
STATE_COLUMNS: dict[str, tuple[int, int]] = {
    "params": (0, 6),
    "pose": (6, 9),
    "velocity": (9, 12),
    "wheel_rate": (12, 14),
    "wheel_angle": (14, 16),
    "rim_speed": (16, 18),
    "motor_step": (18, 20),
}
STATE_WIDTH = 20
_MAX_RATE, _MAX_RATE_STEP, _RADIUS, _TICKS, _HALF_TRACK = 0, 1, 2, 4, 5  # params columns
_POSE, _VELOCITY, _RATE, _ANGLE, _RIM, _MOTOR = (
    STATE_COLUMNS[name][0] for name in list(STATE_COLUMNS)[1:]
)

# A Chipmunk link (odomgym.sim.chipmunk_link.SpaceExchange): its ``addresses`` hold the space, the
# set and get pmBatchedData blocks, then the C functions of CHIPMUNK_FUNCTIONS, in this order.
_SPACE, _SET_DATA, _GET_DATA, _SPACE_STEP, _SET_ITERATOR, _GET_ITERATOR = range(6)
# After the functions: the pmBatchedData block that sets chassis velocities (skid-steer robots,
# whose velocity the World solves itself: odomgym.sim.world.skid_contacts).
_SET_CHASSIS_DATA = 6
#: The C functions compiled code calls, in the order of a link's addresses after the data.
CHIPMUNK_FUNCTIONS = (
    "cpSpaceStep",
    "pmSpaceBodySetIteratorFuncBatched",
    "pmSpaceBodyGetIteratorFuncBatched",
)
#: x, y, θ, ẋ, ẏ, θ̇ per body, in the order pymunk's get iterator writes them.
BODY_STATE_WIDTH = 6
#: pmFloatArrayPush grows (reallocates) its array when it is within two entries of full; a
#: link's incoming buffer has this many spare entries, so it never reallocates numpy's memory.
SPARE_ENTRIES = 2

#: What :func:`step_plain` and :func:`control_step` return: done, a command was not finite
#: (nothing touched), Chipmunk's read-back went wrong (see :func:`check_step_status`).
STEP_OK, STEP_NOT_FINITE, STEP_BAD_READ_BACK = 0, 1, 2

#: Columns of :func:`episode_report`'s rows: name -> (first, stop).
REPORT_COLUMNS: dict[str, tuple[int, int]] = {
    "reward": (0, 1),
    "terminated": (1, 2),
    "progress": (2, 3),
    "time": (3, 4),
    "completion": (4, 5),
    "odom_pose": (5, 8),
    "true_pose": (8, 11),
    "pose_error": (11, 14),
    "encoder_counts": (14, 16),
    "segment": (16, 17),
    "episode_time": (17, 18),
}
REPORT_WIDTH = 18


def new_state(
    max_rate: FloatArray,
    max_rate_step: FloatArray,
    true_radius: FloatArray,
    ticks_per_rad: FloatArray,
    half_track: FloatArray,
) -> FloatArray:
    """A packed state (:data:`STATE_COLUMNS`) of robots at rest with these constants: top
    wheel rate [rad/s] and its largest change in a substep (N,), true wheel radii (N, 2) [m],
    encoder ticks per radian (N,), half the true track (N,) [m]."""
    state = np.zeros((len(max_rate), STATE_WIDTH))
    state[:, _MAX_RATE] = max_rate
    state[:, _MAX_RATE_STEP] = max_rate_step
    state[:, _RADIUS : _RADIUS + 2] = true_radius
    state[:, _TICKS] = ticks_per_rad
    state[:, _HALF_TRACK] = half_track
    return state


def state_views(state: FloatArray) -> dict[str, FloatArray]:
    """The named views of a packed state (:data:`STATE_COLUMNS`)."""
    return {name: state[:, first:stop] for name, (first, stop) in STATE_COLUMNS.items()}


def _iterator_typing(typingctx: Any, function: Any, body: Any, data: Any) -> Any:
    """``iterator(body, data)`` through the function's address: one of pymunk's batch
    iterators (``void (cpBody *, void *)``) on one body. All three arguments are addresses
    (integers)."""
    del typingctx
    if not all(isinstance(t, types.Integer) for t in (function, body, data)):
        return None

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        del signature
        pointer = ir.IntType(8).as_pointer()
        callee_type = ir.FunctionType(ir.VoidType(), [pointer, pointer])
        callee = builder.inttoptr(args[0], callee_type.as_pointer())
        builder.call(callee, [builder.inttoptr(a, pointer) for a in args[1:]])
        return context.get_dummy_value()

    return types.void(function, body, data), codegen


def _space_step_typing(typingctx: Any, function: Any, space: Any, h: Any) -> Any:
    """``cpSpaceStep(space, h)`` through the function's address (``h`` [s] a double)."""
    del typingctx
    if not (
        isinstance(function, types.Integer)
        and isinstance(space, types.Integer)
        and h == types.float64
    ):
        return None

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        del signature
        pointer = ir.IntType(8).as_pointer()
        callee_type = ir.FunctionType(ir.VoidType(), [pointer, ir.DoubleType()])
        callee = builder.inttoptr(args[0], callee_type.as_pointer())
        builder.call(callee, [builder.inttoptr(args[1], pointer), args[2]])
        return context.get_dummy_value()

    return types.void(function, space, h), codegen


# Typed Any: numba's stubs declare an intrinsic's call with the typing context argument too.
_call_iterator: Any = intrinsic(_iterator_typing)
_call_space_step: Any = intrinsic(_space_step_typing)


@inlined_kernel
def drive_wheels(
    command: FloatArray,
    scale: FloatArray,
    params: FloatArray,
    pose: FloatArray,
    h: float,
    rate: FloatArray,
    angle: FloatArray,
    counts: IntArray,
    rim_speed: FloatArray,
    ground_v: FloatArray,
    motor_step: FloatArray,
) -> bool:
    """Wheel velocity controllers, encoders and no-slip contact velocities of one substep.

    Per wheel: clip the command × ``scale`` of its robot to ±max_rate, move the rate toward it
    by at most max_rate_step (the acceleration limit), rotate by the trapezoid mean rate × h,
    count ticks (floor of the true rotation), and set the contact velocities
    (:func:`_set_ground_velocity`). ``params`` holds each robot's constants (the ``params``
    columns of :data:`STATE_COLUMNS`). In place on ``rate``, ``angle``, ``counts``,
    ``rim_speed``, ``ground_v`` and ``motor_step`` (the rotation this substep [rad], for
    transmission effects); returns False (touching nothing) if any command is not finite.
    """
    if not _finite(command):
        return False
    for i in range(command.shape[0]):
        _wheels(i, command, scale, params, h, rate, angle, counts, rim_speed, motor_step)
        _set_ground_velocity(i, rim_speed, math.cos(pose[i, 2]), math.sin(pose[i, 2]), ground_v)
    return True


@inlined_kernel
def drive_plain(
    command: FloatArray,
    scale: FloatArray,
    params: FloatArray,
    pose: FloatArray,
    h: float,
    rate: FloatArray,
    angle: FloatArray,
    counts: IntArray,
    rim_speed: FloatArray,
    ground_v: FloatArray,
    motor_step: FloatArray,
) -> bool:
    """:func:`drive_wheels` then :func:`midstep_translation`, robot by robot: a substep's
    contact velocities when no effect or floor feature acts between them (the heading's cosine
    and sine serve both)."""
    if not _finite(command):
        return False
    for i in range(command.shape[0]):
        _wheels(i, command, scale, params, h, rate, angle, counts, rim_speed, motor_step)
        cos_t = math.cos(pose[i, 2])
        sin_t = math.sin(pose[i, 2])
        _set_ground_velocity(i, rim_speed, cos_t, sin_t, ground_v)
        _midstep_turn(i, ground_v, cos_t, sin_t, params[i, _HALF_TRACK], h)
    return True


@inlined_kernel
def _finite(command: FloatArray) -> bool:
    """True if every command (N, 2) is finite."""
    for i in range(command.shape[0]):
        if not (math.isfinite(command[i, 0]) and math.isfinite(command[i, 1])):
            return False
    return True


@inlined_kernel
def _wheels(
    i: int,
    command: FloatArray,
    scale: FloatArray,
    params: FloatArray,
    h: float,
    rate: FloatArray,
    angle: FloatArray,
    counts: IntArray,
    rim_speed: FloatArray,
    motor_step: FloatArray,
) -> None:
    """Robot ``i``'s wheel controllers and encoders for one substep (see :func:`drive_wheels`)."""
    limit = params[i, _MAX_RATE]
    step = params[i, _MAX_RATE_STEP]
    for w in range(2):
        target = min(max(command[i, w] * scale[i], -limit), limit)
        old = rate[i, w]
        delta = min(max(target - old, -step), step)
        rate[i, w] = old + delta
        mean = old + 0.5 * delta  # constant acceleration within the substep
        angle[i, w] += mean * h
        motor_step[i, w] = mean * h
        counts[i, w] = math.floor(angle[i, w] * params[i, _TICKS])
        rim_speed[i, w] = mean * params[i, _RADIUS + w]


@inlined_kernel
def _set_ground_velocity(
    i: int, rim_speed: FloatArray, cos_t: float, sin_t: float, ground_v: FloatArray
) -> None:
    """No-slip contact velocities of robot ``i``: each rim speed along the heading (cosine and
    sine given) at which Chipmunk solves the step (:func:`midstep_translation` then turns the
    translation)."""
    for w in range(2):
        ground_v[i, w, 0] = rim_speed[i, w] * cos_t
        ground_v[i, w, 1] = rim_speed[i, w] * sin_t


@inlined_kernel
def midstep_translation(
    ground_v: FloatArray, pose: FloatArray, params: FloatArray, h: float
) -> None:
    """Turn each robot's translation (the mean of its two contact velocities) to the mid-step
    heading θ + ω·h/2, after every effect and the floor shaped the contact velocities; the
    rotation part (their difference, perpendicular to the lever arms) stays as it is.

    Why: Chipmunk moves a body by its velocity times h (first order), so a translation along θ
    makes each step of an arc a tangent, not a chord: a 1 m-radius half circle at 0.35 m/s and
    20 Hz drifted 17.5 mm sideways from the (exact, midpoint) odometry of the same wheel motion.
    With the translation along θ + ω·h/2 each step is the chord; the drift is 0.08 mm. ω is the
    rigid-body rate the contacts ask for: ω = (g_R − g_L)·(cos θ, sin θ)/b.
    """
    for i in range(ground_v.shape[0]):
        cos_t = math.cos(pose[i, 2])
        sin_t = math.sin(pose[i, 2])
        _midstep_turn(i, ground_v, cos_t, sin_t, params[i, _HALF_TRACK], h)


@inlined_kernel
def _midstep_turn(
    i: int, ground_v: FloatArray, cos_t: float, sin_t: float, half_track: float, h: float
) -> None:
    """Robot ``i``'s part of :func:`midstep_translation`, at heading cosine and sine given."""
    dvx = ground_v[i, 1, 0] - ground_v[i, 0, 0]
    dvy = ground_v[i, 1, 1] - ground_v[i, 0, 1]
    omega = (dvx * cos_t + dvy * sin_t) / (2.0 * half_track)
    if omega == 0.0:
        return
    turn = 0.5 * omega * h
    c = math.cos(turn)
    s = math.sin(turn)
    mx = 0.5 * (ground_v[i, 0, 0] + ground_v[i, 1, 0])
    my = 0.5 * (ground_v[i, 0, 1] + ground_v[i, 1, 1])
    rx = c * mx - s * my - mx
    ry = s * mx + c * my - my
    for w in range(2):
        ground_v[i, w, 0] += rx
        ground_v[i, w, 1] += ry


@inlined_kernel
def rim_from_wheel_step(
    wheel_step: FloatArray,
    params: FloatArray,
    pose: FloatArray,
    h: float,
    rim_speed: FloatArray,
    ground_v: FloatArray,
) -> None:
    """Rim speeds and no-slip contact velocities from the wheel rotation of this substep (after
    transmission effects changed it), in place."""
    for i in range(wheel_step.shape[0]):
        for w in range(2):
            rim_speed[i, w] = wheel_step[i, w] * params[i, _RADIUS + w] / h
        _set_ground_velocity(i, rim_speed, math.cos(pose[i, 2]), math.sin(pose[i, 2]), ground_v)


@inlined_kernel
def floor_kernel(
    pose: FloatArray,
    lateral: FloatArray,
    rim_speed: FloatArray,
    noise: FloatArray,
    roughness: FloatArray,
    h: float,
    contact: FloatArray,
    ground_v: FloatArray,
) -> None:
    """Contact points (N, 2, 2) [m] and rough-floor ground velocities, in place.

    Roughness: each wheel's ground travel is its rim travel plus k·√|d|·ξ (Chong & Kleeman 1997,
    Eq. 4), i.e. the ground velocity along the heading gains k·√(|v|·h)·ξ / h, with
    k = ``roughness`` (N, 2) of that wheel [m^½].
    """
    for i in range(pose.shape[0]):
        cos_t = math.cos(pose[i, 2])
        sin_t = math.sin(pose[i, 2])
        for w in range(2):
            contact[i, w, 0] = pose[i, 0] - sin_t * lateral[i, w]
            contact[i, w, 1] = pose[i, 1] + cos_t * lateral[i, w]
            k = roughness[i, w]
            if k > 0.0:
                extra = k * math.sqrt(abs(rim_speed[i, w]) * h) * noise[i, w] / h
                ground_v[i, w, 0] += extra * cos_t
                ground_v[i, w, 1] += extra * sin_t


@inlined_kernel
def write_ground(
    addresses: NDArray[np.uint64], heads: NDArray[np.int32], bodies: NDArray[np.uint64]
) -> None:
    """Each ground body's velocity from the first part of a link's buffer, robot by robot, left
    then right (pymunk's set iterator reads from entry ``num`` on, so it starts at 0)."""
    heads[0, 0] = 0
    for i in range(bodies.shape[0]):
        for w in range(2):
            _call_iterator(addresses[_SET_ITERATOR], bodies[i, 1 + w], addresses[_SET_DATA])


@inlined_kernel
def read_chassis(
    addresses: NDArray[np.uint64], heads: NDArray[np.int32], bodies: NDArray[np.uint64]
) -> bool:
    """Each chassis' state into the second part of a link's buffer, robot by robot (pymunk's
    get iterator appends from entry ``num`` on); False if it appended another count."""
    heads[1, 0] = 0
    for i in range(bodies.shape[0]):
        _call_iterator(addresses[_GET_ITERATOR], bodies[i, 0], addresses[_GET_DATA])
    return bool(heads[1, 0] == BODY_STATE_WIDTH * bodies.shape[0])


@kernel
def write_chassis_velocity(
    addresses: NDArray[np.uint64],
    heads: NDArray[np.int32],
    bodies: NDArray[np.uint64],
    rows: NDArray[np.intp],
    velocity: FloatArray,
    values: FloatArray,
) -> None:
    """Set the velocity and angular velocity of the chassis of robots ``rows`` from
    ``velocity`` (N, 3) [m/s, m/s, rad/s], through pymunk's set iterator and the link's third
    block, whose numpy memory is ``values`` (≥ 3·len(rows)); the iterator reads from entry
    ``num`` on, so it starts at 0. What ``World._skid_step`` would do through pymunk's
    properties, without a Python call per body."""
    for k in range(rows.shape[0]):
        for c in range(3):
            values[3 * k + c] = velocity[rows[k], c]
    heads[2, 0] = 0
    for k in range(rows.shape[0]):
        _call_iterator(addresses[_SET_ITERATOR], bodies[rows[k], 0], addresses[_SET_CHASSIS_DATA])


@inlined_kernel
def exchange(
    addresses: NDArray[np.uint64],
    heads: NDArray[np.int32],
    buffer: FloatArray,
    bodies: NDArray[np.uint64],
    ground_v: FloatArray,
    h: float,
    pose: FloatArray,
    velocity: FloatArray,
) -> bool:
    """One Chipmunk step of ``h`` [s] between the World's arrays and the space: the ground
    bodies take ``ground_v`` (N, 2, 2) [m/s]; afterwards ``pose`` and ``velocity`` (N, 3) hold
    each chassis' pose advanced by v·h and its velocity (see ``World._exchange``). False if
    the read-back went wrong (nothing to trust then)."""
    n = bodies.shape[0]
    for i in range(n):
        for w in range(2):
            buffer[4 * i + 2 * w] = ground_v[i, w, 0]
            buffer[4 * i + 2 * w + 1] = ground_v[i, w, 1]
    write_ground(addresses, heads, bodies)
    _call_space_step(addresses[_SPACE_STEP], addresses[_SPACE], h)
    if not read_chassis(addresses, heads, bodies):
        return False
    for i in range(n):
        base = 4 * n + BODY_STATE_WIDTH * i  # x, y, θ, ẋ, ẏ, θ̇
        for k in range(3):
            velocity[i, k] = buffer[base + 3 + k]
            pose[i, k] = buffer[base + k] + buffer[base + 3 + k] * h
    return True


@inlined_kernel
def state_parts(
    state: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The views of a packed state (:data:`STATE_COLUMNS`) a compiled substep works on:
    params, pose, velocity, wheel rate, wheel angle, rim speed, motor step
    (:func:`state_views` is the named Python version)."""
    return (
        state[:, :_POSE],
        state[:, _POSE : _POSE + 3],
        state[:, _VELOCITY : _VELOCITY + 3],
        state[:, _RATE : _RATE + 2],
        state[:, _ANGLE : _ANGLE + 2],
        state[:, _RIM : _RIM + 2],
        state[:, _MOTOR : _MOTOR + 2],
    )


@inlined_kernel
def step_plain(
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
) -> int:
    """``substeps`` whole substeps of a World without effect hooks on a plain floor: wheels,
    contact velocities and their mid-step turn (:func:`drive_plain`), then Chipmunk
    (:func:`exchange`), on the World's packed ``state`` (:data:`STATE_COLUMNS`). Returns
    ``STEP_OK``, ``STEP_NOT_FINITE`` or ``STEP_BAD_READ_BACK``."""
    params, pose, velocity, rate, angle, rim_speed, motor_step = state_parts(state)
    for _ in range(substeps):
        if not drive_plain(
            command, scale, params, pose, h, rate, angle, counts, rim_speed, ground_v, motor_step
        ):
            return STEP_NOT_FINITE
        if not exchange(addresses, heads, buffer, bodies, ground_v, h, pose, velocity):
            return STEP_BAD_READ_BACK
    return STEP_OK


@inlined_kernel
def integrate_odometry(
    counts: NDArray[np.int64],
    last_counts: NDArray[np.int64],
    travel_per_tick: FloatArray,
    wheelbase: FloatArray,
    skid: FloatArray,
    inv_dt: float,
    pose: FloatArray,
    wheel_speed: FloatArray,
) -> None:
    """Midpoint dead reckoning of one sampling period, in place
    (:mod:`odomgym.odometry.calibration`'s equations): ``pose`` (N, 3) and ``wheel_speed``
    (N, 2) [m/s] from cumulative ``counts``; ``skid`` (N, 5) the calibrations' skid-steer terms
    (:func:`odomgym.odometry.calibration.skid_terms`: x_ICR, y_ICR [m], α/E_b, β, p). A robot
    whose x_ICR, y_ICR and α are 0 takes the differential-drive equations alone, so its results
    do not depend on the skid-steer terms' rounding."""
    for i in range(counts.shape[0]):
        left = (counts[i, 0] - last_counts[i, 0]) * travel_per_tick[i, 0]
        right = (counts[i, 1] - last_counts[i, 1]) * travel_per_tick[i, 1]
        last_counts[i, 0] = counts[i, 0]
        last_counts[i, 1] = counts[i, 1]
        wheel_speed[i, 0] = left * inv_dt
        wheel_speed[i, 1] = right * inv_dt
        ds = 0.5 * (left + right)
        if skid[i, 2] == 0.0:
            dtheta = (right - left) / wheelbase[i]
        else:
            # The track at this period's λ = (L + R)/(R − L); the 1e-12 m floor keeps a step
            # that does not turn at the straight-path track (as odomgym.odometry.icr does).
            difference = right - left
            lam = (right + left) / (difference if abs(difference) > 1e-12 else 1e-12)
            curve = skid[i, 2] / (1.0 + (skid[i, 3] * abs(lam)) ** skid[i, 4])
            dtheta = difference / (wheelbase[i] * (1.0 + curve))
        mid = pose[i, 2] + 0.5 * dtheta
        if skid[i, 0] == 0.0 and skid[i, 1] == 0.0:
            pose[i, 0] += ds * math.cos(mid)
            pose[i, 1] += ds * math.sin(mid)
        else:
            forward = ds + skid[i, 1] * dtheta
            leftward = -skid[i, 0] * dtheta
            c = math.cos(mid)
            s = math.sin(mid)
            pose[i, 0] += forward * c - leftward * s
            pose[i, 1] += forward * s + leftward * c
        pose[i, 2] += dtheta


@inlined_kernel
def route_update(
    pose: FloatArray,
    wheel_speed: FloatArray,
    max_speed: FloatArray,
    count: NDArray[np.intp],
    is_turn: NDArray[np.bool_],
    segments: FloatArray,
    cumulative: FloatArray,
    limits: FloatArray,
    advance: bool,
    index: NDArray[np.intp],
    state: FloatArray,
    progress: FloatArray,
    advanced: NDArray[np.bool_],
) -> None:
    """Route features of each robot's current segment
    (:meth:`odomgym.sim.routes.RouteProgress.update`).

    ``segments`` (N, S, 7): start x, y [m], unit direction x, y, length [m or rad], held heading
    [rad], direction (+1 forwards, −1 reversing); ``limits`` (N, 3): position tolerance [m],
    heading tolerance [rad], stop speed [m/s].
    """
    two_pi = 2.0 * math.pi
    for i in range(pose.shape[0]):
        advanced[i] = False
        for _attempt in range(2):  # the second pass describes the segment just moved on to
            k = index[i]
            finished = k >= count[i]
            s = min(k, count[i] - 1)
            # A turn counts the rotation left unwrapped (a 360° spin must not look finished at
            # the start): that goes to ``remaining``; the heading error itself is wrapped.
            rotation_left = segments[i, s, 5] - pose[i, 2]
            error = (rotation_left + math.pi) % two_pi - math.pi
            rel_x = pose[i, 0] - segments[i, s, 0]
            rel_y = pose[i, 1] - segments[i, s, 1]
            travelled = rel_x * segments[i, s, 2] + rel_y * segments[i, s, 3]
            cross = segments[i, s, 2] * rel_y - segments[i, s, 3] * rel_x
            turn = is_turn[i, s]
            direction = segments[i, s, 6]
            if turn:
                remaining = rotation_left
                done_part = segments[i, s, 4] - abs(rotation_left)
                cross = 0.0
            else:
                remaining = segments[i, s, 4] - travelled
                done_part = travelled
                cross = cross * direction
            if finished:
                remaining = 0.0
                cross = 0.0
                error = 0.0
                progress[i] = cumulative[i, count[i]]
            else:
                progress[i] = cumulative[i, s] + min(max(done_part, 0.0), segments[i, s, 4])
            state[i, 0] = remaining
            state[i, 1] = cross
            state[i, 2] = error
            state[i, 3] = wheel_speed[i, 0] / max_speed[i]
            state[i, 4] = wheel_speed[i, 1] / max_speed[i]
            state[i, 5] = 1.0 if turn else 0.0
            state[i, 6] = direction
            total = cumulative[i, count[i]]
            state[i, 7] = progress[i] / total if total > 0.0 else 1.0
            if not advance or finished or advanced[i]:
                break
            stopped = max(abs(wheel_speed[i, 0]), abs(wheel_speed[i, 1])) < limits[i, 2]
            if turn:
                reached = abs(remaining) < limits[i, 1]
            else:
                reached = remaining < limits[i, 0]
            if not (reached and stopped):
                break
            index[i] = k + 1
            advanced[i] = True


@inlined_kernel
def start_frame(pose: FloatArray, start: FloatArray, out: FloatArray) -> None:
    """World-frame poses (N, 3) expressed in each robot's start frame, into ``out``."""
    for i in range(pose.shape[0]):
        c = math.cos(start[i, 2])
        s = math.sin(start[i, 2])
        dx = pose[i, 0] - start[i, 0]
        dy = pose[i, 1] - start[i, 1]
        out[i, 0] = c * dx + s * dy
        out[i, 1] = -s * dx + c * dy
        out[i, 2] = pose[i, 2] - start[i, 2]


@inlined_kernel
def pose_error_into(pose: FloatArray, start: FloatArray, odom: FloatArray, out: FloatArray) -> None:
    """True pose (world frame) in each robot's start frame minus odometry (N, 3), heading
    wrapped to [−π, π), into ``out`` (compiled; callable from other kernels)."""
    start_frame(pose, start, out)
    two_pi = 2.0 * math.pi
    for i in range(pose.shape[0]):
        out[i, 0] -= odom[i, 0]
        out[i, 1] -= odom[i, 1]
        out[i, 2] = (out[i, 2] - odom[i, 2] + math.pi) % two_pi - math.pi


@inlined_kernel
def after_step(
    counts: NDArray[np.int64],
    last_counts: NDArray[np.int64],
    travel_per_tick: FloatArray,
    wheelbase: FloatArray,
    skid: FloatArray,
    inv_dt: float,
    pose: FloatArray,
    wheel_speed: FloatArray,
    max_speed: FloatArray,
    count: NDArray[np.intp],
    is_turn: NDArray[np.bool_],
    segments: FloatArray,
    cumulative: FloatArray,
    limits: FloatArray,
    index: NDArray[np.intp],
    state: FloatArray,
    progress: FloatArray,
    advanced: NDArray[np.bool_],
) -> None:
    """:func:`integrate_odometry` then :func:`route_update` (moving on to the next segment)."""
    integrate_odometry(
        counts, last_counts, travel_per_tick, wheelbase, skid, inv_dt, pose, wheel_speed
    )
    route_update(
        pose,
        wheel_speed,
        max_speed,
        count,
        is_turn,
        segments,
        cumulative,
        limits,
        True,
        index,
        state,
        progress,
        advanced,
    )


@inlined_kernel
def episode_report(
    true_pose: FloatArray,
    start_poses: FloatArray,
    odom_pose: FloatArray,
    counts: NDArray[np.int64],
    index: NDArray[np.intp],
    count: NDArray[np.intp],
    state: FloatArray,
    time: float,
    episodes: FloatArray,
    weights: FloatArray,
    rewarded: bool,
    out: FloatArray,
) -> None:
    """One row per robot of what a route-following env reports after a step (columns in
    :data:`REPORT_COLUMNS`): the reward and its terms, whether the route is done, the
    odometry and true poses and their error, encoder counts, segment and episode time [s].

    ``episodes`` (N, 2): each robot's episode start time [s] and its route share at its last
    reward; ``weights`` = (progress, time, completion) reward weights. With ``rewarded`` the
    reward terms are those of this step and the route share moves on; without (after a reset),
    they are zero and the share stays.
    """
    pose_error_into(true_pose, start_poses, odom_pose, out[:, 11:14])
    for i in range(true_pose.shape[0]):
        done = index[i] >= count[i]
        if rewarded:
            now = state[i, 7]
            out[i, 2] = weights[0] * (now - episodes[i, 1])
            out[i, 3] = -weights[1]
            out[i, 4] = weights[2] * (1.0 if done else 0.0)
            out[i, 0] = out[i, 2] + out[i, 3] + out[i, 4]
            episodes[i, 1] = now
        else:
            out[i, 0] = 0.0
            out[i, 2] = 0.0
            out[i, 3] = 0.0
            out[i, 4] = 0.0
        out[i, 1] = 1.0 if done else 0.0
        for k in range(3):
            out[i, 5 + k] = odom_pose[i, k]
            out[i, 8 + k] = true_pose[i, k]
        out[i, 14] = counts[i, 0]
        out[i, 15] = counts[i, 1]
        out[i, 16] = index[i]
        out[i, 17] = time - episodes[i, 0]


#: The fields of a :class:`StepArrays`, in its constructor's order: the World's (the trial's
#: wheel rate per unit action [rad/s], then what :meth:`odomgym.sim.world.World.step_arrays`
#: returns: packed state, encoder counts, contact velocities, the Chipmunk link's addresses,
#: headers, buffer and bodies, the clock [s]), the odometry's (last counts, travel per tick [m],
#: wheelbase [m], skid-steer terms, pose, wheel speeds [m/s]), the trial's top wheel speeds
#: [m/s], the route's
#: (:meth:`odomgym.sim.routes.RouteProgress.step_arrays`), the trial's start poses, and the
#: substep [s], substeps per step and control period [s].
STEP_FIELDS = (
    "scale",
    "state",
    "counts",
    "ground_v",
    "addresses",
    "heads",
    "buffer",
    "bodies",
    "clock",
    "last_counts",
    "travel_per_tick",
    "wheelbase",
    "skid",
    "odom_pose",
    "wheel_speed",
    "max_speed",
    "count",
    "is_turn",
    "segments",
    "cumulative",
    "limits",
    "index",
    "route_state",
    "progress",
    "advanced",
    "start_poses",
    "substep",
    "substeps",
    "dt",
)


@structref.register
class StepArraysType(types.StructRef):
    """numba's type of a :class:`StepArrays`."""

    def preprocess_fields(self, fields: Any) -> Any:
        unliteral: Any = types.unliteral  # numba's functions carry no annotations
        return tuple((name, unliteral(typ)) for name, typ in fields)


class StepArrays(structref.StructRefProxy):
    """Every array of a Trial's control step (:data:`STEP_FIELDS`), held for
    :func:`control_step`: numba reads the object once per call, where passing its thirty
    arrays one by one would cost ~3 µs. It holds references: the owners update these arrays in
    place, and the Trial makes a new one whenever it rebuilds the route arrays."""

    def __new__(cls, *values: Any) -> StepArrays:
        new: Any = structref.StructRefProxy.__new__  # numba's functions carry no annotations
        return new(cls, *values)  # type: ignore[no-any-return]


_define_proxy: Any = structref.define_proxy
_define_proxy(StepArrays, StepArraysType, list(STEP_FIELDS))


@kernel
def control_step(
    command: FloatArray,
    arrays: Any,
    physics: bool,
    report: bool,
    episodes: FloatArray,
    weights: FloatArray,
    out: FloatArray,
) -> int:
    """One control step of a Trial (``arrays`` its :class:`StepArrays`) for wheel commands
    (N, 2) in [−1, 1]: with ``physics``, the World's substeps (:func:`step_plain`) and its clock
    (without, the World stepped already); then dead reckoning and route progress
    (:func:`after_step`); and with ``report``, the rewarded episode report into ``out``
    (:func:`episode_report`, which describes ``episodes`` and ``weights``).

    Returns :func:`step_plain`'s status (after a failed one nothing after the physics is done).
    """
    a = arrays
    if physics:
        status = step_plain(
            command,
            a.scale,
            a.state,
            a.counts,
            a.ground_v,
            a.addresses,
            a.heads,
            a.buffer,
            a.bodies,
            a.substep,
            a.substeps,
        )
        if status != STEP_OK:
            return status
        a.clock[0] += a.dt
    after_step(
        a.counts,
        a.last_counts,
        a.travel_per_tick,
        a.wheelbase,
        a.skid,
        1.0 / a.dt,
        a.odom_pose,
        a.wheel_speed,
        a.max_speed,
        a.count,
        a.is_turn,
        a.segments,
        a.cumulative,
        a.limits,
        a.index,
        a.route_state,
        a.progress,
        a.advanced,
    )
    if report:
        episode_report(
            a.state[:, _POSE : _POSE + 3],
            a.start_poses,
            a.odom_pose,
            a.counts,
            a.index,
            a.count,
            a.route_state,
            a.clock[0],
            episodes,
            weights,
            True,
            out,
        )
    return STEP_OK


def check_step_status(status: int) -> None:
    """Raise the error a :func:`step_plain` or :func:`control_step` status stands for."""
    if status == STEP_NOT_FINITE:
        raise ValueError("wheel rate commands must be finite")
    if status == STEP_BAD_READ_BACK:
        raise RuntimeError(
            "Chipmunk returned another number of body states than the space has bodies"
        )

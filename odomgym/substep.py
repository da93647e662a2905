"""One physics substep of a :class:`~odomgym.physics.World`, compiled: the wheel controllers and
encoders, the no-slip contact velocities, and the exchange of body states with Chipmunk.

Why a module of its own: a single robot's substep is a few dozen arithmetic operations around
Chipmunk's ``cpSpaceStep`` (0.7 µs for one robot on a 2-core machine), and every crossing of the
Python boundary costs about as much: a numba call ~0.1 µs per array argument, a pymunk property
1-2 µs, a cffi call 0.2-0.4 µs. So the whole substep — wheels, contact velocities, writing the
ground bodies' velocities, Chipmunk's step and reading the chassis back — runs as one compiled
call (:func:`step_plain`), which calls Chipmunk's C functions by address
(:class:`SpaceExchange`). Kernels that call each other live in one module because numba's
on-disk cache notices edits to a kernel's own file only (:mod:`odomgym._jit`).

How Chipmunk is reached: pymunk's batch API (``pymunk.batch``) is a pair of C iterator functions,
``pmSpaceBodySetIteratorFuncBatched`` and ``pmSpaceBodyGetIteratorFuncBatched``, that
``cpSpaceEachBody`` calls for every body of a space with a ``pmBatchedData`` block: they copy
each body's velocity from, or its position, angle, velocity and angular velocity into, a
``pmFloatArray``. Every argument of these functions and of ``cpSpaceStep`` is a pointer or a
double, so compiled code can call them through their addresses (two small numba intrinsics,
:func:`_call_each_body` and :func:`_call_space_step`) with the very arithmetic of pymunk's own
Python wrappers, which remain the World's fallback (``tests/test_world_io.py`` checks that both
give bit-identical trajectories). The addresses are runtime values, so the kernels stay cached.

Units: metres, radians, seconds. Wheel index 0 is the left wheel, 1 the right.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pymunk
import pymunk.batch as pbatch
from llvmlite import ir
from numba import types
from numba.extending import intrinsic
from numpy.typing import NDArray

from odomgym._jit import kernel

__all__ = [
    "STATE_COLUMNS",
    "STATE_WIDTH",
    "SpaceExchange",
    "drive_wheels",
    "exchange",
    "floor_kernel",
    "midstep_translation",
    "new_state",
    "rim_from_wheel_step",
    "state_views",
    "step_plain",
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

# Entries of SpaceExchange.addresses: the space and two pmBatchedData blocks, then functions.
_SPACE, _SET_DATA, _GET_DATA, _EACH_BODY, _SPACE_STEP, _SET_ITERATOR, _GET_ITERATOR = range(7)
_FUNCTIONS = (
    "cpSpaceEachBody",
    "cpSpaceStep",
    "pmSpaceBodySetIteratorFuncBatched",
    "pmSpaceBodyGetIteratorFuncBatched",
)
_STATE_FIELDS = (
    pbatch.BodyFields.POSITION
    | pbatch.BodyFields.ANGLE
    | pbatch.BodyFields.VELOCITY
    | pbatch.BodyFields.ANGULAR_VELOCITY
)
_STATE_WIDTH = 6  # x, y, θ, ẋ, ẏ, θ̇ per body, in the order the get iterator writes them
# pmFloatArrayPush grows (reallocates) its array when it is within two entries of full; two
# spare entries keep it from ever reallocating the numpy memory it writes into.
_SPARE = 2


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


class SpaceExchange:
    """Where a World's body states cross into and out of Chipmunk, once per substep.

    Every body's velocity goes in (a chassis keeps its own, a ground body gets its wheel's
    contact velocity); after Chipmunk's step every body's position, angle, velocity and angular
    velocity come out, in Chipmunk's own body order, which ``rows`` maps the robots onto.
    With ``compiled`` the kernels do this through Chipmunk's functions by address (module
    docstring); otherwise (a pymunk whose batch internals differ from what this module expects,
    checked at construction) :meth:`exchange_in_python` does the same through ``pymunk.batch``.

    Args:
        space: the World's space (its bodies are never added to or removed afterwards).
        chassis: each robot's chassis body.
        ground: each robot's two ground bodies, ``[2i]`` left and ``[2i + 1]`` right.

    Arrays (read them in kernels; the C structures point into them):
        ``rows`` (N, 3) Chipmunk's row of each robot's chassis, left and right ground body;
        ``buffer`` the 2·B velocities going in (B bodies), then the 6·B states coming out and
        two spare entries;
        ``heads`` (2, 4) int32: the ``pmFloatArray`` headers (``num``, ``max``, data pointer) of
        the two parts of ``buffer``, in numpy memory so a kernel can rewind ``num``;
        ``addresses`` (7,) uint64: the space, the two ``pmBatchedData`` blocks and the four C
        functions (``_FUNCTIONS``).
    """

    def __init__(
        self, space: pymunk.Space, chassis: list[pymunk.Body], ground: list[pymunk.Body]
    ) -> None:
        self.space = space
        n_bodies = len(space.bodies)
        ids = pbatch.Buffer()
        pbatch.get_space_bodies(space, pbatch.BodyFields.BODY_ID, ids)
        row = {int(body_id): k for k, body_id in enumerate(np.frombuffer(ids.int_buf(), np.uintp))}
        self.rows = np.array(
            [
                [row[body.id] for body in (c, *ground[2 * i : 2 * i + 2])]
                for i, c in enumerate(chassis)
            ],
            dtype=np.intp,
        ).reshape(-1, 3)
        self.buffer = np.zeros(2 * n_bodies + _STATE_WIDTH * n_bodies + _SPARE)
        self._velocities = self.buffer[: 2 * n_bodies]
        # pymunk.batch's own buffers, for the fallback: the outgoing one wraps our velocities.
        self._out = pbatch.Buffer()
        self._out.set_float_buf(self._velocities)
        self._in = pbatch.Buffer()
        self.heads = np.zeros((2, 4), dtype=np.int32)
        self.addresses = np.zeros(7, dtype=np.uint64)
        self._structures: list[Any] = []  # cffi objects the addresses point into, kept alive
        self.compiled = self._link() and self._link_works(chassis, ground)

    def _link(self) -> bool:
        """Build the C structures and fill ``addresses``; False if this pymunk lacks them."""
        ffi, lib = getattr(pbatch, "ffi", None), getattr(pbatch, "lib", None)
        raw_space = getattr(self.space, "_space", None)  # the cpSpace* pymunk steps
        if ffi is None or lib is None or raw_space is None:
            return False
        try:
            functions = [ffi.addressof(lib, name) for name in _FUNCTIONS]
            if not (
                ffi.sizeof("cpFloat") == 8
                and ffi.sizeof("pmFloatArray") == self.heads[0].nbytes
                and ffi.offsetof("pmFloatArray", "num") == 0
            ):
                return False
            n_velocities = self._velocities.size
            blocks = []
            for k, (part, fields) in enumerate(
                (
                    (self._velocities, pbatch.BodyFields.VELOCITY),
                    (self.buffer[n_velocities:], _STATE_FIELDS),
                )
            ):
                array = ffi.from_buffer("pmFloatArray *", self.heads[k])
                array.arr = ffi.cast("cpFloat *", ffi.from_buffer(part))
                array.max = part.size
                data = ffi.new("pmBatchedData *")
                data.fields = fields.value
                data.floatArray = array
                data.intArray = ffi.NULL
                blocks.append(data)
                self._structures += [array, data]
        except (AttributeError, TypeError, ValueError, ffi.error):
            return False

        def address(pointer: Any) -> int:
            return int(ffi.cast("uintptr_t", pointer))

        self.addresses[:] = [address(raw_space), *map(address, blocks), *map(address, functions)]
        return True

    def _link_works(self, chassis: list[pymunk.Body], ground: list[pymunk.Body]) -> bool:
        """True if the compiled exchange moves what pymunk's properties see: every chassis
        state and a test velocity of one ground body out, another test velocity in. The bodies
        are left as they were (every velocity written back is one just read, then the test
        body's own is restored), so a World unpickled mid-run goes on unchanged."""
        probe, row = ground[0], self.rows[0, 1]
        original = probe.velocity
        probe.velocity = (0.25, -0.5)
        states = self.buffer[self._velocities.size : -_SPARE].reshape(-1, _STATE_WIDTH)
        ok = read_bodies(self.addresses, self.heads)
        ok = ok and tuple(states[row, 3:5]) == (0.25, -0.5)
        for i, body in enumerate(chassis):
            expected = (*body.position, body.angle, *body.velocity, body.angular_velocity)
            ok = ok and tuple(states[self.rows[i, 0]]) == expected
        velocities = self._velocities.reshape(-1, 2)
        velocities[:] = states[:, 3:5]
        velocities[row] = (-1.0, 2.0)
        write_bodies(self.addresses, self.heads)
        ok = ok and tuple(probe.velocity) == (-1.0, 2.0)
        probe.velocity = original
        return ok

    def exchange_in_python(
        self, velocity: FloatArray, ground_v: FloatArray, h: float, pose: FloatArray
    ) -> None:
        """:func:`exchange` through ``pymunk.batch`` and ``Space.step`` (the fallback)."""
        n_velocities = self._velocities.size
        pack_velocities(velocity, ground_v, self.rows, self.buffer[:n_velocities])
        pbatch.set_space_bodies(self.space, pbatch.BodyFields.VELOCITY, self._out)
        self.space.step(h)
        self._in.clear()
        pbatch.get_space_bodies(self.space, _STATE_FIELDS, self._in)
        unpack_states(np.frombuffer(self._in.float_buf(), np.float64), self.rows, h, pose, velocity)


def _each_body_typing(typingctx: Any, function: Any, space: Any, iterator: Any, data: Any) -> Any:
    """``cpSpaceEachBody(space, iterator, data)`` through the function's address: Chipmunk
    calls ``iterator(body, data)`` for every body. All four arguments are addresses (integers)."""
    del typingctx
    if not all(isinstance(t, types.Integer) for t in (function, space, iterator, data)):
        return None

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        del signature
        pointer = ir.IntType(8).as_pointer()
        callee_type = ir.FunctionType(ir.VoidType(), [pointer, pointer, pointer])
        callee = builder.inttoptr(args[0], callee_type.as_pointer())
        builder.call(callee, [builder.inttoptr(a, pointer) for a in args[1:]])
        return context.get_dummy_value()

    return types.void(function, space, iterator, data), codegen


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
_call_each_body: Any = intrinsic(_each_body_typing)
_call_space_step: Any = intrinsic(_space_step_typing)


@kernel
def write_bodies(addresses: NDArray[np.uint64], heads: NDArray[np.int32]) -> None:
    """Every body's velocity from the first part of the exchange buffer (pymunk's
    ``set_space_bodies``: the set iterator reads from entry ``num`` on, so it starts at 0)."""
    heads[0, 0] = 0
    _call_each_body(
        addresses[_EACH_BODY], addresses[_SPACE], addresses[_SET_ITERATOR], addresses[_SET_DATA]
    )


@kernel
def read_bodies(addresses: NDArray[np.uint64], heads: NDArray[np.int32]) -> bool:
    """Every body's state into the second part of the exchange buffer (pymunk's
    ``get_space_bodies`` after ``Buffer.clear``); False if Chipmunk wrote another count."""
    heads[1, 0] = 0
    _call_each_body(
        addresses[_EACH_BODY], addresses[_SPACE], addresses[_GET_ITERATOR], addresses[_GET_DATA]
    )
    return bool(heads[1, 0] == heads[1, 1] - _SPARE)


@kernel
def exchange(
    addresses: NDArray[np.uint64],
    heads: NDArray[np.int32],
    buffer: FloatArray,
    rows: NDArray[np.intp],
    velocity: FloatArray,
    ground_v: FloatArray,
    h: float,
    pose: FloatArray,
) -> bool:
    """One Chipmunk step of ``h`` [s] between the World's arrays and the space: the ground
    bodies take ``ground_v`` (N, 2, 2), the chassis keep ``velocity``; afterwards ``pose`` and
    ``velocity`` (N, 3) hold each chassis' pose advanced by v·h and velocity (see
    ``World._read_state``). False if the read-back went wrong (nothing to trust then)."""
    n_velocities = heads[0, 1]
    pack_velocities(velocity, ground_v, rows, buffer[:n_velocities])
    write_bodies(addresses, heads)
    _call_space_step(addresses[_SPACE_STEP], addresses[_SPACE], h)
    if not read_bodies(addresses, heads):
        return False
    unpack_states(buffer[n_velocities:], rows, h, pose, velocity)
    return True


@kernel
def step_plain(
    command: FloatArray,
    scale: FloatArray,
    state: FloatArray,
    counts: IntArray,
    ground_v: FloatArray,
    addresses: NDArray[np.uint64],
    heads: NDArray[np.int32],
    buffer: FloatArray,
    rows: NDArray[np.intp],
    h: float,
    substeps: int,
) -> int:
    """``substeps`` whole substeps of a World without effect hooks on a plain floor: wheels,
    contact velocities and their mid-step turn (:func:`drive_plain`), then Chipmunk
    (:func:`exchange`), on the World's packed ``state`` (:data:`STATE_COLUMNS`). Returns 0, or
    1 if a command is not finite (nothing touched), or 2 if Chipmunk's read-back went wrong."""
    params = state[:, :_POSE]
    pose = state[:, _POSE : _POSE + 3]
    velocity = state[:, _VELOCITY : _VELOCITY + 3]
    rate = state[:, _RATE : _RATE + 2]
    angle = state[:, _ANGLE : _ANGLE + 2]
    rim_speed = state[:, _RIM : _RIM + 2]
    motor_step = state[:, _MOTOR : _MOTOR + 2]
    for _ in range(substeps):
        if not drive_plain(
            command, scale, params, pose, h, rate, angle, counts, rim_speed, ground_v, motor_step
        ):
            return 1
        if not exchange(addresses, heads, buffer, rows, velocity, ground_v, h, pose):
            return 2
    return 0


@kernel
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
    n = command.shape[0]
    for i in range(n):
        if not (math.isfinite(command[i, 0]) and math.isfinite(command[i, 1])):
            return False
    for i in range(n):
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
        _set_ground_velocity(i, rim_speed, pose, ground_v)
    return True


@kernel
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
    """:func:`drive_wheels` then :func:`midstep_translation`: a substep's contact velocities
    when no effect or floor feature acts between them."""
    if not drive_wheels(
        command, scale, params, pose, h, rate, angle, counts, rim_speed, ground_v, motor_step
    ):
        return False
    midstep_translation(ground_v, pose, params, h)
    return True


@kernel
def pack_velocities(
    velocity: FloatArray,
    ground_v: FloatArray,
    rows: NDArray[np.intp],
    out: FloatArray,
) -> None:
    """Every body's velocity in Chipmunk's body order (``out``, flat x, y per body): a chassis
    keeps its own, a ground body gets its contact velocity."""
    for i in range(rows.shape[0]):
        out[2 * rows[i, 0]] = velocity[i, 0]
        out[2 * rows[i, 0] + 1] = velocity[i, 1]
        for w in range(2):
            out[2 * rows[i, 1 + w]] = ground_v[i, w, 0]
            out[2 * rows[i, 1 + w] + 1] = ground_v[i, w, 1]


@kernel
def unpack_states(
    data: FloatArray,
    rows: NDArray[np.intp],
    h: float,
    pose: FloatArray,
    velocity: FloatArray,
) -> None:
    """Chassis poses advanced by v·h and velocities from Chipmunk's rows (x, y, θ, ẋ, ẏ, θ̇ per
    body, flat), in place (see ``World._read_state``)."""
    for i in range(rows.shape[0]):
        base = _STATE_WIDTH * rows[i, 0]
        for k in range(3):
            velocity[i, k] = data[base + 3 + k]
            pose[i, k] = data[base + k] + data[base + 3 + k] * h


@kernel
def _set_ground_velocity(
    i: int, rim_speed: FloatArray, pose: FloatArray, ground_v: FloatArray
) -> None:
    """No-slip contact velocities of robot ``i``: each rim speed along the heading at which
    Chipmunk solves the step (:func:`midstep_translation` then turns the translation)."""
    cos_t = math.cos(pose[i, 2])
    sin_t = math.sin(pose[i, 2])
    for w in range(2):
        ground_v[i, w, 0] = rim_speed[i, w] * cos_t
        ground_v[i, w, 1] = rim_speed[i, w] * sin_t


@kernel
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
        dvx = ground_v[i, 1, 0] - ground_v[i, 0, 0]
        dvy = ground_v[i, 1, 1] - ground_v[i, 0, 1]
        omega = (dvx * cos_t + dvy * sin_t) / (2.0 * params[i, _HALF_TRACK])
        if omega == 0.0:
            continue
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


@kernel
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
        _set_ground_velocity(i, rim_speed, pose, ground_v)


@kernel
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

"""The C structures through which compiled kernels reach Chipmunk (:mod:`odomgym._kernels`,
"How Chipmunk is reached"): a World's space and bodies as addresses, the two ``pmBatchedData``
blocks of pymunk's batch iterators and the numpy memory they point into, checked against
pymunk's own view of the bodies; and the same exchange through pymunk's public API, the
fallback if a pymunk release changes what the compiled path relies on.

Units: metres, radians, seconds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pymunk
import pymunk.batch as pbatch
from numpy.typing import NDArray

from odomgym._kernels import (
    BODY_STATE_WIDTH,
    CHIPMUNK_FUNCTIONS,
    SPARE_ENTRIES,
    read_chassis,
    write_chassis_velocity,
    write_ground,
)

__all__ = ["SpaceExchange"]

FloatArray = NDArray[np.float64]

_STATE_FIELDS = (
    pbatch.BodyFields.POSITION
    | pbatch.BodyFields.ANGLE
    | pbatch.BodyFields.VELOCITY
    | pbatch.BodyFields.ANGULAR_VELOCITY
)


class SpaceExchange:
    """Where a World's body states cross into and out of Chipmunk, once per substep.

    The ground bodies take their wheels' contact velocities; after Chipmunk's step, each
    chassis' position, angle, velocity and angular velocity come out (a chassis' velocity is
    Chipmunk's own and never written). With ``compiled``, kernels do this by calling pymunk's
    batch iterators on these bodies and Chipmunk's step through their addresses
    (:func:`odomgym._kernels.exchange`); otherwise :meth:`exchange_in_python` does the same
    through pymunk's properties and ``Space.step`` (bit-identical, ``tests/test_world_io.py``).

    Args:
        space: the World's space (its bodies are never added to or removed afterwards).
        chassis: each robot's chassis body.
        ground: each robot's two ground bodies, ``[2i]`` left and ``[2i + 1]`` right.

    Arrays (for kernels; the C structures point into them):
        ``bodies`` (N, 3) uint64: the ``cpBody*`` of each robot's chassis, left and right
        ground body;
        ``buffer``: the 4·N ground velocities going in (robot by robot, left then right, x and
        y), then the 6·N chassis states coming out (x, y, θ, ẋ, ẏ, θ̇) and two spare entries;
        ``heads`` (3, 4) int32: the ``pmFloatArray`` headers (``num``, ``max``, data pointer) of
        the two parts of ``buffer`` and of ``chassis_in``, in numpy memory so a kernel can
        rewind ``num``;
        ``chassis_in`` (3·N,): chassis velocities going in (ẋ, ẏ, θ̇ per robot), for the robots
        whose velocity the World sets itself (skid-steer robots, :meth:`set_chassis_velocity`);
        ``addresses`` (7,) uint64: the space, the set and get ``pmBatchedData`` blocks, the
        C functions of :data:`odomgym._kernels.CHIPMUNK_FUNCTIONS`, then the block that sets
        chassis velocities.
    """

    def __init__(
        self, space: pymunk.Space, chassis: list[pymunk.Body], ground: list[pymunk.Body]
    ) -> None:
        self.space = space
        self._chassis = chassis
        self._ground = ground
        n = len(chassis)
        self.buffer = np.zeros(4 * n + BODY_STATE_WIDTH * n + SPARE_ENTRIES)
        self.chassis_in = np.zeros(3 * n)
        self.heads = np.zeros((3, 4), dtype=np.int32)
        self.addresses = np.zeros(4 + len(CHIPMUNK_FUNCTIONS), dtype=np.uint64)
        self.bodies = np.zeros((n, 3), dtype=np.uint64)
        self._structures: list[Any] = []  # cffi objects the addresses point into, kept alive
        self.compiled = self._link() and self._link_works()

    def _link(self) -> bool:
        """Build the C structures, fill ``addresses`` and ``bodies``; False if this pymunk
        lacks what they need (its C library's functions and types, ``Space._space``,
        ``Body._body``)."""
        ffi, lib = getattr(pbatch, "ffi", None), getattr(pbatch, "lib", None)
        raw_space = getattr(self.space, "_space", None)  # the cpSpace* pymunk steps
        raw_bodies = [getattr(body, "_body", None) for body in self._chassis + self._ground]
        if ffi is None or lib is None or raw_space is None or None in raw_bodies:
            return False
        try:
            functions = [ffi.addressof(lib, name) for name in CHIPMUNK_FUNCTIONS]
            if not (
                ffi.sizeof("cpFloat") == 8
                and ffi.sizeof("pmFloatArray") == self.heads[0].nbytes
                and ffi.offsetof("pmFloatArray", "num") == 0
            ):
                return False
            n_in = 4 * len(self._chassis)
            blocks = []
            for k, (part, fields) in enumerate(
                (
                    (self.buffer[:n_in], pbatch.BodyFields.VELOCITY),
                    (self.buffer[n_in:], _STATE_FIELDS),
                    (
                        self.chassis_in,
                        pbatch.BodyFields.VELOCITY | pbatch.BodyFields.ANGULAR_VELOCITY,
                    ),
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

        self.addresses[:] = [
            address(raw_space),
            *map(address, blocks[:2]),
            *map(address, functions),
            address(blocks[2]),
        ]
        n = len(self._chassis)
        self.bodies[:, 0] = [address(b) for b in raw_bodies[:n]]
        self.bodies[:, 1:] = np.reshape([address(b) for b in raw_bodies[n:]], (n, 2))
        return True

    def _link_works(self) -> bool:
        """True if the compiled exchange moves what pymunk's properties see: every chassis
        state out, with a test velocity on the first; a test velocity into one ground body, the
        others' own. The bodies are left as they were (the test velocities are undone), so a
        World unpickled mid-run goes on unchanged."""
        chassis, probe = self._chassis[0], self._ground[0]
        original = chassis.velocity, chassis.angular_velocity, probe.velocity
        chassis.velocity, chassis.angular_velocity = (0.25, -0.5), 0.125
        ok = read_chassis(self.addresses, self.heads, self.bodies)
        states = self.buffer[4 * len(self._chassis) : -SPARE_ENTRIES].reshape(-1, BODY_STATE_WIDTH)
        for body, state in zip(self._chassis, states, strict=True):
            expected = (*body.position, body.angle, *body.velocity, body.angular_velocity)
            ok = ok and tuple(state) == expected
        self.buffer[: 4 * len(self._chassis)] = [v for body in self._ground for v in body.velocity]
        self.buffer[:2] = (-1.0, 2.0)
        write_ground(self.addresses, self.heads, self.bodies)
        ok = ok and tuple(probe.velocity) == (-1.0, 2.0)
        velocity = np.array([[0.75, -0.25, 1.5]])
        write_chassis_velocity(
            self.addresses, self.heads, self.bodies, np.zeros(1, np.intp), velocity, self.chassis_in
        )
        ok = ok and (*chassis.velocity, chassis.angular_velocity) == (0.75, -0.25, 1.5)
        chassis.velocity, chassis.angular_velocity, probe.velocity = original
        return ok

    def set_chassis_velocity(self, rows: NDArray[np.intp], velocity: FloatArray) -> None:
        """Set the velocity and angular velocity of the chassis of robots ``rows`` from
        ``velocity`` (N, 3) [m/s, m/s, rad/s]: compiled through the link's third block, or
        through pymunk's properties (the same floats either way)."""
        if self.compiled:
            write_chassis_velocity(
                self.addresses, self.heads, self.bodies, rows, velocity, self.chassis_in
            )
            return
        for i in rows:
            body = self._chassis[i]
            body.velocity = (float(velocity[i, 0]), float(velocity[i, 1]))
            body.angular_velocity = float(velocity[i, 2])

    def exchange_in_python(
        self, ground_v: FloatArray, h: float, pose: FloatArray, velocity: FloatArray
    ) -> None:
        """:func:`odomgym._kernels.exchange` through pymunk's properties and ``Space.step``
        (the fallback), with the same arithmetic."""
        for body, (vx, vy) in zip(self._ground, ground_v.reshape(-1, 2).tolist(), strict=True):
            body.velocity = (vx, vy)
        self.space.step(h)
        for i, body in enumerate(self._chassis):
            px, py = body.position
            vx, vy = body.velocity
            omega = body.angular_velocity
            pose[i] = (px + vx * h, py + vy * h, body.angle + omega * h)
            velocity[i] = (vx, vy, omega)

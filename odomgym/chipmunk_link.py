"""The C structures through which compiled kernels reach Chipmunk (:mod:`odomgym.stepping`,
"How Chipmunk is reached"): a World's space, its two ``pmBatchedData`` blocks and the numpy
memory they point into, checked against pymunk's own view of the bodies.

Units: metres, radians, seconds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pymunk
import pymunk.batch as pbatch
from numpy.typing import NDArray

from odomgym.stepping import (
    BODY_STATE_WIDTH,
    CHIPMUNK_FUNCTIONS,
    SPARE_ENTRIES,
    pack_velocities,
    read_bodies,
    unpack_states,
    write_bodies,
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
        functions (``CHIPMUNK_FUNCTIONS``).
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
        self.buffer = np.zeros(2 * n_bodies + BODY_STATE_WIDTH * n_bodies + SPARE_ENTRIES)
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
            functions = [ffi.addressof(lib, name) for name in CHIPMUNK_FUNCTIONS]
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
        states = self.buffer[self._velocities.size : -SPARE_ENTRIES].reshape(-1, BODY_STATE_WIDTH)
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

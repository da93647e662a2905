"""Ahead-of-loop compilation of the per-step kernels with numba.

Why: a control step of one robot is a few dozen arithmetic operations; as numpy calls on
arrays of one row each would cost ~0.8 µs of dispatch, more than the physics itself
(``benchmarks/bench_speed.py`` measures it). The kernels are therefore written as plain loops
over the robots and compiled with numba, which makes a batch of one and a batch of 256 equally
cheap per robot. Set ``NUMBA_DISABLE_JIT=1`` to run the very same source as ordinary Python
(slower, identical semantics), e.g. to step through it in a debugger.

Caveat of numba's on-disk cache: it notices edits to a kernel's own module, not to a kernel it
*calls* in another module. Kernels that call each other therefore live in one module (e.g.
``odomgym.floor``'s cable geometry).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

__all__ = ["inlined_kernel", "kernel"]

F = TypeVar("F", bound=Callable[..., Any])


def kernel(function: F) -> F:
    """Compile ``function`` in nopython mode, cached on disk, IEEE-exact (no fastmath)."""
    compiled = numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")(function)
    return cast(F, compiled)


def inlined_kernel(function: F) -> F:
    """A :func:`kernel` that other kernels inline (numba's ``inline="always"``, at the level of
    numba's IR, so the arithmetic is the same): no call boundary, where passing arrays to a
    called kernel costs reference counting and copies of their descriptions (~0.5 µs of a
    single robot's control step, which calls some fifteen kernels). Called from Python it is
    an ordinary kernel. A call with a constant argument (a loop bound) is compiled for that
    constant, so loops over it unroll; it costs compile time per call site."""
    compiled = numba.njit(
        cache=True, nogil=True, fastmath=False, error_model="numpy", inline="always"
    )(function)
    return cast(F, compiled)

"""glibc's allocator told to keep the memory a diagnosis frees, instead of handing it back.

Why: a noise fit evaluates the filter hundreds of times, and each evaluation allocates the
process noise of every run stacked (on the 14 June OptiOdom sessions four arrays of 2 MB). By
default glibc serves an allocation that large with a fresh ``mmap`` or trims the heap top back
to the system once enough is free, so the next evaluation's arrays fault their pages in again:
on those sessions the page faults were 90 % of the process noise's time (7.3 ms of an
evaluation's process noise against 0.7 ms with the memory kept) and about a third of a
wheel-noise evaluation. With the thresholds raised the freed blocks are reused as they are.

The numbers do not change (an allocator hands back memory, not values); only where it comes
from. The cost: a process that ran a diagnosis keeps up to :data:`TRIM_THRESHOLD` of freed heap
mapped, and allocations up to :data:`MMAP_THRESHOLD` come from the heap (glibc's dynamic
threshold, which would have learnt some of this, stops adjusting once a threshold is set). Set
``ODOMGYM_MALLOPT=0`` to leave the allocator as it is. Other C libraries (musl, macOS,
Windows) are left alone.
"""

from __future__ import annotations

import ctypes
import os
import sys

__all__ = ["MMAP_THRESHOLD", "TRIM_THRESHOLD", "keep_freed_memory"]

MMAP_THRESHOLD = 64 << 20
"""Allocations below this many bytes come from the heap, not a fresh ``mmap`` [bytes]."""

TRIM_THRESHOLD = 256 << 20
"""The heap top is given back to the system only once this much of it is free [bytes]."""

_M_TRIM_THRESHOLD = -1  # glibc's malloc.h
_M_MMAP_THRESHOLD = -3

_DONE = False


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds for this process (once; forked workers inherit
    them). Returns whether they are raised: False with ``ODOMGYM_MALLOPT=0``, off Linux, or
    where the C library has no ``mallopt``."""
    global _DONE
    if _DONE:
        return True
    if os.environ.get("ODOMGYM_MALLOPT", "") == "0" or not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # no symbol table to load, or not glibc
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    _DONE = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )
    return _DONE

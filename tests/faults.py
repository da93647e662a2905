"""Fault injection for the worker-pool tests: a benchmark chunk task that makes its worker
process exit hard, as a killed or out-of-memory worker would. It lives in the tests (module
level, so spawned workers import it by reference), not in the package."""

from __future__ import annotations

import os
from typing import Any

from odomgym.baselines.benchmark import BenchConfig, run_chunk

EXIT_CODE = 86


def exiting_chunk(
    config: BenchConfig, part: list[int], attempt: int, *, robot: int, always: bool
) -> list[dict[str, Any]]:
    """Run the chunk, unless it holds ``robot``: then exit the worker process at once — on
    its first attempt only, or on every attempt if ``always``."""
    if robot in part and (always or attempt == 0):
        os._exit(EXIT_CODE)
    return run_chunk(config, part)

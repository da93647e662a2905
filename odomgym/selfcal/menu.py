"""The self-calibration menu: the experiments a session may choose, one run each, with the
scatter each kind of run shows on the benchmark's ``concrete`` floor.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from odomgym.lab.experiment import Experiment, ExperimentKind

__all__ = ["ACTION_MENU", "STOP", "MenuItem"]

_DEG = math.pi / 180.0


class MenuItem(NamedTuple):
    """One choice of the self-calibration menu.

    Attributes:
        name: the item's name in logs and reports.
        experiment: the run it drives (one run); ``None`` for ``stop``.
        floor_std: standard deviations of the end-pose error one such run scatters by on the
            ``concrete`` benchmark floor (k = 0.0004 m^½), in the run's start frame: x (along
            the start heading), y [m], θ [rad]. Measured: 24 runs of an ideal LabMate at random
            start poses (``benchmarks/bench_selfcal.py --noise``); rougher floors scale them
            by the estimator's roughness factor ρ (the scatter grows in proportion to k).
    """

    name: str
    experiment: Experiment | None
    floor_std: tuple[float, float, float]


ACTION_MENU: tuple[MenuItem, ...] = (
    MenuItem("stop", None, (0.0, 0.0, 0.0)),
    MenuItem(
        "square4-cw", Experiment(ExperimentKind.SQUARE, "cw", 1, 4.0), (0.017, 0.017, 0.40 * _DEG)
    ),
    MenuItem(
        "square4-ccw", Experiment(ExperimentKind.SQUARE, "ccw", 1, 4.0), (0.017, 0.017, 0.40 * _DEG)
    ),
    MenuItem(
        "square2-cw", Experiment(ExperimentKind.SQUARE, "cw", 1, 2.0), (0.0052, 0.0052, 0.29 * _DEG)
    ),
    MenuItem(
        "square2-ccw",
        Experiment(ExperimentKind.SQUARE, "ccw", 1, 2.0),
        (0.0052, 0.0052, 0.29 * _DEG),
    ),
    MenuItem(
        "straight4",
        Experiment(ExperimentKind.STRAIGHT, None, 1, 4.0),
        (0.0005, 0.0087, 0.18 * _DEG),
    ),
    MenuItem(
        "straight4-back",
        Experiment(ExperimentKind.STRAIGHT, None, 1, 4.0, return_trip=True),
        (0.0010, 0.0069, 0.23 * _DEG),
    ),
    MenuItem(
        "spin360-cw",
        Experiment(ExperimentKind.SPIN, "cw", 1, 2.0 * math.pi),
        (0.0002, 0.0002, 0.12 * _DEG),
    ),
    MenuItem(
        "spin360-ccw",
        Experiment(ExperimentKind.SPIN, "ccw", 1, 2.0 * math.pi),
        (0.0002, 0.0002, 0.12 * _DEG),
    ),
    MenuItem(
        "spin720-cw",
        Experiment(ExperimentKind.SPIN, "cw", 1, 4.0 * math.pi),
        (0.0003, 0.0003, 0.17 * _DEG),
    ),
)
"""The experiments a self-calibration session may choose, one run each; index 0 stops."""

STOP = 0

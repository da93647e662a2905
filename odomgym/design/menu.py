"""The design menu: experiments that tell the catalogue effects apart, with their costs, and the
validation runs that judge a final estimate.

Every item is a :class:`odomgym.diagnose.experiments.SyntheticExperiment` (the manoeuvre
language of ``diagnose``'s separating experiment) and is turned into encoder counts by
:func:`odomgym.diagnose.experiments.synthetic_run`: the counts the nominal robot's odometry
commands for the manoeuvre (trapezoid ramps of 0.5 m/s², 20 Hz). A robot that drives by its
odometry logs those counts whatever its true parameters; the ground truth it logs is the replay
of them through the true robot (:func:`odomgym.diagnose.replay.replay_run`).

Which item reveals which effect (``docs/effects.md``, "Which experiments reveal which effect"):
spins of several angles (E_b in proportion to the angle; backlash a fixed loss per reversal;
the tracked point's offset circles the axle), a spin there and back (two reversals per
wheel), arcs at two speeds (turn skid ∝ v·ω), one-way straights (E_d, E_s, wheel toe) and out
and back (E_d, backlash; toe cancels), squares both ways (E_d against E_b) and full circles of
three radii (turn skid at three lateral accelerations).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym.diagnose.experiments import SyntheticExperiment, synthetic_run
from odomgym.diagnose.generate import NOMINAL_ROBOT
from odomgym.errors import SpecError
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "DESIGN_MENU",
    "VALIDATION",
    "DesignItem",
    "item_run",
    "menu_items",
    "select",
]

FloatArray = NDArray[np.float64]

Legs = tuple[tuple[float, float, float], ...]


def _square(side: float, sign: float, v: float = 0.3) -> Legs:
    """Four legs of ``side`` [m] at ``v`` [m/s], each followed by a 90° turn at 1 rad/s (as
    ``diagnose``'s separating squares)."""
    legs: list[tuple[float, float, float]] = []
    for _ in range(4):
        legs.append((v, 0.0, side / v))
        legs.append((0.0, sign * 1.0, math.pi / 2))
    return tuple(legs)


def _circle(radius: float, v: float, turns: float = 1.0) -> Legs:
    """``turns`` of a circle of ``radius`` [m] ccw at ``v`` [m/s]."""
    return ((v, v / radius, turns * 2.0 * math.pi * radius / v),)


@dataclass(frozen=True)
class DesignItem:
    """One experiment of the menu.

    Attributes:
        name: its name in schedules and reports.
        experiment: the manoeuvre (legs of body speed [m/s], yaw rate [rad/s], duration [s]).
        travel_m: its cost in travel: the mean of the two wheels' total rolled distance [m]
            (an in-place spin costs its wheel arcs), computed from the counts.
        time_s: its duration, ramps and stops included [s].
    """

    name: str
    experiment: SyntheticExperiment
    travel_m: float
    time_s: float


_SPIN = 1.0  # yaw rate of spins [rad/s]: wheel speed 0.1 m/s on the 0.2 m wheelbase
_EXPERIMENTS: tuple[SyntheticExperiment, ...] = (
    SyntheticExperiment("spin90", ((0.0, _SPIN, math.pi / 2),), "90° in place, ccw"),
    SyntheticExperiment("spin180", ((0.0, _SPIN, math.pi),), "180° in place, ccw"),
    SyntheticExperiment("spin360-ccw", ((0.0, _SPIN, 2 * math.pi),), "360° in place, ccw"),
    SyntheticExperiment("spin360-cw", ((0.0, -_SPIN, 2 * math.pi),), "360° in place, cw"),
    SyntheticExperiment(
        "spin180-back", ((0.0, _SPIN, math.pi), (0.0, -_SPIN, math.pi)), "180° ccw and back"
    ),
    SyntheticExperiment("arc-slow", ((0.1, 0.1, math.pi / 0.1),), "half circle R 1 m, 0.1 m/s"),
    SyntheticExperiment("arc-fast", ((0.35, 0.35, math.pi / 0.35),), "half circle R 1 m, 0.35 m/s"),
    SyntheticExperiment("straight3", ((0.3, 0.0, 3 / 0.3),), "3 m straight, one way"),
    SyntheticExperiment(
        "straight3-back", ((0.3, 0.0, 3 / 0.3), (-0.3, 0.0, 3 / 0.3)), "3 m out and back"
    ),
    SyntheticExperiment("square1.5-cw", _square(1.5, -1.0), "1.5 m square, cw"),
    SyntheticExperiment("square1.5-ccw", _square(1.5, 1.0), "1.5 m square, ccw"),
    SyntheticExperiment("circle0.25", _circle(0.25, 0.2), "full circle R 0.25 m, 0.2 m/s"),
    SyntheticExperiment("circle0.5", _circle(0.5, 0.3), "full circle R 0.5 m, 0.3 m/s"),
    SyntheticExperiment("circle1", _circle(1.0, 0.35), "full circle R 1 m, 0.35 m/s"),
)

#: The validation runs (never in the menu): 2 m squares both ways, for E_max,syst (Borenstein &
#: Feng 1994, Eq. 3.3, on the noiseless replay), and a free path that exercises every effect
#: — one-way straights, a reversal, fast and slow turns of both signs, a spin.
VALIDATION: tuple[SyntheticExperiment, ...] = (
    SyntheticExperiment("validate-square2-cw", _square(2.0, -1.0), "2 m square, cw"),
    SyntheticExperiment("validate-square2-ccw", _square(2.0, 1.0), "2 m square, ccw"),
    SyntheticExperiment(
        "validate-free",
        (
            (0.3, 0.0, 2.0 / 0.3),
            (0.3, 0.5, (math.pi / 2) / 0.5),
            (0.15, -0.3, (math.pi / 2) / 0.3),
            (0.0, -1.0, math.pi / 2),
            (-0.25, 0.0, 1.0 / 0.25),
            (0.35, 0.7, math.pi / 0.7),
            (0.3, 0.0, 1.5 / 0.3),
        ),
        "a free path: straights, a reversal, arcs at several speeds, a spin",
    ),
)


def item_run(experiment: SyntheticExperiment, robot: RobotSpec = NOMINAL_ROBOT) -> Run:
    """The counts of ``experiment`` as ``robot``'s odometry commands them, started at the
    origin (the start pose is what every replay starts from)."""
    run = synthetic_run(experiment, robot)
    run.true_pose[0] = 0.0
    return run


def _costs(experiment: SyntheticExperiment, robot: RobotSpec) -> tuple[float, float]:
    run = item_run(experiment, robot)
    rolled = np.abs(np.diff(run.counts, axis=0)).sum(axis=0) * robot.metres_per_tick
    return float(rolled.mean()), float(run.time[-1] - run.time[0])


def menu_items(
    experiments: tuple[SyntheticExperiment, ...] = _EXPERIMENTS, robot: RobotSpec = NOMINAL_ROBOT
) -> tuple[DesignItem, ...]:
    """The menu: each experiment with its travel [m] and time [s] cost on ``robot``."""
    out = []
    for e in experiments:
        travel, time = _costs(e, robot)
        out.append(DesignItem(e.name, e, travel, time))
    return tuple(out)


DESIGN_MENU: tuple[DesignItem, ...] = menu_items()
"""Issue 45's menu (14 items) on the OptiOdom-sized robot."""


def select(
    names: list[str] | tuple[str, ...], menu: tuple[DesignItem, ...] = DESIGN_MENU
) -> tuple[DesignItem, ...]:
    """The items called ``names``; an unknown name is a one-line :class:`SpecError` naming it
    and the menu."""
    known = {item.name: item for item in menu}
    out = []
    for name in names:
        if name not in known:
            raise SpecError(f"menu: unknown item {name!r}; items: {', '.join(known)}", field="menu")
        out.append(known[name])
    return tuple(out)

"""Batches of simulated runs driven with a known calibration: plans, driving them, and what
they return.

Why a module of its own: ``odomgym run`` and a notebook should plan and drive the same runs the
same way, and the command line should only parse, call this and print. A *plan* is an
:class:`~odomgym.lab.experiment.Experiment` — the one type for "what to drive and how often",
whether a calibrator asks a lab for it or a user drives it here (:func:`square_plans`,
:func:`straight_plans`). A :class:`RunBatch` holds every run of a list of plans with its return
error ε = true − odometry end pose in the start frame [m, m, rad] (Borenstein & Feng 1994,
§3.1), and the UMBmark measures when both directions were driven (Borenstein & Feng 1994,
Eq. 3.3).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from odomgym.floor import FloorSpec
from odomgym.lab.experiment import Experiment, ExperimentKind
from odomgym.lab.simulated import experiment_route
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Direction, Run, end_error
from odomgym.odometry.umbmark_measures import UMBmarkSummary, summarize_umbmark
from odomgym.robot import RobotSpec
from odomgym.sim.route_runs import simulate_runs
from odomgym.sim.routes import square_route, straight_route

__all__ = [
    "RunBatch",
    "drive_plans",
    "square_plans",
    "straight_plans",
]

FloatArray = NDArray[np.float64]


def square_plans(
    side: float, direction: Literal["cw", "ccw", "both"] = "both", runs: int = 1
) -> list[Experiment]:
    """``runs`` UMBmark squares of side ``side`` [m] each way: cw, ccw, or cw then ccw
    (``"both"``, which is what E_max,syst needs; Borenstein & Feng 1994, §3.2). The side is
    checked as the route checks it, so an error names ``side``."""
    directions: list[Direction] = ["cw", "ccw"] if direction == "both" else [direction]
    for d in directions:
        square_route(side, d)
    return [Experiment(ExperimentKind.SQUARE, d, runs, side) for d in directions]


def straight_plans(distance: float, return_trip: bool = False, runs: int = 1) -> list[Experiment]:
    """``runs`` straight runs of ``distance`` [m], optionally turning on the spot and driving
    back. The distance is checked as the route checks it, so an error names ``distance``."""
    straight_route(distance, return_trip)
    return [Experiment(ExperimentKind.STRAIGHT, None, runs, distance, return_trip=return_trip)]


def _label(plan: Experiment) -> str:
    """The experiment label stored with each run (``square_cw``, ``straight``)."""
    return str(plan.kind) if plan.direction is None else f"{plan.kind}_{plan.direction}"


@dataclass
class RunBatch:
    """Every run of a list of plans, in plan order, numbered from 1.

    Attributes:
        runs: the runs (true poses in the floor frame; ``meta["run"]`` and
            ``meta["experiment"]`` set, as :func:`odomgym.data.native.write_native` stores them).
        directions: each run's direction (``None`` for straight runs).
        odometry_end: each run's own odometry end pose, start frame (n, 3) [m, m, rad].
        errors: return errors ε = true − odometry (n, 3) [m, m, rad], heading wrapped.
        route_name: the first plan's route name (for headings).
    """

    runs: list[Run]
    directions: list[Direction | None]
    odometry_end: FloatArray
    errors: FloatArray
    route_name: str

    def errors_of(self, direction: Direction) -> FloatArray:
        """Return errors of the runs in ``direction`` (k, 3), possibly empty."""
        mask = np.array([d == direction for d in self.directions], dtype=bool)
        selected: FloatArray = self.errors[mask].reshape(-1, 3)
        return selected

    def summary(self) -> UMBmarkSummary | None:
        """The UMBmark measures, if both directions were driven (else ``None``)."""
        cw, ccw = self.errors_of("cw"), self.errors_of("ccw")
        if len(cw) == 0 or len(ccw) == 0:
            return None
        return summarize_umbmark(cw, ccw)

    def rows(self) -> list[tuple[int, str, FloatArray]]:
        """``(run number, direction or "-", error)`` rows for a return-error table."""
        return [
            (k + 1, d if d is not None else "-", error)
            for k, (d, error) in enumerate(zip(self.directions, self.errors, strict=True))
        ]

    def records(self) -> list[dict[str, Any]]:
        """One JSON-ready record per run: return error, odometry and true end, duration [s]."""
        return [
            {
                "run": k + 1,
                "direction": direction,
                "return_error": {"x": error[0], "y": error[1], "theta": error[2]},
                "odom_end": odom,
                "true_end": run.true_pose[-1],
                "duration_s": run.time[-1],
            }
            for k, (run, direction, odom, error) in enumerate(
                zip(self.runs, self.directions, self.odometry_end, self.errors, strict=True)
            )
        ]


def drive_plans(
    robot: RobotSpec,
    floor: FloorSpec,
    plans: Sequence[Experiment],
    *,
    calibration: Calibration | None = None,
    rng: np.random.Generator | None = None,
    progress: Callable[[float], None] | None = None,
) -> RunBatch:
    """Drive every plan (a square, straight or spin experiment) ``plan.runs`` times with the
    reference driver, plan after plan.

    The plans share ``rng`` in order (so one seed gives one batch); ``progress`` receives the
    completed fraction of the whole batch (0..1).
    """
    if not plans:
        raise ValueError("no plans to drive")
    runs: list[Run] = []
    directions: list[Direction | None] = []
    odometry: list[FloatArray] = []
    for index, plan in enumerate(plans):

        def report(fraction: float, offset: int = index) -> None:
            if progress is not None:
                progress((offset + fraction) / len(plans))

        batch, odom_end = simulate_runs(
            robot,
            floor,
            experiment_route(plan),
            calibration=calibration if calibration is not None else Calibration(),
            rng=rng,
            repeats=plan.runs,
            kind=str(plan.kind),
            direction=plan.direction,
            progress=report,
        )
        for run, odom in zip(batch, odom_end, strict=True):
            run.meta.update(run=str(len(runs) + 1), experiment=_label(plan))
            runs.append(run)
            directions.append(plan.direction)
            odometry.append(np.asarray(odom, dtype=float))
    errors = np.array([end_error(run, odom) for run, odom in zip(runs, odometry, strict=True)])
    return RunBatch(
        runs=runs,
        directions=directions,
        odometry_end=np.array(odometry),
        errors=errors.reshape(-1, 3),
        route_name=experiment_route(plans[0]).name,
    )

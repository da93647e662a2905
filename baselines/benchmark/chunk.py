"""The benchmark's unit of work: a chunk of robots calibrated by every method on every floor, in
lockstep, then validated on fresh squares; the row each result becomes, failed or not.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.baselines.base import CALIBRATORS, CalibrationResult, Calibrator
from odomgym.baselines.benchmark.config import (
    ORACLE,
    BenchConfig,
    bench_floor,
    bench_stream,
    calibration_streams,
    configure,
    oracle_calibration,
    population,
)
from odomgym.baselines.validation import ValidationSquare, square_errors
from odomgym.floor import FloorSpec
from odomgym.lab.experiment import Lab
from odomgym.lab.lockstep import run_lockstep
from odomgym.lab.simulated import random_start_poses
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Direction
from odomgym.odometry.umbmark_measures import e_max_syst
from odomgym.robot import RobotSpec

__all__ = [
    "failed_rows",
    "oracle_fractions",
    "run_chunk",
    "validate_calibrations",
]

FloatArray = NDArray[np.float64]


def run_chunk(config: BenchConfig, indices: Sequence[int]) -> list[dict[str, Any]]:
    """Calibrate robots ``indices`` with every method on every floor and validate them.

    All robots of the chunk run in lockstep (:func:`odomgym.lab.lockstep.run_lockstep`): one
    method at a time, their experiments simulated as one batch.
    """
    robots_all = population(config)
    robots = [robots_all[i] for i in indices]
    rows: list[dict[str, Any]] = []
    for f, floor_name in enumerate(config.floors):
        floor, start_region, floor_index = bench_floor(config, floor_name)
        calibrations: list[list[Calibration]] = [[] for _ in robots]
        method_rows: list[list[dict[str, Any]]] = [[] for _ in robots]
        for label, method, budget in config.entries():
            cls = CALIBRATORS[method]
            start = time.perf_counter()

            def procedure(
                lab: Lab, _index: int, cls: type[Calibrator] = cls, budget: int = budget
            ) -> CalibrationResult:
                return configure(cls, budget).calibrate(lab)

            outcomes = run_lockstep(
                procedure,
                robots,
                floor,
                calibration_streams(config, indices, floor_index),
                start_region=start_region,
            )
            wall = (time.perf_counter() - start) / len(robots)
            for k, (robot, outcome) in enumerate(zip(robots, outcomes, strict=True)):
                result = outcome.value
                calibration = result.calibration if result is not None else Calibration()
                calibrations[k].append(calibration)
                method_rows[k].append(
                    _row(label, budget, floor_name, indices[k], robot, calibration, result, wall)
                )
                if outcome.error is not None:
                    method_rows[k][-1]["failed"] = repr(outcome.error)
        if config.oracle:
            for k, robot in enumerate(robots):
                truth = oracle_calibration(robot)
                calibrations[k].append(truth)
                method_rows[k].append(_row(ORACLE, 0, floor_name, indices[k], robot, truth, None))
        errors = validate_calibrations(
            config, floor, start_region, floor_index, indices, robots, calibrations
        )
        for k in range(len(robots)):
            before = errors[k][0]
            e_before = e_max_syst(before["cw"], before["ccw"])
            for row, after in zip(method_rows[k], errors[k][1:], strict=True):
                e_after = e_max_syst(after["cw"], after["ccw"])
                row["e_max_before_mm"] = 1e3 * e_before
                row["e_max_after_mm"] = 1e3 * e_after
                row["improvement"] = e_before / e_after if e_after > 0 else math.inf
                if not math.isfinite(e_after) and not row["failed"]:
                    row["failed"] = "validation squares did not finish with this calibration"
                for name in ("E_d", "E_b", "E_s"):
                    row[f"err_{name}"] = row[f"est_{name}"] - row[f"true_{name}"]
                if indices[k] == 0 and f == 0:
                    row["scatter"] = {
                        "before": {d: v.tolist() for d, v in before.items()},
                        "after": {d: v.tolist() for d, v in after.items()},
                    }
            rows.extend(method_rows[k])
    return rows


def _row(
    label: str,
    budget: int,
    floor: str,
    index: int,
    robot: RobotSpec,
    calibration: Calibration | None,
    result: CalibrationResult | None,
    wall: float = 0.0,
) -> dict[str, Any]:
    """One result row before validation: the truth, the estimate (NaN without a
    ``calibration``), what it cost. The one layout of a row, failed or not."""
    if calibration is None:
        estimate = (math.nan, math.nan, math.nan)
    else:
        estimate = (calibration.e_d, calibration.wheelbase_scale, calibration.distance_scale)
    # A skid-steer population's rows also hold the skid-steer terms a calibration carries (ICR
    # offsets [m], the track curve's α, β, p; 0, 1, 1 for the differential-drive methods); a
    # differential-drive population's rows are as before.
    skid = ("icr_x", "icr_y", "track_alpha", "track_beta", "track_power")
    icr = (
        {
            f"est_{name}": math.nan if calibration is None else getattr(calibration, name)
            for name in skid
        }
        if robot.is_skid_steer
        else {}
    )
    return {
        "method": label,
        "budget": budget,
        "floor": floor,
        "robot": index,
        "true_E_d": robot.e_d,
        "true_E_b": robot.e_b,
        "true_E_s": robot.e_s,
        "est_E_d": estimate[0],
        "est_E_b": estimate[1],
        "est_E_s": estimate[2],
        **icr,
        "runs_used": result.runs_used if result is not None else 0,
        "distance_m": result.distance_used if result is not None else 0.0,
        "wall_time_s": wall,
        "failed": "",
    }


def failed_rows(config: BenchConfig, robots: Sequence[int], reason: str) -> list[dict[str, Any]]:
    """Rows for robots whose worker died twice: every entry marked failed with ``reason``,
    its numbers NaN, so the tables count them as failures and the run still finishes."""
    nan = math.nan
    truth = population(config)
    out = []
    competitors = [(label, budget) for label, _, budget in config.entries()]
    if config.oracle:
        competitors.append((ORACLE, 0))
    for floor in config.floors:
        for robot in robots:
            for label, budget in competitors:
                row = _row(label, budget, floor, robot, truth[robot], None, None)
                row.update(failed=reason, e_max_before_mm=nan, e_max_after_mm=nan, improvement=nan)
                row.update({f"err_{name}": nan for name in ("E_d", "E_b", "E_s")})
                out.append(row)
    return out


def oracle_fractions(
    errors: Sequence[Sequence[Mapping[str, FloatArray]]], oracle: int, method: int
) -> list[float]:
    """Per robot, the *of oracle* figure of calibration ``method``: the oracle's E_max,syst
    (Borenstein & Feng 1994, Eq. 3.3) over the method's on the same validation squares, from
    :func:`validate_calibrations`'s ``errors`` (indices as there: 0 is uncalibrated)."""
    return [
        e_max_syst(e[oracle]["cw"], e[oracle]["ccw"])
        / e_max_syst(e[method]["cw"], e[method]["ccw"])
        for e in errors
    ]


def validate_calibrations(
    config: BenchConfig,
    floor: FloorSpec,
    start_region: float | None,
    floor_index: int,
    indices: Sequence[int],
    robots: Sequence[RobotSpec],
    calibrations: Sequence[Sequence[Calibration]],
) -> list[list[dict[str, FloatArray]]]:
    """Fresh squares for every robot, uncalibrated and with each method's calibration, from
    the same start poses; all robots and calibrations simulated together per direction.

    Returns ``errors[k][c][direction]`` (runs, 3) for robot k and calibration c (0: none).

    Public so that studies beside the benchmark (``benchmarks/bench_selfcal.py``'s error
    budget, ``benchmarks/design_bound.py``'s schedules) validate their calibrations on exactly
    the benchmark's squares and floor noise, paired with its rows.
    """
    runs = config.validation_runs
    out: list[list[dict[str, FloatArray]]] = [
        [{} for _ in range(len(calibrations[k]) + 1)] for k in range(len(robots))
    ]
    directions: tuple[Direction, Direction] = ("cw", "ccw")
    for d, direction in enumerate(directions):
        squares: list[ValidationSquare] = []
        slots: list[tuple[int, int]] = []
        for k, (i, robot) in enumerate(zip(indices, robots, strict=True)):
            rng = bench_stream(config, i, floor_index, 3 + d)
            poses = random_start_poses(rng, runs, start_region)
            for c, calibration in enumerate([Calibration(), *calibrations[k]]):
                # The same floor noise for every calibration of this robot: a paired comparison.
                seeds = np.random.SeedSequence([config.seed, i, floor_index, 5 + d]).spawn(runs)
                for r, seed in enumerate(seeds):
                    squares.append(
                        ValidationSquare(
                            robot,
                            calibration,
                            start=None if poses is None else poses[r],
                            stream=np.random.default_rng(seed),
                        )
                    )
                    slots.append((k, c))
        # A calibration so wrong that the robot cannot finish a square gets NaN errors (and so
        # a NaN E_max,syst): it is reported as failed, not allowed to stop the benchmark.
        errors = square_errors(squares, floor, direction)
        for (k, c), start_row in zip(slots[::runs], range(0, len(slots), runs), strict=True):
            out[k][c][direction] = errors[start_row : start_row + runs]
    return out

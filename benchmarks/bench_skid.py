"""Skid-steer odometry models calibrated and validated on simulated skid-steer robots.

    python benchmarks/bench_skid.py [--out skid-out] [--robots scout2 husky pioneer3at]
        [--floors smooth slippery] [--seed 0]          # ~1 min on 2 cores

For each preset robot and floor, the robot drives *calibration* runs by its own (nominal)
odometry — one lap of circles of radius 0.5, 1, 2 and 4 m each way and a 2 m square each way,
the experiments issue 43 names — measured by the lab's ground-truth sensor (σ = 2 mm, 0.4°).
Each odometry model of :mod:`odomgym.odometry.icr` is fitted to them (``nominal`` is the
robot's believed track, χ = 1; ``constant`` one expansion factor, this project's E_b and the
apparent track of ROS's diff_drive_controller; ``icr`` Mandow et al. 2007's ICRs of each side
and x_ICR; ``curvature`` a factor that moves with the path parameter λ, Wang et al. 2015's form
with a free asymptote and power) and then *validated* on fresh runs the fit never saw: circles
of 0.75, 1.5 and 3 m each way and 20 m random free paths (legs of 1 m, curvature uniform in
±2 /m). The table gives the median over validation runs of the end-position error per metre
driven [%] and of the end-heading error per metre [°/m].

Beside them, the project's six classical calibrators (:mod:`odomgym.baselines`: UMBmark, Jung &
Chung, Lee, Ivanjko, least squares, the trajectory fit), each given its own experiments (2 m
squares where it drives squares) in a simulated lab of the same robot and floor at the same
speed: what a user gets who calibrates a skid-steer robot as a differential-drive one. Their
result is a constant factor (E_b) with wheel corrections (c_L, c_R, E_s), validated alike.

Writes ``OUT/skid_models.md`` (the table), ``OUT/skid_models.json`` and ``OUT/skid_models.png``
(the fitted factors against the path parameter λ beside the World's steady turns, and each
model's heading error per validation circle: where one constant factor fails).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from odomgym.baselines import CALIBRATORS
from odomgym.floor import FLOORS
from odomgym.io import atomic_writer
from odomgym.lab.experiment import SensorAccuracy
from odomgym.lab.simulated import SimLab, measure
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.icr import SKID_MODELS, SkidModel, fit_skid_model, skid_dead_reckon
from odomgym.odometry.runs import Run, wheel_travels
from odomgym.robot import PRESETS, RobotSpec
from odomgym.sim.arc_runs import Arc, circle_plan, drive_arcs, free_plan
from odomgym.sim.route_runs import simulate_runs
from odomgym.sim.routes import square_route
from odomgym.sim.turns import steady_turn

CAL_RADII = (0.5, 1.0, 2.0, 4.0)  # [m]
VAL_RADII = (0.75, 1.5, 3.0)  # [m]
SPEED = 0.3  # [m/s]
#: The classical calibrators and their options (squares of 2 m: a skid-steer robot with its
#: nominal track turns ~52° at a 90° corner, and 4 m squares would take it far off).
CLASSICAL: dict[str, dict[str, float]] = {
    "umbmark": {"side": 2.0},
    "jung_chung": {"side": 2.0},
    "lee": {"side": 2.0},
    "ivanjko": {},
    "least_squares": {"side": 2.0},
    "trajectory": {"side": 2.0},
}


def _circles(robot: RobotSpec, floor: str, radii: tuple[float, ...]) -> list[Run]:
    plans = [circle_plan(r, d) for r in radii for d in ("cw", "ccw")]
    runs = drive_arcs(robot, FLOORS[floor], plans, cruise_speed=SPEED, kind="circular")
    for run, (r, d) in zip(runs, [(r, d) for r in radii for d in ("cw", "ccw")], strict=True):
        run.meta.update(radius=r, direction=d)
    return runs


def _runs(robot: RobotSpec, floor: str, rng: np.random.Generator) -> tuple[list[Run], list[Run]]:
    """Calibration runs (measured) and validation runs (true poses) of one robot on one floor."""
    calibration = _circles(robot, floor, CAL_RADII)
    for direction in ("cw", "ccw"):
        squares, _ = simulate_runs(
            robot, FLOORS[floor], square_route(2.0, direction), cruise_speed=SPEED,
            kind="square", direction=direction,
        )  # fmt: skip
        calibration += squares
    validation = _circles(robot, floor, VAL_RADII)
    plans: list[tuple[Arc, ...]] = [free_plan(rng, 20.0) for _ in range(4)]
    validation += drive_arcs(robot, FLOORS[floor], plans, cruise_speed=SPEED, kind="free")
    return measure(calibration, SensorAccuracy(), rng), validation


def _errors(
    model: SkidModel, run: Run, robot: RobotSpec, calibration: Calibration | None = None
) -> tuple[float, float, float]:
    """End-position error per metre [%], end-heading error per metre [°/m], path length [m]
    (``calibration``: the wheel corrections a classical calibrator found, applied to the
    counts before ``model``)."""
    travels, _ = wheel_travels(run, robot, calibration)
    end = skid_dead_reckon(model, travels, run.true_pose[0])[-1]
    length = float(np.sum(np.hypot(*np.diff(run.true_pose[:, :2], axis=0).T)))
    position = float(np.hypot(*(end[:2] - run.true_pose[-1, :2])))
    heading = abs(math.degrees(math.remainder(end[2] - run.true_pose[-1, 2], math.tau)))
    return 100.0 * position / length, heading / length, length


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("skid-out"))
    parser.add_argument("--robots", nargs="+", default=["scout2", "husky", "pioneer3at"])
    parser.add_argument("--floors", nargs="+", default=["smooth", "slippery"])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    for name in args.robots:
        if name not in PRESETS or not PRESETS[name].is_skid_steer:
            parser.error(f"--robots: {name!r} is not a skid-steer preset")
    for floor in args.floors:
        if floor not in FLOORS:
            parser.error(f"--floors: {floor!r} is not a floor ({', '.join(FLOORS)})")
    rng = np.random.default_rng(args.seed)
    started = time.perf_counter()
    results: list[dict[str, object]] = []
    figure_data: dict[str, object] = {}
    for name in args.robots:
        robot = PRESETS[name]
        for floor in args.floors:
            calibration, validation = _runs(robot, floor, rng)
            fits: list[tuple[str, SkidModel, Calibration | None]] = [
                (kind, fit_skid_model(kind, calibration, robot), None) for kind in SKID_MODELS
            ]
            for method, options in CLASSICAL.items():
                lab = SimLab(robot, FLOORS[floor], rng=rng.spawn(1)[0], cruise_speed=SPEED)
                found = CALIBRATORS[method](**options).calibrate(lab).calibration
                constant = SkidModel("constant", robot.wheelbase, chi_inf=found.wheelbase_scale)
                fits.append((method, constant, found))
            for kind, model, wheels in fits:
                errors = np.array([_errors(model, run, robot, wheels) for run in validation])
                per_circle = {
                    f"{run.meta['radius']}-{run.meta['direction']}": _errors(
                        model, run, robot, wheels
                    )[1]
                    for run in validation
                    if run.kind == "circular"
                }
                results.append(
                    {
                        "robot": name,
                        "floor": floor,
                        "model": kind,
                        "position_pct": float(np.median(errors[:, 0])),
                        "heading_deg_per_m": float(np.median(errors[:, 1])),
                        "circles_heading_deg_per_m": per_circle,
                        "parameters": model.to_dict(),
                    }
                )
                if name == args.robots[0] and floor == args.floors[0] and kind in SKID_MODELS:
                    figure_data[kind] = (model, per_circle)
            print(f"{name} on {floor}: done ({time.perf_counter() - started:.0f} s)", flush=True)
    elapsed = time.perf_counter() - started
    table = _table(results, args.robots, args.floors)
    print(table)
    print(f"({elapsed:.0f} s)")
    out: Path = args.out
    atomic_writer(out / "skid_models.md", lambda p: p.write_text(table + "\n"))
    payload = {"seed": args.seed, "seconds": elapsed, "results": results}
    atomic_writer(out / "skid_models.json", lambda p: p.write_text(json.dumps(payload, indent=1)))
    _figure(PRESETS[args.robots[0]], args.floors[0], figure_data, out / "skid_models.png")


def _table(results: list[dict[str, object]], robots: list[str], floors: list[str]) -> str:
    """Markdown: one row per model, a column per robot and floor."""
    head = "| model | " + " | ".join(f"`{r}` on `{f}`" for r in robots for f in floors) + " |"
    lines = [
        "Median over validation runs: end-position error per metre [%] / heading error [°/m]",
        "",
        head,
        "|---|" + "---|" * (len(robots) * len(floors)),
    ]
    for kind in (*SKID_MODELS, *CLASSICAL):
        cells = []
        for r in robots:
            for f in floors:
                row = next(
                    x for x in results if (x["robot"], x["floor"], x["model"]) == (r, f, kind)
                )
                cells.append(f"{row['position_pct']:.2f} % / {row['heading_deg_per_m']:.2f}")
        label = kind if kind in SKID_MODELS else f"{kind} (classical: E_b, c_L, c_R, E_s)"
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _figure(robot: RobotSpec, floor: str, data: dict[str, object], path: Path) -> None:
    fig, (left, right) = plt.subplots(1, 2, figsize=(11.5, 4.8))
    lam = np.geomspace(0.05, 200.0, 200)
    colours = {
        "nominal": "0.5",
        "constant": "tab:blue",
        "icr": "tab:orange",
        "curvature": "tab:green",
    }
    styles = {"nominal": ":", "constant": "-", "icr": "--", "curvature": "-"}
    for kind, (model, _) in data.items():  # type: ignore[misc]
        left.plot(lam, model.factor(lam), styles[kind], color=colours[kind], label=kind)
    turns = []
    for radius in (0.0, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0):
        turn = steady_turn(robot, SPEED, radius, FLOORS[floor])
        # λ of the commanded rims: (v_L + v_R)/(v_R − v_L) = 2R/b (0 for a spin).
        turns.append((2.0 * radius / robot.true_wheelbase, turn.factor))
    spin = turns[0][1]
    lam_t = np.array([max(t[0], 0.05) for t in turns])
    left.plot(lam_t, [t[1] for t in turns], "ko", label="World, steady turns")
    left.axhline(spin, color="k", lw=0.6, ls=":")
    left.set_xscale("log")
    left.set_xlabel("path parameter λ = (v_L + v_R)/(v_R − v_L) [-] (spin at left)")
    left.set_ylabel("apparent / true track χ [-]")
    left.set_title(f"{robot.name} on {floor}: fitted factors vs the physics")
    left.grid(True, which="major", alpha=0.3)
    left.legend(fontsize=8)
    keys = [f"{r}-{d}" for r in VAL_RADII for d in ("cw", "ccw")]
    width = 0.2
    for k, (kind, (_, per_circle)) in enumerate(data.items()):  # type: ignore[misc]
        right.bar(np.arange(len(keys)) + (k - 1.5) * width, [per_circle[key] for key in keys],
                  width, color=colours[kind], label=kind)  # fmt: skip
    right.set_xticks(np.arange(len(keys)), [k.replace("-", " m ") for k in keys], fontsize=8)
    right.set_yscale("log")
    right.set_xlabel("validation circle (radius, direction)")
    right.set_ylabel("end-heading error per metre [°/m]")
    right.set_title("heading error on circles the fits never saw")
    right.legend(fontsize=8)
    fig.tight_layout()
    atomic_writer(path, lambda p: fig.savefig(p, dpi=110, format="png"))
    plt.close(fig)


if __name__ == "__main__":
    main()

"""The skid-steer calibration benchmark (``odomgym bench skid``): odometry models and the
classical calibrators on simulated skid-steer robots, validated on runs they never saw.

For each preset robot and floor, the robot drives *calibration* runs by its own (nominal)
odometry — one lap of circles of radius 0.5, 1, 2 and 4 m each way and a 2 m square each way,
the experiments of the skid-steer papers (Mandow et al. 2007; Wang et al. 2015) — measured by the
lab's ground-truth sensor (σ = 2 mm, 0.4°). Each odometry model of :mod:`odomgym.odometry.icr`
is fitted to them (``nominal`` the robot's believed track, χ = 1; ``constant`` one expansion
factor, this project's E_b and ROS diff_drive_controller's ``wheel_separation_multiplier``;
``icr`` Mandow et al. 2007's ICRs of each side and x_ICR; ``curvature`` a factor that moves with
the path parameter λ, Wang et al. 2015's form with a free asymptote and power) and *validated*
on fresh runs: circles of 0.75, 1.5 and 3 m each way and four 20 m free paths (legs of 1 m,
curvature uniform in ±2 /m). Beside them, the six classical calibrators of
:mod:`odomgym.baselines` (UMBmark, Jung & Chung, Lee, Ivanjko, least squares, the trajectory
fit), each given its own experiments (2 m squares where it drives squares) in a simulated lab of
the same robot, floor and speed — what a user gets who calibrates a skid-steer robot as a
differential-drive one: a constant factor (E_b) with wheel corrections, validated alike — and
the registered skid-steer calibrator ``skid_icr`` (:mod:`odomgym.baselines.skid_icr`), the ICR
model with the wheels' factors from its own squares and circles.

Each row is the median over the validation runs of the end-position error per metre driven
[%] and of the end-heading error per metre [°/m]. All randomness flows from the seed: each
robot and floor (a *cell*) draws from its own generator, seeded by the seed and the two names
(:func:`cell_seed`), so a cell's rows are the same whichever other cells run beside it and in
whatever order; the same seed gives the same table.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from odomgym.baselines.base import CALIBRATORS
from odomgym.errors import SpecError, refuse_repeats
from odomgym.floor import FLOORS
from odomgym.io import atomic_write_text, atomic_writer
from odomgym.lab.experiment import SensorAccuracy
from odomgym.lab.simulated import SimLab, measure
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.icr import SKID_MODELS, SkidModel, fit_skid_model, skid_dead_reckon
from odomgym.odometry.runs import Direction, Run, wheel_travels
from odomgym.robot import PRESETS, SKID_STEER_PRESETS, RobotSpec

__all__ = [
    "CAL_RADII",
    "CLASSICAL",
    "SKID_CALIBRATORS",
    "SKID_PRESETS",
    "SPEED",
    "VAL_RADII",
    "SkidBenchConfig",
    "calibration_model",
    "cell_seed",
    "run_skid_bench",
    "skid_table",
    "write_skid_outputs",
]

CAL_RADII = (0.5, 1.0, 2.0, 4.0)
"""Radii of the calibration circles [m], each driven both ways."""
VAL_RADII = (0.75, 1.5, 3.0)
"""Radii of the validation circles [m], each driven both ways."""
SPEED = 0.3
"""Cruise speed of every run [m/s]."""
CLASSICAL: dict[str, dict[str, float]] = {
    "umbmark": {"side": 2.0},
    "jung_chung": {"side": 2.0},
    "lee": {"side": 2.0},
    "ivanjko": {},
    "least_squares": {"side": 2.0},
    "trajectory": {"side": 2.0},
}
"""The classical calibrators and their options: squares of 2 m (a skid-steer robot with its
nominal track turns ~52° at a 90° corner, and 4 m squares would take it far off)."""
SKID_CALIBRATORS: dict[str, dict[str, float]] = {"skid_icr": {}, "skid_curvature": {}}
"""The registered skid-steer calibrators and their options: ``skid_icr`` and ``skid_curvature``
(:mod:`odomgym.baselines.skid_icr`: Mandow et al. 2007's ICRs, or a track that moves with the
turn in Wang et al. 2015's form, with the wheels' factors, from their own 2 m squares and
circles of 0.5–4 m). Each draws from a stream of its own, ``default_rng([*cell_seed(...), 1])``,
apart from the classical rows' (spawned from the cell's generator), so that adding them left
every other row as it was."""
SKID_LABELS = {"skid_icr": "ICRs", "skid_curvature": "track curve"}
"""What each registered skid-steer calibrator fits beside the wheels' factors (table labels)."""
SKID_PRESETS = SKID_STEER_PRESETS
"""The skid-steer presets (:data:`odomgym.robot.SKID_STEER_PRESETS`)."""


@dataclass(frozen=True)
class SkidBenchConfig:
    """What ``odomgym bench skid`` runs: ``robots`` (skid-steer preset names), ``floors``
    (:data:`odomgym.floor.FLOORS` names) and the master ``seed``.

    Raises:
        SpecError: a robot that is not a skid-steer preset (``field`` = ``robots``), a floor
            that does not exist (``floors``), a negative seed (``seed``), or an empty list.
    """

    robots: tuple[str, ...] = SKID_PRESETS
    floors: tuple[str, ...] = ("smooth", "slippery")
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.robots:
            raise SpecError("no robot to benchmark", field="robots")
        refuse_repeats(self.robots, "robots")
        refuse_repeats(self.floors, "floors")
        for name in self.robots:
            if name not in SKID_PRESETS:
                raise SpecError(
                    f"{name!r} is not a skid-steer preset ({', '.join(SKID_PRESETS)})",
                    field="robots",
                )
        if not self.floors:
            raise SpecError("no floor to benchmark on", field="floors")
        for floor in self.floors:
            if floor not in FLOORS:
                raise SpecError(f"{floor!r} is not a floor ({', '.join(FLOORS)})", field="floors")
        if self.seed < 0:
            raise SpecError(f"the seed must be >= 0, got {self.seed}", field="seed")


@dataclass
class SkidBenchRow:
    """One model (or classical calibrator) on one robot and floor."""

    robot: str
    floor: str
    model: str
    position_pct: float
    heading_deg_per_m: float
    circles_heading_deg_per_m: dict[str, float]
    parameters: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return dict(vars(self))


def cell_seed(seed: int, robot: str, floor: str) -> list[int]:
    """The seed sequence of one robot and floor's generator: the master ``seed`` and a CRC-32
    of each name (stable across processes and Python versions, unlike ``hash``).

    Why by name and not by the cell's place in the run: ``bench skid --presets jackal scout2``
    must give ``scout2`` the rows ``--presets scout2`` gives it (until 0.3.x a cell's place
    seeded it, so its rows moved with the cells run before it)."""
    return [seed, zlib.crc32(robot.encode()), zlib.crc32(floor.encode())]


def _circles(
    robot: RobotSpec, floor: str, radii: tuple[float, ...], rng: np.random.Generator
) -> list[Run]:
    """Circles of ``radii`` each way; a rough floor's texture drawn from ``rng``."""
    from odomgym.sim.arc_runs import circle_plan, drive_arcs

    directions: tuple[Direction, ...] = ("cw", "ccw")
    senses = [(r, d) for r in radii for d in directions]
    plans = [circle_plan(r, d) for r, d in senses]
    runs = drive_arcs(
        robot, FLOORS[floor], plans, rng=rng.spawn(len(plans)), cruise_speed=SPEED,
        kind="circular",
    )  # fmt: skip
    for run, (r, d) in zip(runs, senses, strict=True):
        run.meta.update(radius=r, direction=d)
    return runs


def _runs(robot: RobotSpec, floor: str, rng: np.random.Generator) -> tuple[list[Run], list[Run]]:
    """Calibration runs (measured) and validation runs (true poses) of one robot on one floor."""
    from odomgym.sim.arc_runs import Arc, drive_arcs, free_plan
    from odomgym.sim.route_runs import simulate_runs
    from odomgym.sim.routes import square_route

    calibration = _circles(robot, floor, CAL_RADII, rng)
    for direction in ("cw", "ccw"):
        squares, _ = simulate_runs(
            robot, FLOORS[floor], square_route(2.0, direction), rng=rng.spawn(1),
            cruise_speed=SPEED, kind="square", direction=direction,
        )  # fmt: skip
        calibration += squares
    validation = _circles(robot, floor, VAL_RADII, rng)
    plans: list[tuple[Arc, ...]] = [free_plan(rng, 20.0) for _ in range(4)]
    validation += drive_arcs(
        robot, FLOORS[floor], plans, rng=rng.spawn(len(plans)), cruise_speed=SPEED, kind="free"
    )
    return measure(calibration, SensorAccuracy(), rng), validation


def calibration_model(calibration: Calibration, robot: RobotSpec) -> SkidModel:
    """The skid-steer model a calibrator's ``calibration`` stands for (its wheels' factors
    applied to the counts before it): the curvature model when its track moves with the turn
    (χ_∞ = E_b; a calibration with both a curve and ICR offsets is none of them: ValueError),
    Mandow et al. 2007's ICRs when it moves them (``y_L, y_R = y_ICR ± E_b·b/2``, x_ICR), else
    one constant factor, E_b."""
    b = float(robot.wheelbase)
    if calibration.has_track_curve and calibration.has_icr:
        raise ValueError(
            "a calibration with both a track curve and ICR offsets is none of "
            "odomgym.odometry.icr's models"
        )
    if calibration.has_track_curve:
        return SkidModel(
            "curvature",
            b,
            chi_inf=calibration.wheelbase_scale,
            alpha=calibration.track_alpha,
            beta=calibration.track_beta,
            power=calibration.track_power,
        )
    if calibration.has_icr:
        half = 0.5 * calibration.wheelbase_scale * b
        return SkidModel(
            "icr",
            b,
            y_left=calibration.icr_y + half,
            y_right=calibration.icr_y - half,
            x_icr=calibration.icr_x,
        )
    return SkidModel("constant", b, chi_inf=calibration.wheelbase_scale)


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


def run_skid_bench(
    config: SkidBenchConfig, progress: Callable[[int, int], None] | None = None
) -> list[SkidBenchRow]:
    """Every model and classical calibrator on every robot and floor of ``config`` (module
    docstring); ``progress(done, total)`` after each robot and floor."""
    rows: list[SkidBenchRow] = []
    cells = [(r, f) for r in config.robots for f in config.floors]
    for done, (name, floor) in enumerate(cells, start=1):
        robot = PRESETS[name]
        key = cell_seed(config.seed, name, floor)
        rng = np.random.default_rng(key)
        calibration, validation = _runs(robot, floor, rng)
        fits: list[tuple[str, SkidModel, Calibration | None]] = [
            (kind, fit_skid_model(kind, calibration, robot), None) for kind in SKID_MODELS
        ]
        # The classical calibrators draw their labs' streams from the cell's generator, in
        # order; the registered skid-steer ones each start one stream seeded by the cell
        # (``[*key, 1]``), so that adding them left every classical row as it was.
        labs = [(m, o, rng.spawn(1)[0]) for m, o in CLASSICAL.items()] + [
            (m, o, np.random.default_rng([*key, 1])) for m, o in SKID_CALIBRATORS.items()
        ]
        for method, options, stream in labs:
            lab = SimLab(robot, FLOORS[floor], rng=stream, cruise_speed=SPEED)
            found = CALIBRATORS[method](**options).calibrate(lab).calibration
            fits.append((method, calibration_model(found, robot), found))
        for kind, model, wheels in fits:
            each = [_errors(model, run, robot, wheels) for run in validation]
            errors = np.array(each)
            per_circle = {
                f"{run.meta['radius']}-{run.meta['direction']}": error[1]
                for run, error in zip(validation, each, strict=True)
                if run.kind == "circular"
            }
            rows.append(
                SkidBenchRow(
                    robot=name,
                    floor=floor,
                    model=kind,
                    position_pct=float(np.median(errors[:, 0])),
                    heading_deg_per_m=float(np.median(errors[:, 1])),
                    circles_heading_deg_per_m=per_circle,
                    parameters=model.to_dict(),
                )
            )
        if progress is not None:
            progress(done, len(cells))
    return rows


def skid_table(rows: Sequence[SkidBenchRow], robots: Sequence[str], floors: Sequence[str]) -> str:
    """Markdown: one row per model, a column per robot and floor."""
    head = "| model | " + " | ".join(f"`{r}` on `{f}`" for r in robots for f in floors) + " |"
    lines = [
        "Median over validation runs: end-position error per metre [%] / heading error [°/m]",
        "",
        head,
        "|---|" + "---|" * (len(robots) * len(floors)),
    ]
    for kind in (*SKID_MODELS, *CLASSICAL, *SKID_CALIBRATORS):
        cells = []
        for r in robots:
            for f in floors:
                row = next(x for x in rows if (x.robot, x.floor, x.model) == (r, f, kind))
                cells.append(f"{row.position_pct:.2f} % / {row.heading_deg_per_m:.2f}")
        label = (
            kind
            if kind in SKID_MODELS
            else f"{kind} (registered: {SKID_LABELS[kind]}, c_L, c_R, E_s)"
            if kind in SKID_CALIBRATORS
            else f"{kind} (classical: E_b, c_L, c_R, E_s)"
        )
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _figure(name: str, floor: str, rows: Sequence[SkidBenchRow], path: Path, seed: int) -> None:
    """The fitted factors of the first robot and floor against the World's steady turns (left)
    and each model's heading error per validation circle (right): where one constant factor
    fails. A rough floor's texture under the steady turns is drawn from a stream of the cell's
    own (``[*cell_seed(...), 2]``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from odomgym.sim.turns import steady_turn

    robot = PRESETS[name]
    models = {
        row.model: (SkidModel(**row.parameters), row.circles_heading_deg_per_m)
        for row in rows
        if (row.robot, row.floor) == (name, floor) and row.model in SKID_MODELS
    }
    fig, (left, right) = plt.subplots(1, 2, figsize=(11.5, 4.8))
    lam = np.geomspace(0.05, 200.0, 200)
    colours = {
        "nominal": "0.5",
        "constant": "tab:blue",
        "icr": "tab:orange",
        "curvature": "tab:green",
    }
    styles = {"nominal": ":", "constant": "-", "icr": "--", "curvature": "-"}
    for kind, (model, _) in models.items():
        left.plot(lam, model.factor(lam), styles[kind], color=colours[kind], label=kind)
    rng = np.random.default_rng([*cell_seed(seed, name, floor), 2])
    turns = []
    for radius in (0.0, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0):
        turn = steady_turn(robot, SPEED, radius, FLOORS[floor], rng=rng.spawn(1)[0])
        # λ of the commanded rims: (v_L + v_R)/(v_R − v_L) = 2R/b (0 for a spin).
        turns.append((2.0 * radius / robot.true_wheelbase, turn.factor))
    lam_t = np.array([max(t[0], 0.05) for t in turns])
    left.plot(lam_t, [t[1] for t in turns], "ko", label="World, steady turns")
    left.axhline(turns[0][1], color="k", lw=0.6, ls=":")
    left.set_xscale("log")
    left.set_xlabel("path parameter λ = (v_L + v_R)/(v_R − v_L) [-] (spin at left)")
    left.set_ylabel("apparent / true track χ [-]")
    left.set_title(f"{name} on {floor}: fitted factors vs the physics")
    left.grid(True, which="major", alpha=0.3)
    left.legend(fontsize=8)
    keys = [f"{r}-{d}" for r in VAL_RADII for d in ("cw", "ccw")]
    width = 0.2
    for k, (kind, (_, per_circle)) in enumerate(models.items()):
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


def write_skid_outputs(
    config: SkidBenchConfig, rows: Sequence[SkidBenchRow], out: Path, elapsed: float
) -> list[Path]:
    """``OUT/skid_models.md`` (the table), ``skid_models.json`` (every row, the seed and the
    seconds) and ``skid_models.png`` (:func:`_figure`), each written atomically; returns them."""
    import json

    out.mkdir(parents=True, exist_ok=True)
    table = skid_table(rows, config.robots, config.floors)
    paths = [out / "skid_models.md", out / "skid_models.json", out / "skid_models.png"]
    atomic_write_text(paths[0], table + "\n")
    payload = {
        "robots": list(config.robots),
        "floors": list(config.floors),
        "seed": config.seed,
        "seconds": elapsed,
        "results": [row.as_dict() for row in rows],
    }
    atomic_write_text(paths[1], json.dumps(payload, indent=1) + "\n")
    _figure(config.robots[0], config.floors[0], rows, paths[2], config.seed)
    return paths

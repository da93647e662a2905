"""The skid-steer diagnosis on field logs made apart from odomgym: named first, held-out error.

    python benchmarks/skid_field_independent.py VARIANT [VARIANT ...] [--preset husky]
                                                [--seed 0] [--jobs 1] [--constant] [--json]

``benchmarks/skid_field.py`` diagnoses field logs that odomgym itself simulates (the World's
elastic tyres, :func:`odomgym.diagnose.generate.simulate_field_log`'s messiness). A diagnosis
that names ``skid_track`` there could still be leaning on artefacts of odomgym's own
simulator. Here the robot and the messiness come from elsewhere: the skid-steer robot is
``tests/independent_skid.py``'s :class:`ElasticSkidRobot` (the classical four-wheel contact
model of Kozłowski & Pazderski 2004 and Mandow et al. 2007 on tyres that deform before they
slide, a saturating law of the TMeasy family, Hirschberg, Rill & Weinfurter 2007, written apart
from odomgym), sized like the preset (``--preset``: wheel diameter, track, axle spacing, encoder
resolution); motion, encoders and logging are ``tests/independent_robot.py``'s (open-loop
S-curve moves planned with the nominal geometry, exact constant-twist steps at 200 Hz, quantised
encoders with a random phase, poses logged at 20 Hz). Its apparent track falls from spins to wide
arcs (for the Husky from 1.85 times the track in a spin to 1.43 on straight paths), which a
constant track cannot follow.

The field messiness is written in this script, not odomgym's:

* the real wheel diameter 4.7 % above the nominal one (the encoders count nominal metres);
* the tracked marker 0.29 m ahead of the geometric centre, and for the ``*_yaw`` variants
  yawed by 2° against the body;
* tracker noise of 1 mm (x, y) and 0.2° (heading), the heading wrapped to [−π, π);
* the tracker losing the marker in bursts of 0.25–4 s (log-uniform) until 38 % of the rows
  (45 % for the ``*45`` variants) are lost, first and last rows kept; a lost row is NaN, or in
  the ``held`` variant the last good pose repeated (as some trackers report a lost marker).

The protocol is a lab's: 3 m squares (two each way), arcs of 0.5, 1, 2 and 4 m radius at 0.3 and
0.6 m/s each way (full circles up to 1 m, half circles beyond), in-place spins of 90°, 180° and
360° each way, two 4 m straights with a return trip, and four 45 s joystick-like free drives
(speed about 0.6 m/s, varying by ±25 %; curvature a random smooth signal within ±1.5 /m):
32 runs.

Each variant's logs are diagnosed against the preset with ``odomgym diagnose``'s default options
and the baseline calibration on (trajectory optimisation, Sousa et al. 2022). The right answer is
``skid_track`` named first, its spin track E_b·(1 + ε) near the robot's, and the held-out runs
predicted open loop better than by the baseline, whose constant track cannot follow the turn.
``--constant`` also diagnoses the same logs with the skid-steer effects (``skid_track``,
``skid_speed``, ``turn_skid``) taken out of the candidates: the best a constant-track model of
the catalogue does, for comparison.

Variants: ``offset`` (marker offset, 38 % lost as NaN), ``offset_yaw`` (and the 2° marker
yaw), ``offset_yaw_nan45`` (and 45 % lost as NaN), ``offset_yaw_held45`` (and 45 % lost as held
poses). Every variant's logs are drawn from ``--seed`` alone (the motion and sensor streams from
one generator, the tracker losses from another seeded ``--seed`` + 1000), and the diagnosis runs
with ``--seed``: the same seed gives the same figures.

Prints a Markdown table, one row per variant: the effects named (in order), whether
``skid_track`` is first, the fitted E_b (``wheelbase``), ε and λ½ (``skid_track``), all
dimensionless, the held-out open-loop position RMS [mm] of the model as given, the baseline, the
diagnosis and (with ``--constant``) the constant-track diagnosis, and the wall time [s] of the
variant (logs made and diagnosed); under the table, the robot's true apparent track over its
track in a spin, at the protocol's arc radii and on straight paths. ``--json`` prints one JSON
object instead, with the fitted parameters and the held-out heading RMS [°] too. A benchmark,
not a test: it exits 0 whatever the diagnosis names.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.baselines.trajectory import TrajectoryBaseline
from odomgym.diagnose.results import Diagnosis
from odomgym.diagnose.workflow import DiagnoseConfig, diagnose
from odomgym.effects import catalogue
from odomgym.odometry.runs import Run
from odomgym.robot import PRESETS, SKID_STEER_PRESETS, RobotSpec

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from independent_robot import (  # noqa: E402
    IndependentRobot,
    Manoeuvre,
    _motor_angles,
    _Segment,
    _timeline,
    logged_run,
    run_streams,
    time_grid,
)
from independent_skid import ElasticSkidRobot, integrate_steps  # noqa: E402

FloatArray = NDArray[np.float64]

DIAMETER_SCALE = 1.047
"""The real wheel diameter over the nominal one (the encoders count nominal metres)."""
MARKER_AHEAD = 0.29
"""The tracked marker ahead of the geometric centre [m]."""
MARKER_YAW = math.radians(2.0)
"""The marker's yaw against the body in the ``*_yaw`` variants [rad]."""
SENSOR_NOISE = (0.001, math.radians(0.2))
"""The tracker's noise, position [m] and heading [rad], one standard deviation."""
LOG_HZ = 20.0
"""The rate the encoders and the tracker are logged at [Hz]."""
INT_HZ = 200.0
"""The rate the body's motion is integrated at [Hz]."""
FREE_RUNS = 4
FREE_DURATION = 45.0
"""The joystick-like free drives: how many, and how long each drives [s]."""
LOSS_SEED_OFFSET = 1000
"""The tracker losses come from a generator seeded ``--seed`` + this."""
SKID_EFFECTS = ("skid_track", "skid_speed", "turn_skid")
"""The skid-steer effects ``--constant`` takes out of the candidates."""


@dataclass(frozen=True)
class Variant:
    """How one variant's tracker differs.

    Attributes:
        marker_yaw: the marker's yaw against the body [rad].
        lost: the share of the logged rows the tracker loses [-].
        held: a lost row repeats the last good pose (else it is NaN).
    """

    marker_yaw: float
    lost: float
    held: bool


VARIANTS: dict[str, Variant] = {
    "offset": Variant(0.0, 0.38, held=False),
    "offset_yaw": Variant(MARKER_YAW, 0.38, held=False),
    "offset_yaw_nan45": Variant(MARKER_YAW, 0.45, held=False),
    "offset_yaw_held45": Variant(MARKER_YAW, 0.45, held=True),
}
"""Every variant by name (module docstring)."""


def protocol() -> list[Manoeuvre]:
    """The lab's protocol (module docstring), without the free drives: 30 runs."""
    out: list[Manoeuvre] = []
    for sense in ("cw", "ccw"):
        for _ in range(2):
            out.append(
                Manoeuvre(
                    "square", sense, size=3.0, speed=0.5, turn_speed=0.3, label=f"square_{sense}"
                )
            )
    for speed in (0.3, 0.6):
        for radius in (0.5, 1.0, 2.0, 4.0):
            for sense in ("cw", "ccw"):
                sweep = 2 * math.pi if radius <= 1.0 else math.pi
                out.append(
                    Manoeuvre(
                        "arc",
                        sense,
                        size=radius,
                        angle=sweep,
                        speed=speed,
                        label=f"arc_{sense}_{radius:g}_{speed:g}",
                    )
                )
    for deg in (90, 180, 360):
        for sense in ("cw", "ccw"):
            out.append(
                Manoeuvre(
                    "spin", sense, angle=math.radians(deg), speed=0.3, label=f"spin_{sense}_{deg}"
                )
            )
    for sense in ("ccw", "cw"):
        out.append(
            Manoeuvre(
                "straight",
                sense,
                size=4.0,
                speed=0.5,
                turn_speed=0.3,
                return_trip=True,
                label="straight_return",
            )
        )
    return out


def free_motor(
    rng: np.random.Generator, nominal_d: float, track: float, duration: float, grid: FloatArray
) -> FloatArray:
    """Joystick-like free driving: the two motor angles [rad] (n, 2) at the times ``grid`` [s].
    The speed ramps up over 2 s to about 0.6 m/s (±25 %, slowly) and down at the end; the
    curvature is a sum of four random sines clipped to ±1.5 /m (the sense reverses); the wheel
    speeds are planned with the nominal diameter and track [m]."""
    fine = np.linspace(0.0, duration, int(duration * 1000) + 1)
    ramp = 2.0
    v = 0.6 * np.clip(np.minimum(fine, duration - fine) / ramp, 0.0, 1.0)
    v = 0.6 * np.sin(0.5 * np.pi * v / 0.6) ** 2
    # random phases in [0, 6.28) rad (the figures in docs/skid-steer.md were drawn so)
    v *= 1.0 + 0.25 * np.sin(2 * np.pi * fine / rng.uniform(6, 12) + rng.uniform(0, 6.28))
    kappa = np.zeros_like(fine)
    for _ in range(4):
        kappa += rng.uniform(0.2, 0.6) * np.sin(
            2 * np.pi * fine / rng.uniform(4, 20) + rng.uniform(0, 6.28)
        )
    kappa = np.clip(kappa, -1.5, 1.5)
    r_n = 0.5 * nominal_d
    wl = v * (1.0 - kappa * track / 2) / r_n
    wr = v * (1.0 + kappa * track / 2) / r_n
    dt = np.diff(fine)
    ang = np.zeros((len(fine), 2))
    ang[1:, 0] = np.cumsum(0.5 * (wl[1:] + wl[:-1]) * dt)
    ang[1:, 1] = np.cumsum(0.5 * (wr[1:] + wr[:-1]) * dt)
    return np.stack([np.interp(grid, fine, ang[:, k]) for k in range(2)], axis=1)


def simulate(
    robot: ElasticSkidRobot,
    nominal_d: float,
    manoeuvre: Manoeuvre | None,
    rng: np.random.Generator,
    marker_yaw: float,
    free_duration: float = 0.0,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """One run of ``manoeuvre`` (None: a free drive of ``free_duration`` [s]), planned with the
    nominal wheel diameter ``nominal_d`` [m] and driven on wheels :data:`DIAMETER_SCALE` times
    larger. Returns the log times [s] (n,), the tracked marker's pose with the tracker's noise
    (x, y [m], heading [rad]) (n, 3), the motor angles at the log times [rad] (n, 2) and the
    encoders' phase (fractional counts at the start) (2,)."""
    motion_rng, _, sensor_rng, start, phase = run_streams(rng)
    planner = IndependentRobot(
        wheel_diameter=nominal_d, wheelbase=robot.track, ticks_per_rev=robot.ticks_per_rev
    )
    if manoeuvre is not None:
        segments = _timeline(manoeuvre, planner, motion_rng)
        log_times, grid, log_index = time_grid(segments, LOG_HZ, INT_HZ)
        motor = _motor_angles(segments, grid)
    else:
        # one stop as long as the drive and a second after it: the time grid of the free drive
        segments = [_Segment(0.0, free_duration + 1.0, (0.0, 0.0), (0.0, 0.0), None)]
        log_times, grid, log_index = time_grid(segments, LOG_HZ, INT_HZ)
        motor = free_motor(motion_rng, nominal_d, robot.track, free_duration, grid)
    # the rims travel on the true diameter; the encoders count the motor angle
    true_d = DIAMETER_SCALE * nominal_d
    rims = np.diff(motor, axis=0) * (0.5 * true_d)
    x, y, theta = integrate_steps(start, robot.twist(rims))
    th = theta[log_index]
    cth, sth = np.cos(th), np.sin(th)
    pose = np.stack(
        [x[log_index] + cth * MARKER_AHEAD, y[log_index] + sth * MARKER_AHEAD, th + marker_yaw],
        axis=1,
    )
    pose[:, :2] += SENSOR_NOISE[0] * sensor_rng.standard_normal((len(log_times), 2))
    pose[:, 2] += SENSOR_NOISE[1] * sensor_rng.standard_normal(len(log_times))
    pose[:, 2] = np.remainder(pose[:, 2] + math.pi, 2 * math.pi) - math.pi  # as a tracker wraps
    return log_times, pose, motor[log_index], phase


def lose(pose: FloatArray, share: float, rng: np.random.Generator, held: bool) -> FloatArray:
    """``pose`` (n, 3) with the tracker's dropouts: bursts of 0.25–4 s (log-uniform) at random
    rows until at least ``share`` of the rows are lost, the first and last rows kept. A lost row
    is NaN, or with ``held`` the last good pose repeated."""
    out = pose.copy()
    n = len(out)
    lost = np.zeros(n, dtype=bool)
    if share <= 0:
        return out
    guard = 0
    while lost.mean() < share and guard < 10000:
        guard += 1
        length = round(math.exp(rng.uniform(math.log(0.25 * LOG_HZ), math.log(4 * LOG_HZ))))
        start = int(rng.integers(1, n - 1))
        lost[start : min(start + length, n - 1)] = True
    if held:
        for k in range(1, n):
            if lost[k]:
                out[k] = out[k - 1]
    else:
        out[lost] = np.nan
    return out


def skid_robot(nominal: RobotSpec) -> ElasticSkidRobot:
    """The independent skid-steer robot sized like the preset ``nominal``."""
    return ElasticSkidRobot(
        wheel_diameter=nominal.wheel_diameter,
        track=nominal.wheelbase,
        axle_spacing=nominal.axle_spacing,
        ticks_per_rev=nominal.ticks_per_rev,
    )


def field_log(
    robot: ElasticSkidRobot, nominal: RobotSpec, variant: Variant, seed: int
) -> list[Run]:
    """The variant's 32 logged runs (the protocol, then the free drives), from ``seed``."""
    rng = np.random.default_rng(seed)
    loss_rng = np.random.default_rng(seed + LOSS_SEED_OFFSET)
    items: list[tuple[Manoeuvre, float]] = [(m, 0.0) for m in protocol()]
    for i in range(FREE_RUNS):
        # the arc only labels the run (kind "free"); free_motor drives it
        label = Manoeuvre("arc", "ccw", size=1.0, angle=1.0, label=f"free_{i}")
        items.append((label, FREE_DURATION))
    runs: list[Run] = []
    for i, (m, free_duration) in enumerate(items):
        t, pose, motor, phase = simulate(
            robot,
            nominal.wheel_diameter,
            None if free_duration else m,
            rng,
            variant.marker_yaw,
            free_duration=free_duration,
        )
        pose = lose(pose, variant.lost, loss_rng, variant.held)
        runs.append(logged_run(m, i, "indep-field", t, pose, motor, phase, robot.ticks_per_rev))
    return runs


def apparent_tracks(robot: ElasticSkidRobot) -> dict[str, float]:
    """The robot's true apparent track over its track [-]: in a spin, on the protocol's arc
    radii (turn-radius ratio λ = 2R/B) and on straight paths (χ_∞, in closed form)."""
    out = {"spin": robot.apparent_track(0.75 * math.pi)}
    for radius in (0.5, 1.0, 2.0, 4.0):
        ratio = 2 * radius / robot.track
        out[f"R {radius:g} m"] = robot.apparent_track(math.atan2(ratio + 1, ratio - 1))
    ratio = robot.cornering_stiffness / robot.slip_stiffness
    out["straight"] = 1 + ratio * (robot.axle_spacing / robot.track) ** 2
    return out


def _finite(value: Any) -> Any:
    """``value`` with every float NaN or infinity as None (JSON has neither)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.generic):
        return value.item()
    return value


def summarise(result: Diagnosis, nominal: RobotSpec, seconds: float) -> dict[str, Any]:
    """One diagnosis's figures: named effects, parameters, held-out RMS [mm], [°]."""
    named = list(result.named_effects)
    held = result.held_out
    out: dict[str, Any] = {
        "named_effects": named,
        "skid_track_first": bool(named) and named[0] == "skid_track",
        "verdict": result.verdict,
        "parameters": result.parameters,
        "e_b": result.model.true_wheelbase / nominal.wheelbase,
        "e_d_mean": 0.5
        * (result.model.true_left_diameter + result.model.true_right_diameter)
        / nominal.wheel_diameter,
        "fit_runs": len(result.fit_runs),
        "holdout_runs": list(result.holdout_runs),
        "skipped_runs": result.skipped_runs,
        "discovered": [d.get("name", d.get("term")) for d in result.discovered],
        "stand_ins": result.stand_ins,
        "seconds": seconds,
    }
    if held is not None:
        out["held_out_position_rms_mm"] = {k: 1e3 * v.position_rms for k, v in held.models.items()}
        out["held_out_heading_rms_deg"] = {
            k: math.degrees(float(np.sqrt(np.nanmean(v.heading**2))))
            for k, v in held.models.items()
        }
        out["baseline_name"] = held.baseline_name
        out["baseline_geometry"] = held.baseline_geometry
    return out


def run_variant(
    name: str, nominal: RobotSpec, seed: int, jobs: int, constant: bool
) -> dict[str, Any]:
    """One variant: its logs made, diagnosed (and with ``constant`` diagnosed again without the
    skid-steer effects), summarised."""
    start = time.perf_counter()
    robot = skid_robot(nominal)
    runs = field_log(robot, nominal, VARIANTS[name], seed)
    row: dict[str, Any] = {
        "variant": name,
        "lost": VARIANTS[name].lost,
        "lost_as": "held" if VARIANTS[name].held else "NaN",
        "marker_yaw_deg": math.degrees(VARIANTS[name].marker_yaw),
        "runs": len(runs),
        "rows": sum(len(r.time) for r in runs),
        "apparent_track": apparent_tracks(robot),
        "log_seconds": time.perf_counter() - start,
    }
    print(f"{name}: {len(runs)} runs logged, diagnosing…", file=sys.stderr, flush=True)
    config = DiagnoseConfig(seed=seed, jobs=jobs)
    began = time.perf_counter()
    result = diagnose(runs, nominal, config, baseline=TrajectoryBaseline())
    row["diagnosis"] = summarise(result, nominal, time.perf_counter() - began)
    if constant:
        print(f"{name}: diagnosing with a constant track…", file=sys.stderr, flush=True)
        candidates = tuple(n for n in catalogue() if n not in SKID_EFFECTS)
        config = DiagnoseConfig(seed=seed, jobs=jobs, candidates=candidates)
        began = time.perf_counter()
        result = diagnose(runs, nominal, config, baseline=TrajectoryBaseline())
        row["constant_track"] = summarise(result, nominal, time.perf_counter() - began)
        row["constant_track"]["candidates"] = list(candidates)
    row["seconds"] = time.perf_counter() - start
    return row


def _figure(value: float | None, digits: int) -> str:
    """``value`` to ``digits`` decimals, or a dash."""
    return "—" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def table(rows: list[dict[str, Any]], preset: str, seed: int) -> str:
    """The rows as Markdown, and the robot's true apparent track under them."""
    out = [
        "| variant | named (in order) | skid_track first | E_b | ε | λ½ | held-out mm: as given"
        " / baseline / diagnosed / constant-track | s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        found = row["diagnosis"]
        e_b = found["parameters"].get("wheelbase", {}).get("e_b", {}).get("value")
        skid = found["parameters"].get("skid_track", {})
        held = found.get("held_out_position_rms_mm", {})
        constant = row.get("constant_track", {}).get("held_out_position_rms_mm", {})
        figures = " / ".join(
            _figure(v, 1)
            for v in (
                held.get("as given"),
                held.get("baseline"),
                held.get("diagnosed"),
                constant.get("diagnosed"),
            )
        )
        out.append(
            f"| {row['variant']} | {', '.join(found['named_effects']) or '(none)'} "
            f"| {'yes' if found['skid_track_first'] else '**no**'} "
            f"| {_figure(e_b, 4)} | {_figure(skid.get('excess', {}).get('value'), 4)}"
            f" | {_figure(skid.get('lambda_half', {}).get('value'), 2)}"
            f" | {figures} | {row['seconds']:.0f} |"
        )
    chi = rows[0]["apparent_track"]
    out += [
        "",
        f"{preset}, seed {seed}. The robot's true apparent track over its track: "
        + ", ".join(f"{k} {v:.3f}" for k, v in chi.items())
        + " (the diagnosis's E_b·(1 + ε) in a spin, E_b on straight paths).",
    ]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "variants", nargs="+", metavar="VARIANT", help=f"one or more of {', '.join(VARIANTS)}"
    )
    parser.add_argument(
        "--preset",
        default="husky",
        choices=SKID_STEER_PRESETS,
        help="the skid-steer preset the robot is sized like and diagnosed against (default husky)",
    )
    parser.add_argument("--seed", type=int, default=0, help="the logs' and diagnosis's seed")
    parser.add_argument("--jobs", type=int, default=1, help="diagnose --jobs (default 1)")
    parser.add_argument(
        "--constant",
        action="store_true",
        help="also diagnose without the skid-steer effects (a constant-track model)",
    )
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")
    args = parser.parse_args(argv)
    for name in args.variants:
        if name not in VARIANTS:
            parser.error(f"unknown variant {name!r}: choose from {', '.join(VARIANTS)}")
    if args.seed < 0:
        parser.error("--seed must be non-negative")
    if args.jobs < 1:
        parser.error("--jobs must be at least 1")
    nominal = PRESETS[args.preset]
    rows = [run_variant(n, nominal, args.seed, args.jobs, args.constant) for n in args.variants]
    if args.json:
        result = {"preset": args.preset, "seed": args.seed, "variants": rows}
        print(json.dumps(_finite(result), indent=1, default=str))
    else:
        print(table(rows, args.preset, args.seed))
    return 0


if __name__ == "__main__":
    sys.exit(main())

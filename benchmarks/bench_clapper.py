"""The CLAPPER's experiments (Borenstein 1995, §6) as distributions: IPEC configurations side by
side, and which error source brings what.

    python benchmarks/bench_clapper.py [--straight-runs 6] [--rectangle-runs 10] [--floor concrete]
                                      [--table configurations|sources|vehicles|all] [--json]

Every row runs the paper's conditions on one floor with the same seeds: the 36 m straight
(§6.1; conditions c and d: with IPEC, 0 and 20 cables; ``--straight-runs`` runs each) and the
7×4 m rectangle (§6.2; 10 cables, with and without IPEC, ``--rectangle-runs`` cw and as many
ccw, cables right in half the runs and left in the other half). Printed per row: straight d —
mean ± sd and worst absolute return heading of truck A [°] (the paper: all within ±1.0°) and the
return position along the path relative to c [mm] (what the cables' travel loss leaves);
rectangle — the vehicle's mean absolute return heading with IPEC [°] (the paper: 0.3°), its
worst position error [mm] (the paper: none over 50 mm), and IPEC's fold reduction of the mean
absolute heading error for the vehicle and each truck (the paper: more than 20-fold).
``--table vehicles`` compares the CLAPPER with the encoder trailer of §7 (the ``trailer``
preset: a LabMate towing a free-rolling two-wheel trailer on a 1 m tongue, one rotary encoder
at the hitch) on the same runs, with the hitch encoder at the CLAPPER's 10 bits and at 16.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from typing import Any

import numpy as np

from odomgym.floor import load_floor
from odomgym.vehicle.ipec import DEFAULT_IPEC, ipec_estimator
from odomgym.vehicle.paper_runs import PAPER_CONDITIONS, SONAR, run_clapper, summarize
from odomgym.vehicle.spec import PAPER_ERRORS, VEHICLES, VehicleSpec
from odomgym.vehicle.trial import CLAPPER_FLOOR

CONFIGURATIONS = ("paper", "gated", "heading-only", "recommended")


def sources() -> dict[str, VehicleSpec]:
    """The error sources, one at a time at the magnitudes of ``PAPER_ERRORS`` (the paper's, or
    stated assumptions), then all of them, then the trucks' own systematic errors."""
    base = VEHICLES["clapper"]
    rows = {"none (calibrated trucks)": base}
    for key, value in PAPER_ERRORS.items():
        unit = "°" if key == "rotary_jitter" else ("ms" if key == "read_skew" else "mm")
        shown = math.degrees(value) if unit == "°" else 1e3 * value
        rows[f"{key} {shown:g} {unit}"] = dataclasses.replace(base, **{key: value})  # type: ignore[arg-type]
    leftover = math.radians(0.1)
    rows["rotary biases ±0.1°"] = dataclasses.replace(
        base, rotary_bias_a=leftover, rotary_bias_b=-leftover
    )
    rows["all of the above"] = dataclasses.replace(
        base, rotary_bias_a=leftover, rotary_bias_b=-leftover, **PAPER_ERRORS
    )  # type: ignore[arg-type]
    rows["tyre_compression 2 mm"] = dataclasses.replace(base, tyre_compression=0.002)
    truck = base.truck_a.with_errors(1.0, 1.0, 0.995)
    rows["wheel scale E_s 0.995"] = dataclasses.replace(base, truck_a=truck, truck_b=truck)
    rows["uncalibrated LabMates"] = VEHICLES["clapper-uncalibrated"]
    return rows


def vehicles() -> dict[str, VehicleSpec]:
    """The CLAPPER and the encoder trailer (10-bit and 16-bit hitch encoder)."""
    trailer = VEHICLES["trailer"]
    return {
        "CLAPPER (two 10-bit encoders, compliant link)": VEHICLES["clapper"],
        "encoder trailer, 10-bit hitch encoder": trailer,
        "encoder trailer, 16-bit hitch encoder": dataclasses.replace(trailer, rotary_bits=16),
    }


def measure(
    spec: VehicleSpec,
    configuration: str,
    floor_name: str,
    straight_runs: int,
    rect_runs: int,
    sonar: tuple[float, float] | None = None,
) -> dict[str, Any]:
    floor = load_floor(floor_name)
    ipec = ipec_estimator(configuration, spec.rotary_resolution)
    straight = run_clapper(
        spec,
        floor,
        "straight",
        conditions=PAPER_CONDITIONS["straight"][2:],
        runs=straight_runs,
        seed=0,
        ipec=ipec,
        sonar=sonar,
    )
    s = summarize(straight)["conditions"]
    along = {
        label: float(np.mean([r.measured()[0][0] for r in straight if r.condition == label]))
        for label in ("c", "d")
    }
    rectangle = run_clapper(
        spec,
        floor,
        "rectangle",
        conditions=PAPER_CONDITIONS["rectangle"],
        directions=("cw", "ccw"),
        sides=("right", "left"),
        runs=rect_runs,
        seed=0,
        ipec=ipec,
        sonar=sonar,
    )
    r = summarize(rectangle)
    w = r["conditions"]["with IPEC"]
    return {
        "straight_d_theta_a_deg": {k: math.degrees(v) for k, v in s["d"]["theta_truck_a"].items()},
        "straight_d_worst_deg": math.degrees(
            max(s["d"][k]["worst"] for k in ("theta_vehicle", "theta_truck_a", "theta_truck_b"))
        ),
        "straight_cable_loss_left_mm": 1e3 * (along["d"] - along["c"]),
        "rectangle_ipec_theta_vehicle_deg": math.degrees(w["theta_vehicle"]["mean_abs"]),
        "rectangle_ipec_worst_position_mm": 1e3 * w["position"]["worst"],
        "rectangle_link_force_max_n": max(g["link_force_max_n"] for g in r["conditions"].values()),
        "reduction": r["reduction"],
    }


def markdown(rows: dict[str, dict[str, Any]], first: str) -> str:
    lines = [
        f"| {first} | straight d: θ_A mean ± sd (worst of all) [°] | cable loss left [mm] | "
        "rectangle IPEC θ [°] | worst position [mm] | reduction vehicle / A / B |",
        "|---|---|---|---|---|---|",
    ]
    for name, m in rows.items():
        a = m["straight_d_theta_a_deg"]
        red = m["reduction"]
        lines.append(
            f"| {name} | {a['mean_abs']:.2f} ± {a['sd']:.2f} ({m['straight_d_worst_deg']:.2f}) | "
            f"{m['straight_cable_loss_left_mm']:+.0f} | "
            f"{m['rectangle_ipec_theta_vehicle_deg']:.2f} | "
            f"{m['rectangle_ipec_worst_position_mm']:.0f} | {red['theta_vehicle']:.1f} / "
            f"{red['theta_truck_a']:.1f} / {red['theta_truck_b']:.1f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--straight-runs", type=int, default=6)
    parser.add_argument("--rectangle-runs", type=int, default=10)
    parser.add_argument("--floor", default=CLAPPER_FLOOR)
    parser.add_argument(
        "--table", choices=["configurations", "sources", "vehicles", "all"], default="all"
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    start = time.perf_counter()
    out: dict[str, Any] = {"floor": args.floor}
    if args.table in ("configurations", "all"):
        out["configurations"] = {
            name: measure(
                VEHICLES["clapper"], name, args.floor, args.straight_runs, args.rectangle_runs
            )
            for name in CONFIGURATIONS
        }
    if args.table in ("sources", "all"):
        out["sources"] = {
            name: measure(spec, DEFAULT_IPEC, args.floor, args.straight_runs, args.rectangle_runs)
            for name, spec in sources().items()
        }
        out["sources"]["sonar measurement ±2 mm, ±0.25°"] = measure(
            VEHICLES["clapper"],
            DEFAULT_IPEC,
            args.floor,
            args.straight_runs,
            args.rectangle_runs,
            sonar=SONAR,
        )
    if args.table in ("vehicles", "all"):
        out["vehicles"] = {
            name: measure(spec, DEFAULT_IPEC, args.floor, args.straight_runs, args.rectangle_runs)
            for name, spec in vehicles().items()
        }
    out["elapsed_s"] = time.perf_counter() - start
    if args.json:
        print(json.dumps(out, indent=2))
        return
    print(
        f"floor {args.floor}; straight: {args.straight_runs} runs per condition; rectangle: "
        f"{args.rectangle_runs} cw + {args.rectangle_runs} ccw per mode; "
        f"{out['elapsed_s']:.0f} s"
    )
    if "configurations" in out:
        print("\nIPEC configurations (clapper vehicle, no error sources)\n")
        print(markdown(out["configurations"], "configuration"))
    if "sources" in out:
        print(f"\nError sources, one at a time (IPEC {DEFAULT_IPEC})\n")
        print(markdown(out["sources"], "error source"))
    if "vehicles" in out:
        print(f"\nThe CLAPPER and the encoder trailer (IPEC {DEFAULT_IPEC})\n")
        print(markdown(out["vehicles"], "vehicle"))


if __name__ == "__main__":
    main()

"""Leave-one-session-out replication of ``odomgym diagnose`` on a real robot's sessions.

    python benchmarks/diagnose_loso.py [DATA] [--robot R.toml] [--jobs 2] [--out DIR] [--json]
    python benchmarks/diagnose_loso.py --jobs 1 --shard 1/2 & python benchmarks/diagnose_loso.py \
        --jobs 1 --shard 2/2; python benchmarks/diagnose_loso.py    # two cores, then the table

DATA: a folder of OptiOdom sessions; by default the 14 June sessions of the OptiOdom robot
(Sousa et al. 2022, MIT): the six shipped in the package and the eight in
``tests/data/optiodom-replication``, gathered into a temporary folder. The robot defaults to
``examples/optiodom_nominal.toml``.

For every session: the others are diagnosed (with the workflow's own held-out split inside),
then the left-out session — never seen by any step — is predicted open loop by the model as given,
the diagnosed model and the baseline calibration (trajectory optimisation of b, D_R, D_L on the
diagnosis's fit runs), each with the session's measurement nuisances fitted on its own runs with
the model fixed (:func:`odomgym.diagnose.openloop.evaluate_open_loop`). Prints one row per fold
and checks what a replication needs:

* the same systematic effects named in every fold;
* overlapping 95 % intervals of E_d, E_b, E_s (session-clustered standard errors, Student's t
  on G − 1 degrees of freedom) across the folds;
* the left-out session predicted better than by the model as given, in every fold; and how often
  at least as well as the baseline.

Each fold's result is written to ``OUT/fold-<session>.json`` as it finishes (atomically), so an
interrupted run resumes where it stopped. Takes 14 diagnoses.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats
from tqdm import tqdm

from odomgym.baselines.trajectory import TrajectoryBaseline
from odomgym.data import sample_session, sample_sessions
from odomgym.data.logs import read_log
from odomgym.diagnose.config import GATE_ORDERS
from odomgym.diagnose.heldout import AS_GIVEN, BASELINE, DIAGNOSED
from odomgym.diagnose.nuisances import sessions_of
from odomgym.diagnose.openloop import NuisanceOptions, evaluate_open_loop
from odomgym.diagnose.workflow import DiagnoseConfig, diagnose
from odomgym.io import atomic_write_text
from odomgym.robot import RobotSpec, load_robot

ROOT = Path(__file__).resolve().parents[1]
SET_B = ROOT / "tests" / "data" / "optiodom-replication"
GEOMETRY = (("wheel_diameter_ratio", "e_d"), ("wheelbase", "e_b"), ("distance_scale", "e_s"))


def gather_june(folder: Path) -> Path:
    """The 14 June sessions in ``folder`` (set A from the package, set B from the tests)."""
    for name in sample_sessions():
        kind, session = name.split("/")
        (folder / kind).mkdir(parents=True, exist_ok=True)
        shutil.copytree(sample_session(name), folder / kind / session)
    for archive in sorted(SET_B.glob("*.tar.xz")):
        kind = archive.name.split("-")[0]
        (folder / kind).mkdir(parents=True, exist_ok=True)
        with tarfile.open(archive) as tar:
            tar.extractall(folder / kind, filter="data")
    return folder


def fold(
    runs: list[Any], robot: RobotSpec, left_out: str, jobs: int, gate_order: str = "catalogue first"
) -> dict[str, Any]:
    """Diagnose every session but ``left_out``; predict ``left_out`` with the three models."""
    labels = sessions_of(runs)
    train = [r for r, s in zip(runs, labels, strict=True) if s != left_out]
    test = [r for r, s in zip(runs, labels, strict=True) if s == left_out]
    start = time.perf_counter()
    config = DiagnoseConfig(jobs=jobs, gate_order=gate_order)
    result = diagnose(train, robot, config, baseline=TrajectoryBaseline())
    seconds = time.perf_counter() - start
    options = NuisanceOptions(frames=True)
    models = {AS_GIVEN: robot, DIAGNOSED: result.model}
    if result.held_out is not None and result.held_out.baseline_geometry:
        g = result.held_out.baseline_geometry
        models[BASELINE] = robot.with_errors(g["E_d"], g["E_b"], g["E_s"])
    errors = {
        label: evaluate_open_loop(label, test, spec, {}, options, 0.25, robot.wheelbase).summary()
        for label, spec in models.items()
    }
    geometry = {}
    for name, key in GEOMETRY:
        entry = result.parameters.get(name, {}).get(key)
        geometry[key] = (
            {"value": entry["value"], "stderr_sessions": entry["stderr_sessions"]}
            if entry
            else {"value": getattr(result.model, key), "stderr_sessions": math.nan}
        )
    return {
        "left_out": left_out,
        "gate_order": gate_order,
        "runs": len(test),
        "seconds": seconds,
        "verdict": result.verdict,
        "systematic_effects": result.systematic_effects,
        "noise_model": result.noise_model,
        "terms_kept": [e["term"] for e in result.discovered],
        "terms_tried": result.terms_tried,
        "sessions_fitted": len(set(sessions_of(train))),
        "geometry": geometry,
        "left_out_open_loop": errors,
        "gate": [step.as_dict() for step in result.gate],
    }


def summarise(folds: list[dict[str, Any]]) -> dict[str, Any]:
    """The replication checks over the folds (module docstring)."""
    # The order in which a fold's rounds named its effects is not a finding: sets are compared.
    named = [tuple(sorted(f["systematic_effects"])) for f in folds]
    effects = set(named)
    modal = max(effects, key=named.count) if named else ()
    overlap: dict[str, Any] = {}
    for _, key in GEOMETRY:
        low, high = [], []
        for f in folds:
            entry = f["geometry"][key]
            se = entry["stderr_sessions"]
            dof = max(f["sessions_fitted"] - 1, 1)
            half = float(stats.t.ppf(0.975, dof)) * se if math.isfinite(se) else 0.0
            low.append(entry["value"] - half)
            high.append(entry["value"] + half)
        overlap[key] = {
            "common_interval": [max(low), min(high)],
            "overlap": max(low) <= min(high),
        }
    better = [
        f["left_out_open_loop"][DIAGNOSED]["combined_rms_mm"]
        < f["left_out_open_loop"][AS_GIVEN]["combined_rms_mm"]
        for f in folds
    ]
    with_base = [f for f in folds if BASELINE in f["left_out_open_loop"]]
    as_good = [
        f["left_out_open_loop"][DIAGNOSED]["combined_rms_mm"]
        <= f["left_out_open_loop"][BASELINE]["combined_rms_mm"]
        for f in with_base
    ]
    return {
        "folds": len(folds),
        "same_systematic_effects": len(effects) == 1,
        "systematic_effect_sets": sorted(list(e) for e in effects),
        "modal_effect_set": list(modal),
        "folds_with_modal_set": f"{named.count(modal)}/{len(folds)}",
        "intervals": overlap,
        "better_than_as_given": f"{sum(better)}/{len(folds)}",
        "as_good_as_baseline": f"{sum(as_good)}/{len(with_base)}",
        "seconds": sum(f["seconds"] for f in folds),
    }


def table(folds: list[dict[str, Any]], summary: dict[str, Any]) -> str:
    """The docs' Markdown table."""
    lines = [
        "| left out | runs | systematic effects | E_d | E_b | E_s | terms kept / tried | "
        "noise | as given [mm, °] | diagnosed [mm, °] | baseline [mm, °] |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for f in folds:
        cells = []
        for _, key in GEOMETRY:
            g = f["geometry"][key]
            se = g["stderr_sessions"]
            cells.append(f"{g['value']:.4f}" + (f" ± {se:.4f}" if math.isfinite(se) else ""))
        errs = []
        for label in (AS_GIVEN, DIAGNOSED, BASELINE):
            e = f["left_out_open_loop"].get(label)
            errs.append(f"{e['position_rms_mm']:.1f}, {e['heading_rms_deg']:.2f}" if e else "—")
        lines.append(
            f"| {f['left_out']} | {f['runs']} | {', '.join(f['systematic_effects']) or '—'} | "
            + " | ".join(cells)
            + f" | {len(f['terms_kept'])} / {f['terms_tried']} | "
            f"{', '.join(f['noise_model']) or '—'} | " + " | ".join(errs) + " |"
        )
    lines += [
        "",
        f"Same systematic effects in every fold: {summary['same_systematic_effects']} "
        f"({summary['systematic_effect_sets']}; the most frequent set in "
        f"{summary['folds_with_modal_set']} folds); 95 % intervals overlap: "
        + ", ".join(f"{k} {v['overlap']}" for k, v in summary["intervals"].items())
        + f"; left-out session better than as given: {summary['better_than_as_given']}; "
        f"at least as good as the baseline: {summary['as_good_as_baseline']}; "
        f"{summary['seconds']:.0f} s of diagnosis.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", nargs="?", help="folder of OptiOdom sessions (default: June)")
    parser.add_argument("--robot", default=str(ROOT / "examples" / "optiodom_nominal.toml"))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", default="loso-out", help="folder of per-fold results")
    parser.add_argument("--json", action="store_true", help="print the folds and summary as JSON")
    parser.add_argument(
        "--shard",
        default="1/1",
        help="K/N: diagnose only folds K, K+N, … (run N processes with --jobs 1 on N cores, "
        "then once without --shard to print the table from their files)",
    )
    parser.add_argument(
        "--gate-order",
        default="catalogue first",
        choices=GATE_ORDERS,
        help="DiagnoseConfig.gate_order: how the open-loop gate eliminates (default: catalogue "
        "first)",
    )
    parser.add_argument(
        "--sessions",
        nargs="+",
        default=None,
        metavar="SESSION",
        help="leave out only these sessions (default: every one); the table shows the folds "
        "in --out",
    )
    parser.add_argument(
        "--table-only",
        action="store_true",
        help="print the table of the folds already in --out, diagnosing none (missing folds "
        "are listed)",
    )
    args = parser.parse_args(argv)
    try:
        shard, shards = (int(v) for v in args.shard.split("/"))
        if not 1 <= shard <= shards:
            raise ValueError
    except ValueError:
        parser.error(f"--shard: expected K/N with 1 <= K <= N, got {args.shard!r}")
    robot = load_robot(args.robot)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(args.data) if args.data else gather_june(Path(tmp))
        runs, _ = read_log(data, robot=robot, format="optiodom")
    sessions = list(dict.fromkeys(sessions_of(runs)))
    folds = []
    if args.sessions:
        unknown = sorted(set(args.sessions) - set(sessions))
        if unknown:
            parser.error(f"--sessions: not in the data: {', '.join(unknown)}")
        sessions = [s for s in sessions if s in args.sessions]
    mine = sessions[shard - 1 :: shards]
    missing = []
    for session in tqdm(mine, desc="leave one session out", file=sys.stderr):
        path = out / f"fold-{session}.json"
        if path.is_file():
            folds.append(json.loads(path.read_text(encoding="utf-8")))
            continue
        if args.table_only:
            missing.append(session)
            continue
        result = fold(runs, robot, session, args.jobs, args.gate_order)
        atomic_write_text(path, json.dumps(result, indent=1, default=float))
        folds.append(result)
    summary = summarise(folds)
    summary["missing_folds"] = missing
    if args.json:
        print(json.dumps({"folds": folds, "summary": summary}, default=float))
    else:
        print(table(folds, summary))
        if missing:
            print(f"\nNot diagnosed yet ({len(missing)} of {len(sessions)}): {', '.join(missing)}")
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    raise SystemExit(main())

"""Leave-one-session-out replication of ``odomgym diagnose`` on a real robot's sessions.

    python benchmarks/diagnose_loso.py [DATA] [--robot R.toml] [--jobs 2] [--out DIR] [--json]
    python benchmarks/diagnose_loso.py --jobs 1 --shard 1/2 & python benchmarks/diagnose_loso.py \
        --jobs 1 --shard 2/2; python benchmarks/diagnose_loso.py --table-only   # two cores

A thin wrapper of :mod:`odomgym.diagnose.loso`, the library behind ``odomgym diagnose DATA
--loso`` (the command for users: same folds, same fold files, same table). What this script
adds is the data: DATA defaults to the 14 June sessions of the OptiOdom robot (Sousa et al.
2022, MIT) — the six shipped in the package and the eight in ``tests/data/optiodom-replication``,
gathered into a temporary folder (:func:`gather_june`) — and the robot to
``examples/optiodom_nominal.toml``. Each fold's diagnosis uses the defaults of ``DiagnoseConfig``
with ``--jobs`` and ``--gate-order``, and the trajectory baseline.

What a fold is and what the summary checks: :mod:`odomgym.diagnose.loso`. Each fold's result is
written to ``OUT/fold-<session>.json`` as it finishes (atomically), so an interrupted run resumes
where it stopped. Takes 14 diagnoses.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tarfile
import tempfile
from pathlib import Path

import numpy as np
from tqdm import tqdm

from odomgym.baselines.trajectory import TrajectoryBaseline
from odomgym.data import sample_session, sample_sessions
from odomgym.data.logs import read_log
from odomgym.diagnose.config import GATE_ORDERS
from odomgym.diagnose.loso import parse_shard, run_loso, table
from odomgym.diagnose.workflow import DiagnoseConfig
from odomgym.errors import SpecError
from odomgym.robot import load_robot

ROOT = Path(__file__).resolve().parents[1]
SET_B = ROOT / "tests" / "data" / "optiodom-replication"


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
        "then once with --table-only to print the table from their files)",
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
        help="leave out only these sessions (default: every one); the table shows their folds",
    )
    parser.add_argument(
        "--table-only",
        action="store_true",
        help="print the table of the folds already in --out, diagnosing none (missing folds "
        "are listed)",
    )
    args = parser.parse_args(argv)
    try:
        shard = parse_shard(args.shard)
    except ValueError as exc:
        parser.error(f"--shard: {exc}")
    robot = load_robot(args.robot)
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(args.data) if args.data else gather_june(Path(tmp))
        runs, _ = read_log(data, robot=robot, format="optiodom")
    bar = tqdm(desc="leave one session out", unit="fold", file=sys.stderr)

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        with bar:
            folds, summary = run_loso(
                runs,
                robot,
                args.out,
                config=DiagnoseConfig(jobs=args.jobs, gate_order=args.gate_order),
                baseline=TrajectoryBaseline,
                sessions=args.sessions,
                shard=shard,
                table_only=args.table_only,
                progress=progress,
            )
    except SpecError as exc:
        parser.error(str(exc))
    if args.json:
        print(json.dumps({"folds": folds, "summary": summary}, default=float))
    else:
        print(table(folds, summary))
        missing = summary["missing_folds"]
        if missing:
            print(
                f"\nNot diagnosed yet ({len(missing)} of {len(folds) + len(missing)}): "
                f"{', '.join(missing)}"
            )
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    raise SystemExit(main())

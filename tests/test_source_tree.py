"""A source checkout's ``odomgym.envs`` and ``odomgym.baselines`` are its own folders, whatever
else is installed (``odomgym._source_tree``).

A checkout put on ``PYTHONPATH`` beside an installed odomgym — an editable install of another
checkout on the dev machine, or the wheel in CI — finds its own ``odomgym/`` first; before the
source-tree finder went first on ``sys.meta_path``, an editable install's finder answered for the
two mapped names with the other checkout's folders, and one process ran two revisions' code
(seen while timing two revisions side by side, ``benchmarks/june_speed.py``).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parent.parent


def test_a_checkout_on_the_path_imports_its_own_envs_and_baselines(tmp_path: Path) -> None:
    tree = tmp_path / "checkout"
    skip = shutil.ignore_patterns("__pycache__")
    for name in ("odomgym", "envs", "baselines"):
        shutil.copytree(ROOT / name, tree / name, ignore=skip)
    probe = (
        "import odomgym, odomgym.envs, odomgym.baselines, odomgym.baselines.trajectory as t; "
        "print(odomgym.__file__); print(odomgym.envs.__file__); "
        "print(odomgym.baselines.__file__); print(t.__file__)"
    )
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run(
        [sys.executable, "-c", probe], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    files = [Path(line).resolve() for line in done.stdout.split()]
    assert len(files) == 4
    for file in files:
        assert file.is_relative_to(tree.resolve()), (file, tree)


def _june_speed() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "june_speed", ROOT / "benchmarks" / "june_speed.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["june_speed"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_the_side_by_side_benchmark_reports_medians_ratio_and_the_target() -> None:
    """``benchmarks/june_speed.py``'s summary of two trees' runs: each median, the ratio of the
    first tree's to the second's, whether every run of a tree met the 60 s target, and whether
    the two reports were the same bytes."""
    bench = _june_speed()
    this = bench.Tree("this tree", ROOT, [58.0, 61.0, 55.0], b"{}")
    other = bench.Tree("v0.3.0", ROOT, [60.0, 64.0, 62.0], b"{}")
    result = bench.summary([this, other])
    assert result["trees"]["this tree"]["median_s"] == 58.0
    assert result["trees"]["v0.3.0"]["median_s"] == 62.0
    assert result["ratio"] == 58.0 / 62.0
    assert result["trees"]["this tree"]["every_run_within_target"] is False
    assert result["same_report"] is True
    text = bench.table([this, other], result)
    assert "| median | **58.0** | **62.0** |" in text
    assert "ratio this tree / v0.3.0: 0.935" in text
    other.report = b"[]"
    assert bench.summary([this, other])["same_report"] is False
    alone = bench.summary([bench.Tree("this tree", ROOT, [50.0], b"")])
    assert "ratio" not in alone and alone["trees"]["this tree"]["every_run_within_target"]

"""A source checkout's ``odomgym.envs`` and ``odomgym.baselines`` are its own folders, whatever
import finder an installed odomgym put on ``sys.meta_path`` (``odomgym._source_tree``).

An editable install adds, at start-up, a finder that maps the two names to *its* checkout's
folders. A second checkout put on ``PYTHONPATH`` found its own ``odomgym/`` first, but the
install's finder, ahead of the checkout's (which went last), answered for the two mapped names:
one process ran two revisions' code (seen while timing two revisions side by side,
``benchmarks/june_speed.py``). The test plants such a finder itself, so it does not depend on
how the machine installed odomgym.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

_DECOY = """
import importlib.util, sys
from pathlib import Path
# An editable install's finder for another checkout: the project's own finder class, loaded
# apart from the package (so the package does not take it for its own), for the decoy folder.
spec = importlib.util.spec_from_file_location("decoy_source_tree", {finder!r})
decoy = importlib.util.module_from_spec(spec)
spec.loader.exec_module(decoy)
sys.meta_path.append(decoy._SourceTreeFinder(Path({decoy_root!r})))
import odomgym, odomgym.envs, odomgym.baselines, odomgym.baselines.trajectory as t
for module in (odomgym, odomgym.envs, odomgym.baselines, t):
    print(module.__file__)
"""


def test_a_checkout_on_the_path_imports_its_own_envs_and_baselines(tmp_path: Path) -> None:
    tree = tmp_path / "checkout"
    skip = shutil.ignore_patterns("__pycache__")
    for name in ("odomgym", "envs", "baselines"):
        shutil.copytree(ROOT / name, tree / name, ignore=skip)
    decoy = tmp_path / "other"
    for name in ("envs", "baselines"):
        (decoy / name).mkdir(parents=True)
        (decoy / name / "__init__.py").write_text("")
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run(
        [
            sys.executable,
            "-c",
            _DECOY.format(finder=str(ROOT / "odomgym" / "_source_tree.py"), decoy_root=str(decoy)),
        ],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    files = [Path(line).resolve() for line in done.stdout.splitlines()]
    assert len(files) == 4
    for file in files:
        assert file.is_relative_to(tree.resolve()), (file, tree)

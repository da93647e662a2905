"""Make ``odomgym.envs`` and ``odomgym.baselines`` importable from a source checkout.

The design card keeps the envs and the reference solutions in top-level ``envs/`` and
``baselines/`` folders, installed as ``odomgym.envs`` and ``odomgym.baselines`` through
setuptools' ``package-dir``. An installed package has them inside ``odomgym/``; a checkout does
not, so Python started in the repository root (where ``odomgym/`` shadows the installed package)
would fail with ``No module named 'odomgym.envs'``. The finder below maps the two names to the
top-level folders exactly as ``package-dir`` does, and only when the folders are not already
inside the package.

It goes first on ``sys.meta_path``: a checkout put on ``PYTHONPATH`` beside an editable install
of *another* checkout (two revisions timed side by side, ``benchmarks/june_speed.py``) found
its ``odomgym`` first, but the editable install's finder, earlier on ``sys.meta_path`` (added
there by its ``.pth`` file at start-up), answered for ``odomgym.envs`` and
``odomgym.baselines`` with the other checkout's folders: one process ran two revisions' code
(``tests/test_source_tree.py``).
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys
from collections.abc import Sequence
from importlib.machinery import ModuleSpec
from pathlib import Path
from types import ModuleType

__all__ = ["install_source_tree_finder"]

MAPPED = ("envs", "baselines")


class _SourceTreeFinder(importlib.abc.MetaPathFinder):
    """Finds ``odomgym.<name>`` in ``<root>/<name>/`` for the mapped names."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None,
        target: ModuleType | None = None,
    ) -> ModuleSpec | None:
        del path, target
        package, _, name = fullname.partition(".")
        if package != "odomgym" or name not in MAPPED:
            return None
        folder = self.root / name
        return importlib.util.spec_from_file_location(
            fullname, folder / "__init__.py", submodule_search_locations=[str(folder)]
        )


def install_source_tree_finder() -> None:
    """Install the finder if this ``odomgym/`` is a source checkout's (idempotent)."""
    here = Path(__file__).resolve().parent
    root = here.parent
    if all((here / name).is_dir() for name in MAPPED):
        return  # an installed package: nothing to map
    if not all((root / name / "__init__.py").is_file() for name in MAPPED):
        return
    if any(isinstance(f, _SourceTreeFinder) for f in sys.meta_path):
        return
    sys.meta_path.insert(0, _SourceTreeFinder(root))

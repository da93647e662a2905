"""Every figure the docs link to is a file the repository holds, not one the author's checkout
happens to have: a PNG that ``.gitignore`` keeps out would be missing from every clone, and
from the docs of the tagged version (``scripts/docs_versions.sh`` builds from the tag)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[1] / "docs"
LINK = re.compile(r"\]\((assets/[^)\s]+)\)")


def _linked() -> list[Path]:
    return sorted(
        {DOCS / m for page in DOCS.rglob("*.md") for m in LINK.findall(page.read_text("utf-8"))}
    )


def test_every_linked_figure_exists() -> None:
    missing = [str(p.relative_to(DOCS)) for p in _linked() if not p.exists()]
    assert not missing


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_no_linked_figure_is_ignored_by_git() -> None:
    paths = [str(p) for p in _linked()]
    result = subprocess.run(
        ["git", "check-ignore", *paths], cwd=DOCS, capture_output=True, text=True, check=False
    )
    if result.returncode == 128:  # not a git checkout (an unpacked sdist): nothing to check
        pytest.skip(result.stderr.strip())
    assert result.stdout.split() == []

"""One version, one place (issue 46): pyproject.toml holds it, and everything that states it agrees.

The installed distribution's metadata, ``odomgym.__version__``, ``odomgym --version``, the
CHANGELOG's top released section and ``CITATION.cff`` must all say the version written in
``pyproject.toml``, and the CHANGELOG's top released date must be CITATION.cff's release date.
The release scripts are checked for what they promise without running them (they build, install
and tag: scripts/test.sh runs scripts/check_dist.sh itself).
"""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from importlib.metadata import version
from pathlib import Path

import odomgym

REPO = Path(__file__).resolve().parents[1]
# "## [0.3.0] — 2026-11-28": a released section, its version and date (ISO 8601).
RELEASED = re.compile(r"^## \[(\d+\.\d+\.\d+)\] — (\d{4}-\d{2}-\d{2})$", flags=re.MULTILINE)


def _pyproject_version() -> str:
    with open(REPO / "pyproject.toml", "rb") as file:
        return str(tomllib.load(file)["project"]["version"])


def _citation_field(name: str) -> str:
    """A top-level scalar of CITATION.cff (the file's own top-level keys are unindented)."""
    text = (REPO / "CITATION.cff").read_text(encoding="utf-8")
    (value,) = re.findall(rf"^{name}: (.+)$", text, flags=re.MULTILINE)
    return value.strip().strip('"')


def test_the_version_is_written_once() -> None:
    """pyproject.toml is the one place; the package reads it back from its metadata."""
    assert version("odomgym") == _pyproject_version()
    assert odomgym.__version__ == version("odomgym")
    source = (REPO / "odomgym" / "__init__.py").read_text(encoding="utf-8")
    assert not re.search(r'__version__\s*=\s*"\d+\.\d+', source), "a version literal in __init__.py"


def test_odomgym_dash_dash_version_prints_the_installed_version() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "odomgym", "--version"], capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == f"odomgym {version('odomgym')}"


def test_changelog_top_released_section_is_this_version() -> None:
    """Keep a Changelog: an [Unreleased] section first, then the released versions, newest
    first, each with its date; the newest is the version in pyproject.toml."""
    text = (REPO / "CHANGELOG.md").read_text(encoding="utf-8")
    sections = re.findall(r"^## \[([^\]]+)\]", text, flags=re.MULTILINE)
    assert sections[0] == "Unreleased"
    released = RELEASED.findall(text)
    assert released, "no released section with a date"
    assert released[0][0] == _pyproject_version()
    dates = [date for _, date in released]
    assert dates == sorted(dates, reverse=True), "released sections are not newest first"


def test_citation_cff_states_this_release() -> None:
    released = RELEASED.findall((REPO / "CHANGELOG.md").read_text(encoding="utf-8"))
    assert _citation_field("version") == _pyproject_version()
    assert _citation_field("date-released") == released[0][1]
    assert _citation_field("license") == "MIT"
    assert "The odomgym authors" in (REPO / "LICENSE").read_text(encoding="utf-8")
    assert "- name: The odomgym authors" in (REPO / "CITATION.cff").read_text(encoding="utf-8")


def test_readme_citing_section_cites_this_version() -> None:
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    citing = readme.split("\n## Citing\n", 1)[1].split("\n## ", 1)[0]
    assert f"version = {{{_pyproject_version()}}}" in citing
    for key in ("borenstein1994umbmark", "borenstein1995clapper", "chong1997accurate",
                "sousa2022optiodom"):  # fmt: skip
        assert key in citing, key


def test_check_dist_runs_the_readme_main_job() -> None:
    """The artefact check runs the README's main job (its robot count aside: see the script)
    and the issue's other commands; scripts/test.sh runs it."""
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    (job,) = re.findall(r"\.venv/bin/odomgym (bench calibrators [^\n]+)", readme)
    check = (REPO / "scripts" / "check_dist.sh").read_text(encoding="utf-8")
    assert re.sub(r"--robots \d+", '--robots "$ROBOTS"', job) in check
    for step in ("twine\" check --strict", "cffconvert\" --validate", "diagnose optiodom:square",
                 "gym.make(env_id)", "--wheel"):  # fmt: skip
        assert step in check, step
    assert "scripts/check_dist.sh" in (REPO / "scripts" / "test.sh").read_text(encoding="utf-8")


def test_release_script_refuses_bad_input() -> None:
    """One line, exit 2, before any work: no version, a malformed one, an unknown option."""
    for argv in ([], ["0.3"], ["0.3.0", "--frobnicate"]):
        done = subprocess.run(
            ["bash", str(REPO / "scripts" / "release.sh"), *argv],
            capture_output=True,
            text=True,
            cwd=REPO,
        )
        assert done.returncode == 2, (argv, done.stdout, done.stderr)
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr
        assert done.stderr.startswith("release.sh: "), done.stderr

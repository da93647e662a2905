"""The OptiOdom sessions shipped inside the package (:mod:`odomgym.data.samples`): names,
unpacking into the cache, the ``optiodom:`` names on the command line, and the package data."""

from __future__ import annotations

import csv
import fnmatch
import json
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path, PurePosixPath

import pytest

import odomgym.data.samples as samples
from odomgym.cli import main
from odomgym.data import find_sessions, read_session, resolve_data, sample_session, sample_sessions
from odomgym.errors import SpecError

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "odomgym" / "data" / "samples" / "optiodom"


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A fresh, empty user cache."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return tmp_path / "cache" / "odomgym"


# ---------------------------------------------------------------------------------- names
def test_names_list_the_shipped_sessions() -> None:
    names = sample_sessions()
    assert "square/230620202042" in names
    kinds = [name.split("/")[0] for name in names]
    assert kinds.count("square") >= 2 and kinds.count("ivanjko") >= 2
    assert names == sorted(names)
    listed = samples.sample_names()
    assert listed[:4] == ["optiodom:", "optiodom:circular", "optiodom:ivanjko", "optiodom:square"]
    assert [f"optiodom:{name}" for name in names] == listed[4:]


def test_every_shipped_session_reads(cache: Path) -> None:
    """Each name gives a session folder of its path type that the reader accepts whole, with
    the runs the authors' layout puts there."""
    for name in sample_sessions():
        kind, session_id = name.split("/")
        folder = sample_session(name)
        assert folder.parent.name == kind and folder.name == session_id
        assert folder.is_relative_to(cache)
        session = read_session(folder)
        assert session.name == session_id and session.path_type == kind
        if kind == "square":
            assert session.side == 0.75
            assert len(session.select("square", "cw")) == len(session.select("square", "ccw"))
        elif kind == "ivanjko":
            third = session.n_runs // 3
            assert session.holdings() == {"straight": third, "spin cw": third, "spin ccw": third}


def test_whole_set_and_kinds_resolve_to_folders_of_sessions(cache: Path) -> None:
    root = resolve_data("optiodom:")
    assert root.name == "optiodom"
    assert {f"{p.parent.name}/{p.name}" for p in find_sessions(root)} == set(sample_sessions())
    with (root / "published_results.csv").open(encoding="utf-8") as file:
        rows = list(csv.DictReader(file))
    # restricted to the shipped sessions, and every one of them has the authors' OptiOdom row
    assert {f"{r['path']}/{r['session']}" for r in rows} == set(sample_sessions())
    assert {r["session"] for r in rows if r["method"] == "optiodom"} == {
        name.split("/")[1] for name in sample_sessions()
    }
    assert "MIT License" in (root / "LICENSE").read_text(encoding="utf-8")
    assert "Sousa" in (root / "README.md").read_text(encoding="utf-8")
    squares = resolve_data("optiodom:square")
    assert squares == root / "square"
    assert [p.name for p in find_sessions(squares)] == [
        n.split("/")[1] for n in sample_sessions() if n.startswith("square/")
    ]
    # spellings: a trailing slash, the prefix given to sample_session, a plain path unchanged
    assert resolve_data("optiodom:square/") == squares
    assert sample_session("optiodom:square/230620202042") == squares / "230620202042"
    assert resolve_data("some/folder") == Path("some/folder")
    assert resolve_data(Path("optiodom:x")) == Path("optiodom:x")  # a Path is never a name


def test_unknown_names_give_one_line_listing_the_available_ones() -> None:
    with pytest.raises(SpecError) as error:
        resolve_data("optiodom:square/123")
    message = str(error.value)
    assert error.value.field == "data"
    assert "\n" not in message and "optiodom:square/123" in message
    assert all(name in message for name in samples.sample_names())
    with pytest.raises(SpecError, match="names several sessions") as error:
        resolve_data("optiodom:square", session=True, field="data")
    assert "optiodom:square/230620202042" in str(error.value)
    with pytest.raises(SpecError, match="unknown shipped session optiodom:circular/1"):
        sample_session("circular/1")


# ---------------------------------------------------------------------------------- cache
def test_cache_location_follows_xdg(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert samples.cache_dir() == tmp_path / "odomgym"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/cache")  # the XDG rule: ignore it
    assert samples.cache_dir() == Path.home() / ".cache" / "odomgym"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert samples.cache_dir() == Path.home() / ".cache" / "odomgym"


def test_unpacking_is_cached_and_leaves_nothing_behind(cache: Path) -> None:
    folder = sample_session("square/230620202042")
    first = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
    assert sorted(first) == [
        "230620202042_metadata.csv",
        *(f"230620202042_run-{n:02d}.csv" for n in range(1, 7)),
    ]
    assert sample_session("square/230620202042") == folder
    assert {p.name: p.stat().st_mtime_ns for p in folder.iterdir()} == first  # not rewritten
    store = folder.parents[2]
    assert store.name.startswith("samples-") and store.parent == cache
    assert not [p for p in store.rglob(".*")], "no staging folders or temporary files left"


def test_failed_unpacking_leaves_no_partial_session(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An archive that breaks half-way leaves neither the session folder nor the staging
    folder; the next call unpacks it whole."""
    real = samples._extract
    calls = []

    def breaks_on_third(*args: object) -> None:
        calls.append(args)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(samples, "_extract", breaks_on_third)
    with pytest.raises(SpecError, match=r"No space left on device.*XDG_CACHE_HOME"):
        sample_session("ivanjko/250620201618")
    monkeypatch.setattr(samples, "_extract", real)
    store = next(cache.iterdir())
    assert not (store / "optiodom" / "ivanjko" / "250620201618").exists()
    assert not [p for p in store.rglob(".*")]
    assert read_session(sample_session("ivanjko/250620201618")).n_runs == 9


def test_a_session_unpacked_by_another_process_first_is_kept(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The race: between our check and our rename another process renamed its copy into
    place. Ours is discarded and theirs used."""
    real = samples._extract
    target: list[Path] = []

    def meanwhile(tar: object, member: object, session: str, into: Path) -> None:
        real(tar, member, session, into)  # type: ignore[arg-type]
        if not target:
            theirs = into.parent / "optiodom" / "square" / session
            theirs.mkdir(parents=True)
            (theirs / "theirs").write_text("", encoding="utf-8")
            target.append(theirs)

    monkeypatch.setattr(samples, "_extract", meanwhile)
    folder = sample_session("square/230620202144")
    assert folder == target[0] and (folder / "theirs").exists()
    assert not [p for p in next(cache.iterdir()).rglob(".*")]


def test_unwritable_cache_is_a_spec_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("", encoding="utf-8")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    with pytest.raises(SpecError, match=r"cannot unpack the shipped data.*XDG_CACHE_HOME"):
        sample_session("square/230620202042")


# ---------------------------------------------------------------------------------- CLI
def test_cli_calibrate_on_a_shipped_session(
    cache: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--data optiodom:square/230620202042`` reproduces the authors' UMBmark row
    (published_results.csv: b = 0.201458, D_R = 0.083954, D_L = 0.084046)."""
    args = ["calibrate", "umbmark", "--data", "optiodom:square/230620202042"]
    assert main([*args, "--conventions", "optiodom", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["b"] == pytest.approx(0.201458, rel=0.002)
    assert report["dr"] == pytest.approx(0.083954, rel=0.002)
    assert report["dl"] == pytest.approx(0.084046, rel=0.002)


@pytest.mark.parametrize(
    ("argv", "field"),
    [
        (["calibrate", "umbmark", "--data", "optiodom:square/1"], "unknown shipped"),
        (["calibrate", "umbmark", "--data", "optiodom:square"], "names several sessions"),
        (["leaderboard", "--data", "optiodom:nosuch"], "unknown shipped"),
        (["fit-noise", "--data", "optiodom:ivanjko", "optiodom:x"], "unknown shipped"),
        (["diagnose", "optiodom:nosuch", "--robot", "optiodom"], "unknown shipped"),
    ],
)
def test_cli_rejects_unknown_names_on_one_line(
    argv: list[str], field: str, cache: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("odomgym: error: ") and field in err
    assert err.count("\n") == 1 and "optiodom:square/230620202042" in err


def test_cli_leaderboard_and_fit_noise_on_shipped_data(
    cache: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["leaderboard", "--data", "optiodom:", "--methods", "umbmark", "--json"]) == 0
    board = json.loads(capsys.readouterr().out)
    assert board["published"], "published_results.csv found beside the sessions"
    assert main(["fit-noise", "--data", "optiodom:ivanjko", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert {s["session"] for s in report["inputs"]["sessions"]} == {
        n.split("/")[1] for n in sample_sessions() if n.startswith("ivanjko/")
    }
    assert all(s["calibration"] == "published" for s in report["inputs"]["sessions"])


# ---------------------------------------------------------------------------------- packaging
def _package_data_globs() -> list[str]:
    config = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    tool = config["tool"]["setuptools"]
    assert "odomgym.data.samples" in tool["packages"]
    assert "odomgym.data.samples.optiodom" in tool["packages"]
    globs: list[str] = tool["package-data"]["odomgym.data.samples.optiodom"]
    return globs


def test_pyproject_package_data_covers_every_shipped_file() -> None:
    """setuptools globs match one path component per ``*``; every file beside the archives
    must be matched, or a regular install would lack it."""
    globs = _package_data_globs()
    files = sorted(p.relative_to(SHIPPED).as_posix() for p in SHIPPED.rglob("*") if p.is_file())
    assert {"LICENSE", "README.md", "published_results.csv"} <= set(files)

    def matches(name: str, glob: str) -> bool:
        parts, pattern = PurePosixPath(name).parts, PurePosixPath(glob).parts
        return len(parts) == len(pattern) and all(
            fnmatch.fnmatchcase(part, bit) for part, bit in zip(parts, pattern, strict=True)
        )

    for name in files:
        assert any(matches(name, glob) for glob in globs), f"{name} is not in the package data"
    total = sum((SHIPPED / name).stat().st_size for name in files)
    assert total < 3_000_000, f"shipped data grew to {total} bytes"


@pytest.mark.slow
def test_wheel_contains_the_shipped_data(tmp_path: Path) -> None:
    """A regular (non-editable) wheel holds the archives, results, licence and README."""
    pytest.importorskip("setuptools")
    source = tmp_path / "src"
    source.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(REPO / name, source / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in ("odomgym", "envs", "baselines"):
        shutil.copytree(REPO / name, source / name, ignore=ignore)
    command = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation"]
    env = {**os.environ, "PIP_NO_INPUT": "1"}
    subprocess.run([*command, "-q", "-w", str(tmp_path / "dist"), str(source)], check=True, env=env)
    (wheel,) = (tmp_path / "dist").glob("odomgym-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
    prefix = "odomgym/data/samples/optiodom/"
    expected = {prefix + p.name for p in SHIPPED.iterdir() if p.is_file()}
    assert expected <= names
    assert "odomgym/data/samples/__init__.py" in names

"""Real data shipped inside the package: six OptiOdom sessions, reachable by name.

The sessions (Sousa et al., J. Intell. Robot. Syst. 105:39, 2022; MIT licence, see
``optiodom/LICENSE`` and ``optiodom/README.md`` beside this module) are three UMBmark square
sessions, two Ivanjko sessions (straight runs and ±180° spins) and one circular session, with
the authors' ``published_results.csv`` rows for them. Wherever odomgym takes a data folder
(``calibrate --data``, ``leaderboard --data``, ``fit-noise --data``, ``diagnose DATA``) a name
may stand for it:

* ``optiodom:<kind>/<session>`` — one session, e.g. ``optiodom:square/230620202042``;
* ``optiodom:<kind>`` — every shipped session of that path type (``square``, ``ivanjko``,
  ``circular``);
* ``optiodom:`` — all of them, with ``published_results.csv``.

:func:`resolve_data` turns such a name (or an ordinary path) into a folder in the OptiOdom
layout (``<root>/<kind>/<session>/…``, ``<root>/published_results.csv``) that the readers of
:mod:`odomgym.data.optiodom` accept unchanged; :func:`sample_session` and :func:`sample_data`
do the same from Python, :func:`sample_sessions` lists the names.

Why unpacked into a cache rather than read from the package in place: the readers take real
folders (they glob, list and open files by path, and
:func:`odomgym.noise.experiment.published_calibration` finds ``published_results.csv`` two folders
above a session), and the CSV files take 4.65 MB raw but 1.45 MB as one ``.tar.xz`` per
session, so the package ships the archives and each session is unpacked once, on first use,
into ``$XDG_CACHE_HOME/odomgym`` (``~/.cache/odomgym`` when unset or relative). The cache
folder is named after a digest of the shipped files, so a newer package never reads an older
unpacking. Unpacking is atomic: into a temporary folder outside the data tree (in the same
cache folder, so on the same file system), renamed into place only when complete, so
concurrent processes and interrupted runs never see a half-written session.
"""

from __future__ import annotations

import functools
import hashlib
import io
import os
import shutil
import tarfile
import tempfile
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

from odomgym.errors import SpecError
from odomgym.io import atomic_write_bytes

__all__ = [
    "SCHEME",
    "cache_dir",
    "resolve_data",
    "sample_data",
    "sample_names",
    "sample_session",
    "sample_sessions",
]

SCHEME = "optiodom:"
_ARCHIVE = ".tar.xz"
_ROOT_FILES = ("LICENSE", "README.md", "published_results.csv")


def _shipped() -> Traversable:
    return resources.files(__name__) / "optiodom"


@functools.cache
def _archives() -> dict[str, Traversable]:
    """The shipped archives (``<kind>-<session>.tar.xz``) by session name
    (``"<kind>/<session>"``)."""
    found: dict[str, Traversable] = {}
    for item in _shipped().iterdir():
        kind, dash, session = item.name.removesuffix(_ARCHIVE).partition("-")
        if item.name.endswith(_ARCHIVE) and dash and item.is_file():
            found[f"{kind}/{session}"] = item
    return dict(sorted(found.items()))


def sample_sessions() -> list[str]:
    """Names of the shipped sessions, ``"<kind>/<session>"``, sorted (e.g.
    ``"square/230620202042"``); prefix them with ``optiodom:`` on the command line."""
    return list(_archives())


def sample_names() -> list[str]:
    """Every name :func:`resolve_data` accepts: ``optiodom:``, ``optiodom:<kind>`` and
    ``optiodom:<kind>/<session>``."""
    kinds = sorted({name.split("/")[0] for name in _archives()})
    return [SCHEME] + [SCHEME + kind for kind in kinds] + [SCHEME + s for s in _archives()]


def cache_dir() -> Path:
    """Where odomgym unpacks shipped data: ``$XDG_CACHE_HOME/odomgym`` if that is an absolute
    path (the XDG rule), else ``~/.cache/odomgym``."""
    base = os.environ.get("XDG_CACHE_HOME", "")
    root = Path(base) if base and os.path.isabs(base) else Path.home() / ".cache"
    return root / "odomgym"


@functools.cache
def _digest() -> str:
    """A digest of every shipped file: names the cache folder of this package's data."""
    sha = hashlib.sha256()
    for name in _ROOT_FILES:
        sha.update(name.encode() + b"\0" + (_shipped() / name).read_bytes())
    for name, archive in _archives().items():
        sha.update(name.encode() + b"\0" + archive.read_bytes())
    return sha.hexdigest()[:16]


def _normalise(name: str) -> str:
    name = name.removeprefix(SCHEME).strip().strip("/")
    return "/".join(part for part in name.split("/") if part)


def _unknown(name: str, field: str) -> SpecError:
    return SpecError(
        f"unknown shipped data {SCHEME}{name}; available: {', '.join(sample_names())}",
        field=field,
    )


def sample_data(name: str = "", *, field: str = "data") -> Path:
    """The folder a shipped-data name stands for, unpacked into the cache if need be.

    Args:
        name: ``""`` (all sessions: the data set's root, holding ``published_results.csv``),
            a path type (``"square"``: its folder, holding its sessions) or a session
            (``"square/230620202042"``: the session folder); an ``optiodom:`` prefix is
            accepted and ignored.
        field: the field named by errors (the CLI option).

    Raises:
        SpecError: an unknown name (the message lists the available ones), or a cache folder
            that cannot be written.
    """
    key = _normalise(name)
    archives = _archives()
    if key in archives:
        chosen = [key]
    else:
        chosen = [s for s in archives if not key or s.split("/")[0] == key]
        if not chosen:
            raise _unknown(key, field)
    root = cache_dir() / f"samples-{_digest()}" / "optiodom"
    try:
        for file in _ROOT_FILES:
            if not (root / file).is_file():
                atomic_write_bytes(root / file, (_shipped() / file).read_bytes())
        for session in chosen:
            _unpack(archives[session], root / session, staging_in=root.parent)
    except OSError as exc:
        raise SpecError(
            f"cannot unpack the shipped data into {root}: {exc.strerror or exc}; set "
            "XDG_CACHE_HOME to a writable folder",
            field=field,
        ) from None
    return root / key if key else root


def sample_session(name: str, *, field: str = "data") -> Path:
    """The folder of one shipped session (``"square/230620202042"``, see
    :func:`sample_sessions`), unpacked into the cache if need be.

    Raises:
        SpecError: ``name`` is not one shipped session (the message lists them).
    """
    key = _normalise(name)
    if key not in _archives():
        sessions = ", ".join(SCHEME + s for s in _archives())
        if not key or key in {s.split("/")[0] for s in _archives()}:
            message = f"{SCHEME}{key} names several sessions; give one of: {sessions}"
        else:
            message = f"unknown shipped session {SCHEME}{key}; sessions: {sessions}"
        raise SpecError(message, field=field)
    return sample_data(key, field=field)


def resolve_data(
    spec: str | os.PathLike[str], *, field: str = "data", session: bool = False
) -> Path:
    """The folder (or file) a data argument stands for: a shipped-data name
    (``optiodom:…``, see the module docstring) is unpacked and its folder returned; anything
    else is taken as a path, unchanged. With ``session=True`` a name must be one session.

    Every command that takes a data folder resolves it here.
    """
    if isinstance(spec, str) and spec.startswith(SCHEME):
        return sample_session(spec, field=field) if session else sample_data(spec, field=field)
    return Path(spec)


def _unpack(archive: Traversable, target: Path, *, staging_in: Path) -> None:
    """Unpack one session archive (members ``<session>/<file>``) to ``target`` atomically.

    The staging folder lies in ``staging_in``, outside the data tree, so that a reader
    globbing the tree while another process unpacks never sees a partial session.
    """
    if target.is_dir():
        return
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=staging_in))
    try:
        try:
            with tarfile.open(fileobj=io.BytesIO(archive.read_bytes()), mode="r:xz") as tar:
                for member in tar:
                    _extract(tar, member, target.name, staging)
        except (tarfile.TarError, EOFError) as exc:  # no lzma module, or a damaged archive
            raise SpecError(
                f"cannot unpack the shipped archive: {exc}", source=str(archive)
            ) from None
        umask = os.umask(0)
        os.umask(umask)
        staging.chmod(0o777 & ~umask)  # mkdtemp makes 0700
        try:
            staging.rename(target)
        except OSError:
            if not target.is_dir():  # otherwise another process unpacked it first
                raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _extract(tar: tarfile.TarFile, member: tarfile.TarInfo, session: str, into: Path) -> None:
    """Write one archive member ``<session>/<file>`` (a regular file) as ``into/<file>``."""
    folder, _, file = member.name.partition("/")
    safe = bool(file) and "/" not in file and not file.startswith(".")
    handle = tar.extractfile(member) if member.isfile() else None
    if folder != session or not safe or handle is None:
        raise SpecError(
            f"unexpected member {member.name!r} in a shipped archive (expected {session}/<file>)"
        )
    (into / file).write_bytes(handle.read())

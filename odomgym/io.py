"""Atomic file output: a reader never sees a half-written file.

Every file odomgym writes (TOML specs, JSON reports, plots, CSV tables) goes through these
helpers: the content is written to a temporary file in the target's directory and renamed over
the target, which POSIX guarantees is atomic on one filesystem.
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn, TypeVar

T = TypeVar("T")

__all__ = ["atomic_folder", "atomic_write_bytes", "atomic_write_text", "atomic_writer"]


def atomic_writer(path: Path, write: Callable[[Path], None]) -> None:
    """Call ``write(tmp_path)`` and rename ``tmp_path`` over ``path`` only if it succeeded."""
    path = Path(path)
    if path.exists() and not path.is_file():
        raise OSError(
            errno.EINVAL,
            "not a regular file (odomgym writes by renaming a new file over the target, which "
            "would replace this device, pipe, socket or folder)",
            str(path),
        )
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(
            prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent
        )
    except OSError as exc:
        _raise_naming(exc, path)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        write(tmp)
        # mkstemp creates 0600; give the file the permissions an ordinary open() would have.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        with open(tmp, "rb") as handle:  # the data must be on disk before the rename
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        _raise_naming(exc, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _raise_naming(exc: OSError, path: Path) -> NoReturn:
    """Raise ``exc`` naming the file the caller asked for: a failed write() names no file, and
    a temporary file's name means nothing to the user. (Another file's error is raised as it
    is.)"""
    if exc.errno is None or (exc.filename is not None and Path(exc.filename).parent != path.parent):
        raise exc
    raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""

    def write(tmp: Path) -> None:
        tmp.write_text(text, encoding="utf-8")

    atomic_writer(path, write)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""

    def write(tmp: Path) -> None:
        tmp.write_bytes(data)

    atomic_writer(path, write)


def atomic_folder(out: Path, fill: Callable[[Path], T]) -> T:
    """Replace the folder ``out`` by one ``fill(tmp)`` writes, atomically: ``fill`` writes into a
    new temporary sibling folder, which is renamed over ``out`` only if it succeeded (the old
    folder, if any, moved aside first and then removed), so a reader sees the old folder or the
    new one, never a half-written one. Returns what ``fill`` returns.

    Raises:
        OSError: ``out`` exists and is not a folder.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OSError(errno.ENOTDIR, "exists and is not a folder", str(out))
    parent = out.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=parent))
    try:
        result = fill(tmp)
        os.chmod(tmp, 0o755)  # mkdtemp makes 0700; an ordinary folder's permissions
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=parent))
            os.replace(out, old / "x")
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return result

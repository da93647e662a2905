"""Refuse every file opened under the source tree: the installed wheel must be self-sufficient.

``scripts/check_dist.sh`` copies this file into the throwaway venv it installs the wheel into,
next to a ``.pth`` line that imports it at every interpreter start (the ``odomgym`` console
script, ``python -c`` and the worker processes alike). A Python audit hook (PEP 578) then sees
every ``open`` (``builtins.open``, ``io.open``, ``os.open``) and every folder listing; one under
the folder named by ``ODOMGYM_SOURCE_TREE`` is a file the wheel forgot (data, a preset, a
template) that only a source checkout has. It is appended to the file named by
``ODOMGYM_GUARD_LOG`` and refused with ``PermissionError``, so the command fails where it read
it, and the check script fails on a non-empty log even if the command swallowed the error.

Not part of the package: it lives beside the scripts that use it and is never installed by a
user.
"""

from __future__ import annotations

import os
import sys
from typing import Any

_TREE = os.environ.get("ODOMGYM_SOURCE_TREE", "")
_LOG = os.environ.get("ODOMGYM_GUARD_LOG", "")
_EVENTS = frozenset({"open", "os.listdir", "os.scandir"})


def _inside_tree(path: object) -> bool:
    """Whether ``path`` (str, bytes or path-like; a file descriptor is not a path) lies under
    the source tree, after resolving ``..`` and links."""
    if not isinstance(path, str | bytes | os.PathLike):
        return False
    real = os.path.realpath(os.fsdecode(path))
    return real == _TREE or real.startswith(_TREE + os.sep)


def _hook(event: str, args: tuple[Any, ...]) -> None:
    """The audit hook: refuse and log a read under the source tree."""
    if event not in _EVENTS or not args or not _inside_tree(args[0]):
        return
    if _LOG:
        with open(_LOG, "a", encoding="utf-8") as log:  # the log is outside the tree
            log.write(f"{event} {args[0]!r} (pid {os.getpid()}, {sys.argv[0]})\n")
    raise PermissionError(f"check_dist: the installed odomgym read the source tree: {args[0]!r}")


if _TREE:
    _TREE = os.path.realpath(_TREE)
    sys.addaudithook(_hook)

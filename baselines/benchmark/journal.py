"""The benchmark's resume journal: every finished chunk of robots, recorded as it completes."""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from odomgym.baselines.benchmark.config import BenchConfig, config_record
from odomgym.errors import SpecError

__all__ = [
    "Journal",
]


class Journal:
    """Each finished chunk of robots, recorded as it completes (JSON lines), so an interrupted
    benchmark can resume where it stopped.

    Line 1 is the format :attr:`VERSION` and the configuration (a journal of another format or
    configuration is refused in one line, never misread), every further line one finished
    chunk: ``{"robots": [...], "rows": [...]}``, appended, flushed and synced before the next is
    started. A last line cut short by the interruption is ignored. The rows are plain JSON (no
    module paths or pickles), so the move of the benchmark's modules into
    ``odomgym.baselines.benchmark`` (0.2.0) left the format, version 1, as it was.
    """

    VERSION = 1

    def __init__(self, path: Path, config: BenchConfig) -> None:
        self.path = Path(path)
        self.config = config

    def _header(self) -> dict[str, Any]:
        return {"journal": self.VERSION, "config": config_record(self.config)}

    def start(self) -> None:
        """Begin a new journal (replacing any earlier one)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._write(json.dumps(self._header()) + "\n", "w")

    def read(self) -> dict[int, list[dict[str, Any]]]:
        """The recorded rows per robot (empty if there is no journal yet)."""
        if not self.path.exists():
            return {}
        lines = self.path.read_text(encoding="utf-8").splitlines()
        if not lines:
            return {}
        try:
            header = json.loads(lines[0])
        except json.JSONDecodeError as exc:
            raise SpecError(
                f"{self.path}:1: not a benchmark journal ({exc})", field="resume"
            ) from None
        version = header.get("journal") if isinstance(header, dict) else None
        if version != self.VERSION:
            raise SpecError(
                f"{self.path}:1: a benchmark journal of format {version!r}, this odomgym reads "
                f"format {self.VERSION}; run without --resume to start over",
                field="resume",
            )
        if header != self._header():
            then, now = header.get("config"), self._header()["config"]
            if isinstance(then, dict):
                # Named setting by setting, as `train --resume` does: a dump of the whole
                # configuration left the user to find the one that differs.
                keys = sorted(set(then) | set(now), key=str)
                said = "; ".join(
                    f"{k} {then.get(k)!r} then, {now.get(k)!r} now"
                    for k in keys
                    if then.get(k) != now.get(k)
                )
            else:
                said = repr(then)
            raise SpecError(
                f"{self.path}:1: recorded for another benchmark configuration ({said}); run "
                "without --resume to start over, or with the settings it was started with",
                field="resume",
            )
        done: dict[int, list[dict[str, Any]]] = {}
        for number, line in enumerate(lines[1:], start=2):
            try:
                entry = json.loads(line)
                robots, rows = list(entry["robots"]), list(entry["rows"])
            except (json.JSONDecodeError, KeyError, TypeError) as exc:
                if number == len(lines):  # cut short by the interruption: run it again
                    break
                raise SpecError(
                    f"{self.path}:{number}: damaged entry ({exc})", field="resume"
                ) from None
            for robot in robots:
                done[int(robot)] = [r for r in rows if r["robot"] == robot]
        return done

    def record(self, robots: Sequence[int], rows: Sequence[dict[str, Any]]) -> None:
        """Append one finished chunk."""
        self._write(json.dumps({"robots": list(robots), "rows": list(rows)}) + "\n", "a")

    def _write(self, line: str, mode: str) -> None:
        """Write ``line`` to the disk now; if that fails (a full disk), cut the journal back to
        its whole lines and name it in the error."""
        size = self.path.stat().st_size if mode == "a" and self.path.exists() else 0
        try:
            with self.path.open(mode, encoding="utf-8") as f:
                f.write(line)
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.truncate(self.path, size)
            raise OSError(exc.errno, exc.strerror or str(exc), str(self.path)) from exc

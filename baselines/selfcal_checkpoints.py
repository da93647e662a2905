"""The checkpoints of a self-calibration training and its resume (``odomgym train selfcal
--resume``): the SB3 model, its record and the learning-curve rows of every attempt.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from odomgym import interrupt
from odomgym.errors import SpecError
from odomgym.io import atomic_write_text, atomic_writer

__all__ = ["Checkpoints", "write_json"]


class Checkpoints:
    """The checkpoint of an interrupted training in its output folder, and the resume.

    Every ``every`` environment steps (at the start of a rollout, when the last update is
    done) the model — weights, optimizer state, step count, and for DQN the replay buffer —
    is written to ``checkpoint.zip`` (``checkpoint_replay.pkl``) and its record to
    ``checkpoint.json``, each whole by a rename. ``--resume`` loads them and trains on to the
    same total; the settings that shape the model (algorithm, sessions, seed, hyperparameters)
    must match the record. The learning-curve rows logged before the checkpoint are kept in
    ``progress.prev.csv`` and joined with the new ones at the end.

    A resumed run is not bit-identical to an uninterrupted one: the sessions in flight at the
    checkpoint are started afresh (seeded ``seed + steps``), as SB3 keeps no env state.
    """

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.model = folder / "checkpoint.zip"
        self.record = folder / "checkpoint.json"
        self.replay = folder / "checkpoint_replay.pkl"
        self.progress = folder / "progress.csv"
        self.previous = folder / "progress.prev.csv"

    def read(self, settings: dict[str, Any]) -> dict[str, Any]:
        """The record of the checkpoint to resume from; one-line errors when there is none or
        it was made with other settings."""
        if not self.record.exists() or not self.model.exists():
            raise SpecError(
                f"{self.folder}: no checkpoint to resume from (checkpoint.json and "
                "checkpoint.zip); start without --resume",
                field="resume",
            )
        try:
            record = json.loads(self.record.read_text(encoding="utf-8"))
            steps = int(record["steps"])
            saved = dict(record["settings"])
            record["wall_time_s"] = float(record["wall_time_s"])
            record["resumed_at"] = [int(k) for k in record["resumed_at"]]
        except (ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
            raise SpecError(
                f"{self.record}: not a checkpoint record odomgym wrote ({exc})", field="resume"
            ) from exc
        differ = sorted(k for k in set(saved) | set(settings) if saved.get(k) != settings.get(k))
        if differ:
            shown = "; ".join(f"{k} {saved.get(k)!r} then, {settings.get(k)!r} now" for k in differ)
            raise SpecError(
                f"{self.record}: the checkpoint was made with other settings ({shown}); "
                "resume with the same --algo, --envs, --seed and --hyperparams",
                field="resume",
            )
        if steps < 0:
            raise SpecError(f"{self.record}: steps {steps} is negative", field="resume")
        return dict(record)

    def save(self, model: Any, settings: dict[str, Any], extra: dict[str, Any]) -> None:
        """Write the checkpoint of ``model`` now (each file whole, the record last, with
        ``extra`` in it)."""
        # The three files are one checkpoint: a stop between them would pair a new model with
        # an old record, so Ctrl-C/SIGTERM wait until all are written.
        with interrupt.deferred():
            atomic_writer(self.model, model.save)  # the temporary name ends in .zip, as SB3 needs
            if hasattr(model, "save_replay_buffer"):  # off-policy (DQN): its buffer is its data
                atomic_writer(self.replay, model.save_replay_buffer)
            record = {"steps": int(model.num_timesteps), **extra, "settings": settings}
            write_json(self.record, record)

    def keep_progress(self, steps: int) -> None:
        """Before a resume: the learning-curve rows logged up to ``steps`` (of every earlier
        attempt) go to ``progress.prev.csv``; SB3 starts ``progress.csv`` afresh."""
        rows, fields = _csv_rows([self.previous, self.progress])
        rows = [r for r in rows if _timesteps(r) <= steps]
        _write_csv(self.previous, rows, fields)

    def finish(self) -> None:
        """After the final model is written: one ``progress.csv`` of every attempt, and no
        checkpoint left to resume from."""
        if self.previous.exists():
            rows, fields = _csv_rows([self.previous, self.progress])
            _write_csv(self.progress, rows, fields)
        self.clear()

    def clear(self) -> None:
        """No checkpoint left: after a finished training, or at a fresh start in a folder an
        earlier training left one in."""
        for path in (self.record, self.model, self.replay, self.previous):
            path.unlink(missing_ok=True)


def _timesteps(row: dict[str, str]) -> float:
    try:
        return float(row.get("time/total_timesteps") or "inf")
    except ValueError:
        return math.inf


def _csv_rows(paths: Sequence[Path]) -> tuple[list[dict[str, str]], list[str]]:
    import csv

    rows: list[dict[str, str]] = []
    fields: list[str] = []
    for path in paths:
        if not path.exists():
            continue
        with path.open(newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            fields += [k for k in reader.fieldnames or [] if k not in fields]
            rows += list(reader)
    return rows, fields


def _write_csv(path: Path, rows: list[dict[str, str]], fields: list[str]) -> None:
    import csv

    def write(tmp: Path) -> None:
        with tmp.open("w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=fields, restval="")
            writer.writeheader()
            writer.writerows(rows)

    atomic_writer(path, write)


def write_json(path: Path, data: dict[str, Any]) -> None:
    """``data`` as indented JSON, written atomically (a checkpoint record, a policy's metadata)."""
    atomic_write_text(path, json.dumps(data, indent=2) + "\n")

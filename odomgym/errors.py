"""Error types and validation helpers shared by every spec loader.

Why a module of its own: a user who mistypes a TOML field should be told *which* field, in
*which* file and on *which* line — not receive a traceback from deep inside numpy or pymunk.
Every loader raises :class:`SpecError` (a ``ValueError``), whose message carries that context.
"""

from __future__ import annotations

import math
import numbers
import os
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TypeVar

import numpy as np

T = TypeVar("T")


class SpecError(ValueError):
    """A robot, floor, calibration or data specification is invalid.

    The message names the field and, where the value came from a file, the file and line.
    """

    def __init__(self, message: str, *, field: str | None = None, source: str | None = None):
        self.field = field
        self.source = source
        prefix = f"{source}: " if source else ""
        super().__init__(prefix + message)


def first_few(names: Sequence[str], shown: int = 5) -> str:
    """``names`` for a one-line message: the first ``shown`` joined by commas, the rest
    counted (``"a, b, c, d, e and 3 more"``); the refusals of an output folder name what it
    holds this way."""
    text = ", ".join(names[:shown])
    return text + (f" and {len(names) - shown} more" if len(names) > shown else "")


def refuse_repeats(names: Sequence[str], field: str) -> None:
    """Refuse, naming ``field``, a list of names that holds one twice: a benchmark would run
    its cell or method twice and count it as two (``bench skid --presets``, ``bench
    calibrators --methods``, their floors)."""
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise SpecError(f"{', '.join(map(repr, twice))} given twice", field=field)


def raw_line(path: Path, offset: int) -> int:
    """The 1-based line of byte ``offset`` in ``path`` (for errors about raw bytes)."""
    try:
        return path.read_bytes()[:offset].count(b"\n") + 1
    except OSError:
        return 1


def read_spec_toml(path: Path, kind: str) -> dict[str, object]:
    """Parse the ``kind`` TOML file at ``path`` (robot, floor, calibration, vehicle): an
    unreadable file or malformed TOML is a one-line :class:`SpecError` naming the file (and, for
    TOML, the parser's line and column)."""
    import tomllib

    try:
        # utf-8-sig: a byte-order mark (Windows editors write one) is read past, as the CSV
        # readers do; TOML itself forbids it, and tomllib called it an "invalid statement".
        raw = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise SpecError(f"cannot read {kind} file: {exc.strerror}", source=str(path)) from None
    except UnicodeDecodeError as exc:
        line = raw_line(path, exc.start)
        raise SpecError(
            f"line {line}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x}); a {kind} file "
            "is TOML, which is UTF-8",
            source=str(path),
        ) from None
    try:
        return tomllib.loads(raw)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"malformed TOML: {exc}", source=str(path)) from None


def load_named(
    spec: object,
    presets: Mapping[str, T],
    kind: str,
    unknown: Callable[[str], str],
    build: Callable[..., T],
) -> T:
    """The preset called ``spec``, or ``build(data, path=path)`` of the ``kind`` TOML file at
    ``spec``; a name that is neither is a :class:`SpecError` with the message ``unknown(name)``
    (which lists the presets), field ``kind``. A spec object of the presets' own type is
    returned as it is (the envs take one as readily as a name); anything else is refused in
    one line, where a spec passed in had become a file name too long for the system."""
    kinds = tuple({type(value) for value in presets.values()})
    if kinds and isinstance(spec, kinds):
        return spec
    if isinstance(spec, os.PathLike):
        spec = os.fspath(spec)
    if not isinstance(spec, str | Path):
        what = " or ".join(kind_.__name__ for kind_ in kinds) or kind
        raise SpecError(
            f"{kind} must be a preset name, a .toml file or a {what}, got "
            f"{type(spec).__name__} {spec!r:.60}",
            field=kind,
        )
    text = str(spec)
    if text in presets:
        return presets[text]
    path = Path(text)
    if path.suffix != ".toml" and not path.exists():
        raise SpecError(unknown(text), field=kind)
    return build(read_spec_toml(path, kind), path=path)


def refuse_stray_keys(
    data: Mapping[str, object], table: str, path: Path | None, nested: tuple[str, ...] = ()
) -> None:
    """Refuse keys that sit outside the spec file's top-level ``[table]`` when it has one (a
    key above the header): they would be ignored. A skid-steer robot's ``axle_spacing``
    written there gave a differential-drive robot without a word. Other tables of the file
    (``[x]`` beside ``[robot]``) are left alone, except one named like a sub-table of
    ``[table]`` (``nested``: ``[effects.backlash]`` beside ``[robot]``, meant as
    ``[robot.effects.backlash]``), which was ignored as silently.

    Raises:
        SpecError: naming the keys, the first as the field, with its ``file:line``.
    """
    if table not in data:
        return
    for name in nested:
        if _is_table(data.get(name)):
            raise SpecError(
                f"the table [{name}…] sits outside [{table}], where it would be ignored: write "
                f"it as [{table}.{name}…]",
                field=name,
                source=_locate_table(path, name) if path else None,
            )
    stray = [k for k, v in data.items() if k != table and not _is_table(v)]
    if stray:
        raise SpecError(
            f"key(s) {', '.join(repr(k) for k in stray)} sit outside the [{table}] table, where "
            f"they would be ignored: move them under [{table}]",
            field=stray[0],
            source=locate_key(path, stray[0]) if path else None,
        )


def _locate_table(path: Path, name: str) -> str:
    """``"file:line"`` of the first header of a table ``[name…]`` in ``path`` (the file alone
    when the text does not show it)."""
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError):
        return str(path)
    header = re.compile(rf"^\s*\[+\s*{re.escape(name)}\s*[.\]]")
    for number, line in enumerate(lines):
        if header.match(line):
            return f"{path}:{number + 1}"
    return str(path)


def _is_table(value: object) -> bool:
    """Whether a parsed TOML value is a table (``[x]``) or an array of tables (``[[x]]``)."""
    if isinstance(value, Mapping):
        return True
    return isinstance(value, list) and bool(value) and all(isinstance(v, Mapping) for v in value)


def locate_key(path: Path, key: str, *, table: str | None = None, index: int = 0) -> str:
    """Return ``"file:line"`` for the line of ``path`` that assigns ``key``.

    TOML parsers report syntax errors with line numbers but not semantic ones (a negative
    wheelbase parses fine), so semantic errors find their line by a textual search: the first
    assignment of ``key`` in the file or, with ``table``, the first one inside the ``index``-th
    ``[[table]]`` (or ``[[<parent>.table]]``) entry of an array of tables. Falls back to the
    file alone (or the entry's header line) when the text does not show it.
    """
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError:
        return str(path)
    leaf = key.split(".")[-1]
    pattern = re.compile(rf"^\s*{re.escape(leaf)}\s*=")
    start, stop = 0, len(lines)
    if table is not None:
        header = re.compile(rf"^\s*\[\[\s*(?:[\w-]+\.)*{re.escape(table)}\s*\]\]")
        entries = [n for n, line in enumerate(lines) if header.match(line)]
        if index >= len(entries):
            return str(path)
        start = entries[index]
        following = [
            n for n, line in enumerate(lines) if n > start and line.lstrip().startswith("[")
        ]
        stop = following[0] if following else len(lines)
    for number in range(start, stop):
        if pattern.match(lines[number]):
            return f"{path}:{number + 1}"
    return f"{path}:{start + 1}" if table is not None else str(path)


def require_positive(name: str, value: object, *, source: str | None = None) -> float:
    """Return ``value`` as a finite float > 0, or raise :class:`SpecError` naming ``name``."""
    number = require_finite(name, value, source=source)
    if number <= 0.0:
        raise SpecError(f"{name} must be > 0, got {number!r}", field=name, source=source)
    return number


def plain_number(value: object) -> object:
    """``value`` as a Python ``float`` (``int`` for an integer) when it is a NumPy number
    scalar, else unchanged. Why: values computed with NumPy arrive as ``np.float32`` or
    ``np.int64``, which are numbers (:class:`numbers.Real`), and a spec stores what it is given
    (a NumPy scalar would not save as TOML)."""
    if isinstance(value, bool | int | float) or not isinstance(value, numbers.Real):
        return value  # NumPy's bool_ is no numbers.Real: refused as a bool is
    return int(value) if isinstance(value, numbers.Integral) else float(value)


def require_finite(name: str, value: object, *, source: str | None = None) -> float:
    """Return ``value`` as a finite float, or raise :class:`SpecError` naming ``name``.

    A NumPy number scalar is refused here, saying how to pass it: a spec that stores what it is
    given would keep it, and it would not save as TOML. The specs people build from computed
    values, :class:`~odomgym.robot.RobotSpec` and
    :class:`~odomgym.odometry.calibration.Calibration`, convert theirs first
    (:func:`plain_number`)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        hint = (
            " (a NumPy value: give float(value))"
            if isinstance(value, numbers.Real) and not isinstance(value, bool)
            else ""
        )
        raise SpecError(
            f"{name} must be a number{hint}, got {type(value).__name__} {value!r}",
            field=name,
            source=source,
        )
    number = float(value)
    if not math.isfinite(number):
        raise SpecError(f"{name} must be finite, got {number!r}", field=name, source=source)
    return number


def require_bool(name: str, value: object, *, source: str | None = None) -> bool:
    """Return ``value`` as a ``bool`` if it is one (NumPy's included), else raise
    :class:`SpecError` naming ``name``. Why: ``bool("no")`` is True, so an option given as a
    string (``ipec="no"``) silently meant yes."""
    if isinstance(value, bool | np.bool_):
        return bool(value)
    raise SpecError(
        f"{name} must be True or False, got {type(value).__name__} {value!r:.40}",
        field=name,
        source=source,
    )


def require_known_options(options: Mapping[str, object], known: tuple[str, ...], env: str) -> None:
    """Refuse ``reset`` options ``env`` does not read, naming the first and the known ones: a
    misspelt ``{"drection": "ccw"}`` was ignored, and the episode drove the default way."""
    unknown = [key for key in options if key not in known]
    if unknown:
        said = ", ".join(known) if known else "none"
        raise SpecError(
            f"unknown reset option {unknown[0]!r} of {env}; its options: {said}",
            field=f"options.{unknown[0]}",
        )


def require_range(
    name: str, value: object, low: float, high: float, *, source: str | None = None
) -> float:
    """Return ``value`` as a float in the closed interval [low, high], or raise."""
    number = require_finite(name, value, source=source)
    if not low <= number <= high:
        raise SpecError(
            f"{name} must lie in [{low}, {high}], got {number!r}", field=name, source=source
        )
    return number


def require_count(name: str, value: object, minimum: int = 0) -> int:
    """``value`` as a whole number >= ``minimum``, or :class:`SpecError` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise SpecError(
            f"{name} must be a whole number, got {type(value).__name__} {value!r}", field=name
        )
    if int(value) < minimum:
        raise SpecError(f"{name} must be >= {minimum}, got {value}", field=name)
    return int(value)

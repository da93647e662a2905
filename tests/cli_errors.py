"""What every command-line test checks of a refused input: one line, no traceback, no work."""

from __future__ import annotations

import pytest


def one_line_error(capsys: pytest.CaptureFixture[str], *needles: str) -> str:
    """The command failed with one line naming what was wrong, printed nothing else (so no
    work was done: every command prints its results only after the work), and no traceback;
    returns the line, which holds every one of ``needles``."""
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("odomgym: error: "), err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]

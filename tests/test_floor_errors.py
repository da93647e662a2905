"""Floor-file errors point at the line inside the entry they concern."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import pytest

import odomgym.envs  # noqa: F401  (registers the envs)
from odomgym.errors import SpecError
from odomgym.floor import load_floor

TWO_PATCHES = """\
[floor]
friction = 0.8

[[floor.patches]]
x_min = 0.0
y_min = 0.0
x_max = 1.0
y_max = 1.0
friction = 0.5

[[floor.patches]]
x_min = 0.0
y_min = 0.0
x_max = {x_max}
y_max = 1.0
friction = {friction}
"""


def _write(tmp_path: Path, **values: float) -> Path:
    path = tmp_path / "floor.toml"
    path.write_text(TWO_PATCHES.format(**values), encoding="utf-8")
    return path


def test_error_in_second_patch_names_its_own_line(tmp_path: Path) -> None:
    # The floor's own `friction` is on line 2 and the first patch's on line 9: the error is the
    # second patch's, on line 16.
    path = _write(tmp_path, x_max=1.0, friction=0)
    with pytest.raises(SpecError, match=r"floor\.toml:16: patches\[1\]\.friction must be > 0"):
        load_floor(path)


def test_empty_patch_rectangle_names_the_bound(tmp_path: Path) -> None:
    path = _write(tmp_path, x_max=-1.0, friction=0.3)
    with pytest.raises(SpecError, match=r"floor\.toml:14: patches\[1\]\.x_max must exceed x_min"):
        load_floor(path)


def test_envs_accept_a_pathlib_path(tmp_path: Path) -> None:
    path = _write(tmp_path, x_max=2.0, friction=0.3)
    env = gym.make("UMBmarkSquare-v0", floor=path)
    assert env.unwrapped.floor.patches[1].friction == 0.3
    env.close()

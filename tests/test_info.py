"""A step's lazily made ``info`` reads as the dict made at once (envs/info.py)."""

from __future__ import annotations

import copy
import pickle
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import odomgym  # noqa: F401  (registers the envs)
from odomgym.envs.info import LazyInfo

ENTRIES = {"true_pose": np.arange(3.0), "segment": 2, "reward_terms": {"time": -0.001}}


def _lazy() -> LazyInfo:
    return LazyInfo(lambda: {key: value for key, value in ENTRIES.items()})


def _same(a: Any, b: Any) -> bool:
    return a.keys() == b.keys() and all(
        np.array_equal(a[k], b[k]) if isinstance(a[k], np.ndarray) else a[k] == b[k] for k in a
    )


@pytest.mark.parametrize(
    "read",
    [
        lambda info: dict(info),
        lambda info: {**info},
        lambda info: info.copy(),
        lambda info: copy.copy(info),
        lambda info: copy.deepcopy(info),
        lambda info: pickle.loads(pickle.dumps(info)),
        lambda info: dict(info.items()),
        lambda info: {key: info[key] for key in info},
        lambda info: {key: info.get(key) for key in list(info.keys())},
        lambda info: dict(zip(info.keys(), info.values(), strict=True)),
        lambda info: info | {},
        lambda info: {} | info,
    ],
)
def test_every_way_of_reading_sees_the_entries(read: Any) -> None:
    out = read(_lazy())
    assert _same(out, ENTRIES)
    assert type(out) is dict or isinstance(out, LazyInfo)


def test_size_membership_text_and_equality_are_those_of_the_dict() -> None:
    info = _lazy()
    assert len(_lazy()) == 3
    assert "segment" in _lazy() and "return_error" not in _lazy()
    assert list(reversed(_lazy())) == list(reversed(ENTRIES))
    assert repr(_lazy()) == repr(ENTRIES)
    assert _lazy() == _lazy() and not (_lazy() != _lazy())
    assert {"segment": 2} != info and info == dict(info)
    assert isinstance(info, dict)


def test_writes_come_after_the_made_entries() -> None:
    """A wrapper adding an entry first (RecordEpisodeStatistics' "episode") sees it added to
    the made entries, in the order an eager dict would have them."""
    info = _lazy()
    info["episode"] = {"r": 1.0}
    assert list(info) == [*ENTRIES, "episode"]
    info = _lazy()
    info.update(extra=1)
    assert list(info) == [*ENTRIES, "extra"]
    assert _lazy().setdefault("segment", 5) == 2
    assert _lazy().pop("segment") == 2
    info = _lazy()
    del info["segment"]
    assert "segment" not in info
    info = _lazy()
    info |= {"x": 1}
    assert list(info) == [*ENTRIES, "x"]
    info = _lazy()
    info.clear()
    assert info == {}


def test_entries_are_made_once_and_only_when_read() -> None:
    calls: list[int] = []

    def make() -> dict[str, Any]:
        calls.append(1)
        return dict(ENTRIES)

    info = LazyInfo(make)
    assert calls == []
    _ = info["segment"], info["true_pose"], len(info)
    assert calls == [1]


def test_a_step_info_read_later_is_the_one_read_at_its_step() -> None:
    """Through gymnasium.make: an info read after many later steps (and a reset) equals the
    info of a twin env read at once; its entries depend on nothing that changes afterwards."""
    env, twin = (gym.make("UMBmarkSquare-v0", covariance_k=(0.001, 0.001)) for _ in range(2))
    env.reset(seed=1)
    twin.reset(seed=1)
    rng = np.random.default_rng(0)
    unread, read_at_once = [], []
    for _ in range(40):
        action = rng.uniform(-1.0, 1.0, 2).astype(np.float32)
        unread.append(env.step(action)[4])
        read_at_once.append(copy.deepcopy(dict(twin.step(action)[4])))
    env.reset(seed=2)
    for lazy, eager in zip(unread, read_at_once, strict=True):
        assert isinstance(lazy, LazyInfo)
        assert _same(lazy, eager)
        assert lazy["odom_covariance"].shape == (3, 3)

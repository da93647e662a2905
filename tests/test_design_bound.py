"""``benchmarks/design_bound.py``: the design enumeration and its loss against direct
arithmetic, and a small end-to-end run (the measured study is in docs/selfcal.md)."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest


def _load() -> ModuleType:
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "design_bound.py"
    spec = importlib.util.spec_from_file_location("design_bound", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


design = _load()


def test_every_multiset_of_menu_items_once() -> None:
    items = len(design.ITEMS)
    for budget in (1, 3, 8):
        counts = design.all_designs(budget)
        assert len(counts) == math.comb(budget + items - 1, items - 1)
        assert np.all(counts.sum(axis=1) == budget)
        assert len({tuple(row) for row in counts}) == len(counts)


def test_design_loss_is_the_trace_of_the_weighted_posterior_covariance() -> None:
    rng = np.random.default_rng(0)
    items = len(design.ITEMS)
    a = rng.standard_normal((items, 3, 2))
    info = a @ a.transpose(0, 2, 1)  # rank-2 information of each item, as a run's can be
    prior = np.diag([1e4, 2e4, 3e3])
    w = rng.standard_normal((2, 3))
    weight = w.T @ w
    counts = design.all_designs(3)[::7]
    loss = design.design_loss(counts, info, weight, prior)
    for row, value in zip(counts, loss, strict=True):
        cov = np.linalg.inv(prior + sum(n * info[i] for i, n in enumerate(row)))
        assert value == pytest.approx(np.trace(weight @ cov), rel=1e-10)


def test_schedules_by_name() -> None:
    counts = design.counts_of(["square4-cw", "straight4", "square4-cw"])
    assert counts.sum() == 3 and counts[design.ITEMS.index("square4-cw")] == 2
    assert design.interleaved(counts) == ["square4-cw", "straight4", "square4-cw"]
    assert design.scripted_schedule(8) == ["square4-cw", "square4-ccw", "straight4"] + [
        "square4-cw",
        "square4-ccw",
    ] * 2 + ["square4-cw"]


def test_a_small_study_end_to_end(capsys: pytest.CaptureFixture[str]) -> None:
    """Four robots on ``concrete``, 3 runs, driven: the predicted miss of the best schedule
    is the least of all (the scripted schedule's rank is reported against it), and every
    driven schedule has an of-oracle figure."""
    argv = ["--robots", "4", "--info-robots", "2", "--floor", "concrete", "--budget", "3"]
    assert design.main([*argv, "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    (record,) = [line for line in lines if "floor" in line]
    predicted = record["predicted_rms_mm"]
    assert predicted["best"] <= min(predicted.values())
    assert record["rank_of_scripted"] >= 1 and record["designs"] == math.comb(11, 8)
    assert set(record["of_oracle"]) == {"best", "scripted", "squares"}
    assert all(0.0 < v < 5.0 for v in record["of_oracle"].values())
    assert record["room_over_scripted_median"] >= 1.0
    with pytest.raises(SystemExit):
        design.main(["--robots", "2", "--info-robots", "3"])

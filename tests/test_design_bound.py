"""``benchmarks/design_bound.py``: the design enumeration and its loss against direct
arithmetic, and a small end-to-end run (the measured study is in docs/selfcal.md)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from benchmark_module import load_benchmark

design = load_benchmark("design_bound")


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


@pytest.mark.slow
def test_a_small_study_end_to_end(capsys: pytest.CaptureFixture[str]) -> None:
    """Four robots on ``concrete``, 3 runs, driven: a JSON record with every schedule's
    of-oracle figure (a calibration that helps: between 10 % and 500 % of the oracle), and
    the scripted schedule driven by name is ``selfcal_scripted`` itself — what pairs the
    study's rows with the benchmark's. Bad arguments are the parser's one-line errors."""
    from odomgym.baselines.selfcal import SelfCalScripted
    from odomgym.baselines.validation import calibrate_in_simulation
    from odomgym.floor import FLOORS
    from odomgym.robot import PRESETS

    argv = ["--robots", "4", "--info-robots", "2", "--floor", "concrete", "--budget", "3"]
    assert design.main([*argv, "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    (record,) = [line for line in lines if "floor" in line]
    assert record["designs"] == math.comb(11, 8)
    assert set(record["of_oracle"]) == {"best", "scripted", "squares"}
    assert all(0.1 < v < 5.0 for v in record["of_oracle"].values())
    robot = PRESETS["labmate"].with_errors(1.004, 0.98, 1.01)
    for budget in (3, 8):
        results = [
            calibrate_in_simulation(c, robot, FLOORS["concrete"], seed=2).result.calibration
            for c in (
                SelfCalScripted(budget),
                SelfCalScripted(budget, schedule=design.scripted_schedule(budget)),
            )
        ]
        assert results[0] == results[1]
    for bad in (["--robots", "2", "--info-robots", "3"], ["--budget", "21"], ["--floor", "ice"]):
        with pytest.raises(SystemExit):
            design.main(bad)

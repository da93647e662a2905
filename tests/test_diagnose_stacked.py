"""The stacked paths of ``odomgym diagnose`` give every run's numbers bit for bit as run by run.

A systematic evaluation replays a thread's share of the runs stacked end to end
(:func:`odomgym.diagnose.replay.replay_stacked`) and scores them in one compiled call
(:func:`odomgym.diagnose.likelihood.score_stacked`); the open-loop fits do the same with their
alignment (:meth:`odomgym.diagnose.openloop.OpenLoopData.stacked_residuals`). Each is checked
here against the run-by-run path it replaced: equality of the bytes, not a tolerance, with
every effect whose replay stacks, effects that restart per run (backlash's play, the
acceleration modulator's gradient), crab angles, wheel jumps, held gains and every thread count.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping

import numpy as np
import pytest
from alien_robot import generate_session

from odomgym.diagnose.fit import Dataset, _held_gains, close_thread_pool, evaluate
from odomgym.diagnose.likelihood import FilterInputs, SensorNoise, run_residual, run_scores
from odomgym.diagnose.nuisances import SessionNuisance
from odomgym.diagnose.openloop import (
    OpenLoopData,
    _measured_minus,
    _pairwise_sum,
    _residual,
    _stacked_open_loop_residuals,
    _StackedRuns,
)
from odomgym.diagnose.replay import Replay, replay_run, stackable
from odomgym.effects import EFFECTS, Effect, Parameter, ReplayArrays, register_effect
from odomgym.effects.discovered import DiscoveredTerms
from odomgym.effects.transmission import play_operator
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

MODEL = RobotSpec(wheel_diameter=0.084, wheelbase=0.2, ticks_per_rev=2796.8)
SENSOR = SensorNoise(0.002, 0.005)
FIELDS = ("pose", "tracked", "travel", "ds", "dtheta")


def _specs() -> dict[str, RobotSpec]:
    """Models with every stage that stacks: geometry, backlash (restarts per run), the
    grammar's terms (the acceleration modulator restarts per run), turn skid, skid track and
    speed, a wheel toe (a crab angle: the wheel gains compute their own cosines), bumps (wheel
    jumps: a second filter pass) and the tracked-point offset (the measurement stage)."""
    terms = {"right_sin1": 0.01, "left_cos2": -0.004, "left_accel": 0.02, "yaw_lateral": 0.03}
    grammar = DiscoveredTerms(list(terms)).write(MODEL, terms)
    spec = EFFECTS["backlash"].write(grammar, {"angle": 0.01})
    spec = EFFECTS["turn_skid"].write(spec, {"gain": 0.3})
    spec = EFFECTS["wheelbase"].write(spec, {"e_b": 1.01})
    skid = EFFECTS["skid_track"].write(spec, {"excess": 0.2, "lambda_half": 2.0})
    skid = EFFECTS["skid_speed"].write(skid, {"gain": 0.05})
    crab = EFFECTS["wheel_toe"].write(spec, {"angle": 0.01})
    crab = EFFECTS["gt_sensor_offset"].write(crab, {"dx": 0.01, "dy": -0.005})
    bumps = EFFECTS["floor_bumps"].write(skid, {"rate": 0.3, "heading_jump": 0.004})
    bumps = EFFECTS["floor_roughness"].write(bumps, {"k_left": 3e-4, "k_right": 2e-4})
    return {"nominal": MODEL, "grammar": spec, "skid": skid, "crab": crab, "bumps": bumps}


@pytest.fixture(scope="module")
def runs() -> list:  # type: ignore[type-arg]
    return generate_session(
        {"out_of_round": {"value": 0.01, "phase": 1.0}}, np.random.default_rng(11)
    )[:5]


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def test_every_catalogue_effect_but_user_ones_replays_stacked() -> None:
    """The catalogue's effects all stack (a user's effect does not unless it says so)."""
    assert all(effect.replays_stacked() for effect in EFFECTS.values())
    assert all(stackable(spec) for spec in _specs().values())


@pytest.mark.parametrize("name", list(_specs()))
def test_stacked_replays_are_each_runs_replay_bit_for_bit(runs: list, name: str) -> None:  # type: ignore[type-arg]
    """All runs, and contiguous shares of them, replayed stacked: each run's poses, travel and
    increments are the bytes of :func:`replay_run` on that run alone."""
    spec = _specs()[name]
    data = Dataset.of(runs, 0.25)
    alone = [replay_run(run, spec) for run in runs]
    for index in (range(len(runs)), range(1, 4), range(3, 5)):
        for j, rep in zip(index, data.replays(spec, index), strict=True):
            for f in FIELDS:
                assert _same(getattr(rep, f), getattr(alone[j], f)), (name, index, j, f)


def test_backlash_restarts_engaged_at_every_stacked_run() -> None:
    """The play operator over runs stacked is the operator over each run alone."""
    rng = np.random.default_rng(3)
    parts = [rng.normal(0.0, 0.01, (n, 2)) for n in (7, 1, 30, 12)]
    width, gap = np.array([0.02, 0.03]), np.array([0.01, 0.015])
    bounds = np.cumsum([0] + [len(p) for p in parts]).astype(np.int64)
    stacked = play_operator(np.concatenate(parts), width, gap, bounds)
    alone = np.concatenate([play_operator(p, width, gap) for p in parts])
    assert _same(stacked, alone)


@pytest.mark.parametrize("threads", ["1", "2", "3"])
def test_stacked_scores_are_run_scores_bit_for_bit(
    runs: list,  # type: ignore[type-arg]
    threads: str,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A systematic evaluation (each thread's share stacked) gives each run the
    log-likelihood and whitened innovations of :func:`run_scores` on that run alone, with the
    gains of its own replay and with gains held from another model, on one thread, two and
    three."""
    monkeypatch.setenv("ODOMGYM_THREADS", threads)
    close_thread_pool()
    data = Dataset.of(runs, 0.25)
    try:
        for name, spec in _specs().items():
            other = EFFECTS["wheelbase"].write(spec, {"e_b": 0.98})
            held = _held_gains(data, other)
            for gains in (None, held):
                for whitened in (True, False):
                    ev = evaluate(data, spec, SENSOR, whitened=whitened, gains=gains)
                    for j, run in enumerate(runs):
                        rep = replay_run(run, spec)
                        mask = data.masks[j]
                        kept = (
                            None
                            if gains is None
                            else FilterInputs(run_residual(run, rep, mask), gains[j])
                        )
                        loglik, white = run_scores(
                            run, rep, spec, SENSOR, mask, whitened=whitened, kept=kept
                        )
                        assert ev.loglik[j].tobytes() == np.float64(loglik).tobytes(), name
                        if whitened:
                            assert white is not None and _same(ev.whitened[j], white), name
                    assert len(ev.whitened) == (len(runs) if whitened else 0)
    finally:
        close_thread_pool()


class _RunSum(Effect):
    """A user's effect that reads a whole run: the wheels slip by a share of the rotation
    summed since the run began (a cumulative sum, which stacked runs would carry over)."""

    name = "test_run_sum"
    parameters = (Parameter("share", "1/rad", 0.0, -1.0, 1.0, 0.01, "slip per rad turned"),)

    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        if stage == "transmission":
            arrays.wheel = arrays.wheel * (1.0 + values["share"] * np.cumsum(arrays.wheel, 0))


@pytest.fixture
def run_sum() -> Iterator[Effect]:
    effect = register_effect(_RunSum())
    try:
        yield effect
    finally:
        EFFECTS.pop(effect.name, None)


def test_a_user_effect_that_reads_whole_runs_is_replayed_run_by_run(
    runs: list,  # type: ignore[type-arg]
    run_sum: Effect,
) -> None:
    """An effect that does not declare ``stacked_replay`` keeps its own run: a spec carrying it
    is replayed run by run, each run's numbers those of the run alone."""
    spec = run_sum.write(_specs()["grammar"], {"share": 0.001})
    assert not run_sum.replays_stacked() and not stackable(spec)
    data = Dataset.of(runs, 0.25)
    ev = evaluate(data, spec, SENSOR)
    for j, run in enumerate(runs):
        rep = replay_run(run, spec)
        for f in FIELDS:
            assert _same(getattr(ev.replays[j], f), getattr(rep, f))
        loglik, _ = run_scores(run, rep, spec, SENSOR, data.masks[j], whitened=False)
        assert ev.loglik[j] == loglik


def test_compiled_pairwise_sum_is_numpys_sum_bit_for_bit() -> None:
    """:func:`~odomgym.diagnose.openloop._pairwise_sum` is ``numpy.sum`` for every length
    through the blocks of 8 and 128 and the halving above them, and for any start (never
    called on nothing: its empty sum is −0.0, numpy's +0.0)."""
    rng = np.random.default_rng(7)
    for n in [*range(1, 300), 511, 1000, 4097, 20001]:
        x = rng.standard_normal(n + 3) * 10.0 ** rng.uniform(-6, 6, n + 3)
        assert np.float64(_pairwise_sum(x, 0, n)).tobytes() == np.sum(x[:n]).tobytes()
        assert np.float64(_pairwise_sum(x, 3, n)).tobytes() == np.sum(x[3 : 3 + n]).tobytes()


@pytest.mark.parametrize("rate", [10.0, 200.0])
def test_stacked_open_loop_residuals_are_per_run_bit_for_bit(rate: float) -> None:
    """The open-loop residuals of all runs from one stacked replay are each run's
    :func:`~odomgym.diagnose.openloop._residual`: without nuisances, with zero ones and with a
    time offset, a tracked-point offset and a yaw, after the stacks were evicted, and in a
    subset; at 10 Hz and at 200 Hz (the alignment's second then holds 200 samples, past
    numpy's pairwise block of 128)."""
    runs = generate_session(
        {"out_of_round": {"value": 0.01, "phase": 1.0}},
        np.random.default_rng(13),
        log_rate_hz=rate,
    )[:4]
    for run in runs[1:3]:  # sessions of two runs each
        run.meta["session"] = "b"
    data = OpenLoopData(runs, 0.25, MODEL.wheelbase)
    sessions = data.sessions
    cases: list[dict[str, SessionNuisance | None]] = [
        {s: None for s in sessions},
        {s: SessionNuisance(s).with_values([0.0, 0.0, 0.0, 0.0]) for s in sessions},
    ]
    for k, tau in enumerate([0.04, -0.03, 0.11, 0.04, 0.0, -0.2]):  # more than are kept
        cases.append(
            {
                s: SessionNuisance(s, frame=True).with_values(
                    [tau * (i + 1), 0.01 * k, -0.004, 0.02 - 0.01 * i]
                )
                for i, s in enumerate(sorted(set(sessions)))
            }
        )
    for spec in _specs().values():
        for case in cases:
            per_run = [case[s] for s in sessions]
            stacked = data.stacked_residuals(spec, per_run)
            assert stacked is not None
            for j in range(len(runs)):
                assert _same(stacked[j], _residual(data, j, spec, per_run[j]))
            part = data.subset([1, 3])
            inside = part.stacked_residuals(spec, [per_run[1], per_run[3]])
            assert inside is not None
            assert _same(inside[1], _residual(data, 3, spec, per_run[3]))


def test_the_stacked_alignment_turns_by_numpys_arctan2() -> None:
    """The alignment's turn is numpy's ``arctan2`` of the mean sine and cosine, as
    :func:`~odomgym.diagnose.openloop.aligned_prediction` computes it, not libm's ``atan2``
    (they differ in the last bit for about one pair in 20 000): runs whose window holds a
    single measured heading, off the prediction by an angle where the two differ, get each
    run's residuals to the last bit."""
    rng = np.random.default_rng(1)
    angles = rng.uniform(-0.01, 0.01, 100_000)
    differ = [
        d
        for d in angles[:20_000]
        if np.arctan2(math.sin(d), math.cos(d)) != math.atan2(math.sin(d), math.cos(d))
    ]
    if not differ:
        pytest.skip("numpy's arctan2 is libm's atan2 on this machine")
    t = np.arange(60) * 0.05
    built, replays = [], []
    for d in differ[:2]:
        tracked = np.stack([0.1 * t, 0.02 * t, np.zeros_like(t)], axis=1)
        measured = tracked + np.array([0.001, -0.002, 0.0])
        measured[:, 2] = np.nan
        measured[0, 2] = d  # the window's one heading
        measured[30:, 2] = d + 0.001
        counts = np.zeros((len(t), 2), dtype=np.int64)
        built.append(Run("straight", t, counts, measured, meta={"session": "s"}))
        zeros = np.zeros(len(t) - 1)
        replays.append(Replay(tracked, tracked, np.zeros((len(t) - 1, 2)), zeros, zeros, 0.2))
    data = OpenLoopData(built, 0.25, MODEL.wheelbase)
    samples = np.array([0, len(t), 2 * len(t)], dtype=np.int64)
    out = _stacked_open_loop_residuals(
        np.concatenate([r.true_pose for r in built]),
        np.concatenate([r.tracked for r in replays]),
        _StackedRuns.of(data),
        samples,
        float(data.length),
    )
    rows = _StackedRuns.of(data).rows
    for j, (run, rep) in enumerate(zip(built, replays, strict=True)):
        reference = _residual(data, j, MODEL, None, _measured_minus(run, rep))
        assert len(reference) > 0
        assert _same(out[rows[j] : rows[j + 1]], reference)


def test_the_flag_counts_only_in_the_class_that_defines_the_replay() -> None:
    """A subclass that overrides a stacking effect's replay without saying so again is not
    stacked; one that keeps the replay it inherits, or says so, is; an effect without a replay
    of its own has nothing to stack."""
    from odomgym.effects import Backlash

    class Reread(Backlash):
        def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
            super().replay(stage, values, arrays)

    class Said(Reread):
        stacked_replay = True

        def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
            super().replay(stage, values, arrays)

    class Kept(Backlash):
        pass

    assert not Reread.replays_stacked()
    assert Said.replays_stacked() and Kept.replays_stacked() and Backlash.replays_stacked()
    assert EFFECTS["wheelbase"].replays_stacked()  # geometry: no replay of its own

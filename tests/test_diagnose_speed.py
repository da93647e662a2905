"""The fast paths of ``odomgym diagnose`` give every number bit for bit as the plain ones.

Each speed-up of the workflow (one filter pass for both scores, cached evaluations, compiled
replay stages) is checked here against the slower path it replaced, kept as the reference:
equality of the bytes, not a tolerance. The threaded evaluation's identity is tested in
``tests/test_discover.py``.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest
from alien_robot import generate_session

from odomgym.diagnose import fit as fit_module
from odomgym.diagnose import openloop as openloop_module
from odomgym.diagnose.discover import library_jacobian
from odomgym.diagnose.fit import (
    Dataset,
    _fixed_replays,
    _held_gains,
    balanced_shares,
    close_thread_pool,
    evaluate,
    fit_noise,
    whitened_stack,
)
from odomgym.diagnose.likelihood import (
    SensorNoise,
    _filter,
    _gauss_update,
    _model_arrays,
    _pose_residual,
    _update3,
    _wheel_gains,
    run_likelihood,
    run_residual,
    run_scores,
    stacked_process_noise,
)
from odomgym.diagnose.nuisances import SessionNuisance
from odomgym.diagnose.openloop import (
    _KEPT_INPUTS,
    OpenLoopData,
    _errors,
    _residual,
    pose_errors,
)
from odomgym.diagnose.replay import _headings, _measure, _positions, _start_pose, replay_run
from odomgym.diagnose.stats import _null_max, sign_matrix, studentised
from odomgym.diagnose.where import RunResidual
from odomgym.effects import EFFECTS, ReplayArrays
from odomgym.effects.discovered import TERMS, DiscoveredTerms, body_modulator, wheel_modulator
from odomgym.effects.registry import scale_columns
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec
from odomgym.workers import run_tasks

MODEL = RobotSpec(wheel_diameter=0.084, wheelbase=0.2, ticks_per_rev=2796.8)
SENSOR = SensorNoise(0.002, 0.005)


def _bits(value: float) -> bytes:
    return np.float64(value).tobytes()


def _numpy_terms(values: dict[str, float], arrays: ReplayArrays) -> tuple[np.ndarray, ...]:
    """The grammar's replay as numpy expressions, one array per term (the path the compiled
    kernels replaced): wheel rotations after the transmission stage, crab and dθ after the
    body stage (which sees ``arrays.ds`` and ``arrays.dtheta`` as given)."""
    safe = np.where(arrays.dt > 0, arrays.dt, np.inf)
    speed = arrays.wheel * arrays.radius[None, :] / safe[:, None]
    if len(arrays.dt) < 2:
        accel = np.zeros_like(speed)
    else:
        mid = np.cumsum(arrays.dt) - 0.5 * arrays.dt
        increasing = np.all(np.diff(mid) > 0)
        accel = np.gradient(np.abs(speed), mid, axis=0) if increasing else 0 * speed
    factor = np.ones_like(arrays.wheel)
    crab = np.zeros_like(arrays.dt)
    yaw = np.ones_like(arrays.dt)
    v, omega = arrays.ds / safe, arrays.dtheta / safe
    for name, c in values.items():
        term = next(t for t in TERMS if t.name == name)
        if term.wheel:
            col = 0 if term.channel == "left" else 1
            m = wheel_modulator(term.modulator, speed, accel, arrays.angle, arrays.time)
            factor[:, col] += c * m[:, col]
        elif term.channel == "crab":
            crab += c * body_modulator(term.modulator, v, omega, arrays.time, arrays.travel)
        else:
            yaw += c * body_modulator(term.modulator, v, omega, arrays.time, arrays.travel)
    return arrays.wheel * factor, arrays.crab + crab, arrays.dtheta * yaw


def test_one_filter_pass_gives_both_scores_bit_identical() -> None:
    """:func:`run_scores` runs the filter once when no wheel jump is expected and twice with
    bumps; either way its log-likelihood is :func:`run_likelihood`'s with the jump mixture and
    its whitened innovations are those with the jumps as their variance."""
    runs = generate_session({"sideslip": {"value": 0.03}}, np.random.default_rng(5))[:4]
    data = Dataset.of(runs, 0.25)
    rough = EFFECTS["floor_roughness"].write(MODEL, {"k_left": 3e-4, "k_right": 2e-4})
    bumpy = EFFECTS["floor_bumps"].write(rough, {"rate": 0.3, "heading_jump": 0.004})
    for spec in (MODEL, rough, bumpy):
        for run, mask in zip(data.runs, data.masks, strict=True):
            rep = replay_run(run, spec)
            mixture = run_likelihood(run, rep, spec, SENSOR, mask)
            gaussian = run_likelihood(run, rep, spec, SENSOR, mask, gaussian_jumps=True)
            loglik, white = run_scores(run, rep, spec, SENSOR, mask, whitened=True)
            assert white is not None
            assert _bits(loglik) == _bits(mixture.loglik)
            assert white.tobytes() == gaussian.whitened.tobytes()
            alone, none = run_scores(run, rep, spec, SENSOR, mask, whitened=False)
            assert none is None
            assert _bits(alone) == _bits(mixture.loglik)
        if spec is bumpy:  # the jumps matter here: the two filters really differ
            assert mixture.whitened.tobytes() != gaussian.whitened.tobytes()


@pytest.mark.parametrize("threads", ["1", "2"])
def test_whitened_innovations_alone_are_the_same_bytes_without_the_jump_mixture(
    threads: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A least-squares residual reads the whitened innovations only (``whitened_stack``, and
    ``evaluate(..., loglik=False)``): they are the bytes of the evaluation that also scores the
    runs, stacked and run by run, with and without expected wheel jumps; only runs with jumps
    expected leave their log-likelihood out (NaN), and without jumps it is still computed
    (the one filter pass gives it anyway)."""
    monkeypatch.setenv("ODOMGYM_THREADS", threads)
    close_thread_pool()
    runs = generate_session({"sideslip": {"value": 0.03}}, np.random.default_rng(5))[:4]
    data = Dataset.of(runs, 0.25)
    rough = EFFECTS["floor_roughness"].write(MODEL, {"k_left": 3e-4, "k_right": 2e-4})
    bumpy = EFFECTS["floor_bumps"].write(rough, {"rate": 0.3, "heading_jump": 0.004})
    try:
        for spec in (rough, bumpy):
            full = evaluate(data, spec, SENSOR)
            alone = evaluate(data, spec, SENSOR, loglik=False)
            assert len(alone.whitened) == len(full.whitened) == len(runs)
            for a, b in zip(alone.whitened, full.whitened, strict=True):
                assert a.tobytes() == b.tobytes()
            assert whitened_stack(data, spec, SENSOR)[0].tobytes() == (
                np.concatenate(full.whitened).tobytes()
            )
            if spec is bumpy:
                assert np.all(np.isnan(alone.loglik)) and np.all(np.isfinite(full.loglik))
            else:
                assert alone.loglik.tobytes() == full.loglik.tobytes()
            # With the wheel-noise gains held at another spec's replay (a held-gains fit).
            held = _held_gains(data, MODEL)
            with_gains = evaluate(data, spec, SENSOR, gains=held)
            assert whitened_stack(data, spec, SENSOR, held)[0].tobytes() == (
                np.concatenate(with_gains.whitened).tobytes()
            )
            # Run by run (the path of a spec that does not replay stacked) the same.
            for run, mask in zip(data.runs, data.masks, strict=True):
                rep = replay_run(run, spec)
                value, white = run_scores(run, rep, spec, SENSOR, mask, whitened=True)
                only, same = run_scores(run, rep, spec, SENSOR, mask, whitened=True, loglik=False)
                assert white is not None and same is not None
                assert same.tobytes() == white.tobytes()
                assert np.isnan(only) if spec is bumpy else _bits(only) == _bits(value)
        with pytest.raises(ValueError, match="loglik=False needs whitened=True"):
            evaluate(data, rough, SENSOR, whitened=False, loglik=False)
    finally:
        close_thread_pool()


def test_gains_held_at_the_spec_itself_are_its_own_and_held_elsewhere_are_not() -> None:
    """A fit with the wheel-noise gains held (``fit._least_squares(hold=True)``) starts from the
    bytes of the plain evaluation: held at the spec being evaluated, the gains are its own. At
    another E_b they are the start's: the heading's gain stays 1/(E_b·b) of the start while the
    replay moves (what keeps such a fit from widening the noise by moving E_b)."""
    runs = generate_session({"sideslip": {"value": 0.03}}, np.random.default_rng(5))[:3]
    data = Dataset.of(runs, 0.25)
    spec = EFFECTS["floor_roughness"].write(MODEL, {"k_left": 3e-4, "k_right": 2e-4})
    held = _held_gains(data, spec)
    plain = whitened_stack(data, spec, SENSOR)[0]
    assert whitened_stack(data, spec, SENSOR, held)[0].tobytes() == plain.tobytes()
    assert all(np.all(g[:, 1, 2] == 1.0 / spec.true_wheelbase) for g in held)
    wide = EFFECTS["wheelbase"].write(spec, {"e_b": 1.05})
    moving = whitened_stack(data, wide, SENSOR)[0]
    kept = whitened_stack(data, wide, SENSOR, held)[0]
    assert kept.tobytes() != moving.tobytes()  # the replay moved, the gains did not
    assert all(np.all(g[:, 1, 2] == 1.0 / spec.true_wheelbase) for g in held)  # left as held


def test_a_fit_scipy_cannot_start_keeps_its_start_and_other_errors_pass(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """scipy's trust-region reflective step that cannot be taken from a start (a one-sided
    parameter at its bound beside one without gradient: seen in the blind matrix) leaves the
    fit at its start, with the start's sum of squares; any other error of scipy is not
    swallowed."""
    runs = generate_session({"sideslip": {"value": 0.03}}, np.random.default_rng(5))[:3]
    data = Dataset.of(runs, 0.25)

    def failing(message: str) -> object:
        def least_squares(*args: object, **kwargs: object) -> None:
            raise ValueError(message)

        return least_squares

    monkeypatch.setattr(fit_module, "least_squares", failing(fit_module._TRUST_REGION_FAILURE))
    spec, cost = fit_module._least_squares(data, MODEL, SENSOR, EFFECTS["wheelbase"])
    start = whitened_stack(data, MODEL, SENSOR)[0]
    assert spec is MODEL and cost == float(start @ start)
    monkeypatch.setattr(fit_module, "least_squares", failing("Residuals are not finite"))
    with pytest.raises(ValueError, match="not finite"):
        fit_module._least_squares(data, MODEL, SENSOR, EFFECTS["wheelbase"])


@pytest.mark.parametrize("spacing", ["logged", "uniform", "stalled", "one", "two"])
def test_compiled_grammar_replay_is_the_numpy_one_bit_for_bit(spacing: str) -> None:
    """Every wheel and body term at once (and each alone) through ``DiscoveredTerms.replay``,
    whose kernels compute the modulators sample by sample, gives the bytes of the numpy
    expressions: on irregular intervals (numpy's non-uniform gradient), equal ones (its uniform
    formula), with a zero interval (middles not increasing: no acceleration), on one and two
    intervals; speeds of both signs, at rest and reversing."""
    rng = np.random.default_rng(7)
    n = {"one": 1, "two": 2}.get(spacing, 60)
    dt = {
        "logged": 0.05 + 0.01 * rng.random(n),
        "uniform": np.full(n, 3 / 64),  # sums exactly: equal steps between the middles
        "stalled": np.where(np.arange(n) == 30, 0.0, 0.05),
    }.get(spacing, np.full(n, 0.05))
    wheel = 0.3 * rng.standard_normal((n, 2))
    wheel[n // 3] = 0.0
    wheel[n // 2, 0] = -0.0
    arrays = ReplayArrays(
        dt=dt,
        wheel=wheel,
        radius=np.array([0.041, 0.042]),
        angle=np.cumsum(wheel, axis=0),
        time=100.0 + np.cumsum(dt),
        ds=0.02 * rng.standard_normal(n),
        dtheta=0.05 * rng.standard_normal(n),
        crab=0.001 * rng.standard_normal(n),
        travel=0.02 * rng.standard_normal((n, 2)),
    )
    arrays.travel[n // 3] = 0.0  # a step that does not move: the spin modulator is 0 there
    every = {t.name: 10.0 ** rng.uniform(-3.0, 3.0) * (-1) ** k for k, t in enumerate(TERMS)}
    # Each term alone with a coefficient of ±2²⁰: c·m outweighs the 1 it is added to, and a
    # power of two scales exactly, so a modulator off in its last bit shows in the result.
    alone = [{name: 2.0**20 * np.sign(c)} for name, c in every.items()]
    for values in [every, *alone]:
        effect = DiscoveredTerms(list(values))
        replayed = ReplayArrays(**{**arrays.__dict__, "memo": {}})
        effect.replay("transmission", values, replayed)
        effect.replay("body", values, replayed)
        expected = _numpy_terms(values, arrays)
        got = (replayed.wheel, replayed.crab, replayed.dtheta)
        assert all(a.tobytes() == b.tobytes() for a, b in zip(got, expected, strict=True))


def test_replays_from_kept_inputs_are_replays_from_scratch() -> None:
    """A dataset keeps each run's inputs (and the angle modulators derived from them) across
    replays; the second replay through a model with every kind of stage is the bytes of a
    fresh :func:`replay_run`, and the kept arrays are read-only."""
    runs = generate_session(
        {"out_of_round": {"value": 0.01, "phase": 1.0}}, np.random.default_rng(8)
    )[:3]
    data = Dataset.of(runs, 0.25)
    terms = {"right_sin1": 0.01, "left_cos2": -0.004, "left_accel": 0.02, "yaw_lateral": 0.03}
    spec = DiscoveredTerms(list(terms)).write(MODEL, terms)
    spec = EFFECTS["backlash"].write(spec, {"angle": 0.01})
    spec = EFFECTS["gt_sensor_offset"].write(spec, {"dx": 0.01, "dy": -0.005})
    for j, run in enumerate(data.runs):
        data.replay(j, spec)
        kept, fresh = data.replay(j, spec), replay_run(run, spec)
        for name in ("pose", "tracked", "travel", "ds", "dtheta"):
            assert getattr(kept, name).tobytes() == getattr(fresh, name).tobytes()
        inputs = data.inputs[j][spec.ticks_per_rev]
        assert "discovered.sin1" in inputs.memo
        assert not inputs.motor.flags.writeable


def test_open_loop_replays_from_kept_inputs_are_replays_from_scratch() -> None:
    """The open-loop fit keeps each run's replay inputs per time offset: every replay, at the
    offset it was built for, after other offsets, after they were evicted and in a subset, is
    the bytes of :func:`pose_errors` (a fresh replay of the corrected run)."""
    runs = generate_session(
        {"out_of_round": {"value": 0.01, "phase": 1.0}}, np.random.default_rng(8)
    )[:2]
    data = OpenLoopData(runs, 0.25, MODEL.wheelbase)
    terms = {"right_sin1": 0.01, "left_accel": 0.02}
    spec = DiscoveredTerms(list(terms)).write(MODEL, terms)
    offsets = [0.0, 0.05, -0.0, 0.12, -0.07, 0.3, 0.05, 0.0]  # more than are kept per run
    for tau in offsets:
        nuisance = SessionNuisance("s", time_offset=tau, dx=0.01, yaw=0.02, frame=True)
        for part, index in ((data, (0, 1)), (data.subset([1]), (1,))):
            for k, j in enumerate(index):
                kept = _errors(part, k, spec, nuisance)
                assert kept.tobytes() == pose_errors(runs[j], spec, nuisance).tobytes()
                # Residuals from errors the caller has: the same, the errors left as they were.
                given = kept.copy()
                from_given = _residual(part, k, spec, nuisance, given)
                assert from_given.tobytes() == _residual(part, k, spec, nuisance).tobytes()
                assert given.tobytes() == kept.tobytes()
    assert 0 < len(data.inputs[0]) <= _KEPT_INPUTS
    assert data.subset([1]).inputs[0] is data.inputs[1]


def test_library_from_forked_processes_is_the_serial_one_bit_for_bit(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The grammar library's evaluations shared among two forked processes give the bytes of
    one process: base innovations, every derivative column, the kept and dropped terms."""
    runs = generate_session({"sideslip": {"value": 0.06}}, np.random.default_rng(22))[:4]
    data = Dataset.of(runs, 0.25)
    terms = ["crab_lateral_signed", "left_accel", "right_sin1", "yaw_lateral", "left_cos2"]
    serial = library_jacobian(data, MODEL, SENSOR, terms)
    from odomgym.diagnose import fit as fit_module

    forks: list[int] = []

    def counted(*args: object, **kwargs: object) -> None:
        forks.append(kwargs["processes"])  # type: ignore[arg-type]
        run_tasks(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(fit_module, "run_tasks", counted)
    forked = library_jacobian(Dataset.of(runs, 0.25), MODEL, SENSOR, terms, processes=2)
    assert forks == [2]  # the evaluations did go to two forked processes
    assert (forked.terms, forked.dropped) == (serial.terms, serial.dropped)
    assert len(serial.terms) >= 3
    pairs = zip(serial.residual + serial.jacobian, forked.residual + forked.jacobian, strict=True)
    for a, b in pairs:
        assert a.tobytes() == b.tobytes()


def test_max_t_null_from_blocks_of_patterns_is_one_pattern_at_a_time() -> None:
    """The max-T test's null distribution computed for blocks of sign patterns is, byte for
    byte, ``studentised(d * s).max()`` one pattern at a time: random and exact patterns, one
    and many candidates, a candidate with no spread (its t is +inf or 0) and tiny and large
    scales."""
    rng = np.random.default_rng(0)
    for trial in range(40):
        candidates, runs = int(rng.integers(1, 12)), int(rng.integers(2, 300))
        d = rng.standard_normal((candidates, runs)) * 10.0 ** rng.uniform(-6, 3)
        if trial % 5 == 0:
            d[0] = 0.0
        if trial % 7 == 0:
            d[-1] = 1.5
        signs = sign_matrix(runs, np.random.default_rng(trial), 1000)
        one_by_one = np.array([studentised(d * s).max() for s in signs])
        assert _null_max(d, signs).tobytes() == one_by_one.tobytes()


def test_compiled_filter_is_its_source_run_by_python() -> None:
    """The filter kernel inlines the Kalman update and compiles it for three measured rows (its
    loops unrolled); run by the Python interpreter (``py_func``), the same source calls the
    update compiled for any number of rows. Both give the same bytes: log-likelihood,
    whitened innovations, count — with the jump mixture, with Gaussian jumps, and the
    open-loop expected gap; and so do the wheel gains it takes (cosines and sines of numba
    and of Python's ``math``)."""
    runs = generate_session({"floor_bumps": {"value": 0.02}}, np.random.default_rng(9))[:3]
    data = Dataset.of(runs, 0.25)
    rough = EFFECTS["floor_roughness"].write(MODEL, {"k_left": 1e-3, "k_right": 1.2e-3})
    bumpy = EFFECTS["floor_bumps"].write(rough, {"rate": 0.5, "heading_jump": 0.01})
    for spec in (rough, bumpy):
        for run, mask in zip(data.runs, data.masks, strict=True):
            mask = mask.copy()
            mask[::7, 2] = False  # some samples with two measured rows
            rep = replay_run(run, spec)
            arrays = (*_model_arrays(rep, spec, SENSOR), run_residual(run, rep, mask), mask)
            for gaussian, update in ((False, True), (True, True), (True, False)):
                compiled_gap = np.full((len(run.time), 2), np.nan)
                python_gap = compiled_gap.copy()
                compiled = _filter(*arrays, gaussian, update, compiled_gap)
                python = _filter.py_func(*arrays, gaussian, update, python_gap)
                assert _bits(compiled[0]) == _bits(python[0])
                assert compiled[1].tobytes() == python[1].tobytes()
                assert compiled[2] == python[2]
                assert compiled_gap.tobytes() == python_gap.tobytes()
            # The wheel gains the filter takes, kept once per replay: the same bytes too.
            args = (rep.pose, rep.ds, rep.dtheta, rep.wheelbase)
            assert _wheel_gains(*args).tobytes() == _wheel_gains.py_func(*args).tobytes()


def test_scalar_filter_is_the_array_filter_bit_for_bit() -> None:
    """The filter's scalar state and its three-row scalar update (``scalar=True``, what every
    caller runs) give the bytes of the array path it replaced (``scalar=False``: the general
    Kalman update and mixture collapse at every sample): log-likelihood, whitened innovations,
    count and open-loop gap; with no noise effect, wheel noise, the jump mixture and Gaussian
    jumps, and with samples of one and two measured rows among the three-row ones."""
    runs = generate_session({"floor_bumps": {"value": 0.02}}, np.random.default_rng(21))[:3]
    data = Dataset.of(runs, 0.25)
    rough = EFFECTS["floor_roughness"].write(MODEL, {"k_left": 1e-3, "k_right": 1.2e-3})
    bumpy = EFFECTS["floor_bumps"].write(rough, {"rate": 0.5, "heading_jump": 0.01})
    checked = 0
    for spec in (MODEL, rough, bumpy):
        for run, full in zip(data.runs, data.masks, strict=True):
            partial = full.copy()
            partial[::7, 2] = False  # position only
            partial[3::11, :2] = False  # heading only
            for mask in (full, partial):
                rep = replay_run(run, spec)
                arrays = (*_model_arrays(rep, spec, SENSOR), run_residual(run, rep, mask), mask)
                for gaussian, update in ((False, True), (True, True), (True, False)):
                    gaps = [np.full((len(run.time), 2), np.nan) for _ in range(2)]
                    fast = _filter(*arrays, gaussian, update, gaps[0], True)
                    slow = _filter(*arrays, gaussian, update, gaps[1], False)
                    assert _bits(fast[0]) == _bits(slow[0])
                    assert fast[1].tobytes() == slow[1].tobytes()
                    assert fast[2] == slow[2]
                    assert gaps[0].tobytes() == gaps[1].tobytes()
                    checked += int(update and np.isfinite(fast[0]) and fast[2] > 0)
    assert checked == 3 * 3 * 2 * 2


def test_scalar_update_is_the_general_update_bit_for_bit() -> None:
    """:func:`_update3` on scalars is :func:`_gauss_update` with three rows, bit for bit, on
    random priors and on the awkward values the products with H's zeros and ones decide:
    signed zeros, a singular prior, infinities and NaN."""
    rng = np.random.default_rng(22)
    cases = []
    for _ in range(200):
        a = rng.standard_normal((3, 3)) * 10.0 ** rng.uniform(-4, 1)
        cases.append((a @ a.T, rng.standard_normal(3), rng.standard_normal(5)))
    cases.append((np.zeros((3, 3)), np.zeros(3), np.zeros(5)))
    cases.append((-0.0 * np.ones((3, 3)), np.array([-0.0, 0.0, -0.0]), np.array([-0.0] * 5)))
    cases.append((np.full((3, 3), np.inf), np.ones(3), np.ones(5)))
    cases.append((np.eye(3), np.array([np.nan, 0.0, 1.0]), np.ones(5)))
    for prior, mean, extra in cases:
        ox, oy, z0, z1, z2 = extra
        r = np.array([4e-6, 4e-6, 2.5e-5])
        h = np.array([[1.0, 0.0, -oy], [0.0, 1.0, ox], [0.0, 0.0, 1.0]])
        # The innovation as the filter forms it for the general update (_update3 forms its own).
        nu = np.array(
            [
                z - (h[a, 0] * mean[0] + h[a, 1] * mean[1] + h[a, 2] * mean[2])
                for a, z in enumerate((z0, z1, z2))
            ]
        )
        sol, post_mean, post_cov = np.zeros(3), np.zeros(3), np.zeros((3, 3))
        with np.errstate(all="ignore"):
            fit = _gauss_update(
                prior, mean, h, nu, r, 3, np.zeros((4, 3, 3)), sol, np.zeros(3), post_mean, post_cov
            )
            got = _update3(*prior.ravel(), *mean, ox, oy, *r, z0, z1, z2)
        want = (fit, *sol, *post_mean, *post_cov.ravel())
        assert np.array(got).tobytes() == np.array(want).tobytes()


def test_start_pose_stops_early_with_the_bytes_of_three_steps() -> None:
    """The replay's start pose (the axle pose whose tracked point is the first measured pose)
    stops iterating once a step leaves the pose as it was; it is the bytes of the three
    steps it took before, for models without a measurement stage (one step), with a tracked
    point offset (rigid: still moving in the last bits) and at poses with signed zeros."""
    rng = np.random.default_rng(23)
    models: list[list[tuple[str, dict[str, float]]]] = [
        [],
        [("turn_skid", {"gain": 0.3}), ("backlash", {"angle": 0.01})],
        [("gt_sensor_offset", {"dx": 0.031, "dy": -0.012})],
        [("gt_sensor_offset", {"dx": 0.0, "dy": 0.0})],
    ]
    poses = [rng.standard_normal(3) for _ in range(20)]
    poses += [np.array([-0.0, 0.0, -0.0]), np.array([0.0, -0.0, np.pi])]
    for effects in models:
        for measured in poses:
            target = measured[None, :]
            pose = target.copy()
            arrays = ReplayArrays(dt=np.zeros(0), wheel=np.zeros((0, 2)))
            for _ in range(3):  # the iteration as it was: always three steps
                pose = pose + (target - _measure(pose, effects, arrays))
            assert _start_pose(measured, effects).tobytes() == pose[0].tobytes()


def test_column_scaling_is_numpys_broadcast_bit_for_bit() -> None:
    """``scale_columns`` (the replay's wheel radii, the wheel noise's k²) gives the bytes of
    numpy's broadcast product, signed zeros, infinities and NaN included, for two columns and
    for three, and the wheel noise it computes is that of ``|travel| * k²``."""
    rng = np.random.default_rng(24)
    for columns in (2, 3):
        matrix = rng.standard_normal((500, columns)) * 10.0 ** rng.uniform(-8, 3, (500, columns))
        matrix[:4] = [[-0.0] * columns, [0.0] * columns, [np.inf] * columns, [np.nan] * columns]
        for factors in (rng.standard_normal(columns), np.array([-0.0, 1e-300, 3.0][:columns])):
            with np.errstate(invalid="ignore"):  # inf · 0 is NaN on both sides
                expected = matrix * factors
                got = scale_columns(matrix, tuple(factors))
            assert got.tobytes() == expected.tobytes()
    travel = rng.standard_normal((300, 2)) * 0.01
    values = {"k_left": 2.3e-4, "k_right": 1.7e-3}
    k2 = np.array([values["k_left"] ** 2, values["k_right"] ** 2])
    got = EFFECTS["floor_roughness"].wheel_variance(values, travel)
    assert got is not None and got.tobytes() == (np.abs(travel) * k2).tobytes()


def test_compiled_integration_is_numpy_cumsum_bit_for_bit() -> None:
    """The replay's midpoint integration (two kernels around numpy's cos and sin) gives the
    bytes of the numpy expressions it replaced, signed zeros at the start included, for one
    run and for the same run stacked behind another."""
    rng = np.random.default_rng(11)
    for first in (0.0, -0.0, 0.3):
        dtheta = 0.05 * rng.standard_normal(50)
        ds = 0.01 * rng.standard_normal(50)
        crab = 1e-3 * rng.standard_normal(50)
        dtheta[0] = ds[0] = first
        for start in (np.array([1.0, -2.0, 0.5]), np.array([-0.0, -0.0, -0.0])):
            theta = start[2] + np.concatenate([[0.0], np.cumsum(dtheta)])
            direction = theta[:-1] + 0.5 * dtheta + crab
            pose = np.empty((51, 3))
            pose[:, 0] = start[0] + np.concatenate([[0.0], np.cumsum(ds * np.cos(direction))])
            pose[:, 1] = start[1] + np.concatenate([[0.0], np.cumsum(ds * np.sin(direction))])
            pose[:, 2] = theta
            one = np.array([0, 50], dtype=np.int64)
            got_theta, got_direction = _headings(start[2:3], dtheta, crab, one)
            got = _positions(
                start[None, :], got_theta, ds, np.cos(got_direction), np.sin(got_direction), one
            )
            assert got_direction.tobytes() == direction.tobytes()
            assert got.tobytes() == pose.tobytes()
            # behind a run of 7 intervals from another start: the second run's rows the same
            two = np.array([0, 7, 57], dtype=np.int64)
            lead = 0.02 * rng.standard_normal(7)
            theta2, direction2 = _headings(
                np.array([0.7, start[2]]),
                np.concatenate([lead, dtheta]),
                np.concatenate([lead, crab]),
                two,
            )
            both = _positions(
                np.array([[3.0, 4.0, 0.7], start]),
                theta2,
                np.concatenate([lead, ds]),
                np.cos(direction2),
                np.sin(direction2),
                two,
            )
            assert direction2[7:].tobytes() == direction.tobytes()
            assert both[8:].tobytes() == pose.tobytes()


def test_a_repeated_noise_fit_is_the_first_one() -> None:
    """:func:`fit_noise` keeps its results on the dataset: a second call with the same inputs
    returns them (nothing refitted), and they are the bytes of a fit on a fresh copy of the
    runs; other effects or a warm start are other entries."""
    runs = generate_session({"floor_roughness": {"value": 0.003}}, np.random.default_rng(12))
    data = Dataset.of(runs[:4], 0.25)
    rough = EFFECTS["floor_roughness"]
    first = fit_noise(data, MODEL, SENSOR, rough)
    again = fit_noise(data, MODEL, SENSOR, rough)
    fresh = fit_noise(Dataset.of(runs[:4], 0.25), MODEL, SENSOR, rough)
    assert again is first and len(data.noise_fits) == 1
    assert first[0] == fresh[0] and first[1] == fresh[1] and _bits(first[2]) == _bits(fresh[2])
    fit_noise(data, MODEL, SensorNoise(0.002, 0.005), None)
    fit_noise(data, MODEL, SensorNoise(0.002, 0.005), rough, warm=True)
    assert len(data.noise_fits) == 3


@pytest.mark.parametrize("threads", ["1", "2"])
def test_a_bump_fit_keeping_its_replays_is_the_fit_replaying_every_time(
    threads: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A noise fit of floor bumps (whose mean loss moves the replay) beside wheel noise
    replays the runs again only when the bumps' rate or jump moved (``KeptReplays``): the
    fitted spec, sensor noise and log-likelihood are the bytes of the fit that replays at
    every evaluation, and it replays exactly where the bumps' values are not among the last
    three a share replayed (on these runs 92 replays instead of 219 on one thread)."""
    monkeypatch.setenv("ODOMGYM_THREADS", threads)
    close_thread_pool()
    runs = generate_session({"floor_bumps": {"value": 0.02}}, np.random.default_rng(14))[:4]
    bumps, rough = EFFECTS["floor_bumps"], EFFECTS["floor_roughness"]
    calls = {"replays": 0}
    seen: list[tuple[tuple[int, int], object]] = []
    replay = Dataset.stacked_replay

    def counted(self: Dataset, spec: RobotSpec, index: range) -> object:
        calls["replays"] += 1
        seen.append(((index.start, index.stop), bumps.read(spec)))
        return replay(self, spec, index)

    monkeypatch.setattr(Dataset, "stacked_replay", counted)
    try:
        kept = fit_module._fit_noise(Dataset.of(runs, 0.25), MODEL, SENSOR, [bumps, rough], False)
        with_kept = calls["replays"]
        calls["replays"] = 0
        seen.clear()
        monkeypatch.setattr(
            fit_module.KeptReplays,
            "stacked",
            lambda self, data, spec, index: data.stacked_replay(spec, index),
        )
        every = fit_module._fit_noise(Dataset.of(runs, 0.25), MODEL, SENSOR, [bumps, rough], False)
    finally:
        close_thread_pool()
    assert not bumps.is_absent(bumps.read(kept[0]))  # the bumps were fitted, not dropped
    assert kept[0] == every[0] and kept[1] == every[1] and _bits(kept[2]) == _bits(every[2])
    recent: dict[tuple[int, int], list[object]] = {}
    moved = 0
    for share, values in seen:  # the fit that replays every time: which values were new?
        latest = recent.setdefault(share, [])
        if values in latest:
            latest.remove(values)
        else:
            moved += 1
        latest.append(values)
        del latest[: -fit_module.KeptReplays.KEPT]
    assert with_kept == moved < calls["replays"]


def _numpy_residual(measured: np.ndarray, predicted: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The residual as numpy expressions (the path :func:`_pose_residual` replaced)."""
    residual = np.where(mask, measured - predicted, 0.0)
    residual[:, 2] = np.mod(residual[:, 2] + np.pi, 2.0 * np.pi) - np.pi
    return residual


def test_compiled_residual_is_numpys_where_and_mod_bit_for_bit() -> None:
    """The heading wrap of :func:`run_residual` is numpy's float remainder: the same bytes on
    random headings over many turns, at the wrap's edges (odd multiples of π, ±0.0, values a
    rounding away from them), and through NaN and infinity, for masked and unmasked samples."""
    rng = np.random.default_rng(21)
    edges = np.array(
        [0.0, -0.0, np.pi, -np.pi, 3 * np.pi, -3 * np.pi, 2 * np.pi, -2 * np.pi, 1e-300, -1e-300]
    )
    near = np.concatenate([np.nextafter(edges, np.inf), np.nextafter(edges, -np.inf)])
    headings = np.concatenate(
        [rng.uniform(-40.0, 40.0, 500), edges, near, [np.nan, np.inf, -np.inf, 1e17, -1e17]]
    )
    n = len(headings)
    measured = rng.normal(0.0, 3.0, (n, 3))
    measured[:, 2] = headings
    predicted = rng.normal(0.0, 3.0, (n, 3))
    predicted[: n // 2, 2] = 0.0  # the heading difference is then exactly the edge value
    predicted[n // 2 :, 2] = -0.0
    rng.shuffle(predicted[n // 2 :])
    for mask in (np.ones((n, 3), dtype=bool), rng.random((n, 3)) < 0.5):
        with np.errstate(invalid="ignore"):
            want = _numpy_residual(measured, predicted, mask)
        assert _pose_residual(measured, predicted, mask).tobytes() == want.tobytes()
    runs = generate_session({"sideslip": {"value": 0.03}}, np.random.default_rng(6))[:3]
    data = Dataset.of(runs, 0.25)
    for run, mask in zip(data.runs, data.masks, strict=True):
        rep = replay_run(run, MODEL)
        want = _numpy_residual(run.true_pose, rep.tracked, mask)
        assert run_residual(run, rep, mask).tobytes() == want.tobytes()


def test_noise_fit_evaluations_with_stacked_process_noise_are_per_run_bit_for_bit(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A noise fit evaluates kept replays with the process noise of all runs computed in one
    call on their stacked travel, and the filter of a thread's share of the runs in one
    compiled call (``likelihood.filter_runs``); each run's variance, jumps and log-likelihood
    are the bytes of the run alone, with roughness, bumps and both (two effects adding
    variances), on one thread, two and three (shares of one run each)."""
    runs = generate_session({"sideslip": {"value": 0.03}}, np.random.default_rng(5))[:3]
    data = Dataset.of(runs, 0.25)
    rough = EFFECTS["floor_roughness"].write(MODEL, {"k_left": 3e-4, "k_right": 2e-4})
    bumps = EFFECTS["floor_bumps"].write(MODEL, {"rate": 0.3, "heading_jump": 0.004})
    both = EFFECTS["floor_bumps"].write(rough, {"rate": 0.3, "heading_jump": 0.004})
    fixed = _fixed_replays(data, rough, [EFFECTS["floor_roughness"]])
    assert fixed is not None and len(fixed.travel) == sum(len(r.time) - 1 for r in runs)
    for spec in (MODEL, rough, bumps, both):
        stacked = stacked_process_noise(spec, fixed.travel, fixed.rows)
        for rep, (variance, jumps, size) in zip(fixed.replays, stacked, strict=True):
            alone = _model_arrays(rep, spec, SENSOR)
            assert variance.tobytes() == alone[3].tobytes()
            assert jumps.tobytes() == alone[4].tobytes() and _bits(size) == _bits(alone[5])
        plain = [
            run_scores(run, rep, spec, SENSOR, mask, whitened=False)[0]
            for run, rep, mask in zip(data.runs, fixed.replays, data.masks, strict=True)
        ]
        for threads in ("1", "2", "3"):
            monkeypatch.setenv("ODOMGYM_THREADS", threads)
            close_thread_pool()
            kept = evaluate(data, spec, SENSOR, whitened=False, fixed=fixed)
            assert kept.loglik.tobytes() == np.array(plain).tobytes(), threads
    close_thread_pool()


def test_filter_updates_every_measured_sample_once_whatever_the_gaps() -> None:
    """The filter propagates between measured samples in a loop of its own; at the edges of
    that loop — runs of one and two samples, a last sample not measured, long gaps, nothing
    measured after the start — every measured component after the first sample is counted
    once, trailing unmeasured samples change no byte of the result, the open-loop gap is
    written exactly at the measured samples, and the compiled kernel is its Python source."""
    run = generate_session({"floor_bumps": {"value": 0.02}}, np.random.default_rng(13))[0]
    spec = EFFECTS["floor_bumps"].write(
        EFFECTS["floor_roughness"].write(MODEL, {"k_left": 1e-3, "k_right": 1.2e-3}),
        {"rate": 0.5, "heading_jump": 0.01},
    )
    rep = replay_run(run, spec)
    pose, tracked, gains, variance, jumps, size, sigma = _model_arrays(rep, spec, SENSOR)
    full = np.isfinite(run.true_pose)
    n = len(run.time)
    gappy = full.copy()
    gappy[5 : n // 2] = False  # a long gap
    gappy[::11, 1] = False  # samples with two measured rows
    gappy[-3:] = False  # the last samples not measured
    start_only = np.zeros_like(full)
    start_only[0] = True

    def run_filter(mask: np.ndarray, stop: int, gaussian: bool, update: bool) -> tuple:
        residual = run_residual(run, rep, mask)[:stop]
        gap = np.full((stop, 2), np.nan)
        args = (
            pose[:stop], tracked[:stop], gains[: stop - 1], variance[: stop - 1],
            jumps[: stop - 1], size, sigma, residual, mask[:stop], gaussian, update, gap,
        )  # fmt: skip
        compiled = _filter(*args)
        python = _filter.py_func(*(*args[:-1], gap.copy()))
        assert _bits(compiled[0]) == _bits(python[0]) and compiled[2] == python[2]
        assert compiled[1].tobytes() == python[1].tobytes()
        return compiled, gap

    for mask in (full, gappy, start_only):
        for stop in (1, 2, 3, n):
            for gaussian, update in ((False, True), (True, True), (True, False)):
                (_, _, count), gap = run_filter(mask, stop, gaussian, update)
                measured = mask[1:stop]
                if update:
                    assert count == int(measured.sum())
                else:
                    rows = np.flatnonzero(measured.any(axis=1)) + 1
                    assert np.isfinite(gap[rows]).all()
                    assert np.isnan(np.delete(gap, rows, axis=0)).all()
    # Trailing unmeasured samples: the bytes of the run cut after its last measured sample.
    last = int(np.flatnonzero(gappy.any(axis=1))[-1]) + 1
    for gaussian in (False, True):
        (long_ll, long_white, long_count), _ = run_filter(gappy, n, gaussian, True)
        (cut_ll, cut_white, cut_count), _ = run_filter(gappy, last, gaussian, True)
        assert _bits(long_ll) == _bits(cut_ll) and long_count == cut_count
        assert long_white[: 3 * last].tobytes() == cut_white.tobytes()
        assert not long_white[3 * last :].any()


def test_a_forked_worker_that_dies_stops_the_diagnosis_naming_its_task(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Both forked paths of the workflow — the candidate fits (``run_fit_jobs``) and the
    library's evaluations (``whitened_stacks``) — turn a worker killed mid-task (here it exits
    with 86, as an out-of-memory kill would end it) into a RuntimeError saying what it was
    doing, instead of waiting for it forever or retrying a task that kills every worker."""
    from types import SimpleNamespace

    from odomgym.diagnose import fit as fit_module

    def dies(*args: object) -> None:
        os._exit(86)

    monkeypatch.setattr(fit_module, "_run_job", dies)
    jobs = {0: SimpleNamespace(effect="wheelbase"), 1: SimpleNamespace(effect="turn_skid")}
    with pytest.raises(RuntimeError, match=r"exit code 86\) while fitting (wheelbase|turn_skid)"):
        fit_module.run_fit_jobs(jobs, 2, lambda k, fit: None)  # type: ignore[arg-type]
    monkeypatch.setattr(fit_module, "_stack_task", dies)
    runs = generate_session({}, np.random.default_rng(3))[:2]
    with pytest.raises(RuntimeError, match=r"while evaluating model [12] \([12] of 2\)"):
        fit_module.whitened_stacks(
            Dataset.of(runs, 0.25), [MODEL, MODEL], SENSOR, lambda k, s: None, processes=2
        )


def test_fit_jobs_are_handed_out_dearest_first_and_the_serial_path_keeps_its_order(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The worker pool takes jobs first come, first served, so ``run_fit_jobs`` hands out
    the candidates fitted beside partners (``skid_track`` beside ``wheelbase``,
    ``floor_bumps`` beside the distance scale: two or three fits each) before the others, in
    registry order otherwise; one process runs them in the caller's order."""
    from types import SimpleNamespace

    from odomgym.diagnose import fit as fit_module

    names = ["wheelbase", "skid_track", "turn_skid", "floor_bumps", "backlash"]
    jobs = {k: SimpleNamespace(effect=name) for k, name in enumerate(names)}
    handed: list[int] = []
    monkeypatch.setattr(
        fit_module,
        "run_forked",
        lambda task, items, processes, finished, doing: handed.extend(k for k, _ in items),
    )
    fit_module.run_fit_jobs(jobs, 2, lambda k, fit: None)  # type: ignore[arg-type]
    assert [names[k] for k in handed] == [
        "skid_track", "floor_bumps", "wheelbase", "turn_skid", "backlash"
    ]  # fmt: skip
    ran: list[int] = []
    monkeypatch.setattr(fit_module, "_run_job", lambda job, attempt: job)
    fit_module.run_fit_jobs(jobs, 1, lambda k, fit: ran.append(k))  # type: ignore[arg-type]
    assert ran == list(range(len(names)))


def _numpy_interval_rates(r: RunResidual) -> dict[str, list[float]]:
    """The manoeuvre view of ``where.localise`` as it was written before it was compiled: a
    loop of numpy calls per interval between measured samples (the reference)."""
    rates: dict[str, list[float]] = {k: [] for k in ("straight", "cross", "turn", "arc", "rev")}
    gained = np.zeros(len(r.ds) + 1)
    gained[r.index] = r.residual[:, 2]
    cross = np.zeros(len(r.ds) + 1)
    cross[r.index] = r.residual[:, 1]
    for a, b in zip(r.index[:-1], r.index[1:], strict=True):
        span = slice(a, b)
        moving = r.classes[span][r.classes[span] != 0]
        if np.any(moving != moving[:1]):
            continue
        cls = np.bincount(r.classes[span], minlength=4).argmax()
        dh, dc = gained[b] - gained[a], cross[b] - cross[a]
        if cls == 1:
            dist = float(np.abs(r.ds[span]).sum())
            if dist > 0.02:
                rates["straight"].append(dh / dist)
                rates["cross"].append(dc / dist)
        elif cls in (2, 3):
            ang = float(np.abs(r.dtheta[span]).sum())
            if ang > 0.05:
                rates["turn" if cls == 2 else "arc"].append(dh / ang)
        if r.reversal[span].any():
            rates["rev"].append(dh / float(r.reversal[span].sum()))
    return rates


def test_the_compiled_manoeuvre_view_gives_numpys_numbers() -> None:
    """``openloop._interval_rates`` (the kernel of ``where.localise``) against the numpy loop
    it replaced, on random runs with every case: intervals of one manoeuvre, of stops, of two
    manoeuvres (left out), ties of stops and motion (``argmax`` takes the first), spans from 1
    to 300 samples (numpy's pairwise sum splits above 128), a NaN heading, reversals. The same
    values, bit for bit, in the same order."""
    rng = np.random.default_rng(11)
    seen = dict.fromkeys(("straight", "cross", "turn", "arc", "rev"), 0)
    for trial in range(40):
        n = int(rng.integers(50, 2000))
        runs = rng.integers(1, 40, size=n // 5)  # runs of one class, to make whole intervals
        classes = np.repeat(rng.integers(0, 4, size=len(runs)), runs)[:n]
        classes = np.concatenate([classes, np.zeros(n - len(classes), dtype=np.int64)])
        gaps = rng.choice([1, 2, 5, 17, 64, 130, 300], size=n)
        index = np.unique(np.concatenate([[0], np.cumsum(gaps)]))
        index = index[index <= n]
        residual = rng.normal(scale=0.01, size=(len(index), 3))
        if trial % 3 == 0:
            residual[rng.integers(len(index)), 2] = np.nan
        r = RunResidual(
            label="x",
            turn="none",
            index=index.astype(np.intp),
            residual=residual,
            final=residual[-1],
            classes=classes.astype(np.int64),
            speed=np.zeros(n),
            omega=np.zeros(n),
            reversal=rng.random(n) < 0.02,
            ds=rng.normal(scale=0.01, size=n),
            dtheta=rng.normal(scale=0.02, size=n),
        )
        expected = _numpy_interval_rates(r)
        kind = np.empty(len(index) - 1, dtype=np.int64)
        heading, off_track, per_reversal = (np.empty(len(kind)) for _ in range(3))
        reversed_ = np.empty(len(kind), dtype=np.bool_)
        gained = np.zeros(n + 1)
        gained[index] = residual[:, 2]
        cross = np.zeros(n + 1)
        cross[index] = residual[:, 1]
        openloop_module._interval_rates(
            index.astype(np.int64), gained, cross, r.classes, r.ds, r.dtheta, r.reversal,
            kind, heading, off_track, per_reversal, reversed_,
        )  # fmt: skip
        got = {
            "straight": heading[kind == 1],
            "cross": off_track[kind == 1],
            "turn": heading[kind == 2],
            "arc": heading[kind == 3],
            "rev": per_reversal[reversed_],
        }
        for key, values in expected.items():
            assert np.asarray(values).tobytes() == got[key].tobytes(), (trial, key)
            seen[key] += len(values)
    assert min(seen.values()) > 20, seen  # every kind of interval was compared


def test_thread_shares_balance_samples_and_leave_the_bytes_alone(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The threads of ``evaluate`` take contiguous shares of nearly equal samples
    (``fit.balanced_shares``), not of equal run counts: on run lengths in the June OptiOdom
    sessions' order (circles of ~2 000 samples, then straights of ~660 and spins of ~230, then
    squares of ~1 800) no share holds more than its equal part plus the longest run, and two
    halves differ by less than a run. Which cut is taken changes no number: runs of very
    unequal lengths give the same bytes on one thread, on two (whose cut, after the third run,
    is not the equal-count cut after the second) and on three (a share of one run, replayed
    and scored run by run)."""
    june_like = [np.zeros(n) for n in [2012] * 30 + [666, 230, 225] * 15 + [1814] * 27]
    total = sum(len(r) for r in june_like)
    for count in (2, 3, 5):
        shares = balanced_shares(june_like, count)
        assert [j for share in shares for j in share] == list(range(len(june_like)))
        assert len(shares) == count and all(len(share) >= 1 for share in shares)
        largest = max(sum(len(june_like[j]) for j in share) for share in shares)
        assert largest <= total / count + max(len(r) for r in june_like)
    # Equal run counts would give 30 circles and 21 straights and spins against 24 straights
    # and spins and 27 squares: 68 207 against 57 946 samples (63 268 against 62 885 here).
    halves = balanced_shares(june_like, 2)
    sizes = [sum(len(june_like[j]) for j in share) for share in halves]
    assert abs(sizes[0] - sizes[1]) <= 666
    assert balanced_shares(june_like, 1) == [range(len(june_like))]
    assert balanced_shares([np.zeros(4)] * 3, 8) == [range(0, 1), range(1, 2), range(2, 3)]

    runs = generate_session({"sideslip": {"value": 0.03}}, np.random.default_rng(5))[:5]
    runs = [_head(runs[0], 40), *runs[1:4], _head(runs[4], 60)]
    data = Dataset.of(runs, 0.25)
    assert balanced_shares(data.masks, 2) == [range(0, 3), range(3, 5)]
    assert data.shares(2) == balanced_shares(data.masks, 2) and data.shares(2) is data.shares(2)
    assert [len(share) for share in balanced_shares(data.masks, 3)].count(1) >= 1
    rough = EFFECTS["floor_roughness"].write(MODEL, {"k_left": 3e-4, "k_right": 2e-4})
    fixed = _fixed_replays(data, rough, [EFFECTS["floor_roughness"]])
    got = {}
    try:
        for threads in ("1", "2", "3"):
            monkeypatch.setenv("ODOMGYM_THREADS", threads)
            close_thread_pool()
            full = evaluate(data, rough, SENSOR)
            kept = evaluate(data, rough, SENSOR, whitened=False, fixed=fixed)
            got[threads] = (
                full.loglik.tobytes(),
                np.concatenate(full.whitened).tobytes(),
                kept.loglik.tobytes(),
            )
    finally:
        close_thread_pool()
    assert got["1"] == got["2"] == got["3"]


def _head(run: Run, samples: int) -> Run:
    """``run``'s first ``samples`` samples: a short run beside long ones."""
    return dataclasses.replace(
        run,
        time=run.time[:samples],
        counts=run.counts[:samples],
        true_pose=run.true_pose[:samples],
    )

"""The trajectory filter of the self-calibration session (issue 20): its pieces against exact
and Monte Carlo answers, its posterior against its actual errors, and what it gains over the
end poses on the same runs."""

from __future__ import annotations

import numpy as np
import pytest
from test_selfcal import _episodes

from odomgym.baselines.selfcal import SelfCal, SelfCalEndPose, scripted_policy
from odomgym.envs.selfcal import SelfCalibrationEnv
from odomgym.errors import SpecError
from odomgym.lab.experiment import SensorAccuracy
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run, replay_odometry, replay_with_jacobian
from odomgym.robot import PRESETS
from odomgym.selfcal.episodes import Episode, step_episodes
from odomgym.selfcal.estimators import (
    PRIOR_STD,
    EndPoseEstimator,
    TrajectoryEstimator,
    chunk_motions,
)
from odomgym.selfcal.menu import ACTION_MENU
from odomgym.selfcal.session import SelfCalSession

ITEM = {item.name: k for k, item in enumerate(ACTION_MENU)}
ROBOT = PRESETS["labmate"]


def _wiggly_run(rng: np.random.Generator, samples: int = 203) -> Run:
    """Encoder counts of a run that drives, curves and turns in place, with a start pose
    away from the origin (the counts alone matter to the odometry)."""
    left = np.cumsum(rng.integers(-40, 120, samples)).astype(np.int64)
    right = np.cumsum(rng.integers(-40, 120, samples)).astype(np.int64)
    counts = np.stack([left - left[0], right - right[0]], axis=1)
    pose = np.zeros((samples, 3))
    pose[:] = (1.5, -0.7, 2.0)
    return Run("free", np.arange(samples) * 0.05, counts, pose)


def _compose(start: np.ndarray, u: np.ndarray) -> np.ndarray:
    out = start.copy()
    for step in u:
        c, s = np.cos(out[2]), np.sin(out[2])
        out = out + np.array([c * step[0] - s * step[1], s * step[0] + c * step[1], step[2]])
    return out


def test_chunk_motions_compose_to_the_odometry_and_their_jacobian_is_exact() -> None:
    """Composed chunk by chunk, the motions give exactly the dead-reckoned end pose, every
    chunk ends where :func:`replay_odometry` puts that sample, and ∂u/∂x equals the
    replay Jacobian of a run that starts at the chunk's start."""
    run = _wiggly_run(np.random.default_rng(3))
    cal = Calibration.from_errors(1.004, 0.98, 1.01)
    poses = replay_odometry(run, ROBOT, cal)
    for every in (1, 7, 20, 500):
        u, jac, _, ends = chunk_motions(run, ROBOT, cal, every)
        assert ends[-1] == len(run.time) - 1
        np.testing.assert_allclose(_compose(run.true_pose[0], u), poses[-1], atol=1e-12)
        # chunk 1 on its own, as a run of its own
        c = min(1, len(ends) - 1)  # the second chunk, or the only one
        a, b = (0 if c == 0 else ends[c - 1]), ends[c]
        sub = Run(
            "free",
            run.time[a : b + 1],
            run.counts[a : b + 1] - run.counts[a],
            np.zeros((b - a + 1, 3)),
        )
        _, full = replay_with_jacobian(sub, ROBOT, cal)
        np.testing.assert_allclose(jac[c], full[-1], rtol=1e-12, atol=1e-15)


def test_chunk_noise_matches_a_monte_carlo_of_the_wheel_travel_noise() -> None:
    """The covariance of a chunk's motion per k² equals the sample covariance of the motions
    when each wheel's travel gets white noise of variance k²·|d| (Chong & Kleeman 1997,
    Eq. 4): 4 000 draws, within 7 % on the diagonal."""
    rng = np.random.default_rng(11)
    run = _wiggly_run(rng, samples=41)
    cal = Calibration()
    _, _, noise, _ = chunk_motions(run, ROBOT, cal, 40)
    per_tick = ROBOT.metres_per_tick
    steps = np.diff(run.counts, axis=0) * per_tick  # wheel travel [m]
    k = 0.002
    draws = []
    for _ in range(4000):
        travel = steps + rng.standard_normal(steps.shape) * k * np.sqrt(np.abs(steps))
        left, right = travel[:, 0], travel[:, 1]
        dtheta = (right - left) / ROBOT.wheelbase
        theta = np.concatenate([[0.0], np.cumsum(dtheta)])[:-1] + 0.5 * dtheta
        ds = 0.5 * (left + right)
        draws.append([np.sum(ds * np.cos(theta)), np.sum(ds * np.sin(theta)), np.sum(dtheta)])
    sample = np.cov(np.array(draws).T)
    np.testing.assert_allclose(np.diag(sample), np.diag(noise[0]) * k**2, rtol=0.07)


def _play_scripted(episodes: list[Episode]) -> None:
    live = list(episodes)
    while live:
        actions = [
            scripted_policy(ep.session.observation(), ep.session.budget, ep.session.runs_used)
            for ep in live
        ]
        results = step_episodes(live, actions, 0.0)
        live = [ep for ep, (_, _, done, _) in zip(live, results, strict=True) if not done]


def _log_errors(estimator: EndPoseEstimator, episode: Episode) -> np.ndarray:
    """Errors of (ln E_s, ln E_d, ln E_b), the order of ``relative_std``."""
    e_d, e_b, e_s = estimator.errors
    robot = episode.robot
    return np.log(np.array([e_s / robot.e_s, e_d / robot.e_d, e_b / robot.e_b]))


@pytest.mark.slow
def test_filter_posterior_matches_its_errors_and_beats_the_end_poses_on_the_same_runs() -> None:
    """On ``concrete`` and ``rough`` (24 robots, the scripted 8 runs): the RMS errors of
    ln E_s, ln E_d, ln E_b lie within a factor 1.6 of the filter's mean posterior standard
    deviations (a filter that ignored the floor's noise would be 3-10x overconfident on
    ``rough``: measured before the roughness refiltering), the roughness factor comes out
    near 1 and near 5, and the end-pose estimator fitted to the *same* runs has a 3x larger
    E_s error and a larger E_b error."""
    for floor, rho_range in (("concrete", (0.9, 1.5)), ("rough", (3.5, 7.0))):
        episodes = _episodes(range(24), floor, 8, "trajectory")
        _play_scripted(episodes)
        errors, stds, rhos, end_errors = [], [], [], []
        for ep in episodes:
            est = ep.session.estimator
            assert isinstance(est, TrajectoryEstimator)
            errors.append(_log_errors(est, ep))
            stds.append(est.relative_std * np.array(PRIOR_STD))
            rhos.append(est.roughness)
            end = EndPoseEstimator(ep.robot, SensorAccuracy())
            for (run, _), name in zip(est._runs, ep.session.history, strict=True):
                end.add(run, ITEM[name])
            end.fit(2)
            end_errors.append(_log_errors(end, ep))
        rms = np.sqrt(np.mean(np.square(errors), axis=0))
        predicted = np.mean(stds, axis=0)
        assert np.all(rms < 1.6 * predicted), (floor, rms, predicted)
        assert np.all(rms > predicted / 1.6), (floor, rms, predicted)
        assert rho_range[0] < np.median(rhos) < rho_range[1]
        end_rms = np.sqrt(np.mean(np.square(end_errors), axis=0))
        assert end_rms[0] > 3.0 * rms[0], (floor, end_rms, rms)
        assert end_rms[2] > rms[2], (floor, end_rms, rms)


def test_filter_recovers_the_true_errors_on_a_noiseless_floor() -> None:
    """With an exact sensor on the noiseless floor, 2 squares and a straight run pin
    E_d, E_b, E_s to 5e-5 (measured: 1e-5 to 3e-5; end poses alone: 1e-4 to 6e-3)."""
    robot = ROBOT.with_errors(1.006, 0.97, 1.012)
    from odomgym.baselines.validation import calibrate_in_simulation
    from odomgym.floor import FLOORS

    report = calibrate_in_simulation(
        SelfCal(budget=3, policy="scripted"),
        robot,
        FLOORS["smooth"],
        seed=5,
        sensor=SensorAccuracy(position_std=1e-5, heading_std=1e-5),
    )
    est = report.result.estimates
    assert abs(est["E_d"] - robot.e_d) < 5e-5
    assert abs(est["E_b"] - robot.e_b) < 5e-5
    assert abs(est["E_s"] - robot.e_s) < 5e-5


def test_observe_is_checked_everywhere() -> None:
    with pytest.raises(SpecError, match="observe must be one of trajectory, end_pose") as err:
        SelfCalSession(ROBOT, 4, observe="tape")
    assert err.value.field == "observe"
    with pytest.raises(SpecError, match="observe"):
        SelfCalibrationEnv(observe="mocap")
    with pytest.raises(SpecError, match="selfcal_end_pose always sees end poses only"):
        SelfCalEndPose(budget=4, observe="trajectory")
    assert isinstance(SelfCalSession(ROBOT, 4).estimator, TrajectoryEstimator)
    assert type(SelfCalSession(ROBOT, 4, observe="end_pose").estimator) is EndPoseEstimator


def test_a_learned_policy_runs_only_with_what_it_was_trained_to_see() -> None:
    """The shipped policy was trained on the trajectory filter's observations; asking it to
    drive an end-pose session is a one-line error, not a silently wrong policy."""
    from odomgym.baselines.validation import calibrate_in_simulation

    with pytest.raises(SpecError, match="trained with observe='trajectory'") as err:
        calibrate_in_simulation(SelfCal(budget=2, observe="end_pose"), ROBOT, seed=1)
    assert err.value.field == "observe"


@pytest.mark.slow
def test_run_information_adds_up_to_the_posterior_and_hardly_depends_on_the_data() -> None:
    """What an experiment design rests on (``benchmarks/design_bound.py``): the runs'
    information matrices, added to the prior's, give the filter's posterior information
    (measured: within 5e-4 relative on all three floors; asserted 1e-3), and one item's
    matrix at a given roughness hardly depends on the robot or its noise — 12 robots,
    different true errors and floor noise, their first 4 m square: within 2.6 % of the mean
    (measured; asserted 3.5 %). What does change the matrix is the roughness factor the runs
    reveal, the floor."""
    for floor in ("concrete", "rough", "cables"):
        episodes = _episodes(range(3), floor, 8, "trajectory")
        _play_scripted(episodes)
        for ep in episodes:
            est = ep.session.estimator
            assert isinstance(est, TrajectoryEstimator)
            est.fit()  # every run filtered with the roughness run_information uses
            total = est.prior_information + sum(est.run_information(run) for run, _ in est._runs)
            posterior = np.linalg.inv(est.covariance)
            rel = np.linalg.norm(total - posterior) / np.linalg.norm(posterior)
            assert rel < 1e-3, (floor, rel)
    episodes = _episodes(range(12), "concrete", 2, "trajectory")
    _play_scripted(episodes)
    matrices = []
    for ep in episodes:
        est = ep.session.estimator
        assert isinstance(est, TrajectoryEstimator)
        assert ep.session.history[0] == "square4-cw"
        est.roughness = 1.0
        matrices.append(est.run_information(est._runs[0][0]))
        est.roughness = 5.0  # a floor 5x as rough: the floor-dominated information drops
        rough = est.run_information(est._runs[0][0])
        assert np.trace(rough) < np.trace(matrices[-1]) / 5.0
    mean = np.mean(matrices, axis=0)
    spread = max(np.linalg.norm(m - mean) / np.linalg.norm(mean) for m in matrices)
    assert spread < 0.035, spread

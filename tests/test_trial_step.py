"""A Trial's step is one compiled call when its World can fuse its physics into it
(:func:`odomgym._kernels.control_step`, holding the arrays of every part in one
:class:`~odomgym._kernels.StepArrays`); it must do exactly what the parts' own public steps do
one after another (World.step, Odometry.update, RouteProgress.update, episode_report), through
everything that changes those arrays: resets, longer routes, a new calibration, pickling."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from odomgym._kernels import REPORT_WIDTH, episode_report
from odomgym.floor import FLOORS
from odomgym.odometry.calibration import Calibration
from odomgym.robot import PRESETS
from odomgym.sim.routes import square_route, straight_route
from odomgym.sim.trial import Trial

N = 3


def _trial() -> Trial:
    return Trial([PRESETS["labmate"]] * N, FLOORS["smooth"], square_route(1.0), dt=0.05)


def _step_by_parts(
    trial: Trial, actions: np.ndarray, report: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> np.ndarray:
    """What Trial.step does, through each part's own public step."""
    world, odometry, progress = trial.world, trial.odometry, trial.progress
    world.step(actions, scale=world.max_rate)  # a unit action is the top wheel rate
    odometry.update(world.counts, world.dt)
    advanced = progress.update(odometry.pose, odometry.wheel_speed, trial._max_speed)
    episodes, weights, out = report
    episode_report(
        world.pose,
        trial.start_poses,
        odometry.pose,
        world.counts,
        progress.index,
        progress.segment_counts,
        progress.state,
        world.time,
        episodes,
        weights,
        True,
        out,
    )
    return advanced


def _run(trial: Trial, steps: int, seed: int, *, by_parts: bool = False) -> np.ndarray:
    """Random actions; every step's report rows, odometry and true poses, and moves-on."""
    rng = np.random.default_rng(seed)
    episodes = np.zeros((N, 2))
    weights = np.array([1.0, 0.001, 1.0])
    step = _step_by_parts if by_parts else Trial.step
    rows = []
    for _ in range(steps):
        out = np.empty((N, REPORT_WIDTH))
        advanced = step(trial, rng.uniform(-1.0, 1.0, (N, 2)), (episodes, weights, out))
        rows.append(np.hstack([out, trial.odom_pose, trial.true_pose, advanced[:, None]]))
    return np.array(rows)


@pytest.mark.parametrize("floor", ["smooth", "bumpy"])  # fused physics, and not
def test_a_trial_step_is_its_parts_steps(floor: str) -> None:
    trial = Trial([PRESETS["labmate"]] * N, FLOORS[floor], square_route(1.0))
    assert trial.world.fuses_substeps == (floor == "smooth")
    parts = Trial([PRESETS["labmate"]] * N, FLOORS[floor], square_route(1.0))
    np.testing.assert_array_equal(_run(trial, 200, 1), _run(parts, 200, 1, by_parts=True))


def test_the_compiled_step_follows_resets_routes_and_calibrations() -> None:
    """A reset onto a longer route reallocates the route arrays, a new calibration changes
    the odometry's constants (an ICR offset among them), a partial reset moves some robots
    back: the fused step sees each as the World's own step does."""

    def story(trial: Trial, by_parts: bool) -> np.ndarray:
        rows = [_run(trial, 60, 2, by_parts=by_parts)]
        trial.reset(routes=[square_route(0.5), *[straight_route(2.0, return_trip=True)] * 2])
        rows.append(_run(trial, 60, 3, by_parts=by_parts))
        trial.odometry.set_calibration(Calibration(c_left=1.01, c_right=0.99), index=1)
        rows.append(_run(trial, 60, 4, by_parts=by_parts))
        # A skid-steer calibration: the ICR offsets reach the compiled step too.
        skid = Calibration(wheelbase_scale=1.6, icr_x=0.03, icr_y=-0.01)
        trial.odometry.set_calibration(skid, index=2)
        rows.append(_run(trial, 60, 8, by_parts=by_parts))
        trial.odometry.reset()
        trial.reset(indices=np.array([0, 2]))
        rows.append(_run(trial, 60, 5, by_parts=by_parts))
        return np.concatenate(rows)

    np.testing.assert_array_equal(story(_trial(), False), story(_trial(), True))


def test_an_unpickled_trial_gathers_its_own_arrays() -> None:
    trial = _trial()
    _run(trial, 50, 6)
    data = pickle.dumps(trial)
    np.testing.assert_array_equal(
        _run(pickle.loads(data), 50, 7), _run(pickle.loads(data), 50, 7, by_parts=True)
    )

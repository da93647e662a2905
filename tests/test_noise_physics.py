"""Floor roughness realised in the physics agrees with the closed form of Chong & Kleeman 1997.

The roughness k adds white noise of variance k²·|d| to each wheel's *ground* travel inside the
wheel–floor contact (odomgym.sim.world), while the encoders count the rim. So the odometry of N
robots commanded identically is identical, and their true poses scatter around it with the
covariance Chong & Kleeman 1997, Eqs. 23-28, predict along the driven wheel travels.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import odomgym
from odomgym.floor import CableBump, FloorSpec
from odomgym.noise.covariance import propagate_path
from odomgym.sim.driver import ReferenceDriver
from odomgym.sim.world import World

ROBOT = odomgym.PRESETS["labmate"].ideal()
RUNS = 1000
K = 0.001  # [m^½]; small enough that second-order effects stay below the tolerance


def _scatter(floor: FloorSpec, rim_speeds: tuple[float, float], steps: int, seed: int = 0):
    """Drive RUNS identical robots open-loop; return true − nominal end poses and the per-step
    wheel travels of the (identical, noise-free) encoder path."""
    world = World([ROBOT] * RUNS, floor, rng=np.random.default_rng(seed))
    radius = 0.5 * ROBOT.wheel_diameter
    command = np.tile(np.array(rim_speeds) / radius, (RUNS, 1))
    travels = []
    last = np.zeros(2)
    for _ in range(steps):
        world.step(command)
        angle = world.wheel_angle[0] * radius
        travels.append((float(angle[0] - last[0]), float(angle[1] - last[1])))
        last = angle.copy()
    nominal = propagate_path(travels, ROBOT.wheelbase, 0.0, 0.0).mean
    return world.pose - nominal, travels


def _assert_matches(errors: np.ndarray, predicted_cov: np.ndarray) -> None:
    emp_cov = np.cov(errors.T)
    emp_std = np.sqrt(np.diag(emp_cov))
    pred_std = np.sqrt(np.diag(predicted_cov))
    # Sample std of N normal draws: relative standard error 1/sqrt(2(N-1)) = 2.2 %; allow 4 SE.
    tolerance = 4.0 / math.sqrt(2 * (RUNS - 1))
    np.testing.assert_allclose(emp_std, pred_std, rtol=tolerance)
    # Correlations: Fisher z has standard error 1/sqrt(N-3); allow 4 SE.
    for i, j in ((0, 2), (1, 2), (0, 1)):
        rho_emp = emp_cov[i, j] / (emp_std[i] * emp_std[j])
        rho_pred = predicted_cov[i, j] / (pred_std[i] * pred_std[j])
        assert abs(np.arctanh(rho_emp) - np.arctanh(rho_pred)) < 4.0 / math.sqrt(RUNS - 3)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "rim_speeds", "steps"),
    [("straight 5 m", (0.5, 0.5), 200), ("arc", (0.3, 0.5), 200)],
)
def test_rough_floor_covariance_matches_closed_form(name: str, rim_speeds, steps: int) -> None:
    errors, travels = _scatter(FloorSpec(roughness=K), rim_speeds, steps)
    errors[:, 2] = np.mod(errors[:, 2] + math.pi, 2 * math.pi) - math.pi
    # The heading error (δ_R − δ_L)/b is linear in the noise: unbiased. (x and y carry
    # second-order biases such as the shortening −D·σ_θ²/2 on a straight line.)
    assert abs(errors[:, 2].mean()) < 4 * errors[:, 2].std() / math.sqrt(RUNS)
    predicted = propagate_path(travels, ROBOT.wheelbase, K, K).cov
    _assert_matches(errors, predicted)


@pytest.mark.slow
def test_bumps_are_heavy_tailed_roughness_is_not() -> None:
    """Roughness gives Gaussian heading errors (excess kurtosis ≈ 0); cables give discrete
    jumps: most robots miss them, the few whose wheel crosses one turn by ≈ 0.57° (heavy tails:
    a three-point distribution with P(jump) = p has excess kurtosis 1/p − 3)."""
    rough, _ = _scatter(FloorSpec(roughness=K), (0.5, 0.5), 200, seed=1)
    bumps = (
        CableBump(x=1.0, y=0.5, angle=math.pi / 2, diameter=0.01, length=0.1),
        CableBump(x=2.0, y=-0.5, angle=math.pi / 2, diameter=0.01, length=0.1),
    )
    world = World([ROBOT] * RUNS, FloorSpec(bumps=bumps))
    starts = np.zeros((RUNS, 3))
    starts[:, 1] = np.linspace(-1.0, 1.0, RUNS)
    world.reset(starts)
    command = np.full((RUNS, 2), 0.5 / (0.5 * ROBOT.wheel_diameter))
    for _ in range(200):
        world.step(command)
    bumpy = world.pose[:, 2]

    def excess_kurtosis(values: np.ndarray) -> float:
        centred = values - values.mean()
        return float(np.mean(centred**4) / np.mean(centred**2) ** 2 - 3.0)

    assert abs(excess_kurtosis(rough[:, 2])) < 0.6
    jumped = np.abs(bumpy) > 1e-6
    assert 0.1 < jumped.mean() < 0.3  # each cable meets a wheel of 10 % of the robots
    assert excess_kurtosis(bumpy) > 1.5


def test_env_reports_the_closed_form_covariance() -> None:
    env = gym.make("StraightLine-v0", robot=ROBOT, distance=2.0, covariance_k=(K, K))
    obs, info = env.reset(seed=0)
    driver = ReferenceDriver(ROBOT)
    while True:
        obs, _, terminated, truncated, info = env.step(driver(obs).astype(np.float32))
        if terminated or truncated:
            break
    cov = info["odom_covariance"]
    assert np.all(np.linalg.eigvalsh(cov) >= -1e-15)
    # The consistency of Chong & Kleeman 1997: the step-by-step composition equals one straight
    # segment (Eqs. 26-27) of the same length.
    travelled = float(info["odom_pose"][0])
    single = propagate_path([(travelled, travelled)], ROBOT.wheelbase, K, K).cov
    np.testing.assert_allclose(cov, single, rtol=0.02, atol=1e-12)
    with pytest.raises(ValueError, match="covariance_k"):
        gym.make("StraightLine-v0", covariance_k=(-1.0, 0.0))

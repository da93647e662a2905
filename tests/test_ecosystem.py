"""Issue 22: every env in the ecosystem's own one-liners — a rendered frame, a RecordVideo
video, SB3's ``PPO("MlpPolicy", env_id)``/``A2C``/``DQN`` and rl-zoo3's ``train`` with the
shipped hyperparameter files — and rendering that costs nothing when it is off."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from importlib import resources
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import odomgym

ENV_IDS = [
    "UMBmarkSquare-v0",
    "StraightLine-v0",
    "ClapperStraight-v0",
    "ClapperRectangle-v0",
    "SelfCalibration-v1",
]


def _act(env: gym.Env, step: int) -> object:  # type: ignore[type-arg]
    """A plausible action: forwards for the route envs, full speed for the CLAPPER, one 4 m
    square after another for the self-calibration session."""
    space = env.action_space
    if isinstance(space, gym.spaces.Discrete):
        return 1 + step % 2  # square4-cw, square4-ccw
    return np.full(space.shape, 0.6 if space.shape == (2,) else 1.0, dtype=np.float32)


def _count(frame: np.ndarray, colour: tuple[int, int, int]) -> int:
    return int(np.all(frame == np.array(colour, dtype=np.uint8), axis=-1).sum())


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_every_env_renders_a_frame(env_id: str) -> None:
    pytest.importorskip("pygame")
    from odomgym.envs.render import ESTIMATE, ROUTE, TRUE_PATH

    env = gym.make(env_id, render_mode="rgb_array")
    assert env.metadata["render_modes"] == ["human", "rgb_array"]
    assert env.metadata["render_fps"] > 0
    env.reset(seed=0)
    for k in range(3 if env_id == "SelfCalibration-v1" else 150):
        env.step(_act(env, k))
    frame = env.render()
    assert frame is not None and frame.dtype == np.uint8
    assert frame.ndim == 3 and frame.shape[2] == 3 and min(frame.shape[:2]) >= 300
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 20  # not blank
    # What the docs say is drawn: the true path/vehicle in blue (more than a legend sample)...
    assert _count(frame, TRUE_PATH) > 200
    if env_id.startswith("Clapper"):
        # ...the estimate in green, the linkage between the two trucks, the programmed path.
        from odomgym.envs.render import LINK

        assert _count(frame, ESTIMATE) > 100
        assert _count(frame, LINK) > 10
        assert _count(frame, ROUTE) > 200
    if env_id == "SelfCalibration-v1":
        from odomgym.envs.render import ODOM_PATH

        assert _count(frame, ESTIMATE) > 20  # the estimates' figures in the panel
        assert _count(frame, ODOM_PATH) > 100  # the latest run's odometry path
    env.close()


def test_the_trailer_renders_its_tongue() -> None:
    pytest.importorskip("pygame")
    from odomgym.envs.render import LINK, TRUE_PATH

    env = gym.make("ClapperRectangle-v0", vehicle="trailer", render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(100):
        env.step(np.ones(1, np.float32))
    frame = env.render()
    assert frame is not None and _count(frame, LINK) > 10 and _count(frame, TRUE_PATH) > 200
    env.close()


def test_the_clapper_frame_follows_its_odometry_off_the_path() -> None:
    """The trucks' own odometry drifts off the path (IPEC corrects the estimate, not it): the
    view grows to keep every path on screen, so the last frame of a whole run shows the orange
    odometry inside the map, none of it at the frame's edges."""
    pytest.importorskip("pygame")
    from odomgym.envs.render import ODOM_PATH

    env = gym.make("ClapperStraight-v0", render_mode="rgb_array")
    env.reset(seed=0)
    terminated = truncated = False
    while not (terminated or truncated):
        _, _, terminated, truncated, _ = env.step(np.ones(1, np.float32))
    frame = env.render()
    assert frame is not None
    header = 70  # the legend band above the map
    ys, xs = np.nonzero(np.all(frame[header:] == np.array(ODOM_PATH, np.uint8), axis=-1))
    assert len(xs) > 100
    assert xs.min() > 0 and xs.max() < frame.shape[1] - 1  # nothing cut at the edges
    assert ys.min() > 0 and ys.max() < frame.shape[0] - header - 1
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_record_video_writes_a_video(env_id: str, tmp_path: Path) -> None:
    pytest.importorskip("pygame")
    pytest.importorskip("moviepy")
    env = gym.make(env_id, render_mode="rgb_array")
    env = gym.wrappers.RecordVideo(
        env, str(tmp_path), episode_trigger=lambda _: True, video_length=12, disable_logger=True
    )
    env.reset(seed=0)
    for k in range(12):
        _, _, terminated, truncated, _ = env.step(_act(env, k))
        if terminated or truncated:
            break
    env.close()
    videos = list(tmp_path.glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000


def test_rendering_off_costs_nothing() -> None:
    """``render_mode=None``: pygame and the renderer are never imported, nothing is kept for
    drawing (in a fresh interpreter, so no other test's import counts)."""
    code = textwrap.dedent(
        f"""
        import sys
        import gymnasium as gym
        import numpy as np
        import odomgym
        for env_id in {ENV_IDS!r}:
            env = gym.make(env_id)
            env.reset(seed=0)
            for k in range(2):
                space = env.action_space
                action = 1 if isinstance(space, gym.spaces.Discrete) else space.sample()
                env.step(action)
            inner = env.unwrapped
            assert getattr(inner, "_trace", None) is None, env_id
            assert getattr(inner, "_history", [()])[1:] == [], env_id
            episode = getattr(inner, "episode", None)
            assert episode is None or episode.trace is None, env_id
        assert "pygame" not in sys.modules
        assert "odomgym.envs.render" not in sys.modules
        print("ok")
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip().endswith("ok")


def test_a_bad_render_mode_is_refused_naming_it() -> None:
    with pytest.raises(ValueError, match="render_mode must be one of"):
        gym.make("ClapperStraight-v0", render_mode="ascii")
    with pytest.raises(odomgym.errors.SpecError, match="render_mode must be one of"):
        gym.make("SelfCalibration-v1", render_mode="ascii")


# ------------------------------------------------------------------------------ SB3 one-liners


def _small(algo: str) -> dict[str, object]:
    """Settings that make 64 steps learn (the defaults collect 2048 steps before PPO's first
    update): two PPO rollouts and updates, thirteen A2C updates, twelve DQN gradient steps.
    A step of ``SelfCalibration-v1`` is a whole run, so steps are what a test pays for."""
    return {"ppo": {"n_steps": 32, "batch_size": 32}, "a2c": {}, "dqn": {"learning_starts": 16}}[
        algo
    ]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_sb3_makes_every_env_from_its_id(env_id: str) -> None:
    """The construction of ``PPO("MlpPolicy", env_id)`` alone (quick): SB3 asks for
    ``render_mode="rgb_array"``, which used to stop the self-calibration env (then
    ``SelfCalibration-v0``)."""
    sb3 = pytest.importorskip("stable_baselines3")
    model = sb3.PPO("MlpPolicy", env_id, device="cpu")
    assert model.get_env().envs[0].unwrapped.render_mode == "rgb_array"


# One run per step: a few hundred steps of the session env take 20-30 s.
_SLOW = pytest.mark.slow


@pytest.mark.parametrize(
    "env_id", [e if e != "SelfCalibration-v1" else pytest.param(e, marks=_SLOW) for e in ENV_IDS]
)
@pytest.mark.parametrize("algo", ["ppo", "a2c", "dqn"])
def test_sb3_one_liner_learns(env_id: str, algo: str) -> None:
    """``PPO("MlpPolicy", env_id)`` (and A2C; DQN where the actions are Discrete): SB3 makes
    the env from its id with ``render_mode="rgb_array"`` and learns for 64 steps."""
    sb3 = pytest.importorskip("stable_baselines3")
    spec = gym.spec(env_id)
    discrete = env_id == "SelfCalibration-v1"
    if algo == "dqn" and not discrete:
        pytest.skip("DQN needs a Discrete action space")
    model = getattr(sb3, algo.upper())("MlpPolicy", env_id, seed=0, device="cpu", **_small(algo))
    made = model.get_env().envs[0].unwrapped
    assert made.spec is not None and made.spec.id == spec.id
    assert made.render_mode == "rgb_array"  # the path that used to stop with a SpecError
    model.learn(64)
    assert model.num_timesteps >= 64
    obs = model.get_env().reset()
    action, _ = model.predict(obs, deterministic=True)
    assert model.get_env().action_space.contains(action[0])


# ------------------------------------------------------------------------------ rl-zoo3


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["ppo", "a2c", "dqn"])
def test_rl_zoo3_trains_from_the_shipped_hyperparameters(algo: str, tmp_path: Path) -> None:
    """The README's zoo command with the shipped file, shortened to 64 steps: two rollouts of
    two sessions (PPO and A2C: two updates; DQN: learning from step 16). Everything else —
    policy, gamma, net_arch, env_kwargs — as shipped."""
    pytest.importorskip("rl_zoo3")
    conf = resources.files("odomgym.data.hyperparams") / f"{algo}.yml"
    sizes = {"ppo": ["n_envs:2", "n_steps:16", "batch_size:32"], "a2c": ["n_envs:2"]}
    sizes["dqn"] = ["n_envs:2", "learning_starts:16"]
    command = [
        sys.executable,
        "-m",
        "rl_zoo3.train",
        "--algo",
        algo,
        "--env",
        "SelfCalibration-v1",
        "--gym-packages",
        "odomgym",
        "-conf",
        str(conf),
        "-n",
        "64",
        "-f",
        str(tmp_path),
        "--eval-freq",
        "-1",
        "--seed",
        "0",
        "-params",
        *sizes[algo],
    ]
    env = {**os.environ, "SDL_VIDEODRIVER": "dummy", "CUDA_VISIBLE_DEVICES": ""}
    result = subprocess.run(
        command, capture_output=True, text=True, timeout=600, check=False, env=env
    )
    assert result.returncode == 0, (result.stdout[-2000:], result.stderr[-3000:])
    run = tmp_path / algo / "SelfCalibration-v1_1"
    assert (run / "SelfCalibration-v1.zip").is_file()
    import yaml

    # The zoo writes its config as a Python OrderedDict; this file is its own output from this
    # test's temporary folder, so the unsafe loader reads nothing foreign.
    config = (run / "SelfCalibration-v1" / "config.yml").read_text()
    saved = dict(yaml.load(config, Loader=yaml.UnsafeLoader))
    assert saved["gamma"] == 1.0  # the shipped value reached the algorithm
    assert "net_arch" in str(saved["policy_kwargs"])
    shipped = yaml.safe_load(conf.read_text())["SelfCalibration-v1"]
    assert dict(saved["env_kwargs"]) == shipped["env_kwargs"]

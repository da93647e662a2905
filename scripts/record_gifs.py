"""Record the animated GIF at the top of each env's documentation page, from a fixed seed.

    SDL_VIDEODRIVER=dummy python scripts/record_gifs.py             # all five envs
    SDL_VIDEODRIVER=dummy python scripts/record_gifs.py --only ClapperStraight-v0

Each env is made with ``render_mode="rgb_array"`` and driven by a fixed, documented policy
(the route envs by :class:`odomgym.sim.driver.ReferenceDriver`, the CLAPPER at full speed along
its path, the self-calibration session by the shipped learned policy); about ``FRAMES``
evenly spaced frames and the last one (held for two seconds) go into
``docs/assets/gifs/<env id>.gif`` with one shared palette, so a GIF stays well under the
documentation's 1 MB budget (the script fails if one does not). The same seed and code
give the same frames, so re-recording changes a GIF only when the env or the renderer
changed. Needs the ``[render]`` extra (pygame) and Pillow (a matplotlib dependency).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray
from PIL import Image

import odomgym  # noqa: F401  (registers the envs)
from odomgym.odometry.calibration import Calibration

OUT = Path(__file__).resolve().parents[1] / "docs" / "assets" / "gifs"
FRAMES = 60
"""Frames per GIF (besides the held last one): enough to see the motion, few enough to stay
small."""
LIMIT = 1_000_000
"""The largest GIF the documentation accepts [bytes]."""
SEED = 0

Policy = Callable[[Any, Any], Any]


def _route_policy(env: gym.Env[Any, Any]) -> Policy:
    from odomgym.sim.driver import ReferenceDriver

    driver = ReferenceDriver(env.unwrapped.robot)  # type: ignore[attr-defined]
    return lambda obs, _info: driver(obs).astype(np.float32)


def _full_speed(env: gym.Env[Any, Any]) -> Policy:
    return lambda _obs, _info: np.ones(1, dtype=np.float32)


def _learned(env: gym.Env[Any, Any]) -> Policy:
    from odomgym.baselines.selfcal import load_policy

    policy = load_policy("learned")
    return lambda obs, _info: policy(obs)


# recording -> (make() arguments, reset options, policy, frame duration [ms]); a recording is an
# env id, or an env id and a label after "+" (the GIF is then ``<env id>-<label>.gif``)
RECORDINGS: dict[str, tuple[dict[str, Any], dict[str, Any], Callable[..., Policy], int]] = {
    "UMBmarkSquare-v0": ({"floor": "bumpy"}, {"direction": "cw"}, _route_policy, 120),
    "StraightLine-v0": ({"floor": "bumpy"}, {"return_trip": True}, _route_policy, 120),
    "ClapperStraight-v0": ({}, {}, _full_speed, 120),
    "ClapperRectangle-v0": ({}, {}, _full_speed, 120),
    "SelfCalibration-v1": ({"budget": 16}, {"floor": "rough"}, _learned, 700),
    # A skid-steer robot whose odometry takes the apparent track the trajectory calibration
    # fits on it (`odomgym calibrate trajectory --robot scout2 --side 2`: E_b = 1.6723), so
    # that it drives its square (docs/skid-steer.md); without it the robot turns ~52° a corner.
    "UMBmarkSquare-v0+scout2": (
        {"robot": "scout2", "side": 2.0, "calibration": Calibration(wheelbase_scale=1.6723)},
        {"direction": "cw"},
        _route_policy,
        120,
    ),
}


def _episode(env_id: str) -> tuple[list[NDArray[np.uint8]], int]:
    """Every frame of one seeded episode, and the number of steps it took."""
    kwargs, options, make_policy, _ = RECORDINGS[env_id]
    env = gym.make(env_id.split("+")[0], render_mode="rgb_array", **kwargs)
    obs, info = env.reset(seed=SEED, options=options)
    policy = make_policy(env)
    frames: list[NDArray[np.uint8]] = []
    steps = 0
    keep_every = 1 if env_id == "SelfCalibration-v1" else 10  # drawing every step is waste
    while True:
        if steps % keep_every == 0:
            frames.append(env.render())  # type: ignore[arg-type]
        obs, _, terminated, truncated, info = env.step(policy(obs, info))
        steps += 1
        if terminated or truncated:
            frames.append(env.render())  # type: ignore[arg-type]
            break
    env.close()
    return frames, steps


def record(env_id: str) -> tuple[Path, int, int]:
    """Write ``OUT/<env_id>.gif``; returns its path, size [bytes] and the episode's steps."""
    frames, steps = _episode(env_id)
    duration = RECORDINGS[env_id][3]
    if len(frames) > FRAMES:
        picks = np.linspace(0, len(frames) - 1, FRAMES).round().astype(int)
        frames = [frames[i] for i in picks]
    # One palette for all frames, from the last one (every path drawn by then).
    palette = Image.fromarray(frames[-1]).quantize(colors=64, dither=Image.Dither.NONE)
    images = [
        Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames
    ]
    durations = [duration] * (len(images) - 1) + [2000]
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / f"{env_id.replace('+', '-')}.gif"
    images[0].save(
        path,
        save_all=True,
        append_images=images[1:],
        duration=durations,
        loop=0,
        optimize=True,
    )
    return path, path.stat().st_size, steps


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", choices=sorted(RECORDINGS), action="append")
    args = parser.parse_args(argv)
    too_big = []
    for env_id in args.only or list(RECORDINGS):
        path, size, steps = record(env_id)
        print(f"{path.relative_to(OUT.parents[2])}: {size / 1e3:.0f} kB ({steps} steps)")
        if size > LIMIT:
            too_big.append(f"{path.name} is {size / 1e6:.2f} MB")
    if too_big:
        print("over the 1 MB limit: " + "; ".join(too_big), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

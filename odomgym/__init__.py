"""odomgym: wheel-odometry (dead-reckoning) research on a pymunk differential-drive simulator.

Importing ``odomgym`` registers the Gymnasium environments (string entry points, so no env
module is imported until ``gymnasium.make`` needs it):

* ``UMBmarkSquare-v0`` — the UMBmark bi-directional square (Borenstein & Feng 1994);
* ``StraightLine-v0`` — straight runs, optionally out and back (Borenstein's CLAPPER paper);
* ``ClapperStraight-v0``, ``ClapperRectangle-v0`` — the CLAPPER vehicle with IPEC (Borenstein
  1995, §6);
* ``SelfCalibration-v1`` — choose the experiments that calibrate a robot within a budget; its
  estimator filters every measured pose of each run. ``SelfCalibration-v0`` is the same env
  with the earlier estimator (end poses only, ``observe="end_pose"``), kept so that code and
  results made with it stay reproducible.

The core API: :class:`~odomgym.robot.RobotSpec`, :class:`~odomgym.floor.FloorSpec`,
:class:`~odomgym.sim.world.World`, :class:`~odomgym.odometry.calibration.Odometry`,
:class:`~odomgym.odometry.calibration.Calibration`, :class:`~odomgym.sim.trial.Trial`,
:class:`~odomgym.sim.driver.ReferenceDriver`, :class:`~odomgym.lab.simulated.SimLab`.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _distribution_version

from odomgym._source_tree import install_source_tree_finder
from odomgym.floor import FLOORS, CableBump, FloorSpec, FrictionPatch, load_floor
from odomgym.odometry.calibration import Calibration, Odometry, load_calibration
from odomgym.robot import PRESETS, RobotSpec, load_robot

# In a source checkout (Python started in the repository root), ``odomgym/`` shadows the
# installed package and lacks ``envs`` and ``baselines``, which setuptools' ``package-dir`` maps
# in from the top-level folders; this finder maps them the same way. A no-op when installed.
install_source_tree_finder()

# The version is written once, in pyproject.toml; the installed distribution's metadata carries
# it here (an editable install's too). A source tree run without any install has no metadata:
# "0+unknown" says so rather than a number that may be stale.
try:
    __version__: str = _distribution_version("odomgym")
except PackageNotFoundError:  # pragma: no cover - only in an uninstalled checkout
    __version__ = "0+unknown"

__all__ = [
    "FLOORS",
    "PRESETS",
    "CableBump",
    "Calibration",
    "FloorSpec",
    "FrictionPatch",
    "Odometry",
    "RobotSpec",
    "__version__",
    "load_calibration",
    "load_floor",
    "load_robot",
    "register_envs",
]

# id -> (entry point, vector entry point, max_episode_steps, default kwargs)
_ENVS: dict[str, tuple[str, str | None, int, dict[str, object]]] = {
    "UMBmarkSquare-v0": (
        "odomgym.envs.umbmark:UMBmarkSquareEnv",
        "odomgym.envs.vector:make_square_vector_env",
        6000,
        {},
    ),
    "StraightLine-v0": (
        "odomgym.envs.straight:StraightLineEnv",
        "odomgym.envs.vector:make_straight_vector_env",
        4000,
        {},
    ),
    # The CLAPPER (Borenstein 1995, §6): 36 m out and back takes ~2100 steps of 40 ms, the
    # 7×4 m rectangle ~1500.
    "ClapperStraight-v0": ("odomgym.envs.clapper:ClapperStraightEnv", None, 6000, {}),
    "ClapperRectangle-v0": ("odomgym.envs.clapper:ClapperRectangleEnv", None, 4000, {}),
    # One step per run: at most MAX_BUDGET (64) runs and the stop (a margin of one, so the
    # limit never truncates a session). v1 estimates with the trajectory filter (observation
    # version 2); v0 keeps the end-pose estimator it was published with (the env's version
    # history says what changed).
    "SelfCalibration-v0": (
        "odomgym.envs.selfcal:SelfCalibrationEnv",
        None,
        66,
        {"observe": "end_pose"},
    ),
    "SelfCalibration-v1": ("odomgym.envs.selfcal:SelfCalibrationEnv", None, 66, {}),
}


def register_envs() -> None:
    """Register odomgym's envs with Gymnasium; safe to call more than once."""
    import gymnasium

    for env_id, (entry_point, vector_entry_point, max_steps, kwargs) in _ENVS.items():
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point=entry_point,
            max_episode_steps=max_steps,
            vector_entry_point=vector_entry_point,
            kwargs=dict(kwargs),
        )


register_envs()

"""Every command in README.md's code blocks runs, as written, in a fresh folder.

The README is parsed, not copied: a command edited there is the command tested here. ``odomgym …``
lines run in-process through :func:`odomgym.cli.main` (exit 0, and every file a ``wrote:`` line
names exists); ``python …`` lines and the Python example run in a subprocess. All of them share
one scratch folder, where the README's relative output paths land, with ``examples/`` linked in.
A command that reads a file another README command writes (``runs.csv``, ``robot.toml``,
``calib.toml``) first runs that command if the file is not there yet, so any one test can run
alone.

What differs from the README, and why (nothing is skipped):

* the first set-up command is ``python3 -m venv … && pip install -q . && odomgym bench …``: the
  tests run in an installed environment, so only the job after the last ``&&`` runs here; the
  install part is checked to install this folder
  (:func:`test_setup_commands_do_what_the_readme_says`);
* ``bash scripts/test.sh`` (the second set-up command) runs the whole test suite, this file
  included; it is checked to run the gates the README lists, not run;
* ``odomgym bench calibrators --robots N`` runs with ``--robots 1`` (:data:`BENCH_ROBOTS`): the
  benchmark's cost is linear in the robots (the README's 10 robots take about a minute on 2
  cores, 100 robots about 3.5 minutes), and one robot still runs every method on every floor
  through every output;
* ``bags/`` for the ROS 2 example is written here from ``runs.csv`` (one bag per run: a
  ``sensor_msgs/JointState`` topic of wheel angles and a ``PoseStamped`` ground truth), since
  no README command writes bags.
"""

from __future__ import annotations

import math
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from odomgym.cli import main

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
BENCH_ROBOTS = "1"
SLOW = ("odomgym bench", "odomgym diagnose", "odomgym run clapper-rectangle")  # ≥ 3 s each

# Files a README command reads, and a snippet of the README command that writes them.
PRODUCERS = {
    "runs.csv": "--log runs.csv",
    "robot.toml": "save('robot.toml')",
    "calib.toml": "--save calib.toml",
}


@dataclass(frozen=True)
class Command:
    """One command of a README code block."""

    text: str  # as the README states it (comment removed)
    argv: tuple[str, ...]  # what runs here

    @property
    def id(self) -> str:
        return re.sub(r"[^A-Za-z0-9_.:/-]+", "_", self.text)[:70]


def _blocks() -> list[tuple[str, str]]:
    """(language, body) of every fenced code block."""
    text = README.read_text(encoding="utf-8")
    return re.findall(r"^```(\w*)\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL)


def _commands() -> list[Command]:
    commands: list[Command] = []
    for language, body in _blocks():
        if language != "bash":
            continue
        for line in body.splitlines():
            words = shlex.split(line, comments=True)
            if not words or words[0] == "bash":  # scripts/test.sh: see the module docstring
                continue
            text = re.sub(r"\s{2,}#.*$", "", line).strip()
            if "&&" in words:  # set-up: venv && pip install && the job
                words = words[len(words) - words[::-1].index("&&") :]
            words[0] = Path(words[0]).name  # .venv/bin/odomgym → odomgym
            if words[:3] == ["odomgym", "bench", "calibrators"] and "--robots" in words:
                words[words.index("--robots") + 1] = BENCH_ROBOTS
            assert words[0] in ("odomgym", "python"), f"README command not understood: {line}"
            if Command(text, tuple(words)) not in commands:
                commands.append(Command(text, tuple(words)))
    return commands


COMMANDS = _commands()


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("readme")
    (folder / "examples").symlink_to(REPO / "examples", target_is_directory=True)
    return folder


def _ensure(name: str, workspace: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Run the README command that writes ``name`` unless it is there already."""
    if not (workspace / name).exists():
        (producer,) = [c for c in COMMANDS if PRODUCERS[name] in c.text]
        _run(producer, workspace, capsys)


def _run(command: Command, workspace: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for name, snippet in PRODUCERS.items():
        if name in command.argv and snippet not in command.text:  # an input, not its output
            _ensure(name, workspace, capsys)
    if any(Path(word).parts[:1] == ("bags",) for word in command.argv):
        _ensure("runs.csv", workspace, capsys)
        _ensure("robot.toml", workspace, capsys)
        _write_bags(workspace)
    if command.argv[0] == "python":
        done = subprocess.run(
            [sys.executable, *command.argv[1:]],
            cwd=workspace,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert done.returncode == 0, f"{command.text}\n{done.stderr}"
        return
    capsys.readouterr()
    code = main(list(command.argv[1:]))
    out, err = capsys.readouterr()
    assert code == 0, f"{command.text}\n{err}"
    for line in (out + err).splitlines():
        if line.startswith("wrote: "):
            for path in line.removeprefix("wrote: ").split(", "):
                assert (workspace / path).exists(), f"{command.text}: {path} not written"


@pytest.mark.parametrize(
    "command",
    [
        pytest.param(
            c, id=c.id, marks=[pytest.mark.slow] if " ".join(c.argv).startswith(SLOW) else []
        )
        for c in COMMANDS
    ],
)
def test_readme_command(
    command: Command,
    workspace: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.chdir(workspace)
    _run(command, workspace, capsys)


def test_readme_lists_the_commands_it_promises() -> None:
    """The parse found every command family (a README reshuffle must not empty this test)."""
    texts = [c.text for c in COMMANDS]
    for family in ("run square", "run straight", "calibrate", "bench calibrators",
                   "leaderboard", "covariance", "fit-noise", "diagnose"):  # fmt: skip
        assert any(t.startswith(f"odomgym {family}") for t in texts), family
    assert texts[0].startswith("python3 -m venv .venv && .venv/bin/pip install -q . && ")


def test_readme_python_example(workspace: Path) -> None:
    (code,) = [body for language, body in _blocks() if language == "python"]
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=workspace, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    numbers = [float(n) for n in re.findall(r"-?\d+\.\d+(?:e-?\d+)?", done.stdout)]
    assert len(numbers) == 3 and all(math.isfinite(n) for n in numbers)  # x, y, θ


def test_setup_commands_do_what_the_readme_says() -> None:
    """Set-up 1 installs this folder and runs the job tested above; set-up 2 is
    ``bash scripts/test.sh``, which installs every extra and runs the gates the README names."""
    setups = [body.strip() for language, body in _blocks() if language == "bash"][:2]
    install, job = setups[0].rsplit(" && ", 1)
    assert install == "python3 -m venv .venv && .venv/bin/pip install -q ."
    assert (REPO / "pyproject.toml").is_file()
    assert job.startswith(".venv/bin/odomgym bench calibrators ")
    assert setups[1] == "bash scripts/test.sh"
    script = (REPO / "scripts" / "test.sh").read_text(encoding="utf-8")
    for step in ('".[all]"', 'ruff" check', 'ruff" format --check', "mypy", "pytest"):
        assert step in script, step


def _write_bags(workspace: Path) -> None:
    """``bags/``: one ROS 2 bag per run of ``runs.csv`` (wheel joint angles from the counts of
    ``robot.toml``'s encoders, the true pose as PoseStamped, both stamped at the log's sample
    times), named by experiment so that the reader labels each run's kind and direction."""
    bags = workspace / "bags"
    if bags.exists():
        return
    pytest.importorskip("rosbags", reason="the README's ROS 2 example needs odomgym[ros]")
    import numpy as np
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    from odomgym.data.native import read_native
    from odomgym.robot import load_robot

    robot = load_robot(workspace / "robot.toml")
    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    pose_type, joint_type = "geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/JointState"
    staging = workspace / ".bags"
    for number, run in enumerate(read_native(workspace / "runs.csv"), start=1):
        with Writer(staging / f"{run.meta['experiment']}-{number:02d}", version=9) as writer:
            poses = writer.add_connection("/mocap/pose", pose_type, typestore=store)
            joints = writer.add_connection("/joint_states", joint_type, typestore=store)
            for t, counts, (x, y, theta) in zip(run.time, run.counts, run.true_pose, strict=True):
                ns = round(1e9 * (1000.0 + float(t)))
                stamp = types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
                header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="world")
                pose = types[pose_type](
                    header=header,
                    pose=types["geometry_msgs/msg/Pose"](
                        position=types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                        orientation=types["geometry_msgs/msg/Quaternion"](
                            x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2)
                        ),
                    ),
                )
                angles = np.asarray(counts, dtype=np.float64) * 2 * math.pi / robot.ticks_per_rev
                joint = types[joint_type](
                    header=header,
                    name=["left_wheel_joint", "right_wheel_joint"],
                    position=angles,
                    velocity=np.zeros(0),
                    effort=np.zeros(0),
                )
                writer.write(poses, ns, store.serialize_cdr(pose, pose_type))
                writer.write(joints, ns, store.serialize_cdr(joint, joint_type))
    staging.rename(bags)

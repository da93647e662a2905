"""``diagnose`` on real data, twice: two disjoint sets of sessions of the same robot must give
the mean wheel diameter on the side of nominal that the data show, with overlapping
session-clustered intervals (the issue also asks for the same set of systematic effects: not
met, see the test's docstring).

The OptiOdom robot (Sousa et al. 2022; MIT): set A is the six sessions shipped in the package
(three square, one circular, two Ivanjko), set B the other eight of the published data (one
square, five circular, two Ivanjko), shipped with the tests as one ``.tar.xz`` per session in
``tests/data/optiodom-replication`` (1.8 MB; the MIT licence beside them) so that the test
runs on any clone. Every published calibration of these sessions (``published_results.csv``:
UMBmark, Jung & Chung, Ivanjko et al., OptiOdom) puts the mean wheel diameter at or below the
nominal 84 mm, and the circles of both sets run short along the track; the diagnosis must
agree (E_s < 1) in both. The docs' table (``docs/diagnose.md``, "Results: the real OptiOdom
robot, twice") comes from the commands given there.
"""

from __future__ import annotations

import math
import shutil
import tarfile
from pathlib import Path

import pytest
from scipy import stats

from odomgym.data import sample_session
from odomgym.data.logs import read_log
from odomgym.diagnose.workflow import DiagnoseConfig, Diagnosis, diagnose
from odomgym.robot import load_robot

ROOT = Path(__file__).resolve().parents[1]
SET_B_ARCHIVES = ROOT / "tests" / "data" / "optiodom-replication"
SET_A = [
    "square/230620202042",
    "square/230620202144",
    "square/230620202317",
    "circular/250620202104",
    "ivanjko/250620201618",
    "ivanjko/250620201636",
]
SET_B = [
    "square/230620202258",
    "circular/250620202119",
    "circular/250620202236",
    "circular/250620202251",
    "circular/250620202317",
    "circular/250620202345",
    "ivanjko/250620201655",
    "ivanjko/250620201738",
]


def diagnose_sessions(sessions: list[str], folder: Path) -> Diagnosis:
    """Diagnose ``sessions`` (set A from the package, set B from the test archives; gathered in
    ``folder``) against the robot as its makers specify it."""
    for name in sessions:
        kind, session = name.split("/")
        target = folder / kind
        target.mkdir(parents=True, exist_ok=True)
        archive = SET_B_ARCHIVES / f"{kind}-{session}.tar.xz"
        if archive.is_file():
            with tarfile.open(archive) as tar:
                if hasattr(tarfile, "data_filter"):  # Python >= 3.11.4
                    tar.extractall(target, filter="data")
                else:  # our own archives, written by this repository
                    tar.extractall(target)
        else:  # the reader does not follow symbolic links: copy
            shutil.copytree(sample_session(name), target / session)
    model = load_robot(ROOT / "examples" / "optiodom_nominal.toml")
    runs, _ = read_log(folder, robot=model, format="optiodom")
    return diagnose(runs, model, DiagnoseConfig(jobs=2))


@pytest.mark.slow
def test_two_sets_of_sessions_put_the_wheels_on_the_same_side_of_nominal(tmp_path: Path) -> None:
    """Both sets name the distance scale, below 1 (the side the circles and every published
    calibration show; before issue 17 a second set gave E_s = 1.004), with overlapping 95 %
    intervals when the standard error is clustered by session (the robot and its markers
    changed between sessions; the model-based standard errors, which assume independent
    innovations, are 2–4 × smaller and their intervals do not overlap). Not met, and not
    pinned: the same *set* of systematic effects (the wheelbase is named in set B only)."""
    a = diagnose_sessions(SET_A, tmp_path / "a")
    b = diagnose_sessions(SET_B, tmp_path / "b")
    # The same mean diameter within the sessions' own spread: 95 % intervals from the
    # session-clustered standard error with Student's t on G − 1 degrees of freedom (few
    # clusters), G = 6 and 8 sessions.
    intervals = []
    for result, sessions in ((a, SET_A), (b, SET_B)):
        e_s = result.parameters["distance_scale"]["e_s"]
        half = stats.t.ppf(0.975, len(sessions) - 1) * e_s["stderr_sessions"]
        intervals.append((e_s["value"] - half, e_s["value"] + half))
    (low_a, high_a), (low_b, high_b) = intervals
    assert max(low_a, low_b) < min(high_a, high_b), intervals
    for result in (a, b):
        circles = [
            f for f in result.findings if f.group.endswith("circular") and f.component == "along"
        ]
        assert circles and all(f.mean < 0 for f in circles), circles
        assert "distance_scale" in result.systematic_effects, result.named_effects
        e_s = result.parameters["distance_scale"]["e_s"]
        assert e_s["value"] + 3 * e_s["stderr"] < 1.0, e_s
        # Per-session frames take the marker bodies' yaw: no wheel toe stands in for them.
        assert "wheel_toe" not in result.named_effects
        assert len(result.session_frames) == len({str(r) for r in result.session_frames})
        assert not math.isnan(result.gap_after)

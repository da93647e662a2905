"""``diagnose`` on real data, twice: two disjoint sets of sessions of the same robot must give
the mean wheel diameter on the side of nominal that the data show (the issue also asks for the
same systematic effects with overlapping intervals: not met, see the test's docstring).

The OptiOdom robot (Sousa et al. 2022; MIT): set A is the six sessions shipped in the package
(three square, one circular, two Ivanjko), set B the other eight of the published data
(``shared/data/optiodom-diff``: one square, five circular, two Ivanjko). Every published
calibration of these sessions (``published_results.csv``: UMBmark, Jung & Chung, Ivanjko et al.,
OptiOdom) puts the mean wheel diameter at or below the nominal 84 mm, and the circles of both
sets run short along the track; the diagnosis must agree (E_s < 1) in both. The docs' table
(``docs/diagnose.md``, "Replication") is printed by ``benchmarks/bench_diagnose.py
--replication``.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pytest
from conftest import SHARED

from odomgym.data.logs import read_log
from odomgym.diagnose.workflow import DiagnoseConfig, Diagnosis, diagnose
from odomgym.robot import load_robot

ROOT = Path(__file__).resolve().parents[1]
FULL = SHARED / "data" / "optiodom-diff"
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
    """Diagnose ``sessions`` of the full data set (copied into ``folder``) against the robot as
    its makers specify it."""
    for name in sessions:
        target = folder / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copytree(FULL / name, target)  # the reader does not follow symbolic links
    model = load_robot(ROOT / "examples" / "optiodom_nominal.toml")
    runs, _ = read_log(folder, robot=model, format="optiodom")
    return diagnose(runs, model, DiagnoseConfig(jobs=2))


@pytest.mark.slow
@pytest.mark.skipif(not FULL.is_dir(), reason="needs shared/data/optiodom-diff (CI has it)")
def test_two_sets_of_sessions_put_the_wheels_on_the_same_side_of_nominal(tmp_path: Path) -> None:
    """Both sets name the distance scale, below 1 (the side the circles and every published
    calibration show; before issue 17 a second set gave E_s = 1.004). The issue's stronger
    target — the same systematic effects with overlapping intervals — is not met (docs table:
    E_s 0.9949 ± 0.0002 vs 0.9964 ± 0.0003, wheelbase named in one set only); this test pins
    what holds."""
    a = diagnose_sessions(SET_A, tmp_path / "a")
    b = diagnose_sessions(SET_B, tmp_path / "b")
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

"""``diagnose`` on real data, twice: two disjoint sets of sessions of the same robot must give
the same systematic effects with overlapping intervals, and the mean wheel diameter on the side
of nominal that the data show.

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
    """Diagnose ``sessions`` of the full data set (linked into ``folder``) against the robot as
    its makers specify it."""
    for name in sessions:
        target = folder / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.symlink_to(FULL / name, target_is_directory=True)
    model = load_robot(ROOT / "examples" / "optiodom_nominal.toml")
    runs, _ = read_log(folder, robot=model, format="optiodom")
    return diagnose(runs, model, DiagnoseConfig(jobs=2))


@pytest.mark.slow
@pytest.mark.skipif(not FULL.is_dir(), reason="needs shared/data/optiodom-diff (CI has it)")
def test_two_sets_of_sessions_give_the_same_systematic_effects(tmp_path: Path) -> None:
    a = diagnose_sessions(SET_A, tmp_path / "a")
    b = diagnose_sessions(SET_B, tmp_path / "b")
    common = set(a.systematic_effects) & set(b.systematic_effects)
    assert common, (a.systematic_effects, b.systematic_effects)
    for name in common:
        for key, entry in a.parameters[name].items():
            other = b.parameters[name][key]
            spread = 1.96 * (entry["stderr"] + other["stderr"])
            assert abs(entry["value"] - other["value"]) < spread, (name, key, entry, other)
    for result in (a, b):
        # The circles run short along the track, and every published calibration puts the mean
        # diameter at or below nominal: E_s must not say the wheels are larger.
        circles = [
            f for f in result.findings if f.group.endswith("circular") and f.component == "along"
        ]
        assert all(f.mean < 0 for f in circles), circles
        e_s = result.parameters.get("distance_scale", {}).get("e_s", {"value": 1.0})["value"]
        assert e_s <= 1.0, result.parameters
        assert not math.isnan(result.gap_after)

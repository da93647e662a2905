"""The allocator setting a diagnosis makes (``odomgym._alloc``): on glibc it is made, the
environment can refuse it, and it changes no number of a diagnosis."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

GLIBC = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"

# A short diagnosis whose whole report.json is printed (the allocator setting applies in
# diagnose(), once per process, so each setting needs a process of its own).
_SCRIPT = """
import hashlib, numpy as np
from alien_robot import generate_session
from odomgym._alloc import keep_freed_memory
from odomgym.diagnose.report import report_json
from odomgym.diagnose.workflow import DiagnoseConfig, diagnose
from odomgym.robot import RobotSpec
runs = generate_session({"sideslip": {"value": 0.03}}, np.random.default_rng(5))[:8]
model = RobotSpec(wheel_diameter=0.084, wheelbase=0.2, ticks_per_rev=2796.8)
text = report_json(diagnose(runs, model, DiagnoseConfig(seed=5)))
print(keep_freed_memory(), hashlib.sha256(text.encode()).hexdigest())
"""


def _run(code: str, **env: str) -> str:
    here = os.path.dirname(__file__)
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=here,
        env={**os.environ, "PYTHONPATH": here, **env},
        timeout=600,
    )
    return done.stdout.strip().splitlines()[-1]


@pytest.mark.skipif(not GLIBC, reason="mallopt is glibc's")
def test_the_thresholds_are_raised_once_unless_the_environment_says_no() -> None:
    code = "from odomgym._alloc import keep_freed_memory as k; print(k(), k())"
    assert _run(code) == "True True"
    assert _run(code, ODOMGYM_MALLOPT="0") == "False False"


@pytest.mark.slow
@pytest.mark.skipif(not GLIBC, reason="mallopt is glibc's")
def test_a_diagnosis_is_the_same_bytes_with_and_without_the_setting() -> None:
    kept = _run(_SCRIPT).split()
    plain = _run(_SCRIPT, ODOMGYM_MALLOPT="0").split()
    assert kept[0] == "True" and plain[0] == "False"
    assert kept[1] == plain[1]

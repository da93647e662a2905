"""Borenstein & Feng 1994, Table III, on the physics simulator: UMBmark and Jung & Chung calibrate
the LabMate.

Table III lists E_max,syst before and after UMBmark compensation for eight LabMate experiments
(4 × 4 m squares, 5 cw + 5 ccw): 232–423 mm before, 10- to 22-fold improvements after. The
``labmate`` preset carries the errors of Fig. 6.5 / experiment E-1 (317 mm before). On the
smooth simulated floor (no cable bumps, sensor noise only) the non-systematic spread is smaller
than in 1994, so the improvement is larger (68–83-fold for UMBmark over seeds 0–2, measured).
"""

from __future__ import annotations

import numpy as np
import pytest

from odomgym.baselines.jung_chung import JungChung
from odomgym.baselines.umbmark import UMBmark, perform_squares
from odomgym.lab.simulated import SimLab
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import return_error
from odomgym.odometry.umbmark_measures import e_max_syst
from odomgym.robot import PRESETS

LABMATE = PRESETS["labmate"]


def _e_max_syst(lab: SimLab, calibration: Calibration) -> float:
    """E_max,syst [m] of a fresh 5 cw + 5 ccw UMBmark run with ``calibration`` (Eq. 3.3)."""
    cw, ccw = perform_squares(lab, calibration, 4.0, 5)
    return e_max_syst(
        [return_error(r, LABMATE, calibration) for r in cw],
        [return_error(r, LABMATE, calibration) for r in ccw],
    )


@pytest.mark.parametrize(
    "calibrator",
    [UMBmark(4.0, 5, scale_phases=0), JungChung(4.0, 5)],
    ids=["umbmark", "jung_chung"],
)
def test_table_iii_on_the_simulator(calibrator: UMBmark | JungChung) -> None:
    lab = SimLab(LABMATE, rng=np.random.default_rng(0))
    before = _e_max_syst(lab, Calibration())
    assert before == pytest.approx(0.317, rel=0.05)  # Table III, E-1
    result = calibrator.calibrate(lab)
    assert before / _e_max_syst(lab, result.calibration) > 10.0  # Table III: ≥ 10-fold
    assert result.runs_used == 10

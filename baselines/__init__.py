"""Reference solutions: calibration methods behind one interface.

``CALIBRATORS`` maps each method's command-line name to its class (see
:class:`odomgym.baselines.base.Calibrator`).
"""

from __future__ import annotations

from odomgym.baselines.base import CalibrationResult, Calibrator
from odomgym.baselines.jung_chung import JungChung
from odomgym.baselines.umbmark import UMBmark

CALIBRATORS: dict[str, type[Calibrator]] = {cls.name: cls for cls in (UMBmark, JungChung)}

__all__ = ["CALIBRATORS", "CalibrationResult", "Calibrator", "JungChung", "UMBmark"]

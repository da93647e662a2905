"""Reference solutions: calibration methods behind one interface.

``CALIBRATORS`` maps each method's command-line name to its class (see
:class:`odomgym.baselines.base.Calibrator`); :func:`register_calibrator` adds a method of your
own, which the command line, the benchmark and the leaderboard then offer (worked example in
``docs/architecture.md``, "A new calibration method"):

* ``umbmark`` — UMBmark (Borenstein & Feng 1994) with the E_s phase of solderspot 2014;
* ``jung_chung`` — Jung & Chung, from the return *heading* errors;
* ``lee`` — Lee et al., UMBmark without the "E_d does not affect turns" assumption;
* ``ivanjko`` — Ivanjko et al., straight runs and in-place spins, nonlinear least squares;
* ``least_squares`` — Antonelli et al. style linear least squares over whole runs;
* ``trajectory`` — OptiOdom-style optimisation over whole trajectories;
* ``skid_icr`` — Mandow et al.'s ICR model of a skid-steer robot (the sides' ICRs and the
  apparent track) with the wheels' factors, from squares and circles of several radii;
* ``skid_curvature`` — a skid-steer robot's apparent track that moves with the turn (Wang et
  al.'s form), with the wheels' factors, from the same runs;
* ``selfcal`` — a learned policy that chooses the experiments, with a Kalman filter along the
  measured runs (``SelfCalibration-v1``; the shipped policy runs in numpy, no torch needed);
* ``selfcal_scripted`` — the same estimator with a fixed schedule (the policy's ablation);
* ``selfcal_end_pose`` — that schedule with end poses only (the trajectory's ablation).
"""

from __future__ import annotations

from odomgym.baselines.base import CALIBRATORS, CalibrationResult, Calibrator, register_calibrator
from odomgym.baselines.ivanjko import Ivanjko
from odomgym.baselines.jung_chung import JungChung
from odomgym.baselines.least_squares import LeastSquares
from odomgym.baselines.lee import Lee
from odomgym.baselines.selfcal import SelfCal, SelfCalEndPose, SelfCalScripted
from odomgym.baselines.skid_icr import SkidCurvature, SkidIcr
from odomgym.baselines.trajectory import Trajectory
from odomgym.baselines.umbmark import UMBmark

# The built-in methods, in the order tables list them.
for _cls in (
    UMBmark,
    JungChung,
    Lee,
    Ivanjko,
    LeastSquares,
    Trajectory,
    SkidIcr,
    SkidCurvature,
    SelfCal,
    SelfCalScripted,
    SelfCalEndPose,
):
    register_calibrator(_cls)

__all__ = [
    "CALIBRATORS",
    "CalibrationResult",
    "Calibrator",
    "Ivanjko",
    "JungChung",
    "LeastSquares",
    "Lee",
    "SelfCal",
    "SelfCalEndPose",
    "SelfCalScripted",
    "SkidCurvature",
    "SkidIcr",
    "Trajectory",
    "UMBmark",
    "register_calibrator",
]

"""UMBmark and Jung & Chung as procedures, on an exact kinematic lab.

:class:`KinematicLab` drives a differential-drive robot with its (possibly calibrated) odometry
around squares and along straight lines — legs of equal odometric wheel travel, on-the-spot
quarter turns the odometry believes exact — while the true pose integrates the *true* wheel
diameters and wheelbase. No slip, no noise, no first-order approximation: what is left after
calibration is the methods' own model error. The real simulator (``odomgym.lab.simulated.SimLab``)
adds physics; this lab isolates the equations.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from odomgym.baselines.jung_chung import JungChung
from odomgym.baselines.umbmark import Components, UMBmark, beta_from_e_d
from odomgym.lab.experiment import Experiment
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Direction, Run, return_error
from odomgym.odometry.umbmark_measures import e_max_syst
from odomgym.robot import PRESETS, RobotSpec

LABMATE = PRESETS["labmate"]


def drive(
    robot: RobotSpec, calibration: Calibration, experiment: Experiment, step: float = 0.01
) -> Run:
    """One run of ``experiment``, sampled every ``step`` metres of wheel travel."""
    travel_per_count = (
        np.array([calibration.c_left, calibration.c_right])
        * calibration.distance_scale
        * robot.metres_per_tick
    )
    quarter = 0.25 * math.pi * calibration.wheelbase_scale * robot.wheelbase
    sign = 1.0 if experiment.direction == "ccw" else -1.0
    size = experiment.size
    if experiment.kind == "square":
        segments = [(size, size), (-sign * quarter, sign * quarter)] * 4
    elif experiment.kind == "straight" and not experiment.return_trip:
        segments = [(size, size)]
    else:
        raise LookupError(f"the kinematic lab cannot drive {experiment}")
    targets = [np.zeros(2)]
    for left, right in segments:
        n = max(1, math.ceil(max(abs(left), abs(right)) / step))
        fractions = np.arange(1, n + 1)[:, None] / n
        targets.append(targets[-1][-1] + fractions * np.array([left, right]))
    odometric = np.vstack(targets)
    counts = np.round(odometric / travel_per_count).astype(np.int64)
    ticks = np.diff(counts, axis=0).astype(float) * math.pi / robot.ticks_per_rev
    s_left = ticks[:, 0] * float(robot.true_left_diameter)
    s_right = ticks[:, 1] * float(robot.true_right_diameter)
    ds = 0.5 * (s_left + s_right)
    dtheta = (s_right - s_left) / float(robot.true_wheelbase)
    theta = np.concatenate([[0.0], np.cumsum(dtheta)])
    mid = theta[:-1] + 0.5 * dtheta
    pose = np.stack(
        [
            np.concatenate([[0.0], np.cumsum(ds * np.cos(mid))]),
            np.concatenate([[0.0], np.cumsum(ds * np.sin(mid))]),
            theta,
        ],
        axis=1,
    )
    return Run(
        kind=experiment.kind,
        time=np.linspace(0.0, 0.05 * (len(pose) - 1), len(pose)),
        counts=counts,
        true_pose=pose,
        direction=experiment.direction,
        side=size,
        source="kinematic",
    )


class KinematicLab:
    """The :class:`odomgym.lab.experiment.Lab` protocol over :func:`drive`."""

    def __init__(self, robot: RobotSpec) -> None:
        self._robot = robot
        self._runs = 0
        self._distance = 0.0

    @property
    def robot(self) -> RobotSpec:
        return self._robot

    @property
    def runs_used(self) -> int:
        return self._runs

    @property
    def distance_used(self) -> float:
        return self._distance

    def perform(self, experiment: Experiment, calibration: Calibration) -> list[Run]:
        runs = [drive(self._robot, calibration, experiment) for _ in range(experiment.runs)]
        self._runs += len(runs)
        self._distance += sum(r.distance for r in runs)
        return runs


def e_max(robot: RobotSpec, calibration: Calibration, side: float = 4.0) -> float:
    """E_max,syst [m] (Borenstein & Feng 1994, Eq. 3.3) of one noise-free cw and one ccw square."""

    def error(direction: Direction) -> np.ndarray:
        run = drive(robot, calibration, Experiment("square", direction, 1, side))
        return return_error(run, robot, calibration)

    return e_max_syst([error("cw")], [error("ccw")])


def test_table_iii_labmate_improvement() -> None:
    """Borenstein & Feng 1994, Table III, E-1: the LabMate (4 × 4 m, b = 340 mm nominal,
    calibrated to 336.17 mm and D_R/D_L = 1.00084) had E_max,syst = 317 mm before compensation;
    the eight experiments improved 10- to 22-fold. Without non-systematic errors the kinematic
    LabMate starts at 311 mm and UMBmark improves it more than 50-fold (88-fold measured)."""
    before = e_max(LABMATE, Calibration())
    assert before == pytest.approx(0.317, rel=0.05)
    result = UMBmark(4.0, 5, scale_phases=0).calibrate(KinematicLab(LABMATE))
    assert before / e_max(LABMATE, result.calibration) > 50.0
    params = result.calibration.parameters(LABMATE)
    assert params["wheelbase"] == pytest.approx(0.33617, abs=0.0001)  # b = 336.17 mm
    assert result.calibration.e_d == pytest.approx(1.00084, abs=2e-5)


@pytest.mark.parametrize(
    ("e_d", "e_b", "use", "tolerance"),
    [
        # Measured model error of (E − 1): ≤ 1.3 % (xy), ≤ 5.4 % (x only) on the LabMate.
        (1.00084, 336.17 / 340.0, "xy", 0.03),
        (1.00084, 336.17 / 340.0, "x", 0.08),
        (0.9995, 1.01, "xy", 0.03),
        (1.002, 1.0, "xy", 0.03),
    ],
)
def test_umbmark_recovers_e_d_and_e_b(
    e_d: float, e_b: float, use: Components, tolerance: float
) -> None:
    """Within ``tolerance`` of the deviation from 1, plus β²/π: the assumption of Borenstein &
    Feng 1994 that E_d causes no Type A error (#5) holds to first order only, and E_d alone leaks
    about β²/π into E_b (1.8e-4 for E_d = 1.002, measured)."""
    robot = LABMATE.with_errors(e_d=e_d, e_b=e_b, e_s=1.0)
    result = UMBmark(4.0, 5, use=use, scale_phases=0).calibrate(KinematicLab(robot))
    found = result.calibration
    leak = beta_from_e_d(e_d, 4.0, LABMATE.wheelbase) ** 2 / math.pi + 1e-5
    assert abs(found.e_d - e_d) <= tolerance * abs(e_d - 1.0) + leak
    assert abs(found.wheelbase_scale - e_b) <= tolerance * abs(e_b - 1.0) + leak
    assert result.runs_used == 10
    assert result.distance_used == pytest.approx(10 * 16.0, rel=0.01)


def test_scale_phase_finds_e_s() -> None:
    """The E_s phase of solderspot 2014: 2 × 3 straight runs of 2 m find E_s = 1.01 to 1e-4."""
    robot = LABMATE.with_errors(e_s=1.01)
    umbmark = UMBmark(4.0, 5)
    result = umbmark.calibrate(KinematicLab(robot))
    assert result.calibration.distance_scale == pytest.approx(1.01, abs=1e-4)
    assert result.estimates["E_s_2"] == pytest.approx(1.0, abs=1e-4)
    assert result.runs_used == sum(e.runs for e in umbmark.experiments()) == 16
    assert not result.notes


def test_second_compensation_is_applied_when_the_rule_advises() -> None:
    """Noise-free runs have SEM = 0, so the 3·SEM rule always advises a second round, which
    removes what the first-order model left."""
    robot = LABMATE.with_errors(e_d=1.002, e_b=0.98)
    once = UMBmark(4.0, 5, scale_phases=0).calibrate(KinematicLab(robot))
    twice = UMBmark(4.0, 5, scale_phases=0, second_compensation=True).calibrate(KinematicLab(robot))
    assert any("second compensation applied" in note for note in twice.notes)
    assert e_max(robot, twice.calibration) < 0.1 * e_max(robot, once.calibration)
    assert twice.runs_used == 20


def test_one_run_per_direction_cannot_decide_a_second_compensation() -> None:
    result = UMBmark(4.0, 1, scale_phases=0, second_compensation=True).calibrate(
        KinematicLab(LABMATE)
    )
    assert any("needs at least two runs" in note for note in result.notes)


def test_jung_chung_recovers_e_b_and_e_d_in_its_own_model() -> None:
    """Jung & Chung's α_d = π·b·β/(4L) is the extra turn of a robot whose *left* wheel is
    nominal and whose right wheel is E_d times larger; on such a robot they recover E_b and E_d
    to 1e-4 of their deviation. On a robot whose wheels straddle the nominal diameter the α_d
    term costs them a few per cent of E_b − 1."""
    e_d, e_b = 1.00084, 336.17 / 340.0
    own_model = dataclasses.replace(
        LABMATE.with_errors(e_b=e_b),
        true_left_diameter=0.15,
        true_right_diameter=0.15 * e_d,
    )
    found = JungChung(4.0, 5).calibrate(KinematicLab(own_model)).calibration
    assert abs(found.e_d - e_d) <= 1e-3 * abs(e_d - 1.0)
    assert abs(found.wheelbase_scale - e_b) <= 1e-3 * abs(e_b - 1.0)

    straddling = LABMATE  # D_L, D_R split around 150 mm (Borenstein & Feng 1994, Eqs. 6.31–6.32)
    found = JungChung(4.0, 5).calibrate(KinematicLab(straddling)).calibration
    assert abs(found.wheelbase_scale - e_b) <= 0.05 * abs(e_b - 1.0)
    assert e_max(straddling, found) < e_max(straddling, Calibration()) / 30.0


def test_optiodom_jung_chung_barely_corrects() -> None:
    """With 5 runs per direction the authors' double division leaves ~4/5 of the error."""
    right = JungChung(4.0, 5).calibrate(KinematicLab(LABMATE)).calibration
    buggy = JungChung(4.0, 5, conventions="optiodom").calibrate(KinematicLab(LABMATE))
    ratio = (buggy.calibration.wheelbase_scale - 1.0) / (right.wheelbase_scale - 1.0)
    assert ratio == pytest.approx(0.2, abs=0.02)
    assert e_max(LABMATE, buggy.calibration) > 0.7 * e_max(LABMATE, Calibration())

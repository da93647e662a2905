"""Replay a logged run's wheel motions through a robot model: the predicted tracked poses.

The model is a :class:`~odomgym.robot.RobotSpec` with its effects: the logged encoder counts are
the motor rotations; the replay applies, per sample interval, the equations of
``docs/effects.md`` — transmission (backlash), the true wheel geometry, body increments (turn skid,
wheel toe), midpoint integration, the tracked point — i.e. the World's physics without Chipmunk.
It starts from the first measured pose, moved from the tracked point to the axle.

Everything is vectorised over the samples of a run (numpy), so a fit can replay dozens of runs
per millisecond-scale evaluation. What a replay takes from the run alone (:class:`RunInputs`) is
computed once per run by a fit, which replays every run hundreds of times.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.effects import EFFECTS, ReplayArrays
from odomgym.effects.registry import scale_columns
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = ["Replay", "RunInputs", "replay_run", "session_time", "wheel_angles"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Replay:
    """A run replayed through a model.

    Attributes:
        pose: predicted axle-midpoint poses (T, 3) [m, m, rad].
        tracked: predicted poses of the tracked point (T, 3), comparable with ``run.true_pose``.
        travel: each wheel's ground travel per sample interval (n, 2) [m], n = T − 1.
        ds, dtheta: body increments per interval [m], [rad].
        wheelbase: the model's true wheelbase [m].
    """

    pose: FloatArray
    tracked: FloatArray
    travel: FloatArray
    ds: FloatArray
    dtheta: FloatArray
    wheelbase: float


@dataclass(frozen=True)
class RunInputs:
    """What every replay of a run takes from the run alone, whatever the model's geometry and
    effects: computed once and shared, read-only, by the replays of a fit.

    Attributes:
        ticks_per_rev: the encoder resolution ``motor`` was converted with [counts/rev].
        dt: sample intervals (n,) [s].
        motor: motor rotation per interval (n, 2) [rad], from the counts.
        angle: each wheel's angle at the middle of every interval (n, 2) [rad].
        time: time since the session started at the middle of every interval (n,) [s].
        memo: what effects derive from these arrays (:class:`odomgym.effects.ReplayArrays`).
    """

    ticks_per_rev: float
    dt: FloatArray
    motor: FloatArray
    angle: FloatArray
    time: FloatArray
    memo: dict[str, tuple[FloatArray, FloatArray]] = field(default_factory=dict)

    @classmethod
    def of(cls, run: Run, ticks_per_rev: float) -> RunInputs:
        """``run``'s inputs at ``ticks_per_rev``, the arrays made read-only (an effect that
        wrote into one would change every later replay of the run)."""
        dt = np.diff(run.time)
        motor = np.diff(run.counts, axis=0).astype(np.float64) * (2.0 * np.pi / ticks_per_rev)
        inputs = cls(ticks_per_rev, dt, motor, wheel_angles(run, motor), session_time(run))
        for array in (inputs.dt, inputs.motor, inputs.angle, inputs.time):
            array.flags.writeable = False
        return inputs


def _effects_of(spec: RobotSpec) -> list[tuple[str, dict[str, float]]]:
    return [(name, values) for name, values in spec.effect_dict().items() if name in EFFECTS]


def _body_order(
    effects: list[tuple[str, dict[str, float]]],
) -> list[tuple[str, dict[str, float]]]:
    """``effects`` in the order of the ``"body"`` stage: the spec's, except that an effect
    that must follow another one present (:attr:`~odomgym.effects.Effect.body_after`) comes
    after the rest."""
    names = {name for name, _ in effects}
    late = {name for name in names if names.intersection(EFFECTS[name].body_after)}
    if not late:
        return effects
    return [e for e in effects if e[0] not in late] + [e for e in effects if e[0] in late]


def replay_run(run: Run, spec: RobotSpec, inputs: RunInputs | None = None) -> Replay:
    """Replay ``run``'s counts through ``spec`` (its true geometry and its effects).

    ``inputs``: ``run``'s :class:`RunInputs`, if the caller keeps them (made here when not
    given, or when made for another encoder resolution). The first sample must carry a full
    measured pose (:func:`odomgym.diagnose.screen.screen_runs` starts every run of a diagnosis
    at its first one).
    """
    effects = _effects_of(spec)
    if inputs is None or inputs.ticks_per_rev != spec.ticks_per_rev:
        inputs = RunInputs.of(run, spec.ticks_per_rev)
    dt = inputs.dt
    radius = 0.5 * np.array([spec.true_left_diameter, spec.true_right_diameter], dtype=float)
    arrays = ReplayArrays(
        dt=dt,
        wheel=inputs.motor,
        wheelbase=float(spec.true_wheelbase),
        radius=radius,
        angle=inputs.angle,
        time=inputs.time,
        memo=inputs.memo,
    )
    for name, values in effects:
        EFFECTS[name].replay("transmission", values, arrays)
    travel = scale_columns(arrays.wheel, radius)
    wheelbase = float(spec.true_wheelbase)
    arrays.travel = travel
    arrays.ds = 0.5 * (travel[:, 0] + travel[:, 1])
    arrays.dtheta = (travel[:, 1] - travel[:, 0]) / wheelbase
    arrays.crab = np.zeros(len(dt))  # not zeros_like: a Python function, ~6 µs a call
    for name, values in _body_order(effects):
        EFFECTS[name].replay("body", values, arrays)
    start = _start_pose(run.true_pose[0], effects)
    ds, dtheta = arrays.ds, arrays.dtheta
    # Midpoint integration: θ the running sum of dθ, each interval translated along its middle
    # heading plus the crab angle.
    theta, direction = _headings(float(start[2]), _floats(dtheta), _floats(arrays.crab))
    pose = _positions(start, theta, _floats(ds), np.cos(direction), np.sin(direction))
    tracked = _measure(pose, effects, arrays)
    return Replay(pose, tracked, travel, ds, dtheta, wheelbase)


def _floats(values: FloatArray) -> FloatArray:
    """``values`` as float64 (what the stages give; a kernel compiles for one dtype)."""
    return np.asarray(values, dtype=np.float64)


# The two kernels below are numpy's cumulative sums and sums written out (``np.cumsum`` adds
# in order, its first element the first input itself), so a replay's bits do not depend on
# which computed it; the cosines and sines between them stay numpy's. Compiled because a fit
# replays every run hundreds of times and a dozen small numpy calls per replay added up.
@kernel
def _headings(theta0: float, dtheta: FloatArray, crab: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Heading at every sample (T,) from ``theta0`` [rad] and the increments ``dtheta`` (n,),
    and the direction of translation over every interval (n,): its middle heading plus
    ``crab`` [rad]."""
    n = dtheta.shape[0]
    theta = np.empty(n + 1)
    direction = np.empty(n)
    theta[0] = theta0 + 0.0
    total = 0.0
    for i in range(n):
        total = dtheta[i] if i == 0 else total + dtheta[i]
        theta[i + 1] = theta0 + total
    for i in range(n):
        direction[i] = theta[i] + 0.5 * dtheta[i] + crab[i]
    return theta, direction


@kernel
def _positions(
    start: FloatArray, theta: FloatArray, ds: FloatArray, cos_d: FloatArray, sin_d: FloatArray
) -> FloatArray:
    """Axle poses (T, 3) [m, m, rad] from the start pose, the headings ``theta`` (T,) and each
    interval's translation ``ds`` [m] along the direction whose cosine and sine are given."""
    n = ds.shape[0]
    pose = np.empty((n + 1, 3))
    pose[0, 0] = start[0] + 0.0
    pose[0, 1] = start[1] + 0.0
    x = 0.0
    y = 0.0
    for i in range(n):
        x = ds[i] * cos_d[i] if i == 0 else x + ds[i] * cos_d[i]
        y = ds[i] * sin_d[i] if i == 0 else y + ds[i] * sin_d[i]
        pose[i + 1, 0] = start[0] + x
        pose[i + 1, 1] = start[1] + y
    for i in range(n + 1):
        pose[i, 2] = theta[i]
    return pose


def wheel_angles(run: Run, motor: FloatArray) -> FloatArray:
    """Each wheel's angle at the middle of every interval [rad], from the session's start when
    the run records where its wheels began (``meta["wheel_angle0"]``), else from the run's."""
    start = np.zeros(2)
    given = run.meta.get("wheel_angle0")
    if given is not None:
        start = np.asarray(given, dtype=float).reshape(2)
    before = np.concatenate([np.zeros((1, 2)), np.cumsum(motor, axis=0)[:-1]])
    angles: FloatArray = start + before + 0.5 * motor
    return angles


def session_time(run: Run) -> FloatArray:
    """Time since the session started at the middle of every interval [s]."""
    t0 = float(run.meta.get("session_time", 0.0))  # type: ignore[arg-type]
    middle: FloatArray = t0 + 0.5 * (run.time[1:] + run.time[:-1]) - run.time[0]
    return middle


def _measure(
    pose: FloatArray, effects: list[tuple[str, dict[str, float]]], arrays: ReplayArrays
) -> FloatArray:
    arrays.pose = pose
    arrays.tracked = pose.copy()
    for name, values in effects:
        EFFECTS[name].replay("measurement", values, arrays)
    return arrays.tracked


def _start_pose(measured: FloatArray, effects: list[tuple[str, dict[str, float]]]) -> FloatArray:
    """The axle pose whose tracked point is the measured first pose (fixed-point iteration:
    exact in two steps for rigid offsets, which do not change the heading).

    The iteration stops early once a step leaves the pose's bytes as they were: ``_measure``
    is a function of the pose alone, so every further step would give those bytes again (the
    common case, a model without a measurement stage, takes one step instead of three)."""
    target = np.asarray(measured, dtype=float)[None, :]
    pose = target.copy()
    arrays = ReplayArrays(dt=np.zeros(0), wheel=np.zeros((0, 2)))
    for _ in range(3):
        seen = _measure(pose, effects, arrays)
        moved = pose + (target - seen)
        settled = moved.tobytes() == pose.tobytes()
        pose = moved
        if settled:
            break
    start: FloatArray = pose[0]
    return start

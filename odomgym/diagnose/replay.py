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

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.effects import EFFECTS, ReplayArrays
from odomgym.effects.registry import scale_columns
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "Replay",
    "RunInputs",
    "RunStack",
    "StackedReplay",
    "replay_run",
    "replay_stacked",
    "session_time",
    "stackable",
    "wheel_angles",
]

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


@dataclass(frozen=True)
class RunStack:
    """Several runs' :class:`RunInputs` stacked end to end, for :func:`replay_stacked`: computed
    once per fit's runs and encoder resolution, shared read-only by its replays.

    Attributes:
        ticks_per_rev: the encoder resolution of every run's inputs [counts/rev].
        dt, motor, angle, time: the runs' :class:`RunInputs` arrays stacked (N,), (N, 2).
        bounds: where each run's intervals start, and where the last ends (R + 1,).
        first: each run's first measured pose (R, 3) [m, m, rad].
        measured: the runs' measured poses stacked (N + R, 3) (NaN where not measured).
        memo: as :attr:`RunInputs.memo`, for the stacked arrays.
    """

    ticks_per_rev: float
    dt: FloatArray
    motor: FloatArray
    angle: FloatArray
    time: FloatArray
    bounds: NDArray[np.int64]
    first: FloatArray
    measured: FloatArray
    memo: dict[str, tuple[FloatArray, FloatArray]] = field(default_factory=dict)

    @classmethod
    def of(cls, runs: list[Run], inputs: list[RunInputs]) -> RunStack:
        """The stack of ``runs`` with their ``inputs`` (one encoder resolution)."""
        ticks = {i.ticks_per_rev for i in inputs}
        if len(ticks) > 1:
            raise ValueError(f"runs stacked at several encoder resolutions: {sorted(ticks)}")
        lengths = [len(i.dt) for i in inputs]
        bounds = np.zeros(len(inputs) + 1, dtype=np.int64)
        np.cumsum(lengths, out=bounds[1:])
        stack = cls(
            ticks.pop() if ticks else 0.0,
            np.concatenate([i.dt for i in inputs]) if inputs else np.zeros(0),
            np.concatenate([i.motor for i in inputs]) if inputs else np.zeros((0, 2)),
            np.concatenate([i.angle for i in inputs]) if inputs else np.zeros((0, 2)),
            np.concatenate([i.time for i in inputs]) if inputs else np.zeros(0),
            bounds,
            np.array([np.asarray(r.true_pose[0], dtype=float) for r in runs]).reshape(-1, 3),
            np.ascontiguousarray(
                np.concatenate([np.asarray(r.true_pose, dtype=np.float64) for r in runs])
                if runs
                else np.zeros((0, 3))
            ),
        )
        for array in (
            stack.dt,
            stack.motor,
            stack.angle,
            stack.time,
            stack.bounds,
            stack.first,
            stack.measured,
        ):
            array.flags.writeable = False
        return stack


@dataclass(frozen=True)
class StackedReplay:
    """The runs of a :class:`RunStack` replayed (:func:`replay_stacked`): the arrays of
    :class:`Replay` for every run, stacked end to end.

    Attributes:
        pose, tracked: axle and tracked poses (N + R, 3) [m, m, rad].
        travel: wheel travel per interval (N, 2) [m].
        ds, dtheta: body increments per interval (N,) [m], [rad].
        wheelbase: the model's true wheelbase [m].
        bounds: run r's intervals are rows ``bounds[r]:bounds[r + 1]``, its poses rows
            ``bounds[r] + r:bounds[r + 1] + r + 1`` (R + 1,).
        cos_mid, sin_mid: cosine and sine of every interval's middle heading θ + dθ/2 (N,),
            or empty where the replay did not compute them (a crab angle made its directions
            differ from the middle headings).
    """

    pose: FloatArray
    tracked: FloatArray
    travel: FloatArray
    ds: FloatArray
    dtheta: FloatArray
    wheelbase: float
    bounds: NDArray[np.int64]
    cos_mid: FloatArray = field(default_factory=lambda: np.zeros(0))
    sin_mid: FloatArray = field(default_factory=lambda: np.zeros(0))

    def samples(self) -> NDArray[np.int64]:
        """Where each run's poses start, and where the last ends (R + 1,)."""
        out: NDArray[np.int64] = self.bounds + np.arange(len(self.bounds), dtype=np.int64)
        return out

    def split(self) -> list[Replay]:
        """Each run's :class:`Replay`, its arrays views of the stacked ones."""
        out = []
        for r in range(len(self.bounds) - 1):
            a, b = int(self.bounds[r]), int(self.bounds[r + 1])
            rows = slice(a + r, b + r + 1)
            out.append(
                Replay(
                    self.pose[rows],
                    self.tracked[rows],
                    self.travel[a:b],
                    self.ds[a:b],
                    self.dtheta[a:b],
                    self.wheelbase,
                )
            )
        return out


def stackable(spec: RobotSpec) -> bool:
    """Whether every effect of ``spec`` replays runs stacked
    (:meth:`~odomgym.effects.Effect.replays_stacked`)."""
    return all(EFFECTS[name].replays_stacked() for name, _ in _effects_of(spec))


def replay_stacked(stack: RunStack, spec: RobotSpec) -> StackedReplay:
    """Every run of ``stack`` replayed through ``spec``, in one pass over the stacked arrays:
    the same numbers as :func:`replay_run` on each run (the stages act sample by sample, or
    run by run through :attr:`~odomgym.effects.ReplayArrays.bounds`; the integration restarts
    at each run's first measured pose), each run's arrays views of the stacked results.

    Why: a fit replays all its runs at every evaluation, and a run's replay was mostly the
    stages' numpy calls and the Python between them (~58 µs a run of ~1 300 samples on the
    June OptiOdom sessions); stacked, each call is paid once for all runs. Only for a spec
    whose effects all replay stacked (:func:`stackable`): the caller replays the others run
    by run."""
    effects = _effects_of(spec)
    if stack.ticks_per_rev != spec.ticks_per_rev:
        raise ValueError(
            f"a stack of inputs at {stack.ticks_per_rev} counts/rev replayed through a spec "
            f"of {spec.ticks_per_rev}"
        )
    radius = 0.5 * np.array([spec.true_left_diameter, spec.true_right_diameter], dtype=float)
    wheelbase = float(spec.true_wheelbase)
    arrays = ReplayArrays(
        dt=stack.dt,
        wheel=stack.motor,
        wheelbase=wheelbase,
        radius=radius,
        angle=stack.angle,
        time=stack.time,
        memo=stack.memo,
        bounds=stack.bounds,
    )
    travel = _motion_stages(arrays, effects)
    starts = _start_pose(stack.first, effects)
    ds, dtheta, crab = _floats(arrays.ds), _floats(arrays.dtheta), _floats(arrays.crab)
    bounds = stack.bounds
    theta, direction = _headings(np.ascontiguousarray(starts[:, 2]), dtheta, crab, bounds)
    cos_d, sin_d = _cos_sin(direction)
    pose = _positions(starts, theta, ds, cos_d, sin_d, bounds)
    tracked = _measure(pose, effects, arrays)
    if np.any(crab != 0.0):  # the directions are not the middle headings
        cos_d = sin_d = np.zeros(0)
    return StackedReplay(pose, tracked, travel, ds, dtheta, wheelbase, bounds, cos_d, sin_d)


@kernel
def _cos_sin(angle: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Cosine and sine of every element of ``angle`` (a contiguous vector), compiled: libm's
    (2.0 ms instead of numpy's 2.8 ms for 133 000 angles, 2026-11-30). The run-by-run replay,
    the stacked one and the open-loop alignment all take theirs from here or from libm in a
    kernel, so the paths agree on every machine, not only where numpy's sine and cosine are
    libm's (they are on this project's machine: the results are the bytes numpy's gave; a numpy
    with SIMD sine and cosine, 1.24 on AVX-512, would have moved them in their last bits)."""
    c = np.empty(angle.shape[0])
    s = np.empty(angle.shape[0])
    for i in range(angle.shape[0]):
        c[i] = math.cos(angle[i])
        s[i] = math.sin(angle[i])
    return c, s


def _motion_stages(arrays: ReplayArrays, effects: list[tuple[str, dict[str, float]]]) -> FloatArray:
    """The ``"transmission"`` and ``"body"`` stages on ``arrays`` (one run's or several
    stacked), with the true geometry between them: the wheels' travel (n, 2) [m], and
    ``arrays.ds``, ``dtheta`` and ``crab`` set."""
    for name, values in effects:
        EFFECTS[name].replay("transmission", values, arrays)
    travel = scale_columns(arrays.wheel, arrays.radius)
    arrays.travel = travel
    arrays.ds = 0.5 * (travel[:, 0] + travel[:, 1])
    arrays.dtheta = (travel[:, 1] - travel[:, 0]) / arrays.wheelbase
    arrays.crab = np.zeros(len(arrays.dt))  # not zeros_like: a Python function, ~6 µs a call
    for name, values in _body_order(effects):
        EFFECTS[name].replay("body", values, arrays)
    return travel


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
    travel = _motion_stages(arrays, effects)
    wheelbase = arrays.wheelbase
    start = _start_pose(run.true_pose[0], effects)
    ds, dtheta = arrays.ds, arrays.dtheta
    # Midpoint integration: θ the running sum of dθ, each interval translated along its middle
    # heading plus the crab angle.
    one = np.array([0, len(dt)], dtype=np.int64)
    theta, direction = _headings(start[2:3], _floats(dtheta), _floats(arrays.crab), one)
    cos_d, sin_d = _cos_sin(direction)
    pose = _positions(start[None, :], theta, _floats(ds), cos_d, sin_d, one)
    tracked = _measure(pose, effects, arrays)
    return Replay(pose, tracked, travel, ds, dtheta, wheelbase)


def _floats(values: FloatArray) -> FloatArray:
    """``values`` as float64 (what the stages give; a kernel compiles for one dtype)."""
    return np.asarray(values, dtype=np.float64)


# The two kernels below are numpy's cumulative sums and sums written out, run by run
# (``np.cumsum`` adds in order, its first element the first input itself), so a replay's bits
# do not depend on which computed it, nor on how many runs were stacked; the cosines and sines
# between them are :func:`_cos_sin`'s. Compiled because a fit replays every run hundreds of
# times and a dozen small numpy calls per replay added up. One run is a stack of one
# (``bounds`` = [0, n]).
@kernel
def _headings(
    theta0: FloatArray, dtheta: FloatArray, crab: FloatArray, bounds: NDArray[np.int64]
) -> tuple[FloatArray, FloatArray]:
    """Heading at every sample of every run of a stack (N + R,), run r from ``theta0[r]``
    [rad] with the increments ``dtheta`` of its intervals, rows ``bounds[r]:bounds[r + 1]``,
    and the direction of translation over every interval (N,): its middle heading plus
    ``crab`` [rad]."""
    runs = bounds.shape[0] - 1
    theta = np.empty(dtheta.shape[0] + runs)
    direction = np.empty(dtheta.shape[0])
    for r in range(runs):
        a = bounds[r]
        b = bounds[r + 1]
        p = a + r
        theta[p] = theta0[r] + 0.0
        total = 0.0
        for i in range(a, b):
            total = dtheta[i] if i == a else total + dtheta[i]
            theta[p + 1 + i - a] = theta0[r] + total
        for i in range(a, b):
            direction[i] = theta[p + i - a] + 0.5 * dtheta[i] + crab[i]
    return theta, direction


@kernel
def _positions(
    start: FloatArray,
    theta: FloatArray,
    ds: FloatArray,
    cos_d: FloatArray,
    sin_d: FloatArray,
    bounds: NDArray[np.int64],
) -> FloatArray:
    """Axle poses (N + R, 3) [m, m, rad] of every run of a stack, run r from ``start[r]``,
    from the headings ``theta`` (N + R,) and each interval's translation ``ds`` [m] along the
    direction whose cosine and sine are given."""
    runs = bounds.shape[0] - 1
    pose = np.empty((ds.shape[0] + runs, 3))
    for r in range(runs):
        a = bounds[r]
        b = bounds[r + 1]
        p = a + r
        pose[p, 0] = start[r, 0] + 0.0
        pose[p, 1] = start[r, 1] + 0.0
        x = 0.0
        y = 0.0
        for i in range(a, b):
            x = ds[i] * cos_d[i] if i == a else x + ds[i] * cos_d[i]
            y = ds[i] * sin_d[i] if i == a else y + ds[i] * sin_d[i]
            pose[p + 1 + i - a, 0] = start[r, 0] + x
            pose[p + 1 + i - a, 1] = start[r, 1] + y
        for i in range(p, b + r + 1):
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
    """The axle pose whose tracked point is the measured first pose (3,), or the axle poses of
    measured first poses (R, 3) (fixed-point iteration: exact in two steps for rigid offsets,
    which do not change the heading).

    The iteration stops early once a step leaves the poses' bytes as they were: ``_measure``
    is a function of each pose alone, so every further step would give those bytes again (the
    common case, a model without a measurement stage, takes one step instead of three). So a
    pose that settles before the others stays as it settled, and each of R poses is the one
    its own iteration gives."""
    target = np.asarray(measured, dtype=float).reshape(-1, 3)
    pose = target.copy()
    arrays = ReplayArrays(dt=np.zeros(0), wheel=np.zeros((0, 2)))
    for _ in range(3):
        seen = _measure(pose, effects, arrays)
        moved = pose + (target - seen)
        settled = moved.tobytes() == pose.tobytes()
        pose = moved
        if settled:
            break
    start: FloatArray = pose[0] if np.ndim(measured) == 1 else pose
    return start

"""One record for one experiment run, simulated or measured: :class:`Run`.

Calibrators, metrics and the diagnose workflow never care whether a run came from the simulator
or from a robot with motion capture: both are a time series of cumulative encoder counts and
ground-truth poses. Odometry is *recomputed* from the counts (:func:`replay_odometry`) with
whatever nominal parameters and calibration the caller chooses, which is how a calibration is
evaluated on runs it did not produce.

Frames: ground-truth poses are in the frame of whatever measured them (the simulator's world
frame, or a motion-capture frame). :func:`return_error` expresses errors in the *start frame*
(origin at the first ground-truth pose, +x along its heading), the frame of the UMBmark
equations (Borenstein & Feng 1994, §6.1).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from odomgym.odometry.calibration import Calibration, wrap_angle
from odomgym.robot import RobotSpec

__all__ = [
    "PARAMETER_NAMES",
    "Direction",
    "Run",
    "WheelSteps",
    "end_error",
    "integrate_steps",
    "replay_odometry",
    "replay_with_jacobian",
    "require_differential",
    "return_error",
    "rotate_into",
    "step_jacobians",
    "to_frame",
    "to_start_frame",
    "wheel_steps",
    "wheel_travels",
]

FloatArray = NDArray[np.float64]
Direction = Literal["cw", "ccw"]


MAX_RUN_LENGTH = 1000.0
"""The longest path one run may drive [m]. A run's poses and counts are recorded at every step,
so memory grows with its length (1 km at 0.3 m/s is ~67 000 steps of 50 ms per robot); UMBmark's
square is 16 m, the CLAPPER's longest run 36 m. Longer asks are refused in one line rather than
failing deep inside numpy's allocator (:mod:`odomgym.sim.routes`), and a measured session's
side that asks for more is refused at its metadata line (:mod:`odomgym.data.optiodom`)."""
MIN_RUN_LENGTH = 1e-3
"""The shortest path one run may drive [m]: below a millimetre a route's direction is lost to
rounding (a side of 1e-308 m divided by zero)."""


@dataclass
class Run:
    """A run: samples of time, cumulative encoder counts and ground-truth pose.

    Attributes:
        kind: what was driven: ``"square"``, ``"straight"``, ``"spin"`` or ``"free"``.
        time: sample times (T,) [s].
        counts: cumulative encoder counts (T, 2), columns [left, right], starting at 0.
        true_pose: ground-truth poses (T, 3): x, y [m], θ [rad] (unwrapped).
        direction: ``"cw"``/``"ccw"`` for squares and spins, ``None`` otherwise.
        side: square side L or straight-run length D [m] (0 when not applicable).
        source: where the run came from (file path, or ``"sim"``), for error messages.
        meta: free-form extra information (seed, robot name, session, …).
    """

    kind: str
    time: FloatArray
    counts: NDArray[np.int64] | NDArray[np.float64]
    true_pose: FloatArray
    direction: Direction | None = None
    side: float = 0.0
    source: str = "sim"
    meta: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = len(self.time)
        if self.counts.shape != (t, 2) or self.true_pose.shape != (t, 3):
            raise ValueError(
                f"{self.source}: run arrays disagree in length: time {self.time.shape}, "
                f"counts {self.counts.shape}, true_pose {self.true_pose.shape}"
            )
        if t < 2:
            raise ValueError(f"{self.source}: a run needs at least two samples, got {t}")

    @property
    def distance(self) -> float:
        """Ground-truth path length [m] (sum of sample-to-sample displacements)."""
        steps = np.diff(self.true_pose[:, :2], axis=0)
        return float(np.sum(np.hypot(steps[:, 0], steps[:, 1])))


class WheelSteps(NamedTuple):
    """Each sample step of a run as the odometry reads its encoder counts.

    Attributes:
        left, right: each wheel's travel per step, Δs_L and Δs_R [m] (T − 1,).
        wheelbase: the calibrated wheelbase B [m].
        ds: the travel of the midpoint, (Δs_L + Δs_R)/2 [m] (T − 1,).
        dtheta: the heading change, (Δs_R − Δs_L)/B [rad] (T − 1,).
    """

    left: FloatArray
    right: FloatArray
    wheelbase: float
    ds: FloatArray
    dtheta: FloatArray


def wheel_travels(
    run: Run, robot: RobotSpec, calibration: Calibration | None = None
) -> tuple[FloatArray, float]:
    """``run``'s encoder counts as the travel of each wheel per sample (T − 1, 2) [m] (left,
    right) and the effective wheelbase [m], with ``robot``'s nominal parameters and
    ``calibration``: the one place counts become metres for every replay and fit of a run
    (the equations of :class:`odomgym.odometry.calibration.Odometry`)."""
    cal = calibration if calibration is not None else Calibration()
    per_tick = robot.metres_per_tick * cal.distance_scale
    increments = np.diff(run.counts, axis=0).astype(np.float64)
    travels = increments * np.array([cal.c_left * per_tick, cal.c_right * per_tick])
    return travels, cal.wheelbase_scale * robot.wheelbase


def require_differential(calibration: Calibration | None, what: str) -> None:
    """Raise ValueError unless ``calibration`` is a differential-drive one (no ICR offsets, a
    constant track): ``what`` (a model of the differential-drive odometry, e.g. Chong &
    Kleeman's covariance) would otherwise drop the skid-steer terms silently."""
    if calibration is not None and calibration.is_skid_steer:
        terms = []
        if calibration.has_icr:
            terms.append(
                f"ICR offsets (icr_x = {calibration.icr_x:g} m, icr_y = {calibration.icr_y:g} m)"
            )
        if calibration.has_track_curve:
            terms.append(f"track curve (track_alpha = {calibration.track_alpha:g})")
        raise ValueError(
            f"{what} models a differential-drive odometry; the calibration's "
            f"{' and '.join(terms)} are a skid-steer robot's"
        )


def wheel_steps(run: Run, robot: RobotSpec, calibration: Calibration | None = None) -> WheelSteps:
    """``run``'s encoder counts as wheel travel and motion per step (:func:`wheel_travels`).

    Raises:
        ValueError: ``calibration`` holds skid-steer terms (ICR offsets, a track that moves
            with the turn), which these differential-drive steps (and the Jacobians built on
            them) do not hold; :func:`replay_odometry` replays such a calibration.
    """
    require_differential(calibration, "this replay (replay_odometry takes skid-steer terms)")
    travels, wheelbase = wheel_travels(run, robot, calibration)
    left, right = travels[:, 0], travels[:, 1]
    return WheelSteps(left, right, wheelbase, 0.5 * (left + right), (right - left) / wheelbase)


def integrate_steps(
    start: FloatArray, ds: FloatArray, dtheta: FloatArray, lateral: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """Midpoint dead reckoning of per-step travel ``ds`` [m] and turn ``dtheta`` [rad] from
    ``start`` (x, y [m], θ [rad]), as :class:`odomgym.odometry.calibration.Odometry` does:
    poses (T, 3) and each step's midpoint heading μ_j = θ_j + Δθ_j/2 (T − 1,) [rad].
    ``lateral`` [m], each step's motion to the left of the heading (a skid-steer calibration's
    −x_ICR·Δθ), is 0 when not given."""
    x0, y0, th0 = start
    theta = th0 + np.concatenate([[0.0], np.cumsum(dtheta)])
    mid = theta[:-1] + 0.5 * dtheta
    poses = np.empty((len(theta), 3))
    c, s = np.cos(mid), np.sin(mid)
    if lateral is None:
        dx, dy = ds * c, ds * s
    else:
        dx, dy = ds * c - lateral * s, ds * s + lateral * c
    poses[:, 0] = x0 + np.concatenate([[0.0], np.cumsum(dx)])
    poses[:, 1] = y0 + np.concatenate([[0.0], np.cumsum(dy)])
    poses[:, 2] = theta
    return poses, mid


def step_jacobians(
    steps: WheelSteps,
    cos_mid: FloatArray,
    sin_mid: FloatArray,
    heading_before: Callable[[FloatArray], FloatArray],
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Each step's contribution to ∂(x, y, θ)/∂(ln k_L, ln k_R, ln B) (module docs of
    :func:`replay_with_jacobian`): three (T − 1, 3) arrays, summed over the steps by the caller.

    ``cos_mid``, ``sin_mid`` are the cosines and sines of each step's midpoint heading in the
    caller's frame; ``heading_before`` maps the steps' ∂Δθ (T − 1, 3) to ∂θ at the start of
    each step, the sum over the earlier steps the caller's frame counts from (the whole run, or
    each chunk's start).
    """
    left, right, wheelbase, ds, dtheta = steps
    d_ds = np.stack([0.5 * left, 0.5 * right, np.zeros_like(ds)], axis=1)  # (n, 3)
    d_dtheta = np.stack([-left / wheelbase, right / wheelbase, -dtheta], axis=1)
    d_mid = heading_before(d_dtheta) + 0.5 * d_dtheta
    d_x = d_ds * cos_mid[:, None] - (ds * sin_mid)[:, None] * d_mid
    d_y = d_ds * sin_mid[:, None] + (ds * cos_mid)[:, None] * d_mid
    return d_x, d_y, d_dtheta


def replay_odometry(
    run: Run, robot: RobotSpec, calibration: Calibration | None = None
) -> FloatArray:
    """Dead-reckon ``run``'s encoder counts with ``robot``'s nominal parameters (T, 3).

    The odometry starts at the first ground-truth pose (the OptiOdom convention), so the
    result is directly comparable with ``run.true_pose``. Same equations as
    :class:`odomgym.odometry.calibration.Odometry`, vectorised over the samples, the skid-steer
    terms of a calibration included (ICR offsets, a track that moves with the turn).
    """
    if calibration is not None and calibration.is_skid_steer:
        travels, _ = wheel_travels(run, robot, calibration)
        forward, leftward, dtheta = calibration.body_steps(
            travels[:, 0], travels[:, 1], robot.wheelbase
        )
        poses, _ = integrate_steps(run.true_pose[0], forward, dtheta, lateral=leftward)
        return poses
    _, _, _, ds, dtheta = wheel_steps(run, robot, calibration)
    poses, _ = integrate_steps(run.true_pose[0], ds, dtheta)
    return poses


def rotate_into(dx: FloatArray, dy: FloatArray, heading: FloatArray | float) -> FloatArray:
    """Vectors (dx, dy) [m] of the world frame expressed in a frame turned by ``heading``
    [rad] (one angle, or one per vector): (K, 2), the rotation by −heading. The one rotation
    behind every start frame and body frame of the numpy code (the compiled step has its own,
    :func:`odomgym._kernels.start_frame`)."""
    c, s = np.cos(heading), np.sin(heading)
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=1)


def to_frame(points: FloatArray, origin: FloatArray) -> FloatArray:
    """Poses (K, 3) — or positions (K, 2) — of the world frame in the frame of ``origin``
    (x, y [m], θ [rad]): at its origin, +x along its heading."""
    x0, y0, th0 = origin[0], origin[1], origin[2]
    xy = rotate_into(points[:, 0] - x0, points[:, 1] - y0, th0)
    if points.shape[1] == 2:
        return xy
    return np.column_stack([xy, points[:, 2] - th0])


def to_start_frame(run: Run, points: FloatArray) -> FloatArray:
    """Express world-frame poses (K, 3) in the run's start frame (first true pose at origin)."""
    return to_frame(points, run.true_pose[0])


def return_error(
    run: Run,
    robot: RobotSpec,
    calibration: Calibration | None = None,
    *,
    frame: Literal["start", "world"] = "start",
) -> FloatArray:
    """UMBmark return error ε = true − odometry at the end of the run (3,).

    With ``frame="start"`` (default), ε_x, ε_y [m] are in the frame whose origin is the first
    true pose and whose +x axis is the starting heading — the frame of the UMBmark equations
    (Borenstein & Feng 1994, §6.1). ``frame="world"`` keeps the ground-truth frame (the OptiOdom
    authors' convention: errors in the motion-capture frame). ε_θ [rad] is wrapped to [−π, π).
    """
    odom = replay_odometry(run, robot, calibration)
    ends = np.stack([run.true_pose[-1], odom[-1]])
    if frame == "start":
        ends = to_start_frame(run, ends)
    error: FloatArray = ends[0] - ends[1]
    error[2] = float(wrap_angle(error[2]))
    return error


def end_error(run: Run, odometry_end: FloatArray) -> FloatArray:
    """True − odometry at the end of ``run`` in its start frame (3,), heading wrapped.

    ``odometry_end`` is the robot's own odometry pose, which lives in the start frame (the
    odometry starts at zero where the robot starts), e.g. as returned by
    :func:`odomgym.sim.route_runs.simulate_runs`.
    """
    error: FloatArray = to_start_frame(run, run.true_pose[-1:])[0] - np.asarray(odometry_end)
    error[2] = float(wrap_angle(error[2]))
    return error


#: The order of the columns of :func:`replay_with_jacobian`'s Jacobian.
PARAMETER_NAMES: tuple[str, str, str] = ("left_diameter", "right_diameter", "wheelbase")


def replay_with_jacobian(
    run: Run, robot: RobotSpec, calibration: Calibration | None = None
) -> tuple[FloatArray, FloatArray]:
    """Dead-reckon ``run`` like :func:`odomgym.odometry.runs.replay_odometry`, with the pose's
    sensitivity to *relative* changes of the left diameter, right diameter and wheelbase.

    With Δs_L = k_L·N_L, Δs_R = k_R·N_R (k the calibrated travel per count [m]), Δs = (Δs_R +
    Δs_L)/2, Δθ = (Δs_R − Δs_L)/B and the midpoint heading μ_j = θ_j + Δθ_j/2, the derivatives
    with respect to x = ln k_L, ln k_R, ln B are cumulative sums over the samples:

        ∂θ_k/∂x = Σ_{j<k} ∂Δθ_j/∂x,      ∂μ_j/∂x = ∂θ_j/∂x + ½·∂Δθ_j/∂x
        ∂x_k/∂x = Σ_{j<k} (∂Δs_j/∂x·cos μ_j − Δs_j·sin μ_j·∂μ_j/∂x)
        ∂y_k/∂x = Σ_{j<k} (∂Δs_j/∂x·sin μ_j + Δs_j·cos μ_j·∂μ_j/∂x)

    with ∂(Δs, Δθ)/∂ln k_L = (Δs_L/2, −Δs_L/B), ∂/∂ln k_R = (Δs_R/2, Δs_R/B) and
    ∂/∂ln B = (0, −Δθ). A relative change of a diameter is a relative change of its k.

    Returns:
        ``(poses, jacobian)``: poses (T, 3) — x, y [m], θ [rad] — identical to
        :func:`~odomgym.odometry.runs.replay_odometry`; jacobian (T, 3, 3) with
        ``jacobian[k, i, j]`` = ∂pose_i/∂ln(parameter_j) at sample k, parameters in the order
        of :data:`PARAMETER_NAMES` ([m] or [rad] per unit relative change).
    """
    steps = wheel_steps(run, robot, calibration)
    poses, mid = integrate_steps(run.true_pose[0], steps.ds, steps.dtheta)
    cos_mid, sin_mid = np.cos(mid), np.sin(mid)
    d_x, d_y, d_dtheta = step_jacobians(
        steps,
        cos_mid,
        sin_mid,
        lambda d: np.cumsum(d, axis=0) - d,  # ∂θ_j, j = 0..n−1
    )

    jacobian = np.zeros((len(run.time), 3, 3))
    jacobian[1:, 0] = np.cumsum(d_x, axis=0)
    jacobian[1:, 1] = np.cumsum(d_y, axis=0)
    jacobian[1:, 2] = np.cumsum(d_dtheta, axis=0)
    return poses, jacobian

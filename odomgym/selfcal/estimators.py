"""The self-calibration estimators: what a session learns of the odometry's parameters from the
runs it measured.

**The estimators** fit the three effective odometry parameters
x = (ln D_L/D_n, ln D_R/D_n, ln b/b_n), with a Gaussian prior centred on the nominal robot with
σ = the benchmark population's half-ranges (:class:`odomgym.lab.population.Population`:
E_d ± 0.01, E_b ± 0.05, E_s ± 0.02), which keeps the fit well posed after one run.

* :class:`TrajectoryEstimator` (``observe="trajectory"``, the default) — an augmented-state
  Kalman filter along every measured pose of each run (Larsen et al. 1998; Martinelli et al.
  2007): the odometry's motion between samples predicts the pose, the floor's wheel-travel
  noise (Chong & Kleeman 1997, Eq. 4) widens the prediction, the measured pose corrects pose and
  parameters together.
* :class:`EndPoseEstimator` (``observe="end_pose"``) — a Gauss–Newton fit to each run's end pose
  alone, what a person with a tape measure at the home position gets (UMBmark's information,
  Borenstein & Feng 1994, §6.3): each run's encoder counts are dead-reckoned from its exactly
  known start pose with the candidate parameters
  (:func:`odomgym.odometry.runs.replay_with_jacobian`) and the residuals are weighted by the
  sensor's accuracy plus the floor's scatter for that kind of run.

Both estimate the floor's roughness factor ρ ≥ 1 from the end-pose residuals: the scatter of
each kind of run over :data:`ACTION_MENU`'s per-run standard deviations, measured on the
``concrete`` benchmark floor (ρ ≈ 5 on the ``rough`` floor), so a rough floor down-weights
itself relative to the prior.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from odomgym.errors import SpecError, require_count
from odomgym.lab.experiment import SensorAccuracy
from odomgym.odometry.calibration import Calibration, wrap_angle
from odomgym.odometry.runs import Run, replay_with_jacobian, step_jacobians, wheel_steps
from odomgym.robot import RobotSpec
from odomgym.selfcal.menu import ACTION_MENU

__all__ = [
    "CLIP_PRIORS",
    "ESTIMATORS",
    "PRIOR_STD",
    "REFERENCE_ROUGHNESS",
    "EndPoseEstimator",
    "TrajectoryEstimator",
    "check_observe",
    "chunk_motions",
]

FloatArray = NDArray[np.float64]

#: Half-ranges of the benchmark population (E_s, E_d, E_b) [-]: the prior's standard deviations
#: of (ln E_s, ln E_d, ln E_b).
PRIOR_STD: tuple[float, float, float] = (0.02, 0.01, 0.05)
#: Estimates are kept within this many prior half-ranges of nominal, so the odometry can always
#: drive the next run [-].
CLIP_PRIORS = 3.0

# (ln E_s, ln E_d, ln E_b) → x = (ln D_L, ln D_R, ln b): D_L = E_s·D/√…, to first order
# ln D_L = ln E_s − ½ ln E_d, ln D_R = ln E_s + ½ ln E_d.
_TO_X = np.array([[1.0, -0.5, 0.0], [1.0, 0.5, 0.0], [0.0, 0.0, 1.0]])
_FROM_X = np.linalg.inv(_TO_X)


class EndPoseEstimator:
    """Gauss–Newton estimate of the effective D_L, D_R and b from runs' measured end poses.

    Args:
        robot: the nominal robot (its owner's knowledge: wheel diameter, wheelbase, encoder).
        sensor: accuracy of the end-pose measurement.
        initial: the prior's mean (default: the nominal robot, x = 0).

    Why end poses only: that is what a person with a tape measure (UMBmark's §6.3 procedure)
    or a sonar calibrator gets, and it is the fair comparison with UMBmark; the start pose of
    every run is exact (the measuring frame is set up there).
    """

    def __init__(
        self, robot: RobotSpec, sensor: SensorAccuracy, initial: Calibration | None = None
    ) -> None:
        self.robot = robot
        self.sensor = sensor
        self._sensor_var = np.array(
            [sensor.position_std**2, sensor.position_std**2, sensor.heading_std**2]
        )
        prior_cov = _TO_X @ np.diag(np.square(PRIOR_STD)) @ _TO_X.T
        self._prior_info = np.linalg.inv(prior_cov)
        self._prior_logdet = float(np.linalg.slogdet(prior_cov)[1])
        self._x0 = self._to_x(initial) if initial is not None else np.zeros(3)
        #: Keep the estimate near the prior's mean rather than the nominal robot (set by a
        #: session that starts a skid-steer robot from its apparent track).
        self.centred = False
        self._limit = CLIP_PRIORS * np.array(PRIOR_STD)  # on (ln E_s, ln E_d, ln E_b)
        self.x = self._x0.copy()
        self.covariance = prior_cov
        self.roughness = 1.0
        self._runs: list[tuple[Run, FloatArray]] = []  # (run, floor variance at ρ = 1)

    def _to_x(self, calibration: Calibration) -> FloatArray:
        p = calibration.parameters(self.robot)
        d, b = self.robot.wheel_diameter, self.robot.wheelbase
        return np.log([p["left_diameter"] / d, p["right_diameter"] / d, p["wheelbase"] / b]).astype(
            np.float64
        )

    @property
    def calibration(self) -> Calibration:
        """The calibration the estimate stands for (exactly the identity at x = 0)."""
        return self._calibration_at(self.x)

    def _calibration_at(self, x: FloatArray) -> Calibration:
        d, b = self.robot.wheel_diameter, self.robot.wheelbase
        return Calibration.from_parameters(
            self.robot,
            wheelbase=b * math.exp(x[2]),
            right_diameter=d * math.exp(x[1]),
            left_diameter=d * math.exp(x[0]),
        )

    @property
    def errors(self) -> FloatArray:
        """The estimated (E_d, E_b, E_s) [-]."""
        cal = self.calibration
        return np.array([cal.e_d, cal.wheelbase_scale, cal.distance_scale])

    @property
    def relative_std(self) -> FloatArray:
        """Posterior standard deviations of (ln E_s, ln E_d, ln E_b) over the prior's [-]."""
        cov = _FROM_X @ self.covariance @ _FROM_X.T
        out: FloatArray = np.sqrt(np.clip(np.diag(cov), 1e-30, None)) / np.array(PRIOR_STD)
        return out

    @property
    def prior_information(self) -> FloatArray:
        """The population prior's information matrix (inverse covariance) on x [-]."""
        out: FloatArray = self._prior_info.copy()
        return out

    @property
    def information_gain(self) -> float:
        """½·ln(det prior covariance / det posterior covariance) [nats]: what the runs so far
        taught the estimator (0 before any run)."""
        return 0.5 * (self._prior_logdet - float(np.linalg.slogdet(self.covariance)[1]))

    def residual(self, run: Run) -> tuple[FloatArray, FloatArray]:
        """Measured − predicted end pose of ``run`` in its start frame (x, y [m], θ [rad]) at
        the current estimate, and the Jacobian (3, 3) of the *predicted* end pose with respect
        to x (the residual's is its negative; Gauss–Newton steps by (JᵀWJ)⁻¹JᵀWr)."""
        poses, jac = replay_with_jacobian(run, self.robot, self.calibration)
        theta0 = float(run.true_pose[0, 2])
        c, s = math.cos(theta0), math.sin(theta0)
        rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        diff = run.true_pose[-1] - poses[-1]
        diff[2] = float(wrap_angle(diff[2]))
        return rot @ diff, rot @ jac[-1]

    def predicted_std(self, item: int) -> FloatArray:
        """Standard deviations of an end-pose residual of a run of menu item ``item`` at the
        current roughness estimate (x, y [m], θ [rad])."""
        floor = np.square(ACTION_MENU[item].floor_std)
        return np.sqrt(self._sensor_var + self.roughness**2 * floor)

    def add(self, run: Run, item: int, iterations: int = 1) -> FloatArray:
        """Take in one measured run of menu item ``item`` and update the estimate (this class
        refits all runs; :class:`TrajectoryEstimator` filters the new one).

        Returns the run's innovation — its residual at the estimate *before* the update,
        divided by :meth:`predicted_std` [-] — which tells a policy how surprising it was.
        """
        r, _ = self.residual(run)
        innovation = r / self.predicted_std(item)
        self._runs.append((run, np.square(np.array(ACTION_MENU[item].floor_std))))
        self._update(iterations)
        return innovation

    def _update(self, iterations: int) -> None:
        """Take in the run :meth:`add` just appended: refit on all runs so far."""
        self.fit(iterations)

    def fit(self, iterations: int = 2) -> None:
        """Gauss–Newton iterations on all runs so far, re-estimating the roughness factor."""
        for _ in range(iterations):
            info = self._prior_info.copy()
            grad = -self._prior_info @ (self.x - self._x0)
            residuals = []
            for run, floor_var in self._runs:
                r, jac = self.residual(run)
                weight = 1.0 / (self._sensor_var + self.roughness**2 * floor_var)
                info += jac.T @ (weight[:, None] * jac)
                grad += jac.T @ (weight * r)
                residuals.append(r)
            self.covariance = np.linalg.inv(info)
            self.x = self._clipped(self.x + self.covariance @ grad)
            self.roughness = self._roughness_from(residuals, self.roughness)

    def _clipped(self, x: FloatArray) -> FloatArray:
        """``x`` with (ln E_s, ln E_d, ln E_b) kept within :data:`CLIP_PRIORS` half-ranges of
        the nominal robot, or of the prior's mean when :attr:`centred` (a skid-steer session,
        whose apparent track lies far from the nominal one)."""
        if not self.centred:  # about the nominal robot
            out: FloatArray = _TO_X @ np.clip(_FROM_X @ x, -self._limit, self._limit)
            return out
        centre = _FROM_X @ self._x0
        shifted: FloatArray = _TO_X @ np.clip(
            _FROM_X @ x, centre - self._limit, centre + self._limit
        )
        return shifted

    def _roughness_from(self, residuals: list[FloatArray], current: float) -> float:
        """The roughness factor ρ that explains the end-pose residuals (one per run, in the
        order of the runs) beyond the sensor's accuracy: the floor-dominated components'
        excess variance over the menu's scatter at ρ = 1, clipped to [1, 20]; ``current`` when
        no component is floor-dominated."""
        excess, floor_total = 0.0, 0.0
        for r, (_, floor_var) in zip(residuals, self._runs, strict=True):
            floor_dominated = floor_var > self._sensor_var
            excess += float(np.sum((r**2 - self._sensor_var)[floor_dominated]))
            floor_total += float(np.sum(floor_var[floor_dominated]))
        if floor_total > 0.0:
            return float(np.clip(math.sqrt(max(excess, 0.0) / floor_total), 1.0, 20.0))
        return current


#: Roughness k [m^½] the trajectory filter's process noise is scaled from (times the estimated
#: factor ρ): the ``concrete`` benchmark floor's, at which :data:`ACTION_MENU`'s scatter was
#: measured.
REFERENCE_ROUGHNESS = 0.0004


def chunk_motions(
    run: Run, robot: RobotSpec, calibration: Calibration, every: int
) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.intp]]:
    """The motion of ``run`` between every ``every``-th sample, as the odometry with
    ``calibration`` dead-reckons it from the encoder counts, each chunk in its own start frame.

    Returns ``(u, jac, noise, ends)`` for the C chunks:

    * ``u`` (C, 3): the chunk's displacement (along, across [m]) and heading change [rad] in
      the frame of the chunk's first pose (midpoint integration, as
      :func:`odomgym.odometry.runs.replay_odometry`);
    * ``jac`` (C, 3, 3): ∂u/∂(ln D_L, ln D_R, ln b), as in
      :func:`odomgym.odometry.runs.replay_with_jacobian` but from each chunk's start;
    * ``noise`` (C, 3, 3): the covariance of u per unit k² [m^-1 · the units of u²] when each
      wheel's ground travel has white noise of variance k²·|d| (Chong & Kleeman 1997, Eq. 4):
      a wheel-travel error δ at step j moves the chunk's end by δ/2 along the heading μ_j and
      turns it by ∓δ/b about the robot's position at j, so
      Σ_j k²|d_L,j| g_L,j g_L,jᵀ + k²|d_R,j| g_R,j g_R,jᵀ;
    * ``ends`` (C,): the sample index at which each chunk ends.

    All chunks are computed at once (reduceat over the samples), so a 2 000-sample run costs a
    few vectorised passes, not a Python loop over samples.
    """
    steps = wheel_steps(run, robot, calibration)
    left, right, b, ds, dtheta = steps
    n = len(ds)
    starts = np.arange(0, n, every, dtype=np.intp)
    chunk = np.repeat(np.arange(len(starts)), np.diff(np.append(starts, n)))

    def since_start(values: FloatArray) -> FloatArray:
        """Cumulative sums of ``values`` (n, ...) from each chunk's start, before each step."""
        total = np.concatenate([np.zeros((1, *values.shape[1:])), np.cumsum(values, axis=0)])
        out: FloatArray = total[:-1] - total[starts][chunk]
        return out

    mid = since_start(dtheta) + 0.5 * dtheta
    cos_mid, sin_mid = np.cos(mid), np.sin(mid)
    step_x, step_y = ds * cos_mid, ds * sin_mid
    u = np.stack(
        [
            np.add.reduceat(step_x, starts),
            np.add.reduceat(step_y, starts),
            np.add.reduceat(dtheta, starts),
        ],
        axis=1,
    )
    d_x, d_y, d_dtheta = step_jacobians(steps, cos_mid, sin_mid, since_start)
    jac = np.stack(
        [
            np.add.reduceat(d_x, starts),
            np.add.reduceat(d_y, starts),
            np.add.reduceat(d_dtheta, starts),
        ],
        axis=1,
    )
    to_end_x = u[chunk, 0] - since_start(step_x)  # from the robot at step j to the chunk's end
    to_end_y = u[chunk, 1] - since_start(step_y)
    turn = np.full(n, 1.0 / b)
    g_left = np.stack([0.5 * cos_mid + to_end_y / b, 0.5 * sin_mid - to_end_x / b, -turn], axis=1)
    g_right = np.stack([0.5 * cos_mid - to_end_y / b, 0.5 * sin_mid + to_end_x / b, turn], axis=1)
    per_step = np.abs(left)[:, None, None] * (g_left[:, :, None] * g_left[:, None, :]) + np.abs(
        right
    )[:, None, None] * (g_right[:, :, None] * g_right[:, None, :])
    noise = np.add.reduceat(per_step, starts, axis=0)
    ends = np.append(starts[1:], n).astype(np.intp)
    return u, jac, noise, ends


class TrajectoryEstimator(EndPoseEstimator):
    """Estimate the effective D_L, D_R and b from whole measured trajectories.

    Where a lab records the whole run (motion capture, as OptiOdom's OptiTrack; every sample of
    a simulated run through :func:`odomgym.lab.simulated.measure`), the end pose throws most of it
    away. This estimator runs an augmented-state extended Kalman filter — the robot's pose and the
    three parameters x in one state (Larsen et al. 1998; Martinelli et al. 2007) — along each
    run: every ``chunk`` samples the odometry's motion with the
    current parameters predicts the pose (:func:`chunk_motions`), the floor's wheel-travel
    noise (Chong & Kleeman 1997, Eq. 4, with k = ρ·:data:`REFERENCE_ROUGHNESS`) widens it,
    and the measured pose (σ of the sensor) corrects pose and parameters together. The
    filter's parameter estimate after a run is the prior of the next, starting from the same
    population prior as :class:`EndPoseEstimator`; each run is filtered twice, the second time
    linearised at the first pass's estimate.

    Why a filter and not a least-squares fit of positions (:mod:`odomgym.baselines.trajectory`):
    the floor's noise accumulates along a run — a heading error at one metre moves every later
    position — so successive samples' errors are strongly correlated, and an unweighted fit
    counts the same disturbance many times. The filter models the accumulation and weighs each
    stretch of the run by what it can still tell. Measured on the calibrator benchmark's robots
    (8 runs of the scripted schedule, 100 robots): the errors of ln E_s, ln E_d, ln E_b match
    the filter's posterior standard deviations on ``concrete`` and ``rough`` within 10–25 %, and
    E_s is pinned 10× better than from end poses.

    The roughness factor ρ comes from the end-pose residuals as in :class:`EndPoseEstimator`;
    when it moves by more than 25 % from the value the runs were filtered with, all runs are
    filtered again from the prior (a rough floor is recognised after its first run, and that
    run no longer counts as if it were smooth).

    Args:
        robot: the nominal robot.
        sensor: accuracy of each measured pose sample.
        initial: the prior's mean (default: the nominal robot).
        chunk: samples between filter updates (20 = 1 s at the labs' 20 Hz) [-].
    """

    def __init__(
        self,
        robot: RobotSpec,
        sensor: SensorAccuracy,
        initial: Calibration | None = None,
        chunk: int = 20,
    ) -> None:
        super().__init__(robot, sensor, initial)
        self.chunk = require_count("chunk", chunk, 1)
        self._filtered_roughness = self.roughness

    def _update(self, iterations: int) -> None:
        """Filter the run :meth:`add` just appended (``iterations`` is ignored: each run is
        filtered twice), then settle the roughness factor."""
        del iterations
        self._filter_run(self._runs[-1][0])
        self._settle_roughness()

    def fit(self, iterations: int = 2) -> None:
        """Filter every run again from the prior (with the current roughness factor)."""
        del iterations
        self._refilter()

    def run_information(self, run: Run) -> FloatArray:
        """The information (3, 3) that ``run`` adds about x = (ln D_L, ln D_R, ln b) [-]:
        posterior minus prior inverse covariance of one filter pass from the population prior,
        linearised at the current estimate, with the current roughness factor ρ.

        Why it is useful: in the linearised model the increment does not depend on the prior
        or on the measured values, only on the run's shape, the floor (through ρ) and the
        sensor, so information matrices of different runs add up, and the posterior
        covariance of any set of runs is the inverse of the prior's information plus theirs —
        what an experiment design compares without driving the runs (information matrices
        add: Pukelsheim 2006, Ch. 1; ``benchmarks/design_bound.py``). Measured: on the three
        benchmark floors the runs' matrices plus the prior's match the filter's posterior
        information within 5e-4 (relative Frobenius norm).
        """
        prior_cov = np.linalg.inv(self._prior_info)
        _, cov = self._filter_pass(run, self.x, prior_cov, self.x, self.roughness)
        info = np.linalg.inv(cov) - self._prior_info
        out: FloatArray = 0.5 * (info + info.T)
        return out

    def _settle_roughness(self) -> None:
        for _ in range(2):
            residuals = [self.residual(run)[0] for run, _ in self._runs]
            self.roughness = self._roughness_from(residuals, self.roughness)
            if abs(math.log(self.roughness / self._filtered_roughness)) <= math.log(1.25):
                return
            self._refilter()

    def _refilter(self) -> None:
        self._filtered_roughness = self.roughness
        self.x = self._x0.copy()
        self.covariance = np.linalg.inv(self._prior_info)
        for run, _ in self._runs:
            self._filter_run(run)

    def _filter_run(self, run: Run) -> None:
        prior_x, prior_cov = self.x.copy(), self.covariance.copy()
        linearised_at = prior_x
        for _ in range(2):
            x, cov = self._filter_pass(
                run, prior_x, prior_cov, linearised_at, self._filtered_roughness
            )
            linearised_at = x
        self.x = self._clipped(x)
        self.covariance = cov

    def _filter_pass(
        self,
        run: Run,
        prior_x: FloatArray,
        prior_cov: FloatArray,
        linearised_at: FloatArray,
        roughness: float,
    ) -> tuple[FloatArray, FloatArray]:
        """One pass of the filter over ``run`` with roughness factor ``roughness``: the
        parameters' mean and covariance after it."""
        calibration = self._calibration_at(linearised_at)
        u, jac, noise, ends = chunk_motions(run, self.robot, calibration, self.chunk)
        noise = noise * (REFERENCE_ROUGHNESS * roughness) ** 2
        sensor = np.diag(self._sensor_var)
        mean = np.concatenate([run.true_pose[0], prior_x])  # the start pose is exact
        cov = np.zeros((6, 6))
        cov[3:, 3:] = prior_cov
        transition = np.eye(6)
        for c, end in enumerate(ends):
            cos_t, sin_t = math.cos(mean[2]), math.sin(mean[2])
            rot = np.array([[cos_t, -sin_t, 0.0], [sin_t, cos_t, 0.0], [0.0, 0.0, 1.0]])
            moved = rot @ (u[c] + jac[c] @ (mean[3:] - linearised_at))
            transition[0, 2] = -moved[1]
            transition[1, 2] = moved[0]
            transition[:3, 3:] = rot @ jac[c]
            mean[:3] += moved
            cov = transition @ cov @ transition.T
            cov[:3, :3] += rot @ noise[c] @ rot.T
            innovation = run.true_pose[end] - mean[:3]
            innovation[2] = float(wrap_angle(innovation[2]))
            gain = np.linalg.solve(cov[:3, :3] + sensor, cov[:3, :]).T
            mean = mean + gain @ innovation
            cov = cov - gain @ cov[:3, :]
            cov = 0.5 * (cov + cov.T)
        return mean[3:], cov[3:, 3:]


#: What the session's estimator sees of each run: ``"trajectory"`` (every measured pose sample,
#: :class:`TrajectoryEstimator`, the default: the labs record them) or ``"end_pose"`` (the end
#: pose only, :class:`EndPoseEstimator`: what UMBmark's tape measure gives).
ESTIMATORS: dict[str, type[EndPoseEstimator]] = {
    "trajectory": TrajectoryEstimator,
    "end_pose": EndPoseEstimator,
}


def check_observe(observe: object) -> str:
    """``observe`` if it names an estimator of :data:`ESTIMATORS`, else a SpecError naming it."""
    if not isinstance(observe, str) or observe not in ESTIMATORS:
        raise SpecError(
            f"observe must be one of {', '.join(ESTIMATORS)}, got {observe!r}", field="observe"
        )
    return observe

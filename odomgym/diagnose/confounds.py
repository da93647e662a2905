"""Confounds, derived from the data at hand: where robot effects and measurement errors give the
same logs.

A fitted robot effect is a statement about the robot only if nothing else produces the same
logs. Some things do, exactly: a ground-truth frame scaled by 0.5 % is a robot whose wheels are
0.5 % larger and whose wheelbase is 0.5 % wider; a rigid body yawed on the robot is a wheel toe.
Which confounds exist depends on the model *and* on the runs — closed squares measured at their
end points cannot tell a common scale of wheels and wheelbase from nothing at all — so they are
derived here from the data, not listed by hand.

**Which.** The joint Jacobian of the fit's open-loop residuals with respect to the robot's
parameters and every measurement nuisance (:func:`odomgym.diagnose.sensitivity.joint_jacobian`;
invisible nuisances left out), every column scaled to unit norm. A direction whose singular
value is below :data:`RELATIVE_SINGULAR_VALUE` (10⁻³) of the largest is one in which the data
cannot tell its parts apart: the bound at which
:func:`odomgym.diagnose.discover.library_jacobian` drops a term and the gate's variance
inflation bound (VIF 10⁶; Kutner, Nachtsheim, Neter & Li 2005, §10.5) refuses one. The
near-null space (numerical rank from the singular value decomposition: Golub & Van Loan 2013,
*Matrix Computations*, 4th ed., §5.5) gets a basis by Gauss–Jordan elimination with the
robot's columns as pivots, and each direction is made as sparse as the data allow
(:func:`_partners`): its robot part alone where that is a confound too — robot against robot,
the data cannot tell those parameters apart even with every nuisance known — else one
direction for each kind of nuisance that completes it alone (E_s trades against a frame scale
and, on constant-speed runs, against a clock rate: two confounds, not one mixing both).
Directions without a robot parameter are the nuisances' own affair and are dropped. A weak
column is not a confound: its parameter is imprecise, which its standard error says.

**Moved?** The fitted change of the robot's parameters from the model as given is projected on
a confound's robot part; against the standard error of that projection (cluster-robust, as the
fit's own errors: Liang & Zeger 1986; session-clustered with two or more sessions but never
below run-clustered, since with few sessions their sandwich has no spread along most
directions) it has *moved* beyond the two-sided 95 % interval of Student's t with G − 1 degrees
of freedom, G its clusters (:data:`MOVED`); never along a direction the fit
is free along (robot-against-robot, or against nuisances it fits), whose values there are set
by a signal below the rule's bound. Its two readings are then: the robot changed by
the projection (the measurement as fitted), or the robot as given along the direction and the
nuisances changed by the opposite amount — to first order the same residuals.

**Which experiment separates them.** Each experiment of
:data:`odomgym.diagnose.experiments.SEPARATING_EXPERIMENTS` (the nominal robot's counts) is
replayed under both readings; the one whose predicted logs differ most, in units of the sensor's
noise, is named. Where no experiment moves the two readings apart by more than
:data:`RELATIVE_SINGULAR_VALUE` of what the robot part alone moves (an exact confound: a frame
scale, a frame yaw), the measurement check of the nuisance is named instead
(:attr:`odomgym.diagnose.sensitivity.NuisanceKind.check`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from odomgym.diagnose.experiments import SEPARATING_EXPERIMENTS, synthetic_run
from odomgym.diagnose.fit import build_within
from odomgym.diagnose.likelihood import SensorNoise
from odomgym.diagnose.openloop import OpenLoopData, OpenLoopFit
from odomgym.diagnose.replay import replay_run
from odomgym.diagnose.sensitivity import (
    NUISANCE_KINDS,
    JointJacobian,
    joint_jacobian,
    remove_nuisances,
    robot_parameters,
)
from odomgym.diagnose.stats import clustered_covariance
from odomgym.robot import RobotSpec

__all__ = [
    "MOVED",
    "RELATIVE_SINGULAR_VALUE",
    "Component",
    "Confound",
    "derive_confounds",
]

FloatArray = NDArray[np.float64]
RELATIVE_SINGULAR_VALUE = 1e-3
"""A direction of the unit-column joint Jacobian whose singular value is below this fraction of
the largest is a confound (module docstring)."""
MOVED = 0.975
"""A fit has moved along a confound when its projection lies beyond the two-sided 95 % interval
of its cluster-robust standard error: beyond the 0.975 quantile of Student's t with G − 1
degrees of freedom standard errors, G the clusters the error was taken over (Cameron & Miller
2015, §VI: with few clusters a normal critical value, 1.96, rejects too often — on effect-free
logs of two sessions a frame scale had "moved" by 2.0 standard errors)."""


def _critical(clusters: int) -> float:
    """How many standard errors a move must exceed (:data:`MOVED`)."""
    return float(stats.t.ppf(MOVED, max(clusters - 1, 1)))


_KEPT = 1e-3  # components of a reported direction below this (unit vector) are dropped
_SHOWN = 0.05  # components a sentence names
_LINEAR = 0.01  # the separations' move, in units of one parameter scale (first order)


@dataclass(frozen=True)
class Component:
    """One part of a confound's direction.

    Attributes:
        name: the column (a robot parameter ``EFFECT.PARAMETER``, or a nuisance).
        weight: its share of the unit direction, every column scaled to unit norm first.
        per_unit: the change of the quantity itself for a unit move along the direction [unit].
        unit: the quantity's SI unit.
        robot: whether it is one of the robot's parameters.
    """

    name: str
    weight: float
    per_unit: float
    unit: str
    robot: bool

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class Confound:
    """A direction in which the robot's parameters and the nuisances give the same logs.

    Attributes:
        components: the direction (unit vector over unit-norm columns; components below 1e-3
            dropped), robot parameters first.
        relative_singular_value: |J̃·v| / the largest singular value of J̃, J̃ the joint
            Jacobian with unit columns (0 for a robot parameter the data do not see).
        move, move_stderr: the fitted change of the robot from the model as given, projected on
            the direction's robot part, and its standard error (direction units; ∞ where the
            fit is free along the direction, NaN where it cannot give one).
        moved: |move| beyond the 95 % interval, t(G − 1) · move_stderr (:data:`MOVED`; never
            where ``fitted``).
        fitted: whether the fit has every part of the direction free (robot parameters and
            fitted nuisances): then its values along it are set by a signal below the rule's
            bound (the gate's variance inflation refuses such a term), not moved.
        robot_reading: the first reading — each robot parameter's change by ``move`` [its unit].
        nuisance_reading: the second — each nuisance's value, the robot as given along the
            direction [its unit]; empty for a direction of robot parameters alone.
        experiment: the menu's experiment whose predicted logs under the two readings differ
            most (None where none does: an exact confound, or a robot parameter seen by none).
        separation_sigma: by how much, the larger of position and heading in sensor σ, at the
            move ``probe``.
        probe: the move the separations are given at: |move| where the fit moved, else a
            reference move, the largest robot component changed by its parameter's scale.
        separations: every experiment's separation at ``probe`` [sensor σ].
        check: where no robot experiment separates the readings, the measurement that does
            (:attr:`odomgym.diagnose.sensitivity.NuisanceKind.check` of the largest nuisance
            component).
    """

    components: tuple[Component, ...]
    relative_singular_value: float
    move: float
    move_stderr: float
    moved: bool
    fitted: bool
    robot_reading: tuple[tuple[str, float], ...]
    nuisance_reading: tuple[tuple[str, float], ...]
    experiment: str | None
    separation_sigma: float
    probe: float
    separations: tuple[tuple[str, float], ...]
    check: str | None

    @property
    def robot(self) -> tuple[str, ...]:
        """The robot parameters involved."""
        return tuple(c.name for c in self.components if c.robot)

    @property
    def nuisances(self) -> tuple[str, ...]:
        """The nuisances involved."""
        return tuple(c.name for c in self.components if not c.robot)

    def direction(self) -> str:
        """The direction as named components, largest first (those of at least 0.05)."""
        shown = sorted(self.components, key=lambda c: -abs(c.weight))
        return ", ".join(f"{c.name} {c.weight:+.2f}" for c in shown if abs(c.weight) >= _SHOWN)

    def sentence(self) -> str:
        """One sentence for the report: the direction, whether the fit moved along it, the
        two readings and what separates them."""
        where = f"({self.direction()}; relative singular value {self.relative_singular_value:.1e})"
        shown = [c for c in self.components if abs(c.weight) >= _SHOWN]
        robot = [c.name for c in shown if c.robot] or list(self.robot)
        others = [c.name for c in shown if not c.robot]
        if others:
            head = f"{_names(robot)} trade against {_names(_kinds(others))} {where}"
        elif len(self.robot) > 1:
            head = f"{_names(robot)} cannot be told apart on these data {where}"
        else:
            head = f"{_names(robot)} is not seen by these data {where}"
        if self.moved:
            second = (
                f"{_nuisance_text(self.nuisance_reading)} with the rest of the fitted model"
                if self.nuisance_reading
                else "the robot as given"
            )
            body = (
                f"the fit moved along it by {abs(self.move) / self.move_stderr:.1f} standard "
                f"errors, so the logs read equally as the robot with "
                f"{_robot_text(self.robot_reading, self.components)} or as {second}"
            )
        elif self.fitted:
            body = "the fit has every part of it free, so its values along it are not determined"
        elif math.isfinite(self.move_stderr) and self.move_stderr > 0:
            body = (
                f"the fit did not move along it ({abs(self.move) / self.move_stderr:.1f} "
                "standard errors)"
            )
        else:
            body = "the fit cannot give its values along it a standard error"
        if self.experiment is not None:
            tail = (
                f"the experiment '{self.experiment}' separates them by "
                f"{self.separation_sigma:.1f} σ of the sensor"
            )
        elif self.check is not None:
            tail = f"no robot experiment separates them: {self.check}"
        else:
            tail = "no experiment of the menu separates them"
        return f"{head}: {body}; {tail}."

    def as_dict(self) -> dict[str, Any]:
        """JSON-safe (non-finite numbers as None)."""
        return {
            "components": [c.as_dict() for c in self.components],
            "relative_singular_value": _finite(self.relative_singular_value),
            "move": _finite(self.move),
            "move_stderr": _finite(self.move_stderr),
            "moved": self.moved,
            "fitted": self.fitted,
            "robot_reading": {k: _finite(v) for k, v in self.robot_reading},
            "nuisance_reading": {k: _finite(v) for k, v in self.nuisance_reading},
            "experiment": self.experiment,
            "separation_sigma": _finite(self.separation_sigma),
            "probe": _finite(self.probe),
            "separations": {k: _finite(v) for k, v in self.separations},
            "check": self.check,
            "sentence": self.sentence(),
        }


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _names(names: Sequence[str]) -> str:
    return " and ".join([", ".join(names[:-1]), names[-1]] if len(names) > 1 else names)


def _kinds(names: Sequence[str]) -> list[str]:
    """Nuisance column names without their sessions, each once."""
    return list(dict.fromkeys(n.split("[", 1)[0] for n in names))


def _robot_text(reading: Sequence[tuple[str, float]], components: Sequence[Component]) -> str:
    """Each robot parameter's change, a dimensionless one in per cent."""
    units = {c.name: c.unit for c in components}
    return ", ".join(
        f"{name} {100.0 * value:+.3f} %"
        if units[name] == "-"
        else f"{name} {value:+.4g} {units[name]}"
        for name, value in reading
    )


def _nuisance_text(reading: Sequence[tuple[str, float]]) -> str:
    """Each nuisance kind's value, the mean over its sessions where there are several."""
    by_kind: dict[str, list[float]] = {}
    for name, value in reading:
        by_kind.setdefault(name.split("[", 1)[0], []).append(value)
    kinds = {k.name: k for k in NUISANCE_KINDS}
    parts = []
    for name, values in by_kind.items():
        kind = kinds[name]
        text = kind.reading.format(value=float(np.mean(values)) * kind.display)
        parts.append(text + (f" (mean of {len(values)} sessions)" if len(values) > 1 else ""))
    return _names(parts)


def _sparse_basis(null: FloatArray, robot: int) -> list[FloatArray]:
    """A basis of the span of ``null``'s columns made of sparse directions, one per robot
    parameter it involves: Gauss–Jordan elimination of ``null``ᵀ with the robot's columns
    (the first ``robot``) preferred as pivots, largest entry first; then each robot direction
    made orthogonal to the directions without a robot parameter (they are the nuisances' own
    trade-offs, not part of it). Returns the robot directions."""
    rows = null.T.copy()
    pivots: list[int] = []
    for i in range(len(rows)):
        rest = rows[i:]
        rest /= np.linalg.norm(rest, axis=1, keepdims=True)
        free = np.ones(rows.shape[1], dtype=bool)
        free[pivots] = False
        size = np.abs(rest) * free
        mine = size[:, :robot]
        pick = mine if mine.size and float(mine.max()) >= 10 * _KEPT else size
        r, c = (int(a) for a in np.unravel_index(int(np.argmax(pick)), pick.shape))
        rows[[i, i + r]] = rows[[i + r, i]]
        rows[i] /= rows[i, c]
        for o in range(len(rows)):
            if o != i:
                rows[o] -= rows[o, c] * rows[i]
        pivots.append(c)
    own = [rows[i] for i, p in enumerate(pivots) if p >= robot]
    out = []
    basis = np.linalg.qr(np.array(own).T)[0] if own else np.zeros((rows.shape[1], 0))
    for i, p in enumerate(pivots):
        if p < robot:
            v = rows[i] - basis @ (basis.T @ rows[i])
            out.append(v / np.linalg.norm(v))
    return out


def _robot_covariances(fit: OpenLoopFit) -> list[tuple[FloatArray, int]]:
    """Cluster-robust covariances of the fit's robot parameters (fit units): run-clustered, and
    with two or more sessions session-clustered too — the sandwiches of
    :func:`odomgym.diagnose.openloop._clustered_errors` (Liang & Zeger 1986) — with the normal
    matrix inverted without the directions the 1e-3 rule calls unidentifiable (eigenvalues of
    the unit-scaled normal matrix below (1e-3)²): a confound the fit is free along (a toe
    against fitted frame yaws) must not spread its rounding noise into the others' errors.
    Where every direction is identifiable this is the plain inverse. Each comes with its
    number of clusters."""
    problem = fit.problem
    robot, own, res = fit.blocks
    a, _ = problem.normal(robot, own, res, range(len(res)))
    diagonal = np.sqrt(np.maximum(np.diag(a), 0.0))
    seen = diagonal > 0
    inverse = 1.0 / np.where(seen, diagonal, 1.0)
    values, vectors = np.linalg.eigh(a * np.outer(inverse, inverse))
    keep = values > RELATIVE_SINGULAR_VALUE**2 * float(np.max(values, initial=0.0))
    pseudo = (vectors[:, keep] / values[keep]) @ vectors[:, keep].T
    cov: FloatArray = pseudo * np.outer(inverse, inverse) * np.outer(seen, seen)
    scores = np.array([problem.score(robot, own, res, j) for j in range(len(res))])
    sessions = list(problem.data.sessions)
    groups: list[list[object]] = [list(range(len(res)))]
    if len(set(sessions)) >= 2:
        groups.append(list(sessions))
    size = problem.size
    return [
        (clustered_covariance(cov, scores, labels)[:size, :size], len(set(labels)))
        for labels in groups
    ]


def _separations(
    jacobian: JointJacobian,
    given: RobotSpec,
    components: Sequence[Component],
    reference: float,
    sensor: SensorNoise,
) -> tuple[list[tuple[str, float]], list[float]]:
    """Every menu experiment's separation of the two readings [sensor σ] and the largest change
    the robot part alone makes there [sensor σ], for a move ``reference`` along the direction:
    the first reading is the fitted robot without nuisances; the second the robot moved back by
    ``reference`` along the direction's robot part with the nuisances it names (each kind's
    mean over its sessions), its predicted logs compared with the first's."""
    problem = jacobian.fit.problem
    index = {name: k for k, name in enumerate(jacobian.names)}
    du = np.zeros(problem.size)
    nuisance: dict[int, list[float]] = {}
    by_name = {c.name: c for c in jacobian.columns}
    for part in components:
        column = by_name[part.name]
        if column.parameter is not None:
            du[index[part.name]] = -reference * part.per_unit / column.parameter.scale
        else:
            nuisance.setdefault(column.kind, []).append(-reference * part.per_unit)
    values = np.zeros(len(NUISANCE_KINDS))
    for kind, moved in nuisance.items():
        values[kind] = float(np.mean(moved))
    first = jacobian.fit.spec
    second = build_within(problem.build, jacobian.fit.x[: problem.size], du)
    scale = np.array([sensor.position, sensor.position, sensor.heading])
    out: list[tuple[str, float]] = []
    effects: list[float] = []
    for experiment in SEPARATING_EXPERIMENTS:
        run = synthetic_run(experiment, given)
        logged = dataclasses.replace(run, true_pose=replay_run(run, first).tracked)
        fixed = remove_nuisances(logged, values)
        apart = fixed.true_pose - replay_run(fixed, second).tracked
        alone = logged.true_pose - replay_run(logged, second).tracked
        out.append((experiment.name, _in_sigma(apart, scale)))
        effects.append(_in_sigma(alone, scale))
    return out, effects


def _in_sigma(error: FloatArray, scale: FloatArray) -> float:
    """The larger of the largest position and heading difference, in sensor σ."""
    position = float(np.max(np.hypot(error[:, 0], error[:, 1])))
    heading = float(np.max(np.abs(np.mod(error[:, 2] + math.pi, 2 * math.pi) - math.pi)))
    return max(position / max(float(scale[0]), 1e-12), heading / max(float(scale[2]), 1e-12))


def derive_confounds(
    data: OpenLoopData,
    fit: OpenLoopFit,
    given: RobotSpec,
    *,
    sensor: SensorNoise | None = None,
    jacobian: JointJacobian | None = None,
) -> list[Confound]:
    """Every confound of ``fit``'s robot parameters on ``data`` (module docstring), strongest
    first, with whether the fit moved along it from ``given``, its two readings and the
    experiment or measurement that separates them.

    Args:
        data: the runs ``fit`` was fitted on.
        fit: an open-loop fit (:func:`~odomgym.diagnose.openloop.fit_open_loop`).
        given: the model as given (the robot the fitted changes are measured from).
        sensor: the ground-truth sensor's noise, the unit of the separations (1 mm, 2 mrad
            unless given).
        jacobian: :func:`~odomgym.diagnose.sensitivity.joint_jacobian` of ``fit`` on
            ``data``, if the caller has it (it also lists the invisible nuisances).
    """
    noise = sensor if sensor is not None else SensorNoise(0.001, 0.002)
    jac = jacobian if jacobian is not None else joint_jacobian(data, fit)
    robot = jac.robot
    if robot == 0:
        return []
    seen = np.flatnonzero(jac.norms > 0)
    unseen = [k for k in range(robot) if jac.norms[k] == 0]
    scaled = jac.matrix[:, seen] / jac.norms[seen]
    _, singular, vt = np.linalg.svd(scaled, full_matrices=False)
    largest = float(singular[0]) if len(singular) else 1.0
    null = vt[singular < RELATIVE_SINGULAR_VALUE * largest].T
    directions: list[FloatArray] = []
    for v in _sparse_basis(null, int(np.sum(seen < robot))) if null.size else []:
        full = np.zeros(len(jac.names))
        full[seen] = v
        directions.append(full)
    for k in unseen:
        full = np.zeros(len(jac.names))
        full[k] = 1.0
        directions.append(full)
    parameters = [c.parameter for c in jac.columns[:robot]]
    scales = np.array([p.scale for p in parameters if p is not None])
    reads = robot_parameters(fit)
    given_values = fit.effect.read(given) if fit.effect is not None else {}
    keys = [n if n in fit.values else n.split(".", 1)[1] for n, _ in reads]
    change = np.array([fit.values[k] - given_values[k] for k in keys])
    physical = [(np.diag(scales) @ c @ np.diag(scales), g) for c, g in _robot_covariances(fit)]
    out = []
    kept: list[FloatArray] = []
    unit = np.zeros_like(jac.matrix)
    unit[:, seen] = scaled
    kinds: dict[int, NDArray[np.bool_]] = {}
    for k, column in enumerate(jac.columns[robot:], start=robot):
        kinds.setdefault(column.kind, np.zeros(len(jac.names), dtype=bool))[k] = True
    norms = np.where(jac.norms > 0, jac.norms, 1.0)
    for found in directions:
        for v in _partners(unit, found, robot, list(kinds.values()), largest):
            top = int(np.argmax(np.abs(v[:robot])))
            v *= math.copysign(1.0, v[top])
            if any(abs(float(v @ w)) > 1.0 - 1e-6 for w in kept):
                continue  # found again from another robot direction
            kept.append(v)
            per_unit = np.where(jac.norms > 0, v / norms, v)
            components = tuple(
                Component(
                    jac.names[k],
                    float(v[k]),
                    float(per_unit[k]),
                    jac.columns[k].unit,
                    bool(k < robot),
                )
                for k in np.flatnonzero(v)
            )
            sigma = _relative(unit, v, largest)
            out.append(_assess(jac, given, components, v, change, physical, sigma, noise))
    return sorted(out, key=lambda c: c.relative_singular_value)


def _relative(unit: FloatArray, v: FloatArray, largest: float) -> float:
    """|J̃·v| / the largest singular value, J̃ the unit-column Jacobian."""
    return float(np.linalg.norm(unit @ v)) / largest


def _best_on(unit: FloatArray, support: NDArray[np.bool_]) -> FloatArray:
    """The unit direction on ``support`` whose residual change is least: the last right
    singular vector of those columns (zero elsewhere)."""
    _, _, vt = np.linalg.svd(unit[:, support], full_matrices=False)
    best = np.zeros(unit.shape[1])
    best[support] = vt[-1]
    return best


def _trimmed(unit: FloatArray, v: FloatArray, largest: float) -> FloatArray:
    """``v`` without its components below 1e-3: the best direction on the rest if that is still
    a confound (a truncation alone would leave |J̃·v| at the size of what was dropped), else
    ``v`` itself."""
    support = np.abs(v) >= _KEPT * float(np.max(np.abs(v)))
    best = _best_on(unit, support)
    return best if _relative(unit, best, largest) < RELATIVE_SINGULAR_VALUE else v


def _partners(
    unit: FloatArray,
    found: FloatArray,
    robot: int,
    kinds: Sequence[NDArray[np.bool_]],
    largest: float,
) -> list[FloatArray]:
    """The confounds a near-null direction ``found`` stands for, each as sparse as the data
    allow: its robot part alone if that is a confound (robot against robot); else one
    direction for each kind of nuisance (all its sessions' columns) that completes the robot
    part alone — a robot parameter may trade against two nuisances separately (E_s against a
    frame scale and against a clock rate on constant-speed runs), and one direction mixing them
    would hide both; else ``found`` itself (its nuisances needed together)."""
    v = _trimmed(unit, found / np.linalg.norm(found), largest)
    mine = (np.abs(v) > 0) & (np.arange(len(v)) < robot)
    alone = _best_on(unit, mine)
    if _relative(unit, alone, largest) < RELATIVE_SINGULAR_VALUE:
        return [_trimmed(unit, alone, largest)]
    out = []
    for columns in kinds:
        w = _best_on(unit, mine | columns)
        if (
            _relative(unit, w, largest) < RELATIVE_SINGULAR_VALUE
            and float(np.max(np.abs(w[columns]))) >= _KEPT
            and float(np.max(np.abs(w[mine]))) >= _KEPT
        ):
            out.append(_trimmed(unit, w, largest))
    return out or [v]


def _assess(
    jac: JointJacobian,
    given: RobotSpec,
    components: tuple[Component, ...],
    v: FloatArray,
    change: FloatArray,
    covariances: Sequence[tuple[FloatArray, int]],
    sigma: float,
    sensor: SensorNoise,
) -> Confound:
    """The confound along unit direction ``v``: the fit's move along it (the fitted ``change``
    of the robot in physical units, its ``covariances`` with their cluster counts), the
    readings and the separations."""
    robot = jac.robot
    part = v[:robot]
    weight = part / float(part @ part)
    norms = jac.norms[:robot]
    move = float(weight @ (norms * change))
    by_name = {c.name: c for c in jac.columns}
    nuisance_parts = [c for c in components if not c.robot]
    active = set(jac.fit.problem.active)
    fitted = all(by_name[c.name].kind in active for c in nuisance_parts)
    critical = _critical(2)
    if fitted:  # free in the fit: its values along it are set by a signal below the bound
        stderr = math.inf
    else:
        # Session-clustered where there are sessions, but never below run-clustered: the
        # sessions' scores sum to zero at the fit, so with G sessions their sandwich has rank
        # G − 1 and, with two or three, no spread along most directions (Cameron & Miller
        # 2015 on few clusters).
        spreads = [
            (float(weight @ (norms[:, None] * c * norms[None, :]) @ weight), g)
            for c, g in covariances
        ]
        finite = [(v, g) for v, g in spreads if math.isfinite(v)]
        if finite:
            largest, clusters = max(finite)
            stderr = math.sqrt(max(largest, 0.0))
            critical = _critical(clusters)
        else:
            stderr = math.nan
    moved = math.isfinite(stderr) and abs(move) > critical * stderr
    robot_reading = tuple((c.name, move * c.per_unit) for c in components if c.robot)
    nuisance_reading = tuple((c.name, -move * c.per_unit) for c in components if not c.robot)
    robot_parts = [c for c in components if c.robot]
    scales = {c.name: c.parameter.scale for c in jac.columns[:robot] if c.parameter is not None}
    unit_move = 1.0 / max(abs(c.per_unit) / scales[c.name] for c in robot_parts)
    # First order: at 1 % of a parameter scale the second-order terms are 1e-5 of the first.
    reference = _LINEAR * unit_move
    separations, effects = _separations(jac, given, components, reference, sensor)
    probe = abs(move) if moved else unit_move
    ratio = probe / reference
    separations = [(name, value * ratio) for name, value in separations]
    best = max(separations, key=lambda item: item[1])
    exact = best[1] <= RELATIVE_SINGULAR_VALUE * max(effects) * ratio
    experiment = None if exact or best[1] == 0.0 else best[0]
    check = None
    if experiment is None and nuisance_parts:
        biggest = max(nuisance_parts, key=lambda c: abs(c.weight))
        check = NUISANCE_KINDS[by_name[biggest.name].kind].check
    return Confound(
        components=components,
        relative_singular_value=sigma,
        move=move,
        move_stderr=stderr,
        moved=moved,
        fitted=fitted,
        robot_reading=robot_reading,
        nuisance_reading=nuisance_reading,
        experiment=experiment,
        separation_sigma=best[1],
        probe=probe,
        separations=tuple(separations),
        check=check,
    )

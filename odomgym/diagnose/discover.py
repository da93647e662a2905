"""Discovery: effects the catalogue does not hold, found by sparse regression on the residuals.

When the best catalogue model still leaves structure in its whitened innovations, the workflow
regresses them on a library of candidate terms, the grammar of :mod:`odomgym.effects.discovered`
(each channel — left/right wheel travel, crab angle, yaw increment — times each modulator —
1, |v|, v², |ω|, |v·ω|, direction, acceleration, the wheels' angles, session time):

1. **Library.** Each term's column is the derivative of every run's whitened innovations with
   respect to its coefficient at the current model (central differences through the replay and
   the Kalman filter), so the regression is generalised least squares on the pose disagreement,
   not on numerically differentiated states. Columns that the runs cannot tell apart from
   earlier ones (a modulator that never varies, e.g. the direction of travel when the robot
   never reverses) are dropped and listed.
2. **Sparse selection.** Sequentially thresholded ridge regression (STLSQ, Brunton, Proctor &
   Kutz 2016, as implemented by PySINDy's ``STLSQ`` optimizer, ridge weight :data:`RIDGE`) on
   unit-norm columns, where a well-resolved coefficient's noise is one whitened unit. The
   threshold is chosen by K-fold cross-validation over **whole runs** (the folds of the
   catalogue fits): the held-out sum of squared whitened innovations, never an in-sample fit.
3. **Test.** The selected terms are fitted jointly (non-linear least squares, the sensor and
   wheel noise refitted beside them, as a catalogue candidate) and each kept only if its Wald
   statistic passes α/2 after a Bonferroni correction over the whole library, and the set must
   raise the cross-validated log-likelihood.

:func:`structure_test` is the Lagrange-multiplier (score) test of the same library: do the
whitened innovations depend on any term? It decides whether the systematic structure is
exhausted (before a noise effect may be named) and, on held-out runs, whether the final model
is ``explained``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from odomgym.diagnose.fit import (
    CandidateFit,
    Dataset,
    cross_validate,
    evaluate,
    fit_candidate,
    whitened_stacks,
)
from odomgym.diagnose.likelihood import SensorNoise
from odomgym.diagnose.physical import term_modulator
from odomgym.diagnose.replay import replay_run
from odomgym.diagnose.stats import sign_flip_p, wald_p
from odomgym.effects import Effect
from odomgym.effects.discovered import (
    CATALOGUE_POINTS,
    TERMS,
    DiscoveredTerms,
    describe_term,
    term_by_name,
)
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "THRESHOLDS",
    "TIE",
    "Discovery",
    "StructureTest",
    "best_threshold",
    "channel_evidence",
    "discover",
    "library_jacobian",
    "structure_test",
    "term_sentence",
]

FloatArray = NDArray[np.float64]

THRESHOLDS = (3.0, 4.0, 5.0, 6.5, 8.0, 10.0, 13.0, 16.0, 20.0, 25.0, 32.0, 40.0, 50.0, 64.0)
"""STLSQ thresholds tried, in whitened units of a unit-norm column (a coefficient's noise is 1)."""
BLOCK = 60
"""Whitened innovations per block of the sign-flip test: 60 values are 20 checkpoints of the
likelihood (5 s at the default 0.25 s), longer than the few samples the filter needs to absorb
a jump, shorter than an arc or a straight, so an effect shown by a few runs still spans many
blocks."""

RIDGE = 0.1
"""STLSQ's ridge weight on unit-norm columns: it damps the directions the runs barely resolve
(near-collinear terms such as v² and |v·ω| on arcs of one radius, whose least-squares
coefficients cancel each other at large values and fail on held-out runs), and shrinks a
well-resolved term by only ~10 % before the threshold; the kept terms are refitted unbiased."""
_STEP = 0.5  # finite-difference step in units of a term's scale


@dataclass
class Library:
    """Whitened innovations and their derivatives with respect to the library's terms."""

    terms: list[str]
    residual: list[FloatArray]  # per run (m_j,)
    jacobian: list[FloatArray]  # per run (m_j, K), per unit of coefficient
    dropped: list[str] = field(default_factory=list)  # not identifiable from these runs


def library_jacobian(
    data: Dataset,
    spec: RobotSpec,
    sensor: SensorNoise,
    terms: Sequence[str] | None = None,
    *,
    processes: int = 1,
) -> Library:
    """Every run's whitened innovations at ``spec`` and their derivatives with respect to each
    term's coefficient (central differences about the spec's current value); columns the runs
    cannot separate from earlier ones are dropped (relative residual norm below 1e-3 after
    projecting on the kept columns). ``processes``: the evaluations (two per term) are shared
    among that many forked processes (:func:`~odomgym.diagnose.fit.whitened_stacks`; the same
    numbers)."""
    names = list(terms) if terms is not None else [t.name for t in TERMS]
    steps: list[tuple[float, float]] = []
    specs = [spec]
    labels = ["the model itself"]
    for name in names:
        effect = DiscoveredTerms([name])
        current = effect.read(spec)[name]
        h = _STEP * term_by_name(name).scale
        bound = effect.parameters[0]
        high = min(current + h, bound.high)
        low = max(current - h, bound.low)
        steps.append((high, low))
        specs += [effect.write(spec, {name: high}), effect.write(spec, {name: low})]
        labels += [f"term {name} at {high:g}", f"term {name} at {low:g}"]
    base: list[FloatArray] = []
    waiting: dict[int, list[FloatArray]] = {}  # one side of a term's difference
    derivatives: dict[int, list[FloatArray]] = {}

    def use(index: int, stack: list[FloatArray]) -> None:
        # Each term's central difference as soon as both sides are in (the stacks are not
        # all kept: they add up to hundreds of MB on large data).
        if index == 0:
            base.extend(stack)
            return
        k = (index - 1) // 2
        other = waiting.pop(k, None)
        if other is None:
            waiting[k] = stack
            return
        plus, minus = (stack, other) if index % 2 == 1 else (other, stack)
        high, low = steps[k]
        derivatives[k] = [(p - m) / (high - low) for p, m in zip(plus, minus, strict=True)]

    whitened_stacks(data, specs, sensor, use, processes, labels)
    columns: list[list[FloatArray]] = [[] for _ in data.runs]
    kept: list[str] = []
    dropped: list[str] = []
    basis: list[FloatArray] = []
    for k, name in enumerate(names):
        per_run = derivatives.pop(k)
        stacked = np.concatenate(per_run)
        norm = float(np.linalg.norm(stacked))
        residual = stacked.copy()
        for q in basis:
            residual -= (q @ residual) * q
        if (
            norm == 0.0
            or not np.all(np.isfinite(stacked))
            or np.linalg.norm(residual) < 1e-3 * norm
        ):
            dropped.append(name)
            continue
        basis.append(residual / np.linalg.norm(residual))
        kept.append(name)
        for j, col in enumerate(per_run):
            columns[j].append(col)
    jac = [np.stack(c, axis=1) if c else np.zeros((len(base[j]), 0)) for j, c in enumerate(columns)]
    return Library(kept, base, jac, dropped)


@dataclass(frozen=True)
class StructureTest:
    """The score test of the library on a model's whitened innovations.

    Attributes:
        statistic: g·I⁻¹·g/s² with g = Jᵀr, I = JᵀJ, s² the innovations' mean square (χ²
            with ``dof`` degrees of freedom if the innovations do not depend on any term).
        dof: rank of I.
        p_value: the larger of the parametric and the block sign-flip p-values
            (:func:`structure_test`): is there structure at all?
        p_consistent: the larger of the parametric and a sign-flip test of *whole runs*: is
            the structure shared by the runs? (A noise effect differs from run to run; it may be
            named only when this one finds nothing.)
        follows: the term whose own score is largest (what the residuals follow most).
        z: that term's standardised score g_k/√I_kk.
        scores: every term's standardised score.
    """

    statistic: float
    dof: int
    p_value: float
    follows: str | None
    z: float
    scores: dict[str, float]
    p_parametric: float = 1.0
    p_sign_flip: float = 1.0
    p_consistent: float = 1.0

    def as_dict(self) -> dict[str, Any]:
        return {
            "statistic": self.statistic,
            "dof": self.dof,
            "p_value": self.p_value,
            "p_parametric": self.p_parametric,
            "p_sign_flip": self.p_sign_flip,
            "p_consistent_across_runs": self.p_consistent,
            "follows": self.follows,
            "z": self.z,
        }


def structure_test(library: Library, seed: int = 0, draws: int = 4000) -> StructureTest:
    """Do the whitened innovations depend on any term of the library?

    Two tests of the same statistic T = gᵀI⁺g (g = Jᵀr, I = JᵀJ on unit-norm columns), and the
    larger p-value is the one used — structure must be both significant and consistent:

    * **parametric** (Rao's score test): under the model r is white with unit variance, so T is
      χ² with rank(I) degrees of freedom; T is divided by the innovations' mean square when that
      exceeds 1 (a noise model that is only roughly right — heavy-tailed bump jumps under a
      Gaussian filter — inflates the spread, which must not count as dependence);
    * **sign flips of blocks**: under no dependence the score of each block of :data:`BLOCK`
      consecutive innovations is symmetric about 0 and blocks are nearly independent, so
      flipping the signs of whole blocks gives T's null distribution whatever the shape of the
      noise (exact for up to 12 blocks, else ``draws`` random flips from ``seed``). A heavy
      jump that a Gaussian filter absorbs over a few samples makes the parametric test reject;
      it stays inside one block, and only a dependence shared by many blocks survives the
      flips;
    * **sign flips of whole runs** (``p_consistent``): the same with runs as the units; weak
      when an effect shows in a few runs only (its p cannot fall below 2^(1−k) for k runs),
      robust to anything a run does on its own.
    """
    if not library.terms:
        return StructureTest(0.0, 0, 1.0, None, 0.0, {})
    r = np.concatenate(library.residual)
    jac = np.concatenate(library.jacobian, axis=0)
    # Unit-norm columns: the statistic does not depend on the terms' units, and the rank
    # decision compares correlations, not coefficients per second with coefficients per m/s.
    norms = np.linalg.norm(jac, axis=0)
    scale = np.where(norms > 0, norms, 1.0)
    jac = jac / scale
    blocks = np.stack(
        [
            (j[k : k + BLOCK] / scale).T @ res[k : k + BLOCK]
            for j, res in zip(library.jacobian, library.residual, strict=True)
            for k in range(0, len(res), BLOCK)
        ]
    )
    runs = np.stack(
        [(j / scale).T @ res for j, res in zip(library.jacobian, library.residual, strict=True)]
    )
    g = runs.sum(axis=0)
    info = jac.T @ jac
    eig, vec = np.linalg.eigh(info)
    keep = eig > eig.max() * 1e-8
    basis = vec[:, keep] / np.sqrt(eig[keep])
    variance = max(float(r @ r) / max(len(r), 1), 1.0)
    statistic = float(np.sum((basis.T @ g) ** 2)) / variance
    dof = int(keep.sum())
    p_param = float(stats.chi2.sf(statistic, dof)) if dof else 1.0
    rng = np.random.default_rng(seed)
    p_blocks = sign_flip_p(blocks, basis, statistic * variance, rng, draws)
    p_runs = sign_flip_p(runs, basis, statistic * variance, rng, draws)
    diag = np.sqrt(np.maximum(np.diag(info), 1e-300))
    z = g / diag / math.sqrt(variance)
    best = int(np.argmax(np.abs(z)))
    scores = {name: float(v) for name, v in zip(library.terms, z, strict=True)}
    return StructureTest(
        statistic,
        dof,
        max(p_param, p_blocks),
        library.terms[best],
        float(z[best]),
        scores,
        p_param,
        p_blocks,
        max(p_param, p_runs),
    )


TIE = 1e-9
"""Relative difference of two held-out sums of squares below which :func:`best_threshold`
counts them as equal: a threshold that zeroes every coefficient in every fold gives "none"'s
sum of squares summed in another order, equal to ~10⁻¹⁶ (on the June OptiOdom sessions,
52268.98028182433 against …434), and which of two such numbers is smaller is decided by the
BLAS's thread count."""


def best_threshold(path: Mapping[str, float]) -> str:
    """The key of ``path`` (``"none"``, then the thresholds in the order tried) with the least
    held-out sum of squares; of keys within :data:`TIE` of it (relative to "none"'s), the
    first — "none" before any threshold, a smaller threshold before a larger — so that the
    choice does not turn on the last digits of the arithmetic. Keys whose sum is not finite are
    never chosen ("none" if no key has a finite sum)."""
    finite = {k: v for k, v in path.items() if math.isfinite(v)}
    if not finite:
        return "none"
    best = min(finite.values())
    tolerance = TIE * abs(finite.get("none", best))
    return next(k for k, v in finite.items() if v <= best + tolerance)


def _stlsq_normal(gram: FloatArray, moment: FloatArray, threshold: float) -> FloatArray:
    """:func:`_stlsq` on the system with Gram matrix ``gram`` (XᵀX) and moments ``moment``
    (Xᵀy): R with RᵀR = XᵀX (a tiny diagonal jitter keeps it positive definite) and z with
    Rᵀz = Xᵀy give ‖y − Xw‖² = ‖z − Rw‖² + const for every w."""
    k = gram.shape[0]
    jitter = 1e-12 * max(float(np.trace(gram)), 1e-300) / max(k, 1)
    upper = np.linalg.cholesky(gram + jitter * np.eye(k)).T
    z: FloatArray = np.asarray(np.linalg.solve(upper.T, moment), dtype=np.float64)
    return _stlsq(upper, z, threshold)


def _stlsq(x: FloatArray, y: FloatArray, threshold: float) -> FloatArray:
    """PySINDy's STLSQ on (x, y): coefficients with those below ``threshold`` set to 0."""
    import pysindy as ps

    if x.shape[1] == 0:
        return np.zeros(0)
    optimizer = ps.STLSQ(threshold=threshold, alpha=RIDGE, max_iter=30, unbias=True)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "sparsity parameter is too big", convergence
            optimizer.fit(x, y[:, None])
    coef: FloatArray = np.asarray(optimizer.coef_, dtype=float).reshape(-1)
    return coef


@dataclass
class Discovery:
    """What one discovery pass found.

    Attributes:
        terms: the discovered terms (names), empty if none survived the tests.
        fit: the joint fit of those terms (None if none).
        threshold: the STLSQ threshold chosen by cross-validation (None: no term helped).
        cv_path: held-out sum of squared whitened innovations per threshold, and without terms.
        selected: the terms STLSQ selected before the tests.
        rejected: selected terms that failed the Wald test, with their p-values.
        cv_gain: the held-out log-likelihood gain of the discovered set [nats].
        dropped: library terms not identifiable from these runs.
        structure: the score test that triggered the pass.
    """

    terms: list[str]
    fit: CandidateFit | None
    threshold: float | None
    cv_path: dict[str, float]
    selected: list[str]
    rejected: dict[str, float]
    cv_gain: float
    dropped: list[str]
    structure: StructureTest

    def entries(self) -> list[dict[str, Any]]:
        """``report.json``'s ``discovered`` list."""
        if self.fit is None:
            return []
        out = []
        for name in self.terms:
            term = term_by_name(name)
            value = float(self.fit.values[name])
            err = float(self.fit.stderr.get(name, math.nan))
            out.append(
                {
                    "term": name,
                    "channel": term.channel,
                    "modulator": term.modulator,
                    "coefficient": value,
                    "stderr": err,
                    "unit": term.unit,
                    "sentence": term_sentence(name, self.fit.values, self.fit.stderr),
                    "catalogue_equivalent": catalogue_equivalent(name, value),
                }
            )
        return out


def catalogue_equivalent(term: str, value: float) -> str | None:
    """The catalogue effect grammar term ``term`` at coefficient ``value`` is a point of
    (:data:`~odomgym.effects.discovered.CATALOGUE_POINTS`), or None. ``yaw_lateral`` is a point
    of two one-sided effects, told apart by its sign: negative (under-turning in fast turns) is
    ``turn_skid``, positive (over-turning) ``skid_speed``, on a robot of either class."""
    if term == "yaw_lateral":
        return "skid_speed" if value > 0.0 else "turn_skid"
    same = [k for k, v in CATALOGUE_POINTS.items() if v.startswith(term + " ")]
    return same[0] if same else None


def term_sentence(name: str, values: Mapping[str, float], stderr: Mapping[str, float]) -> str:
    """Term ``name``'s sentence at ``values`` (all terms fitted together) with their standard
    errors; a sin/cos pair of the same channel and harmonic is one sinusoid, described once
    with its amplitude √(a² + b²) and phase (standard error by propagation)."""
    term = term_by_name(name)
    value = float(values[name])
    err = float(stderr.get(name, math.nan))
    if term.modulator[:3] in ("sin", "cos"):
        other = term.channel + "_" + ("cos" if term.modulator.startswith("sin") else "sin")
        other += term.modulator[-1]
        if other in values:
            a = value if term.modulator.startswith("sin") else float(values[other])
            b = float(values[other]) if term.modulator.startswith("sin") else value
            amplitude = math.hypot(a, b)
            ea = float(stderr.get(f"{term.channel}_sin{term.modulator[-1]}", math.nan))
            eb = float(stderr.get(f"{term.channel}_cos{term.modulator[-1]}", math.nan))
            se = math.hypot(a * ea, b * eb) / amplitude if amplitude > 0 else math.nan
            phase = math.degrees(math.atan2(b, a))
            return (
                describe_term(f"{term.channel}_sin{term.modulator[-1]}", amplitude, se)
                + f" (phase {phase:.0f}°; {term.channel}_sin{term.modulator[-1]} and "
                f"{term.channel}_cos{term.modulator[-1]} together)"
            )
    return describe_term(name, value, err)


def discover(
    data: Dataset,
    spec: RobotSpec,
    sensor: SensorNoise,
    folds: Sequence[Sequence[int]],
    *,
    alpha: float,
    nuisance: Effect | None,
    library: Library | None = None,
    structure: StructureTest | None = None,
) -> Discovery:
    """One discovery pass on the fit runs ``data`` at the current model (module docstring).

    ``alpha`` is the family-wise level of the Wald tests (Bonferroni over the library's terms).
    """
    lib = library if library is not None else library_jacobian(data, spec, sensor)
    test = structure if structure is not None else structure_test(lib)
    empty = Discovery([], None, None, {}, [], {}, 0.0, lib.dropped, test)
    if not lib.terms:
        return empty
    norms = np.linalg.norm(np.concatenate(lib.jacobian, axis=0), axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    xs = [j / norms for j in lib.jacobian]
    ys = [-r for r in lib.residual]
    # Least squares (ridge included) depends on the rows only through XᵀX and Xᵀy: each run's
    # Gram matrix and moment vector are summed per fold and STLSQ runs on the equivalent
    # K-row system (Cholesky factor R, Rᵀz = Xᵀy) — the same coefficients as on every row,
    # at a cost that no longer grows with the length of the logs.
    grams = [x.T @ x for x in xs]
    moments = [x.T @ y for x, y in zip(xs, ys, strict=True)]
    squares = [float(y @ y) for y in ys]
    path: dict[str, float] = {"none": float(sum(squares))}
    for threshold in THRESHOLDS:
        sse = 0.0
        for fold in folds:
            held = set(fold)
            train = [j for j in range(len(xs)) if j not in held]
            coef = _stlsq_normal(
                np.sum([grams[j] for j in train], axis=0),
                np.sum([moments[j] for j in train], axis=0),
                threshold,
            )
            for j in fold:
                sse += squares[j] - 2.0 * float(coef @ moments[j]) + float(coef @ grams[j] @ coef)
        path[f"{threshold:g}"] = sse
    best_key = best_threshold(path)
    if best_key == "none":
        return Discovery([], None, None, path, [], {}, 0.0, lib.dropped, test)
    threshold = float(best_key)
    coef = _stlsq_normal(np.sum(grams, axis=0), np.sum(moments, axis=0), threshold)
    selected = [lib.terms[k] for k in np.flatnonzero(coef)]
    if not selected:
        return Discovery([], None, threshold, path, [], {}, 0.0, lib.dropped, test)
    family = len(lib.terms)
    rejected: dict[str, float] = {}
    terms = list(selected)
    fit: CandidateFit | None = None
    for _ in range(len(selected)):
        effect = DiscoveredTerms(terms)
        fit = fit_candidate(data, spec, sensor, effect, nuisance)
        p = {}
        for name in terms:
            err = fit.stderr.get(name, math.nan)
            value = fit.values[name] - effect.read(spec)[name]
            zval = abs(value) / err if err > 0 and math.isfinite(err) else 0.0
            p[name] = wald_p(zval, family)
            limits = next(q for q in effect.parameters if q.name == name)
            if limits.at_limit(fit.values[name]):
                p[name] = 1.0  # at the edge of its range: a stand-in, not a measurement
        worst = max(terms, key=lambda n: p[n])
        if p[worst] < 0.5 * alpha:
            break
        rejected[worst] = p[worst]
        terms.remove(worst)
        fit = None
        if not terms:
            break
    if fit is None or not terms:
        return Discovery([], None, threshold, path, selected, rejected, 0.0, lib.dropped, test)
    base_loglik = evaluate(data, spec, sensor, whitened=False).loglik
    cv = cross_validate(data, fit, DiscoveredTerms(terms), folds)
    gain = float(np.sum(cv - base_loglik))
    if gain <= 0.0:
        return Discovery([], None, threshold, path, selected, rejected, gain, lib.dropped, test)
    return Discovery(terms, fit, threshold, path, selected, rejected, gain, lib.dropped, test)


def channel_evidence(
    runs: Sequence[Run], spec: RobotSpec, name: str, bins: int = 10
) -> dict[str, Any] | None:
    """The data behind a discovered term, for a person to look at: the term's channel measured
    interval by interval (from consecutive measured poses, against the replay of ``spec``, the
    model *without* the term) binned by the term's modulator.

    Channels: a wheel's relative travel error (along-track error ± b/2 × heading error, over
    the predicted travel), the crab angle (cross-track error over the predicted translation),
    the relative yaw error (heading error over the predicted yaw). Intervals that barely move
    the channel (travel < 2 mm, yaw < 0.01 rad) carry only sensor noise and are left out.
    Returns bin centres ``x``, mean channel error ``y`` and its standard error ``se`` (NaN-free),
    or None without dense ground truth.
    """
    term = term_by_name(name)
    xs: list[FloatArray] = []
    ys: list[FloatArray] = []
    for run in runs:
        rep = replay_run(run, spec)
        measured = run.true_pose
        ok = np.all(np.isfinite(measured), axis=1)
        both = ok[1:] & ok[:-1]
        if not np.any(both):
            continue
        d_meas = np.diff(measured, axis=0)
        d_pred = np.diff(rep.tracked, axis=0)
        theta = rep.pose[:-1, 2] + 0.5 * rep.dtheta
        c, s = np.cos(theta), np.sin(theta)
        along = c * (d_meas[:, 0] - d_pred[:, 0]) + s * (d_meas[:, 1] - d_pred[:, 1])
        cross = -s * (d_meas[:, 0] - d_pred[:, 0]) + c * (d_meas[:, 1] - d_pred[:, 1])
        heading = d_meas[:, 2] - d_pred[:, 2]
        mod = term_modulator(run, rep, spec, name)
        if term.wheel:
            w = 0 if term.channel == "left" else 1
            side = -1.0 if w == 0 else 1.0
            error = along + side * 0.5 * rep.wheelbase * heading
            base = rep.travel[:, w]
            use = both & (np.abs(base) > 2e-3)
            value = error / np.where(use, base, 1.0)
        elif term.channel == "crab":
            use = both & (np.abs(rep.ds) > 2e-3)
            value = cross / np.where(use, rep.ds, 1.0)
        else:
            use = both & (np.abs(rep.dtheta) > 0.01)
            value = heading / np.where(use, rep.dtheta, 1.0)
        xs.append(mod[use])
        ys.append(value[use])
    if not xs or sum(len(x) for x in xs) < 3 * bins:
        return None
    x = np.concatenate(xs)
    y = np.concatenate(ys)
    # Robust to the heavy tails of per-interval differences: clip at 5 median deviations.
    centre = float(np.median(y))
    spread = 1.4826 * float(np.median(np.abs(y - centre))) or 1.0
    keep = np.abs(y - centre) < 5 * spread
    x, y = x[keep], y[keep]
    edges = np.unique(np.quantile(x, np.linspace(0, 1, bins + 1)))
    if len(edges) < 3:
        return None
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    out_x, out_y, out_se = [], [], []
    for b in range(len(edges) - 1):
        sel = which == b
        if np.count_nonzero(sel) < 3:
            continue
        out_x.append(float(np.mean(x[sel])))
        out_y.append(float(np.mean(y[sel])))
        out_se.append(float(np.std(y[sel], ddof=1) / math.sqrt(np.count_nonzero(sel))))
    return {"x": out_x, "y": out_y, "se": out_se, "intervals": len(x)}

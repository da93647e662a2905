"""Running the wheel-noise fit of :mod:`odomgym.noise.fit` (Chong & Kleeman 1997, §6.3) end to end.

Where the runs come from — the §6.3 experiment simulated on a rough floor
(:func:`simulate_noise_experiment`), a recorded path re-driven with known per-wheel noise
(:func:`with_wheel_noise`), or OptiOdom sessions replayed with their published calibration
(:func:`published_calibration`) — and what comes out: a JSON-safe report of one fit per pool of
runs (:func:`fit_noise_report`), its human table (:func:`format_noise_report`) and the Fig. 4
residual scatters (:func:`plot_noise_fit`).
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy import stats

from odomgym.floor import FloorSpec
from odomgym.io import atomic_writer
from odomgym.noise.fit import (
    IntervalMethod,
    NoiseFit,
    NoiseSamples,
    Systematic,
    check_noise_run,
    fit_noise,
    noise_samples,
)
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Run, require_differential, wheel_travels
from odomgym.robot import PRESETS, RobotSpec

__all__ = [
    "fit_noise_report",
    "format_noise_report",
    "plot_noise_fit",
    "published_calibration",
    "simulate_noise_experiment",
    "with_wheel_noise",
]


# ----------------------------------------------------------------------------- runs to fit
def simulate_noise_experiment(
    robot: str | RobotSpec = "labmate",
    *,
    k: float = 0.0005,
    runs: int = 60,
    distance: float = 10.0,
    rng: np.random.Generator,
    ideal: bool = True,
    friction: float = 0.8,
    cruise_speed: float = 0.2,
) -> tuple[list[Run], RobotSpec]:
    """Chong & Kleeman 1997, §6.3, in simulation: ``runs`` robots drive ``distance`` [m] forward
    and back (backwards, no turn) on ``FloorSpec(roughness=k)`` [m^½], all in one pymunk space.

    ``robot`` is a preset name (``"labmate"``, ``"monash"``, …) or a spec; ``ideal`` drops its
    systematic errors (true = nominal), so the errors are the floor's alone and their mean is
    ~0. Returns the runs and the robot whose nominal parameters replay their odometry.
    """
    spec = _preset(robot)
    if ideal:
        spec = spec.ideal()
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
        raise ValueError(f"runs must be a positive integer, got {runs!r}")
    from odomgym.sim.route_runs import simulate_runs
    from odomgym.sim.routes import straight_route

    floor = FloorSpec(friction=friction, roughness=k, name=f"roughness-{k:g}")
    recorded, _ = simulate_runs(
        spec, floor, straight_route(distance, return_trip=True), rng=rng, repeats=runs,
        cruise_speed=cruise_speed, kind="straight",
    )  # fmt: skip
    return recorded, spec


def _preset(robot: str | RobotSpec) -> RobotSpec:
    if isinstance(robot, RobotSpec):
        return robot
    if robot not in PRESETS:
        raise ValueError(f"unknown robot preset {robot!r}; known: {', '.join(sorted(PRESETS))}")
    return PRESETS[robot]


def with_wheel_noise(
    runs: Sequence[Run],
    robot: RobotSpec,
    k_left: float,
    k_right: float,
    *,
    rng: np.random.Generator,
    calibration: Calibration | None = None,
) -> list[Run]:
    """Copies of ``runs`` whose ground truth is their encoder path re-driven with wheel noise.

    Each sample's wheel travel d (from the counts, as the odometry sees it) becomes
    d + k·√|d|·ξ with ξ ~ N(0, 1) per wheel and sample (Eq. 4, with *separate* k_L, k_R, which
    :class:`~odomgym.floor.FloorSpec` cannot express), integrated as exact arcs from the first
    true pose. This is the kinematic Monte Carlo of :mod:`odomgym.noise.montecarlo` on a recorded
    path: a known ground truth for testing the fit, including its second-order effects.
    """
    for name, value in (("k_left", k_left), ("k_right", k_right)):
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"{name} must be a finite number >= 0 [m^1/2], got {value!r}")
    require_differential(calibration, "the wheel-noise replay")
    cal = calibration if calibration is not None else Calibration()
    noisy = []
    for run in runs:
        travels, wheelbase = wheel_travels(run, robot, cal)
        check_noise_run(run, travels)
        scale = np.sqrt(np.abs(travels)) * np.array([k_left, k_right])
        travels = travels + scale * rng.standard_normal(travels.shape)
        dtheta = (travels[:, 1] - travels[:, 0]) / wheelbase
        x0, y0, th0 = run.true_pose[0]
        theta = th0 + np.concatenate([[0.0], np.cumsum(dtheta)])
        chord = travels.mean(axis=1) * np.sinc(0.5 * dtheta / math.pi)
        mid = theta[:-1] + 0.5 * dtheta
        pose = np.empty_like(run.true_pose)
        pose[:, 0] = x0 + np.concatenate([[0.0], np.cumsum(chord * np.cos(mid))])
        pose[:, 1] = y0 + np.concatenate([[0.0], np.cumsum(chord * np.sin(mid))])
        pose[:, 2] = theta
        noisy.append(Run(run.kind, run.time, run.counts, pose, run.direction, run.side,
                         run.source, dict(run.meta, wheel_noise=(k_left, k_right))))  # fmt: skip
    return noisy


def published_calibration(
    session_dir: str | Path, robot: RobotSpec, method: str = "optiodom"
) -> Calibration | None:
    """The calibration ``method`` published for an OptiOdom session, or None if not listed.

    Reads ``published_results.csv`` two folders above the session (the data set's root):
    the calibrated (b, D_R, D_L) [m] of Sousa et al. 2022, mapped onto ``robot``'s nominal.
    """
    folder = Path(session_dir)
    table = folder.resolve().parent.parent / "published_results.csv"
    if not table.is_file():
        return None
    with table.open(encoding="utf-8") as file:
        for row in csv.DictReader(file):
            if row["method"] == method and row["session"] == folder.name:
                return Calibration.from_parameters(
                    robot, float(row["b"]), float(row["dr"]), float(row["dl"])
                )
    return None


def _group_label(run: Run) -> str:
    """Runs sharing a systematic error: same session, path kind and turning direction."""
    turn = run.direction or (str(run.meta.get("turn", "")) if run.kind == "free" else "")
    return ":".join(part for part in (str(run.meta.get("session", "")), run.kind, turn) if part)


# ----------------------------------------------------------------------------- report
def fit_noise_report(
    *,
    robot: str = "labmate",
    k: float = 0.0005,
    runs: int = 60,
    distance: float = 10.0,
    seed: int = 0,
    data: Sequence[str | Path] = (),
    pool: Literal["all", "path-type", "kind", "session"] = "kind",
    calibration: Literal["published", "session"] = "published",
    systematic: Systematic = "group-mean",
    interval: IntervalMethod = "profile",
    confidence: float = 0.95,
    n_bootstrap: int = 200,
    plot: str | Path | None = None,
    check_plot: Callable[[Path], None] | None = None,
) -> dict[str, Any]:
    """Fit k_L, k_R on a simulated §6.3 experiment or on recorded sessions; a JSON-safe dict.

    Without ``data``: :func:`simulate_noise_experiment` with ``robot`` (preset name, ideal),
    ``k`` [m^½], ``runs``, ``distance`` [m] and ``seed``; one fit, whose entry says whether
    the intervals cover the true k. With ``data`` (OptiOdom session folders, or folders
    holding them): each session's runs are replayed with its published OptiOdom calibration
    (``calibration="published"``, falling back to the session's own parameters when it has
    none) or with its own metadata (``"session"``); runs are grouped by session, path and
    turning direction (the groups whose means are removed; groups of a single run are dropped
    and listed), and pooled into one fit per path type and run kind (``pool="kind"``:
    Ivanjko straights and spins apart), per path type, per session, or all together; a pool
    that cannot be fitted (too few runs) is listed under ``"skipped"`` with the reason.
    ``seed`` drives the simulation and the bootstrap (independent streams). ``plot``: write
    the Fig. 4 scatters there (one file per fit, named after the fit when there are several).
    ``check_plot``: called with every file ``plot`` may write, once the runs are read and
    before any fit — the names depend on the pools the data holds, and a command checks them
    all before the work (a bad one had stopped it after writing the others).
    """
    if pool not in ("all", "path-type", "kind", "session"):
        raise ValueError(f"pool must be 'all', 'path-type', 'kind' or 'session', got {pool!r}")
    if calibration not in ("published", "session"):
        raise ValueError(f"calibration must be 'published' or 'session', got {calibration!r}")
    seeds = np.random.SeedSequence(seed).spawn(2)
    sim_rng, boot_rng = np.random.default_rng(seeds[0]), np.random.default_rng(seeds[1])
    pools: dict[str, NoiseSamples] = {}
    report: dict[str, Any] = {
        "model": "Chong & Kleeman 1997: wheel noise variance k^2|d| (Eq. 4), "
        "end-pose covariance k_L^2 A + k_R^2 B (Eqs. 23-28); Gaussian maximum likelihood",
        "systematic": systematic,
        "interval": interval,
        "confidence": confidence,
    }
    if not data:
        recorded, spec = simulate_noise_experiment(
            robot, k=k, runs=runs, distance=distance, rng=sim_rng
        )
        pools["simulation"] = noise_samples(recorded, spec, group="all")
        report["source"] = "simulation"
        report["inputs"] = {"robot": spec.name, "ideal": True, "k_true_sqrt_m": k, "runs": runs,
                            "distance_m": distance, "seed": seed}  # fmt: skip
    else:
        from odomgym.data import find_sessions, read_session

        sessions = []
        for folder in [p for d in data for p in (find_sessions(d) or [Path(d)])]:
            session = read_session(folder)
            cal = (
                published_calibration(folder, session.robot) if calibration == "published" else None
            )
            for kind in dict.fromkeys(r.kind for r in session.runs):
                samples = noise_samples(session.select(kind), session.robot, cal or session.initial,
                                        group=_group_label)  # fmt: skip
                key = {"all": "all", "path-type": session.path_type, "session": session.name,
                       "kind": f"{session.path_type}:{kind}"}[pool]  # fmt: skip
                pools[key] = pools[key] + samples if key in pools else samples
            used = "published" if cal is not None else "session"
            sessions.append({"session": session.name, "path_type": session.path_type,
                             "runs": session.n_runs, "calibration": used})  # fmt: skip
        report["source"] = "data"
        report["inputs"] = {"sessions": sessions, "pool": pool, "seed": seed}
    targets = {n: _plot_target(plot, n, len(pools)) for n in pools} if plot is not None else {}
    if check_plot is not None:
        for target in targets.values():
            check_plot(target)
    report["fits"], report["skipped"], report["plots"] = [], [], []
    for name, samples in pools.items():
        dropped: list[str] = []
        if systematic == "group-mean":  # a group of one run says nothing about the spread
            dropped = [g for g in dict.fromkeys(samples.groups) if samples.groups.count(g) == 1]
            samples = samples.select([g not in dropped for g in samples.groups])
        try:
            fit = fit_noise(samples, systematic=systematic, confidence=confidence,
                            interval=interval, rng=boot_rng, n_bootstrap=n_bootstrap)  # fmt: skip
        except ValueError as exc:
            report["skipped"].append({"name": name, "reason": str(exc)})
            continue
        entry = {"name": name, **fit.to_dict(), "dropped_single_run_groups": dropped}
        if not data:
            entry["covers_true"] = {
                "k_left": fit.k_left_interval[0] <= k <= fit.k_left_interval[1],
                "k_right": fit.k_right_interval[0] <= k <= fit.k_right_interval[1],
            }
        report["fits"].append(entry)
        if name in targets:
            plot_noise_fit(targets[name], fit, title=f"{name}: {fit.n_runs} runs")
            report["plots"].append(str(targets[name]))
    return report


def _plot_target(plot: str | Path, name: str, pools: int) -> Path:
    """The file the fit of pool ``name`` is plotted to: ``plot`` itself for the only pool,
    else ``plot`` with the pool's name after its stem (``noise-ivanjko-spin.png``)."""
    target = Path(plot)
    if pools > 1:
        slug = re.sub(r"[^A-Za-z0-9_-]+", "-", name)
        target = target.with_name(f"{target.stem}-{slug}{target.suffix}")
    return target


def format_noise_report(report: dict[str, Any]) -> str:
    """A human table of :func:`fit_noise_report`: k_L, k_R with intervals per fit, then the
    residual spread measured against the model's per component (x, y [mm], θ [deg]) with the
    variance ratio and the χ² test, and the three correlations."""
    inputs = report["inputs"]
    if report["source"] == "simulation":
        head = (
            f"simulation: {inputs['robot']} (ideal), {inputs['runs']} runs of "
            f"{inputs['distance_m']:g} m forward and back on a floor of k = "
            f"{inputs['k_true_sqrt_m']:g} m^1/2, seed {inputs['seed']}"
        )
    else:
        head = f"data: {len(inputs['sessions'])} sessions, one fit per {inputs['pool']}"
    removed = "group means removed (REML)" if report["systematic"] == "group-mean" else "none"
    lines = [
        f"Wheel-noise fit (Chong & Kleeman Eq. 4): {head}",
        f"systematic errors: {removed}; {report['confidence']:.0%} {report['interval']} intervals",
        "",
        f"{'fit':<18}{'runs':>5}{'groups':>7}   {'k_L [m^1/2]':<32}k_R [m^1/2]",
    ]
    for fit in report["fits"]:
        k_l, k_r = (
            f"{fit[f'k_{w}_sqrt_m']:.2e} [{fit[f'k_{w}_interval'][0]:.2e}, "
            f"{fit[f'k_{w}_interval'][1]:.2e}]"
            for w in ("left", "right")
        )
        lines.append(f"{fit['name']:<18}{fit['runs']:>5}{fit['groups']:>7}   {k_l:<32}{k_r}")
    lines += ["", f"{'fit':<18}{'':<7}{'measured':>12}{'model':>12}{'var ratio':>11}"
              f"{'chi2/dof':>14}{'p':>8}"]  # fmt: skip
    for fit in report["fits"]:
        for c in fit["components"]:
            scale, unit = (1e3, "mm") if c["unit"] == "m" else (180.0 / math.pi, "deg")
            spread = [f"{scale * math.sqrt(c[key]):.3f} {unit}" for key in
                      ("measured_var", "predicted_var")]  # fmt: skip
            if _defined(c["chi2"]):
                check = (f"{c['ratio']:>11.2f}{c['chi2']:>9.1f}/{c['dof']:<4}"
                         f"{c['p_value']:>8.3f}")  # fmt: skip
            else:  # the runs did not differ: nothing to test (odomgym.noise.fit.ComponentFit)
                check = f"{'n/a':>11}{'n/a':>14}{'n/a':>8}"
            lines.append(f"{fit['name']:<18}{c['name']:<7}{spread[0]:>12}{spread[1]:>12}{check}")
        corr = ", ".join(
            f"{key} {_signed(fit['measured_corr'][key])}/{_signed(fit['predicted_corr'][key])}"
            for key in ("x_y", "x_theta", "y_theta")
        )
        lines.append(f"{fit['name']:<18}corr measured/model: {corr}")
    for fit in report["fits"]:
        if fit["dropped_single_run_groups"]:
            groups = ", ".join(fit["dropped_single_run_groups"])
            lines.append(f"{fit['name']}: dropped groups of a single run: {groups}")
    lines += [f"skipped {s['name']}: {s['reason']}" for s in report["skipped"]]
    return "\n".join(lines)


def _defined(value: float | None) -> bool:
    """Whether a check's value exists: not None (JSON null) and not NaN."""
    return value is not None and math.isfinite(value)


def _signed(value: float | None) -> str:
    return "—" if value is None else f"{value:+.2f}"


def plot_noise_fit(path: str | Path, fit: NoiseFit, *, title: str = "") -> None:
    """Chong & Kleeman 1997, Fig. 4: residual scatters x–y, x–θ, y–θ with the measured (solid) and
    the fitted model's (dashed) 95 % ellipses, x, y in mm and θ in degrees; written atomically."""
    # A Figure without pyplot: no global backend switch, nothing left open in a notebook.
    from matplotlib.figure import Figure

    scale = np.array([1e3, 1e3, 180.0 / math.pi])
    labels = ("x error [mm]", "y error [mm]", "θ error [deg]")
    radius = math.sqrt(float(stats.chi2.ppf(0.95, 2)))
    circle = np.stack([np.cos(np.linspace(0, 2 * math.pi, 200)),
                       np.sin(np.linspace(0, 2 * math.pi, 200))])  # fmt: skip
    fig = Figure(figsize=(13.5, 4.5))
    axes = fig.subplots(1, 3)
    for ax, (i, j) in zip(axes, ((0, 1), (0, 2), (1, 2)), strict=True):
        ax.scatter(fit.residuals[:, i] * scale[i], fit.residuals[:, j] * scale[j], s=12,
                   color="tab:blue", label="runs")  # fmt: skip
        for cov, style, name in ((fit.measured_cov, "-", "measured"),
                                 (fit.predicted_cov, "--", "model")):  # fmt: skip
            sub = cov[np.ix_((i, j), (i, j))] * np.outer(scale[[i, j]], scale[[i, j]])
            values, vectors = np.linalg.eigh(sub)
            ring = vectors @ (np.sqrt(np.maximum(values, 0.0))[:, None] * circle) * radius
            ax.plot(ring[0], ring[1], style, color="k", label=f"95 % {name}")
        ax.set_xlabel(labels[i])
        ax.set_ylabel(labels[j])
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(
        f"{title}  k_L = {fit.k_left:.2e}, k_R = {fit.k_right:.2e} m^1/2".strip(), fontsize=10
    )
    fig.tight_layout()
    target = Path(path)

    def write(tmp: Path) -> None:
        fig.savefig(tmp, dpi=120, format=target.suffix.lstrip(".") or "png")

    atomic_writer(target, write)

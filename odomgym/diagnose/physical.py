"""Is a fitted effect physically plausible, judged at the data's own operating range?

A regression term can reach any coefficient where its modulator is small, and a noise effect
any magnitude where nothing bounds it; on real logs both happily stand in for what the model
lacks — a synchronisation error, a frame error, slip at every start. Two checks keep a diagnosis
to what a robot can physically do:

* **A discovered term's size** (:func:`term_size`): the change it makes at the data's operating
  range, |c|·q₉₅(|m|) with q₉₅ the 95th percentile of its modulator's magnitude over the
  intervals where the robot moves, against :data:`PLAUSIBLE_CHANGE` (a wheel's travel or the
  yaw changed by more than 10 %) or :data:`PLAUSIBLE_CRAB` (a translation more than 5° off the
  heading); and a term that, in any interval, makes a wheel travel backwards or more than twice
  what it turned is implausible whatever the percentile says. Such a term is a *stand-in*: it
  is reported, not kept.
* **Floor bumps** (:func:`check_bumps`): named only where the data show their signature —
  heavy-tailed heading increments *during steady driving*, where slip at starts and stops, a
  time offset or a controller transient cannot produce them (excess kurtosis of the heading
  disagreement's increments over steady intervals, tested against its sampling error
  √(24/n)) — and only with what the floor can produce: at most ``max_rate`` crossings per metre
  of a wheel's travel (one per metre by default, three times the project's cable-strewn
  benchmark floor; bumps every few centimetres are heavier-tailed wheel noise, not obstacles,
  and as bumps they would shorten the mean travel and move E_s), each with a jump whose travel
  loss a·b is at most what a wheel loses crossing an obstacle of
  ``max_obstacle`` (the rigid-wheel-over-cylinder geometry of
  :func:`odomgym.sim.cables.bump_extra_rotation`; a 20 mm obstacle by default, a thick cable or a
  door threshold, the largest a lab floor plausibly holds).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from odomgym.diagnose.likelihood import measurement_mask
from odomgym.diagnose.replay import Replay, replay_run, session_time, wheel_angles
from odomgym.effects.discovered import body_modulator, term_by_name, wheel_modulator
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec
from odomgym.sim.cables import bump_extra_rotation

__all__ = [
    "PLAUSIBLE_CHANGE",
    "PLAUSIBLE_CRAB",
    "BumpCheck",
    "TermSize",
    "check_bumps",
    "term_modulator",
    "term_size",
]

FloatArray = NDArray[np.float64]

PLAUSIBLE_CHANGE = 0.10
"""The largest relative change of a wheel's travel or of the yaw increment a term may make at
the data's operating range [-]: a differential-drive robot whose wheels slip by tens of percent
at the speeds and accelerations it actually had would not be usable for dead reckoning."""

PLAUSIBLE_CRAB = math.radians(5.0)
"""The largest crab angle (translation off the heading) a term may make at the data's operating
range [rad]."""

OPERATING_QUANTILE = 0.95
"""The quantile of a modulator's magnitude that stands for the data's operating range."""

_MOVING = 1e-4  # [m] per interval: slower intervals carry no modulator worth judging


def term_modulator(run: Run, rep: Replay, spec: RobotSpec, name: str) -> FloatArray:
    """The modulator of grammar term ``name`` over every interval of ``run`` (n,), computed as
    the replay computes it, from the logged wheel motions through ``spec`` (``rep``)."""
    term = term_by_name(name)
    dt = np.diff(run.time)
    safe = np.where(dt > 0, dt, np.inf)
    times = session_time(run)
    if term.wheel:
        motor = np.diff(run.counts, axis=0).astype(float) * (2 * np.pi / spec.ticks_per_rev)
        speed = rep.travel / safe[:, None]
        accel = np.gradient(np.abs(speed), np.cumsum(dt), axis=0) if len(dt) > 1 else 0 * speed
        angles = wheel_angles(run, motor)
        wheel = 0 if term.channel == "left" else 1
        column: FloatArray = wheel_modulator(term.modulator, speed, accel, angles, times)[:, wheel]
        return column
    return body_modulator(term.modulator, rep.ds / safe, rep.dtheta / safe, times, rep.travel)


@dataclass(frozen=True)
class TermSize:
    """A discovered term judged at the data's operating range (module docstring).

    Attributes:
        term: the term's name; coefficient: its fitted value.
        operating: q₉₅ of the modulator's magnitude over moving intervals (its unit).
        change: |c|·operating — the relative change of the channel (rad for crab).
        extreme: the largest |c·m| over all moving intervals.
        limit: the plausible bound of ``change``.
        plausible: within the bound, and no wheel travelling backwards or doubled.
        reason: why not, in words ("" when plausible).
    """

    term: str
    coefficient: float
    operating: float
    change: float
    extreme: float
    limit: float
    plausible: bool
    reason: str

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def term_size(runs: Sequence[Run], spec: RobotSpec, name: str, coefficient: float) -> TermSize:
    """Judge term ``name`` with ``coefficient`` on ``runs`` replayed through ``spec``
    (module docstring)."""
    term = term_by_name(name)
    values: list[FloatArray] = []
    for run in runs:
        rep = replay_run(run, spec)
        mod = term_modulator(run, rep, spec, name)
        moving = (
            np.abs(rep.travel[:, 0 if term.channel == "left" else 1]) > _MOVING
            if term.wheel
            else (np.abs(rep.ds) > _MOVING) | (np.abs(rep.dtheta) * rep.wheelbase > _MOVING)
        )
        values.append(np.abs(mod[moving]))
    magnitude = np.concatenate(values) if values else np.zeros(0)
    if magnitude.size == 0:
        return TermSize(name, coefficient, 0.0, 0.0, 0.0, math.inf, True, "")
    operating = float(np.quantile(magnitude, OPERATING_QUANTILE))
    change = abs(coefficient) * operating
    extreme = abs(coefficient) * float(np.max(magnitude))
    limit = PLAUSIBLE_CRAB if term.channel == "crab" else PLAUSIBLE_CHANGE
    reason = ""
    if term.wheel and extreme >= 1.0:
        reason = (
            f"in some intervals it changes the {term.channel} wheel's travel by "
            f"{100 * extreme:.3g} %: the wheel would travel backwards or twice what it turned"
        )
    elif change > limit:
        size = (
            f"{math.degrees(change):.3g}° of crab"
            if term.channel == "crab"
            else f"{100 * change:.3g} % of the {term.channel}"
            + (" wheel's travel" if term.wheel else " increment")
        )
        bound = f"{math.degrees(limit):.3g}°" if term.channel == "crab" else f"{100 * limit:.3g} %"
        reason = f"{size} at the data's operating range (bound {bound})"
    return TermSize(name, coefficient, operating, change, extreme, limit, not reason, reason)


@dataclass(frozen=True)
class BumpCheck:
    """Whether fitted floor bumps are what the data show and what the floor can do.

    Attributes:
        rate: fitted bumps per metre of a wheel's travel [1/m]; heading_jump: per bump [rad].
        loss_per_bump: travel one bump loses, heading_jump × wheelbase [m].
        largest_loss: what a wheel loses crossing an obstacle of ``max_obstacle`` [m].
        max_obstacle: the largest obstacle the floor is assumed to hold [m].
        steady_intervals: how many steady-driving intervals the signature was measured on.
        excess_kurtosis: of the heading disagreement's increments over them [-].
        kurtosis_p: one-sided p-value of that excess against 0 (sampling error √(24/n)).
        max_rate: the most crossings per metre the floor is assumed to hold [1/m].
        signature: heavy tails during steady driving (p below the test level).
        plausible: the jump within the obstacle bound and the rate within ``max_rate``.
        reason: why the bumps are not named, in words ("" when they may be).
    """

    rate: float
    heading_jump: float
    loss_per_bump: float
    largest_loss: float
    max_obstacle: float
    steady_intervals: int
    excess_kurtosis: float
    kurtosis_p: float
    max_rate: float
    signature: bool
    plausible: bool
    reason: str

    @property
    def accepted(self) -> bool:
        """Signature and magnitude both hold."""
        return self.signature and self.plausible

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "accepted": self.accepted}


def _steady_increments(runs: Sequence[Run], spec: RobotSpec, interval: float) -> FloatArray:
    """Increments of the heading disagreement (measured − replayed) between consecutive
    measured samples ``interval`` apart, over intervals of steady driving: every sample between
    them moving, no wheel reversing, each wheel's speed changing by less than 20 % across the
    interval (starts, stops and transients left out)."""
    out: list[FloatArray] = []
    for run in runs:
        mask = measurement_mask(run, interval)[:, 2]
        rows = np.flatnonzero(mask)
        if len(rows) < 3 or not np.isfinite(run.true_pose[0, 2]):
            continue
        rep = replay_run(run, spec)
        error = run.true_pose[:, 2] - rep.tracked[:, 2]
        dt = np.diff(run.time)
        speed = rep.travel / np.where(dt > 0, dt, np.inf)[:, None]
        for a, b in itertools.pairwise(rows):
            seg = speed[a:b]
            if len(seg) == 0 or np.any(np.abs(seg) * np.maximum(dt[a:b], 1e-9)[:, None] < _MOVING):
                continue
            if np.any(np.sign(seg) != np.sign(seg[0])):
                continue
            high, low = np.max(np.abs(seg), axis=0), np.min(np.abs(seg), axis=0)
            if np.any(high - low > 0.2 * high):
                continue
            # Wrapped: across a gap the measured heading may have been unwrapped the wrong way
            # round (odomgym.data.native), and an increment is small anyway.
            step = error[b] - error[a]
            out.append(np.atleast_1d(np.mod(step + np.pi, 2.0 * np.pi) - np.pi))
    return np.concatenate(out) if out else np.zeros(0)


def _bump_losses(spec: RobotSpec, jump: float, max_obstacle: float) -> tuple[float, float]:
    """The travel [m] one bump of heading jump ``jump`` [rad] loses under ``spec``, and the
    most that crossing a ``max_obstacle`` [m] obstacle can lose
    (:func:`odomgym.sim.cables.bump_extra_rotation`)."""
    loss = jump * float(spec.true_wheelbase)
    return loss, bump_extra_rotation(0.5 * float(spec.wheel_diameter), max_obstacle)


def bump_size_reasons(
    spec: RobotSpec, values: Mapping[str, float], *, max_obstacle: float, max_rate: float
) -> list[str]:
    """Why fitted ``floor_bumps`` ``values`` are beyond what a floor can make under ``spec``
    (empty if they are not): each bump losing more travel than crossing a ``max_obstacle`` [m]
    obstacle can (:func:`odomgym.sim.cables.bump_extra_rotation`), or more than ``max_rate``
    bumps per metre — the magnitude half of :func:`check_bumps`, which needs no replay."""
    rate, jump = float(values.get("rate", 0.0)), float(values.get("heading_jump", 0.0))
    loss, largest = _bump_losses(spec, jump, max_obstacle)
    reasons = []
    if loss > largest:
        reasons.append(
            f"each bump would lose {1e3 * loss:.3g} mm of travel ({math.degrees(jump):.3g}° of "
            f"heading), more than crossing a {1e3 * max_obstacle:.3g} mm obstacle can "
            f"({1e3 * largest:.3g} mm)"
        )
    if rate > max_rate:
        reasons.append(
            f"{rate:.3g} bumps per metre is more than the {max_rate:.3g} a floor is assumed to "
            f"hold: heavier-tailed wheel noise, not obstacles (as bumps they would shorten the "
            f"mean travel by {100 * rate * loss:.2g} % and move E_s)"
        )
    return reasons


_MIN_STEADY = 20
"""Fewest steady intervals on which :func:`check_bumps` tests the kurtosis (its normal
approximation, standard error √(24/n), is poor below)."""


def check_bumps(
    runs: Sequence[Run],
    spec: RobotSpec,
    values: Mapping[str, float],
    *,
    max_obstacle: float,
    max_rate: float,
    interval: float,
    alpha: float,
) -> BumpCheck:
    """Check fitted ``floor_bumps`` ``values`` on ``runs`` replayed through ``spec`` (the
    systematic model, without the bumps' mean loss) — module docstring."""
    rate, jump = float(values.get("rate", 0.0)), float(values.get("heading_jump", 0.0))
    loss, largest = _bump_losses(spec, jump, max_obstacle)
    increments = _steady_increments(runs, spec, interval)
    n = len(increments)
    if n >= _MIN_STEADY:
        excess = float(stats.kurtosis(increments, fisher=True, bias=False))
        p = float(stats.norm.sf(excess / math.sqrt(24.0 / n)))
    else:
        excess, p = math.nan, 1.0
    signature = p < alpha
    size = bump_size_reasons(spec, values, max_obstacle=max_obstacle, max_rate=max_rate)
    plausible = not size
    reasons = []
    if not signature and n < _MIN_STEADY:
        reasons.append(
            f"too little steady driving to look for heavy-tailed heading jumps ({n} steady "
            f"intervals, {_MIN_STEADY} needed)"
        )
    elif not signature:
        reasons.append(
            "no heavy-tailed heading jumps during steady driving "
            f"(excess kurtosis {excess:.3g} over {n} steady intervals, p = {p:.3g})"
        )
    reasons += size
    return BumpCheck(
        rate=rate,
        heading_jump=jump,
        loss_per_bump=loss,
        largest_loss=largest,
        max_obstacle=max_obstacle,
        steady_intervals=n,
        excess_kurtosis=excess,
        kurtosis_p=p,
        max_rate=max_rate,
        signature=signature,
        plausible=plausible,
        reason="; ".join(reasons),
    )

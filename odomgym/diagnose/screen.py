"""Which runs a diagnosis can use: each run started at its first full pose, and a run with too
little ground truth set aside, named, with the reason — the rest are diagnosed.

Real logs have gaps (:mod:`odomgym.data.gaps`): a tracker that found the marker only after the
logger started, lost it for seconds, or never saw it in one run. Every step of the workflow
compares a replay with the measured rows only, so gaps cost information, not correctness — as
long as each run gives the steps something to compare. :func:`screen_runs` makes each run such a
run or sets it aside:

1. Poses a tracker held while the wheels turned are made gaps
   (:func:`odomgym.data.gaps.mark_held_poses`; the readers did it already for logs read from
   files, the rule is idempotent).
2. **Start.** A replay starts from a measured pose with a heading (x, y and θ): a run starts at
   its first such row, the rows before it dropped (counts from zero there again, and the run's
   ``session_time`` and ``wheel_angle0`` moved with it). A run without one is set aside.
3. **Something to compare.** At least :data:`MIN_MEASURED` measured position after the start.
   One is enough on purpose: an UMBmark-style log measures a run's first and last rows only,
   and that is a complete experiment.
4. **The run's motion seen.** The ground truth must follow the run through at least
   :data:`MIN_COVERAGE` (a quarter) of its wheel motion: the encoder counts turned (both
   wheels, summed) between the start and the last measured position, over those of the whole
   logged run. Why: a run the tracker lost right after its start reports the disagreement of a
   run a fraction as long — near zero, the sensor's noise, for every model — yet it weighs as
   much as any other run in the held-out comparison (:mod:`odomgym.diagnose.heldout`: runs
   weigh equally), which it would dilute more than its few samples inform the fits. (Its final
   disagreement is no final one either; :mod:`odomgym.diagnose.where` leaves such finals out
   by itself.) Why a quarter, not a half: the fits use every measured sample of a run however
   far it was followed, so the cut should take only runs that are mostly unseen. On logs like
   the issue's — the independent generator's 24-run protocol with 45 % of the ground truth lost
   in bursts of 0.8 s on average, ten seeds — a quarter sets aside 4 % of the runs (short
   spins the tracker lost early), a half would set aside 7 %. A run whose wheels never turned
   has nothing to miss and passes.

A diagnosis needs :data:`MIN_RUNS` usable runs (:func:`usable_runs`): fewer stop it with one
line naming the runs set aside and why.

Before these rules, a run is **split at a hole** (:func:`holes`): an interval between two logged
rows longer than :data:`HOLE_FACTOR` times the run's median interval, over which a wheel turned
(more than :data:`odomgym.data.gaps.END_SLACK_COUNTS` counts). Rows were dropped there — the
encoders and the ground truth alike — and the path in between is unknown: a replay would take
the whole hole as one step along one arc, whatever the robot did. A user's log with a 5 s hole
over a 90° spin and two straights was diagnosed that way without a word, as a distance scale
of 0.993 instead of the wheelbase and diameter ratio it carried (held-out error 69 mm against
0.9 mm without the hole). Each part is then a run of its own, named ``<run>#1``, ``<run>#2``, …,
of kind ``"free"`` (a part of a square is no square), screened by the rules above like any
other run. Logs on a regular clock (every format this project reads, the OptiOdom sessions
resampled onto their tracker's clock) have no such interval; a logger's jitter or a dropped row
or two stay far below ten intervals.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odomgym.data.gaps import END_SLACK_COUNTS, first_full_pose, mark_held_poses
from odomgym.errors import SpecError
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "HOLE_FACTOR",
    "MIN_COVERAGE",
    "MIN_MEASURED",
    "MIN_RUNS",
    "Hole",
    "SkippedRun",
    "holes",
    "screen_runs",
    "split_at_holes",
    "usable_runs",
]

MIN_MEASURED = 1
"""Fewest measured positions after a run's start pose (module docstring, rule 3)."""
MIN_COVERAGE = 0.25
"""Least share of a run's wheel motion its ground truth must follow (module docstring, rule 4)."""
MIN_RUNS = 3
"""Fewest usable runs a diagnosis needs: at least two to fit and one to hold out, and a
cross-validation over two or more fit runs."""
_LISTED = 5  # skipped runs named in the error when too few are left; the others are counted
HOLE_FACTOR = 10.0
"""How many times a run's median interval between rows an interval must last, with a wheel
turning over it, to be a hole where rows were dropped (module docstring)."""
_MIN_INTERVALS = 3  # a median of fewer intervals says nothing about the log's clock


@dataclass(frozen=True)
class Hole:
    """An interval of a run where rows were dropped (:func:`holes`).

    Attributes:
        row: the 1-based row of the run before the hole (the row after it is ``row + 1``).
        start, end: the times of those two rows [s].
        median: the run's median interval between rows [s].
        turned: each wheel's counts over the hole (left, right).
    """

    row: int
    start: float
    end: float
    median: float
    turned: tuple[int, int]

    def __str__(self) -> str:
        ratio = (self.end - self.start) / self.median
        return (
            f"t jumps from {self.start:.6g} s to {self.end:.6g} s (rows {self.row}–{self.row + 1}, "
            f"{ratio:.0f}× the run's median interval of {self.median:.3g} s) while the wheels "
            f"turned {self.turned[0]:+d} and {self.turned[1]:+d} counts"
        )


@dataclass(frozen=True)
class SkippedRun:
    """A run the diagnosis set aside.

    Attributes:
        run: the run's id (``meta["run"]``, else its 1-based position in the runs given).
        source: where it came from (``Run.source``: the file, and for native logs its line).
        reason: why, in one line.
    """

    run: str
    source: str
    reason: str

    def as_dict(self) -> dict[str, str]:
        """The report's entry (``skipped_runs`` in ``report.json``)."""
        return {"run": self.run, "source": self.source, "reason": self.reason}

    def __str__(self) -> str:
        return f"skipped run {self.run} ({self.source}): {self.reason}"


def screen_runs(
    runs: Sequence[Run], robot: RobotSpec | None = None
) -> tuple[list[Run], list[SkippedRun]]:
    """The usable runs, each started at its first full pose, and the runs set aside (module
    docstring), both in the order given.

    Args:
        runs: the runs, as read or built.
        robot: the model; its encoder resolution moves a trimmed run's recorded wheel angles
            (``meta["wheel_angle0"]``) to its new start. Without it such a run's angles are
            dropped (they then count from its new start, as for a run that records none).

    Every usable run carries its id in ``meta["run"]`` (its 1-based position among ``runs``
    when it had none), so that the report names runs the same way whatever was set aside.
    """
    usable: list[Run] = []
    skipped: list[SkippedRun] = []
    parts = [
        (name, part, given.source)
        for index, given in enumerate(runs)
        for name, part in split_at_holes(given, str(given.meta.get("run", index + 1)), robot)
    ]
    for name, part, source in parts:
        if isinstance(part, str):  # a part of one row beside a hole
            skipped.append(SkippedRun(name, source, part))
            continue
        run, _ = mark_held_poses(part)
        reason = _too_little(run)
        if reason is not None:
            skipped.append(SkippedRun(name, run.source, reason))
            continue
        start = first_full_pose(run)
        assert start is not None  # _too_little checked it
        if start:
            run = _start_at(run, start, robot)
        if "run" not in run.meta:
            run = dataclasses.replace(run, meta={"run": name, **run.meta})
        usable.append(run)
    return usable, skipped


def usable_runs(
    runs: Sequence[Run], robot: RobotSpec | None = None, minimum: int = MIN_RUNS
) -> tuple[list[Run], list[SkippedRun]]:
    """:func:`screen_runs`, refusing fewer than ``minimum`` usable runs, runs that never move,
    and (with ``robot``) logs a unit away from its odometry (:func:`check_scale`).

    Raises:
        SpecError: one line naming the runs set aside and why (field ``x``, the ground truth's
            first column), or, with none set aside, how many runs there are (field ``runs``);
            :func:`check_scale`'s.
    """
    usable, skipped = screen_runs(runs, robot)
    source = _common_file(runs)
    if len(usable) >= minimum:
        if not any(_moves(run) for run in usable):
            # Runs that never move match every model within noise: the verdict would be
            # "nothing missing", though the data can tell nothing.
            raise SpecError(
                f"none of the {len(usable)} runs moves (no wheel turns by more than "
                f"{END_SLACK_COUNTS} counts from its start): a diagnosis needs runs that drive "
                "(squares, straights, turns)",
                field="ticks_left",
                source=source,
            )
        if robot is not None:
            check_scale(usable, robot, source)
        return usable, skipped
    # Counted as screened: a run cut at a hole counts as its parts (it is said in the message).
    cut = len(usable) + len(skipped) - len(runs)
    parts = " (the runs cut at holes where rows were dropped count as their parts)" if cut else ""
    if not skipped:
        raise SpecError(
            f"diagnose needs at least {minimum} runs, got {len(usable)}{parts}",
            field="runs",
            source=source,
        )
    named = "; ".join(f"run {s.run} ({s.source}): {s.reason}" for s in skipped[:_LISTED])
    more = f"; and {len(skipped) - _LISTED} more" if len(skipped) > _LISTED else ""
    raise SpecError(
        f"diagnose needs at least {minimum} runs with enough ground truth (x, y, theta), but "
        f"only {len(usable)} of {len(usable) + len(skipped)} have it{parts}; set aside: "
        f"{named}{more}",
        field="x",
    )


DISTANCE_LIMITS = (0.6, 1.6)
"""The ground truth's distance over the nominal odometry's (the median of straight stretches,
:func:`scale_ratios`) outside which a diagnosis is refused [-]. A real wheel's diameter is
off by a few per cent; a factor of 2 or 4 is a unit: a radius given as the diameter, counts
per wheel turn before quadrature decoding or gearing. The fit's distance scale ends at the
robot model's limits (0.5–2.0 × the nominal diameters, :data:`odomgym.robot.TRUE_TO_NOMINAL`),
where a user got an error about ``true_right_diameter``, a field they had never given."""

TRACK_LIMITS = (0.3, 3.0)
"""The apparent track over the nominal one (E_b ≈ distance ratio / turn ratio,
:func:`scale_ratios`) outside which a diagnosis is refused [-]. Wide: a skid-steer robot's
apparent track is 1.2–1.9 × its real one (docs/skid-steer.md); a wheelbase in millimetres or
centimetres is 1000 or 100 ×."""

_STRETCH = 0.3  # m of nominal wheel travel that closes a stretch
_STRAIGHT = 0.05  # rad: a stretch turning less than this is straight
_TURN = 0.5  # rad of nominal turn that closes a turning stretch
_MIN_STRETCHES = 3  # fewest stretches of a kind whose median is judged


def scale_ratios(runs: Sequence[Run], robot: RobotSpec) -> tuple[float | None, float | None]:
    """How far the logs' ground truth is from ``robot``'s nominal odometry, before any fit:
    (distance ratio, turn ratio), each None with fewer than three stretches to judge it by.

    Each run's measured poses are cut into stretches, each closed once the nominal odometry
    (``wheel_diameter``, ``ticks_per_rev``, ``wheelbase``; Borenstein & Feng 1994, Eqs.
    6.1–6.5) has travelled 0.3 m or turned 0.5 rad, or the true heading has turned 0.5 rad.
    The distance ratio is the median over the straight ones (both headings turning less than
    0.05 rad) of the true displacement over the odometry's travel, ≈ E_s; the turn ratio the
    median over the turning ones of the true heading change over the odometry's, ≈ E_s / E_b
    (negative when the robot turns the other way; the true change taken, modulo 2π, nearest the
    odometry's, as the measured headings tell it no better). Medians,
    so a bump or a tracker's glitch does not move them; straight stretches and heading
    changes, so a tracked point off the axle does not either."""
    per_tick = robot.metres_per_tick
    straight: list[float] = []
    turning: list[float] = []
    for run in runs:
        travel = np.asarray(run.counts, dtype=np.float64) * per_tick
        along = 0.5 * (travel[:, 0] + travel[:, 1])
        heading = (travel[:, 1] - travel[:, 0]) / robot.wheelbase
        pose = np.asarray(run.true_pose, dtype=np.float64)
        measured = np.flatnonzero(np.isfinite(pose).all(axis=1))
        if measured.size < 2:
            continue
        start = int(measured[0])
        for end in measured[1:].tolist():
            moved = along[end] - along[start]
            turned = heading[end] - heading[start]
            # The true turn is known only modulo 2π between measured headings (a log measured
            # at a square's ends reads back ~0 for its 2π): taken as the one nearest the
            # odometry's, as the diagnosis' residuals wrap a heading difference.
            gap = pose[end, 2] - pose[start, 2] - turned
            truly = turned + math.remainder(gap, math.tau)
            if abs(moved) < _STRETCH and abs(turned) < _TURN and abs(truly) < _TURN:
                continue
            if abs(turned) < _STRAIGHT and abs(truly) < _STRAIGHT:
                shift = pose[end, :2] - pose[start, :2]
                straight.append(math.hypot(shift[0], shift[1]) / abs(moved))
            elif abs(turned) >= _TURN or abs(truly) >= _TURN:
                # A robot that turns while its wheels say it does not: an infinite ratio.
                turning.append(truly / turned if turned else math.copysign(math.inf, truly))
            start = end
    distance = float(np.median(straight)) if len(straight) >= _MIN_STRETCHES else None
    turn = float(np.median(turning)) if len(turning) >= _MIN_STRETCHES else None
    return distance, turn


def check_scale(runs: Sequence[Run], robot: RobotSpec, source: str | None = None) -> None:
    """Refuse, in one line naming the robot file's fields, logs whose ground truth is a unit
    away from ``robot``'s nominal odometry (:func:`scale_ratios` outside
    :data:`DISTANCE_LIMITS` or :data:`TRACK_LIMITS`, or turning the other way): no fit of a
    few per cent bridges that, and it ended in an error about a field the user never gave.

    Raises:
        SpecError: field ``wheel_diameter`` (distance), ``wheelbase`` (track) or
            ``ticks_left`` (the other way), ``source`` the logs' file.
    """
    distance, turn = scale_ratios(runs, robot)
    if distance is not None and not DISTANCE_LIMITS[0] <= distance <= DISTANCE_LIMITS[1]:
        raise SpecError(
            f"the ground truth moves {distance:.3g} × the distance the robot model's odometry "
            f"gives (median of the straight stretches; wheel_diameter {robot.wheel_diameter:g} "
            f"m, ticks_per_rev {robot.ticks_per_rev:g}): one of them is off by that factor, not "
            "a few per cent a diagnosis fits. wheel_diameter is the diameter in metres (not "
            "the radius); ticks_per_rev the counts per wheel turn after quadrature decoding "
            "and gearing",
            field="wheel_diameter",
            source=source,
        )
    if turn is not None and turn <= 0.0:
        raise SpecError(
            f"the robot turns the other way than its wheels say (true heading change over the "
            f"odometry's: {turn:.3g}, median of the turning stretches): are ticks_left and "
            "ticks_right swapped, a counter's sign reversed, or theta measured clockwise? "
            "(theta is counter-clockwise from x, the counts grow when a wheel drives forward)",
            field="ticks_left",
            source=source,
        )
    if turn is not None:
        track = (distance if distance is not None else 1.0) / turn
        if not TRACK_LIMITS[0] <= track <= TRACK_LIMITS[1]:
            raise SpecError(
                f"the robot turns as if its track were {track:.3g} × the robot model's "
                f"wheelbase ({robot.wheelbase:g} m; median of the turning stretches): beyond "
                "what any error of a real robot, skid-steer included, gives. wheelbase is the "
                "distance between the left and right wheels' contact lines, in metres",
                field="wheelbase",
                source=source,
            )


def _moves(run: Run) -> bool:
    """Whether a wheel of ``run`` turns by more than the counts of a wheel at rest."""
    counts = np.asarray(run.counts)
    return bool(np.abs(counts - counts[0]).max() > END_SLACK_COUNTS)


def _common_file(runs: Sequence[Run]) -> str | None:
    """The file every run of ``runs`` was read from (their ``source`` without a line), or
    None: for the errors about the runs as a whole."""
    files = {
        run.source.rsplit(":", 1)[0] if run.source.rsplit(":", 1)[-1].isdigit() else run.source
        for run in runs
    }
    if len(files) == 1:
        (file,) = files
        return None if file == "sim" else file
    return None


def holes(run: Run) -> list[Hole]:
    """The intervals of ``run`` where rows were dropped (module docstring): longer than
    :data:`HOLE_FACTOR` times its median interval, with a wheel turning more than
    :data:`~odomgym.data.gaps.END_SLACK_COUNTS` counts over them; none for a run of fewer than
    three intervals."""
    time = np.asarray(run.time, dtype=np.float64)
    dt = np.diff(time)
    if len(dt) < _MIN_INTERVALS:
        return []
    median = float(np.median(dt))
    if not median > 0.0:
        return []
    turned = np.diff(np.asarray(run.counts), axis=0)
    long = dt > HOLE_FACTOR * median
    moved = np.abs(turned).max(axis=1) > END_SLACK_COUNTS
    return [
        Hole(
            int(k) + 1,
            float(time[k]),
            float(time[k + 1]),
            median,
            (round(float(turned[k, 0])), round(float(turned[k, 1]))),
        )
        for k in np.flatnonzero(long & moved)
    ]


SLOW_CLOCK = 1.0
"""The median interval between a run's samples [s] beyond which its clock is suspect.
Wheel odometry is logged at 10–1000 Hz; a median of a second or more is more likely a clock
in milliseconds read as seconds (a user's logs were), which makes every speed a thousandth of
the true one and the diagnosis silently wrong."""


def slow_clock(runs: Sequence[Run]) -> float | None:
    """The median interval between samples over ``runs`` [s] when it is at least
    :data:`SLOW_CLOCK` (a hint that ``t`` is not in seconds), else None. The runs are not
    changed: a log really sampled that slowly is diagnosed as it is."""
    steps = [np.diff(np.asarray(run.time, dtype=np.float64)) for run in runs]
    steps = [step for step in steps if step.size]
    if not steps:
        return None
    median = float(np.median(np.concatenate(steps)))
    return median if median >= SLOW_CLOCK else None


def part_names(name: str, found: Sequence[Hole]) -> list[str]:
    """The names of the parts a run named ``name`` is cut into at the holes ``found``:
    ``["<name>#1", ..., "<name>#k"]`` for k - 1 holes, ``[name]`` for none. One rule for the
    runs :func:`split_at_holes` makes and for the notices that name them beforehand."""
    if not found:
        return [name]
    return [f"{name}#{i}" for i in range(1, len(found) + 2)]


def split_at_holes(
    run: Run, name: str, robot: RobotSpec | None = None
) -> list[tuple[str, Run | str]]:
    """``run`` (named ``name``) cut at its :func:`holes`: [(name, run)] without one, else each
    part as ``("<name>#i", part)`` — of kind ``"free"``, its counts from zero, its clock and
    wheel angles moved to its start as for a trimmed run, ``meta["split_from"]`` the run's name
    — or ``("<name>#i", reason)`` for a part of a single row, which is no run."""
    found = holes(run)
    if not found:
        return [(name, run)]
    bounds = [0, *(hole.row for hole in found), len(run.time)]
    out: list[tuple[str, Run | str]] = []
    for label, (a, b) in zip(part_names(name, found), itertools.pairwise(bounds), strict=True):
        if b - a < 2:
            out.append((label, f"one row (row {a + 1}) between holes where rows were dropped"))
            continue
        part = _start_at(run, a, robot) if a else run
        part = dataclasses.replace(
            part,
            kind="free",
            direction=None,
            side=0.0,
            time=part.time[: b - a],
            counts=part.counts[: b - a],
            true_pose=part.true_pose[: b - a],
            meta={**part.meta, "run": label, "split_from": name},
        )
        out.append((label, part))
    return out


def _too_little(run: Run) -> str | None:
    """Why ``run`` has too little ground truth to diagnose (module docstring), or None."""
    start = first_full_pose(run)
    if start is None:
        return "no row has a full pose (x, y and theta), and a replay starts from one"
    position: NDArray[np.bool_] = np.asarray(np.isfinite(run.true_pose[:, :2]).all(axis=1))
    after = np.flatnonzero(position[start + 1 :]) + start + 1
    if len(after) < MIN_MEASURED:
        rows = len(position)
        return f"no measured position after its first full pose (row {start + 1} of {rows})"
    motion = np.abs(np.diff(np.asarray(run.counts, dtype=np.float64), axis=0)).sum(axis=1)
    total = float(motion.sum())
    if total > 0.0:
        seen = float(motion[start : after[-1]].sum()) / total
        if seen < MIN_COVERAGE:
            return (
                f"its ground truth follows {math.floor(100 * seen)} % of its wheel motion (rows "
                f"{start + 1}–{after[-1] + 1} of {len(position)}; at least "
                f"{100 * MIN_COVERAGE:.0f} % needed)"
            )
    return None


def _start_at(run: Run, start: int, robot: RobotSpec | None) -> Run:
    """``run`` from row ``start`` on: its counts from zero there, ``meta["trimmed_rows"]`` the
    rows dropped, and the session clock and wheel angles it records moved to the new start."""
    counts = np.asarray(run.counts)
    meta = {**run.meta, "trimmed_rows": start}
    if "session_time" in meta:
        begun = float(run.time[start] - run.time[0])
        meta["session_time"] = float(meta["session_time"]) + begun  # type: ignore[arg-type]
    if "wheel_angle0" in meta:
        if robot is None:
            del meta["wheel_angle0"]
        else:
            turned = (counts[start] - counts[0]) * (2.0 * math.pi / robot.ticks_per_rev)
            angle0 = np.asarray(meta["wheel_angle0"], dtype=np.float64).reshape(2)
            meta["wheel_angle0"] = [float(a) for a in angle0 + turned]
    return dataclasses.replace(
        run,
        time=run.time[start:],
        counts=counts[start:] - counts[start],
        true_pose=run.true_pose[start:],
        meta=meta,
    )

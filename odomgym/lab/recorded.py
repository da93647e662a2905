"""A :class:`odomgym.lab.experiment.Lab` over a recorded session: calibrators meet real data.

A recorded robot cannot drive again, so the lab serves the runs that were recorded and refuses
(with :class:`ExperimentNotRecorded`, a ``LookupError``) experiments the session does not hold.

Which experiment a recorded run answers is decided in one place, :func:`recorded_kind`: a run's
own ``kind`` label, except that the OptiOdom reader labels the runs of a *circular* session
``"free"`` (the authors' scripts treat every non-square, non-Ivanjko session alike), so a free
run whose ``meta["path_type"]`` is ``"circular"`` counts as a circular run, its direction the
way its ground truth turned (``meta["turn"]``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from odomgym.data.optiodom import Session
from odomgym.lab.experiment import Experiment, ExperimentKind
from odomgym.odometry.calibration import Calibration
from odomgym.odometry.runs import Direction, Run
from odomgym.robot import RobotSpec

__all__ = ["ExperimentNotRecorded", "RecordedLab", "recorded_kind"]


class ExperimentNotRecorded(LookupError):
    """A :class:`RecordedLab` was asked for runs its session does not hold.

    A ``LookupError``, so calibrators can treat "this lab cannot do that" uniformly.
    """


def recorded_kind(run: Run) -> tuple[ExperimentKind | None, Direction | None]:
    """The experiment kind and direction a recorded run answers (see the module docstring);
    ``(None, None)`` for a run labelled with a kind odomgym does not know."""
    if run.kind == ExperimentKind.FREE and run.meta.get("path_type") == "circular":
        turn = run.meta.get("turn")
        return ExperimentKind.CIRCULAR, ("cw" if turn == "cw" else "ccw" if turn == "ccw" else None)
    try:
        kind = ExperimentKind(run.kind)
    except ValueError:
        return None, None
    return kind, (run.direction if kind.has_direction else None)


class RecordedLab:
    """The :class:`odomgym.lab.experiment.Lab` protocol over a recorded :class:`Session`.

    A recorded robot cannot drive again: :meth:`perform` returns the first ``experiment.runs``
    recorded runs of the requested kind and direction (:func:`recorded_kind`), and raises
    :class:`ExperimentNotRecorded` when the session holds fewer, or holds them at another size
    (square side or spin angle, within ``size_tolerance``), or the experiment wants a return
    trip. Circular and free runs are served whatever their radius, laps or length: the
    recordings do not state them, and the methods that ask for them (trajectory fits) take any
    shape.

    The ``calibration`` passed to :meth:`perform` cannot change what was recorded; it is
    accepted and ignored, because calibrators replay the counts with whatever calibration they
    are evaluating (:func:`odomgym.odometry.runs.replay_odometry`). Serving the same run again (e.g.
    for a second compensation round) costs no further budget: :attr:`runs_used` and
    :attr:`distance_used` count each distinct run once.

    Args:
        session: the recorded session.
        robot: the nominal robot to report; default ``session.robot``. Give another to
            reproduce results computed with other nominal parameters.
        size_tolerance: relative tolerance when matching ``experiment.size`` [-].
    """

    def __init__(
        self,
        session: Session,
        *,
        robot: RobotSpec | None = None,
        size_tolerance: float = 0.01,
    ) -> None:
        self.session = session
        self._robot = robot if robot is not None else session.robot
        self.size_tolerance = size_tolerance
        self._served: dict[str, float] = {}

    @property
    def robot(self) -> RobotSpec:
        """The nominal robot."""
        return self._robot

    @property
    def runs_used(self) -> int:
        """Distinct runs served so far."""
        return len(self._served)

    @property
    def distance_used(self) -> float:
        """Ground-truth distance of the distinct runs served so far [m]."""
        return float(sum(self._served.values()))

    def holdings(self) -> dict[tuple[ExperimentKind, Direction | None], int]:
        """How many runs the session holds per (kind, direction), in the order first met."""
        counts: dict[tuple[ExperimentKind, Direction | None], int] = {}
        for run in self.session.runs:
            kind, direction = recorded_kind(run)
            if kind is not None:
                counts[kind, direction] = counts.get((kind, direction), 0) + 1
        return counts

    def describe_holdings(self) -> str:
        """The holdings in words, e.g. ``"3 circular cw, 3 circular ccw"``."""
        words = [f"{n} {k} {d}" if d else f"{n} {k}" for (k, d), n in self.holdings().items()]
        return ", ".join(words) or "no runs"

    def select(self, kind: ExperimentKind, direction: Direction | None) -> list[Run]:
        """The session's runs answering ``kind`` (and ``direction``, unless ``None``), in
        file order."""
        chosen = []
        for run in self.session.runs:
            run_kind, run_direction = recorded_kind(run)
            if run_kind is kind and (direction is None or run_direction == direction):
                chosen.append(run)
        return chosen

    def perform(self, experiment: Experiment, calibration: Calibration) -> list[Run]:
        """Return the recorded runs matching ``experiment`` (see the class docstring)."""
        del calibration  # what was recorded cannot be re-driven; see the class docstring
        session = self.session
        held = self.describe_holdings()
        what = f"{experiment.direction or ''} {experiment.kind}".strip()
        prefix = f"session {session.name} ({session.directory})"
        if experiment.return_trip:
            raise ExperimentNotRecorded(
                f"{prefix} holds no straight runs with a return trip (it holds {held})"
            )
        matching = self.select(experiment.kind, experiment.direction)
        recorded_size = self._recorded_size(experiment, matching)
        if recorded_size is not None and not math.isclose(
            experiment.size, recorded_size, rel_tol=self.size_tolerance
        ):
            raise ExperimentNotRecorded(
                f"{prefix} holds {what} runs of size {recorded_size:g}, "
                f"not {experiment.size:g} (configure the calibrator with size {recorded_size:g})"
            )
        if len(matching) < experiment.runs:
            raise ExperimentNotRecorded(
                f"{prefix} holds {len(matching)} {what} runs, the experiment asks for "
                f"{experiment.runs} (the session holds {held})"
            )
        served = matching[: experiment.runs]
        for run in served:
            self._served.setdefault(run.source, run.distance)
        return served

    @staticmethod
    def _recorded_size(experiment: Experiment, runs: Sequence[Run]) -> float | None:
        """The size the session's runs were recorded at, or ``None`` if unknown/irrelevant."""
        if not runs or experiment.kind in (ExperimentKind.CIRCULAR, ExperimentKind.FREE):
            return None
        if experiment.kind is ExperimentKind.SPIN:
            angle = runs[0].meta.get("angle")
            return float(angle) if isinstance(angle, float) else None
        side = runs[0].side
        return side if side > 0.0 else None


# ---------------------------------------------------------------------------------- reading

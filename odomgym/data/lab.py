"""A :class:`odomgym.experiments.Lab` over a recorded session: calibrators meet real data.

A recorded robot cannot drive again, so the lab serves the runs that were recorded and refuses
(with :class:`ExperimentNotRecorded`, a ``LookupError``) experiments the session does not hold.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from odomgym.data.optiodom import Session
from odomgym.experiments import Experiment
from odomgym.odometry import Calibration
from odomgym.robot import RobotSpec
from odomgym.runs import Run

__all__ = ["ExperimentNotRecorded", "RecordedLab"]


class ExperimentNotRecorded(LookupError):
    """A :class:`RecordedLab` was asked for runs its session does not hold.

    A ``LookupError``, so calibrators can treat "this lab cannot do that" uniformly.
    """


class RecordedLab:
    """The :class:`odomgym.experiments.Lab` protocol over a recorded :class:`Session`.

    A recorded robot cannot drive again: :meth:`perform` returns the first ``experiment.runs``
    recorded runs of the requested kind and direction, and raises :class:`ExperimentNotRecorded`
    when the session holds fewer, or holds them at another size (square side or spin angle,
    within ``size_tolerance``), or the experiment wants a return trip.

    The ``calibration`` passed to :meth:`perform` cannot change what was recorded; it is
    accepted and ignored, because calibrators replay the counts with whatever calibration they
    are evaluating (:func:`odomgym.runs.replay_odometry`). Serving the same run again (e.g. for a
    second compensation round) costs no further budget: :attr:`runs_used` and
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

    def perform(self, experiment: Experiment, calibration: Calibration) -> list[Run]:
        """Return the recorded runs matching ``experiment`` (see the class docstring)."""
        del calibration  # what was recorded cannot be re-driven; see the class docstring
        session = self.session
        held = ", ".join(f"{n} {k}" for k, n in session.holdings().items()) or "no runs"
        what = f"{experiment.direction or ''} {experiment.kind}".strip()
        prefix = f"session {session.name} ({session.directory})"
        if experiment.return_trip:
            raise ExperimentNotRecorded(
                f"{prefix} holds no straight runs with a return trip (it holds {held})"
            )
        matching = session.select(
            experiment.kind, experiment.direction if experiment.kind != "straight" else None
        )
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
        if not runs:
            return None
        if experiment.kind == "spin":
            angle = runs[0].meta.get("angle")
            return float(angle) if isinstance(angle, float) else None
        side = runs[0].side
        return side if side > 0.0 else None


# ---------------------------------------------------------------------------------- reading

"""The settings of :func:`odomgym.diagnose.workflow.diagnose`: :class:`DiagnoseConfig`.

One frozen object, checked once when it is made (a bad value raises
:class:`odomgym.errors.SpecError` naming its field), that every step reads: the rounds
(:mod:`odomgym.diagnose.rounds`), the steps after them (:mod:`odomgym.diagnose.verdict`) and the
orchestration. It is a module of its own so that each of those, and the command line that builds
it from its options, can take the settings without importing the code of the others. Units are
SI: the checkpoint interval and the time offset in seconds, the obstacle in metres, the bump
rate per metre of wheel travel, the tie between candidates in nats.
"""

from __future__ import annotations

from dataclasses import dataclass

from odomgym.effects import EFFECTS
from odomgym.errors import SpecError

__all__ = ["GATE_ORDERS", "DiagnoseConfig"]

GATE_ORDERS = ("joint", "catalogue first")
"""How the open-loop gate may eliminate proposals (:attr:`DiagnoseConfig.gate_order`)."""


@dataclass(frozen=True)
class DiagnoseConfig:
    """Settings of :func:`~odomgym.diagnose.workflow.diagnose`.

    Attributes:
        holdout: fraction of runs held out for the gap report (0 < holdout < 1).
        seed: seeds the split, the folds and the sign-flip tests.
        alpha: bound on the false-alarm rate of the verdict on data the model explains: half
            goes to the selection test (family-wise over the candidates), half to the
            whiteness test behind ``unexplained`` (Bonferroni over the two).
        max_rounds: most effects added one after the other.
        checkpoint_interval: least time between two samples entering the likelihood [s]
            (dense ground truth is thinned; its sensor noise is then closer to white).
        folds: most cross-validation folds.
        candidates: effect names to consider (default: the whole catalogue).
        initial_sensor: starting guess of the sensor noise (position [m], heading [rad]).
        tie_nats: candidates whose held-out log-likelihood gains differ by less than this
            [nats] are tied (2·3 = 6 on the deviance scale: below "strong" evidence in Kass &
            Raftery 1995, §3.2).
        jobs: worker processes fitting candidates side by side, evaluating the grammar
            library's finite differences, and fitting the open-loop gate's trials of a pass
            (results do not depend on it).
        session_frames: fit a tracked-point offset and a yaw misalignment per session
            (:mod:`odomgym.diagnose.nuisances`); None: when the runs come from two or more
            sessions (``Run.meta["session"]``).
        discover: run the discovery pass (:mod:`odomgym.diagnose.discover`) when the catalogue
            leaves structure.
        time_offset: fit each session's time offset between the encoder log and the ground
            truth (:mod:`odomgym.diagnose.nuisances`; needs dense ground truth).
        max_time_offset: the largest time offset searched [s].
        max_obstacle: the largest obstacle the floor is assumed to hold [m] — the bound on
            what named floor bumps may do (:mod:`odomgym.diagnose.physical`).
        max_bump_rate: the most obstacle crossings per metre of a wheel's travel the floor is
            assumed to hold [1/m].
        gate_order: how the open-loop gate (:func:`odomgym.diagnose.gate.open_loop_gate`)
            eliminates: ``"catalogue first"`` (the default) the catalogue effects alone, then
            the discovered terms on top of the effects kept, so that a term cannot displace a
            named mechanism it resembles (with it every leave-one-session-out fold of the June
            OptiOdom sessions keeps the same five effects: docs/diagnose.md, "Leave one
            session out"); ``"joint"`` the effects and the terms together (the order before).
    """

    holdout: float = 0.3
    seed: int = 0
    alpha: float = 0.05
    max_rounds: int = 8
    checkpoint_interval: float = 0.25
    folds: int = 10
    candidates: tuple[str, ...] | None = None
    initial_sensor: tuple[float, float] = (0.002, 0.005)
    tie_nats: float = 3.0
    jobs: int = 1
    discover: bool = True
    session_frames: bool | None = None
    time_offset: bool = True
    max_time_offset: float = 1.0
    max_obstacle: float = 0.02
    max_bump_rate: float = 1.0
    gate_order: str = "catalogue first"

    def __post_init__(self) -> None:
        if not 0.0 < self.holdout < 1.0:
            raise SpecError(f"holdout must lie in (0, 1), got {self.holdout!r}", field="holdout")
        if not 0.0 < self.alpha < 1.0:
            raise SpecError(f"alpha must lie in (0, 1), got {self.alpha!r}", field="alpha")
        if not 0.0 < self.max_time_offset <= 10.0:
            raise SpecError(
                f"max_time_offset must lie in (0, 10] s, got {self.max_time_offset!r}",
                field="max_time_offset",
            )
        if not 0.0 < self.max_obstacle <= 1.0:
            raise SpecError(
                f"max_obstacle must lie in (0, 1] m, got {self.max_obstacle!r}",
                field="max_obstacle",
            )
        if not 0.0 < self.max_bump_rate <= 100.0:
            raise SpecError(
                f"max_bump_rate must lie in (0, 100] per metre, got {self.max_bump_rate!r}",
                field="max_bump_rate",
            )
        if self.gate_order not in GATE_ORDERS:
            raise SpecError(
                f"gate_order must be one of {', '.join(map(repr, GATE_ORDERS))}, "
                f"got {self.gate_order!r}",
                field="gate_order",
            )
        if self.max_rounds < 1 or self.folds < 2:
            raise SpecError("max_rounds must be >= 1 and folds >= 2", field="max_rounds")
        for name in self.candidates or ():
            if name not in EFFECTS:
                raise SpecError(
                    f"unknown effect {name!r}; known: {', '.join(EFFECTS)}", field="candidates"
                )

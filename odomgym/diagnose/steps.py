"""What passes between the steps of :func:`odomgym.diagnose.workflow.diagnose`.

Each step of the workflow is one call; the records below are what a step hands to the later
ones, so that the orchestration reads as the list of steps in ``docs/diagnose.md`` and every
quantity has one name: the split (:class:`RunSplit`), the recording's nuisances and the fit runs
with them removed (:class:`Recording`), the noise effects kept after their signature check
(:class:`NoiseNamed`), and the systematic model the gate, the estimator and the real-size rule
settled on (:class:`SystematicModel`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from odomgym.diagnose.fit import Dataset
from odomgym.diagnose.gate import GateResult, SystematicFit
from odomgym.diagnose.nuisances import SessionNuisance
from odomgym.diagnose.openloop import NuisanceOptions, OpenLoopData, OpenLoopFit
from odomgym.effects import EFFECTS, Effect
from odomgym.odometry.runs import Run
from odomgym.robot import RobotSpec

__all__ = [
    "Backward",
    "NoiseNamed",
    "Recording",
    "RunSplit",
    "SystematicModel",
    "TermRefusal",
    "run_id",
]


def run_id(run: Run, index: int) -> str:
    """A run's name in the report: its ``meta["run"]``, else its place among the runs (from 1)."""
    return str(run.meta.get("run", index + 1))


@dataclass(frozen=True)
class RunSplit:
    """Step 1: which runs are fitted and which held out (indices into the runs given), how
    (``"sessions"`` or ``"blocks"``), and the runs themselves."""

    fit_index: list[int]
    held_index: list[int]
    kind: str
    fit: list[Run]
    held: list[Run]


@dataclass(frozen=True)
class Recording:
    """Step 2: the recording's measurement nuisances and the fit runs with them removed.

    Attributes:
        clock: each fit session's time offset (zero where the data show none).
        frames: each fit session's tracked point and yaw misalignment (zero without frames).
        timed: the fit runs, their clocks corrected; what the open-loop fits see (they refit
            the frames).
        corrected: the fit runs, every nuisance removed; what the filter sees.
        data: ``corrected`` as the filter's dataset (its measured samples thinned to one per
            checkpoint interval).
        open_data: ``timed`` for the open-loop fits.
        options: the nuisances the open-loop fits refit (the frames).
        clock_options: those of a held-out session, fitted on its own runs (the clock too).
        nominal: the model as given fitted open loop (its nuisances alone).
        frames_on: whether tracked points and yaws are fitted per session.
        pictured: the held-out runs whose predictions the report draws.
    """

    clock: dict[str, SessionNuisance]
    frames: dict[str, SessionNuisance]
    timed: list[Run]
    corrected: list[Run]
    data: Dataset
    open_data: OpenLoopData
    options: NuisanceOptions
    clock_options: NuisanceOptions
    nominal: OpenLoopFit
    frames_on: bool
    pictured: list[int]


@dataclass(frozen=True)
class Backward:
    """Step 5: the named effects the final model no longer needs (``absorbed``), and the
    effects an earlier round found significant that are not significant added to it
    (``unsupported``: no proposals of the gate)."""

    absorbed: list[str]
    unsupported: list[str]


def _moves_mean(name: str) -> bool:
    """Whether effect ``name`` changes the replay (a noise effect with a mean part)."""
    return type(EFFECTS[name]).replay is not Effect.replay


@dataclass(frozen=True)
class NoiseNamed:
    """Step 6: the noise effects the rounds named, sorted by their signature check.

    Attributes:
        kept: named, with their signature in the data and a plausible size.
        refused: named by the rounds, refused by the check.
        checks: each checked effect's record (:meth:`odomgym.diagnose.physical.BumpCheck.
            as_dict`).
        values: each kept effect's parameters as the rounds fitted them.
        partners_named: the systematic effects the rounds still name beside the kept ones.
        vanished: kept by the check, then refitted to the floor of their range on the final
            systematic model (step 11): the rest of the model carries them.
        errors: the kept effects' standard errors at that refit
            (:func:`odomgym.diagnose.fit.noise_stderr`), ``{effect: {parameter: {...}}}``.
    """

    kept: list[str]
    refused: list[str]
    checks: dict[str, dict[str, Any]]
    values: dict[str, dict[str, float]]
    partners_named: tuple[str, ...] = ()
    vanished: list[str] = field(default_factory=list)
    errors: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)

    @property
    def took_over(self) -> list[str]:
        """The systematic partners whose part a kept noise effect's mean took over: those the
        rounds no longer name beside it (the backward check absorbed them). They are no
        proposals of the gate, which starts from a robot with that mean (:meth:`with_means`)."""
        out = [
            p
            for n in self.kept
            if _moves_mean(n)
            for p in EFFECTS[n].partners
            if p not in self.partners_named
        ]
        return list(dict.fromkeys(out))

    def with_means(self, robot: RobotSpec) -> RobotSpec:
        """``robot`` carrying the kept noise effects that move the mean (``robot`` itself when
        there are none): every open-loop fit of the gate starts from it."""
        out = robot
        for name in self.kept:
            if _moves_mean(name):
                out = EFFECTS[name].write(out, self.values[name])
        return out


@dataclass(frozen=True)
class TermRefusal:
    """A discovered term the gate kept that is not a real size (step 10).

    Attributes:
        term: the proposal (a sinusoid's sine and cosine together, ``"a+b"``).
        coefficient: its final value (a sinusoid: its amplitude) [the term's unit].
        stderr: the largest standard error the report gives for it.
        discovery_coefficient: the value the discovery proposed (a sinusoid: amplitude).
        reason: why it is refused, in words.
    """

    term: str
    coefficient: float
    stderr: float
    discovery_coefficient: float
    reason: str

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class SystematicModel:
    """Steps 8–10: the systematic model the gate kept, its values by the chosen estimator.

    Attributes:
        gate: the open-loop gate's record (the last pass's).
        chosen: the kept model's values by the estimator that predicts the folds better.
        estimators: each estimator's mean square fold error [m²].
        corrected: the fit runs with the kept model's nuisances removed.
        tied: effects tied in a last ``ambiguous`` round; resolved: whether the gate kept
            them all.
        refused: terms refused by the real-size rule, over every pass.
        interval: the checkpoint interval of the filter's datasets [s].
    """

    gate: GateResult
    chosen: SystematicFit
    estimators: Mapping[str, float]
    corrected: list[Run]
    tied: list[str]
    resolved: bool
    refused: list[TermRefusal] = field(default_factory=list)
    interval: float = 0.25

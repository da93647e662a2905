"""Experiment design over the effect catalogue (issue 45, steps 1–3): which runs identify a
robot that may carry any of several effects.

* :mod:`~odomgym.design.prior` — the prior over effect subsets and sizes (fixed ranges
  with their sources) and the spec of a parameter vector;
* :mod:`~odomgym.design.menu` — the menu of experiments with travel and time costs, and
  the validation runs;
* :mod:`~odomgym.design.model` — each item's linear-Gaussian measurement model
  (Jacobian through the replay, sensor and wheel noise), computed once;
* :mod:`~odomgym.design.posterior` — the exact posterior over subsets and parameters;
* :mod:`~odomgym.design.schedules` — the best fixed schedule, the oracle's schedules and
  the greedy expected-information-gain policy;
* :mod:`~odomgym.design.tree` — the scripted decision tree;
* :mod:`~odomgym.design.nonlinear` — measurements through the replay and the
  relinearised (Laplace) posterior.

``benchmarks/effect_room.py`` measures the room a policy has (docs/effect-design.md).
"""

from odomgym.design.menu import DESIGN_MENU, VALIDATION, DesignItem, menu_items, select
from odomgym.design.model import (
    ItemModel,
    LinearModel,
    ValidationError,
    build_model,
    validation_errors,
    validation_runs,
)
from odomgym.design.posterior import ModelPosterior, SubsetPrior, subset_posteriors
from odomgym.design.prior import (
    DEFAULT_PRIOR,
    OPTIONAL_EFFECTS,
    PARAMETERS,
    DesignPrior,
    EffectPrior,
    GeometryPrior,
    spec_of,
)
from odomgym.design.schedules import (
    DesignRobots,
    SessionRobot,
    best_fixed_schedule,
    bma_risk,
    greedy_session,
    oracle_loss,
    oracle_schedules,
    run_schedule,
    search,
)

__all__ = [
    "DEFAULT_PRIOR",
    "DESIGN_MENU",
    "OPTIONAL_EFFECTS",
    "PARAMETERS",
    "VALIDATION",
    "DesignItem",
    "DesignPrior",
    "DesignRobots",
    "EffectPrior",
    "GeometryPrior",
    "ItemModel",
    "LinearModel",
    "ModelPosterior",
    "SessionRobot",
    "SubsetPrior",
    "ValidationError",
    "best_fixed_schedule",
    "bma_risk",
    "build_model",
    "greedy_session",
    "menu_items",
    "oracle_loss",
    "oracle_schedules",
    "run_schedule",
    "search",
    "select",
    "spec_of",
    "subset_posteriors",
    "validation_errors",
    "validation_runs",
]

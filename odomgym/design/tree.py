"""A scripted decision tree an engineer would write (issue 45, step 3): survey, probe what is
undecided, then spend the rest where the always-present errors need it.

Written from ``docs/effects.md``'s "Which experiments reveal which effect" before it was run on
any robot, with one threshold and no tuning:

1. **Survey**: a one-way 3 m straight (E_d, E_s, wheel toe) and 360° spins both ways (E_b, the
   tracked point's offset, backlash).
2. **Probe**: while an optional effect is undecided — its posterior probability between
   ``threshold`` and 1 − ``threshold`` — drive the item that reveals it, in catalogue order:
   toe → another one-way straight, turn skid → the 0.25 m circle (the cheapest fast turn),
   backlash → the 180° spin there and back, offset → a 180° spin.
3. **Fill**: cycle through a straight, a 180° spin and the item of every effect judged present,
   each time the next that still fits the budget, until none fits.

Every decision reads the exact subset posterior (:class:`~odomgym.design.posterior.
ModelPosterior`), never the robot.
"""

from __future__ import annotations

from odomgym.design.model import LinearModel
from odomgym.design.posterior import ModelPosterior, SubsetPrior
from odomgym.design.prior import OPTIONAL_EFFECTS
from odomgym.design.schedules import SessionRobot, check_budget
from odomgym.errors import SpecError

__all__ = ["PROBES", "SURVEY", "tree_session"]

SURVEY: tuple[str, ...] = ("straight3", "spin360-ccw", "spin360-cw")
"""The first runs, whatever the robot."""
PROBES: dict[str, str] = {
    "wheel_toe": "straight3",
    "turn_skid": "circle0.25",
    "backlash": "spin180-back",
    "gt_sensor_offset": "spin180",
}
"""The item that reveals each optional effect (docs/effects.md)."""
FILL: tuple[str, ...] = ("straight3", "spin180")


def tree_session(
    model: LinearModel,
    prior: SubsetPrior,
    robot: SessionRobot,
    budget_m: float,
    threshold: float = 0.1,
) -> ModelPosterior:
    """One session of the scripted tree (module docstring) within ``budget_m`` [m] of travel.
    A menu without the tree's items is a one-line :class:`SpecError` naming the missing one."""
    check_budget(budget_m, model)
    index = {name: i for i, name in enumerate(model.names)}
    for name in (*SURVEY, *PROBES.values(), *FILL):
        if name not in index:
            raise SpecError(f"menu: the scripted tree needs item {name!r}", field="menu")
    post = ModelPosterior(model, prior)

    def drive(name: str) -> bool:
        i = index[name]
        if post.travel_m + model.costs[i] > budget_m + 1e-9:
            return False
        post.update(i, robot.measure(i))
        return True

    for name in SURVEY:
        drive(name)
    probed = True
    while probed:
        probed = False
        p = post.effect_probability()
        for k, effect in enumerate(OPTIONAL_EFFECTS):
            if threshold < p[k] < 1.0 - threshold and drive(PROBES[effect]):
                probed = True
                break
    present = post.effect_probability() >= 1.0 - threshold
    cycle = [*FILL, *(PROBES[e] for k, e in enumerate(OPTIONAL_EFFECTS) if present[k])]
    k = 0
    while True:
        for step in range(len(cycle)):
            if drive(cycle[(k + step) % len(cycle)]):
                k = (k + step + 1) % len(cycle)
                break
        else:
            return post

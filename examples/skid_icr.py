"""The apparent track of skid-steer robots against turn radius and speed (docs/skid-steer.md).

    python examples/skid_icr.py [OUT.png]     # default docs/assets/skid_icr.png; ~35 s

Left: the ``scout2`` preset (elastic tyres, docs/skid-steer.md "Tyres") on the ``smooth`` floor
(μ = 0.8) at four speeds, each point a steady turn in the World
(:func:`odomgym.sim.turns.steady_turn`, dots) beside the same contact law solved directly
(:func:`odomgym.sim.turns.contact_steady_turn`, dashed), the factor against the radius driven
(they coincide), with the two analytic limits: rigid contacts' 1 + (a/b)² and the tyres' linear
range 1 + (C_α/C_κ)·(a/b)². Third panel: ``scout2``'s factor against speed at a spin and four
commanded radii.
Right: the ``pioneer3at``
preset at three speeds against Wang et al. 2015's empirical function of the ICR coefficient for
a Pioneer 3-AT, χ = 1 + 0.4728/(1 + 0.0538·√|λ|) with λ = (v_L + v_R)/(v_R − v_L), drawn
against the radius it implies, R = λ·χ·B/2 (as an implementation citing the paper writes it;
the coefficients are second-hand, see docs/skid-steer.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from odomgym.io import atomic_writer
from odomgym.robot import PRESETS, RobotSpec
from odomgym.sim.turns import contact_steady_turn, steady_turn

RADII = (0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0)  # commanded [m]


def _radii(robot: RobotSpec, speed: float) -> list[float]:
    """The commanded radii of :data:`RADII` no wheel must exceed its top speed for."""
    return [
        r for r in RADII if speed + speed / r * robot.true_wheelbase / 2 <= robot.max_wheel_speed
    ]


def _panel(ax: object, robot: RobotSpec, speeds: tuple[float, ...]) -> None:
    colours = plt.get_cmap("viridis")(np.linspace(0.0, 0.85, len(speeds)))
    for speed, colour in zip(speeds, colours, strict=True):
        world = [steady_turn(robot, speed, r) for r in _radii(robot, speed)]
        coulomb = [contact_steady_turn(robot, speed, r, 0.8) for r in _radii(robot, speed)]
        ax.plot([t.radius for t in world], [t.factor for t in world], "o-", color=colour,
                label=f"{speed:.1f} m/s, World")  # type: ignore[attr-defined]  # fmt: skip
        ax.plot([t.radius for t in coulomb], [t.factor for t in coulomb], "--", color=colour,
                label=f"{speed:.1f} m/s, contact law solved directly")  # type: ignore[attr-defined]  # fmt: skip
    shape = (robot.axle_spacing / robot.true_wheelbase) ** 2
    analytic = 1.0 + shape
    ax.axhline(analytic, color="0.4", ls="--", lw=1, label=f"rigid: 1 + (a/b)² = {analytic:.3f}")  # type: ignore[attr-defined]
    linear = 1.0 + robot.tyre_cornering_stiffness / robot.tyre_slip_stiffness * shape
    ax.axhline(linear, color="0.4", ls=":", lw=1,
               label=f"tyres' linear range: 1 + (C_α/C_κ)(a/b)² = {linear:.3f}")  # type: ignore[attr-defined]  # fmt: skip
    ax.set_xscale("log")  # type: ignore[attr-defined]
    ax.set_xlabel("turn radius driven [m]")  # type: ignore[attr-defined]
    ax.set_ylabel("apparent track / true track χ [-]")  # type: ignore[attr-defined]
    ax.grid(True, which="both", alpha=0.3)  # type: ignore[attr-defined]


def _speed_panel(ax: object, robot: RobotSpec) -> None:
    """The factor against speed at four commanded radii (and a spin), World only."""
    speeds = np.linspace(0.1, 1.0, 10)
    colours = plt.get_cmap("plasma")(np.linspace(0.0, 0.8, 5))
    for radius, colour in zip((0.0, 0.5, 1.0, 2.0, 5.0), colours, strict=True):
        points = [
            (v, steady_turn(robot, float(v), radius).factor)
            for v in speeds
            if radius == 0.0 or radius in _radii(robot, float(v))
        ]
        label = "spin" if radius == 0.0 else f"{radius:g} m commanded"
        ax.plot(*zip(*points, strict=True), "o-", color=colour, label=label)  # type: ignore[attr-defined]
    ax.set_xlabel("speed of the turn [m/s] (a spin: rim speed)")  # type: ignore[attr-defined]
    ax.set_ylabel("apparent track / true track χ [-]")  # type: ignore[attr-defined]
    ax.set_title(f"{robot.name}, μ = 0.8: against speed")  # type: ignore[attr-defined]
    ax.grid(True, alpha=0.3)  # type: ignore[attr-defined]
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2)  # type: ignore[attr-defined]


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("docs/assets/skid_icr.png")
    fig, (left, right, speed) = plt.subplots(1, 3, figsize=(16.5, 6.4))
    _panel(left, PRESETS["scout2"], (0.2, 0.5, 0.8, 1.1))
    left.set_title("AgileX Scout 2.0 (scout2), μ = 0.8: steady turns")
    left.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2)
    pioneer = PRESETS["pioneer3at"]
    _panel(right, pioneer, (0.1, 0.3, 0.5))
    lam = np.logspace(-0.5, 3, 200)
    chi = 1.0 + 0.4728 / (1.0 + 0.0538 * np.sqrt(lam))
    right.plot(lam * chi * 0.40 / 2.0, chi, color="tab:red", lw=2,
               label="Wang et al. 2015, empirical χ(λ) (B = 0.40 m)")  # fmt: skip
    right.set_xlim(left.get_xlim())
    right.set_title("Pioneer 3-AT (pioneer3at), μ = 0.8, against Wang et al. 2015")
    right.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2)
    _speed_panel(speed, PRESETS["scout2"])
    fig.tight_layout()
    atomic_writer(out, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

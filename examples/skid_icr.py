"""The apparent track of skid-steer robots against turn radius and speed (docs/skid-steer.md).

    python examples/skid_icr.py [OUT.png]     # default docs/assets/skid_icr.png; ~20 s

Left: the ``scout2`` preset on the ``smooth`` floor (μ = 0.8) at four speeds, each point a
steady turn (:func:`odomgym.sim.turns.steady_turn`), the factor against the radius driven — the
figure that shows where one constant factor fails: fast tight turns. Right: the ``pioneer3at``
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
from odomgym.sim.turns import steady_turn

RADII = (0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0)  # commanded [m]


def _curve(robot: RobotSpec, speed: float) -> tuple[list[float], list[float], float]:
    """Factors and radii driven over :data:`RADII` at ``speed`` [m/s], and the spin's factor."""
    turns = []
    for radius in RADII:  # only the turns no wheel is asked to exceed its top speed for
        outer = speed + speed / radius * robot.true_wheelbase / 2
        if outer <= robot.max_wheel_speed:
            turns.append(steady_turn(robot, speed, radius))
    spin = steady_turn(robot, speed, 0.0)
    return [t.radius for t in turns], [t.factor for t in turns], spin.factor


def _panel(ax: object, robot: RobotSpec, speeds: tuple[float, ...]) -> None:
    colours = plt.get_cmap("viridis")(np.linspace(0.0, 0.85, len(speeds)))
    for speed, colour in zip(speeds, colours, strict=True):
        radii, factors, spin = _curve(robot, speed)
        ax.plot(radii, factors, "o-", color=colour, label=f"{speed:.1f} m/s (spin {spin:.3f})")  # type: ignore[attr-defined]
    analytic = 1.0 + (robot.axle_spacing / robot.true_wheelbase) ** 2
    ax.axhline(analytic, color="0.4", ls="--", lw=1, label=f"1 + (a/b)² = {analytic:.3f}")  # type: ignore[attr-defined]
    ax.set_xscale("log")  # type: ignore[attr-defined]
    ax.set_xlabel("turn radius driven [m]")  # type: ignore[attr-defined]
    ax.set_ylabel("apparent track / true track χ [-]")  # type: ignore[attr-defined]
    ax.grid(True, which="both", alpha=0.3)  # type: ignore[attr-defined]


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("docs/assets/skid_icr.png")
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.4))
    _panel(left, PRESETS["scout2"], (0.2, 0.5, 0.8, 1.1))
    left.set_title("AgileX Scout 2.0 (scout2), μ = 0.8: steady turns")
    left.legend(fontsize=8, loc="lower right")
    pioneer = PRESETS["pioneer3at"]
    _panel(right, pioneer, (0.1, 0.3, 0.5))
    lam = np.logspace(-0.5, 3, 200)
    chi = 1.0 + 0.4728 / (1.0 + 0.0538 * np.sqrt(lam))
    right.plot(lam * chi * 0.40 / 2.0, chi, color="tab:red", lw=2,
               label="Wang et al. 2015, empirical χ(λ) (B = 0.40 m)")  # fmt: skip
    right.set_xlim(left.get_xlim())
    right.set_title("Pioneer 3-AT (pioneer3at), μ = 0.8, against Wang et al. 2015")
    right.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    atomic_writer(out, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

"""The two worked examples of docs/diagnose.md ("The yardstick of each kind"): a noise effect
judged by the spread it predicts, and a confound with a measurement error of the ground truth.

    python examples/yardsticks.py [OUT]    # writes OUT/rough-diagnose, OUT/bumps-diagnose,
                                           # OUT/scale-diagnose (default: the current folder)

Each is a robot of :data:`odomgym.diagnose.generate.NOMINAL_ROBOT`'s size driven through the
rich characterisation protocol in the pymunk World and diagnosed against the robot as given,
blind. About a minute on two cores.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from odomgym.diagnose.generate import NOMINAL_ROBOT, simulate_protocol
from odomgym.diagnose.report import write_outputs
from odomgym.diagnose.sensitivity import GroundTruthError
from odomgym.diagnose.workflow import diagnose
from odomgym.effects import EFFECTS
from odomgym.floor import FLOORS


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(".")
    # Wheel noise k = 0.002 m^½ from the `rough` floor's physics (Chong & Kleeman 1997, Eq. 4).
    rough = simulate_protocol(
        NOMINAL_ROBOT, "rich", np.random.default_rng(3), floor=FLOORS["rough"]
    )
    # Bumps: 0.5 per metre of a wheel's travel, each losing 3 mm of it (15 mrad of heading).
    bumpy = EFFECTS["floor_bumps"].write(NOMINAL_ROBOT, {"rate": 0.5, "heading_jump": 0.015})
    bumps = simulate_protocol(bumpy, "rich", np.random.default_rng(5))
    # The robot as given, logged by a tracker whose frame is 0.5 % too large.
    plain = simulate_protocol(NOMINAL_ROBOT, "rich", np.random.default_rng(7))
    scaled = [GroundTruthError(scale=0.005).apply(run) for run in plain]
    for name, runs in (("rough", rough), ("bumps", bumps), ("scale", scaled)):
        result = diagnose(runs, NOMINAL_ROBOT)
        write_outputs(result, out / f"{name}-diagnose", name)
        print(f"{name}: {result.verdict}, named {result.named_effects}")
        for check in result.spread:
            print(
                f"  {check['effect']}: log score {check['difference']:+.1f} ± "
                f"{check['stderr']:.3g} per {check['units'][:-1]}, regions "
                f"{100 * check['coverage']['50']:.1f} % / {100 * check['coverage']['95']:.1f} %"
            )
        for confound in result.confounds:
            if confound["moved"]:
                print(f"  {confound['sentence']}")


if __name__ == "__main__":
    main()

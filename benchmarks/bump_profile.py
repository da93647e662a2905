"""The filter's likelihood of floor bumps profiled over the jump size, at the true rate.

    python benchmarks/bump_profile.py [--jump 0.034] [--rate 0.5] [--spread 0.05]
                                      [--robots 2] [--factors 0.4 0.55 0.7 0.85 1 1.15]

Why: the hidden-effect matrix's bump fields at 10–20 × fit a jump smaller than the truth and
their 95 % regions hold too few held-out errors (docs/diagnose.md, "Why the bump fields' regions
are too narrow"). This script shows where the likelihood itself peaks. It draws ``--robots``
robots of the independent generator (``tests/independent_robot.py``) carrying bumps at
``--rate`` per metre of a wheel's travel, each turning the robot by ``--jump`` rad, their loss
spread over ``--spread`` m of the wheel's travel (the generator's default 0.05). It drives them
through the rich protocol (24 runs each). Then it prints the summed log-likelihood of the
runs (:func:`odomgym.diagnose.likelihood.run_likelihood`, the diagnosis's filter, one sample per
0.25 s) and the share of measured samples inside the model's 50 % and 95 % predictive regions,
for the nominal robot carrying the bumps at each ``--factors`` × the true jump. Nothing else is
fitted: the true sensor noise, no wheel noise. A spread below the jump's loss of travel is
clipped by the generator (a wheel cannot lose more than it travels in a step).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jump", type=float, default=0.034, help="heading jump per bump [rad]")
    parser.add_argument("--rate", type=float, default=0.5, help="bumps per metre of a wheel")
    parser.add_argument("--spread", type=float, default=0.05, help="a bump's length [m]")
    parser.add_argument("--robots", type=int, default=2, help="robots drawn (24 runs each)")
    parser.add_argument(
        "--factors", type=float, nargs="+", default=[0.4, 0.55, 0.7, 0.85, 1.0, 1.15]
    )
    args = parser.parse_args()

    import independent_robot as generator

    from odomgym.diagnose.generate import NOMINAL_ROBOT
    from odomgym.diagnose.likelihood import (
        SensorNoise,
        measurement_mask,
        run_likelihood,
        run_predictive,
    )
    from odomgym.diagnose.replay import replay_run
    from odomgym.effects import EFFECTS

    generator.BUMP_SPREAD = args.spread
    runs = []
    for seed in range(args.robots):
        robot = generator.IndependentRobot(
            effects={"floor_bumps": {"rate": args.rate, "heading_jump": args.jump}}
        )
        runs += generator.generate(robot, generator.rich_protocol(), np.random.default_rng(seed))
    robot = generator.IndependentRobot()
    sensor = SensorNoise(robot.sensor_position_std, robot.sensor_heading_std)
    masks = [measurement_mask(run, 0.25) for run in runs]
    bumps = EFFECTS["floor_bumps"]
    print(f"{len(runs)} runs; rate {args.rate} /m, jump {args.jump} rad, spread {args.spread} m")
    print("| jump / truth | log-likelihood [nats] | in 50 % region | in 95 % region |")
    print("|---|---|---|---|")
    for factor in args.factors:
        spec = bumps.write(NOMINAL_ROBOT, {"rate": args.rate, "heading_jump": factor * args.jump})
        total = 0.0
        levels = []
        for run, mask in zip(runs, masks, strict=True):
            replay = replay_run(run, spec)
            total += run_likelihood(run, replay, spec, sensor, mask).loglik
            levels.append(run_predictive(run, replay, spec, sensor, mask).levels)
        level = np.concatenate(levels)
        level = level[np.isfinite(level)]
        print(
            f"| {factor:.2f} | {total:.1f} | {100 * np.mean(level <= 0.5):.1f} % | "
            f"{100 * np.mean(level <= 0.95):.1f} % |",
            flush=True,
        )


if __name__ == "__main__":
    main()

"""``odomgym train selfcal``: train a self-calibration policy with stable-baselines3 (the
``rl`` extra)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from odomgym.cli._common import Reporter, check_output, count, processes, seed32
from odomgym.errors import SpecError

if TYPE_CHECKING:
    from odomgym.cli._common import Commands


def register(commands: Commands) -> None:
    """Add ``train``."""
    from odomgym.selfcal.menu import ACTION_MENU

    parser = commands.add_parser(
        "train",
        help="train a self-calibration policy (needs the rl extra)",
        description="Train a policy in SelfCalibration-v1 with stable-baselines3: each step it "
        f"picks one of {len(ACTION_MENU) - 1} experiments or stops; the reward is the validated "
        "improvement of the final corrections. Writes the SB3 model, the numpy policy that "
        "odomgym calibrate selfcal --policy takes, progress.csv and a learning-curve plot.",
    )
    parser.add_argument("what", choices=["selfcal"], help="what to train: selfcal")
    parser.add_argument(
        "--algo",
        choices=["ppo", "a2c", "dqn"],
        default="ppo",
        help="SB3 algorithm (Discrete actions: ppo, a2c, dqn; default ppo)",
    )
    parser.add_argument(
        "--steps", type=count, help="environment steps (default: the data file's n_timesteps)"
    )
    parser.add_argument(
        "--envs",
        type=processes,
        help="sessions stepped together (default: the data file's n_envs)",
    )
    parser.add_argument(
        "--workers", type=processes, default=2, help="processes simulating them (default 2)"
    )
    parser.add_argument(
        "--seed", type=seed32, default=0, help="random seed, 0 to 2**32 - 1 (default 0)"
    )
    parser.add_argument(
        "--out", default="runs/selfcal", help="output folder (default runs/selfcal)"
    )
    parser.add_argument(
        "--hyperparams",
        help="a YAML file in rl-baselines3-zoo's format with a SelfCalibration-v1 key for "
        "--algo (default: the shipped odomgym/data/hyperparams/<algo>.yml, which the zoo "
        "reads too)",
    )
    parser.add_argument(
        "--checkpoint-every",
        type=count,
        metavar="STEPS",
        help="write a checkpoint (OUT/checkpoint.zip) every STEPS environment steps "
        "(default 10000, about two minutes)",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="go on from the checkpoint an interrupted training left in --out (same --algo, "
        "--envs, --seed and --hyperparams) to --steps in all",
    )
    parser.add_argument(
        "--eval-sessions",
        type=processes,
        metavar="N",
        help="held-out sessions the trained policy is evaluated on, stepped together in one "
        "batch (default 32; the evaluation only reports, it never changes the policy)",
    )
    parser.add_argument("--json", action="store_true", help="one JSON object instead of text")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Train (or resume), then print the evaluation on held-out sessions, how to use the
    policy and the files written."""
    import importlib.util

    report = Reporter.of(args)
    if importlib.util.find_spec("stable_baselines3") is None:
        raise SpecError(
            "training needs stable-baselines3 and torch: pip install 'odomgym[rl]'",
            field="train",
        )
    check_output(args.out, option="--out", folder=True)
    from odomgym.baselines.selfcal_train import (
        CHECKPOINT_EVERY,
        EVAL_SEEDS,
        load_hyperparams,
        train,
    )

    params = load_hyperparams(args.algo, args.hyperparams)  # one-line errors before any work
    steps = args.steps or int(params.get("n_timesteps", 100_000))
    envs = args.envs or int(params.get("n_envs", 8))
    eval_seeds = EVAL_SEEDS
    if args.eval_sessions is not None:  # the first N of the held-out seeds, more if need be
        eval_seeds = tuple(range(EVAL_SEEDS[0], EVAL_SEEDS[0] + args.eval_sessions))
    command = (
        f"odomgym train selfcal --algo {args.algo} --steps {steps} --envs {envs} "
        f"--workers {args.workers} --seed {args.seed} --out {args.out}"
        + (f" --hyperparams {args.hyperparams}" if args.hyperparams else "")
        + (f" --eval-sessions {args.eval_sessions}" if args.eval_sessions is not None else "")
    )
    result = train(
        algo=args.algo,
        steps=steps,
        envs=envs,
        workers=args.workers,
        seed=args.seed,
        out=args.out,
        hyperparams=args.hyperparams,
        progress=report.shows_progress,
        command=command,
        eval_seeds=eval_seeds,
        checkpoint_every=args.checkpoint_every or CHECKPOINT_EVERY,
        resume=args.resume,
    )
    if report.json:
        report.document(
            {
                "algo": args.algo,
                "steps": result.steps,
                "wall_time_s": round(result.wall_time_s, 1),
                "evaluation": result.evaluation,
                "policy": str(result.policy_file),
                "model": str(result.model_file),
            }
        )
    else:
        ev = result.evaluation
        report.text(
            f"trained {args.algo} for {result.steps} steps in {result.wall_time_s / 60:.1f} min; "
            f"on {len(eval_seeds)} held-out sessions: mean reward "
            f"{ev['reward_mean']:.2f}, mean ln(E_max before/after) "
            f"{ev['log_improvement_mean']:.2f}, {ev['runs_mean']:.1f} runs"
        )
    report.status(f"use it: odomgym calibrate selfcal --policy {result.policy_file}")
    report.wrote([str(path) for path in result.written])
    return 0

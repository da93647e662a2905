"""Every numeric option of every command, given absurd values, end to end.

    python benchmarks/fuzz_cli.py                  # all commands, 3 s per invocation
    python benchmarks/fuzz_cli.py --seconds 1 --only run calibrate

Walks the command line's parser, finds each option that takes a number, and runs the command
in this process with one of ``0, -1, nan, inf, 1e308, 1e-308, 1e20 (a whole number), 0.5``
for it (the other arguments small and valid). Each invocation either ends by itself — exit 0,
or 1/2 with one ``odomgym…: error:`` line — or is still working after ``--seconds`` and is
stopped as SIGTERM would stop it (exit 143). Anything else (a traceback, another exception,
another exit code) is printed as ``BAD``. Prints the counts; exit 1 if any was bad.

Why a benchmark and not a test: invocations that start real work run for their whole time
budget (about 400 invocations, ~10 minutes). ``tests/test_fuzz.py`` holds the regression
tests of what this found and the parsers' own properties.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
VALUES = ["0", "-1", "nan", "inf", "1e308", "1e-308", "100000000000000000000", "0.5"]
SESSION = "optiodom:square/230620202042"
# Small valid arguments per command, so that the option under test is what decides.
BASE: dict[str, list[str]] = {
    "calibrate": ["umbmark", "--side", "1", "--runs", "1"],
    "diagnose": [SESSION, "--robot", str(ROOT / "examples" / "optiodom_nominal.toml")],
    "covariance": [
        *["--left", "1", "--right", "1", "--wheelbase", "0.5", "--kl", "0.01", "--kr", "0.01"]
    ],
    "train": ["selfcal", "--steps", "64", "--envs", "4", "--workers", "1"],
    "bench": ["calibrators", "--robots", "1"],
    "leaderboard": ["--data", "optiodom:"],
}


def numeric_options(parser: argparse.ArgumentParser) -> list[tuple[list[str], str]]:
    """(sub-command path, option) for every option whose type is not plain text."""
    found: list[tuple[list[str], str]] = []

    def walk(node: argparse.ArgumentParser, path: list[str]) -> None:
        subs = [a for a in node._actions if isinstance(a, argparse._SubParsersAction)]
        if subs:
            for name, child in subs[0].choices.items():
                walk(child, [*path, name])
            return
        for action in node._actions:
            if action.option_strings and action.type not in (None, str) and action.nargs is None:
                found.append((path, action.option_strings[-1]))

    walk(parser, [])
    return found


def argv_for(path: list[str], option: str, value: str) -> list[str]:
    base = [a for a in BASE.get(path[0], []) if a not in path]
    if option in base:  # the option under test replaces its valid default
        k = base.index(option)
        base = base[:k] + base[k + 2 :]
    return [*path, *base, option, value]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="per invocation (3)")
    parser.add_argument("--only", nargs="+", help="commands to fuzz (default: all)")
    args = parser.parse_args()
    os.chdir(tempfile.mkdtemp(prefix="odomgym-fuzz-cli-"))
    # Import the heavy modules now: an alarm inside an import would leave it half-done.
    import matplotlib.pyplot  # noqa: F401

    import odomgym.baselines.benchmark
    import odomgym.diagnose.workflow
    from odomgym import interrupt
    from odomgym.cli import build_parser
    from odomgym.cli import main as odomgym_main

    with contextlib.suppress(ImportError):
        import odomgym.baselines.selfcal_train  # noqa: F401

    def alarm(signum: int, frame: Any) -> None:
        interrupt.stop(143, "time budget over")  # as the command line's SIGTERM handler

    signal.signal(signal.SIGALRM, alarm)
    options = [
        (path, option)
        for path, option in numeric_options(build_parser())
        if not args.only or path[0] in args.only
    ]
    counts = {"ok": 0, "stopped": 0, "bad": 0}
    start = time.perf_counter()
    for path, option in options:
        for value in VALUES:
            argv = argv_for(path, option, value)
            out, err = io.StringIO(), io.StringIO()
            signal.setitimer(signal.ITIMER_REAL, args.seconds)
            outcome: int | str
            try:
                with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                    try:
                        outcome = odomgym_main(argv)
                    except SystemExit as exc:  # argparse refused the text
                        outcome = int(exc.code or 0)
            except BaseException as exc:  # what the command let escape
                outcome = f"{type(exc).__name__}: {' '.join(str(exc).split())[:160]}"
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            text = err.getvalue()
            lines = [line for line in text.splitlines() if line.strip()]
            bad = not isinstance(outcome, int) or outcome not in (0, 1, 2, 143)
            bad = bad or "Traceback" in text
            if outcome in (1, 2):
                bad = bad or not (lines and lines[-1].startswith("odomgym"))
            if bad:
                counts["bad"] += 1
                print("BAD", " ".join(argv), "->", outcome, "|", lines[-2:], flush=True)
            else:
                counts["stopped" if outcome == 143 else "ok"] += 1
    total = sum(counts.values())
    print(
        f"{len(options)} numeric options x {len(VALUES)} values = {total} invocations in "
        f"{time.perf_counter() - start:.0f} s: {counts['ok']} ended by themselves (exit 0/1/2), "
        f"{counts['stopped']} still working at {args.seconds:g} s (stopped, exit 143), "
        f"{counts['bad']} bad"
    )
    return 1 if counts["bad"] else 0


if __name__ == "__main__":
    sys.exit(main())

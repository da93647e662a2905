#!/usr/bin/env bash
# Install odomgym with every extra into a fresh virtual environment, then run the quality gates
# (ruff lint, ruff format, mypy on the installed package) and the whole test suite.
#
#   bash scripts/test.sh            # venv in .venv-test (recreated every time)
#   VENV=/tmp/v bash scripts/test.sh
#
# pytest runs the WHOLE suite, tests marked slow included, on parallel workers (pytest-xdist,
# part of the test extra): -n auto starts one worker per CPU, 2 on the 2-core CI machine, and
# --dist worksteal lets a worker that runs dry take tests queued for the other (the June
# diagnosis, the longest, starts first: tests/conftest.py orders the longest tests ahead). The
# total work bounds the suite, not the order: 9 min 15 s and 11 min 24 s on two workers from a
# fresh clone on the 2-core machine (2026-11-27; 19-24 min of CPU), against 16 min 41 s when that order
# was introduced. PYTEST_WORKERS overrides the count (0: serially, in this process, e.g. to read a
# failure without xdist in the way).
#
# Everyday loop, from the dev venv (editable install), without the slow end-to-end tests:
#
#   pytest -n auto -m "not slow"    # 54 s on 2 idle cores (2026-12-01, 1 077 tests); CI runs the slow ones too
#
# A test that takes 3 s or more (call or fixture set-up, `pytest --durations`) is marked slow.
#
# numba's kernels are compiled once, by scripts/warm_kernels.py beside the gates, before pytest
# starts: in a fresh venv both workers would otherwise compile the same kernels at the same time,
# ~40 s of CPU each (the fast lane: 100 s from an empty cache, 64 s after the warm-up, 54 s
# warm; docs/testing.md).
#
# The artefacts (issue 46): scripts/check_dist.sh builds the sdist and the wheel, checks them
# (twine check --strict, cffconvert --validate on CITATION.cff, the wheel from the sdist against
# the wheel from the tree) and runs the README's main job, every env and diagnose from the wheel
# installed in a fresh venv outside the tree. It starts in the background before the gates
# (ruff, mypy and mkdocs use one core; it and the kernels' warm-up share the other) and goes on
# beside pytest; its log is printed after pytest, whose summary line is then repeated as the
# closing line. Issue 46 allows it 60 s on top of the test command: alone on 2 cores it took
# 90 s (93 s of CPU; the gates 54 s), so beside the gates and pytest it adds at most half its
# CPU time, 47 s (2026-11-28). Waiting for it before pytest instead cost 41-73 s after the
# gates on this shared machine.
#
# torch is pinned first because this machine ships a CPU build of 2.13.0 locally; without the
# pin pip may choose a multi-GB CUDA build to satisfy the `rl` extra's loose range.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${VENV:-.venv-test}"
PYTHON="${PYTHON:-python3}"

rm -rf "$VENV"
"$PYTHON" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
# pip byte-compiles what it installs (about 50 s of CPU for torch, Ray and the rest). Kept: with
# PYTHONDONTWRITEBYTECODE set (this machine's shells set it) Python writes no cache of its own,
# so without pip's every process the tests start compiled torch and SB3 from source again; a
# `--no-compile` run (2026-12-02) was minutes slower, not faster.
"$VENV/bin/python" -m pip install -q torch==2.13.0
# A regular (non-editable) install: envs/ and baselines/ become odomgym/envs and
# odomgym/baselines on disk, which is what mypy and the tests then check.
"$VENV/bin/python" -m pip install -q ".[all]"
rm -rf build

DIST_LOG="$(mktemp)"
echo "== check_dist.sh started in the background (log: $DIST_LOG)"
DIST_START=$SECONDS
PYTHON="$VENV/bin/python" setsid bash scripts/check_dist.sh > "$DIST_LOG" 2>&1 &
DIST_PID=$!
WARM_LOG="$(mktemp)"
WARM_PID=""
# A failed gate ends the script: end the background process groups (the check, the warm-up)
# with it.
trap 'kill -TERM -- -"$DIST_PID" 2>/dev/null || true
      [[ -z "$WARM_PID" ]] || kill -TERM -- -"$WARM_PID" 2>/dev/null || true
      rm -f "$WARM_LOG"' EXIT

# numba's kernels compiled once, beside the gates (docs/testing.md).
setsid "$VENV/bin/python" scripts/warm_kernels.py > "$WARM_LOG" 2>&1 &
WARM_PID=$!

echo "== ruff check"
"$VENV/bin/ruff" check .
echo "== ruff format --check"
"$VENV/bin/ruff" format --check .
echo "== mypy (installed package)"
# From a neutral folder, so that the source folder odomgym/ (which lacks envs/ and baselines/,
# mapped in by package-dir) does not shadow the installed package.
REPO="$(pwd)"
(cd "$(mktemp -d)" && "$REPO/$VENV/bin/mypy" --config-file "$REPO/pyproject.toml" -p odomgym)
echo "== mkdocs build --strict (the documentation site; a broken link or undocumented name fails)"
SITE="$(mktemp -d)"
NO_MKDOCS_2_WARNING=1 "$VENV/bin/mkdocs" build --strict --quiet --site-dir "$SITE"
rm -rf "$SITE"
WARM_START=$SECONDS
if wait "$WARM_PID"; then
    echo "== numba kernels compiled (waited $((SECONDS - WARM_START)) s for it after the gates):"
    grep '^warm_kernels:' "$WARM_LOG" || true
else
    # Only time is at stake: the tests go on, and their workers compile what they need.
    cat "$WARM_LOG"
    echo "== scripts/warm_kernels.py FAILED (above); pytest goes on without the warm-up"
fi
WARM_PID=""
rm -f "$WARM_LOG"
echo "== pytest (every test, slow ones included, on ${PYTEST_WORKERS:-auto} xdist workers)"
PYTEST_LOG="$(mktemp)"
# --durations: the 15 slowest calls and set-ups under CI's own conditions (a fresh venv, the
# artefact check beside), where the suite's time goes (docs/testing.md).
"$VENV/bin/pytest" -p no:cacheprovider -n "${PYTEST_WORKERS:-auto}" --dist worksteal \
    --durations=15 | tee "$PYTEST_LOG"
PYTEST_DONE=$SECONDS
DIST_STATUS=0
wait "$DIST_PID" || DIST_STATUS=$?
trap - EXIT
echo "== check_dist.sh (started $((PYTEST_DONE - DIST_START)) s before pytest ended; waited" \
    "$((SECONDS - PYTEST_DONE)) s for it after pytest):"
grep -v '^WARNING: Location' "$DIST_LOG" || true
rm -f "$DIST_LOG"
[[ $DIST_STATUS == 0 ]] || { echo "== check_dist.sh failed (exit $DIST_STATUS)"; exit 1; }
# pytest's summary again, as the closing line of the test command.
tail -n 1 "$PYTEST_LOG"
rm -f "$PYTEST_LOG"

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
#   pytest -n auto -m "not slow"    # 111 s on 2 idle cores (2026-11-28); CI runs the slow ones too
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
"$VENV/bin/python" -m pip install -q torch==2.13.0
# A regular (non-editable) install: envs/ and baselines/ become odomgym/envs and
# odomgym/baselines on disk, which is what mypy and the tests then check.
"$VENV/bin/python" -m pip install -q ".[all]"
rm -rf build

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
echo "== pytest (every test, slow ones included, on ${PYTEST_WORKERS:-auto} xdist workers)"
"$VENV/bin/pytest" -p no:cacheprovider -n "${PYTEST_WORKERS:-auto}" --dist worksteal

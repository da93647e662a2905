#!/usr/bin/env bash
# Build odomgym's sdist and wheel and check them as a stranger would meet them (issue 46):
#
#   1. CITATION.cff valid (cffconvert --validate);
#   2. python -m build: the sdist, then the wheel built FROM THE SDIST; python -m build --wheel:
#      the wheel built from the tree; both wheels must hold the same file list (a file the
#      sdist forgot would be missing from the first);
#   3. twine check --strict on the sdist and the wheel (metadata, the README renders);
#   4. the wheel installed into a fresh venv outside the source tree, with its dependencies
#      (from pip's cache once scripts/test.sh's own install has filled it);
#   5. from a neutral folder, with every file open under the source tree refused
#      (scripts/dist_guard.py, a Python audit hook in that venv): odomgym --version equals
#      pyproject.toml's version, gymnasium.make (and make_vec where a vector entry point is
#      registered) of every registered odomgym env with a reset and a step, the README's main
#      job and odomgym diagnose optiodom:square on the OptiOdom sessions the wheel ships;
#   6. prints the wheel's size, its file count and the install time.
#
#   bash scripts/check_dist.sh          # the CI lane (scripts/test.sh runs it)
#   bash scripts/check_dist.sh --full   # the README's commands exactly (scripts/release.sh)
#   bash scripts/check_dist.sh --full --tree DIR   # another checkout, e.g. an old commit's
#                                        # (scripts/release.sh --at; without a CITATION.cff
#                                        # there, before 0.3.0, its check is skipped)
#
# The CI lane runs cheaper forms of the two long commands, because issue 46 allows the whole
# check at most 60 s on top of the test command on 2 idle cores. Measured 2026-11-28 (warm pip
# cache, cold numba cache in the fresh venv): the main job with 10 robots 37 s, with 1 robot
# 14-19 s, most of it compiling (one robot still runs every calibrator on every floor through
# every output file); the full diagnose 49 s, with --max-rounds 1 30-38 s (the data read from the
# wheel, the replay, one round, the held-out check and every figure); pip with --no-compile
# 6-9 s instead of 24 s (Python compiles what it imports on first use). The CI lane in all:
# 90 s wall, 93 s CPU, alone on the 2 cores. scripts/test.sh runs it beside its gates and
# pytest, so it adds at most half its CPU time (47 s) to the test command, less while the gates
# leave a core idle. --full runs the README's commands exactly and installs as a user would.
# tests/test_readme.py runs the README's commands from the tree (the main job with --robots 1).
#
# Needs build, twine and cffconvert (the [release] extra) in $PYTHON's environment: by default
# the test venv's python, else python3. Writes only in a temporary folder (and setuptools'
# build/ and odomgym.egg-info/ in the tree, removed before and after: a stale build/lib would
# slip deleted files into the tree's wheel). Exit 1 with one line naming the failed check.
set -euo pipefail
SCRIPTS="$(cd "$(dirname "$0")" && pwd -P)"
TREE="$SCRIPTS/.."

FULL=0
while (($#)); do
    case "$1" in
        --full) FULL=1 ;;
        --tree)
            [[ $# -ge 2 && -f "${2}/pyproject.toml" ]] \
                || { echo "check_dist.sh: --tree needs a folder with a pyproject.toml" >&2; exit 2; }
            TREE="$2"; shift ;;
        -h|--help) sed -n '2,40p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "check_dist.sh: unknown option '$1' (expected --full, --tree DIR)" >&2; exit 2 ;;
    esac
    shift
done
if [[ -n "${PYTHON:-}" && "$PYTHON" == */* ]]; then  # a relative path is the caller's
    PYTHON="$(cd "$(dirname "$PYTHON")" && pwd)/$(basename "$PYTHON")"
fi
cd "$TREE"
REPO="$(pwd -P)"
if [[ -z "${PYTHON:-}" ]]; then
    PYTHON="$SCRIPTS/../.venv-test/bin/python"; [[ -x "$PYTHON" ]] || PYTHON=python3
fi
PYTHON="$(command -v "$PYTHON")" || { echo "check_dist.sh: no python '$PYTHON'" >&2; exit 2; }
# Absolute (the checks run from another folder), without resolving the venv's symbolic link.
PYBIN="$(cd "$(dirname "$PYTHON")" && pwd)"
PYTHON="$PYBIN/$(basename "$PYTHON")"
fail() { echo "check_dist.sh: FAILED: $*" >&2; exit 1; }
for module in build twine cffconvert; do
    "$PYTHON" -c "import $module" 2>/dev/null \
        || fail "$PYTHON lacks '$module': pip install '.[release]' (or PYTHON=<a python with it>)"
done
now() { date +%s.%N; }
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }
START="$(now)"

WORK="$(mktemp -d "${TMPDIR:-/tmp}/odomgym-dist.XXXXXX")"
WORK="$(cd "$WORK" && pwd -P)"
case "$WORK/" in "$REPO"/*) fail "the temporary folder $WORK is inside the source tree";; esac
clean_tree() { rm -rf "$REPO"/build/lib "$REPO"/build/bdist.* "$REPO"/odomgym.egg-info; }
trap 'clean_tree; rm -rf "$WORK"' EXIT
trap 'exit 143' TERM INT  # ended from outside (scripts/test.sh after a failed gate): clean up
VERSION="$("$PYTHON" -c 'import tomllib; print(tomllib.load(open("pyproject.toml", "rb"))["project"]["version"])')"
echo "== check_dist: odomgym $VERSION ($([[ $FULL == 1 ]] && echo full || echo CI lane)), work folder $WORK"

echo "-- cffconvert --validate"
if [[ ! -f CITATION.cff && "$REPO" != "$(cd "$SCRIPTS/.." && pwd -P)" ]]; then
    echo "   no CITATION.cff in $REPO (a tree from before 0.3.0): skipped"
else
    "$PYBIN/cffconvert" --validate --infile CITATION.cff || fail "CITATION.cff is not valid CFF"
fi

echo "-- python -m build (sdist, then the wheel from the sdist; and a wheel from the tree)"
clean_tree
"$PYTHON" -m build --outdir "$WORK/dist" . > "$WORK/build.log" 2>&1 \
    || { tail -20 "$WORK/build.log"; fail "python -m build"; }
clean_tree
"$PYTHON" -m build --wheel --outdir "$WORK/tree" . > "$WORK/build-tree.log" 2>&1 \
    || { tail -20 "$WORK/build-tree.log"; fail "python -m build --wheel"; }
clean_tree
SDIST="$WORK/dist/odomgym-$VERSION.tar.gz"
WHEEL="$WORK/dist/odomgym-$VERSION-py3-none-any.whl"
[[ -f "$SDIST" && -f "$WHEEL" ]] || fail "expected $(basename "$SDIST") and $(basename "$WHEEL"), got: $(ls "$WORK/dist")"

echo "-- twine check --strict"
"$PYBIN/twine" check --strict "$SDIST" "$WHEEL" || fail "twine check --strict"

echo "-- the wheel from the sdist against the wheel from the tree"
"$PYTHON" - "$WHEEL" "$WORK/tree/odomgym-$VERSION-py3-none-any.whl" <<'EOF' || fail "the two wheels differ"
import sys
import zipfile

from_sdist, from_tree = (set(zipfile.ZipFile(path).namelist()) for path in sys.argv[1:])
for name in sorted(from_tree - from_sdist):
    print(f"   only in the wheel from the tree: {name}")
for name in sorted(from_sdist - from_tree):
    print(f"   only in the wheel from the sdist: {name}")
sys.exit(from_sdist != from_tree)
EOF

echo "-- install the wheel into a fresh venv ($WORK/venv)"
INSTALL_START="$(now)"
if [[ $FULL == 1 ]]; then
    INSTALL_HOW="python -m venv + pip install, as a user would"
    "$PYTHON" -m venv "$WORK/venv"
    "$WORK/venv/bin/python" -m pip install -q "$WHEEL" > "$WORK/pip.log" 2>&1 \
        || { grep -v '^WARNING: Location' "$WORK/pip.log" | tail -20; fail "pip install of the wheel"; }
else
    INSTALL_HOW="venv without pip, pip --python ... --no-compile, from pip's cache"
    "$PYTHON" -m venv --without-pip "$WORK/venv"
    "$PYTHON" -m pip --python "$WORK/venv/bin/python" install -q --no-compile "$WHEEL" \
        > "$WORK/pip.log" 2>&1 \
        || { grep -v '^WARNING: Location' "$WORK/pip.log" | tail -20; fail "pip install of the wheel"; }
fi
INSTALL_SECONDS="$(since "$INSTALL_START")"

# Every file the installed odomgym opens under the source tree is refused and logged.
SITE="$("$WORK/venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
cp "$SCRIPTS/dist_guard.py" "$SITE/_odomgym_dist_guard.py"
echo "import _odomgym_dist_guard" > "$SITE/_odomgym_dist_guard.pth"
export ODOMGYM_SOURCE_TREE="$REPO" ODOMGYM_GUARD_LOG="$WORK/source-reads.log"
: > "$ODOMGYM_GUARD_LOG"
mkdir "$WORK/run"
cd "$WORK/run"
unset PYTHONPATH
export PYTHONNOUSERSITE=1 MPLBACKEND=Agg
VBIN="$WORK/venv/bin"
guard_clean() {
    [[ ! -s "$ODOMGYM_GUARD_LOG" ]] || { cat "$ODOMGYM_GUARD_LOG" >&2; fail "$1 read the source tree"; }
}

echo "-- odomgym --version"
"$VBIN/odomgym" --version
[[ "$("$VBIN/odomgym" --version)" == "odomgym $VERSION" ]] || fail "odomgym --version is not 'odomgym $VERSION'"
"$VBIN/python" - "$WORK/venv" <<'EOF' || fail "odomgym was not imported from the venv"
import sys
from pathlib import Path

import odomgym

where = Path(odomgym.__file__).resolve()
print(f"   imported from {where.parent}")
sys.exit(Path(sys.argv[1]).resolve() not in where.parents)
EOF

echo "-- gymnasium.make every registered odomgym env (reset, one step; make_vec where registered)"
"$VBIN/python" -W ignore::DeprecationWarning - <<'EOF' || fail "gymnasium.make of a registered env"
import gymnasium as gym

import odomgym  # noqa: F401  (registers the envs)

ids = sorted(i for i, spec in gym.registry.items() if str(spec.entry_point).startswith("odomgym."))
assert ids, "no odomgym env registered"
for env_id in ids:
    env = gym.make(env_id)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    env.close()
    made = "make"
    if gym.registry[env_id].vector_entry_point:
        vec = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
        vec.reset(seed=0)
        vec.step(vec.action_space.sample())
        vec.close()
        made += " + make_vec"
    print(f"   {env_id}: {made}")
print(f"   {len(ids)} envs")
EOF
guard_clean "gymnasium.make"

if [[ $FULL == 1 ]]; then ROBOTS=10 DIAGNOSE_OPTIONS=(); else ROBOTS=1 DIAGNOSE_OPTIONS=(--max-rounds 1); fi
echo "-- the README's main job: odomgym bench calibrators --robots $ROBOTS --out bench-out"
JOB_START="$(now)"
"$VBIN/odomgym" bench calibrators --robots "$ROBOTS" --out bench-out > bench.log 2>&1 \
    || { tail -20 bench.log; fail "odomgym bench calibrators"; }
grep -E '^wrote: ' bench.log | cut -c1-120
[[ -s bench-out/improvement.png && -s bench-out/summary.csv ]] || fail "bench-out lacks its outputs"
guard_clean "odomgym bench calibrators"
BENCH_SECONDS="$(since "$JOB_START")"

echo "-- odomgym diagnose optiodom:square ${DIAGNOSE_OPTIONS[*]:-}"
JOB_START="$(now)"
"$VBIN/odomgym" diagnose optiodom:square "${DIAGNOSE_OPTIONS[@]}" > diagnose.log 2>&1 \
    || { tail -20 diagnose.log; fail "odomgym diagnose optiodom:square"; }
grep -E '^wrote: ' diagnose.log | cut -c1-120
[[ -s square-diagnose/report.json ]] || fail "square-diagnose/report.json not written"
guard_clean "odomgym diagnose"
DIAGNOSE_SECONDS="$(since "$JOB_START")"

"$PYTHON" - "$WHEEL" "$SDIST" "$INSTALL_SECONDS" "$INSTALL_HOW" <<'EOF'
import os
import sys
import zipfile

wheel, sdist, seconds, how = sys.argv[1:]
files = len([n for n in zipfile.ZipFile(wheel).namelist() if not n.endswith("/")])
print(f"== wheel {os.path.basename(wheel)}: {os.path.getsize(wheel) / 1e6:.2f} MB, {files} files;"
      f" sdist {os.path.getsize(sdist) / 1e6:.2f} MB")
print(f"== install time {seconds} s ({how})")
EOF
echo "== main job ${BENCH_SECONDS} s, diagnose ${DIAGNOSE_SECONDS} s; check_dist total $(since "$START") s: passed"

#!/usr/bin/env bash
# Build the documentation site of each released version from its own tag, with mike, into a
# LOCAL branch (default gh-pages). Nothing is pushed or hosted; `mike serve` shows the result
# (docs/release.md).
#
#   bash scripts/docs_versions.sh 0.2.0 0.3.0            # each from tag v0.2.0, v0.3.0
#   bash scripts/docs_versions.sh --branch site 0.3.0
#
# Each version is checked out at its tag in a temporary git worktree and built by that tree's
# own mkdocs.yml, hooks and docstrings (mike deploy runs `mkdocs build` in it: $PYTHON's
# mkdocs, first on PATH), with that
# tree's own odomgym first on the import path (PYTHONPATH): the hooks generate the command-line
# page from the package's parser and check the API pages against its modules, so an older
# tree must not see the installed, newer package. A tree whose mkdocs.yml does not name mike as
# its version provider (0.2.0, before issue 46) is built from a copy of it beside it,
# mkdocs-mike.yml, with `extra.version.provider: mike` appended, so that its pages show the
# selector too; the tagged mkdocs.yml itself is not changed. The last version given becomes the
# alias `latest` and the default page. Builds are --strict where the tree's mkdocs.yml says so
# (both releases' do).
#
# Needs mike and the [docs] extra in $PYTHON's environment (default: .venv-test's python, else
# python3); tags made by scripts/release.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
REPO="$(pwd -P)"
BRANCH=gh-pages
VERSIONS=()
while (($#)); do
    case "$1" in
        --branch) [[ $# -ge 2 ]] || { echo "docs_versions.sh: --branch needs a name" >&2; exit 2; }
                  BRANCH="$2"; shift ;;
        -h|--help) sed -n '2,22p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        -*) echo "docs_versions.sh: unknown option '$1'" >&2; exit 2 ;;
        *) [[ "$1" =~ ^[0-9]+\.[0-9]+\.[0-9]+$ ]] \
               || { echo "docs_versions.sh: '$1' is not a version MAJOR.MINOR.PATCH" >&2; exit 2; }
           VERSIONS+=("$1") ;;
    esac
    shift
done
((${#VERSIONS[@]})) || { echo "docs_versions.sh: no version given (e.g. 0.2.0 0.3.0)" >&2; exit 2; }
for v in "${VERSIONS[@]}"; do
    git rev-parse -q --verify "refs/tags/v$v" > /dev/null \
        || { echo "docs_versions.sh: no tag v$v (scripts/release.sh makes it)" >&2; exit 2; }
done
if [[ -z "${PYTHON:-}" ]]; then
    PYTHON="$REPO/.venv-test/bin/python"; [[ -x "$PYTHON" ]] || PYTHON="$(command -v python3)"
fi
PYBIN="$(cd "$(dirname "$PYTHON")" && pwd)"
"$PYBIN/python" -c "import mike, mkdocs" 2> /dev/null \
    || { echo "docs_versions.sh: $PYBIN/python lacks mike or mkdocs: pip install '.[release,docs]'" >&2; exit 2; }

WORK="$(mktemp -d "${TMPDIR:-/tmp}/odomgym-docs.XXXXXX")"
# A bare venv that sees $PYTHON's packages through a path line (which runs none of their .pth
# files): an editable odomgym's import hook (a developer's venv) would otherwise map
# odomgym.envs and odomgym.baselines to the working tree instead of the tagged tree's folders.
# mike runs `mkdocs` from PATH: both commands go through this venv's python.
SITE="$("$PYBIN/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
"$PYBIN/python" -m venv --without-pip "$WORK/venv"
echo "$SITE" > "$("$WORK/venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/odomgym-docs-deps.pth"
mkdir "$WORK/bin"
printf '#!/bin/sh\nexec "%s" -m mkdocs "$@"\n' "$WORK/venv/bin/python" > "$WORK/bin/mkdocs"
printf '#!/bin/sh\nexec "%s" -c "import sys; from mike.driver import main; sys.exit(main())" "$@"\n' \
    "$WORK/venv/bin/python" > "$WORK/bin/mike"
chmod +x "$WORK/bin/mkdocs" "$WORK/bin/mike"
cleanup() {
    for tree in "$WORK"/v[0-9]*; do [[ -d "$tree" ]] && git worktree remove --force "$tree" 2> /dev/null; done
    rm -rf "$WORK"
}
trap cleanup EXIT
LAST="${VERSIONS[${#VERSIONS[@]}-1]}"
for v in "${VERSIONS[@]}"; do
    TREE="$WORK/v$v"
    git worktree add -q --detach "$TREE" "v$v"
    CONFIG=mkdocs.yml
    if ! grep -q "provider: mike" "$TREE/mkdocs.yml"; then
        # A copy plus the selector, not INHERIT: mike adds its plugin to the config's plugin
        # list, and under INHERIT that list would replace the tree's (mkdocstrings lost).
        grep -q '^extra:' "$TREE/mkdocs.yml" \
            && { echo "docs_versions.sh: v$v's mkdocs.yml has an extra: section; add the provider by hand" >&2; exit 1; }
        CONFIG=mkdocs-mike.yml
        { cat "$TREE/mkdocs.yml"; printf 'extra:\n  version:\n    provider: mike\n    default: latest\n'; } \
            > "$TREE/$CONFIG"
        echo "== $v: its mkdocs.yml names no version provider: built from a copy with the selector ($CONFIG)"
    fi
    ALIASES=()
    [[ "$v" == "$LAST" ]] && ALIASES=(latest)
    echo "== $v: mike deploy from tag v$v ($(git rev-parse --short "v$v^{commit}")) into $BRANCH"
    (cd "$TREE" && PATH="$WORK/bin:$PATH" PYTHONPATH="$TREE" NO_MKDOCS_2_WARNING=1 mike deploy \
        --config-file "$CONFIG" --branch "$BRANCH" --update-aliases \
        --message "docs $v from tag v$v" "$v" "${ALIASES[@]}")
done
"$WORK/bin/mike" set-default --branch "$BRANCH" --message "docs: default latest" latest
echo "== $BRANCH holds:"
"$WORK/bin/mike" list --branch "$BRANCH"
echo "   (local only; view with: $PYBIN/mike serve --branch $BRANCH)"

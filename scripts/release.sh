#!/usr/bin/env bash
# Tag a release of odomgym locally, after checking that it is one (issue 46; docs/release.md).
# Uploads nothing, pushes nothing: the tag is an annotated git tag `vVERSION` in this repository.
#
#   bash scripts/release.sh VERSION                  # tag HEAD, after every check below
#   bash scripts/release.sh VERSION --at COMMIT      # a historical release: tag an older commit
#   bash scripts/release.sh VERSION --at COMMIT --skip-tests
#
# Checks, in order; the first that fails stops the script with one line (exit 1; bad arguments
# exit 2), before anything is tagged:
#   1. the working tree is clean (no change, no untracked file) and `vVERSION` is not a tag yet;
#   2. CHANGELOG.md (HEAD's: the changelog of record) has a released section `## [VERSION] —
#      YYYY-MM-DD`;
#   3. at HEAD: pyproject.toml's version is VERSION, CHANGELOG's top released section is
#      VERSION, CITATION.cff states VERSION and the changelog's date;
#   4. the tests pass: `bash scripts/test.sh` (the README's test command, the artefact check's CI
#      lane included);
#   5. the artefacts: `bash scripts/check_dist.sh --full` (the README's commands exactly, from the
#      wheel in a fresh venv outside the tree);
#   then `git tag -a vVERSION` with the changelog section as its message.
#
# --at COMMIT, for a release whose commit predates this script (0.2.0: 054f92d). The commit must
# be an ancestor of HEAD and its committer date (UTC) the changelog's date for VERSION. What can
# be checked there is: the commit checked out in a temporary worktree, step 4 is that tree's own
# scripts/test.sh, step 5 is this check_dist.sh run on that tree (--tree); step 3 cannot hold
# there (the version was not kept in one place before 0.3.0, and a commit cannot be changed
# after the fact): the commit's own pyproject version is printed and written into the tag's
# message, and the tag is made even when it differs.
#
# --skip-tests skips step 4 and is accepted ONLY with --at: it exists for re-tagging old
# commits whose own test command has already passed in CI when they landed (and takes ~12 min
# a commit). A release of HEAD always runs the tests.
#
# Environment: PYTHON, the python with the [release] extra for check_dist.sh (default: the
# .venv-test that step 4 leaves, else python3).
set -euo pipefail
cd "$(dirname "$0")/.."
REPO="$(pwd -P)"

usage() { echo "release.sh: $*; usage: release.sh VERSION [--at COMMIT] [--skip-tests]" >&2; exit 2; }
fail() { echo "release.sh: not released: $*" >&2; exit 1; }

VERSION="" AT="" SKIP_TESTS=0
while (($#)); do
    case "$1" in
        --at) [[ $# -ge 2 ]] || usage "--at needs a commit"; AT="$2"; shift ;;
        --skip-tests) SKIP_TESTS=1 ;;
        -h|--help) sed -n '2,38p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        -*) usage "unknown option '$1'" ;;
        *) [[ -z "$VERSION" ]] || usage "one VERSION only (got '$VERSION' and '$1')"; VERSION="$1" ;;
    esac
    shift
done
[[ -n "$VERSION" ]] || usage "no VERSION"
[[ "$VERSION" =~ ^[0-9]+\.[0-9]+\.[0-9]+$ ]] || usage "VERSION must be MAJOR.MINOR.PATCH, got '$VERSION'"
if [[ $SKIP_TESTS == 1 && -z "$AT" ]]; then
    usage "--skip-tests only re-tags an old commit (--at COMMIT): a release of HEAD runs the tests"
fi
TAG="v$VERSION"

echo "== 1. a clean working tree, no tag $TAG yet"
[[ -z "$(git status --porcelain)" ]] || fail "the working tree has changes or untracked files (git status)"
if git rev-parse -q --verify "refs/tags/$TAG" > /dev/null; then fail "the tag $TAG exists already"; fi

echo "== 2. CHANGELOG.md has a released section for $VERSION"
DATE="$(python3 - "$VERSION" <<'EOF'
import re
import sys

text = open("CHANGELOG.md", encoding="utf-8").read()
found = re.findall(rf"^## \[{re.escape(sys.argv[1])}\] — (\d{{4}}-\d{{2}}-\d{{2}})$", text, re.M)
print(found[0] if found else "")
EOF
)"
[[ -n "$DATE" ]] || fail "CHANGELOG.md has no section '## [$VERSION] — YYYY-MM-DD'"
NOTES="$(awk -v v="## [$VERSION] " 'index($0, v) == 1 { on = 1; next } on && /^## \[/ { exit } on' CHANGELOG.md)"
echo "   [$VERSION] — $DATE"

if [[ -z "$AT" ]]; then
    COMMIT="$(git rev-parse HEAD)"
    echo "== 3. pyproject.toml, CHANGELOG.md and CITATION.cff agree on $VERSION"
    python3 - "$VERSION" "$DATE" <<'EOF' || fail "the version is not $VERSION everywhere (above)"
import re
import sys
import tomllib

version, date = sys.argv[1:]
problems = []
with open("pyproject.toml", "rb") as file:
    if (found := tomllib.load(file)["project"]["version"]) != version:
        problems.append(f"pyproject.toml says {found}")
released = re.findall(r"^## \[(\d+\.\d+\.\d+)\] — ", open("CHANGELOG.md", encoding="utf-8").read(), re.M)
if released[:1] != [version]:
    problems.append(f"CHANGELOG.md's top released section is {released[:1]}")
cff = open("CITATION.cff", encoding="utf-8").read()
for key, want in (("version", version), ("date-released", date)):
    got = re.findall(rf"^{key}: \"?([^\"\n]+)\"?$", cff, re.M)
    if got != [want]:
        problems.append(f"CITATION.cff {key}: {got} (want {want})")
for problem in problems:
    print(f"   {problem}", file=sys.stderr)
sys.exit(bool(problems))
EOF
    echo "== 4. the tests: bash scripts/test.sh"
    bash scripts/test.sh || fail "scripts/test.sh failed"
    echo "== 5. the artefacts: bash scripts/check_dist.sh --full"
    bash scripts/check_dist.sh --full || fail "scripts/check_dist.sh --full failed"
    MESSAGE="odomgym $VERSION ($DATE)"
else
    COMMIT="$(git rev-parse -q --verify "$AT^{commit}")" || fail "--at $AT is not a commit"
    git merge-base --is-ancestor "$COMMIT" HEAD || fail "--at $AT is not in HEAD's history"
    COMMIT_DATE="$(TZ=UTC0 git show -s --date=format-local:%Y-%m-%d --format=%cd "$COMMIT")"
    [[ "$COMMIT_DATE" == "$DATE" ]] \
        || fail "$AT was committed on $COMMIT_DATE, CHANGELOG.md dates $VERSION $DATE"
    OLD="$(mktemp -d "${TMPDIR:-/tmp}/odomgym-release-$VERSION.XXXXXX")"
    trap 'git worktree remove --force "$OLD/tree" 2> /dev/null || true; rm -rf "$OLD"' EXIT
    git worktree add -q --detach "$OLD/tree" "$COMMIT"
    OLD_VERSION="$(python3 -c 'import sys, tomllib; print(tomllib.load(open(sys.argv[1], "rb"))["project"]["version"])' "$OLD/tree/pyproject.toml")"
    echo "== 3. at ${COMMIT:0:12} ($COMMIT_DATE): its pyproject.toml says $OLD_VERSION"
    if [[ "$OLD_VERSION" != "$VERSION" ]]; then
        echo "   NOTE: not $VERSION — the version was not kept in one place before 0.3.0; the tag" \
             "marks this code, whose wheel and 'odomgym --version' say $OLD_VERSION"
    fi
    if [[ $SKIP_TESTS == 1 ]]; then
        echo "== 4. the tests: SKIPPED (--skip-tests: this old commit's CI passed when it landed)"
    else
        echo "== 4. the tests: that commit's own bash scripts/test.sh"
        (cd "$OLD/tree" && bash scripts/test.sh) || fail "$AT's scripts/test.sh failed"
    fi
    echo "== 5. the artefacts: bash scripts/check_dist.sh --full --tree <$AT's checkout>"
    bash scripts/check_dist.sh --full --tree "$OLD/tree" || fail "check_dist.sh on $AT failed"
    MESSAGE="odomgym $VERSION ($DATE), tagged afterwards at ${COMMIT:0:12} by scripts/release.sh --at"
    if [[ "$OLD_VERSION" != "$VERSION" ]]; then
        MESSAGE+=$'\n\n'"This commit's own pyproject.toml says $OLD_VERSION (the version was not kept in one place before 0.3.0): its wheel and 'odomgym --version' say $OLD_VERSION."
    fi
    [[ $SKIP_TESTS == 1 ]] && MESSAGE+=$'\n\n'"Tagged with --skip-tests: the tests ran in CI when the commit landed, not again."
fi

git tag -a --cleanup=verbatim "$TAG" -F - "$COMMIT" <<EOF
$MESSAGE
$NOTES
EOF
echo "== tagged $TAG at $(git rev-parse --short "$COMMIT") (local only: nothing pushed or uploaded)"

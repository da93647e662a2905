"""A full disk, for real: each command writing its outputs runs in a private mount namespace
(``unshare -m``) on a 64 KiB tmpfs filled to the last page. It must exit 1 with one line naming
the file it could not write and "No space left on device" — never a traceback — and leave no
temporary file: what it did write is whole (a journal to resume from, a finished file).

Needs root or unprivileged user namespaces for ``unshare``; skipped (saying so) where the
machine allows neither. ``tests/test_cli.py`` has the unprivileged, monkeypatched version.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DISK = f"{tempfile.gettempdir()}/odomgym-full-disk"  # mounted over only inside the namespace
SESSION = "optiodom:square/230620202042"
ROBOT = str(REPO / "examples" / "optiodom_nominal.toml")

CASES = {
    "run": ([*"run square --runs 2 --side 1 --log".split(), f"{DISK}/runs.csv"], set()),
    "calibrate": (
        [*"calibrate umbmark --side 1 --runs 1 --save".split(), f"{DISK}/c.toml"],
        set(),
    ),
    "bench": (
        [
            *"bench calibrators --robots 2 --floor concrete --methods umbmark --budget 4".split(),
            *["--out", f"{DISK}/bench"],
        ],
        {"bench", "bench/journal.jsonl"},
    ),
    "leaderboard": ([*"leaderboard --data optiodom: --out".split(), f"{DISK}/board.md"], set()),
    "diagnose": (
        [
            *["diagnose", SESSION, "--robot", ROBOT],
            *"--candidates wheel_diameter_ratio --max-rounds 1 --out".split(),
            f"{DISK}/diag",
        ],
        {"diag.journal"},
    ),
    "train": (
        [*"train selfcal --steps 64 --envs 4 --workers 1 --out".split(), f"{DISK}/train"],
        {"train", "train/progress.csv"},
    ),
}


def _namespaces_work() -> bool:
    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(
        ["unshare", "-m", "sh", "-c", f"mkdir -p {DISK} && mount -t tmpfs tmpfs {DISK}"],
        capture_output=True,
    )
    return probe.returncode == 0


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(CASES))
def test_a_full_disk_is_one_line_and_leaves_no_temporary(name: str) -> None:
    if not _namespaces_work():
        pytest.skip("no private mount namespace here (unshare -m needs root or user namespaces)")
    if name == "train":
        pytest.importorskip("stable_baselines3")
    argv, may_remain = CASES[name]
    command = " ".join([sys.executable, "-m", "odomgym", *argv])
    script = (
        f"mkdir -p {DISK} && mount -t tmpfs -o size=64k tmpfs {DISK} && "
        f"dd if=/dev/zero of={DISK}/fill bs=4k count=16 2>/dev/null && "
        f"{command} >/dev/null; echo rc=$?; cd {DISK} && find . -mindepth 1 ! -name fill"
    )
    done = subprocess.run(
        ["unshare", "-m", "sh", "-c", script],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
    )
    rc, *left = done.stdout.split()
    err = [line for line in done.stderr.splitlines() if line.strip()]
    assert rc == "rc=1", (rc, done.stderr)
    assert "Traceback" not in done.stderr, done.stderr
    assert err[-1].startswith(f"odomgym: error: {DISK}/"), err
    assert err[-1].endswith(": No space left on device"), err
    remaining = {path.removeprefix("./") for path in left}
    assert not [p for p in remaining if Path(p).name.startswith(".")], remaining
    assert remaining <= may_remain, remaining

"""Rebuild the OptiOdom sample sessions shipped in ``odomgym/data/samples/optiodom/``.

    python scripts/make_optiodom_samples.py [../shared/data/optiodom-diff]

Writes one reproducible ``<kind>-<session>.tar.xz`` per session of :data:`SESSIONS` (members
``<session>/<file>``, sorted, mtime 0, owner root, mode 0644), ``published_results.csv``
restricted to those sessions' rows, and the data's ``LICENSE``. The files are copied byte for
byte: the shipped sessions read exactly as the full data set's. ``README.md`` beside them
(attribution, list of sessions) is kept by hand.
"""

from __future__ import annotations

import csv
import io
import lzma
import sys
import tarfile
from pathlib import Path

SESSIONS = (
    "square/230620202042",
    "square/230620202144",
    "square/230620202317",
    "ivanjko/250620201618",
    "ivanjko/250620201636",
    "circular/250620202104",
)
ROOT = Path(__file__).resolve().parents[1]
TARGET = ROOT / "odomgym" / "data" / "samples" / "optiodom"
DEFAULT_SOURCE = ROOT.parent / "shared" / "data" / "optiodom-diff"


def write_archive(folder: Path, archive: Path) -> None:
    """``folder``'s files as ``<folder name>/<file>`` in a reproducible ``.tar.xz``."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.PAX_FORMAT) as tar:
        for path in sorted(folder.iterdir()):
            if not path.is_file():
                raise SystemExit(f"{path}: not a regular file")
            data = path.read_bytes()
            info = tarfile.TarInfo(f"{folder.name}/{path.name}")
            info.size, info.mode, info.mtime = len(data), 0o644, 0
            info.uid = info.gid = 0
            info.uname = info.gname = ""
            tar.addfile(info, io.BytesIO(data))
    archive.parent.mkdir(parents=True, exist_ok=True)
    archive.write_bytes(lzma.compress(buffer.getvalue(), preset=9 | lzma.PRESET_EXTREME))


def write_published(source: Path, target: Path) -> int:
    """The rows of ``source`` for :data:`SESSIONS`; returns how many."""
    wanted = {tuple(name.split("/")) for name in SESSIONS}
    with source.open(newline="", encoding="utf-8") as handle:
        reader = csv.DictReader(handle)
        fields = list(reader.fieldnames or ())
        rows = [row for row in reader if (row["path"], row["session"]) in wanted]
    with target.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    return len(rows)


def main(argv: list[str]) -> int:
    source = Path(argv[0]) if argv else DEFAULT_SOURCE
    if not (source / "published_results.csv").is_file():
        print(f"no OptiOdom data at {source}", file=sys.stderr)
        return 2
    total = 0
    for name in SESSIONS:
        archive = TARGET / f"{name.replace('/', '-')}.tar.xz"
        write_archive(source / name, archive)
        size = archive.stat().st_size
        total += size
        print(f"{archive.relative_to(ROOT)}: {size} bytes")
    rows = write_published(source / "published_results.csv", TARGET / "published_results.csv")
    (TARGET / "LICENSE").write_bytes((source / "LICENSE").read_bytes())
    print(f"published_results.csv: {rows} rows; archives: {total} bytes in all")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

"""``odomgym diagnose DATA --loso``: leave one session out (:mod:`odomgym.diagnose.loso`).

On the three shipped square sessions of the OptiOdom robot (Sousa et al. 2022), with a small
diagnosis per fold (two candidate effects, one round, no discovery: a few seconds a fold on one
core), so the checks run the real folds: one fold file per session and the table; a second call
diagnoses only the fold whose file is missing and prints the same table; two shards and a
``--table-only`` call give the folds of one full run; bad options are one line; and, slow,
``--backend ray`` on a local Ray writes the same fold files as ``--backend local``, byte for
byte but for the timing fields.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import re
import shutil
from pathlib import Path
from typing import Any

import pytest
from cli_errors import one_line_error

from odomgym.cli import main
from odomgym.diagnose import loso
from odomgym.diagnose.loso import TIMING_FIELDS, without_timing

ROOT = Path(__file__).resolve().parents[1]
DATA = "optiodom:square"
SESSIONS = ["230620202042", "230620202144", "230620202317"]  # in the data's order
SMALL = ["--jobs", "1", "--no-discover", "--max-rounds", "1"]
SMALL += ["--candidates", "wheelbase", "distance_scale"]
FOLD_KEYS = {
    "left_out",
    "gate_order",
    "runs",
    "seconds",
    "verdict",
    "systematic_effects",
    "noise_model",
    "terms_kept",
    "terms_tried",
    "sessions_fitted",
    "geometry",
    "left_out_open_loop",
    "gate",
}  # the keys of benchmarks/diagnose_loso.py's fold files before the command existed


def _argv(out: Path, *extra: str) -> list[str]:
    robot = str(ROOT / "examples" / "optiodom_nominal.toml")
    return ["diagnose", DATA, "--robot", robot, "--loso", "--out", str(out), *SMALL, *extra]


def _run(argv: list[str]) -> str:
    """``odomgym`` in this process, which must succeed; its stdout."""
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(argv) == 0
    return printed.getvalue()


def _untimed_text(path: Path) -> str:
    """A fold file's bytes (as text) without the lines of its timing fields."""
    lines = path.read_text(encoding="utf-8").splitlines()
    timing = tuple(f'"{key}":' for key in TIMING_FIELDS)
    return "\n".join(line for line in lines if not line.lstrip().startswith(timing))


def _untimed_table(text: str) -> str:
    """The printed table without its last sentence's wall time and the status lines."""
    status = ("resumed: ", "wrote: ")
    table = "\n".join(line for line in text.splitlines() if not line.startswith(status))
    return re.sub(r"\d+ s of diagnosis", "_ s of diagnosis", table.strip())


@pytest.fixture(scope="module")
def full(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """One full run of the three folds: the fold folder and what the command printed."""
    out = tmp_path_factory.mktemp("loso") / "full"
    return out, _run(_argv(out))


@pytest.mark.slow
def test_the_command_writes_a_fold_file_per_session_and_prints_the_table(
    full: tuple[Path, str],
) -> None:
    out, printed = full
    assert sorted(p.name for p in out.iterdir()) == [f"fold-{s}.json" for s in SESSIONS]
    for session in SESSIONS:
        fold = json.loads((out / f"fold-{session}.json").read_text(encoding="utf-8"))
        assert set(fold) == FOLD_KEYS and fold["left_out"] == session
        assert fold["sessions_fitted"] == 2 and fold["gate_order"] == "catalogue first"
        assert {"as given", "diagnosed"} <= set(fold["left_out_open_loop"])
    rows = [line for line in printed.splitlines() if line.startswith("| 2306")]
    assert [row.split(" | ")[0] for row in rows] == [f"| {s}" for s in SESSIONS]
    assert printed.startswith("| left out | runs | systematic effects |")
    assert "left-out session better than as given: " in printed
    assert "wrote: " + ", ".join(str(out / f"fold-{s}.json") for s in SESSIONS) in printed


@pytest.mark.slow
def test_a_second_call_diagnoses_only_the_missing_fold_and_prints_the_same_table(
    full: tuple[Path, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source, printed = full
    out = tmp_path / "again"
    shutil.copytree(source, out)
    (out / f"fold-{SESSIONS[1]}.json").unlink()
    kept = {s: (out / f"fold-{s}.json").stat().st_mtime_ns for s in (SESSIONS[0], SESSIONS[2])}
    diagnosed: list[str] = []
    real = loso.fold

    def counted(*args: Any, **kwargs: Any) -> dict[str, Any]:
        diagnosed.append(args[2])
        return real(*args, **kwargs)

    monkeypatch.setattr(loso, "fold", counted)
    again = _run(_argv(out))
    assert diagnosed == [SESSIONS[1]]
    assert {s: (out / f"fold-{s}.json").stat().st_mtime_ns for s in kept} == kept
    assert f"resumed: 2 of 3 folds taken from {out}" in again
    assert f"wrote: {out / f'fold-{SESSIONS[1]}.json'}\n" in again  # only the new one
    assert _untimed_table(again) == _untimed_table(printed)
    assert _untimed_text(out / f"fold-{SESSIONS[1]}.json") == _untimed_text(
        source / f"fold-{SESSIONS[1]}.json"
    )
    diagnosed.clear()
    assert _untimed_table(_run(_argv(out))) == _untimed_table(printed)  # all three on disk
    assert diagnosed == []


@pytest.mark.slow  # it diagnoses the three folds again (12 s of CPU): CI runs it
def test_two_shards_then_the_table_give_the_full_run(
    full: tuple[Path, str], tmp_path: Path
) -> None:
    source, _ = full
    out = tmp_path / "shards"
    _run(_argv(out, "--shard", "1/2"))
    assert sorted(p.name for p in out.iterdir()) == [f"fold-{s}.json" for s in SESSIONS[::2]]
    _run(_argv(out, "--shard", "2/2"))
    for session in SESSIONS:
        name = f"fold-{session}.json"
        assert _untimed_text(out / name) == _untimed_text(source / name)
    sharded = json.loads(_run(_argv(out, "--table-only", "--json")))
    whole = json.loads(_run(_argv(source, "--table-only", "--json")))
    assert without_timing(sharded) == without_timing(whole)
    assert sharded["summary"]["missing_folds"] == [] and len(sharded["folds"]) == 3
    partial = _run(_argv(tmp_path / "none", "--table-only", "--sessions", SESSIONS[2]))
    assert f"Not diagnosed yet (1 of 1): {SESSIONS[2]}" in partial
    assert not (tmp_path / "none").exists()  # nothing diagnosed, nothing written


@pytest.mark.parametrize("shard", ["0/2", "3/2", "2", "a/b", "1/2/3"])
def test_a_bad_shard_is_refused_by_the_parser(
    shard: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as stopped:
        main(_argv(tmp_path / "out", "--shard", shard))
    err = capsys.readouterr().err.strip().splitlines()
    assert stopped.value.code == 2
    assert "argument --shard: expected K/N with 1 <= K <= N" in err[-1], err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("extra", "needles"),
    [
        (["--sessions", SESSIONS[0], "nope"], ("--sessions: not in the data: nope",)),
        (["--shard", "1/2"], ("--shard needs --loso",)),
        (["--sessions", SESSIONS[0]], ("--sessions needs --loso",)),
        (["--table-only"], ("--table-only needs --loso",)),
    ],
)
def test_bad_loso_options_are_one_line(
    extra: list[str],
    needles: tuple[str, ...],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    argv = _argv(tmp_path / "out", *extra)
    if "needs --loso" in needles[0]:
        argv.remove("--loso")
    assert main(argv) == 2
    one_line_error(capsys, *needles)
    assert not (tmp_path / "out").exists()


def test_one_session_or_a_broken_fold_file_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = _argv(tmp_path / "one")
    argv[1] = f"{DATA}/{SESSIONS[0]}"
    assert main(argv) == 2
    one_line_error(capsys, "two or more sessions")
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / f"fold-{SESSIONS[0]}.json").write_text("{", encoding="utf-8")
    assert main(_argv(broken, "--table-only")) == 2
    out, err = capsys.readouterr()  # after the notices about the data read (held poses)
    assert out == "" and "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("odomgym: error: ") and f"fold-{SESSIONS[0]}.json: " in last
    assert "cannot read this fold file" in last


@pytest.mark.slow
def test_folds_on_ray_are_the_local_folds(
    full: tuple[Path, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every fold one Ray task on a local Ray of two CPUs: the same fold files, byte for byte
    except the timing fields, and the same table."""
    pytest.importorskip("ray")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    source, printed = full
    out = tmp_path / "ray"
    on_ray = _run(_argv(out, "--backend", "ray", "--jobs", "2"))
    for session in SESSIONS:
        name = f"fold-{session}.json"
        assert _untimed_text(out / name) == _untimed_text(source / name)
    assert _untimed_table(on_ray) == _untimed_table(printed)


def _fold(session: str, e_b: float, se: float) -> dict[str, Any]:
    """A fold's entries as :func:`odomgym.diagnose.loso.fold` writes them, with E_b's value and
    session-clustered standard error given (E_d and E_s exact)."""
    geometry = {"e_d": (1.0, 1e-4), "e_b": (e_b, se), "e_s": (1.0, 1e-4)}
    models = {"as given": 10.0, "diagnosed": 4.0}
    return {
        "left_out": session,
        "gate_order": "catalogue first",
        "runs": 6,
        "seconds": 1.0,
        "verdict": "explained",
        "systematic_effects": ["wheelbase"],
        "noise_model": [],
        "terms_kept": [],
        "terms_tried": 0,
        "sessions_fitted": 1,
        "geometry": {k: {"value": v, "stderr_sessions": e} for k, (v, e) in geometry.items()},
        "left_out_open_loop": {
            m: {"position_rms_mm": r, "heading_rms_deg": 0.5, "combined_rms_mm": r}
            for m, r in models.items()
        },
        "gate": [],
    }


def test_fold_files_are_strict_json_and_a_missing_interval_is_not_a_no(tmp_path: Path) -> None:
    """A fold fitted on one session has no standard error: its file held Python's ``NaN``
    literal (refused by strict parsers), and when no fold had an interval the check read "no"
    for E_b values that agree to four digits. The file now holds ``null``, read back as NaN,
    and the check says it cannot tell (None; "n/a" in the table)."""
    from odomgym.diagnose.loso import _read_fold, _write_fold, summarise, table

    def refuse(name: str) -> float:
        raise ValueError(f"not strict JSON: {name}")

    written = [
        _write_fold(tmp_path / f"fold-{s}.json", _fold(s, 1.0033 + k * 1e-4, math.nan))
        for k, s in enumerate(SESSIONS[:2])
    ]
    for session in SESSIONS[:2]:
        text = (tmp_path / f"fold-{session}.json").read_text(encoding="utf-8")
        json.loads(text, parse_constant=refuse)
        assert '"stderr_sessions": null' in text
        again = _read_fold(tmp_path / f"fold-{session}.json", "catalogue first")
        assert math.isnan(again["geometry"]["e_b"]["stderr_sessions"])
    assert math.isnan(written[0]["geometry"]["e_b"]["stderr_sessions"])
    checks = summarise(written)
    assert [checks["intervals"][k]["overlap"] for k in ("e_d", "e_b", "e_s")] == [True, None, True]
    assert "95 % intervals overlap: e_d True, e_b n/a, e_s True;" in table(written, checks)
    # Beside folds with intervals, a fold without one is its value alone, in any order: inside
    # their common part it agrees, outside it does not (the June table's E_b fold at 1.0000).
    inside, outside = _fold("a", 1.0005, math.nan), _fold("b", 1.01, math.nan)
    sized = _fold("c", 1.0, 1e-3)
    sized["sessions_fitted"] = 13
    for folds, agree in (
        ([inside, sized], True),
        ([sized, inside], True),
        ([outside, sized], False),
    ):
        e_b = summarise(folds)["intervals"]["e_b"]
        assert e_b["overlap"] is agree
    assert (
        summarise([inside, sized])["intervals"]["e_b"]["common_interval"]
        == summarise([sized, inside])["intervals"]["e_b"]["common_interval"]
    )

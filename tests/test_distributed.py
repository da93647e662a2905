"""``--backend ray`` and ``--ray-address`` (:mod:`odomgym.distributed`): results byte-identical
to ``--backend local``, on a real Ray head started here by ``ray start --head`` (not only an
in-process Ray), the cluster found by Ray's convention; and the one-line errors without Ray.

Also the periods a fleet takes from dated session names (OptiOdom's ``DDMMYYYYhhmm``).
"""

from __future__ import annotations

import contextlib
import datetime
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from cli_errors import one_line_error

from odomgym.cli import main
from odomgym.data import sample_session
from odomgym.data.optiodom import session_time
from odomgym.diagnose.config import DiagnoseConfig
from odomgym.diagnose.fleet import diagnose_fleet, find_fleet, read_robot_runs
from odomgym.robot import PRESETS


def _files(root: Path) -> dict[str, bytes]:
    """Every file below ``root`` by its relative path, with its bytes."""
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


# ------------------------------------------------------------------------- a real Ray head
@pytest.fixture(scope="module")
def ray_head() -> Iterator[str]:
    """A Ray head started by ``ray start --head --block`` (2 CPUs, its own temporary folder, so
    no other Ray on the machine sees it), as a user starts a cluster; yields its address and
    stops it (its whole process group) afterwards. Token authentication off
    (``RAY_AUTH_MODE=disabled``): the head listens on this machine for the length of the
    module only, and a driver of either mode connects to it (a token cluster's drivers set
    ``RAY_AUTH_MODE=token`` themselves: docs/fleet.md)."""
    pytest.importorskip("ray")
    ray_cli = Path(sys.executable).parent / "ray"
    if not ray_cli.exists():
        pytest.skip("the ray command line is not installed beside this Python")
    temp = Path(tempfile.mkdtemp(prefix="r", dir="/tmp"))  # Ray's socket paths must stay short
    env = dict(os.environ, RAY_AUTH_MODE="disabled", RAY_USAGE_STATS_ENABLED="0")
    command = [str(ray_cli), "start", "--head", "--port=0", "--num-cpus=2", "--block"]
    command += ["--include-dashboard=false", "--disable-usage-stats", f"--temp-dir={temp}"]
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        start_new_session=True,
    )
    address = None
    lines = []
    deadline = time.monotonic() + 120
    assert process.stdout is not None
    while address is None and time.monotonic() < deadline:
        line = process.stdout.readline()
        if not line:
            break
        lines.append(line)
        found = re.search(r"ray start --address='([^']+)'", line)
        address = found.group(1) if found else None
    try:
        assert address is not None, "ray start --head gave no address:\n" + "".join(lines)
        yield address
    finally:
        # Politely, then for sure: its raylet may take half a minute to drain its workers.
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            pass
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=10)
        shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture
def no_ray_address(monkeypatch: pytest.MonkeyPatch) -> None:
    """No cluster named by the environment: each test names the head itself."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)


def _small_fleet(root: Path) -> Path:
    """Two simulated LabMates, one session each (one with a planted E_b)."""
    assert main(["fleet", "--example", "2", str(root), "--sessions", "1"]) == 0
    return root


@pytest.mark.slow
@pytest.mark.usefixtures("no_ray_address")
def test_a_fleet_on_a_ray_head_is_byte_identical_to_local(tmp_path: Path, ray_head: str) -> None:
    """Every file of the fleet's output — each robot's report, model and figures, fleet.md,
    fleet.json — is the same byte for byte whether the diagnoses run here one after the other
    or as Ray tasks on the head (their files carried back to be written here). Two candidate
    effects and no discovery keep it short; the command-line path is the next test's."""
    robots = find_fleet(_small_fleet(tmp_path / "fleet"))
    config = DiagnoseConfig(candidates=("wheelbase", "distance_scale"), discover=False, jobs=1)
    for backend, address in (("local", None), ("ray", ray_head)):
        out = tmp_path / backend
        lines: list[str] = []
        diagnose_fleet(
            robots, out, config=config, backend=backend, address=address, status=lines.append
        )
        assert len(lines) == 2
    local, distributed = _files(tmp_path / "local"), _files(tmp_path / "ray")
    assert local.keys() == distributed.keys() and "robots/robot-1/report.json" in local
    assert [k for k in local if local[k] != distributed[k]] == []


@pytest.mark.slow
@pytest.mark.usefixtures("no_ray_address")
def test_diagnose_and_bench_find_the_head_by_ray_address(
    tmp_path: Path,
    ray_head: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``diagnose --backend ray`` with the cluster in ``RAY_ADDRESS`` (candidate fits as Ray
    tasks) writes the same files as ``--backend local``; ``bench --backend ray --ray-address``
    gives the same summary as local processes (all but the wall time)."""
    fleet = _small_fleet(tmp_path / "fleet")
    log = str(fleet / "robot-2" / "session-1.csv")
    common = ["diagnose", log, "--robot", str(fleet / "robot-2" / "robot.toml"), "--no-baseline"]
    common += [
        "--no-discover",
        "--candidates",
        "wheelbase",
        "distance_scale",
        "wheel_diameter_ratio",
    ]
    assert main([*common, "--out", str(tmp_path / "d-local"), "--jobs", "2"]) == 0
    monkeypatch.setenv("RAY_ADDRESS", ray_head)
    assert main([*common, "--out", str(tmp_path / "d-ray"), "--backend", "ray"]) == 0
    monkeypatch.delenv("RAY_ADDRESS")
    assert _files(tmp_path / "d-local") == _files(tmp_path / "d-ray")

    bench = ["bench", "calibrators", "--robots", "2", "--floor", "concrete", "--budget", "4"]
    bench += ["--methods", "umbmark", "--json", "--no-oracle"]
    capsys.readouterr()
    assert main([*bench, "--out", str(tmp_path / "b-local"), "--jobs", "2"]) == 0
    local = capsys.readouterr().out
    assert (
        main(
            [
                *bench,
                "--out",
                str(tmp_path / "b-ray"),
                "--backend",
                "ray",
                "--ray-address",
                ray_head,
            ]
        )
        == 0
    )
    distributed = capsys.readouterr().out
    import json

    def results(text: str) -> list[dict[str, object]]:  # all but the wall time
        rows = json.loads(text)["summary"]
        return [{k: v for k, v in row.items() if not k.startswith("wall_time")} for row in rows]

    assert results(local) == results(distributed)


# ----------------------------------------------------------------------------- without Ray
@pytest.mark.parametrize(
    "argv",
    [
        ["fleet", "ROBOTS", "--backend", "ray"],
        ["diagnose", "optiodom:square/230620202042", "--backend", "ray"],
        ["bench", "calibrators", "--backend", "ray"],
    ],
)
def test_backend_ray_without_ray_is_one_line_naming_the_extra(
    argv: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # what `import ray` sees when it is missing
    monkeypatch.chdir(tmp_path)
    (tmp_path / "ROBOTS").mkdir()
    assert main(argv) == 2
    one_line_error(capsys, "--backend ray needs Ray", "odomgym[distributed]")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ROBOTS"]  # nothing written


@pytest.mark.parametrize("command", [["fleet", "ROBOTS"], ["bench", "calibrators"]])
def test_ray_address_without_backend_ray_is_one_line(
    command: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "ROBOTS").mkdir()
    assert main([*command, "--ray-address", "127.0.0.1:6379"]) == 2
    one_line_error(capsys, "--ray-address needs --backend ray")


def test_an_address_where_nothing_answers_is_one_line_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--ray-address 127.0.0.1:1`` retried for minutes, printing Ray's multi-line errors (a
    user stopped it after 300 s): the address is now tried first, and refused in one line."""
    pytest.importorskip("ray")
    import time

    from odomgym.distributed import check_reachable
    from odomgym.errors import SpecError

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    started = time.monotonic()
    argv = ["bench", "calibrators", "--robots", "1", "--backend", "ray"]
    assert main([*argv, "--ray-address", "127.0.0.1:1"]) == 2
    one_line_error(capsys, "cannot join Ray at 127.0.0.1:1: nothing accepts a connection")
    assert time.monotonic() - started < 30.0
    with pytest.raises(SpecError, match=r"at ray://\[::1\]:1: .* at \[::1\]:1 \(") as caught:
        check_reachable("ray://[::1]:1")
    assert caught.value.field == "ray-address"
    check_reachable("auto")  # left to Ray


def _without_grpcio(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make grpcio (Ray Client's dependency) look uninstalled, whether or not it is."""
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "grpc" else real(name, *a)
    )


def test_a_ray_client_address_without_grpcio_names_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A ``ray://`` address needs Ray Client (grpcio, ``ray[client]``), which the
    ``[distributed]`` extra does not install: refused in one line saying what to install,
    before any connection; a ``host:port`` address does not need it."""
    pytest.importorskip("ray")
    _without_grpcio(monkeypatch)
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    argv = ["bench", "calibrators", "--robots", "1", "--backend", "ray"]
    assert main([*argv, "--ray-address", "ray://127.0.0.1:1"]) == 2
    one_line_error(capsys, "a ray:// address goes through Ray Client, which needs grpcio")


def test_the_client_check_needs_no_ray(monkeypatch: pytest.MonkeyPatch) -> None:
    """:func:`check_client` itself imports nothing of Ray: it runs without the extra."""
    from odomgym.distributed import check_client
    from odomgym.errors import SpecError

    _without_grpcio(monkeypatch)
    with pytest.raises(SpecError, match=r"pip install 'ray\[client\]'") as caught:
        check_client("ray://head:10001")
    assert caught.value.field == "ray-address"
    check_client("head:6379")  # the core's own protocol


# --------------------------------------------------------------------- periods from dates
@pytest.mark.parametrize(
    ("name", "when"),
    [
        ("230620202042", datetime.datetime(2020, 6, 23, 20, 42)),  # a shipped June session
        ("010120210000", datetime.datetime(2021, 1, 1, 0, 0)),
        ("321320201200", None),  # 12 digits, no date
        ("2306202020", None),
        ("session-1", None),
    ],
)
def test_optiodom_session_names_are_their_start(name: str, when: datetime.datetime | None) -> None:
    assert session_time(name) == when


def test_a_robots_dated_sessions_give_its_periods_by_month(tmp_path: Path) -> None:
    """OptiOdom sessions in ``square/``: the sub-folder only organises them (it names the path
    type), the months of the session names are the periods."""
    robot = tmp_path / "fleet" / "robot-a"
    (robot / "square").mkdir(parents=True)
    PRESETS["labmate"].save(robot / "robot.toml")
    source = sample_session("square/230620202042")
    for new in ("230620202042", "150720200930"):  # June and July 2020
        target = robot / "square" / new
        shutil.copytree(source, target)
        for path in target.iterdir():
            path.rename(target / path.name.replace("230620202042", new))
    (found,) = find_fleet(tmp_path / "fleet")
    assert found.periods == ("2020-06", "2020-07")
    runs = read_robot_runs(found)
    assert {r.meta["period"] for r in runs} == {"2020-06", "2020-07"}
    assert {r.meta["session"] for r in runs} == {"230620202042", "150720200930"}


@pytest.mark.slow
@pytest.mark.usefixtures("no_ray_address")
def test_ray_workers_import_the_odomgym_this_process_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ray puts the driver's working folder first on its workers' sys.path. Run from a folder
    holding another ``odomgym/`` (a source checkout beside an installed odomgym; here a decoy
    that cannot be imported), the workers must still import this process's odomgym, its
    subpackages included, and a module of the user's in that folder must still import there
    (``odomgym.distributed.ray_session``)."""
    pytest.importorskip("ray")
    import ray

    import odomgym
    import odomgym.baselines
    from odomgym.distributed import ray_session

    decoy = tmp_path / "odomgym"
    decoy.mkdir()
    (decoy / "__init__.py").write_text('raise ImportError("the decoy odomgym")\n')
    (tmp_path / "users_own_effects_7f3.py").write_text("ANSWER = 42\n")
    monkeypatch.chdir(tmp_path)

    def where() -> tuple[str, str, int]:
        import users_own_effects_7f3  # type: ignore[import-not-found]

        import odomgym as imported
        import odomgym.baselines as baselines

        return imported.__file__ or "", baselines.__file__ or "", users_own_effects_7f3.ANSWER

    with ray_session(None, 1) as started:
        assert started  # this call started Ray (else it would not have chosen the folder)
        found = ray.get(ray.remote(where).remote())
    assert found == (odomgym.__file__, odomgym.baselines.__file__, 42)
    assert Path.cwd() == tmp_path  # the working folder is given back

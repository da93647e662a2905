"""docs/specs.md stays true: its TOML examples load with the values written, its key tables list
exactly the keys the loaders accept (derived from the code), its presets tables match the presets,
and the error messages it quotes are the ones the loaders and the CLI produce.

Conventions of the doc that this test relies on:

* every ```toml block starts with ``# robot spec``, ``# floor spec``, ``# calibration file`` or
  ``# vehicle spec``;
  an invalid example adds `` (invalid): FILE.toml`` and is followed by a ```text block holding
  ``odomgym.errors.SpecError: MESSAGE`` for that file name;
* a ```console block line ``$ odomgym …`` followed by output lines is a command whose stderr is
  that output (only commands with output are run: the error examples);
* ``<!-- keys: NAME -->`` and ``<!-- presets: NAME -->`` precede the tables they name.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import shlex
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pytest

from odomgym.effects import EFFECTS
from odomgym.errors import SpecError
from odomgym.floor import FLOORS, CableBump, FloorSpec, FrictionPatch, load_floor
from odomgym.odometry.calibration import Calibration, load_calibration
from odomgym.robot import PRESETS, RobotSpec, load_robot
from odomgym.vehicle.spec import ENCODER_TRAILER, VEHICLES, VehicleSpec, calibrated, load_vehicle

DOC = Path(__file__).resolve().parents[1] / "docs" / "specs.md"
TEXT = DOC.read_text(encoding="utf-8")

LOADERS: dict[str, Callable[[str], Any]] = {
    "robot spec": load_robot,
    "floor spec": load_floor,
    "calibration file": load_calibration,
    "vehicle spec": load_vehicle,
}
TOP_TABLE = {
    "robot spec": "robot",
    "floor spec": "floor",
    "calibration file": "calibration",
    "vehicle spec": "vehicle",
}
MARKER = re.compile(
    r"# (robot spec|floor spec|calibration file|vehicle spec)(?: \(invalid\): (\S+\.toml))?"
)
FENCE = re.compile(r"^```(\w*)\n(.*?)^```$", re.MULTILINE | re.DOTALL)
ERROR_PREFIX = f"{SpecError.__module__}.{SpecError.__qualname__}: "

# The minimal valid bodies to which the acceptance check adds one documented key.
MINIMAL_ROBOT = "wheel_diameter = 0.15\nwheelbase = 0.34\nticks_per_rev = 2048\n"
MINIMAL_BUMP = "[[floor.bumps]]\nx = 1.0\ny = 2.0\n"
MINIMAL_PATCH = (
    "[[floor.patches]]\nx_min = 0.0\ny_min = 0.0\nx_max = 1.0\ny_max = 1.0\nfriction = 0.5\n"
)
REQUIRED_ROBOT = {"wheel_diameter", "wheelbase", "ticks_per_rev"}
TRUCKS = ("truck_a", "truck_b")
# One-key vehicle files: link_length must stay strictly inside (link_min, link_max), by default
# (0.9, 1.1), and link_max above the default link_length 1; other floats take 0.3.
VEHICLE_VALUES = {
    "link_length": "1.05",
    "link_max": "1.3",
    "linear_bias": "0.003",
    "linear_eccentricity": "0.001",
    "rotary_jitter": "0.002",
    "read_skew": "0.004",
    "tyre_compression": "0.002",
}


# ---------------------------------------------------------------------- parsing the doc
def _fences() -> list[tuple[str, str]]:
    """(language, body) of every fenced block, in document order."""
    return [(m.group(1), m.group(2)) for m in FENCE.finditer(TEXT)]


def _toml_blocks() -> list[tuple[str, str | None, str, str | None]]:
    """(kind, invalid file name or None, TOML text, quoted error or None) per ```toml block."""
    fences = _fences()
    out = []
    for index, (lang, body) in enumerate(fences):
        if lang != "toml":
            continue
        first = body.splitlines()[0]
        match = MARKER.fullmatch(first)
        assert match, f"a ```toml block in {DOC.name} starts with no marker: {first!r}"
        kind, name = match.group(1), match.group(2)
        quoted = None
        if name is not None:
            following = [b for lang2, b in fences[index + 1 :] if lang2 == "text"]
            assert following, f"invalid example {name} has no ```text block with its error"
            quoted = following[0].strip()
        out.append((kind, name, body, quoted))
    return out


BLOCKS = _toml_blocks()
VALID = [(kind, text) for kind, name, text, _ in BLOCKS if name is None]
INVALID = [(kind, name, text, quoted) for kind, name, text, quoted in BLOCKS if name is not None]


def _table(marker: str) -> list[list[str]]:
    """The body rows of the Markdown table after ``<!-- marker -->``, as stripped cells."""
    start = TEXT.index(f"<!-- {marker} -->")
    lines = TEXT[start:].splitlines()[1:]
    rows = []
    for line in lines:
        if not line.startswith("|"):
            if rows:
                break
            continue
        cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        rows.append(cells)
    assert len(rows) > 2, f"no table after <!-- {marker} -->"
    return rows[2:]  # header and separator


def _code(cell: str) -> str:
    """The name in a cell like ``\\`wheel_diameter\\```."""
    match = re.fullmatch(r"`([^`]+)`", cell)
    assert match, f"expected a `name` cell, got {cell!r}"
    return match.group(1)


def _keyed(marker: str) -> dict[str, list[str]]:
    rows = _table(marker)
    table = {_code(row[0]): row for row in rows}
    assert len(table) == len(rows), f"a key is listed twice in <!-- {marker} -->"
    return table


# ---------------------------------------------------------------------- the examples load
def _assert_written(spec: Any, table: Mapping[str, Any], kind: str, base: Path) -> None:
    """Every value written in ``table`` is what the loaded ``spec`` holds (``base``: the
    directory of the file, against which a vehicle resolves a truck's relative path)."""
    for key, value in table.items():
        if kind == "vehicle spec" and key in TRUCKS:
            truck = getattr(spec, key)
            if isinstance(value, Mapping):  # an inline robot spec
                _assert_written(truck, value, "robot spec", base)
            elif value in PRESETS:
                assert truck == PRESETS[value], key
            else:  # a robot file next to the vehicle file
                assert truck == load_robot(base / value), key
        elif kind == "robot spec" and key == "effects":
            for name, values in value.items():
                stored = EFFECTS[name].read(spec)
                for param, number in values.items():
                    assert stored[param] == pytest.approx(number), f"effects.{name}.{param}"
        elif kind == "robot spec" and key in ("e_d", "e_b", "e_s"):
            assert getattr(spec, key) == pytest.approx(value, rel=1e-12), key
        elif kind == "floor spec" and key in ("bumps", "patches"):
            items = getattr(spec, key)
            assert len(items) == len(value)
            for item, written in zip(items, value, strict=True):
                for field, number in written.items():
                    assert getattr(item, field) == number, f"{key}.{field}"
        else:
            assert getattr(spec, key) == value, key


@pytest.mark.parametrize(
    ("kind", "text"), VALID, ids=[f"{k}-{i}" for i, (k, _) in enumerate(VALID)]
)
def test_example_loads_with_the_values_written(kind: str, text: str, tmp_path: Path) -> None:
    path = tmp_path / "example.toml"
    path.write_text(text, encoding="utf-8")
    spec = LOADERS[kind](str(path))
    data = tomllib.loads(text)
    table = data.get(TOP_TABLE[kind], data)
    assert len(table) >= 4, "a worked example should spell out its keys"
    _assert_written(spec, table, kind, tmp_path)


def test_every_schema_has_a_worked_example_and_an_error_example() -> None:
    assert {kind for kind, _ in VALID} == set(LOADERS)
    assert {kind for kind, *_ in INVALID} == set(LOADERS)


def test_the_worked_examples_carry_their_paper_values(tmp_path: Path) -> None:
    """Spot checks of the complete robot, floor, calibration and vehicle examples (the first of
    each)."""
    spec = {}
    for kind, text in VALID:
        if kind in spec:
            continue
        path = tmp_path / f"{TOP_TABLE[kind]}.toml"
        path.write_text(text, encoding="utf-8")
        spec[kind] = LOADERS[kind](str(path))
    robot: RobotSpec = spec["robot spec"]
    assert robot.true_wheelbase == 0.36898  # Chong & Kleeman 1997, Table 8, after calibration
    assert robot.effect_values("backlash") == {"angle": 0.004}
    floor: FloorSpec = spec["floor spec"]
    assert floor.roughness == FLOORS["concrete"].roughness
    assert len(floor.bumps) == 2 and floor.bumps[0].diameter == 0.010
    calibration: Calibration = spec["calibration file"]
    # Borenstein & Feng 1994, Eqs. 6.33-6.34 with E_d = 1.00084 (Fig. 6.5).
    assert calibration == Calibration.from_errors(e_d=1.00084, e_b=336.17 / 340.0)
    vehicle: VehicleSpec = spec["vehicle spec"]
    assert vehicle.truck_a == PRESETS["labmate"]  # Borenstein 1995, §2: LabMate trucks
    assert vehicle.truck_b.wheel_diameter == 0.15 and vehicle.truck_b.wheelbase == 0.34  # Table I
    assert vehicle.link_length == 1.0  # §3.3
    assert vehicle.sample_period == 0.04  # §4.1
    assert math.degrees(vehicle.rotary_resolution) == pytest.approx(0.35, abs=0.005)  # §2
    assert vehicle.linear_resolution == 1e-4  # §2
    assert vehicle.linear_bias == 0.002  # §5.2


# ---------------------------------------------------------------------- the errors are real
@pytest.mark.parametrize(
    ("kind", "name", "text", "quoted"), INVALID, ids=[name for _, name, _, _ in INVALID]
)
def test_quoted_error_is_what_the_loader_raises(
    kind: str, name: str, text: str, quoted: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    Path(name).write_text(text, encoding="utf-8")
    assert quoted.startswith(ERROR_PREFIX), quoted
    with pytest.raises(SpecError) as raised:
        LOADERS[kind](name)
    assert str(raised.value) == quoted.removeprefix(ERROR_PREFIX)


def _console_commands() -> list[tuple[str, str]]:
    """(command, expected output) for each console command the doc shows output for."""
    out = []
    for lang, body in _fences():
        if lang != "console":
            continue
        command, output = None, []
        for line in [*body.splitlines(), "$ "]:
            if line.startswith("$ "):
                if command is not None and output:
                    out.append((command, "\n".join(output)))
                command, output = line[2:], []
            else:
                output.append(line)
    return out


CONSOLE = _console_commands()


@pytest.mark.parametrize(("command", "expected"), CONSOLE, ids=[c for c, _ in CONSOLE])
def test_quoted_command_line_error_is_what_the_cli_prints(
    command: str,
    expected: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from odomgym.cli import main

    monkeypatch.chdir(tmp_path)
    for _, name, text, _ in INVALID:
        Path(name).write_text(text, encoding="utf-8")
    argv = shlex.split(command)
    assert argv[0] == "odomgym"
    assert main(argv[1:]) == 2
    assert capsys.readouterr().err.strip() == expected.strip()


def test_the_doc_shows_a_command_line_error() -> None:
    assert CONSOLE and all("odomgym: error:" in expected for _, expected in CONSOLE)


# ---------------------------------------------------------------------- the key tables
def _fields(kind: type[Any]) -> dict[str, dataclasses.Field[Any]]:
    return {f.name: f for f in dataclasses.fields(kind)}


def _robot_keys() -> set[str]:
    """RobotSpec's fields plus the error ratios ``from_dict`` hands to ``with_errors``."""
    ratios = set(inspect.signature(RobotSpec.with_errors).parameters) - {"self"}
    return set(_fields(RobotSpec)) | ratios


DATACLASS_TABLES = {
    "robot": RobotSpec,
    "floor": FloorSpec,
    "floor.bumps": CableBump,
    "floor.patches": FrictionPatch,
    "calibration": Calibration,
    "vehicle": VehicleSpec,
}


def test_robot_table_lists_exactly_the_keys_load_robot_accepts() -> None:
    assert set(_keyed("keys: robot")) == _robot_keys()


@pytest.mark.parametrize(
    "marker", ["floor", "floor.bumps", "floor.patches", "calibration", "vehicle"]
)
def test_table_lists_exactly_the_dataclass_fields(marker: str) -> None:
    assert set(_keyed(f"keys: {marker}")) == set(_fields(DATACLASS_TABLES[marker]))


@pytest.mark.parametrize("marker", sorted(DATACLASS_TABLES))
def test_documented_defaults_are_the_code_defaults(marker: str) -> None:
    """Column 4 (default): ``required`` for arguments without a default, the literal default
    otherwise (derived defaults, ``None`` in the signature, are described in words and not
    checked). Defaults come from the constructor's signature, generated or written out; the
    vehicle's trucks, required by ``VehicleSpec``, get their default from the loader."""
    rows = _keyed(f"keys: {marker}")
    parameters = inspect.signature(DATACLASS_TABLES[marker]).parameters
    for name in _fields(DATACLASS_TABLES[marker]):
        cell = rows[name][3]
        default = parameters[name].default
        if marker == "vehicle" and name in TRUCKS:
            truck = getattr(VehicleSpec.from_dict({}), name)
            assert truck == PRESETS[truck.name], name
            assert cell == f'`"{truck.name}"`', name
        elif default is inspect.Parameter.empty:
            assert cell == "required", name
        elif isinstance(default, str):
            assert cell == f'`"{default}"`', name
        elif isinstance(default, int | float) and not isinstance(default, bool):
            assert f"{default:g}" in cell, (name, cell)


def _builtin_effect_parameters() -> dict[tuple[str, str], Any]:
    """(effect, parameter) → Parameter for the catalogue shipped in ``odomgym.effects`` (effects
    other tests register at run time are left out)."""
    return {
        (name, p.name): p
        for name, effect in EFFECTS.items()
        if type(effect).__module__.startswith("odomgym.effects.")
        for p in effect.parameters
    }


def test_effects_table_matches_the_catalogue() -> None:
    """Every parameter of every shipped effect, with its unit, absent value and range."""
    rows = _table("keys: robot.effects")
    documented = {(_code(row[0]), _code(row[1])): row for row in rows}
    assert len(documented) == len(rows)
    expected = _builtin_effect_parameters()
    assert set(documented) == set(expected)
    for key, p in expected.items():
        row = documented[key]
        assert row[3] == p.unit, key
        assert row[4] == f"{p.absent:g}", key
        assert row[5] == f"[{p.low:g}, {p.high:g}]", key


def _one_key(marker: str, key: str, type_cell: str) -> tuple[Callable[[str], Any], str]:
    """A minimal valid file that sets documented ``key`` (of type ``type_cell``)."""
    value = '"x"' if type_cell == "string" else "0.3"
    if marker == "vehicle":
        value = "12" if type_cell == "int" else VEHICLE_VALUES.get(key, value)
    if marker == "robot":  # a systematic error is a factor near 1 (true/nominal within 0.5–2)
        value = {"e_d": "1.01", "e_b": "0.98", "e_s": "1.02"}.get(key, value)
    if marker == "floor" and key == "roughness":
        value = "0.002"  # the rough preset (at most MAX_ROUGHNESS = 0.1)
    line = f"{key} = {value}\n"
    if marker == "robot" and key in ("com_x", "com_y"):  # a skid-steer robot's, loading each wheel
        line = f"axle_spacing = 0.3\n{key} = 0.05\n"
    if marker == "robot" and key.startswith("tyre_"):  # a skid-steer robot's, both or neither
        line = "axle_spacing = 0.3\ntyre_slip_stiffness = 20.0\ntyre_cornering_stiffness = 7.0\n"
    if marker == "robot":
        return load_robot, MINIMAL_ROBOT + ("" if key in REQUIRED_ROBOT else line)
    if marker == "floor":
        return load_floor, "[floor]\n" + line
    if marker == "floor.bumps":
        return load_floor, MINIMAL_BUMP + ("" if key in ("x", "y") else line)
    if marker == "floor.patches":
        return load_floor, MINIMAL_PATCH  # every patch key is required, so all are set
    if marker == "vehicle":
        return load_vehicle, "[vehicle]\n" + line
    return load_calibration, "[calibration]\n" + line


@pytest.mark.parametrize("marker", sorted(DATACLASS_TABLES))
def test_every_documented_scalar_key_is_accepted_by_its_loader(marker: str, tmp_path: Path) -> None:
    checked = 0
    for key, row in _keyed(f"keys: {marker}").items():
        if row[1] not in ("float", "int", "string"):
            continue  # tables, arrays of tables, trucks: the worked examples load them
        loader, text = _one_key(marker, key, row[1])
        path = tmp_path / f"{marker}-{key}.toml"
        path.write_text(text, encoding="utf-8")
        spec = loader(str(path))
        if marker == "vehicle":
            assert getattr(spec, key) == tomllib.loads(text)["vehicle"][key], key
        checked += 1
    assert checked >= 4 or marker == "floor"


def test_every_documented_effect_parameter_is_accepted(tmp_path: Path) -> None:
    for (effect, param), p in _builtin_effect_parameters().items():
        path = tmp_path / f"{effect}-{param}.toml"
        middle = 0.5 * (p.low + p.high)
        path.write_text(
            f"{MINIMAL_ROBOT}\n[effects.{effect}]\n{param} = {middle!r}\n", encoding="utf-8"
        )
        load_robot(str(path))


def test_an_undocumented_key_is_rejected(tmp_path: Path) -> None:
    """The loaders reject keys outside the tables (so the tables are the whole schema)."""
    cases = [
        (load_robot, MINIMAL_ROBOT + "wheel_base = 0.3\n"),
        (load_floor, "[floor]\nbump = 1.0\n"),
        (load_floor, MINIMAL_BUMP + "width = 1.0\n"),
        (load_calibration, "[calibration]\nc_rigth = 1.0\n"),
        (load_robot, MINIMAL_ROBOT + "[effects.backlash]\nwidth = 0.1\n"),
        (load_vehicle, "[vehicle]\nlink_lenght = 1.0\n"),
        (load_vehicle, "[vehicle.truck_b]\n" + MINIMAL_ROBOT + "wheel_base = 0.3\n"),
    ]
    for index, (loader, text) in enumerate(cases):
        path = tmp_path / f"bad{index}.toml"
        path.write_text(text, encoding="utf-8")
        with pytest.raises(SpecError, match="unknown"):
            loader(str(path))


def test_a_truck_is_a_preset_a_file_next_to_the_vehicle_or_a_table(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The ``truck_a`` / ``truck_b`` row: a preset name, a robot file relative to the vehicle
    file (not to the working directory), or an inline robot table."""
    folder = tmp_path / "vehicles"
    folder.mkdir()
    (folder / "rear.toml").write_text(f'[robot]\nname = "rear"\n{MINIMAL_ROBOT}', encoding="utf-8")
    monkeypatch.chdir(tmp_path)  # rear.toml is not in the working directory
    cases = {
        'truck_a = "navbot"\ntruck_b = "rear.toml"\n': ("navbot", "rear"),
        f'truck_a = "monash"\n[vehicle.truck_b]\nname = "inline"\n{MINIMAL_ROBOT}': (
            "monash",
            "inline",
        ),
    }
    for index, (body, names) in enumerate(cases.items()):
        path = folder / f"vehicle{index}.toml"
        path.write_text(f"[vehicle]\n{body}", encoding="utf-8")
        vehicle = load_vehicle(str(path.relative_to(tmp_path)))
        assert (vehicle.truck_a.name, vehicle.truck_b.name) == names
        assert vehicle.truck_a == PRESETS[names[0]]
    assert load_vehicle("vehicles/vehicle0.toml").truck_b == load_robot(folder / "rear.toml")


# ---------------------------------------------------------------------- presets
def test_robot_presets_table_matches_odomgym_presets() -> None:
    rows = _keyed("presets: robot")
    assert set(rows) == set(PRESETS)
    for name, spec in PRESETS.items():
        row = rows[name]
        assert row[1:4] == [
            f"{spec.wheel_diameter:g}",
            f"{spec.wheelbase:g}",
            f"{spec.ticks_per_rev:g}",
        ], name
        assert row[4:7] == [f"{spec.e_d:.5f}", f"{spec.e_b:.5f}", f"{spec.e_s:.5f}"], name


def test_floor_presets_table_matches_odomgym_floors() -> None:
    rows = _keyed("presets: floor")
    assert set(rows) == set(FLOORS)
    for name, floor in FLOORS.items():
        row = rows[name]
        assert row[1:4] == [f"{floor.friction:g}", f"{floor.roughness:g}", str(len(floor.bumps))]


def test_vehicle_presets_table_matches_odomgym_vehicles() -> None:
    rows = _keyed("presets: vehicle")
    assert set(rows) == set(VEHICLES)
    for name, vehicle in VEHICLES.items():
        row = rows[name]
        assert row[1:3] == [f"`{vehicle.truck_a.name}`", f"`{vehicle.truck_b.name}`"], name
        known = {**PRESETS, "encoder-trailer": ENCODER_TRAILER}
        known.update({f"{k}-calibrated": calibrated(v) for k, v in PRESETS.items()})
        assert vehicle.trucks == (known[vehicle.truck_a.name], known[vehicle.truck_b.name])
        numbers = (
            vehicle.link_length,
            vehicle.link_min,
            vehicle.link_max,
            vehicle.sample_period,
            vehicle.rotary_bits,
            vehicle.linear_resolution,
        )
        assert row[3:9] == [f"{x:g}" for x in numbers], name
        if "no encoder biases" in row[9]:  # the source column says so
            biases = (vehicle.rotary_bias_a, vehicle.rotary_bias_b, vehicle.linear_bias)
            assert biases == (0.0, 0.0, 0.0), name


# ---------------------------------------------------------------------- passing a spec
def test_envs_take_the_example_files_as_strings(tmp_path: Path) -> None:
    """The Python section: ``gymnasium.make(..., robot=, floor=, calibration=)`` with paths."""
    import gymnasium  # odomgym registered its envs when the loaders were imported

    paths = {}
    for kind, text in VALID:
        if kind not in paths:
            paths[kind] = tmp_path / f"{TOP_TABLE[kind]}.toml"
            paths[kind].write_text(text, encoding="utf-8")
    env = gymnasium.make(
        "UMBmarkSquare-v0",
        robot=str(paths["robot spec"]),
        floor=str(paths["floor spec"]),
        calibration=str(paths["calibration file"]),
    )
    try:
        assert env.unwrapped.robot == load_robot(str(paths["robot spec"]))
        assert env.unwrapped.floor == load_floor(str(paths["floor spec"]))
        assert env.unwrapped.calibration == load_calibration(str(paths["calibration file"]))
    finally:
        env.close()
    # The vehicle section: gymnasium.make("ClapperStraight-v0", vehicle="my_vehicle.toml").
    env = gymnasium.make("ClapperStraight-v0", vehicle=str(paths["vehicle spec"]))
    try:
        assert env.unwrapped.vehicle == load_vehicle(str(paths["vehicle spec"]))
    finally:
        env.close()

"""The house rules of ``docs/architecture.md``, checked on the import graph.

Every ``import`` counts — at module level, inside functions (lazy) and under
``TYPE_CHECKING`` — because each is a dependency a reader must follow. The rules:

* no import cycle between modules (a package's ``__init__`` importing its own submodules is not
  a cycle: the submodules must not import the package's ``__init__`` back);
* layers, lowest first: the core (``odomgym.*``), the envs (``odomgym.envs``), the baselines
  (``odomgym.baselines``), the command line (``odomgym.cli``); a module imports only its own
  layer and the ones below;
* inside the core, a folder per layer: each room (a top-level module or a subpackage of
  ``odomgym``) stands in one tier of :data:`PACKAGE_LAYERS` and imports only rooms of lower
  tiers, so the tree itself draws the architecture (``docs/architecture.md``);
* importing an env imports neither the benchmark runner nor Ray.
"""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

LAYERS = ("odomgym", "odomgym.envs", "odomgym.baselines", "odomgym.cli")
ENTRY_POINTS = {"odomgym.__main__": "odomgym.cli"}  # ``python -m odomgym`` is the command line

# The rooms of the package, lowest tier first; a room imports only rooms of lower tiers (two
# rooms of one tier never import each other). A room is a top-level module of ``odomgym``
# (``errors``), one of its subpackages (``sim``: every module in ``odomgym/sim/``), the
# package's own ``__init__`` (``odomgym``: the public names) or one of the three upper layers.
PACKAGE_LAYERS: tuple[frozenset[str], ...] = tuple(
    frozenset(tier.split())
    for tier in (
        "errors io interrupt _jit _source_tree",  # no odomgym import but one another's
        "workers distributed effects floor _kernels",  # worker pool, Ray backend, effects, kernels
        "robot",  # RobotSpec: nominal vs true
        "odometry",  # dead reckoning, runs and their measures: no simulator
        "data odomgym",  # measured logs; the package's public names
        "sim",  # the World and what drives a robot through it
        "lab",  # experiments, simulated and recorded labs, plans, the population
        "vehicle selfcal",  # the two-truck vehicle; the self-calibration session
        "diagnose noise",  # the discrepancy workflow; the random error and its fit
        "design",  # which experiments identify which catalogue effects (issue 45)
        "envs",
        "baselines",
        "cli",
    )
)
# The modules that stay at the top level of ``odomgym/``: the foundation below every layer
# folder, and the two specs every layer reads.
TOP_LEVEL = {
    "odomgym.__main__",
    "odomgym._jit",
    "odomgym._kernels",
    "odomgym._source_tree",
    "odomgym.errors",
    "odomgym.interrupt",
    "odomgym.io",
    "odomgym.workers",
    "odomgym.distributed",
    "odomgym.robot",
    "odomgym.floor",
}


def _modules() -> dict[str, Path]:
    """Every module of the package and its file. ``odomgym.envs`` and ``odomgym.baselines``
    are folders of their own in a source checkout (``package-dir``), so each root is walked."""
    out: dict[str, Path] = {}
    for root in ("odomgym", "odomgym.envs", "odomgym.baselines"):
        for folder in importlib.import_module(root).__path__:
            for path in sorted(Path(folder).rglob("*.py")):
                parts = path.relative_to(folder).with_suffix("").parts
                if parts[-1] == "__init__":
                    parts = parts[:-1]
                out[".".join((root, *parts))] = path
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The package's modules that ``name`` imports, anywhere in its file."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([base] if base else []))
            targets = [f"{base}.{alias.name}" for alias in node.names]
            # ``from package import module`` depends on the module; ``from package import
            # name`` on the package's ``__init__``.
            if any(target not in modules for target in targets):
                targets.append(base)
        for target in targets:
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    # A package's __init__ may import its own submodules (it assembles them).
    if path.name == "__init__.py":
        found = {t for t in found if not t.startswith(name + ".")}
    return found


def _layer(name: str) -> int:
    name = ENTRY_POINTS.get(name, name)
    return max(
        i for i, prefix in enumerate(LAYERS) if name == prefix or name.startswith(prefix + ".")
    )


def _room(name: str) -> str:
    """The room of a module: an upper layer, the package's ``__init__``, a top-level module or
    a subpackage of ``odomgym``."""
    name = ENTRY_POINTS.get(name, name)
    if name == "odomgym":
        return "odomgym"
    return name.split(".")[1]


def _tier(room: str) -> int:
    return next(i for i, tier in enumerate(PACKAGE_LAYERS) if room in tier)


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def test_the_walk_sees_every_layer() -> None:
    graph = _graph()
    assert len(graph) > 80
    assert {_layer(name) for name in graph} == set(range(len(LAYERS)))


def test_no_import_cycle() -> None:
    graph = _graph()
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    assert cycles == []


def test_no_module_imports_a_higher_layer() -> None:
    graph = _graph()
    upward = sorted(
        f"{a} -> {b}" for a, targets in graph.items() for b in targets if _layer(b) > _layer(a)
    )
    assert upward == []


def test_every_room_stands_in_one_tier() -> None:
    rooms = {_room(name) for name in _graph()}
    placed = [room for tier in PACKAGE_LAYERS for room in tier]
    assert len(placed) == len(set(placed))
    assert sorted(rooms - set(placed)) == []


def test_each_layer_is_a_folder() -> None:
    """Below the package's ``__init__``, only the foundation modules stay at the top level of
    ``odomgym/``; every other module lives in the folder of its layer."""
    top = {
        name
        for name, path in _modules().items()
        if name.count(".") == 1 and path.name != "__init__.py"
    }
    assert top == TOP_LEVEL


def test_no_room_imports_a_room_of_its_tier_or_above() -> None:
    graph = _graph()
    upward = sorted(
        f"{a} -> {b}"
        for a, targets in graph.items()
        for b in targets
        if _room(a) != _room(b) and _tier(_room(b)) >= _tier(_room(a))
    )
    assert upward == []


def test_importing_an_env_imports_no_benchmark_runner_nor_ray() -> None:
    code = (
        "import sys, gymnasium as gym, odomgym.envs\n"
        "for env_id in ('UMBmarkSquare-v0', 'SelfCalibration-v1', 'ClapperStraight-v0'):\n"
        "    gym.make(env_id).reset(seed=0)\n"
        "print(sorted(m for m in sys.modules if m.startswith('odomgym.baselines') or m == 'ray'))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300
    )
    assert out.stdout.strip() == "[]"

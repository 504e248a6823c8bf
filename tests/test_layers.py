"""The house in layers: every project import points down (docs/design.md, "The shape of the house").

1. ``uav_model``: the shared model (frames, mission schema and loader, world, plant).
2. ``companion.planning`` (the pure core) and ``sim_bridge`` (the stub), side by side, each in
   sub-rooms, lowest first:
   - planning: the core (grid, A*, DWA, vehicle planner, scoring), then ``coordination`` (timed
     routes, the space-time plan, the occlusion certificate, the schedule clocks and in-flight
     re-plans), then ``flight`` (a mission's fleet of planners, the headless runner, the flown
     forecast);
   - the stub: ``sim_bridge.vehicle`` (the simulated autopilot), then the bridge around it.
3. The companion app, in sub-rooms, lowest first: errors; the vehicle port and MAVSDK adapter;
   plots, scenarios and file formats; the app (pilot, flight plan, results); replays.
4. The top, which may import anything: the CLI and its commands, ``companion.sitl``
   (embedded stub, in-process adapter), the pytest plugin, the bench.

Every import counts, wherever it stands: at module level, inside a function, and under
``if TYPE_CHECKING:`` (a type that points up is still a dependency). Within a room no file takes
part in an import cycle; a cycle is judged on the imports that run (module level and inside
functions), since an import made only for type checking executes nothing.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# (module prefix, layer, wing, rank, room); the longest matching prefix wins. Within a layer, a
# room may import the rooms of its own wing with a lower rank, and nothing else of that layer
# (layer 4 excepted: the top may import anything).
ROOMS: tuple[tuple[str, int, str, int, str], ...] = (
    ("uav_model", 1, "model", 0, "model"),
    ("companion.planning", 2, "planning", 0, "planning core"),
    ("companion.planning.coordination", 2, "planning", 1, "coordination"),
    ("companion.planning.flight", 2, "planning", 2, "flight"),
    ("sim_bridge.vehicle", 2, "stub", 0, "simulated vehicle"),
    ("sim_bridge", 2, "stub", 1, "bridge"),
    ("companion", 3, "app", 2, "app misc"),
    ("companion.errors", 3, "app", 0, "errors"),
    ("companion.vehicle", 3, "app", 1, "vehicle port"),
    ("companion.plots", 3, "app", 2, "plots"),
    ("companion.scenarios", 3, "app", 2, "scenarios"),
    ("companion.formats", 3, "app", 2, "formats"),
    ("companion.app", 3, "app", 3, "app"),
    ("companion.replay", 3, "app", 3, "replay"),
    ("companion.cli", 4, "top", 0, "top"),
    ("companion.__main__", 4, "top", 0, "top"),
    ("companion.sitl", 4, "top", 0, "top"),
    ("companion.testing", 4, "top", 0, "top"),
    ("companion.bench", 4, "top", 0, "top"),
)


def room_of(module: str) -> tuple[int, str, int, str] | None:
    best: tuple[str, int, str, int, str] | None = None
    for entry in ROOMS:
        prefix = entry[0]
        if (module == prefix or module.startswith(prefix + ".")) and (best is None or len(prefix) > len(best[0])):
            best = entry
    return None if best is None else best[1:]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _type_checking_lines(tree: ast.AST) -> set[int]:
    """The lines of every import under ``if TYPE_CHECKING:``."""
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for inner in node.body:
                lines.update(n.lineno for n in ast.walk(inner) if isinstance(n, (ast.Import, ast.ImportFrom)))
    return lines


def imported_modules(path: Path, module: str, *, runtime_only: bool = False) -> list[tuple[int, str]]:
    """Every module ``path`` imports, with its line: at module level and inside functions alike
    (``runtime_only``: without the imports made only under ``if TYPE_CHECKING:``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    typing_only = _type_checking_lines(tree) if runtime_only else set()
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if getattr(node, "lineno", None) in typing_only:
            continue
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.append((node.lineno, target))
            # `from pkg import sub` may name a submodule: judge it by its own room.
            found.extend((node.lineno, f"{target}.{alias.name}") for alias in node.names)
    return found


def product_modules() -> list[Path]:
    return sorted(p for pkg in ("uav_model", "companion", "sim_bridge") for p in (ROOT / pkg).rglob("*.py"))


def violations(path: Path, module: str | None = None) -> list[str]:
    module = module or module_name(path)
    mine = room_of(module)
    assert mine is not None, f"{module} is in no room: add it to ROOMS"
    bad = []
    for line, target in imported_modules(path, module):
        theirs = room_of(target)
        if theirs is None or theirs[3] == mine[3]:
            continue
        if theirs[0] > mine[0]:
            why = "up a layer"
        elif theirs[0] < mine[0] or mine[0] == 4:
            continue
        elif theirs[1] != mine[1]:
            why = "sideways, to another wing"
        elif theirs[2] >= mine[2]:
            why = "sideways" if theirs[2] == mine[2] else "up a room"
        else:
            continue
        bad.append(f"{path.name}:{line}: {module} ({mine[3]}, layer {mine[0]}) imports "
                   f"{target} ({theirs[3]}, layer {theirs[0]}): {why}")
    return bad


def import_graph(paths: list[Path]) -> dict[str, set[str]]:
    """Module -> the product modules it imports where it runs (a package stands for its
    ``__init__``; a name taken from a package that is no module of its own is the package)."""
    modules = {module_name(p): p for p in paths}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        graph[name] = set()
        for _, target in imported_modules(path, name, runtime_only=True):
            # A module's own packages are run before it: importing one is no edge of its own.
            if target in modules and target != name and not name.startswith(target + "."):
                graph[name].add(target)
        # Importing a.b.c runs a/__init__ and a/b/__init__ first.
        for target in list(graph[name]):
            parts = target.split(".")
            graph[name].update(".".join(parts[:k]) for k in range(1, len(parts))
                               if ".".join(parts[:k]) in modules and ".".join(parts[:k]) != name
                               and not name.startswith(".".join(parts[:k]) + "."))
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
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
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


@cache
def _product_graph() -> dict[str, set[str]]:
    return import_graph(product_modules())


def test_every_product_module_is_in_a_room() -> None:
    assert product_modules(), "no product modules found"
    for path in product_modules():
        assert room_of(module_name(path)) is not None, path


@pytest.mark.parametrize("path", product_modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_point_down(path: Path) -> None:
    assert violations(path) == []


def test_no_product_file_takes_part_in_an_import_cycle() -> None:
    assert cycles(_product_graph()) == []


def test_the_check_catches_upward_and_sideways_imports(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    probe.write_text("from companion.planning import astar\nimport sim_bridge.vehicle\nimport numpy\n")
    assert len(violations(probe, "uav_model.probe")) == 3  # the package, its submodule, and the stub
    assert len(violations(probe, "companion.planning.probe")) == 1  # planning beside the stub
    assert violations(probe, "companion.sitl.probe") == []  # the top may import anything


def test_the_check_catches_imports_up_the_sub_rooms(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    probe.write_text("def later():\n    from companion.app import pilot\n")
    assert len(violations(probe, "companion.formats.probe")) == 2  # inside a function too
    assert len(violations(probe, "companion.vehicle.probe")) == 2
    assert len(violations(probe, "companion.replay")) == 2  # beside the app, not above it
    down = tmp_path / "down.py"
    down.write_text("from companion.formats import qgc_plan\nfrom companion.vehicle import port\n")
    assert violations(down, "companion.app.probe") == []  # the app stands on the formats and the port
    core = tmp_path / "core.py"
    core.write_text("from companion.planning.coordination.plan import Blocking\n"
                    "from companion.planning.flight import headless\n")
    assert len(violations(core, "companion.planning.grid")) == 4  # each package and what it names
    assert len(violations(core, "companion.planning.coordination.certificate")) == 2  # flight is above it
    assert len(violations(core, "companion.planning.flight.fleet_setup")) == 0


def test_the_cycle_check_counts_imports_inside_functions(tmp_path: Path) -> None:
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "a.py").write_text("import pkg.b\n")
    (tmp_path / "pkg" / "b.py").write_text("def late():\n    from pkg import a\n")
    (tmp_path / "pkg" / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import pkg.a\n")
    graph = {"pkg.a": {"pkg.b"}, "pkg.b": set(), "pkg.c": set()}
    for name in ("b", "c"):
        path = tmp_path / "pkg" / f"{name}.py"
        graph[f"pkg.{name}"] = {t for _, t in imported_modules(path, f"pkg.{name}", runtime_only=True)
                                if t in graph}
    assert cycles(graph) == [["pkg.a", "pkg.b"]]  # the type-only import of c closes no cycle

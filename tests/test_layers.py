"""The house in layers: every project import points down (docs/design.md, "The shape of the house").

1. ``uav_model``: the shared model (frames, mission schema and loader, world, plant).
2. ``companion.planning`` (the pure core) and ``sim_bridge`` (the stub), side by side.
3. The companion app: vehicle port and MAVSDK adapter, pilot, scenarios, plots, errors.
4. The top, which may import anything: the CLI and its commands, ``companion.sitl``
   (embedded stub, in-process adapter), the pytest plugin, the bench.

Imports inside ``if TYPE_CHECKING:`` count too: a type that points up is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# (module prefix, layer, room); the longest matching prefix wins.
ROOMS: tuple[tuple[str, int, str], ...] = (
    ("uav_model", 1, "model"),
    ("companion.planning", 2, "planning"),
    ("sim_bridge", 2, "stub"),
    ("companion", 3, "app"),
    ("companion.cli", 4, "top"),
    ("companion.__main__", 4, "top"),
    ("companion.sitl", 4, "top"),
    ("companion.testing", 4, "top"),
    ("companion.bench", 4, "top"),
)


def room_of(module: str) -> tuple[int, str] | None:
    best: tuple[str, int, str] | None = None
    for prefix, layer, room in ROOMS:
        if (module == prefix or module.startswith(prefix + ".")) and (best is None or len(prefix) > len(best[0])):
            best = (prefix, layer, room)
    return None if best is None else (best[1], best[2])


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(path: Path, module: str) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
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
        if theirs is None or theirs[1] == mine[1]:
            continue
        points_up = theirs[0] > mine[0]
        sideways = theirs[0] == mine[0] and mine[0] < 4
        if points_up or sideways:
            bad.append(f"{path.name}:{line}: {module} ({mine[1]}, layer {mine[0]}) imports "
                       f"{target} ({theirs[1]}, layer {theirs[0]})")
    return bad


def test_every_product_module_is_in_a_room() -> None:
    assert product_modules(), "no product modules found"
    for path in product_modules():
        assert room_of(module_name(path)) is not None, path


@pytest.mark.parametrize("path", product_modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_point_down(path: Path) -> None:
    assert violations(path) == []


def test_the_check_catches_upward_and_sideways_imports(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    probe.write_text("from companion.planning import astar\nimport sim_bridge.vehicle\nimport numpy\n")
    assert len(violations(probe, "uav_model.probe")) == 3  # the package, its submodule, and the stub
    assert len(violations(probe, "companion.planning.probe")) == 1  # planning beside the stub
    assert violations(probe, "companion.sitl.probe") == []  # the top may import anything

"""The house: every import of the planner runs down a floor (or stays in its room), never up.

The floors, bottom to top, follow the flow scenario -> robot / world -> goals -> search -> smooth -> timing
-> gate -> profile (README, Layout). The API sits above the whole planner.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
FLOORS = (
    "core",
    "kinematics",
    "robots",
    "dynamics",
    "meshio",
    "meshes",
    "collision",
    "redundancy",
    "timing",
    "scenario",
    "gate",
    "plan",
    "task",
    "documents",
    "tools",
    "generate",
    "sweep",
    "campaign",
    "cli",
)
#: Engines and edge libraries, and the only rooms that may import them.
ENGINES = {
    "ompl": ("planner.plan.ompl_adapter",),
    "matplotlib": ("planner.documents", "planner.sweep.plots"),
    "fastapi": (),
    "typer": ("planner.cli",),
    "api": (),
}


def _modules() -> dict[str, Path]:
    out = {}
    for path in (ROOT / "planner").rglob("*.py"):
        mod = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        out[mod.removesuffix(".__init__")] = path
    return out


def _imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


def _room(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def test_every_room_is_on_a_floor() -> None:
    rooms = {_room(m) for m in _modules()} - {"", "__init__"}
    assert rooms <= set(FLOORS), f"rooms without a floor: {sorted(rooms - set(FLOORS))}"


def test_no_import_runs_up_a_floor() -> None:
    upward = []
    for mod, path in _modules().items():
        here = _room(mod)
        if here not in FLOORS:
            continue
        for name in _imports(path):
            if not name.startswith("planner."):
                continue
            there = _room(name)
            if there in FLOORS and FLOORS.index(there) > FLOORS.index(here):
                upward.append(f"{mod} -> {name}")
    assert not upward, "imports running up a floor:\n" + "\n".join(sorted(upward))


@pytest.mark.parametrize("engine", sorted(ENGINES))
def test_engines_are_imported_by_their_adapters_only(engine: str) -> None:
    allowed = ENGINES[engine]
    offenders = [
        mod
        for mod, path in _modules().items()
        if any(n == engine or n.startswith(engine + ".") for n in _imports(path))
        and not any(mod == a or mod.startswith(a + ".") for a in allowed)
    ]
    assert not offenders, f"{engine} imported outside {allowed}: {offenders}"

"""No import circles: no module of planner/ or api/ reaches itself through the imports it runs.

Every ``import`` and ``from ... import`` counts, at module level and inside functions (a function-level
import only postpones a circle: the two modules still cannot be read, tested or replaced apart). Imports
under ``if TYPE_CHECKING:`` never run and are left out. ``from package import name`` counts as an import
of the submodule when ``name`` is one, else of the package's ``__init__``; the implicit import of a
module's parent packages is not an edge (a package's ``__init__`` re-exporting its submodules would
otherwise be a circle of every package).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("planner", "api")


def _modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            out[name.removesuffix(".__init__")] = path
    return out


def _type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imported(module: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Modules of planner/ and api/ that ``module`` imports when it runs (module level and in functions)."""
    names: set[str] = set()
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _type_checking(child):
                for other in child.orelse:
                    visit_node(other)
                continue
            visit_node(child)

    def visit_node(node: ast.AST) -> None:
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: resolved against the module's package
                parent = package[: len(package) - node.level + 1]
                base = ".".join([*parent, base] if base else parent)
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                names.add(sub if sub in modules else base)
        visit(node)

    visit(ast.parse(path.read_text(encoding="utf-8")))
    out = set()
    for name in names:
        while name and name not in modules:  # ``import a.b.c`` of a module a.b's attribute: a.b
            name = name.rpartition(".")[0]
        if name and name != module:
            out.add(name)
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the modules of planner/ and api/ it imports."""
    modules = _modules()
    return {module: _imported(module, path, modules) for module, path in modules.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0

    def connect(v: str) -> None:
        nonlocal counter
        index[v] = low[v] = counter
        counter += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                connect(w)
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
            connect(v)
    return found


def test_the_cycle_finder_finds_module_and_function_level_circles() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert cycles(graph) == [["a", "b", "c"]]
    # The real graph has the edges the finder must see: a module-level and a function-level import.
    real = import_graph()
    assert "planner.robots.cabin8_geometry" in real["planner.robots.cabin8"]  # module level
    assert "planner.plan.pipeline" in real["planner.sweep.task"]  # inside plan_outcome()
    assert "planner.robots.cabin8" not in real["planner.robots.cabin8_geometry"]  # TYPE_CHECKING only


def test_no_import_circles() -> None:
    found = cycles(import_graph())
    assert not found, "import circles:\n" + "\n".join(" <-> ".join(c) for c in found)


#: The only modules that import by name: the lazy public API (``planner.X`` resolved on first use) and the
#: stand-in that defers toppra's eager matplotlib import. Everything else names what it runs by the
#: object itself (job kinds, pool workers, sweep tasks), so a reader can follow it and a checker sees it.
IMPORT_BY_NAME = {"planner", "planner.core.lazy"}


def test_nothing_imports_by_name_outside_the_lazy_modules() -> None:
    offenders = set()
    for name, path in _modules().items():
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            called = node.func if isinstance(node, ast.Call) else None
            spelled = (
                called.attr
                if isinstance(called, ast.Attribute)
                else getattr(called, "id", None)
                if called
                else None
            )
            if spelled in {"import_module", "__import__", "resolve_name"}:
                offenders.add(name)
    assert offenders <= IMPORT_BY_NAME, sorted(offenders - IMPORT_BY_NAME)
    assert offenders == IMPORT_BY_NAME  # the allowed ones still do (else the set above is stale)

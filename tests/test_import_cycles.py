"""No import circles among the project's modules: every import, read with ``ast``, draws an edge
from the importing module to the project module it names, and the graph has no cycle.

Imports inside functions count (a lazy import is still a dependency, and a circle closed by one
is still a circle: each module needs the other); imports under ``if TYPE_CHECKING:`` do not (they
never run). ``from package import name`` is an edge to the submodule ``package.name`` where there is
one, else to the package.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("runtime", "behaviors", "policy", "recording", "sim", "evaluation")


def project_modules(root: Path) -> dict[str, Path]:
    """Dotted module name -> file, for every module of the project's packages under ``root``."""
    modules = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def is_type_checking(test: ast.expr) -> bool:
    return ((isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
            or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))


def imports_that_run(node: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement below ``node``, leaving out the bodies of ``if TYPE_CHECKING:``."""
    found = []
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.Import, ast.ImportFrom)):
            found.append(child)
        elif isinstance(child, ast.If) and is_type_checking(child.test):
            for other in child.orelse:
                found += imports_that_run(other) if not isinstance(other, (ast.Import, ast.ImportFrom)) else [other]
        else:
            found += imports_that_run(child)
    return found


def import_graph(root: Path) -> dict[str, set[str]]:
    """Module -> the project modules it imports (itself left out)."""
    modules = project_modules(root)

    def known(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
        edges = set()
        for node in imports_that_run(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                edges |= {known(alias.name) for alias in node.names}
                continue
            base = (".".join(package[: len(package) - node.level + 1] + ([node.module] if node.module else []))
                    if node.level else node.module or "")
            edges |= {f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else known(base) for alias in node.names}
        graph[module] = {edge for edge in edges if edge and edge != module}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected sets of more than one module (Tarjan), each as a closed path
    ``a -> b -> ... -> a`` through its modules, sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[set[str]] = []

    def visit(module: str) -> None:
        index[module] = low[module] = len(index)
        stack.append(module)
        on_stack.add(module)
        for other in sorted(graph.get(module, ())):
            if other not in index:
                visit(other)
                low[module] = min(low[module], low[other])
            elif other in on_stack:
                low[module] = min(low[module], index[other])
        if low[module] == index[module]:
            component = set()
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.add(member)
                if member == module:
                    break
            if len(component) > 1:
                components.append(component)

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return sorted(closed_path(graph, component) for component in components)


def closed_path(graph: dict[str, set[str]], component: set[str]) -> list[str]:
    """A path from the component's first module back to itself, inside the component."""
    start = min(component)
    came_from = {start: start}
    frontier = [start]
    while frontier:
        module = frontier.pop(0)
        for other in sorted(graph[module] & component):
            if other == start:
                path = [module]
                while path[-1] != start:
                    path.append(came_from[path[-1]])
                return [start, *reversed(path[:-1]), start]
            if other not in came_from:
                came_from[other] = module
                frontier.append(other)
    raise AssertionError(f"no way back to {start} in {sorted(component)}")


def test_no_module_of_the_project_imports_itself_through_others():
    assert [" -> ".join(cycle) for cycle in import_cycles(import_graph(ROOT))] == []


def test_the_graph_holds_the_imports_of_the_real_packages():
    """The check reads the real packages (an empty graph would pass vacuously)."""
    graph = import_graph(ROOT)
    assert "runtime.tree.behavior" in graph["runtime.app.runner"]
    assert "behaviors.execute_policy.tail" in graph["behaviors.execute_policy.seam"]
    assert "runtime.app.world" in graph["runtime.app.world_check"]  # a lazy import, inside a function


def write_modules(root: Path, files: dict[str, str]) -> None:
    for package in PACKAGES:
        (root / package).mkdir(parents=True, exist_ok=True)
        (root / package / "__init__.py").write_text("")
    for name, source in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(source)


@pytest.mark.parametrize("files, cycle", [
    ({"sim/a.py": "from .b import x\n", "sim/b.py": "def f():\n    from sim.a import y\n"},
     ["sim.a", "sim.b", "sim.a"]),
    ({"runtime/p/__init__.py": "from .q import Q\n", "runtime/p/q.py": "from runtime.p import P\n"},
     ["runtime.p", "runtime.p.q", "runtime.p"]),
    ({"evaluation/a.py": "import evaluation.b\n", "evaluation/b.py": "from evaluation import c\n",
      "evaluation/c.py": "from . import a\n"},
     ["evaluation.a", "evaluation.b", "evaluation.c", "evaluation.a"]),
])
def test_a_circle_is_named_as_a_path_through_its_modules(tmp_path, files, cycle):
    write_modules(tmp_path, files)
    assert import_cycles(import_graph(tmp_path)) == [cycle]


@pytest.mark.parametrize("files", [
    {"sim/a.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import B\n", "sim/b.py": "from .a import A\n"},
    {"runtime/p/__init__.py": "from .q import Q\n", "runtime/p/q.py": "from . import r\n", "runtime/p/r.py": ""},
])
def test_type_only_imports_and_sibling_submodules_make_no_circle(tmp_path, files):
    write_modules(tmp_path, files)
    assert import_cycles(import_graph(tmp_path)) == []

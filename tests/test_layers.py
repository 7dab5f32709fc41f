"""Dependencies flow one way: every import of every module, read with ``ast``, stays inside the
layers its package may use.

    runtime    the engine: imports only itself
    behaviors  -> runtime
    policy     -> runtime                     (runs beside a real robot: nothing simulated)
    sim        -> runtime, behaviors, policy   (the worked example)

``tests``, ``benchmarks`` and ``tools`` sit on top and may import anything; no layer imports them.
Imports inside functions count: a lazy import is still a dependency.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALLOWED = {
    "runtime": {"runtime"},
    "behaviors": {"runtime", "behaviors"},
    "policy": {"runtime", "policy"},
    "sim": {"runtime", "behaviors", "policy", "sim"},
}
PROJECT_PACKAGES = set(ALLOWED) | {"tests", "benchmarks", "tools"}


def imported_modules(path: Path, module: str) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file of ``module`` (a dotted name)."""
    tree = ast.parse(path.read_text(), str(path))
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            found.append((node.lineno, name))
    return found


def layer_violations(root: Path) -> list[str]:
    """``file:line: layer imports X`` for every import that crosses a layer the wrong way."""
    problems = []
    for layer, allowed in ALLOWED.items():
        for path in sorted((root / layer).rglob("*.py")):
            relative = path.relative_to(root)
            module = ".".join(relative.with_suffix("").parts)
            for line, name in imported_modules(path, module):
                top = name.split(".")[0]
                if top in PROJECT_PACKAGES and top not in allowed:
                    problems.append(f"{relative}:{line}: {layer} imports {name} "
                                    f"({layer} may import only {', '.join(sorted(allowed))})")
    return problems


def test_no_import_crosses_a_layer_the_wrong_way():
    assert layer_violations(ROOT) == []


def test_every_layer_is_read():
    """The check reads the real packages (an empty walk would pass vacuously)."""
    counts = {layer: len(list((ROOT / layer).rglob("*.py"))) for layer in ALLOWED}
    assert all(count >= 3 for count in counts.values()), counts
    lines = imported_modules(ROOT / "sim" / "world.py", "sim.world")
    assert (lines and any(name == "sim.embedded_policy" for _, name in lines)
            and any(name == "policy.images" for _, name in lines))


@pytest.mark.parametrize("layer, source, crossing", [
    ("runtime", "def f():\n    from sim.world import create_vla_sim\n", "runtime imports sim.world"),
    ("runtime", "from ..behaviors import register\n", "runtime imports behaviors"),
    ("behaviors", "import policy.server\n", "behaviors imports policy.server"),
    ("behaviors", "from sim import robot_model\n", "behaviors imports sim"),
    ("policy", "from sim.robot_model import ARM_JOINTS\n", "policy imports sim.robot_model"),
    ("sim", "from benchmarks.baselines import Stream\n", "sim imports benchmarks.baselines"),
])
def test_each_wrong_way_import_is_named_with_file_and_line(tmp_path, layer, source, crossing):
    for name in ALLOWED:
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text("")
    (tmp_path / layer / "mod.py").write_text("import numpy\n" + source)
    [problem] = layer_violations(tmp_path)
    line = source.count("\n", 0, source.index("import")) + 2
    assert problem.startswith(f"{layer}/mod.py:{line}: {crossing} ({layer} may import only ")


def test_allowed_imports_pass(tmp_path):
    for name in ALLOWED:
        (tmp_path / name).mkdir()
    (tmp_path / "sim" / "mod.py").write_text("from policy.adapter import X\nfrom behaviors import y\nfrom .world import z\n")
    (tmp_path / "policy" / "mod.py").write_text("from runtime.bus import Bus\nfrom . import wire\n")
    assert layer_violations(tmp_path) == []

"""Dependencies flow one way: every import of every module, read with ``ast``, stays inside the
layers its package may use.

    runtime     the engine: imports only itself
    behaviors   -> runtime
    policy      -> runtime                     (runs beside a real robot: nothing simulated)
    recording   -> runtime                     (``--record``/``--live`` and the report, one package whose
                                                modules import one another in no circle; attached to
                                                the runner as a run observer, ``runtime.app.observer``)
    sim         -> runtime, behaviors, policy   (the worked example)
    evaluation  -> all of the above

``tests``, ``benchmarks`` and ``tools`` sit on top and may import anything; no layer imports them.
Imports inside functions count: a lazy import is still a dependency. No layer imports another
package's private names (``_name``).

The core (runtime, behaviors, policy) is what a robot computer installs without extras, so it
never imports the third-party modules of the ``[sim]`` and ``[record]`` extras (mujoco,
matplotlib, foxglove, mcap, imageio, ...; ``runtime.extras.EXTRA_OF_MODULE``), not even lazily.
Those extras are the point of ``sim`` (``[sim]``) and ``recording`` (``[record]``), which may
import theirs; ``evaluation`` draws its plots with matplotlib (``[record]``).
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from runtime.extras import EXTRA_OF_MODULE

ROOT = Path(__file__).resolve().parents[1]
ALLOWED = {
    "runtime": {"runtime"},
    "behaviors": {"runtime", "behaviors"},
    "policy": {"runtime", "policy"},
    "recording": {"runtime", "recording"},
    "sim": {"runtime", "behaviors", "policy", "sim"},
    "evaluation": {"runtime", "behaviors", "policy", "recording", "sim", "evaluation"},
}
PROJECT_PACKAGES = set(ALLOWED) | {"tests", "benchmarks", "tools"}
EXTRA_MODULES = {module: extra for module, extra in EXTRA_OF_MODULE.items() if extra in ("sim", "record")}
"""Third-party modules the core must never import: those of the ``[sim]`` and ``[record]`` extras."""
EXTRAS_ALLOWED = {"sim": {"sim"}, "recording": {"record"}, "evaluation": {"sim", "record"}}
"""The extras whose modules a layer may import (the core layers: none)."""


def imported_modules(path: Path, module: str) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file of ``module`` (a dotted name)."""
    return [(line, name) for line, name, _ in imported_names(path, module)]


def imported_names(path: Path, module: str) -> list[tuple[int, str, tuple[str, ...]]]:
    """(line, absolute module name, names taken from it) of every import in ``module``'s file."""
    tree = ast.parse(path.read_text(), str(path))
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name, ()) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            found.append((node.lineno, name, tuple(alias.name for alias in node.names)))
    return found


def layer_violations(root: Path) -> list[str]:
    """``file:line: layer imports X`` for every import that crosses a layer the wrong way, reaches
    an extra the layer may not use, or takes another package's private name."""
    problems = []
    for layer, allowed in ALLOWED.items():
        extras = EXTRAS_ALLOWED.get(layer, set())
        for path in sorted((root / layer).rglob("*.py")):
            relative = path.relative_to(root)
            module = ".".join(relative.with_suffix("").parts)
            for line, name, names in imported_names(path, module):
                top = name.split(".")[0]
                where = f"{relative}:{line}: {layer} imports {name}"
                if top in PROJECT_PACKAGES and top not in allowed:
                    problems.append(f"{where} ({layer} may import only {', '.join(sorted(allowed))})")
                elif top in EXTRA_MODULES and EXTRA_MODULES[top] not in extras:
                    problems.append(f"{where} (a module of the [{EXTRA_MODULES[top]}] extra; "
                                    f"{layer} may use {', '.join(sorted(extras)) or 'no extra'})")
                private = [n for n in names if n.startswith("_") and not n.startswith("__")]
                if top in PROJECT_PACKAGES and top != layer and private:
                    problems.append(f"{where}: {', '.join(private)} (a private name of {top})")
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
    ("runtime", "import recording\n", "runtime imports recording"),
    ("recording", "from sim.world import create_vla_sim\n", "recording imports sim.world"),
    ("policy", "from recording.report import render_report\n", "policy imports recording.report"),
    ("evaluation", "from tests.fakes import FakeBus\n", "evaluation imports tests.fakes"),
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
    (tmp_path / "policy" / "mod.py").write_text("from runtime.io.bus import Bus\nfrom . import wire\n")
    (tmp_path / "recording" / "mod.py").write_text("import mcap\ndef f():\n    import foxglove\n    import matplotlib\n")
    (tmp_path / "sim" / "cell.py").write_text("import mujoco\n")
    (tmp_path / "evaluation" / "mod.py").write_text("from recording.report.html import CSS\nfrom sim import world\n")
    assert layer_violations(tmp_path) == []


def test_the_core_imports_no_module_of_the_sim_and_record_extras():
    assert {"mujoco", "matplotlib", "foxglove", "mcap", "imageio"} <= set(EXTRA_MODULES)


@pytest.mark.parametrize("layer, source, named", [
    ("runtime", "def load():\n    import mujoco\n", "runtime imports mujoco (a module of the [sim] extra; runtime may use no extra)"),
    ("behaviors", "import matplotlib.pyplot as plt\n", "behaviors imports matplotlib.pyplot (a module of the [record] extra"),
    ("policy", "from mcap.writer import Writer\n", "policy imports mcap.writer (a module of the [record] extra"),
    ("policy", "def f():\n    import foxglove\n", "policy imports foxglove (a module of the [record] extra"),
    ("runtime", "import imageio.v2\n", "runtime imports imageio.v2 (a module of the [record] extra"),
    ("recording", "import mujoco\n", "recording imports mujoco (a module of the [sim] extra; recording may use record)"),
])
def test_an_extra_reached_from_the_core_is_named(tmp_path, layer, source, named):
    for name in ALLOWED:
        (tmp_path / name).mkdir()
    (tmp_path / layer / "mod.py").write_text(source)
    [problem] = layer_violations(tmp_path)
    assert named in problem, problem


def test_a_private_name_of_another_package_is_named(tmp_path):
    for name in ALLOWED:
        (tmp_path / name).mkdir()
    (tmp_path / "evaluation" / "cli.py").write_text("from runtime.app.cli import _parse_set as parse_set\n")
    (tmp_path / "runtime" / "cli.py").write_text("from .loader import _private_helper\n")
    assert layer_violations(tmp_path) == [
        "evaluation/cli.py:1: evaluation imports runtime.app.cli: _parse_set (a private name of runtime)"]


def import_cycles(root: Path, package: str) -> list[list[str]]:
    """The groups of ``package``'s modules that import one another in a circle (lazy imports count)."""
    modules = {}
    for path in sorted((root / package).rglob("*.py")):
        module = ".".join(path.relative_to(root).with_suffix("").parts)
        modules[module.removesuffix(".__init__")] = (path, module)
    graph = {}
    for name, (path, module) in modules.items():
        imported: set[str] = set()
        for _, target, names in imported_names(path, module):
            imported |= {t for t in (target, *(f"{target}.{n}" for n in names)) if t in modules and t != name}
        graph[name] = imported
    reach = {name: _reachable(graph, name) for name in graph}
    groups = {tuple(sorted(m for m in reach[name] if name in reach[m])) for name in graph if name in reach[name]}
    return sorted(list(group) for group in groups)


def _reachable(graph: dict[str, set[str]], start: str) -> set[str]:
    reach, stack = set(), [start]
    while stack:
        for nxt in graph[stack.pop()]:
            if nxt not in reach:
                reach.add(nxt)
                stack.append(nxt)
    return reach


def test_the_recording_and_its_report_import_each_other_in_no_circle():
    assert len(list((ROOT / "recording" / "report").glob("*.py"))) >= 5
    assert import_cycles(ROOT, "recording") == []


def test_a_circle_is_found(tmp_path):
    (tmp_path / "recording" / "report").mkdir(parents=True)
    (tmp_path / "recording" / "session.py").write_text("from .report.data import load\n")
    (tmp_path / "recording" / "report" / "data.py").write_text("def f():\n    from ..session import Session\n")
    (tmp_path / "recording" / "files.py").write_text("import json\n")
    assert import_cycles(tmp_path, "recording") == [["recording.report.data", "recording.session"]]

"""Dependencies flow one way: every import of every module, read with ``ast``, stays inside the
layers its package may use.

    runtime     the engine: imports only itself
    behaviors   -> runtime
    policy      -> runtime                     (runs beside a real robot: nothing simulated)
    recording   -> runtime                     (``--record``/``--live`` and the report, one package whose
                                                modules import one another in no circle; attached to
                                                the runner as a run observer, ``runtime.app.observer``)
    sim         -> runtime, behaviors, policy   (the worked example)
    evaluation  -> runtime, behaviors, policy, recording   (a world and its embedded policy are
                                                reached through ``objective.worlds``, never imported)

``tests``, ``benchmarks`` and ``tools`` sit on top and may import anything; no layer imports them.

Inside ``runtime``, its rooms flow one way too (``ROOMS``):

    runtime.errors, runtime.extras   what every room uses: import nothing else of runtime
    runtime.io       bus, ROS 2, clocks        -> errors, extras
    runtime.motion   robot, scene, motion      -> errors, extras, io
    runtime.tree     the tree engine           -> errors, extras, io
    runtime.app      runner, CLI, server, ...  -> all of the above

so the tree engine, the bus and ROS 2, and motion import nothing of the application, and the tree
engine nothing of motion (behaviors bring the two together).
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
    "evaluation": {"runtime", "behaviors", "policy", "recording", "evaluation"},
}
PROJECT_PACKAGES = set(ALLOWED) | {"tests", "benchmarks", "tools"}
BASE = {"runtime", "runtime.errors", "runtime.extras"}
ROOMS = {
    "runtime.errors": BASE,
    "runtime.extras": BASE,
    "runtime.io": BASE | {"runtime.io"},
    "runtime.motion": BASE | {"runtime.io", "runtime.motion"},
    "runtime.tree": BASE | {"runtime.io", "runtime.tree"},
    "runtime.app": BASE | {"runtime.io", "runtime.motion", "runtime.tree", "runtime.app"},
}
"""The rooms of ``runtime`` -> what their modules may import of ``runtime`` (``runtime`` alone: its
``__init__``)."""
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
                if layer == "runtime":
                    problems += room_violations(where, module, name)
                private = [n for n in names if n.startswith("_") and not n.startswith("__")]
                if top in PROJECT_PACKAGES and top != layer and private:
                    problems.append(f"{where}: {', '.join(private)} (a private name of {top})")
    return problems


def room_of(module: str) -> str | None:
    """The room of ``runtime`` that holds ``module`` (a dotted name), or None outside them."""
    return next((room for room in ROOMS if module == room or module.startswith(room + ".")), None)


def room_violations(where: str, module: str, imported: str) -> list[str]:
    """The problem, if any, of ``module`` (in ``runtime``) importing ``imported``."""
    room, target = room_of(module), room_of(imported) or imported
    if room is None or not imported.startswith("runtime") or target in ROOMS[room]:
        return []
    return [f"{where} ({room} may import only {', '.join(sorted(ROOMS[room]))})"]


def test_no_import_crosses_a_layer_the_wrong_way():
    assert layer_violations(ROOT) == []


def test_every_layer_is_read():
    """The check reads the real packages (an empty walk would pass vacuously)."""
    counts = {layer: len(list((ROOT / layer).rglob("*.py"))) for layer in ALLOWED}
    assert all(count >= 3 for count in counts.values()), counts
    rooms = {room: len(list((ROOT / Path(*room.split("."))).rglob("*.py"))) for room in ROOMS if "." in room}
    assert all(count >= 4 for room, count in rooms.items() if room not in ("runtime.errors", "runtime.extras")), rooms
    assert all((ROOT / "runtime" / f"{name}.py").is_file() for name in ("errors", "extras"))
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
    ("evaluation", "def f():\n    from sim.embedded_policy import make_backend\n", "evaluation imports sim.embedded_policy"),
])
def test_each_wrong_way_import_is_named_with_file_and_line(tmp_path, layer, source, crossing):
    for name in ALLOWED:
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text("")
    (tmp_path / layer / "mod.py").write_text("import numpy\n" + source)
    [problem] = layer_violations(tmp_path)
    line = source.count("\n", 0, source.index("import")) + 2
    assert problem.startswith(f"{layer}/mod.py:{line}: {crossing} ({layer} may import only ")


@pytest.mark.parametrize("room, source, imported", [
    ("tree", "from runtime.app.runner import run_file\n", "runtime.app.runner"),
    ("tree", "def f():\n    from ..motion.scene import PlanningScene\n", "runtime.motion.scene"),
    ("io", "from ..tree.ports import NameKind\n", "runtime.tree.ports"),
    ("io", "def f():\n    from runtime.app import cli\n", "runtime.app"),
    ("motion", "from runtime.app.world import World\n", "runtime.app.world"),
    ("motion", "from runtime.tree.behavior import RunContext\n", "runtime.tree.behavior"),
])
def test_each_wrong_way_import_between_rooms_is_named(tmp_path, room, source, imported):
    for name in ALLOWED:
        (tmp_path / name).mkdir()
    (tmp_path / "runtime" / room).mkdir()
    (tmp_path / "runtime" / room / "mod.py").write_text(source)
    [problem] = layer_violations(tmp_path)
    line = source.count("\n", 0, source.index("import")) + 1
    assert problem.startswith(f"runtime/{room}/mod.py:{line}: runtime imports {imported} (runtime.{room} may import only ")


def test_allowed_imports_pass(tmp_path):
    for name in ALLOWED:
        (tmp_path / name).mkdir()
    (tmp_path / "sim" / "mod.py").write_text("from policy.adapter import X\nfrom behaviors import y\nfrom .world import z\n")
    (tmp_path / "policy" / "mod.py").write_text("from runtime.io.bus import Bus\nfrom . import wire\n")
    (tmp_path / "recording" / "mod.py").write_text("import mcap\ndef f():\n    import foxglove\n    import matplotlib\n")
    (tmp_path / "sim" / "cell.py").write_text("import mujoco\n")
    (tmp_path / "evaluation" / "mod.py").write_text("from recording.report.html import CSS\nfrom policy.specs import parse_policy\n")
    for room in ("app", "tree", "motion"):
        (tmp_path / "runtime" / room).mkdir()
    (tmp_path / "runtime" / "app" / "mod.py").write_text("from ..tree.loader import load_tree\nfrom runtime.motion import scene\n")
    (tmp_path / "runtime" / "tree" / "mod.py").write_text("from runtime.io.bus import Bus\nfrom ..errors import SetupError\n")
    (tmp_path / "runtime" / "motion" / "mod.py").write_text("from runtime.io.timestamps import time_msg\nfrom . import samples\n")
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

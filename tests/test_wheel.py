"""A wheel works without the checkout: `objective`, its SubTree library and the interface sources.

The wheel is built as a user builds it (``pip wheel --no-deps .``) and installed with
``--no-deps`` into a fresh venv; that venv reaches the dependencies through a ``.pth`` naming
this venv's site-packages (installing them again would take minutes and the network), and every
command runs from a directory outside the checkout, on a copy of the Objective, so nothing can be
found next to the checkout's files.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(300)

ROOT = Path(__file__).resolve().parents[1]
PYTHON = f"python{sys.version_info.major}.{sys.version_info.minor}"  # the venv's lib/ folder


def _run(cmd: list[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "MUJOCO_GL": "egl", "PYTHONPATH": ""}
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """A fresh venv with only the wheel installed; returns its bin/ directory."""
    work = tmp_path_factory.mktemp("wheel")
    # Build from a copy of the sources: setuptools builds in the tree, and a checkout's stale
    # build/lib would slip files that no longer exist into the wheel.
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True,
                           text=True, check=True, timeout=60).stdout.splitlines()
    source = work / "source"
    for name in files:
        if (ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    built = _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(work / "dist"), str(source)],
                 cwd=work, timeout=240)
    assert built.returncode == 0, built.stderr[-3000:]
    [wheel] = (work / "dist").glob("objective_runtime-*.whl")
    venv = work / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)],
                   check=True, timeout=60)
    installed = _run([sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "install",
                      "--no-deps", "--quiet", str(wheel)], cwd=work)
    assert installed.returncode == 0, installed.stderr[-3000:]
    site = Path(_run([str(venv / "bin" / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     cwd=work).stdout.strip())
    (site / "zz_dependencies.pth").write_text(f"import site; site.addsitedir({sysconfig.get_paths()['purelib']!r})\n")
    return venv / "bin"


@pytest.fixture
def outside(tmp_path) -> Path:
    """A directory outside the checkout holding copies of the Objectives the tests run."""
    shutil.copy(ROOT / "objectives" / "stack_cubes.xml", tmp_path / "stack_cubes.xml")
    return tmp_path


def test_the_wheel_is_what_runs(installed, outside):
    proc = _run([str(installed / "python"), "-c", "import runtime, behaviors, policy, sim; "
                 "print(';'.join(m.__file__ for m in (runtime, behaviors, policy, sim)))"], cwd=outside)
    assert proc.returncode == 0, proc.stderr
    assert all(path.startswith(str(installed.parent)) for path in proc.stdout.strip().split(";")), proc.stdout


def test_validate_finds_the_subtree_library_without_the_checkout(installed, outside):
    proc = _run([str(installed / "objective"), "validate", "stack_cubes.xml"], cwd=outside)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "ok: stack_cubes.xml: Stack Cubes (15 nodes), Prepare for Policy (8 nodes)"


def test_the_stacking_objective_runs_on_the_kinematic_world(installed, outside):
    proc = _run([str(installed / "objective"), "run", "stack_cubes.xml", "--world", "kinematic", "--json",
                 "--max-seconds", "60"], cwd=outside)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["status"] == "SUCCESS"
    library = installed.parent / "lib" / PYTHON / "site-packages" / "objectives" / "move_to_waypoint.xml"
    assert library.is_file()


def test_the_interface_sources_and_their_builder_ship(installed, outside):
    proc = _run([str(installed / "objective"), "build-interfaces", "--help"], cwd=outside)
    assert proc.returncode == 0 and "--build-dir" in proc.stdout, proc.stderr
    interfaces = installed.parent / "lib" / PYTHON / "site-packages" / "runtime" / "ros" / "interfaces"
    for package, source in [("moveit_pro_ml_msgs", "srv/GetActionChunk.srv"),
                            ("moveit_pro_controllers_msgs", "action/FollowJointTrajectoryWithAdmittance.action"),
                            ("control_msgs", "msg/GripperCommand.msg"),
                            ("controller_manager_msgs", "srv/SwitchController.srv"),
                            ("objective_server_msgs", "action/DoObjective.action")]:
        for name in ("package.xml", "CMakeLists.txt", source):
            assert (interfaces / package / name).is_file(), f"{package}/{name} is not in the wheel"

"""A wheel works without the checkout: as the core alone, beside a sourced ROS 2, with its SubTree
library and the interface sources.

The wheel is built as a user builds it (``pip wheel --no-deps .``) from a copy of the sources, and
every command runs from a directory outside the checkout, so nothing can be found next to the
checkout's files. Three installations:

- ``installed``: the wheel alone (``--no-deps``) in a fresh venv that reaches this venv's
  packages through a ``.pth`` (every extra: the simulated cell runs).
- ``core``: ``pip install 'WHEEL[ros]'`` into a fresh venv, as a robot computer without a ROS
  install does: the core and the PyPI ROS wheels, no mujoco, matplotlib, foxglove or mcap
  (slow); and, in the default suite, the same core from a view of this venv's packages without
  the [sim] and [record] extras, and views with one of the two.
- ``sourced ROS`` (slow): the ROS 2 wheels in a prefix of their own, supplied through
  ``PYTHONPATH`` and ``LD_LIBRARY_PATH`` as ``source /opt/ros/jazzy/setup.bash`` supplies them;
  ``pip install WHEEL`` must pull no second rclpy.

Where pip installs the ROS wheels, the project's interface packages come from an overlay prefix laid out like a
colcon workspace's ``install/`` (the copies ``make setup`` built into this venv), supplied the same
way, so no test waits for cmake.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import sysconfig
import threading
import tomllib
import uuid
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(600)

ROOT = Path(__file__).resolve().parents[1]
PYTHON = f"python{sys.version_info.major}.{sys.version_info.minor}"  # the venvs' lib/ folder
INTERFACES = sorted(p.name for p in (ROOT / "runtime" / "io" / "ros" / "interfaces").iterdir() if (p / "package.xml").is_file())
EXTRA_MODULES = ("mujoco", "matplotlib", "foxglove", "mcap", "imageio")
"""What the core must run without: the [sim] and [record] extras' modules."""


SHELL_ONLY = ("LD_LIBRARY_PATH", "_ROS_WHEELS_BOOTSTRAP_COMPLETE")
"""What this venv's ROS wheels put into its environment: a fresh shell has neither (the core
venvs' own bootstrapper then puts their lib/ on the library path)."""


def _environment(env: dict[str, str] | None) -> dict[str, str]:
    """This process's environment, on loopback, and without this venv's library path when ``env``
    (a prefix's variables, as a sourced setup.bash exports them) is given."""
    base = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "MUJOCO_GL": "egl", "PYTHONPATH": ""}
    if env is not None:
        base = {name: value for name, value in base.items() if name not in SHELL_ONLY}
    return {**base, **(env or {})}


def _run(cmd: list[str], cwd: Path, timeout: float = 120, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=cwd, env=_environment(env), capture_output=True, text=True, timeout=timeout)


def _pip(venv: Path, *args: str, cwd: Path, timeout: float = 400) -> subprocess.CompletedProcess[str]:
    """This venv's pip, installing into ``venv`` (pip's --python)."""
    return _run([sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), *args], cwd=cwd, timeout=timeout)


def _fresh_venv(path: Path) -> Path:
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(path)], check=True, timeout=60)
    return path


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
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
    [found] = (work / "dist").glob("objective_runtime-*.whl")
    return found


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Path:
    """A fresh venv with only the wheel installed; returns its bin/ directory."""
    venv = _fresh_venv(tmp_path_factory.mktemp("installed") / "venv")
    done = _pip(venv, "install", "--no-deps", "--quiet", str(wheel), cwd=wheel.parent)
    assert done.returncode == 0, done.stderr[-3000:]
    site = venv / "lib" / PYTHON / "site-packages"
    (site / "zz_dependencies.pth").write_text(f"import site; site.addsitedir({sysconfig.get_paths()['purelib']!r})\n")
    return venv / "bin"


def interface_overlay(root: Path) -> dict[str, str]:
    """The project's interface packages (built into this venv by ``make setup``) as a prefix of
    their own, laid out as colcon installs one; returns the variables a ``setup.bash`` sets."""
    here = Path(sys.prefix)
    site = root / "lib" / PYTHON / "site-packages"
    (root / "share").mkdir(parents=True)
    site.mkdir(parents=True)
    for package in INTERFACES:
        (site / package).symlink_to(here / "lib" / PYTHON / "site-packages" / package)
        (root / "share" / package).symlink_to(here / "share" / package)
        for library in (here / "lib").glob(f"lib{package}__*.so"):
            (root / "lib" / library.name).symlink_to(library)
    return {"PYTHONPATH": str(site), "LD_LIBRARY_PATH": str(root / "lib"), "AMENT_PREFIX_PATH": str(root)}


def joined(*envs: dict[str, str]) -> dict[str, str]:
    """Environment variables of several prefixes, the first one first (as sourcing them in reverse)."""
    out: dict[str, str] = {}
    for env in envs:
        for name, value in env.items():
            out[name] = f"{out[name]}{os.pathsep}{value}" if name in out else value
    return out


def extras_top_levels(*extras: str) -> set[str]:
    """The top-level entries of site-packages the distributions of pyproject's ``extras`` installed."""
    from importlib.metadata import distribution

    wanted = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    tops = set()
    for extra in extras:
        for requirement in wanted[extra]:
            dist = distribution(re.split(r"[=<>\[ ;]", requirement, maxsplit=1)[0])
            tops |= {Path(str(f)).parts[0] for f in dist.files or () if not str(f).startswith("..")}
    return tops


def core_view(site: Path, without: tuple[str, ...] = ("sim", "record")) -> Path:
    """This venv's site-packages as ``site`` (symlinks) without the project and without what the
    extras ``without`` installed (by default: the core's dependencies and the ROS wheels only)."""
    here = Path(sysconfig.get_paths()["purelib"])
    left_out = extras_top_levels(*without) | {"objective_runtime-0.1.0.dist-info"}
    site.mkdir(parents=True)
    for entry in here.iterdir():
        if entry.name not in left_out and not entry.name.startswith("__editable__"):
            (site / entry.name).symlink_to(entry)
    return site


def viewed(wheel: Path, work: Path, without: tuple[str, ...]) -> tuple[Path, dict[str, str]]:
    """The wheel ``--no-deps`` in a fresh venv whose dependencies are ``core_view(without)``;
    its bin/ and the variables its commands need."""
    venv = _fresh_venv(work / "venv")
    done = _pip(venv, "install", "--no-deps", "--quiet", str(wheel), cwd=work)
    assert done.returncode == 0, done.stderr[-3000:]
    view = core_view(work / "view" / "site-packages", without)
    (venv / "lib" / PYTHON / "site-packages" / "zz_dependencies.pth").write_text(
        f"import site; site.addsitedir({str(view)!r})\n")
    # This venv's ROS wheels keep their libraries in its lib/ (its bootstrapper's path).
    return venv / "bin", {"LD_LIBRARY_PATH": os.environ.get("LD_LIBRARY_PATH", ""), "_ROS_WHEELS_BOOTSTRAP_COMPLETE": "1"}


@pytest.fixture(scope="module", params=["view", pytest.param("pip", marks=pytest.mark.slow)])
def core(wheel, request, tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """The wheel as the core alone in a fresh venv; its bin/ and the variables its commands need.

    ``pip``: ``pip install 'WHEEL[ros]'`` (the registries, about 2-6 minutes here), the interface
    packages from an overlay prefix. ``view``: the wheel ``--no-deps``, its dependencies from a
    view of this venv's site-packages without the [sim] and [record] extras (seconds)."""
    work = tmp_path_factory.mktemp(f"core-{request.param}")
    if request.param == "view":
        return viewed(wheel, work, without=("sim", "record"))
    venv = _fresh_venv(work / "venv")
    done = _pip(venv, "install", "--quiet", f"{wheel}[ros]", cwd=work)
    assert done.returncode == 0, done.stderr[-3000:]
    return venv / "bin", interface_overlay(work / "overlay")


@pytest.fixture
def outside(tmp_path) -> Path:
    """A directory outside the checkout holding copies of the Objectives the tests run."""
    shutil.copy(ROOT / "objectives" / "stack_cubes.xml", tmp_path / "stack_cubes.xml")
    return tmp_path


# -- the wheel beside every extra --------------------------------------------------------------
def test_the_wheel_is_what_runs(installed, outside):
    proc = _run([str(installed / "python"), "-c", "import runtime, behaviors, policy, sim, recording; "
                 "print(';'.join(m.__file__ for m in (runtime, behaviors, policy, sim, recording)))"], cwd=outside)
    assert proc.returncode == 0, proc.stderr
    assert all(path.startswith(str(installed.parent)) for path in proc.stdout.strip().split(";")), proc.stdout


def test_validate_finds_the_subtree_library_without_the_checkout(installed, outside):
    proc = _run([str(installed / "objective"), "validate", "stack_cubes.xml"], cwd=outside)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "ok: stack_cubes.xml: Stack Cubes (16 nodes), Prepare for Policy (9 nodes)"


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
    site = installed.parent / "lib" / PYTHON / "site-packages"
    interfaces = site / "runtime" / "io" / "ros" / "interfaces"
    for package, source in [("moveit_pro_ml_msgs", "srv/GetActionChunk.srv"),
                            ("moveit_pro_controllers_msgs", "action/FollowJointTrajectoryWithAdmittance.action"),
                            ("control_msgs", "msg/GripperCommand.msg"),
                            ("controller_manager_msgs", "srv/SwitchController.srv"),
                            ("objective_server_msgs", "action/DoObjective.action")]:
        for name in ("package.xml", "CMakeLists.txt", source):
            assert (interfaces / package / name).is_file(), f"{package}/{name} is not in the wheel"
    # Sources only: an installed message package of the same name (a sourced ROS's) is never shadowed.
    assert not any((site / package).exists() for package in INTERFACES)


# -- the core alone, ROS 2 from PyPI ([ros]) ---------------------------------------------------
def test_the_core_installs_without_the_sim_and_record_extras(core, outside):
    bin_dir, overlay = core
    probe = f"import importlib.util as u; print([m for m in {EXTRA_MODULES!r} if u.find_spec(m)])"
    proc = _run([str(bin_dir / "python"), "-c", probe], cwd=outside, env=overlay)
    assert proc.returncode == 0 and proc.stdout.strip() == "[]", proc.stdout + proc.stderr


def test_the_core_validates_every_shipped_objective(core, outside):
    bin_dir, overlay = core
    files = sorted(str(p) for p in (ROOT / "objectives").rglob("*.xml"))
    proc = _run([str(bin_dir / "objective"), "validate", *files], cwd=outside, env=overlay)
    assert proc.returncode == 0, proc.stderr
    assert len([line for line in proc.stdout.splitlines() if line.startswith("ok: ")]) == len(files) > 10


def test_the_core_names_the_extra_a_command_needs(core, outside):
    bin_dir, overlay = core
    proc = _run([str(bin_dir / "objective"), "run", "stack_cubes.xml"], cwd=outside, env=overlay)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert ("error: world 'vla_sim' cannot start: mujoco is not installed: it comes with the [sim] extra, "
            "pip install 'objective-runtime[sim]'") in proc.stderr
    (outside / "wait.xml").write_text('<root BTCPP_format="4"><BehaviorTree ID="W"><Wait seconds="0.1"/></BehaviorTree></root>')
    proc = _run([str(bin_dir / "objective"), "run", "wait.xml", "--record", "rec"], cwd=outside, env=overlay)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert ("error: --record/--live: mcap is not installed: it comes with the [record] extra, "
            "pip install 'objective-runtime[record]'") in proc.stderr


def my_policy_from_the_docs() -> str:
    """The one-file policy of docs/policy-side.md (Step 0), exactly as written there."""
    text = (ROOT / "docs" / "policy-side.md").read_text()
    [source] = re.findall(r"```python\n(# my_policy\.py\n.*?)```", text, re.S)
    return source


class Process:
    """A long-running ``objective`` command whose stdout lines are read as they come."""

    def __init__(self, cmd: list[str], cwd: Path, env: dict[str, str]) -> None:
        self.proc = subprocess.Popen(cmd, cwd=cwd, env=_environment(env), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def first_line(self, timeout: float = 60) -> str:
        line: list[str] = []
        reader = threading.Thread(target=lambda: line.append(self.proc.stdout.readline()), daemon=True)
        reader.start()
        reader.join(timeout)
        assert line and line[0], f"no output within {timeout} s; stderr:\n{self.stop()}"
        return line[0].strip()

    def stop(self) -> str:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        return self.proc.stderr.read() if self.proc.stderr else ""


def serve_adapt_and_smoke_test(bin_dir: Path, cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """``objective serve --backend my_policy.py:make``, ``objective adapter`` in front of it, and
    ``objective smoke-test`` calling the adapter's service over ROS 2, as docs/policy-side.md walks it."""
    (cwd / "my_policy.py").write_text(my_policy_from_the_docs())
    service = f"/t{uuid.uuid4().hex[:8]}/get_action_chunk"
    server = Process([str(bin_dir / "objective"), "serve", "--backend", "my_policy.py:make", "--port", "0",
                      "--insecure-no-key"], cwd, env)
    adapter = None
    try:
        listening = server.first_line()
        assert listening.startswith("listening on http://127.0.0.1:"), listening
        adapter = Process([str(bin_dir / "objective"), "adapter", "--infer-url", listening.split()[-1],
                           "--service-name", service], cwd, env)
        return _run([str(bin_dir / "objective"), "smoke-test", service, "--joints", "j1;j2;j3", "--synthetic-joints",
                     "--image-names", "scene", "--synthetic-images", "--expected-steps", "50", "--wait", "30",
                     "--timeout", "10"], cwd=cwd, env=env, timeout=90)
    finally:
        if adapter is not None:
            adapter.stop()
        server.stop()


def test_the_core_serves_and_adapts_your_policy_from_one_file(core, outside):
    bin_dir, overlay = core
    proc = serve_adapt_and_smoke_test(bin_dir, outside, overlay)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.splitlines()[-1] == "VERDICT: PASS"


# -- the core with one extra ------------------------------------------------------------------
def test_the_sim_extra_alone_runs_the_cell_and_names_the_record_extra(wheel, tmp_path_factory, outside):
    bin_dir, env = viewed(wheel, tmp_path_factory.mktemp("sim-only"), without=("record",))
    proc = _run([str(bin_dir / "objective"), "run", "stack_cubes.xml", "--world", "kinematic", "--json"], cwd=outside, env=env)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.strip().splitlines()[-1])["status"] == "SUCCESS"
    proc = _run([str(bin_dir / "objective"), "run", "stack_cubes.xml", "--world", "kinematic", "--record", "rec"],
                cwd=outside, env=env)
    assert proc.returncode == 2 and "error: --record/--live: mcap is not installed: it comes with the [record] extra" in proc.stderr


def test_the_record_extra_alone_records_a_run_without_the_cell(wheel, tmp_path_factory, outside):
    bin_dir, env = viewed(wheel, tmp_path_factory.mktemp("record-only"), without=("sim",))
    (outside / "wait.xml").write_text('<root BTCPP_format="4"><BehaviorTree ID="W"><Wait seconds="0.5"/></BehaviorTree></root>')
    proc = _run([str(bin_dir / "objective"), "run", "wait.xml", "--record", "rec"], cwd=outside, env=env)
    assert proc.returncode == 0, proc.stderr
    assert (outside / "rec" / "run.mcap").is_file() and (outside / "rec" / "report.html").is_file()
    proc = _run([str(bin_dir / "objective"), "report", "rec"], cwd=outside, env=env)
    assert proc.returncode == 0 and str(Path("rec") / "report.html") in proc.stdout, proc.stderr


# -- beside a sourced ROS 2 --------------------------------------------------------------------
@pytest.fixture(scope="module")
def sourced_ros(wheel, tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """The ROS 2 wheels (the [ros] extra's list) in a prefix of their own, and the project's
    wheel installed alone into another venv; its bin/ and what setup.bash would export."""
    work = tmp_path_factory.mktemp("sourced")
    ros = _fresh_venv(work / "ros")
    wanted = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["ros"]
    done = _pip(ros, "install", "--quiet", *wanted, cwd=work)
    assert done.returncode == 0, done.stderr[-3000:]
    ros_site = ros / "lib" / PYTHON / "site-packages"
    # The prefix's libraries: its lib/ and the ones the wheels vendor (site-packages/ros_*.libs),
    # all of them in /opt/ros/jazzy/lib on a robot.
    libraries = [ros / "lib", *sorted(ros_site.glob("ros_*.libs"))]
    ros_env = {"PYTHONPATH": str(ros_site), "LD_LIBRARY_PATH": os.pathsep.join(map(str, libraries)),
               "AMENT_PREFIX_PATH": str(ros)}
    venv = _fresh_venv(work / "venv")
    done = _pip(venv, "install", str(wheel), cwd=work)
    assert done.returncode == 0, done.stderr[-3000:]
    listed = _pip(venv, "list", "--format", "json", cwd=work)
    names = {entry["name"].lower() for entry in json.loads(listed.stdout)}
    assert not any(name.startswith("ros-") for name in names), sorted(names)
    return venv / "bin", joined(interface_overlay(work / "overlay"), ros_env)


@pytest.mark.slow
def test_beside_a_sourced_ros_rclpy_is_the_sourced_one(sourced_ros, outside):
    bin_dir, env = sourced_ros
    proc = _run([str(bin_dir / "python"), "-c", "import rclpy, moveit_pro_ml_msgs.srv as s; print(rclpy.__file__)"],
                cwd=outside, env=env)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().startswith(env["PYTHONPATH"].split(os.pathsep)[-1]), proc.stdout


@pytest.mark.slow
def test_beside_a_sourced_ros_an_objective_runs_over_ros(sourced_ros, outside):
    """``objective run --ros``: the tree calls a std_srvs/Trigger service another node serves."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_srvs.srv import Trigger

    bin_dir, env = sourced_ros
    service = f"/t{uuid.uuid4().hex[:8]}/ready"
    (outside / "ready.xml").write_text(
        f'<root BTCPP_format="4"><BehaviorTree ID="Ready"><CallTriggerService service_name="{service}"/>'
        "</BehaviorTree></root>")
    calls: list[str] = []

    def answer(request, response):
        calls.append(service)
        response.success, response.message = True, "ready"
        return response

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("trigger_server", context=context)
    node.create_service(Trigger, service, answer)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        proc = _run([str(bin_dir / "objective"), "run", "ready.xml", "--ros", "--json"], cwd=outside, env=env, timeout=60)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.strip().splitlines()[-1])["status"] == "SUCCESS"
    assert calls == [service]


@pytest.mark.slow
def test_beside_a_sourced_ros_your_policy_is_served_and_adapted(sourced_ros, outside):
    bin_dir, env = sourced_ros
    proc = serve_adapt_and_smoke_test(bin_dir, outside, env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.splitlines()[-1] == "VERDICT: PASS"

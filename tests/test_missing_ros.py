"""An installation without ROS 2 (no ``[ros]`` extra, nothing sourced) or without the project's
interface packages: every command says what to install, never an internal error.

The missing modules are simulated in a subprocess: a ``sys.meta_path`` finder placed first
refuses them as an absent package is refused (``ModuleNotFoundError`` naming the module).
"""
from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import pytest

import runtime.app.build_interfaces as build_interfaces
from runtime.app import cli
from runtime.extras import is_ros_module, missing_module_message, project_interface_packages

REPO = Path(__file__).resolve().parent.parent

BLOCKER = """
import sys
from runtime.extras import is_ros_module, project_interface_packages
BLOCK_ROS = {block_ros}
INTERFACES = project_interface_packages()


class Missing:
    def find_spec(self, name, path=None, target=None):
        top = name.split(".")[0]
        if top in INTERFACES or (BLOCK_ROS and is_ros_module(top)):
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None


sys.meta_path.insert(0, Missing())
from runtime.app.cli import main
sys.exit(main(sys.argv[1:]))
"""


def objective_without(block_ros: bool, *argv: str) -> subprocess.CompletedProcess[str]:
    """``objective ARGV`` in a process where the project's interface packages, and with
    ``block_ros`` every ROS 2 module, cannot be imported."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    return subprocess.run([sys.executable, "-c", BLOCKER.format(block_ros=block_ros), *argv], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)


def test_validate_without_ros_names_the_ros_extra_and_a_sourced_ros():
    proc = objective_without(True, "validate", "objectives/stack_cubes.xml")
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == (
        "error: the behaviors of 'behaviors' (behaviors:register) cannot load: controller_manager_msgs is not "
        "installed, nor is ROS 2: source your ROS 2 Jazzy (source /opt/ros/jazzy/setup.bash) or pip install "
        "'objective-runtime[ros]', then build the project's interface packages with `objective build-interfaces`")


def test_validate_without_the_interface_packages_says_to_build_them():
    proc = objective_without(False, "validate", "objectives/stack_cubes.xml")
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == (
        "error: the behaviors of 'behaviors' (behaviors:register) cannot load: controller_manager_msgs is not "
        "installed: build the project's interface packages with `objective build-interfaces`")


def test_a_ros_message_package_names_the_ros_extra():
    assert missing_module_message("sensor_msgs.msg") == (
        "sensor_msgs is not installed: source your ROS 2 Jazzy (source /opt/ros/jazzy/setup.bash) "
        "or pip install 'objective-runtime[ros]'")
    assert is_ros_module("builtin_interfaces") and is_ros_module("rclpy") and not is_ros_module("numpy")
    assert "controller_manager_msgs" in project_interface_packages()


def test_build_interfaces_runs_before_the_behaviors_can_load(monkeypatch, capsys):
    """`objective build-interfaces` builds what the behaviors import: it must not need them."""
    assert build_interfaces.COMMAND.needs_registry is False
    ran = []
    monkeypatch.setattr(build_interfaces, "COMMAND",
                        dataclasses.replace(build_interfaces.COMMAND, run=lambda args, registry: ran.append(registry) or 0))

    def no_behaviors():
        raise AssertionError("the behaviors were loaded")

    monkeypatch.setattr(cli, "_installed_registry", no_behaviors)
    assert cli.main(["build-interfaces"]) == 0
    assert ran == [None]


@pytest.mark.parametrize("argv", [["behaviors"], ["build-interfaces", "--help"]])
def test_commands_without_ros_end_without_an_internal_error(argv):
    proc = objective_without(True, *argv)
    assert "internal error" not in proc.stderr and "Traceback" not in proc.stderr

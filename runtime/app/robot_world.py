"""World ``robot``: your own robot from URDF + SRDF + joint_limits.yaml, no simulator.

For running Objectives against a real ROS 2 graph (``objective run --ros --realtime --world robot``):
the robot's drivers and controllers live elsewhere; this world only gives the behaviors a
planning scene to check motions against. Options (``--world-option KEY=VALUE``):

``urdf`` (or ``mjcf``: the robot as MuJoCo XML, e.g. what ``objective sim-robot --describe`` writes;
one of the two is required), ``srdf`` (required), ``couplings`` (YAML of joints that follow
another, for a model without URDF ``<mimic>``), ``joint_limits`` (MoveIt-style YAML; without it only
position limits are known and velocity/acceleration are unbounded, which ExecutePolicy refuses),
``cartesian_limits`` (the Cartesian envelope's YAML, ``runtime.motion.scene.envelope``; without it none),
``group`` (default ``manipulator``), ``gripper_joint``, ``package_dirs`` (``;``-separated, for
``package://`` meshes), ``waypoints`` (YAML ``waypoints: {Name: {joints: [...], positions: [...]}}``).
"""
from __future__ import annotations

from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Callable

import yaml

from runtime.tree.behavior import RunContext
from runtime.tree.resources import WAYPOINTS
from runtime.motion.scene import PlanningScene, RobotModel, load_envelope, load_joint_limits
from runtime.errors import OptionError
from runtime.extras import load_entry_point

MJCF_LOADER_GROUP = "objective.robot_loaders"
"""Entry points ``mjcf = module:function(path, srdf, couplings=...) -> RobotModel``."""

OPTIONS = ("seed", "realtime", "policy_latency", "record_dir", "policy", "urdf", "mjcf", "srdf", "couplings",
           "joint_limits", "cartesian_limits", "group", "gripper_joint", "package_dirs", "waypoints")


def _existing(options: dict[str, Any], key: str) -> Path:
    value = options.get(key)
    if not value:
        raise OptionError(f"option '{key}' is required (--world-option {key}=PATH)")
    path = Path(str(value))
    if not path.is_file():
        raise OptionError(f"option '{key}': no such file {path}")
    return path


def load_waypoints_yaml(path: Path) -> dict[str, dict[str, float]]:
    """``waypoints: {Name: {joints: [...], positions: [...]}}``; OptionError naming what is wrong."""
    try:
        doc = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise OptionError(f"{path}: not YAML: {err}") from None
    waypoints = doc.get("waypoints") if isinstance(doc, dict) else None
    if not isinstance(waypoints or {}, dict):
        raise OptionError(f"{path}: 'waypoints' must be a mapping of name -> joints and positions")
    out: dict[str, dict[str, float]] = {}
    for name, entry in (waypoints or {}).items():
        entry = entry if isinstance(entry, dict) else {}
        joints, positions = entry.get("joints"), entry.get("positions")
        if not isinstance(joints, list) or not isinstance(positions, list) or len(joints) != len(positions):
            raise OptionError(f"{path}: waypoint '{name}' needs equally long 'joints' and 'positions' lists")
        try:
            out[str(name)] = {str(j): float(p) for j, p in zip(joints, positions)}
        except (TypeError, ValueError):
            raise OptionError(f"{path}: waypoint '{name}': positions must be numbers, got {positions}") from None
    return out


def _load_mjcf(path: Path, srdf: Path, couplings: Any) -> RobotModel:
    """The robot of an MJCF file, by the loader an installed package names in ``MJCF_LOADER_GROUP``
    (the simulated cell's, ``sim.mjcf``: the engine itself reads no MJCF)."""
    found = [ep for ep in entry_points(group=MJCF_LOADER_GROUP) if ep.name == "mjcf"]
    if not found:
        raise OptionError("option 'mjcf' needs an MJCF loader, which comes with the [sim] extra "
                          "(pip install 'objective-runtime[sim]'); or describe the robot with urdf=FILE")
    loader: Callable[..., RobotModel] = load_entry_point(found[0], "option 'mjcf'")
    return loader(path, srdf, couplings=couplings)


class RobotDescriptionWorld:
    name = "robot"

    def __init__(self, options: dict[str, Any]) -> None:
        unknown = sorted(set(options) - set(OPTIONS))
        if unknown:
            raise OptionError(f"unknown options {', '.join(unknown)} (known: {', '.join(OPTIONS[4:])})")
        if options.get("urdf") and options.get("mjcf"):
            raise OptionError("options 'urdf' and 'mjcf' both describe the robot: give one of them")
        srdf = _existing(options, "srdf")
        couplings = _existing(options, "couplings") if options.get("couplings") else ()
        if options.get("mjcf"):
            self.robot = _load_mjcf(_existing(options, "mjcf"), srdf, couplings)
        else:
            dirs = [d for d in str(options.get("package_dirs") or "").split(";") if d]
            self.robot = RobotModel.from_urdf(_existing(options, "urdf"), srdf, package_dirs=dirs, couplings=couplings)
        self.group = str(options.get("group") or "manipulator")
        self.gripper_joint = options.get("gripper_joint") or None
        limits = None
        if options.get("joint_limits"):
            joints = list(self.robot.movable_joints)
            lower, upper = self.robot.position_limits(joints)
            position = {j: (lo, hi) for j, lo, hi in zip(joints, lower, upper)}
            limits = load_joint_limits(_existing(options, "joint_limits"), position)
        self.limits = limits
        self.envelope = None
        if options.get("cartesian_limits"):
            tip = self.robot.group(self.group).tip_link
            self.envelope = load_envelope(_existing(options, "cartesian_limits"), self.robot, tip)
        self.waypoints = load_waypoints_yaml(_existing(options, "waypoints")) if options.get("waypoints") else {}

    def start(self, context: RunContext) -> None:
        context.scene = PlanningScene(self.robot, self.group, self.gripper_joint, limits=self.limits, envelope=self.envelope)
        context.resources.set(WAYPOINTS, self.waypoints)

    def step_to(self, t: float) -> None:
        """Nothing to simulate: the real robot moves on its own clock."""

    def reset(self, seed: int) -> None:
        raise OptionError("world 'robot' drives a real robot: it cannot be reset")

    def summary(self) -> dict[str, Any]:
        return {"robot": self.robot.source if hasattr(self.robot, "source") else "", "group": self.group}

    def close(self) -> None:
        pass


def create(options: dict[str, Any]) -> RobotDescriptionWorld:
    return RobotDescriptionWorld(options)


create.hosts_servers = False  # type: ignore[attr-defined]  # the robot's drivers serve; the run's node only calls

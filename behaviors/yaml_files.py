"""Poses and joint states to and from YAML files, as MoveIt Pro writes them.

MoveIt Pro keeps these files in the configuration's objectives directory; here a relative name
is taken relative to the directory of the Objective that names it (the file the node is written
in), so an Objective and its YAML files travel together. The YAML is the ROS message as a
mapping (``header: {stamp: {sec, nanosec}, frame_id}``, ``pose: {position, orientation}``);
a vector of poses is one YAML document per pose (``---`` between them). Files are written
whole: to a temporary file first, then renamed over the old one.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, ClassVar

import yaml
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState

from runtime.tree import node_info
from runtime.tree.behavior import Behavior, Status
from runtime.tree.ports import InputPort, OutputPort, PortType
from runtime.errors import ObjectiveError

MAX_YAML_BYTES = 5 * 1024 * 1024


class YamlFileError(ObjectiveError, ValueError):
    """A file that cannot be read or written, or whose content is not what the node needs."""


# -- pure conversions --------------------------------------------------------------------------
def pose_to_dict(msg: PoseStamped) -> dict[str, Any]:
    p, o = msg.pose.position, msg.pose.orientation
    return {
        "header": {"stamp": {"sec": int(msg.header.stamp.sec), "nanosec": int(msg.header.stamp.nanosec)}, "frame_id": msg.header.frame_id},
        "pose": {"position": {"x": p.x, "y": p.y, "z": p.z}, "orientation": {"x": o.x, "y": o.y, "z": o.z, "w": o.w}},
    }


def _number(mapping: Any, key: str, where: str) -> float:
    if not isinstance(mapping, dict) or key not in mapping:
        raise YamlFileError(f"{where} lacks '{key}'")
    value = mapping[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise YamlFileError(f"{where}.{key} is not a number: {value!r}")
    return float(value)


def pose_from_dict(data: Any, where: str) -> PoseStamped:
    """A PoseStamped from its YAML mapping; YamlFileError naming the missing or bad field."""
    if not isinstance(data, dict) or "pose" not in data:
        raise YamlFileError(f"{where} is not a PoseStamped (no 'pose' mapping)")
    msg = PoseStamped()
    header = data.get("header") or {}
    if not isinstance(header, dict):
        raise YamlFileError(f"{where}.header is not a mapping")
    msg.header.frame_id = str(header.get("frame_id") or "world")
    stamp = header.get("stamp") or {}
    if not isinstance(stamp, dict):
        raise YamlFileError(f"{where}.header.stamp is not a mapping of sec and nanosec")
    try:
        msg.header.stamp.sec = int(stamp.get("sec", 0))
        msg.header.stamp.nanosec = int(stamp.get("nanosec", 0))
    except (TypeError, ValueError, AssertionError) as err:
        raise YamlFileError(f"{where}.header.stamp is not a valid time: {err}") from None
    pose = data["pose"]
    position, orientation = (pose or {}).get("position"), (pose or {}).get("orientation")
    p, o = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (_number(position, k, f"{where}.pose.position") for k in "xyz")
    o.x, o.y, o.z, o.w = (_number(orientation, k, f"{where}.pose.orientation") for k in "xyzw")
    return msg


def joint_state_to_dict(msg: JointState) -> dict[str, Any]:
    """MoveIt Pro's robot-state file layout: the joint state under ``joint_state``."""
    return {
        "joint_state": {
            "header": {"stamp": {"sec": int(msg.header.stamp.sec), "nanosec": int(msg.header.stamp.nanosec)}, "frame_id": msg.header.frame_id},
            "name": list(msg.name),
            "position": [float(v) for v in msg.position],
            "velocity": [float(v) for v in msg.velocity],
            "effort": [float(v) for v in msg.effort],
        }
    }


# -- files -------------------------------------------------------------------------------------
def resolve(node: Behavior, name: str, suffix: str = "") -> Path:
    """``name`` (plus ``suffix`` when it has none) relative to the Objective's directory.

    Objectives may come from anywhere, so the file must lie inside the Objective's directory
    or the current working directory: a YamlFileError says so otherwise.
    """
    if not name.strip():
        raise YamlFileError("the file name is empty")
    path = Path(name)
    if suffix and not path.suffix:
        path = path.with_suffix(suffix)
    location = node_info.location(node)
    base = Path(location.file).parent if location is not None and location.file and not location.file.startswith("<") else Path.cwd()
    resolved = (base / path).resolve()
    allowed = (base.resolve(), Path.cwd().resolve())
    if not any(resolved.is_relative_to(root) for root in allowed):
        raise YamlFileError(f"{name} is outside the Objective's directory ({allowed[0]}) and the working directory ({allowed[1]})")
    return resolved


def read_documents(path: Path) -> list[Any]:
    try:
        if path.stat().st_size > MAX_YAML_BYTES:
            raise YamlFileError(f"{path} is larger than {MAX_YAML_BYTES} bytes")
        with path.open(encoding="utf-8") as f:
            return [d for d in yaml.safe_load_all(f) if d is not None]
    except FileNotFoundError:
        raise YamlFileError(f"no file {path}") from None
    except (OSError, UnicodeDecodeError) as err:
        raise YamlFileError(f"cannot read {path}: {err}") from None
    except yaml.YAMLError as err:
        raise YamlFileError(f"{path} is not valid YAML: {err}") from None


def write_whole(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically: a reader sees the old file or the new one, never half."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except OSError as err:
        raise YamlFileError(f"cannot write {path}: {err}") from None


def dump(data: Any) -> str:
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=False)


# -- nodes -------------------------------------------------------------------------------------
class LoadPoseStampedVectorFromYaml(Behavior):
    """MoveIt Pro's LoadPoseStampedVectorFromYaml."""

    description: ClassVar[str] = (
        "Read a vector of PoseStamped from a YAML file (one document per pose, '---' between them); "
        "a relative file_path is relative to the Objective's directory."
    )
    ports = (
        InputPort("file_path", PortType.STRING, description="The YAML file, e.g. place_poses.yaml."),
        OutputPort("output", PortType.POSE_STAMPED_LIST, "The poses, in file order."),
    )

    def update(self) -> Status:
        try:
            path = resolve(self, self.get_input("file_path"))
            documents = read_documents(path)
            if not documents:
                raise YamlFileError(f"{path} holds no poses")
            poses = [pose_from_dict(d, f"{path.name} document {i + 1}") for i, d in enumerate(documents)]
        except YamlFileError as err:
            return self.fail(str(err))
        self.set_output("output", poses)
        self.feedback_message = f"{len(poses)} poses from {path}"
        return Status.SUCCESS


class SavePoseStampedToYaml(Behavior):
    """MoveIt Pro's SavePoseStampedToYaml."""

    description: ClassVar[str] = (
        "Write a PoseStamped to <yaml_filename>.yaml in the Objective's directory; with a namespace the pose goes "
        "under that key, and overwrite=false keeps the file's other keys."
    )
    ports = (
        InputPort("message", PortType.POSE_STAMPED, description="The pose to save."),
        InputPort("yaml_filename", PortType.STRING, description="File name; .yaml is added when it has no extension."),
        InputPort("namespace", PortType.STRING, "", "Key to store the pose under (empty: the file is the pose)."),
        InputPort("overwrite", PortType.BOOL, True, "Replace the whole file; false keeps the other namespaces in it."),
    )

    def update(self) -> Status:
        pose = pose_to_dict(self.get_input("message"))
        namespace = self.get_input("namespace").strip()
        try:
            path = resolve(self, self.get_input("yaml_filename"), ".yaml")
            if not namespace:
                content: Any = pose
            else:
                content = {}
                if not self.get_input("overwrite") and path.exists():
                    existing = read_documents(path)
                    if existing and not isinstance(existing[0], dict):
                        raise YamlFileError(f"{path} does not hold a mapping of namespaces; cannot add '{namespace}'")
                    content = dict(existing[0]) if existing else {}
                content[namespace] = pose
            write_whole(path, dump(content))
        except YamlFileError as err:
            return self.fail(str(err))
        self.feedback_message = f"pose saved to {path}" + (f" under '{namespace}'" if namespace else "")
        return Status.SUCCESS


class SaveRobotJointStateToYaml(Behavior):
    """MoveIt Pro's SaveRobotJointStateToYaml."""

    description: ClassVar[str] = "Write a joint state to <yaml_filename>.yaml in the Objective's directory (under joint_state)."
    ports = (
        InputPort("message", PortType.JOINT_STATE, description="The joint state to save, e.g. from GetJointState."),
        InputPort("yaml_filename", PortType.STRING, description="File name; .yaml is added when it has no extension."),
    )

    def update(self) -> Status:
        try:
            path = resolve(self, self.get_input("yaml_filename"), ".yaml")
            write_whole(path, dump(joint_state_to_dict(self.get_input("message"))))
        except YamlFileError as err:
            return self.fail(str(err))
        self.feedback_message = f"joint state saved to {path}"
        return Status.SUCCESS


NODES = (LoadPoseStampedVectorFromYaml, SavePoseStampedToYaml, SaveRobotJointStateToYaml)

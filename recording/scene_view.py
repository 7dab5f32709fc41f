"""The robot and its planning scene as ROS 2 messages a 3D viewer draws (Foxglove, RViz).

- ``/tf`` and ``/tf_static``: every link's pose relative to its parent link, computed from a
  joint state with the planning model's forward kinematics, links behind a joint on ``/tf``, links
  fixed to their parent once on ``/tf_static`` (what ``robot_state_publisher`` publishes); in a
  recording the worker computes them from a ``TfModel`` this module builds (``tf_model``);
- ``/robot_markers``: one ``visualization_msgs/MarkerArray`` of the robot's collision geometry
  (capsules, cylinders, boxes, convex hulls as triangle lists), each marker locked to its link's
  frame, so the recorded ``/tf`` moves it; sent once, its CDR from the on-disk cache;
- ``/planning_scene_markers``: the planning scene's world objects (table, cubes, added
  objects) in ``world``, sent again whenever the scene's version changes (objects deleted from
  the scene are deleted from the view).

What is drawn is what the safety checks see (the collision model), not the rendered meshes.
Functions here build messages; ``SceneView`` decides when to send them.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import coal
import numpy as np
from numpy.typing import NDArray
import pinocchio as pin
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose
from std_msgs.msg import ColorRGBA
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from runtime.app.disk_cache import cached, content_key
from runtime.motion.scene.collision import Box, Capsule, Cylinder, Mesh, Sphere
from .event_messages import stamp_of  # noqa: F401  (where the tests and the recorder find it)
from .mcap_writer import SerializedMessage, cdr_bytes
from .tf_model import TF_STATIC_TOPIC, TF_TOPIC, LinkDriver, LinkTf, TfModel, TfTemplate, link_coefficients

WORLD_FRAME = "world"
ROBOT_MARKERS_TOPIC = "/robot_markers"
SCENE_MARKERS_TOPIC = "/planning_scene_markers"

SCENE_MARKERS_PERIOD_S = 0.2
"""The scene's objects are sent at most this often (clock time): cubes pushed by the gripper
change the scene at every physics step, and 5 Hz is enough to watch (a carried cube is drawn in
its link's frame, so it follows /tf at the joint states' rate)."""

ROBOT_RGBA = (0.62, 0.66, 0.72, 1.0)
TABLE_RGBA = (0.55, 0.42, 0.30, 1.0)
OBJECT_RGBA = (0.85, 0.55, 0.15, 0.9)
NAMED_RGBA = {"red": (0.85, 0.15, 0.15, 1.0), "green": (0.15, 0.7, 0.25, 1.0), "blue": (0.15, 0.3, 0.85, 1.0)}


def pose_msg(transform: pin.SE3) -> Pose:
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in transform.translation)
    x, y, z, w = pin.Quaternion(transform.rotation).coeffs()
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = float(x), float(y), float(z), float(w)
    return pose


def _rgba(values: tuple[float, float, float, float]) -> ColorRGBA:
    return ColorRGBA(r=values[0], g=values[1], b=values[2], a=values[3])


def object_color(name: str) -> tuple[float, float, float, float]:
    """Objects named after a colour (``cube_blue``) are drawn in it; the table in wood."""
    if name == "table":
        return TABLE_RGBA
    for word, rgba in NAMED_RGBA.items():
        if word in name.split("_"):
            return rgba
    return OBJECT_RGBA


@dataclass
class LinkTree:
    """Parent of every link (BODY frame) of a robot model, ``world`` for the root; which links
    move relative to their parent (a joint between them) and which are fixed to it."""

    model: pin.Model
    data: pin.Data
    frame_ids: dict[str, int]
    parents: dict[str, str]
    moving: tuple[str, ...]
    fixed: tuple[str, ...]

    @classmethod
    def of(cls, robot: Any) -> "LinkTree":
        parents = {link: robot.parent_link(link) for link in robot.link_names if link != "universe"}
        parents = {link: (WORLD_FRAME if parent in ("universe", link) else parent) for link, parent in parents.items()}
        frame_ids = {link: robot.frame_id(link) for link in parents}

        def joint_of(link: str) -> int:
            return 0 if link == WORLD_FRAME else robot.model.frames[frame_ids[link]].parentJoint

        moving = tuple(link for link, parent in parents.items() if joint_of(link) != joint_of(parent))
        fixed = tuple(link for link in parents if link not in moving)
        return cls(robot.model, robot.model.createData(), frame_ids, parents, moving, fixed)


@dataclass(frozen=True)
class JointMap:
    """A joint state's positions (in one order of names) to the robot's full configuration, as
    ``robot.configuration`` computes it, precomputed once per order (it runs at 50 Hz)."""

    neutral: NDArray[np.float64]
    rows: NDArray[np.float64]
    """For each configuration entry set: which position sets it..."""
    q_index: NDArray[np.intp]
    """...which entry of q it is..."""
    multiplier: NDArray[np.float64]
    offset: NDArray[np.float64]
    """...and how (a coupled joint follows its driver: multiplier * value + offset)."""

    @classmethod
    def of(cls, robot: Any, names: tuple[str, ...]) -> "JointMap | None":
        """None where it cannot (a joint unknown to the model, or one of two entries in q)."""
        entries: dict[int, tuple[int, float, float]] = {}
        for row, name in enumerate(names):
            if name not in robot.movable_joints:
                return None
            for target, multiplier, offset in robot.driven_by(name):
                if robot.model.joints[robot.model.getJointId(target)].nq != 1:
                    return None
                entries[robot.joint_q_index(target)] = (row, multiplier, offset)  # the last one wins, as there
        rows, multipliers, offsets = zip(*entries.values()) if entries else ((), (), ())
        return cls(np.asarray(robot.neutral(), dtype=float), np.array(rows, dtype=int), np.array(list(entries), dtype=int),
                   np.array(multipliers, dtype=float), np.array(offsets, dtype=float))

    def configuration(self, positions: Any) -> NDArray[np.float64]:
        q = self.neutral.copy()
        q[self.q_index] = self.multiplier * np.asarray(positions, dtype=float)[self.rows] + self.offset
        return q


class TfEncoder:
    """Turns a configuration into the serialized TFMessage of a fixed list of links.

    Written as CDR directly into a prepared buffer (the frame names never change; only the
    stamps and the seven numbers per link do): building rosidl TransformStamped objects 50
    times a second cost more than the rest of the recording together."""

    def __init__(self, tree: LinkTree, links: tuple[str, ...]) -> None:
        self.tree = tree
        self.links = links
        self._frames = [(tree.frame_ids.get(tree.parents[link]), tree.frame_ids[link]) for link in links]
        template = TfTemplate([(tree.parents[link], link) for link in links])
        self._buffer, self._stamp_at, self._values_at = template.buffer, template.stamp_at, template.values_at

    def encode(self, q: NDArray[np.float64], stamp: Time) -> SerializedMessage:
        data = self.tree.data
        pin.framesForwardKinematics(self.tree.model, data, q)
        poses = data.oMf
        buffer = self._buffer
        stamp_bytes = _STAMP.pack(stamp.sec, stamp.nanosec)
        for (parent, child), stamp_at, values_at in zip(self._frames, self._stamp_at, self._values_at):
            relative = poses[child] if parent is None else poses[parent].actInv(poses[child])
            buffer[stamp_at:stamp_at + 8] = stamp_bytes
            _XYZQUAT.pack_into(buffer, values_at, *pin.SE3ToXYZQUAT(relative).tolist())  # x y z qx qy qz qw
        return SerializedMessage(TFMessage, bytes(buffer))


_STAMP = struct.Struct("<iI")
_XYZQUAT = struct.Struct("<7d")


_REVOLUTE = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0), "JointModelRZ": (0.0, 0.0, 1.0),
             "JointModelRUBX": (1.0, 0.0, 0.0), "JointModelRUBY": (0.0, 1.0, 0.0), "JointModelRUBZ": (0.0, 0.0, 1.0)}
_PRISMATIC = {"JointModelPX": (1.0, 0.0, 0.0), "JointModelPY": (0.0, 1.0, 0.0), "JointModelPZ": (0.0, 0.0, 1.0)}
_UNALIGNED = {"JointModelRevoluteUnaligned": "revolute", "JointModelRevoluteUnboundedUnaligned": "revolute",
              "JointModelPrismaticUnaligned": "prismatic"}


def _joint_motion(joint: Any) -> tuple[str, NDArray[np.float64]] | None:
    """(kind, unit axis) of a one-axis joint; None for any other (spherical, free-flyer...)."""
    name = joint.shortname()
    if name in _REVOLUTE:
        return "revolute", np.array(_REVOLUTE[name])
    if name in _PRISMATIC:
        return "prismatic", np.array(_PRISMATIC[name])
    if name in _UNALIGNED:
        axis = np.asarray(joint.extract().axis, dtype=float)
        return _UNALIGNED[name], axis / np.linalg.norm(axis)
    return None


def _neutral_value(model: pin.Model, joint: int) -> float:
    q, j = pin.neutral(model), model.joints[joint]
    return float(np.arctan2(q[j.idx_q + 1], q[j.idx_q])) if j.nq == 2 else float(q[j.idx_q])


def tf_model(robot: Any, tree: LinkTree) -> TfModel | None:
    """What the recording worker needs to compute ``/tf`` and ``/tf_static`` for ``robot``
    (``recording.tf_model``); None where a link is more than one joint, or a joint with
    more than one axis, away from its parent link (the run then computes ``/tf`` itself)."""
    model = robot.model
    drivers: dict[str, list[LinkDriver]] = {}
    for name in robot.movable_joints:
        for target, multiplier, offset in robot.driven_by(name):
            drivers.setdefault(target, []).append(LinkDriver(name, float(multiplier), float(offset)))

    def placement(link: str) -> pin.SE3:
        return pin.SE3.Identity() if link == WORLD_FRAME else model.frames[tree.frame_ids[link]].placement

    def joint_of(link: str) -> int:
        return 0 if link == WORLD_FRAME else model.frames[tree.frame_ids[link]].parentJoint

    def link_tf(link: str) -> LinkTf | None:
        parent = tree.parents[link]
        joint, parent_joint, after = joint_of(link), joint_of(parent), placement(link)
        if joint == parent_joint:
            before = placement(parent).inverse()
            kind, axis, name = "fixed", None, ""
        else:
            motion = _joint_motion(model.joints[joint])
            if model.parents[joint] != parent_joint or motion is None:
                return None
            before = placement(parent).inverse() * model.jointPlacements[joint]
            (kind, axis), name = motion, model.names[joint]
        coefficients = link_coefficients((before.rotation, before.translation), kind, axis,
                                         (after.rotation, after.translation))
        neutral = 0.0 if kind == "fixed" else _neutral_value(model, joint)
        return LinkTf(parent, link, tuple(tuple(float(v) for v in row) for row in coefficients),
                      tuple(drivers.get(name, ())), neutral)

    moving = [link_tf(link) for link in tree.moving]
    fixed = [link_tf(link) for link in tree.fixed]
    if any(link is None for link in (*moving, *fixed)):
        return None
    return TfModel(tuple(moving), tuple(fixed))  # type: ignore[arg-type]


def _hull_triangles(hull: Any) -> NDArray[np.float64]:
    """(3 * n_triangles, 3) vertices of a coal convex hull, as a triangle list."""
    points = np.asarray(hull.points())
    indices = np.array([[hull.polygons(i)[k] for k in range(3)] for i in range(hull.num_polygons)], dtype=int)
    result: NDArray[np.float64] = points[indices.reshape(-1)]
    return result


def _shape_markers(geometry: Any, pose: pin.SE3) -> list[Marker]:
    """Markers (without header, id or colour) drawing one collision geometry at ``pose``."""
    def marker(kind: int, at: pin.SE3, sx: float, sy: float, sz: float) -> Marker:
        m = Marker(type=kind, action=Marker.ADD, pose=pose_msg(at))
        m.scale.x, m.scale.y, m.scale.z = float(sx), float(sy), float(sz)
        return m

    if isinstance(geometry, (coal.Box, Box)):
        size = 2 * np.asarray(geometry.halfSide) if isinstance(geometry, coal.Box) else geometry.size
        return [marker(Marker.CUBE, pose, *size)]
    if isinstance(geometry, (coal.Sphere, Sphere)):
        return [marker(Marker.SPHERE, pose, *(2 * geometry.radius,) * 3)]
    if isinstance(geometry, (coal.Cylinder, Cylinder)):
        length = 2 * geometry.halfLength if isinstance(geometry, coal.Cylinder) else geometry.length
        return [marker(Marker.CYLINDER, pose, 2 * geometry.radius, 2 * geometry.radius, length)]
    if isinstance(geometry, (coal.Capsule, Capsule)):
        half = geometry.halfLength if isinstance(geometry, coal.Capsule) else geometry.length / 2
        d = 2 * geometry.radius
        ends = [pose * pin.SE3(np.eye(3), np.array([0.0, 0.0, z])) for z in (-half, half)]
        return [marker(Marker.CYLINDER, pose, d, d, 2 * half)] + [marker(Marker.SPHERE, e, d, d, d) for e in ends]
    if isinstance(geometry, coal.ConvexBase):
        m = marker(Marker.TRIANGLE_LIST, pose, 1.0, 1.0, 1.0)
        m.points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in _hull_triangles(geometry)]
        return [m]
    if isinstance(geometry, Mesh):
        return []  # a world mesh is drawn through its collision hull once it is in the model
    return []


def robot_markers(robot: Any, stamp: Time) -> MarkerArray:
    """The robot's collision geometry, each marker in its link's frame (``frame_locked``)."""
    out = MarkerArray()
    for go in robot.collision_model.geometryObjects:
        link = robot.link_of_frame(go.parentFrame)
        link_in_joint = robot.model.frames[robot.frame_id(link)].placement
        pose = link_in_joint.actInv(go.placement)  # geometry placements are relative to the joint
        for m in _shape_markers(go.geometry, pose):
            m.header.frame_id = link
            m.header.stamp = stamp
            m.ns = "robot"
            m.id = len(out.markers)
            m.frame_locked = True
            m.color = _rgba(ROBOT_RGBA)
            out.markers.append(m)
    return out


_SENTINEL = Time(sec=2_147_480_000, nanosec=999_999_937)
"""A stamp no marker field holds: where it lands in the CDR is where each marker's stamp goes."""
_OFFSET = struct.Struct("<I")


def _geometry_digest(robot: Any) -> str:
    """What the robot's markers are made of: each collision geometry's link, placement, kind and
    size (a convex hull's vertices), and this module's code."""
    parts: list[str | bytes] = [Path(__file__).read_bytes(), pin.__version__, coal.__version__]
    for go in robot.collision_model.geometryObjects:
        link = robot.link_of_frame(go.parentFrame)
        geometry = go.geometry
        parts += [link, type(geometry).__name__, robot.model.frames[robot.frame_id(link)].placement.homogeneous.tobytes(),
                  go.placement.homogeneous.tobytes()]
        if isinstance(geometry, coal.ConvexBase):
            parts += [np.asarray(geometry.points()).tobytes(), str(geometry.num_polygons)]
        else:
            parts += [repr([getattr(geometry, a, None) for a in ("halfSide", "radius", "halfLength", "size", "length")])]
    return content_key(*parts)


def _stamped_template(robot: Any) -> bytes:
    """The robot's markers in CDR, stamped ``_SENTINEL``, after the offsets of those stamps
    (a count, then each offset: little-endian uint32)."""
    markers = robot_markers(robot, _SENTINEL)
    data = cdr_bytes(markers)
    sentinel = _STAMP.pack(_SENTINEL.sec, _SENTINEL.nanosec)
    offsets, at = [], data.find(sentinel)
    while at >= 0:
        offsets.append(at)
        at = data.find(sentinel, at + 1)
    if len(offsets) != len(markers.markers):
        raise ValueError("the sentinel stamp is not where the markers' stamps are")
    return _OFFSET.pack(len(offsets)) + b"".join(_OFFSET.pack(o) for o in offsets) + data


def _stamp_template(template: bytes, stamp: Time) -> bytes:
    (count,) = _OFFSET.unpack_from(template)
    data = bytearray(template[4 + 4 * count:])
    stamp_bytes = _STAMP.pack(stamp.sec, stamp.nanosec)
    for k in range(count):
        (at,) = _OFFSET.unpack_from(template, 4 + 4 * k)
        data[at:at + 8] = stamp_bytes
    return bytes(data)


def robot_markers_cdr(robot: Any, stamp: Time) -> SerializedMessage:
    """``robot_markers`` serialized, from the on-disk cache (``runtime.app.disk_cache``) when the
    robot's collision geometry is what it was: building them is a tenth of a second of Python
    (thousands of triangle vertices) that every recorded run would pay."""
    try:
        template = cached("robot_markers", _geometry_digest(robot), lambda: _stamped_template(robot), _checked_template)
    except ValueError:
        return SerializedMessage(MarkerArray, cdr_bytes(robot_markers(robot, stamp)))
    return SerializedMessage(MarkerArray, _stamp_template(template, stamp))


def _checked_template(data: bytes) -> bytes:
    (count,) = _OFFSET.unpack_from(data)
    if len(data) < 4 + 4 * count + 8 or data[4 + 4 * count:8 + 4 * count] != b"\x00\x01\x00\x00":
        raise ValueError("not a stamped MarkerArray template")
    return data


def object_markers(objects: dict[str, Any], attachments: tuple[Any, ...], stamp: Time,
                   previous: dict[str, int] | None = None) -> MarkerArray:
    """The scene's world objects in ``world`` and the objects the robot carries, locked to their
    link; the markers of ``previous`` (name -> marker count) that are gone now are deleted."""
    placed = [(name, WORLD_FRAME, obj.shape, obj.pose) for name, obj in objects.items()]
    placed += [(a.name, a.link, a.shape, a.pose) for a in attachments]
    out = MarkerArray()
    for name, frame, shape, pose in sorted(placed, key=lambda p: p[0]):
        for k, m in enumerate(_shape_markers(shape, pin.SE3(np.asarray(pose, dtype=float).reshape(4, 4)))):
            m.header.frame_id = frame
            m.header.stamp = stamp
            m.ns = name
            m.id = k
            m.frame_locked = frame != WORLD_FRAME
            m.color = _rgba(object_color(name))
            out.markers.append(m)
    drawn = marker_counts(out)
    for name, count in sorted((previous or {}).items()):
        out.markers += [Marker(ns=name, id=k, action=Marker.DELETE) for k in range(drawn.get(name, 0), count)]
    return out


def marker_counts(markers: MarkerArray) -> dict[str, int]:
    counts: dict[str, int] = {}
    for m in markers.markers:
        if m.action == Marker.ADD:
            counts[m.ns] = counts.get(m.ns, 0) + 1
    return counts


class SceneView:
    """Sends ``/tf`` with every recorded joint state, ``/tf_static`` and the robot's markers once,
    and the scene's objects whenever the scene changes. ``scene`` is read lazily: worlds create it on start.

    With ``send_tf_model``, the recording worker computes ``/tf`` and ``/tf_static`` from the
    joint states it receives: this view sends it the robot's ``TfModel`` once (per robot) and
    computes nothing per joint state but the scene's markers (``tf_here`` turns that off again,
    e.g. when the worker is lost). A robot the model cannot describe gets its ``/tf`` here."""

    def __init__(self, scene: Callable[[], Any], write: Callable[[str, Any, float], None],
                 stamp: Callable[[float], Time], send_tf_model: Callable[[TfModel | None], None] | None = None) -> None:
        self._scene = scene
        self._write = write
        self._stamp = stamp
        self._send_tf_model = send_tf_model
        self._tf: TfEncoder | None = None
        """The run's own ``/tf`` encoder (None while the worker computes it)."""
        self._robot: Any = None
        self._joint_maps: dict[tuple[str, ...], JointMap | None] = {}
        self._scene_version: Any = None
        self._scene_sent_s = -float("inf")
        self._objects: dict[str, int] = {}

    def tf_here(self) -> None:
        """Compute ``/tf`` in this process from now on (``/tf_static`` and the markers are sent
        again with the next joint state)."""
        self._send_tf_model = None
        self._robot = None

    def joint_state(self, msg: Any, seconds: float) -> None:
        scene = self._scene()
        robot = getattr(scene, "robot", None)
        if robot is None:
            return
        if robot is not self._robot:
            self._new_robot(robot, msg, seconds)
        if self._tf is not None:
            self._write(TF_TOPIC, self._tf.encode(self._configuration(robot, msg), self._stamp(seconds)), seconds)
        version = scene.version
        if version != self._scene_version and seconds - self._scene_sent_s >= SCENE_MARKERS_PERIOD_S - 1e-9:
            self._scene_version, self._scene_sent_s = version, seconds
            objects, attachments = scene.objects, scene.attachments
            markers = object_markers(objects, attachments, self._stamp(seconds), self._objects)
            self._write(SCENE_MARKERS_TOPIC, markers, seconds)
            self._objects = marker_counts(markers)

    def _new_robot(self, robot: Any, msg: Any, seconds: float) -> None:
        """``/tf_static`` (or the worker's ``TfModel``) and the robot's markers, for a robot seen first."""
        self._robot, self._tf = robot, None
        self._joint_maps.clear()
        tree = LinkTree.of(robot)
        model = tf_model(robot, tree) if self._send_tf_model is not None else None
        stamp = self._stamp(seconds)
        if self._send_tf_model is not None:
            self._send_tf_model(model)  # (None: the worker stops, this view computes /tf)
        if model is None:
            self._tf = TfEncoder(tree, tree.moving)
            self._write(TF_STATIC_TOPIC, TfEncoder(tree, tree.fixed).encode(self._configuration(robot, msg), stamp), seconds)
        self._write(ROBOT_MARKERS_TOPIC, robot_markers_cdr(robot, stamp), seconds)

    def _configuration(self, robot: Any, msg: Any) -> NDArray[np.float64]:
        names = tuple(msg.name)
        if names not in self._joint_maps:
            self._joint_maps[names] = JointMap.of(robot, names)
        joint_map = self._joint_maps[names]
        return joint_map.configuration(msg.position) if joint_map is not None else robot.configuration(dict(zip(names, msg.position)))

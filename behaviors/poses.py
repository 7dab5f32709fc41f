"""Poses on the blackboard: read them from the planning scene, transform them, compare them.

A pose on the blackboard is a ``geometry_msgs/PoseStamped``: ``header.frame_id`` names the frame
the pose is expressed in, ``pose.position`` is in metres and ``pose.orientation`` is a unit
quaternion (x, y, z, w), exactly what a ROS node would publish, so a pose written here can be
handed to any behavior that expects one.

Frames that the nodes here understand:

- ``world`` (also spelled ``universe``, pinocchio's name for it): the planning scene's root;
- every frame of the robot model (links such as ``wrist_3_link``, sites such as ``tcp``), placed
  by forward kinematics at the robot's current joint state (read from ``/joint_states``);
- every planning-scene object (``cube_red``, ``table``...), attached ones included.

The math is in pure functions (``pose_to_matrix``, ``matrix_to_pose``, ``stack_check``...);
the node classes only read ports, ask the scene and write results.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from geometry_msgs.msg import Pose, PoseStamped
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from runtime.tree.behavior import Behavior, Condition, Status
from runtime.io.timestamps import time_msg
from runtime.tree.ports import InputPort, NameKind, Names, OutputPort, PortType, Range
from runtime.errors import ObjectiveError, SetupError
from runtime.motion.scene import PlanningScene

from .visualization import axis_markers, text_marker

WORLD_FRAME = "world"
WORLD_ALIASES = (WORLD_FRAME, "universe")
JOINT_STATES_TOPIC = "/joint_states"
MARKER_TOPIC = "/visual_markers"


# -- pure math -------------------------------------------------------------------------------
def pose_to_matrix(pose: Pose) -> NDArray[np.float64]:
    """4x4 homogeneous matrix of a ``geometry_msgs/Pose`` (the quaternion is normalised)."""
    q = pose.orientation
    quat = np.array([q.x, q.y, q.z, q.w], dtype=float)
    norm = float(np.linalg.norm(quat))
    if not math.isfinite(norm) or norm < 1e-9:
        raise ValueError(f"orientation quaternion (x, y, z, w) = {tuple(quat)} is not a rotation (zero length)")
    from scipy.spatial.transform import Rotation  # scipy.spatial: ~0.3 s, imported on first use

    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(quat / norm).as_matrix()
    m[:3, 3] = (pose.position.x, pose.position.y, pose.position.z)
    if not np.all(np.isfinite(m)):
        raise ValueError("pose position is not finite")
    return m


def matrix_to_pose(frame_id: str, matrix: NDArray[np.float64], stamp: float = 0.0) -> PoseStamped:
    """A ``PoseStamped`` in ``frame_id`` from a 4x4 matrix, stamped ``stamp`` seconds."""
    msg = PoseStamped()
    msg.header.frame_id = frame_id
    msg.header.stamp = time_msg(stamp)
    from scipy.spatial.transform import Rotation  # scipy.spatial: ~0.3 s, imported on first use

    x, y, z = (float(v) for v in matrix[:3, 3])
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x, y, z
    qx, qy, qz, qw = (float(v) for v in Rotation.from_matrix(matrix[:3, :3]).as_quat())
    if qw < 0:  # one spelling per rotation: w >= 0
        qx, qy, qz, qw = -qx, -qy, -qz, -qw
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = qx, qy, qz, qw
    return msg


def offset_matrix(translation_xyz: list[float], quaternion_xyzw: list[float]) -> NDArray[np.float64]:
    """The 4x4 offset of TransformPose's ports; raises ValueError naming the bad port."""
    if len(translation_xyz) != 3:
        raise ValueError(f"translation_xyz needs 3 values (x;y;z), got {len(translation_xyz)}")
    if len(quaternion_xyzw) != 4:
        raise ValueError(f"quaternion_xyzw needs 4 values (x;y;z;w), got {len(quaternion_xyzw)}")
    quat = np.asarray(quaternion_xyzw, dtype=float)
    norm = float(np.linalg.norm(quat))
    if not math.isfinite(norm) or norm < 1e-9:
        raise ValueError(f"quaternion_xyzw {list(quaternion_xyzw)} is not a rotation (zero length)")
    from scipy.spatial.transform import Rotation  # scipy.spatial: ~0.3 s, imported on first use

    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(quat / norm).as_matrix()
    m[:3, 3] = translation_xyz
    return m


def rotation_angle(matrix: NDArray[np.float64]) -> float:
    """Angle (rad, in [0, pi]) of the rotation part of a 4x4 (or 3x3) matrix."""
    r = np.asarray(matrix)[:3, :3]
    return float(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)))


@dataclass(frozen=True)
class StackCheck:
    """The answer of ``stack_check``, with the numbers behind it (for the failure message)."""

    stacked: bool
    offset_error: float
    """Metres between the top object's centre and the point it should be at."""
    clearance: float
    """Metres between the gripper frame and the top object's centre."""
    reason: str


def stack_check(
    top_center: NDArray[np.float64],
    bottom_center: NDArray[np.float64],
    gripper_position: NDArray[np.float64],
    stack_height: float,
    position_tolerance: float,
    min_clearance: float,
) -> StackCheck:
    """Is the top object resting on the bottom one, and has the gripper let go of it?

    The top centre must be within ``position_tolerance`` of the point ``stack_height`` straight
    above (world +z) the bottom centre. Only centres are compared, so it does not matter which
    face either cube rests on. The gripper frame must be at least ``min_clearance`` away from
    the top centre: a cube still held in the air above the other one is not stacked.
    """
    target = np.asarray(bottom_center, dtype=float) + np.array([0.0, 0.0, stack_height])
    delta = np.asarray(top_center, dtype=float) - target
    error = float(np.linalg.norm(delta))
    clearance = float(np.linalg.norm(np.asarray(gripper_position, dtype=float) - np.asarray(top_center, dtype=float)))
    where = f"{error * 1000:.1f} mm from the stacked position (dx {delta[0] * 1000:+.1f}, dy {delta[1] * 1000:+.1f}, dz {delta[2] * 1000:+.1f} mm)"
    if error > position_tolerance:
        return StackCheck(False, error, clearance, f"not stacked: {where}, tolerance {position_tolerance * 1000:.1f} mm")
    if clearance < min_clearance:
        return StackCheck(
            False, error, clearance,
            f"stacked but the gripper is {clearance * 1000:.1f} mm from the top object (needs {min_clearance * 1000:.1f} mm): not released",
        )
    return StackCheck(True, error, clearance, f"stacked: {where}; gripper {clearance * 1000:.1f} mm away")


# -- the robot's current state and where frames are ---------------------------------------------
def pose_markers(pose: PoseStamped, namespace: str, text: str, size_m: float, lifetime_s: float) -> MarkerArray:
    """A pose drawn as three arrows (x red, y green, z blue) of length ``size_m`` from its origin,
    plus ``text`` above it when not empty (``behaviors.visualization``'s markers, as VisualizePose
    draws them); ``lifetime_s`` 0 keeps them until they are replaced (same ``namespace`` and ids)."""
    if not size_m > 0:
        raise ValueError(f"marker_size must be a positive length in metres, got {size_m}")
    if not lifetime_s >= 0:
        raise ValueError(f"marker_lifetime must be 0 (forever) or a positive number of seconds, got {lifetime_s}")
    markers = axis_markers(namespace, 0, pose, size_m, lifetime_s)
    if text:
        markers.append(text_marker(namespace, len(markers), pose, text, size_m, lifetime_s))
    return MarkerArray(markers=markers)


class FrameError(ObjectiveError, LookupError):
    """A frame's pose that cannot be told yet: no joint states, or states without the needed joints.
    (A frame or object the scene does not know is a ``SetupError``: the run ends as ERROR.)"""


class RobotState:
    """The latest ``/joint_states`` message, turned into joint positions or a scene row.

    Nodes subscribe in ``setup()`` (the runner calls it after the world started and before the
    first tick), so the subscription has a message by the time the node first ticks and a
    Condition can answer in that tick.
    """

    def __init__(self, subscription: Any, topic: str = JOINT_STATES_TOPIC) -> None:
        self.topic = topic
        self.subscription = subscription

    @classmethod
    def subscribe(cls, bus: Any, topic: str = JOINT_STATES_TOPIC) -> RobotState:
        return cls(bus.create_subscription(topic, JointState, reliable=True), topic)

    def positions(self, joints: tuple[str, ...] | list[str]) -> NDArray[np.float64]:
        """Current positions of ``joints``; FrameError when no message arrived or one is missing."""
        state = self.subscription.latest
        if state is None:
            raise FrameError(f"no joint states on '{self.topic}' yet")
        by_name = dict(zip(state.name, state.position))
        missing = [j for j in joints if j not in by_name]
        if missing:
            raise FrameError(f"joint states on '{self.topic}' lack {', '.join(missing)}")
        return np.array([by_name[j] for j in joints], dtype=float)

    def row(self, scene: Any) -> NDArray[np.float64]:
        """The scene's default layout row: group joints, plus the gripper when it is published
        under the scene's gripper joint name (otherwise the scene's reference value is used)."""
        layout = scene.layout()
        row = self.positions(layout.group.joints)
        state = self.subscription.latest
        if layout.gripper_joint is not None and layout.gripper_joint in state.name:
            row = np.append(row, state.position[list(state.name).index(layout.gripper_joint)])
        return row


def known_frames(scene: Any) -> str:
    """The frame names a failure message lists: world, robot links, scene objects."""
    objects = sorted(scene.objects) + sorted(a.name for a in scene.attachments)
    return f"'{WORLD_FRAME}', robot links ({', '.join(scene.robot.link_names)}) or scene objects ({', '.join(objects) or 'none'})"


def frame_in_world(scene: PlanningScene, frame: str, state: RobotState | None) -> NDArray[np.float64]:
    """World pose (4x4) of ``world``, a robot frame or a scene object (attached ones too)."""
    if frame in WORLD_ALIASES:
        return np.eye(4)
    if frame in scene.objects:
        return scene.object_pose(frame)
    attached = {a.name for a in scene.attachments}
    if scene.robot.has_frame(frame) or frame in attached:
        if state is None:
            raise FrameError(f"the pose of '{frame}' needs the robot's joint states, and none are read here")
        row = state.row(scene)
        if frame in attached:
            return scene.object_world_pose(frame, row)
        return scene.link_pose(row, frame)
    raise SetupError(f"unknown frame '{frame}' (known: {known_frames(scene)})")


def pose_in_world(scene: Any, pose: PoseStamped, state: RobotState | None) -> NDArray[np.float64]:
    return frame_in_world(scene, pose.header.frame_id or WORLD_FRAME, state) @ pose_to_matrix(pose.pose)


def as_pose_stamped(value: Any, port: str) -> PoseStamped:
    if not isinstance(value, PoseStamped):
        raise ValueError(f"port '{port}' expects a geometry_msgs/PoseStamped, got {type(value).__name__}")
    return value


# -- nodes -----------------------------------------------------------------------------------
class ReadsRobotState:
    """Mixin for nodes that place robot frames: subscribes to the joint states in ``setup``, so
    the subscription holds a message by the first tick (a Condition must answer in it)."""

    context: Any
    robot_state: RobotState | None = None

    def setup(self, **kwargs: Any) -> None:
        self.robot_state = RobotState.subscribe(self.context.bus)

    def state(self) -> RobotState:
        if self.robot_state is None:  # ticked without setup (e.g. a unit test)
            self.robot_state = RobotState.subscribe(self.context.bus)
        return self.robot_state

    def now(self) -> float:
        now: float = self.context.clock.now()
        return now


class SceneBehavior(ReadsRobotState, Behavior):
    """An Action on the planning scene. ``needs_world``: the world the runner starts fills the scene."""

    needs_world = True


NO_SCENE = "this run has no planning scene (no world was started)"


class GetObjectPose(SceneBehavior):
    """The pose of a planning-scene object (e.g. a cube) in the world frame."""

    description = "Write the world-frame pose (PoseStamped) of a planning-scene object, e.g. cube_red."
    ports = (
        InputPort("object_name", PortType.STRING, description="Planning-scene object, e.g. cube_red.", names=Names(NameKind.OBJECT)),
        OutputPort("pose", PortType.ANY, "The object's pose (geometry_msgs/PoseStamped, frame 'world')."),
    )

    def update(self) -> Status:
        scene = self.context.scene
        if scene is None:
            return self.fail(NO_SCENE)
        name = self.get_input("object_name")
        attached = {a.name for a in scene.attachments}
        if name not in scene.objects and name not in attached:
            known = sorted(scene.objects) + sorted(attached)
            raise SetupError(f"no object '{name}' in the planning scene (objects: {', '.join(known) or 'none'})")
        try:
            matrix = frame_in_world(scene, name, self.state())
        except FrameError as err:
            return self.fail(str(err))
        self.set_output("pose", matrix_to_pose(WORLD_FRAME, matrix, self.now()))
        return Status.SUCCESS


class GetLatestTransform(SceneBehavior):
    """Where ``source_frame`` is, seen from ``target_frame``, right now (like tf2's lookupTransform)."""

    description = "Write the pose of source_frame expressed in target_frame (world, robot links, scene objects) as a PoseStamped."
    ports = (
        InputPort("target_frame", PortType.STRING, WORLD_FRAME, "Frame the result is expressed in.", names=Names(NameKind.FRAME)),
        InputPort("source_frame", PortType.STRING, description="Frame whose pose is looked up, e.g. tcp or cube_blue.",
                  names=Names(NameKind.FRAME)),
        OutputPort("transform", PortType.ANY, "Pose of source_frame in target_frame (geometry_msgs/PoseStamped)."),
    )

    def update(self) -> Status:
        scene = self.context.scene
        if scene is None:
            return self.fail(NO_SCENE)
        target, source = self.get_input("target_frame"), self.get_input("source_frame")
        try:
            relative = np.linalg.inv(frame_in_world(scene, target, self.state())) @ frame_in_world(scene, source, self.state())
        except FrameError as err:
            return self.fail(str(err))
        self.set_output("transform", matrix_to_pose(target, relative, self.now()))
        return Status.SUCCESS


class TransformPose(SceneBehavior):
    """Re-express a pose in another frame, after moving it by an offset in its own frame.

    The offset is applied first, in the input pose's own axes (``translation_xyz`` 0;0;-0.1 on a
    pose whose z points down into a cube moves it 10 cm up, away from the cube), then the result
    is expressed in ``target_frame_id``.
    """

    description = "Apply an offset (in the pose's own axes) to a PoseStamped and express it in another frame."
    ports = (
        InputPort("input_pose", PortType.ANY, description="The pose to transform (geometry_msgs/PoseStamped), e.g. {cube_pose}."),
        InputPort("target_frame_id", PortType.STRING, WORLD_FRAME, "Frame to express the result in.", names=Names(NameKind.FRAME)),
        InputPort("translation_xyz", PortType.FLOAT_LIST, "0;0;0", "Offset x;y;z (m) in the input pose's own axes.", valid=Range(-100.0, 100.0, "m")),
        InputPort("quaternion_xyzw", PortType.FLOAT_LIST, "0;0;0;1", "Rotation offset x;y;z;w in the input pose's own axes.", valid=Range(-1.0, 1.0)),
        InputPort("visualize_pose", PortType.BOOL, False, f"Also draw the result on {MARKER_TOPIC} (visualization_msgs/MarkerArray: axes x red, y green, z blue)."),
        InputPort("marker_text", PortType.STRING, "", "Label drawn above the pose (empty: none)."),
        InputPort("marker_size", PortType.FLOAT, 0.1, "Length of the drawn axes (m).", valid=Range(0.0, 10.0, "m")),
        InputPort("marker_lifetime", PortType.FLOAT, 0.0, "Seconds the drawing stays; 0: until the node draws again.", valid=Range(0.0, 86400.0, "s")),
        OutputPort("output_pose", PortType.ANY, "The transformed pose (geometry_msgs/PoseStamped)."),
    )
    marker_publisher = None

    def update(self) -> Status:
        scene = self.context.scene
        if scene is None:
            return self.fail(NO_SCENE)
        target = self.get_input("target_frame_id")
        try:
            pose = as_pose_stamped(self.get_input("input_pose"), "input_pose")
            offset = offset_matrix(self.get_input("translation_xyz"), self.get_input("quaternion_xyzw"))
            in_world = pose_in_world(scene, pose, self.state()) @ offset
            result = np.linalg.inv(frame_in_world(scene, target, self.state())) @ in_world
            output = matrix_to_pose(target, result, self.now())
            markers = self._markers(output)
        except (ValueError, FrameError) as err:
            return self.fail(str(err))
        if markers is not None:
            if self.marker_publisher is None:
                self.marker_publisher = self.context.bus.create_publisher(MARKER_TOPIC, MarkerArray)
            self.marker_publisher.publish(markers)
        self.set_output("output_pose", output)
        return Status.SUCCESS

    def _markers(self, pose: PoseStamped) -> MarkerArray | None:
        if not self.get_input("visualize_pose"):
            return None
        return pose_markers(pose, self.name, self.get_input("marker_text"), self.get_input("marker_size"), self.get_input("marker_lifetime"))


class IsPoseNearIdentity(Condition):
    """SUCCESS when a pose is the identity within tolerances (e.g. a transform between two
    frames that should coincide)."""

    description = "SUCCESS when a PoseStamped is within the position and rotation tolerances of the identity."
    ports = (
        InputPort("pose", PortType.ANY, description="The pose to test (geometry_msgs/PoseStamped), e.g. {transform}."),
        InputPort("position_tolerance", PortType.FLOAT, 0.01, "Largest distance from the origin (m).", valid=Range(0.0, 100.0, "m")),
        InputPort("rotation_tolerance", PortType.FLOAT, 0.01, "Largest rotation angle (rad).", valid=Range(0.0, math.pi, "rad")),
    )

    def update(self) -> Status:
        try:
            pose = as_pose_stamped(self.get_input("pose"), "pose")
            matrix = pose_to_matrix(pose.pose)
        except ValueError as err:
            return self.fail(str(err))
        distance = float(np.linalg.norm(matrix[:3, 3]))
        angle = rotation_angle(matrix)
        position_tolerance, rotation_tolerance = self.get_input("position_tolerance"), self.get_input("rotation_tolerance")
        summary = f"position {distance * 1000:.1f} mm (tolerance {position_tolerance * 1000:.1f}), rotation {angle:.4f} rad (tolerance {rotation_tolerance:.4f})"
        if distance <= position_tolerance and angle <= rotation_tolerance:
            self.feedback_message = f"near identity: {summary}"
            return Status.SUCCESS
        return self.fail(f"not near identity: {summary}")


class CheckObjectStacked(ReadsRobotState, Condition):
    """SUCCESS when one object rests on another and the gripper has let go of it.

    Answers in the tick it runs (never RUNNING), so it can guard a ReactiveFallback that stops
    a policy as soon as the stack is built. See ``stack_check`` for the geometry.
    """

    needs_world = True
    description = (
        "SUCCESS when top_object's centre is within position_tolerance of the point stack_height above "
        "bottom_object's centre (world z) and gripper_frame is at least min_gripper_distance from it."
    )
    ports = (
        InputPort("top_object_name", PortType.STRING, description="Object that should be on top, e.g. cube_blue.", names=Names(NameKind.FRAME)),
        InputPort("bottom_object_name", PortType.STRING, description="Object it should rest on, e.g. cube_green.", names=Names(NameKind.FRAME)),
        InputPort("stack_height", PortType.FLOAT, 0.03, "Centre-to-centre height of a stack (m): the bottom object's height for cubes.", valid=Range(0.0, 10.0, "m")),
        InputPort("position_tolerance", PortType.FLOAT, 0.015, "Largest distance (m) of the top centre from its stacked position.", valid=Range(0.0, 10.0, "m")),
        InputPort("gripper_frame", PortType.STRING, "tcp", "Robot frame that must be away from the top object (the tool centre point).",
                  names=Names(NameKind.FRAME)),
        InputPort("min_gripper_distance", PortType.FLOAT, 0.05, "Smallest distance (m) between gripper_frame and the top object's centre.", valid=Range(0.0, 10.0, "m")),
    )

    def update(self) -> Status:
        scene = self.context.scene
        if scene is None:
            return self.fail(NO_SCENE)
        top, bottom = self.get_input("top_object_name"), self.get_input("bottom_object_name")
        if top == bottom:
            return self.fail(f"top_object_name and bottom_object_name are both '{top}'")
        try:
            top_center = frame_in_world(scene, top, self.state())[:3, 3]
            bottom_center = frame_in_world(scene, bottom, self.state())[:3, 3]
            gripper = frame_in_world(scene, self.get_input("gripper_frame"), self.state())[:3, 3]
        except FrameError as err:
            return self.fail(str(err))
        answer = stack_check(
            top_center,
            bottom_center,
            gripper,
            self.get_input("stack_height"),
            self.get_input("position_tolerance"),
            self.get_input("min_gripper_distance"),
        )
        message = f"{top} on {bottom}: {answer.reason}"
        self.last_check = {"top": top, "bottom": bottom, "stacked": answer.stacked, "reason": answer.reason}
        if answer.stacked:
            self.feedback_message = message
            return Status.SUCCESS
        return self.fail(message)

    def run_summary(self) -> dict[str, Any]:
        """The last answer, for ``objective run --json`` (under ``stack_check``)."""
        check = getattr(self, "last_check", None)
        return {} if check is None else {"stack_check": check}


NODES = (GetObjectPose, GetLatestTransform, TransformPose, IsPoseNearIdentity, CheckObjectStacked)

"""MoveIt Pro's visualization nodes without a UI: markers and transforms on the bus.

``VisualizePose`` and ``VisualizePath`` publish ``visualization_msgs/MarkerArray`` on
``/visualization_marker_array`` (RViz's and Foxglove's usual topic); ``PublishTF`` publishes
``tf2_msgs/TFMessage`` on ``/tf``. In a recorded run (``--record``) these topics are recorded,
so the markers and frames appear in the MCAP file and its viewers. A frame published by
``PublishTF`` is for viewers only: the pose nodes here resolve frames from the planning scene.
"""
from __future__ import annotations

from typing import Any, ClassVar

from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point, PoseStamped, TransformStamped, Vector3
from std_msgs.msg import ColorRGBA
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from runtime.io.bus import RecordsTopics, capability
from runtime.tree.behavior import Behavior, Status
from runtime.tree.decorators import elapsed
from runtime.tree.ports import InputPort, PortType, Range
from runtime.io.timestamps import duration_msg, time_msg

MARKER_TOPIC = "/visualization_marker_array"
TF_TOPIC = "/tf"
AXIS_COLORS = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
"""x red, y green, z blue, as RViz draws frames."""


# -- pure marker building ----------------------------------------------------------------------
def _lifetime(seconds: float) -> Duration:
    return duration_msg(max(0.0, seconds))


def axis_markers(namespace: str, first_id: int, pose: PoseStamped, size_m: float, lifetime_s: float) -> list[Marker]:
    """Three arrows (x red, y green, z blue) of length ``size_m`` showing ``pose``'s axes."""
    from scipy.spatial.transform import Rotation

    o = pose.pose.orientation
    rotation = Rotation.from_quat([o.x, o.y, o.z, o.w])
    markers = []
    for axis, color in enumerate(AXIS_COLORS):
        direction = rotation.apply([size_m if i == axis else 0.0 for i in range(3)])
        start = pose.pose.position
        marker = Marker(ns=namespace, id=first_id + axis, type=Marker.ARROW, action=Marker.ADD)
        marker.header = pose.header
        marker.pose.orientation.w = 1.0
        marker.points = [Point(x=start.x, y=start.y, z=start.z), Point(x=start.x + direction[0], y=start.y + direction[1], z=start.z + direction[2])]
        marker.scale = Vector3(x=size_m * 0.1, y=size_m * 0.2, z=size_m * 0.3)  # shaft and head diameters, head length
        marker.color = ColorRGBA(r=color[0], g=color[1], b=color[2], a=1.0)
        marker.lifetime = _lifetime(lifetime_s)
        markers.append(marker)
    return markers


def text_marker(namespace: str, marker_id: int, pose: PoseStamped, text: str, size_m: float, lifetime_s: float) -> Marker:
    marker = Marker(ns=namespace, id=marker_id, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD, text=text)
    marker.header = pose.header
    marker.pose.position.x = pose.pose.position.x
    marker.pose.position.y = pose.pose.position.y
    marker.pose.position.z = pose.pose.position.z + size_m * 1.2
    marker.pose.orientation.w = 1.0
    marker.scale.z = max(size_m * 0.4, 0.01)
    marker.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
    marker.lifetime = _lifetime(lifetime_s)
    return marker


def path_marker(namespace: str, path: list[PoseStamped], lifetime_s: float) -> Marker:
    """A line through the poses' positions, in the first pose's frame."""
    marker = Marker(ns=namespace, id=0, type=Marker.LINE_STRIP, action=Marker.ADD)
    marker.header = path[0].header
    marker.pose.orientation.w = 1.0
    marker.points = [Point(x=p.pose.position.x, y=p.pose.position.y, z=p.pose.position.z) for p in path]
    marker.scale.x = 0.005
    marker.color = ColorRGBA(r=1.0, g=0.8, b=0.0, a=1.0)
    marker.lifetime = _lifetime(lifetime_s)
    return marker


def pose_transform(pose: PoseStamped, child_frame_id: str, stamp_s: float) -> TransformStamped:
    msg = TransformStamped(child_frame_id=child_frame_id)
    msg.header.frame_id = pose.header.frame_id
    msg.header.stamp = time_msg(stamp_s)
    p, o = pose.pose.position, pose.pose.orientation
    msg.transform.translation = Vector3(x=p.x, y=p.y, z=p.z)
    msg.transform.rotation = o
    return msg


# -- nodes -------------------------------------------------------------------------------------
class _Publishes(Behavior):
    """Creates its publisher once per run and has the topic recorded when the run records."""

    topic: ClassVar[str]
    msg_type: ClassVar[type]

    def publisher(self) -> Any:
        if getattr(self, "_publisher", None) is None:
            bus = self.context.bus
            recorder = capability(bus, RecordsTopics)  # a recorded run: markers land in the bag
            if recorder is not None:
                recorder.record_topic(self.topic, self.msg_type)
            self._publisher = bus.create_publisher(self.topic, self.msg_type)
        return self._publisher


def _check_size(value: float, port: str) -> str | None:
    return None if value > 0 else f"{port} must be positive, got {value}"


class VisualizePose(_Publishes):
    """MoveIt Pro's VisualizePose."""

    topic, msg_type = MARKER_TOPIC, MarkerArray
    description: ClassVar[str] = (
        f"Publish a pose as three axis arrows (and an optional label) on {MARKER_TOPIC} (visualization_msgs/MarkerArray)."
    )
    ports = (
        InputPort("pose", PortType.POSE_STAMPED, description="The pose to show."),
        InputPort("marker_name", PortType.STRING, "pose", "Marker namespace: a new marker with the same name replaces the old one."),
        InputPort("marker_size", PortType.FLOAT, 0.1, "Arrow length (m).", valid=Range(0, 10, "m", min_open=True)),
        InputPort("marker_lifetime", PortType.FLOAT, 0.0, "Seconds the marker stays (0: until replaced).", valid=Range(0, 86400, "s")),
        InputPort("marker_text", PortType.STRING, "", "Label drawn above the pose (empty: none)."),
    )

    def update(self) -> Status:
        pose, size = self.get_input("pose"), self.get_input("marker_size")
        problem = _check_size(size, "marker_size")
        if problem:
            return self.fail(problem)
        name, lifetime = self.get_input("marker_name"), self.get_input("marker_lifetime")
        markers = axis_markers(name, 0, pose, size, lifetime)
        if self.get_input("marker_text"):
            markers.append(text_marker(name, 3, pose, self.get_input("marker_text"), size, lifetime))
        self.publisher().publish(MarkerArray(markers=markers))
        return Status.SUCCESS


class VisualizePath(_Publishes):
    """MoveIt Pro's VisualizePath."""

    topic, msg_type = MARKER_TOPIC, MarkerArray
    description: ClassVar[str] = (
        f"Publish a vector of poses as a line (and optionally each pose's axes) on {MARKER_TOPIC}."
    )
    ports = (
        InputPort("path", PortType.POSE_STAMPED_LIST, description="The poses, e.g. PlanCartesianPath's path."),
        InputPort("marker_name", PortType.STRING, "path", "Marker namespace."),
        InputPort("marker_lifetime", PortType.FLOAT, 0.0, "Seconds the markers stay (0: until replaced).", valid=Range(0, 86400, "s")),
        InputPort("show_poses", PortType.BOOL, False, "Also draw each pose's axes."),
        InputPort("pose_marker_size", PortType.FLOAT, 0.05, "Arrow length (m) of the pose axes.", valid=Range(0, 10, "m", min_open=True)),
    )

    def update(self) -> Status:
        path = self.get_input("path")
        if not path:
            return self.fail("path is empty: nothing to show")
        frames = sorted({p.header.frame_id for p in path})
        if len(frames) > 1:
            return self.fail(f"the path's poses are in different frames ({', '.join(frames)}): transform them to one first")
        size = self.get_input("pose_marker_size")
        problem = _check_size(size, "pose_marker_size")
        if problem:
            return self.fail(problem)
        name, lifetime = self.get_input("marker_name"), self.get_input("marker_lifetime")
        markers = [path_marker(name, path, lifetime)]
        if self.get_input("show_poses"):
            for i, pose in enumerate(path):
                markers += axis_markers(name, 1 + 3 * i, pose, size, lifetime)
        self.publisher().publish(MarkerArray(markers=markers))
        return Status.SUCCESS


class PublishTF(_Publishes):
    """MoveIt Pro's PublishTF: a pose as a transform, again and again until halted."""

    topic, msg_type = TF_TOPIC, TFMessage
    description: ClassVar[str] = (
        f"Publish pose as the transform from its frame to child_frame_id on {TF_TOPIC} at publish_rate, "
        "RUNNING until halted (put it in a Parallel). For viewers: the pose nodes here do not resolve that frame."
    )
    ports = (
        InputPort("pose", PortType.POSE_STAMPED, description="Where child_frame_id is, in the pose's frame."),
        InputPort("child_frame_id", PortType.STRING, description="Name of the published frame."),
        InputPort("publish_rate", PortType.UINT, 50, "Publications per second of run-clock time (Hz).", valid=Range(1, 1000, "Hz")),
    )

    def initialise(self) -> None:
        self.last_s: float | None = None

    def update(self) -> Status:
        rate, child = self.get_input("publish_rate"), self.get_input("child_frame_id").strip()
        if rate <= 0:
            return self.fail(f"publish_rate must be positive, got {rate}")
        if not child:
            return self.fail("child_frame_id is empty")
        now = self.context.clock.now()
        if self.last_s is None or elapsed(self.last_s, now, 1000.0 / rate):
            self.publisher().publish(TFMessage(transforms=[pose_transform(self.get_input("pose"), child, now)]))
            self.last_s = now
        return Status.RUNNING


NODES = (VisualizePose, VisualizePath, PublishTF)

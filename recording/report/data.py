"""A recording read back: ``events.jsonl`` and ``run.mcap`` as plain arrays for the report.

Everything the report draws comes from these two files, so a recording can be rendered again
(``objective report DIR``) on another machine. A recording is read as untrusted data: only the
message types of ``DECODED_TYPES`` (what the recorder writes and the report draws) are ever
decoded, whatever a schema names, and ``run.mcap`` is read within bounds
(``recording.report.mcap_reader``). Messages are decoded with rclpy's deserializer (the inverse
of what the recorder wrote); the tests decode the same files independently with
mcap-ros2-support, the way Foxglove would.
"""
from __future__ import annotations

import json
import os
import struct
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray
from mcap.exceptions import EndOfFile
from mcap.records import Message, Metadata
from rclpy.serialization import deserialize_message

from runtime.errors import ObjectiveError
from ..bus import JOINT_STATES_TOPIC
from ..cdr import JointStateArrays, TrajectoryArrays, joint_state_arrays, joint_trajectory_arrays
from ..mcap_writer import METADATA_NAME
from ..files import EVENTS_FILE, MCAP_FILE
from ..schema import message_class
from .mcap_reader import ReadLimits, messages, records


@dataclass
class JointSeries:
    """Measured joint states: ``position``/``velocity`` are (samples x joints), NaN where missing."""

    times: NDArray[np.float64]
    names: list[str]
    position: NDArray[np.float64]
    velocity: NDArray[np.float64]


@dataclass
class CommandedGoal:
    """One trajectory sent to a controller: absolute times (the seam stamp plus time_from_start)."""

    topic: str
    sent_at: float
    names: list[str]
    times: NDArray[np.float64]
    position: NDArray[np.float64]
    velocity: NDArray[np.float64]

    @property
    def start(self) -> float:
        return float(self.times[0]) if len(self.times) else self.sent_at

    @property
    def end(self) -> float:
        return float(self.times[-1]) if len(self.times) else self.sent_at


@dataclass
class CameraFrame:
    """The views a policy was given in one request, at the request instant."""

    time: float
    request: int
    views: list[tuple[str, NDArray[np.uint8]]]
    """(image name, H x W x 3 uint8 RGB) in the request's order."""


@dataclass
class Recording:
    directory: Path
    tree_id: str = ""
    nodes: list[dict[str, Any]] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] | None = None
    limits: dict[str, dict[str, Any]] = field(default_factory=dict)
    topics: dict[str, tuple[str, int]] = field(default_factory=dict)
    """topic -> (type name, message count)."""
    joints: JointSeries | None = None
    goals: list[CommandedGoal] = field(default_factory=list)
    gripper_commands: list[tuple[float, float]] = field(default_factory=list)
    requests: list[dict[str, Any]] = field(default_factory=list)
    responses: list[dict[str, Any]] = field(default_factory=list)
    frames: list[CameraFrame] = field(default_factory=list)
    partial: list[str] = field(default_factory=list)
    """Why the recording is incomplete (empty when it is whole): the run did not finish it."""

    def of_kind(self, kind: str) -> list[dict[str, Any]]:
        return [e for e in self.events if e["kind"] == kind]

    def final_statuses(self) -> dict[int, tuple[str, str]]:
        """node index -> (last status, its message), from the node_status events."""
        out: dict[int, tuple[str, str]] = {}
        for e in self.of_kind("node_status"):
            out[int(e["data"]["node"])] = (e["data"]["status"], e["data"].get("message") or "")
        return out


def image_rgb(msg: Any) -> NDArray[np.uint8]:
    """H x W x 3 uint8 RGB pixels of a sensor_msgs/Image (rgb8, bgr8, rgba8, bgra8, mono8)."""
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}
    encoding = msg.encoding.lower()
    if encoding not in channels:
        raise ValueError(f"camera image encoding '{msg.encoding}' is not one the report can show ({', '.join(channels)})")
    n = channels[encoding]
    raw = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    rows: NDArray[np.uint8] = raw.reshape(msg.height, msg.step)[:, : msg.width * n].reshape(msg.height, msg.width, n)
    if encoding == "mono8":
        return np.repeat(rows, 3, axis=2)
    if encoding.startswith("bgr"):
        rows = rows[:, :, 2::-1]
    return np.ascontiguousarray(rows[:, :, :3])


def _seconds(t: Any) -> float:
    result: float = t.sec + t.nanosec * 1e-9
    return result


def read_events(path: Path, recording: Recording) -> None:
    with open(path, encoding="utf-8", errors="replace") as stream:
        lines = stream.readlines()
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as err:
            if number == len(lines) and not line.endswith("\n"):  # the process died writing it
                recording.partial.append(f"{path.name} ends in the middle of line {number}")
                break
            raise ObjectiveError(f"{path}:{number}: not a JSON event ({err.msg})") from None
        add_event(record, recording)


def add_event(record: dict[str, Any], recording: Recording) -> None:
    """One ``events.jsonl`` record into ``recording`` (the tree, limits and summary to their fields)."""
    kind = record.get("kind")
    if kind == "tree":
        recording.tree_id = record.get("source", "")
        recording.nodes = record["data"]["nodes"]
    elif kind == "joint_limits":
        recording.limits = {j["name"]: j for j in record["data"]["joints"]}
    elif kind == "run_summary":
        recording.summary = record["data"]
    else:
        recording.events.append(record)


def _joint_series(messages: list[tuple[float, Any]]) -> JointSeries:
    names: list[str] = []
    for _, msg in messages:
        names.extend(n for n in msg.name if n not in names)
    column = {n: i for i, n in enumerate(names)}
    position = np.full((len(messages), len(names)), np.nan)
    velocity = np.full((len(messages), len(names)), np.nan)
    for row, (_, msg) in enumerate(messages):
        cols = [column[n] for n in msg.name]
        if len(msg.position) == len(cols):
            position[row, cols] = msg.position
        if len(msg.velocity) == len(cols):
            velocity[row, cols] = msg.velocity
    return JointSeries(np.array([t for t, _ in messages]), names, position, velocity)


def _joint_state(data: bytes, cls: type) -> JointStateArrays:
    """A recorded joint state's names, positions and velocities (read directly from its CDR)."""
    try:
        return joint_state_arrays(data)
    except ValueError:  # not the little-endian CDR this project writes: rclpy reads any
        msg = deserialize_message(data, cls)
        return JointStateArrays(tuple(msg.name), tuple(msg.position), tuple(msg.velocity))


def _trajectory(data: bytes, cls: type) -> TrajectoryArrays:
    """A recorded trajectory's stamp, names and points (read directly from its CDR)."""
    try:
        return joint_trajectory_arrays(data)
    except ValueError:  # not the little-endian CDR this project writes: rclpy reads any
        msg = deserialize_message(data, cls)
        return TrajectoryArrays(_seconds(msg.header.stamp), tuple(msg.joint_names),
                                tuple(_seconds(p.time_from_start) for p in msg.points),
                                tuple(tuple(p.positions) for p in msg.points), tuple(tuple(p.velocities) for p in msg.points))


def _goal(topic: str, sent_at: float, trajectory: TrajectoryArrays) -> CommandedGoal:
    start = trajectory.stamp_s if trajectory.stamp_s > 0 else sent_at  # a zero stamp means "start now"
    times = start + np.array(trajectory.times_s, dtype=float)
    n = len(trajectory.joint_names)

    def column(rows: tuple[tuple[float, ...], ...]) -> NDArray[np.float64]:
        return np.array([row or [np.nan] * n for row in rows], dtype=float).reshape(len(rows), n)

    return CommandedGoal(topic, sent_at, list(trajectory.joint_names), times, column(trajectory.positions),
                         column(trajectory.velocities))


JOINT_STATE, TRAJECTORY, STRING, GRIPPER_GOAL, IMAGE = (
    "sensor_msgs/msg/JointState", "trajectory_msgs/msg/JointTrajectory", "std_msgs/msg/String",
    "control_msgs/action/GripperCommand_Goal", "sensor_msgs/msg/Image")
DECODED_TYPES = frozenset({JOINT_STATE, TRAJECTORY, STRING, GRIPPER_GOAL, IMAGE})
"""The only message types the report decodes (and so the only type names it imports): what the
recorder writes and the report draws. Any other type is counted by its name, never imported."""


def _wanted(topic: str, type_name: str) -> bool:
    """The messages the report draws; the rest (feedback, goals, results...) are only counted."""
    if topic == JOINT_STATES_TOPIC:
        return type_name == JOINT_STATE
    if type_name == TRAJECTORY:
        return topic.endswith("/joint_trajectory")
    if type_name == STRING:
        return topic.endswith("/request") or topic.endswith("/response")
    return type_name == GRIPPER_GOAL


def clock_origin_ns(path: Path) -> int:
    """The wall-clock instant of the runtime clock's zero in a recording (0 for older files):
    the ``objective_runtime`` metadata record, written before the first message."""
    with open(path, "rb") as stream:
        try:
            for record in records(stream, path, os.fstat(stream.fileno()).st_size):
                if isinstance(record, Metadata) and record.name == METADATA_NAME:
                    return int(record.metadata.get("clock_origin_ns", "0"))
                if isinstance(record, Message):
                    return 0
        except (EndOfFile, struct.error):  # a file cut before its first message
            return 0
    return 0


@dataclass
class McapContents:
    """What the report keeps of a recording's messages, built one message at a time: read back
    from ``run.mcap`` (``read_mcap``), or as they arrive in the recording worker."""

    recording: Recording
    origin_ns: int = 0
    """Wall-clock log time of the runtime clock's zero (``clock_origin_ns``)."""
    classes: dict[str, type] = field(default_factory=dict)
    joint_messages: list[tuple[float, Any]] = field(default_factory=list)
    images: dict[tuple[str, int], bytes] = field(default_factory=dict)
    counts: dict[str, list[Any]] = field(default_factory=lambda: defaultdict(lambda: ["", 0]))
    on_frame: Callable[[CameraFrame], None] | None = None
    """Called with each camera frame as soon as its request and images are in, in request order
    (the recording worker encodes the video as the run goes)."""
    pending: list[dict[str, Any]] = field(default_factory=list)
    """Requests whose frame waits for images not yet arrived (and every request after them)."""

    def add(self, topic: str, type_name: str, log_time_ns: int, data: bytes) -> Any:
        """Take one message; returns a joint state as read (``JointStateArrays``), else None."""
        recording = self.recording
        self.counts[topic][0] = type_name
        self.counts[topic][1] += 1
        if type_name == IMAGE:
            self.images[(topic, log_time_ns - self.origin_ns)] = data  # decoded only if a request shows it
            return None
        if not _wanted(topic, type_name):
            return None
        cls = self.classes.get(type_name)
        if cls is None:
            assert type_name in DECODED_TYPES  # (``_wanted``): a recording names no module to import
            cls = self.classes[type_name] = message_class(type_name)
        t = (log_time_ns - self.origin_ns) * 1e-9
        if topic == JOINT_STATES_TOPIC:
            msg = _joint_state(data, cls)
            self.joint_messages.append((t, msg))
            return msg
        if type_name == TRAJECTORY:  # (on a controller's /joint_trajectory: _wanted)
            recording.goals.append(_goal(topic, t, _trajectory(data, cls)))
            return None
        msg = deserialize_message(data, cls)
        if type_name == GRIPPER_GOAL:
            recording.gripper_commands.append((t, float(msg.command.position)))
        elif topic.endswith("/request"):
            request = json.loads(msg.data)
            recording.requests.append(request)
            self.pending.append(request)
            self._frames(final=False)
        elif topic.endswith("/response"):
            recording.responses.append(json.loads(msg.data))
        return None

    def end_time_s(self) -> float | None:
        """Clock time of the last joint state (where a partial recording ends)."""
        return self.joint_messages[-1][0] if self.joint_messages else None

    def finish(self) -> None:
        """Fill in what needs every message: topic counts, the joint series, the camera frames."""
        recording = self.recording
        recording.topics = {topic: (name, count) for topic, (name, count) in self.counts.items()}
        if self.joint_messages:
            recording.joints = _joint_series(self.joint_messages)
        self._frames(final=True)

    def _frames(self, final: bool) -> None:
        """The camera frames of the pending requests, in order, up to the first one whose images
        have not all arrived (``final``: the recording is over, a frame shows the views it has)."""
        image_class = None
        while self.pending:
            request = self.pending[0]
            keys = [(view["topic"], int(round(request["time"] * 1e9))) for view in request.get("images", [])]
            if not final and not all(key in self.images for key in keys):
                return
            image_class = image_class or message_class(IMAGE)
            try:
                views = [(view["name"], image_rgb(deserialize_message(self.images[key], image_class)))
                         for view, key in zip(request.get("images", []), keys) if key in self.images]
            except Exception:
                if final:
                    raise
                self.on_frame = None  # an image the report cannot show: the same error, once, at the end
                return
            self.pending.pop(0)
            for key in keys:
                self.images.pop(key, None)
            if views:
                frame = CameraFrame(request["time"], request["request"], views)
                self.recording.frames.append(frame)
                if self.on_frame is not None:
                    self.on_frame(frame)


def read_mcap(path: Path, recording: Recording, limits: ReadLimits = ReadLimits()) -> None:
    contents = McapContents(recording, clock_origin_ns(path))
    with open(path, "rb") as stream:
        # Read front to back, as a stream: file order is recording order, which is clock order
        # (the recorder writes as time passes), and a file whose writer was killed (no summary
        # section, maybe half a chunk) still gives every complete chunk.
        try:
            for schema, channel, message in messages(stream, path, os.fstat(stream.fileno()).st_size, limits):
                contents.add(channel.topic, schema.name if schema is not None else "", message.log_time, message.data)
        except (EndOfFile, struct.error):  # cut inside a record's opcode and length, or inside its body
            end = contents.end_time_s()
            why = "its last whole chunk" if (recording.summary or {}).get("recording_incomplete") else "the recorder did not close it"
            recording.partial.append(f"{path.name} ends early{f' at {end:.2f} s' if end is not None else ''}: {why}")
    contents.finish()


def mark_unfinished(recording: Recording) -> None:
    if recording.summary is None:
        recording.partial.insert(0, f"{EVENTS_FILE} has no run summary: the run was killed before it finished")
    elif recording.summary.get("recording_incomplete"):
        recording.partial.insert(0, f"the recording is incomplete: {recording.summary['recording_incomplete']}")


def load_recording(directory: Path | str) -> Recording:
    """Read ``DIR/events.jsonl`` and ``DIR/run.mcap``; ObjectiveError if either is missing or unreadable."""
    directory = Path(directory)
    events, mcap = directory / EVENTS_FILE, directory / MCAP_FILE
    for path in (events, mcap):
        if not path.is_file():
            raise ObjectiveError(f"{directory}: no {path.name} (is this a directory written by `objective run --record`?)")
    recording = Recording(directory)
    read_events(events, recording)
    try:
        read_mcap(mcap, recording)
    except ObjectiveError:
        raise
    except Exception as err:  # not MCAP at all, or damaged (a truncated end is read as partial)
        raise ObjectiveError(f"{mcap}: cannot read the recording: {err}") from None
    mark_unfinished(recording)
    return recording

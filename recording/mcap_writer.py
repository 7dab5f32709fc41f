"""Write ROS 2 messages into an MCAP file the way ``ros2 bag record -s mcap`` does.

Messages are serialized by rclpy's C serializer (the same CDR bytes a ROS 2 subscriber gets),
which is what keeps recording cheap: the pure-Python encoder of mcap-ros2-support costs an
order of magnitude more per message. Schemas use the ``ros2msg`` encoding
(``recording.schema``). Each channel carries the ``offered_qos_profiles`` metadata the
MCAP ros2 profile requires (in rosbag2's Jazzy YAML). Log times are wall-clock nanoseconds:
the runtime clock's seconds plus the instant the run started (``clock_origin_ns``, stored in the
file's ``objective_runtime`` metadata record so a reader gets the runtime clock back).

Crash safety: the file is written in chunks, and the open chunk is closed and flushed to the
operating system every ``FLUSH_INTERVAL_S`` of wall time (``flush_if_due``, once per tick). A
process killed outright (SIGKILL) leaves a file whose every complete chunk can be read
(``recording.report.data`` reads it as a partial recording); only the summary section is missing.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .files import open_new
from .schema import message_class, message_definition, type_name

LIBRARY = "objective-runtime recorder"
METADATA_NAME = "objective_runtime"
"""The MCAP metadata record holding ``clock_origin_ns``: log time = origin + runtime clock."""

_INFINITE = "\n    sec: 9223372036\n    nsec: 854775807"


@dataclass(frozen=True)
class OfferedQos:
    """The QoS a topic's publisher offers, as ``ros2 bag`` records it."""

    reliable: bool = True
    transient_local: bool = False
    depth: int = 10

    def profile(self) -> dict[str, Any]:
        """The profile as data (``metadata.yaml`` carries it so); ``yaml()`` is its text."""
        infinite = {"sec": 9223372036, "nsec": 854775807}
        return {"history": "keep_last", "depth": self.depth, "reliability": "reliable" if self.reliable else "best_effort",
                "durability": "transient_local" if self.transient_local else "volatile", "deadline": infinite,
                "lifespan": infinite, "liveliness": "automatic", "liveliness_lease_duration": infinite,
                "avoid_ros_namespace_conventions": False}

    def yaml(self) -> str:
        """rosbag2's (Jazzy) ``offered_qos_profiles`` text: a list of one profile."""
        return (
            f"- history: keep_last\n  depth: {self.depth}\n"
            f"  reliability: {'reliable' if self.reliable else 'best_effort'}\n"
            f"  durability: {'transient_local' if self.transient_local else 'volatile'}\n"
            f"  deadline:{_INFINITE}\n  lifespan:{_INFINITE}\n  liveliness: automatic\n"
            f"  liveliness_lease_duration:{_INFINITE}\n  avoid_ros_namespace_conventions: false"
        )


SENSOR_DATA_QOS = OfferedQos(reliable=False, depth=5)
LATCHED_QOS = OfferedQos(transient_local=True, depth=1)


@dataclass(frozen=True)
class SerializedMessage:
    """A message already serialized (CDR), with its type: written as it is."""

    msg_class: type
    data: bytes


def message_type(msg: Any) -> type:
    return msg.msg_class if isinstance(msg, SerializedMessage) else type(msg)


def cdr_bytes(msg: Any) -> bytes:
    """The CDR bytes a ROS 2 subscriber would get (rclpy's C serializer)."""
    if isinstance(msg, SerializedMessage):
        return msg.data
    from rclpy.serialization import serialize_message  # (a recorded run's process needs it rarely)

    return serialize_message(msg)


FLUSH_INTERVAL_S = 0.5
"""Most wall time the messages of a run may sit in memory before reaching the file."""


def to_nanoseconds(seconds: float) -> int:
    return max(0, int(round(seconds * 1e9)))


def wall_clock_origin_ns(clock_now_s: float) -> int:
    """The wall-clock instant at which the runtime clock read zero."""
    return time.time_ns() - to_nanoseconds(clock_now_s)


class McapRos2Writer:
    """One ``.mcap`` file: a channel per topic (one type per topic), a schema per message type."""

    def __init__(self, path: Path | str, clock_origin_ns: int = 0, flush_interval_s: float = FLUSH_INTERVAL_S) -> None:
        from mcap.well_known import Profile  # (imported by the process that writes: the worker, mostly)
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.clock_origin_ns = clock_origin_ns
        self.flush_interval_s = flush_interval_s
        self._stream = open_new(self.path)  # never through a link planted there
        self._writer = Writer(self._stream, compression=CompressionType.ZSTD)
        self._writer.start(profile=Profile.ROS2, library=LIBRARY)
        self._writer.add_metadata(METADATA_NAME, {"clock_origin_ns": str(clock_origin_ns)})
        self._writer.flush()  # the header: a file killed before its first chunk is still an MCAP file
        self._flushed_at = time.monotonic()
        self.qos: dict[str, OfferedQos] = {}
        """Topic -> offered QoS, for topics not published reliable/volatile (the default)."""
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, type]] = {}
        self._topic_of: dict[int, str] = {}
        self.counts: dict[str, int] = {}
        self.topics: dict[str, tuple[str, OfferedQos]] = {}
        """Topic -> (type name, offered QoS), in the order the channels were opened."""
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.closed = False

    def _channel(self, topic: str, msg_class: type) -> int:
        known = self._channels.get(topic)
        if known is not None:
            channel, cls = known
            if cls is not msg_class:
                raise TypeError(f"recording topic '{topic}' carries {type_name(cls)}, got {type_name(msg_class)}")
            return channel
        channel = self.open_channel(topic, type_name(msg_class), self.qos.get(topic, OfferedQos()))
        self._channels[topic] = (channel, msg_class)
        return channel

    def open_channel(self, topic: str, name: str, qos: OfferedQos) -> int:
        """Register ``topic`` carrying type ``name`` (``pkg/msg/Type``); its schema once per type."""
        from mcap.well_known import MessageEncoding, SchemaEncoding

        schema = self._schemas.get(name)
        if schema is None:
            definition = message_definition(message_class(name))
            schema = self._schemas[name] = self._writer.register_schema(name, SchemaEncoding.ROS2, definition.encode())
        channel = self._writer.register_channel(topic, MessageEncoding.CDR, schema, {"offered_qos_profiles": qos.yaml()})
        self.topics[topic] = (name, qos)
        self._topic_of[channel] = topic
        return channel

    def write(self, topic: str, msg: Any, seconds: float) -> None:
        """Record ``msg`` on ``topic`` at ``seconds`` of the runtime clock."""
        if not self.closed:
            channel = self._channel(topic, message_type(msg))
            self.write_cdr(channel, cdr_bytes(msg), self.clock_origin_ns + to_nanoseconds(seconds))

    def write_cdr(self, channel: int, data: bytes, log_time_ns: int) -> None:
        """Record serialized ``data`` on ``channel`` (``open_channel``) at wall-clock ``log_time_ns``."""
        if self.closed:
            return
        topic = self._topic_of[channel]
        sequence = self.counts.get(topic, 0)
        self._writer.add_message(channel, log_time=log_time_ns, data=data, publish_time=log_time_ns, sequence=sequence)
        self.counts[topic] = sequence + 1
        self.first_ns = log_time_ns if self.first_ns is None else min(self.first_ns, log_time_ns)
        self.last_ns = log_time_ns if self.last_ns is None else max(self.last_ns, log_time_ns)

    def flush_if_due(self) -> None:
        """Close the open chunk and flush the file when ``flush_interval_s`` of wall time passed
        since the last time (the runner's bus calls it once per tick)."""
        now = time.monotonic()
        if not self.closed and now - self._flushed_at >= self.flush_interval_s:
            self._writer.flush()  # what was recorded so far survives a crash
            self._flushed_at = now

    def flush(self) -> None:
        """Close the open chunk and hand the file to the operating system now."""
        if not self.closed:
            self._writer.flush()
            self._flushed_at = time.monotonic()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()
        finally:
            self._stream.close()

    def abandon(self) -> None:
        """Stop writing (a write failed: a full disk): the file keeps its whole chunks, readable as
        a partial recording; the open chunk and the summary section are not written."""
        self.closed = True
        try:
            self._stream.close()
        except OSError:
            pass  # (what the stream still buffered had no room either)

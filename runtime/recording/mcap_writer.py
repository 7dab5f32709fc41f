"""Write ROS 2 messages into an MCAP file the way ``ros2 bag record -s mcap`` does.

Messages are serialized by rclpy's C serializer (the same CDR bytes a ROS 2 subscriber gets),
which is what keeps recording cheap: the pure-Python encoder of mcap-ros2-support costs an
order of magnitude more per message. Schemas use the ``ros2msg`` encoding
(``runtime.recording.schema``); times are nanoseconds of the runtime clock.

Crash safety: the file is written in chunks, and the open chunk is closed and flushed to the
operating system every ``FLUSH_INTERVAL_S`` of wall time (``flush_if_due``, once per tick). A
process killed outright (SIGKILL) leaves a file whose every complete chunk can be read
(``runtime.report.data`` reads it as a partial recording); only the summary section is missing.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from mcap.well_known import MessageEncoding, Profile, SchemaEncoding
from mcap.writer import CompressionType, Writer
from rclpy.serialization import serialize_message

from .schema import message_definition, type_name

LIBRARY = "objective-runtime recorder"
FLUSH_INTERVAL_S = 0.5
"""Most wall time the messages of a run may sit in memory before reaching the file."""


def to_nanoseconds(seconds: float) -> int:
    return max(0, int(round(seconds * 1e9)))


class McapRos2Writer:
    """One ``.mcap`` file: a channel per topic (one type per topic), a schema per message type."""

    def __init__(self, path: Path | str, flush_interval_s: float = FLUSH_INTERVAL_S) -> None:
        self.path = Path(path)
        self.flush_interval_s = flush_interval_s
        self._stream = open(self.path, "wb")
        self._writer = Writer(self._stream, compression=CompressionType.ZSTD)
        self._writer.start(profile=Profile.ROS2, library=LIBRARY)
        self._writer.flush()  # the header: a file killed before its first chunk is still an MCAP file
        self._flushed_at = time.monotonic()
        self._schemas: dict[type, int] = {}
        self._channels: dict[str, tuple[int, type]] = {}
        self._sequence: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self.closed = False

    def _channel(self, topic: str, msg_class: type) -> int:
        known = self._channels.get(topic)
        if known is not None:
            channel, cls = known
            if cls is not msg_class:
                raise TypeError(f"recording topic '{topic}' carries {type_name(cls)}, got {type_name(msg_class)}")
            return channel
        schema = self._schemas.get(msg_class)
        if schema is None:
            schema = self._writer.register_schema(
                type_name(msg_class), SchemaEncoding.ROS2, message_definition(msg_class).encode()
            )
            self._schemas[msg_class] = schema
        channel = self._writer.register_channel(topic, MessageEncoding.CDR, schema)
        self._channels[topic] = (channel, msg_class)
        return channel

    def write(self, topic: str, msg: Any, seconds: float) -> None:
        """Record ``msg`` on ``topic`` at ``seconds`` of the runtime clock."""
        if self.closed:
            return
        channel = self._channel(topic, type(msg))
        stamp = to_nanoseconds(seconds)
        sequence = self._sequence.get(topic, 0)
        self._sequence[topic] = sequence + 1
        self._writer.add_message(channel, log_time=stamp, data=serialize_message(msg), publish_time=stamp, sequence=sequence)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def flush_if_due(self) -> None:
        """Close the open chunk and flush the file when ``flush_interval_s`` of wall time passed
        since the last time (the runner's bus calls it once per tick)."""
        now = time.monotonic()
        if not self.closed and now - self._flushed_at >= self.flush_interval_s:
            self._writer.flush()  # what was recorded so far survives a crash
            self._flushed_at = now

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()
        finally:
            self._stream.close()

"""How a recorded run hands its messages to the recording worker (``recording.report.worker``).

The run only serializes: every message is kept as it is until the batch is sent, then becomes
its CDR bytes (``recording.cdr``; rclpy's C serializer for the few types it leaves;
bytes prepared before, such as the robot's markers, as they are); every event is one JSON line.
``flush_if_due`` writes the batch to the worker's stdin (one ``write`` per tick at
most, about ``SEND_INTERVAL_S`` apart). A message must not change after it was written: the
bus's never do (the in-process bus hands its subscribers the same object). The worker writes ``run.mcap`` (schemas, chunks, zstd, the summary section),
``events.jsonl`` and ``metadata.yaml``, turns events into ``/rosout`` and node status messages,
and builds the report's data as messages arrive.

A frame on the pipe is ``kind`` (1 byte) and the payload's length (4 bytes, little endian), then
the payload:

- ``START``: JSON ``{"directory", "clock_origin_ns"}``, once, before anything else;
- ``CHANNEL``: JSON ``{"id", "topic", "type", "qos"}``: a topic's first message follows;
- ``MESSAGE``: channel id (2 bytes), log time (8 bytes, wall-clock ns), the CDR bytes;
- ``EVENT``: one ``events.jsonl`` line of an event that also goes on ``/rosout`` or
  ``/behavior_tree/node_status``; ``NOTE``: a line that goes only to ``events.jsonl``;
- ``TF_MODEL``: JSON ``recording.tf_model.TfModel``: from now on the worker writes
  ``/tf`` with every ``/joint_states`` message (and ``/tf_static`` with the first); ``null``:
  it stops (a new robot the model cannot describe: the run sends ``/tf``);
- ``END``: the recording is over (the worker finishes the files);
- ``RENDER``: JSON ``{"directory"}``: render the report and answer one JSON line on stdout.

Crash safety: a killed run loses only the batch it had not sent yet (``SEND_INTERVAL_S`` of wall
time); the worker writes everything it received. A worker that dies (``WorkerLost``) loses the
messages it had not flushed yet: at most ``FLUSH_INTERVAL_S`` of them plus what sat in the pipe
(``PIPE_BYTES``) or in what it read ahead (``recording.report.worker.READ_AHEAD_BYTES``); ``run.mcap`` stays partial, and the run rewrites ``events.jsonl`` whole from
its own copy of the lines and goes on writing it (``recording.recorder``).
"""
from __future__ import annotations

import array
import enum
import errno
import fcntl
import json
import os
import select
import struct
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterator

from .cdr import message_encoder
from .mcap_writer import OfferedQos, SerializedMessage, cdr_bytes, message_type, to_nanoseconds
from .schema import type_name
from .tf_model import TfModel


class Frame(enum.IntEnum):
    START = 1
    CHANNEL = 2
    MESSAGE = 3
    EVENT = 4
    NOTE = 5
    END = 6
    RENDER = 7
    TF_MODEL = 8


HEADER = struct.Struct("<BI")
MESSAGE_HEADER = struct.Struct("<Hq")
SEND_INTERVAL_S = 0.05
"""Most wall time messages wait in the run before they are sent: a write wakes the worker, and
on a busy machine each wake-up can cost the run a time slice, so the run sends about 20 batches
a second rather than one per tick (a killed run loses at most this much)."""
SEND_BYTES = 256 << 10
"""A batch this large is sent at once (camera frames)."""
PIPE_BYTES = 1 << 20
"""The pipe's capacity asked for (Linux's default limit for an unprivileged process)."""
STALL_TIMEOUT_S = 10.0
"""A worker that reads nothing for this long while the run waits to send is taken as lost."""
_F_SETPIPE_SZ = 1031


class WorkerLost(Exception):
    """The worker stopped reading (it died or hung): what was not sent is not recorded by it."""


def frame(kind: Frame, payload: bytes) -> bytes:
    return HEADER.pack(kind, len(payload)) + payload


def json_frame(kind: Frame, data: dict[str, Any]) -> bytes:
    return frame(kind, json.dumps(data).encode())


def widen_pipe(fd: int) -> None:
    """Ask for a ``PIPE_BYTES`` pipe (a camera frame batch then fits); the default is kept if refused."""
    try:
        fcntl.fcntl(fd, _F_SETPIPE_SZ, PIPE_BYTES)
    except OSError:
        pass


@dataclass
class _Channel:
    id: int
    msg_class: type


class Handoff:
    """The run's side: a sink (``write``/``qos``/``flush_if_due``/``close``, as ``McapRos2Writer``)
    that serializes here and sends to the worker through ``fd`` (the worker's stdin)."""

    def __init__(self, fd: int, directory: str, clock_origin_ns: int) -> None:
        self.fd = fd
        self.on_lost: Callable[[WorkerLost], None] | None = None
        """Called (once) when the worker is lost; without it ``WorkerLost`` is raised."""
        os.set_blocking(fd, False)  # a worker that stops reading must not hang the run (see ``send``)
        widen_pipe(fd)
        self.clock_origin_ns = clock_origin_ns
        self.qos: dict[str, OfferedQos] = {}
        self._channels: dict[str, _Channel] = {}
        self._encoders: dict[type, Callable[[Any, dict[int, bytes]], bytes]] = {}
        self._sent_at = -float("inf")
        self._pending: list[bytes | tuple[int, int, Any]] = []
        """What was written since the last batch: frames, and (channel id, log time, message)
        for the messages, serialized when the batch is sent."""
        self._pending_bytes = 0
        self._add(json_frame(Frame.START, {"directory": directory, "clock_origin_ns": clock_origin_ns}))
        self.closed = False

    def write(self, topic: str, msg: Any, seconds: float) -> None:
        """Record ``msg`` on ``topic`` at ``seconds`` of the runtime clock (sent with the next batch)."""
        if self.closed:
            return
        cls = message_type(msg)
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._channels[topic] = _Channel(len(self._channels), cls)
            qos = self.qos.get(topic, OfferedQos())
            self._add(json_frame(Frame.CHANNEL, {"id": channel.id, "topic": topic, "type": type_name(cls),
                                                "qos": [qos.reliable, qos.transient_local, qos.depth]}))
        elif channel.msg_class is not cls:
            raise TypeError(f"recording topic '{topic}' carries {type_name(channel.msg_class)}, got {type_name(cls)}")
        self._pending.append((channel.id, self.clock_origin_ns + to_nanoseconds(seconds), msg))
        self._pending_bytes += _size_hint(msg)

    def _add(self, frame_bytes: bytes) -> None:
        self._pending.append(frame_bytes)
        self._pending_bytes += len(frame_bytes)

    def _serialize(self) -> bytes:
        """What was written since the last batch, as frames. The messages are serialized here,
        together, rather than one at a time between ticks: the serializers' code and data are
        then still in the CPU's caches from the previous message (several times cheaper each)."""
        batch = bytearray()
        known: dict[int, bytes] = {}  # (a goal reuses the bytes of its trajectory, written just before)
        for item in self._pending:
            if isinstance(item, bytes):
                batch += item
                continue
            channel, log_time_ns, msg = item
            if isinstance(msg, SerializedMessage):
                data = msg.data
            else:
                cls = type(msg)
                encode = self._encoders.get(cls)
                if encode is None:
                    encode = self._encoders[cls] = message_encoder(cls) or _rclpy_encode
                data = encode(msg, known)
            batch += HEADER.pack(Frame.MESSAGE, MESSAGE_HEADER.size + len(data))
            batch += MESSAGE_HEADER.pack(channel, log_time_ns)
            batch += data
        self._pending.clear()
        self._pending_bytes = 0
        return bytes(batch)

    def event(self, line: str, note: bool = False) -> None:
        """One ``events.jsonl`` line (``note``: not also a ``/rosout``/node status message)."""
        if not self.closed:
            self._add(frame(Frame.NOTE if note else Frame.EVENT, line.encode()))

    def tf_model(self, model: TfModel | None) -> None:
        """The worker computes ``/tf`` and ``/tf_static`` with ``model`` from the next joint state
        on (None: it stops; the run sends them)."""
        if not self.closed:
            self._add(frame(Frame.TF_MODEL, json.dumps(model.to_json() if model is not None else None).encode()))

    def flush_if_due(self) -> None:
        """Send the batch if it waited ``SEND_INTERVAL_S`` or grew to ``SEND_BYTES`` (the bus
        calls this once per spin)."""
        now = time.monotonic()
        if now - self._sent_at >= SEND_INTERVAL_S or self._pending_bytes >= SEND_BYTES:
            self._sent_at = now
            self.send()

    def send(self, final: bytes = b"") -> None:
        """Write the batch (and ``final``) to the worker; ``WorkerLost`` if it stopped reading."""
        if self.closed:
            return
        self._add(final)
        data = self._serialize()
        if not data:
            return
        try:
            write_all(self.fd, data)
        except WorkerLost as lost:
            self.closed = True
            if self.on_lost is None:
                raise
            self.on_lost(lost)

    def close(self) -> None:
        """Send what is left and tell the worker the recording is over."""
        if not self.closed:
            self.send(frame(Frame.END, b""))
            self.closed = True


def _rclpy_encode(msg: Any, known: dict[int, bytes]) -> bytes:
    return cdr_bytes(msg)  # (its padding is not zeros: nothing to reuse)


def _size_hint(msg: Any) -> int:
    """About how many bytes ``msg`` will take (its ``data``: camera frames, prepared bytes)."""
    data = getattr(msg, "data", None)
    return len(data) if isinstance(data, (bytes, bytearray, array.array)) else 0


def write_all(fd: int, data: bytes, stall_timeout_s: float = STALL_TIMEOUT_S) -> None:
    """Write ``data`` to the pipe ``fd`` (blocking or not); ``WorkerLost`` if the reader is gone
    or reads nothing for ``stall_timeout_s``."""
    view, sent = memoryview(data), 0
    try:
        while sent < len(view):
            try:
                sent += os.write(fd, view[sent:])
            except BlockingIOError:
                writable = select.poll()
                writable.register(fd, select.POLLOUT)
                if not writable.poll(stall_timeout_s * 1000):
                    raise WorkerLost(f"the recording worker read nothing for {stall_timeout_s:.0f} s") from None
    except OSError as err:
        reason = "it exited" if err.errno in (errno.EPIPE, errno.EBADF) else err.strerror
        raise WorkerLost(f"the recording worker stopped reading ({reason})") from None


def read_frames(source: int | Callable[[], bytes]) -> Iterator[tuple[Frame | None, bytes]]:
    """The frames arriving from ``source`` (a file descriptor, or a function returning what has
    arrived, ``b""`` at the end) until end of file; a ``None`` kind between reads marks "nothing
    more for now" (the worker flushes its files then). A torn last frame is dropped."""
    read = source if callable(source) else (lambda: os.read(source, PIPE_BYTES))
    pending = bytearray()
    while True:
        try:
            data = read()
        except InterruptedError:
            continue
        if not data:
            return
        pending += data
        at = 0
        while len(pending) - at >= HEADER.size:
            kind, size = HEADER.unpack_from(pending, at)
            if len(pending) - at - HEADER.size < size:
                break
            start = at + HEADER.size
            yield Frame(kind), bytes(pending[start:start + size])
            at = start + size
        del pending[:at]
        yield None, b""

"""CDR (XCDR1, little endian) written by hand for the messages a recording sends most often.

rclpy's C serializer costs a few microseconds per message in a tight loop but tens of them in a
running simulation (its code and buffers are cold by then); ``/joint_states`` at 50 Hz is the
most frequent message a run records, and most of its bytes never change (the frame id and the
joint names), so they are encoded once per list of names and only the stamp and the numbers are
written per message. rclpy reads the bytes back as the message sent, and so does
mcap-ros2-support (``tests/test_recording_worker.py``); they differ from rclpy's own only in
padding (rclpy leaves its padding bytes uninitialized and pads the end to 8 bytes).
"""
from __future__ import annotations

import struct
import sys
from typing import Any

from sensor_msgs.msg import JointState

ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR, little endian, no options."""
_STAMP = struct.Struct("<iI")
_COUNT = struct.Struct("<I")


def align(buffer: bytearray, size: int) -> None:
    """Pad to ``size`` bytes, counted from after the 4-byte encapsulation header."""
    buffer.extend(b"\0" * (-(len(buffer) - 4) % size))


def add_string(buffer: bytearray, text: str) -> None:
    data = text.encode() + b"\0"
    align(buffer, 4)
    buffer += _COUNT.pack(len(data)) + data


def add_doubles(buffer: bytearray, values: Any) -> None:
    """A ``float64[]`` (``values``: an ``array('d')``, as rosidl stores it)."""
    align(buffer, 4)
    buffer += _COUNT.pack(len(values))
    if len(values):
        align(buffer, 8)
        buffer += values.tobytes()


class JointStateEncoder:
    """``sensor_msgs/JointState`` to CDR, the frame id and the names encoded once per list."""

    def __init__(self) -> None:
        self._heads: dict[tuple[str, tuple[str, ...]], bytes] = {}

    def encode(self, msg: Any) -> bytes:
        stamp = msg.header.stamp
        key = (msg.header.frame_id, tuple(msg.name))
        head = self._heads.get(key)
        if head is None:
            names = bytearray(ENCAPSULATION + bytes(8))
            add_string(names, key[0])
            align(names, 4)
            names += _COUNT.pack(len(key[1]))
            for name in key[1]:
                add_string(names, name)
            head = self._heads[key] = bytes(names[12:])
        buffer = bytearray(ENCAPSULATION)
        buffer += _STAMP.pack(stamp.sec, stamp.nanosec)
        buffer += head
        for values in (msg.position, msg.velocity, msg.effort):
            add_doubles(buffer, values)
        return bytes(buffer)


def _string_at(data: bytes, at: int) -> tuple[str, int]:
    """The string at ``at`` (aligned to 4 first) and the offset after it."""
    at += -(at - 4) % 4
    (size,) = _COUNT.unpack_from(data, at)
    return data[at + 4:at + 3 + size].decode(), at + 4 + size


def joint_state_positions(data: bytes) -> tuple[tuple[str, ...], tuple[float, ...]]:
    """The names and positions of a ``sensor_msgs/JointState`` in CDR (little endian, as
    ``JointStateEncoder`` and rclpy write it); ValueError for anything else."""
    if data[:4] != ENCAPSULATION:
        raise ValueError("not little-endian CDR")
    try:
        _, at = _string_at(data, 12)  # after the stamp: the frame id
        at += -(at - 4) % 4
        (count,) = _COUNT.unpack_from(data, at)
        at += 4
        names = []
        for _ in range(count):
            name, at = _string_at(data, at)
            names.append(name)
        at += -(at - 4) % 4
        (size,) = _COUNT.unpack_from(data, at)
        at += 4
        at += -(at - 4) % 8
        positions = struct.unpack_from(f"<{size}d", data, at)
    except struct.error as err:
        raise ValueError(f"a truncated JointState ({err})") from None
    return tuple(names), positions


def hand_encoders() -> dict[type, Any]:
    """Message class -> its hand-written encoder (none on a big-endian machine: the arrays'
    bytes are copied as they are in memory)."""
    return {JointState: JointStateEncoder().encode} if sys.byteorder == "little" else {}

"""CDR (XCDR1, little endian) written by hand for the messages a recording sends.

rclpy's C serializer costs a few microseconds per message in a tight loop but tens of them in a
running simulation (its code and buffers are cold by then, and it first converts the whole
Python message into a C one). Two encoders here write the bytes from the Python message directly:

- ``JointStateEncoder``: ``/joint_states`` at 50 Hz is the most frequent message a run records,
  and most of its bytes never change (the frame id and the joint names), so they are encoded
  once per list of names and only the stamp and the numbers are written per message;
- ``MessageEncoder``: any other message type, from the field types rosidl generates into each
  Python message class (``SLOT_TYPES``), compiled once per type into a list of field writers
  (numeric arrays are copied from their buffers, nested messages are their fields in order,
  one ``struct.pack`` for a nested message of numbers only such as a ``Duration`` or a ``Pose``).
  A type with a field it does not know (``char``, ``wstring``, ``long double``) is left to
  rclpy (``message_encoder`` returns None).

rclpy reads the bytes back as the message sent, and so does mcap-ros2-support
(``tests/test_recording_worker.py``, ``tests/test_cdr.py``); they differ from rclpy's own only in
padding (rclpy leaves its padding bytes uninitialized and pads the end to 8 bytes).
"""
from __future__ import annotations

import array
import importlib
import struct
import sys
from operator import attrgetter
from typing import Any, Callable, NamedTuple

from rosidl_parser import definition as idl
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


class JointStateArrays(NamedTuple):
    """What a recording reads of a ``sensor_msgs/JointState``."""

    name: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]


def _strings_at(data: bytes, at: int) -> tuple[list[str], int]:
    """The ``string[]`` at ``at`` and the offset after it."""
    at += -(at - 4) % 4
    (count,) = _COUNT.unpack_from(data, at)
    at += 4
    strings = []
    for _ in range(count):
        text, at = _string_at(data, at)
        strings.append(text)
    return strings, at


def _doubles_at(data: bytes, at: int) -> tuple[tuple[float, ...], int]:
    at += -(at - 4) % 4
    (size,) = _COUNT.unpack_from(data, at)
    at += 4
    if size:
        at += -(at - 4) % 8
    return struct.unpack_from(f"<{size}d", data, at), at + 8 * size


def joint_state_arrays(data: bytes) -> JointStateArrays:
    """The names, positions and velocities of a ``sensor_msgs/JointState`` in CDR (little
    endian, as ``JointStateEncoder`` and rclpy write it), without building the message (rclpy's
    deserializer costs several times more); ValueError for anything else."""
    if data[:4] != ENCAPSULATION:
        raise ValueError("not little-endian CDR")
    try:
        _, at = _string_at(data, 12)  # after the stamp: the frame id
        names, at = _strings_at(data, at)
        position, at = _doubles_at(data, at)
        velocity, at = _doubles_at(data, at)
    except struct.error as err:
        raise ValueError(f"a truncated JointState ({err})") from None
    return JointStateArrays(tuple(names), position, velocity)


class TrajectoryArrays(NamedTuple):
    """What a recording reads of a ``trajectory_msgs/JointTrajectory``: its stamp and, per point,
    its time from start (both in seconds), positions and velocities."""

    stamp_s: float
    joint_names: tuple[str, ...]
    times_s: tuple[float, ...]
    positions: tuple[tuple[float, ...], ...]
    velocities: tuple[tuple[float, ...], ...]


def joint_trajectory_arrays(data: bytes) -> TrajectoryArrays:
    """``joint_state_arrays`` for a ``trajectory_msgs/JointTrajectory`` (a policy's chunk, a
    controller's goal: hundreds of points, each a message rclpy would build)."""
    if data[:4] != ENCAPSULATION:
        raise ValueError("not little-endian CDR")
    try:
        sec, nanosec = _STAMP.unpack_from(data, 4)
        _, at = _string_at(data, 12)
        names, at = _strings_at(data, at)
        at += -(at - 4) % 4
        (count,) = _COUNT.unpack_from(data, at)
        at += 4
        times, positions, velocities = [], [], []
        for _ in range(count):
            position, at = _doubles_at(data, at)
            velocity, at = _doubles_at(data, at)
            _, at = _doubles_at(data, at)  # accelerations
            _, at = _doubles_at(data, at)  # effort
            at += -(at - 4) % 4
            point_sec, point_nanosec = _STAMP.unpack_from(data, at)
            at += 8
            times.append(point_sec + point_nanosec * 1e-9)
            positions.append(position)
            velocities.append(velocity)
    except struct.error as err:
        raise ValueError(f"a truncated JointTrajectory ({err})") from None
    return TrajectoryArrays(sec + nanosec * 1e-9, tuple(names), tuple(times), tuple(positions), tuple(velocities))


FieldWriter = Callable[[bytearray, Any], None]
"""Appends one field's value to a CDR buffer (started with the encapsulation header)."""

_FORMATS = {"boolean": "?", "octet": "B", "uint8": "B", "int8": "b", "uint16": "H", "int16": "h", "uint32": "I",
            "int32": "i", "uint64": "Q", "int64": "q", "float": "f", "double": "d"}
_ZEROS = bytes(8)


def _pad(buffer: bytearray, size: int) -> None:
    buffer += _ZEROS[:-(len(buffer) - 4) % size]


def _primitive(fmt: str) -> FieldWriter:
    packer = struct.Struct("<" + fmt)
    size, pack = packer.size, packer.pack

    def write(buffer: bytearray, value: Any) -> None:
        buffer += _ZEROS[:-(len(buffer) - 4) % size]
        buffer += pack(value)
    return write


def _string(buffer: bytearray, value: str) -> None:
    data = value.encode()
    buffer += _ZEROS[:-(len(buffer) - 4) % 4]
    buffer += _COUNT.pack(len(data) + 1)
    buffer += data
    buffer += b"\0"


def _numbers(fmt: str, counted: bool) -> FieldWriter:
    """A sequence (``counted``) or fixed array of numbers: rosidl holds them in an ``array.array``
    (sequences), a numpy array (fixed arrays) or a list (booleans)."""
    size = struct.calcsize(fmt)
    dtype = "<" + ("?" if fmt == "?" else fmt)

    def write(buffer: bytearray, values: Any) -> None:
        if counted:
            buffer += _ZEROS[:-(len(buffer) - 4) % 4]
            buffer += _COUNT.pack(len(values))
        if len(values):
            buffer += _ZEROS[:-(len(buffer) - 4) % size]
            if isinstance(values, array.array):
                buffer += values.tobytes()
            elif hasattr(values, "astype"):
                buffer += values.astype(dtype, copy=False).tobytes()
            else:
                buffer += struct.pack(f"<{len(values)}{fmt}", *values)
    return write


def _flat_leaves(cls: type[Any], prefix: str = "") -> list[tuple[str, str]] | None:
    """(dotted attribute, struct format) of every field of a message made of numbers only, nested
    messages included (``Duration``, ``Point``, ``Pose``, ``Wrench``...); None for any other."""
    leaves: list[tuple[str, str]] = []
    names = list(cls.get_fields_and_field_types())
    kinds = list(getattr(cls, "SLOT_TYPES", ()))
    if not names or len(names) != len(kinds):
        return None
    for name, kind in zip(names, kinds):
        path = f"{prefix}_{name}"
        if isinstance(kind, idl.BasicType) and kind.typename in _FORMATS:
            leaves.append((path, _FORMATS[kind.typename]))
        elif isinstance(kind, idl.NamespacedType):
            nested = _flat_leaves(_message_class(kind), path + ".")
            if nested is None:
                return None
            leaves += nested
        else:
            return None
    return leaves


def _flat(leaves: list[tuple[str, str]]) -> FieldWriter:
    """One ``struct.pack`` for a message of numbers only: its layout (the padding between fields)
    precomputed for each of the 8 places it can start at."""
    get = attrgetter(*(path for path, _ in leaves))
    packers = []
    for start in range(8):
        fmt, at = "<", start
        for _, code in leaves:
            size = struct.calcsize(code)
            fmt += "x" * (-at % size) + code
            at += -at % size + size
        packers.append(struct.Struct(fmt).pack)
    if len(leaves) == 1:
        return lambda buffer, msg: buffer.extend(packers[(len(buffer) - 4) % 8](get(msg)))
    return lambda buffer, msg: buffer.extend(packers[(len(buffer) - 4) % 8](*get(msg)))


def _items(item: FieldWriter, counted: bool) -> FieldWriter:
    def write(buffer: bytearray, values: Any) -> None:
        if counted:
            _pad(buffer, 4)
            buffer += _COUNT.pack(len(values))
        for value in values:
            item(buffer, value)
    return write


def _field_writer(kind: Any) -> FieldWriter | None:
    """How to write a field of rosidl type ``kind``; None where this module does not know it."""
    if isinstance(kind, idl.BasicType):
        fmt = _FORMATS.get(kind.typename)
        return None if fmt is None else _primitive(fmt)
    if isinstance(kind, (idl.UnboundedString, idl.BoundedString)):
        return _string
    if isinstance(kind, idl.NamespacedType):
        cls = _message_class(kind)
        leaves = _flat_leaves(cls)
        if leaves is not None:
            return _flat(leaves)
        encoder = _message_encoder(cls)
        return None if encoder is None else encoder.write
    if isinstance(kind, (idl.AbstractSequence, idl.Array)):
        counted = isinstance(kind, idl.AbstractSequence)
        element = kind.value_type
        if isinstance(element, idl.BasicType) and element.typename in _FORMATS:
            return _numbers(_FORMATS[element.typename], counted)
        item = _field_writer(element)
        return None if item is None else _items(item, counted)
    return None


def _message_class(kind: Any) -> type:
    result: type = getattr(importlib.import_module(".".join(kind.namespaces)), kind.name)
    return result


class MessageEncoder:
    """One message type to CDR (see the module doc); ``message_encoder`` makes them."""

    def __init__(self, fields: list[tuple[Callable[[Any], Any], FieldWriter]]) -> None:
        self._fields = fields

    def write(self, buffer: bytearray, msg: Any) -> None:
        for get, write in self._fields:
            write(buffer, get(msg))

    def encode(self, msg: Any, known: dict[int, bytes] | None = None) -> bytes:
        """``msg`` in CDR. ``known``: the CDR of messages encoded before, by ``id``, to reuse
        where one is this message's first field (a controller goal holds the trajectory also
        recorded on its own topic): a first field starts where a whole message does, so its
        bytes are the same. What is encoded here is added to it."""
        fields = self._fields
        head = known.get(id(fields[0][0](msg))) if known else None
        if head is None:
            buffer = bytearray(ENCAPSULATION)
        else:
            buffer, fields = bytearray(head), fields[1:]
        for get, write in fields:
            write(buffer, get(msg))
        data = bytes(buffer)
        if known is not None:
            known[id(msg)] = data
        return data


_COMPILED: dict[type, MessageEncoder | None] = {}
"""Per message class: its encoder, or None (left to rclpy). Message classes never change within
a process, so what is compiled once holds for every recording."""


def _message_encoder(cls: type[Any]) -> MessageEncoder | None:
    if cls not in _COMPILED:
        _COMPILED[cls] = None  # (no message type contains itself; a second look sees "not known")
        names = list(cls.get_fields_and_field_types())
        kinds = list(getattr(cls, "SLOT_TYPES", ()))
        writers = [_field_writer(kind) for kind in kinds]
        if not names and not kinds:  # an empty structure: IDL gives it one uint8 member
            _COMPILED[cls] = MessageEncoder([(lambda msg: 0, _primitive("B"))])
        elif len(names) == len(kinds) and all(w is not None for w in writers):
            _COMPILED[cls] = MessageEncoder([(attrgetter("_" + name), w) for name, w in zip(names, writers)])  # type: ignore[misc]
    return _COMPILED[cls]


def message_encoder(cls: type) -> Callable[[Any, dict[int, bytes] | None], bytes] | None:
    """The CDR encoder of message class ``cls`` (``encode(msg, known)``, see
    ``MessageEncoder.encode``); None for a type left to rclpy (see the module doc)."""
    if sys.byteorder != "little":
        return None  # the arrays' bytes are copied as they are in memory
    if cls is JointState:
        joint_states = JointStateEncoder()

        def encode_joint_state(msg: Any, known: dict[int, bytes] | None = None) -> bytes:
            return joint_states.encode(msg)

        return encode_joint_state
    encoder = _message_encoder(cls)
    return None if encoder is None else encoder.encode

"""Port declarations and the conversion of XML strings into typed values.

Every node class declares its ports as a tuple of ``PortInfo`` (name, type, default,
description, direction). In XML every value is a string; ``convert`` turns it into the declared
type, and a ``{key}`` (or ``{=}``, meaning the key named like the port) makes it a blackboard
reference resolved at tick time. Conversion of literals happens at load time, so a bad literal
is a load-time error that names the file, line, node and port.
"""
from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass
from typing import Any

from runtime.errors import ObjectiveError


class Direction(enum.Enum):
    INPUT = "input_port"
    OUTPUT = "output_port"
    INOUT = "inout_port"


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()
"""Default of a port that must be set in the XML."""


# Port types, named as they appear in `objective behaviors` and in TreeNodesModel XML.
class PortType(enum.Enum):
    STRING = "string"
    # ROS 2 messages held on the blackboard (never literals: ports of these types take a {key}).
    POSE_STAMPED = "geometry_msgs::msg::PoseStamped"
    POSE_STAMPED_LIST = "std::vector<geometry_msgs::msg::PoseStamped>"
    JOINT_STATE = "sensor_msgs::msg::JointState"
    JOINT_TRAJECTORY = "trajectory_msgs::msg::JointTrajectory"
    TWIST_STAMPED = "geometry_msgs::msg::TwistStamped"
    TWIST = "geometry_msgs::msg::Twist"
    WRENCH_STAMPED = "geometry_msgs::msg::WrenchStamped"
    WRENCH = "geometry_msgs::msg::Wrench"
    HEADER = "std_msgs::msg::Header"
    IMAGE = "sensor_msgs::msg::Image"
    CAMERA_INFO = "sensor_msgs::msg::CameraInfo"
    ANY_LIST = "std::vector<BT::Any>"
    """A vector of any element type (MoveIt Pro's templated vector nodes)."""
    # numbers, booleans, lists of them, anything
    FLOAT = "double"
    INT = "int"
    UINT = "unsigned int"
    BOOL = "bool"
    FLOAT_LIST = "std::vector<double>"
    INT_LIST = "std::vector<int>"
    STRING_LIST = "std::vector<std::string>"
    NODE_STATUS = "NodeStatus"
    """A status a node returns: SUCCESS, FAILURE, RUNNING or SKIPPED (converted to its name)."""
    ANY = "AnyTypeAllowed"


NUMERIC_TYPES = frozenset({PortType.FLOAT, PortType.INT, PortType.UINT, PortType.FLOAT_LIST, PortType.INT_LIST})
INT32_MIN, INT32_MAX, UINT32_MAX = -(2**31), 2**31 - 1, 2**32 - 1
"""BehaviorTree.CPP's ``int`` and ``unsigned int``: the widest an integer port can be."""


def _number(value: float) -> str:
    """A bound as people write it: 10, 0.001, 3.14159, 1e+06 only when it must."""
    if isinstance(value, int) or (float(value).is_integer() and abs(value) < 1e16):
        return str(int(value))
    return f"{value:.10g}"


@dataclass(frozen=True)
class Range:
    """The values a numeric port accepts: ``[min, max]``, either end open (``min_open``/``max_open``)
    or absent (None). ``unit`` is shown after the range (``(0, 600] s``)."""

    min: float | None = None
    max: float | None = None
    unit: str = ""
    min_open: bool = False
    max_open: bool = False
    finite: bool = True
    """False: +-infinity is accepted at an end with no bound (e.g. ``Range(0, None, finite=False)``)."""

    def __str__(self) -> str:
        low = "-inf" if self.min is None else _number(self.min)
        high = "inf" if self.max is None else _number(self.max)
        text = f"{'(' if self.min_open or self.min is None else '['}{low}, {high}{')' if self.max_open or self.max is None else ']'}"
        return f"{text} {self.unit}" if self.unit else text

    def accepts(self, value: float) -> bool:
        if isinstance(value, float) and (math.isnan(value) or (math.isinf(value) and self.finite)):
            return False
        if self.min is not None and (value < self.min or (self.min_open and value == self.min)):
            return False
        return not (self.max is not None and (value > self.max or (self.max_open and value == self.max)))


FINITE = Range(finite=True)
"""What a float port with no declared range accepts: any finite number."""


class NameKind(enum.Enum):
    """What a string port's value names in the world (``Names``)."""

    FRAME = "frame"
    """``world``, a robot link or a planning-scene object."""
    OBJECT = "object"
    """A planning-scene object."""
    JOINT_GROUP = "joint group"
    JOINT = "joint"
    WAYPOINT = "waypoint"
    SERVICE = "service"
    ACTION = "action"
    CONTROLLER = "controller"
    """A ros2_control controller the controller manager lists."""
    TOPIC = "topic"
    """A topic the world publishes (``interface``: its message type)."""


@dataclass(frozen=True)
class Names:
    """A string port (or each item of a string list) names a thing of the world: checked against
    the world before the first tick and by ``objective validate --world`` (``runtime.app.world_check``).
    An empty value means "none" and is not checked."""

    kind: NameKind
    interface: type | tuple[type, ...] | None = None
    """For a service or an action: the ROS 2 type it must have (e.g. ``GetActionChunk``), or the
    types it may have (a trajectory controller's action: either interface)."""
    creates: bool = False
    """The node creates the object it names (AddCollisionBox, PlaceSimBox): later nodes may name it."""
    activates: bool | None = None
    """For a controller: the node activates it (True) or deactivates it (False), for the nodes after it."""

    @property
    def interfaces(self) -> tuple[type, ...]:
        """``interface`` as a tuple of the types allowed (empty: none declared)."""
        if self.interface is None:
            return ()
        return self.interface if isinstance(self.interface, tuple) else (self.interface,)


@dataclass(frozen=True)
class PortInfo:
    name: str
    type: PortType = PortType.STRING
    default: Any = REQUIRED
    description: str = ""
    direction: Direction = Direction.INPUT
    valid: Range | None = None
    """The values a numeric port accepts (see ``Range``); checked at load time and when read."""
    length: int | None = None
    """How many items a list port takes (``3`` for x;y;z); None: any number."""
    names: Names | None = None
    """What the value names in the world (a frame, a joint group, an action, ...), if anything."""

    @property
    def required(self) -> bool:
        return self.default is REQUIRED and self.direction is not Direction.OUTPUT

    @property
    def has_default(self) -> bool:
        """False for required ports, outputs and optional ports without a value (default None)."""
        return self.default is not REQUIRED and self.default is not None and self.direction is not Direction.OUTPUT

    def describe_default(self) -> str:
        return to_xml_string(self.default) if self.has_default else ""


def InputPort(name: str, type: PortType = PortType.STRING, default: Any = REQUIRED, description: str = "",
              valid: Range | None = None, length: int | None = None, names: Names | None = None) -> PortInfo:
    return PortInfo(name, type, default, description, Direction.INPUT, valid, length, names)


def OutputPort(name: str, type: PortType = PortType.ANY, description: str = "", default: Any = REQUIRED) -> PortInfo:
    """An output port; ``default`` ("{key}") names the entry written when the XML leaves it unset."""
    return PortInfo(name, type, default, description, Direction.OUTPUT)


def InOutPort(name: str, type: PortType = PortType.ANY, default: Any = REQUIRED, description: str = "",
              valid: Range | None = None) -> PortInfo:
    return PortInfo(name, type, default, description, Direction.INOUT, valid)


def range_problem(info: PortInfo, value: Any) -> str | None:
    """Why a converted ``value`` is outside ``info.valid`` ("must be in (0, 10] s, got inf"), or None.

    Lists are checked for their ``info.length``, then item by item ("item 3 must be in ...").
    Only numeric ports are checked.
    """
    if info.type not in NUMERIC_TYPES or info.direction is Direction.OUTPUT:
        return None
    valid = info.valid or FINITE
    items = list(value) if isinstance(value, (list, tuple)) else [value]
    if info.length is not None and isinstance(value, (list, tuple)) and len(items) != info.length:
        return f"needs {info.length} values, got {len(items)}"
    for index, item in enumerate(items, 1):
        if isinstance(item, (int, float)) and not isinstance(item, bool) and not valid.accepts(item):
            which = f"item {index} " if isinstance(value, (list, tuple)) else ""
            wanted = "a finite number" if valid.min is None and valid.max is None else f"in {valid}"
            return f"{which}must be {wanted}, got {_shown(item)}"
    return None


def _shown(value: int | float) -> str:
    text = to_xml_string(value)
    return text if len(text) <= 24 else f"{text[:12]}... ({len(text.lstrip('-'))} digits)"


MESSAGE_CLASSES: dict[PortType, tuple[str, str]] = {
    PortType.POSE_STAMPED: ("geometry_msgs.msg", "PoseStamped"),
    PortType.JOINT_STATE: ("sensor_msgs.msg", "JointState"),
    PortType.JOINT_TRAJECTORY: ("trajectory_msgs.msg", "JointTrajectory"),
    PortType.TWIST_STAMPED: ("geometry_msgs.msg", "TwistStamped"),
    PortType.TWIST: ("geometry_msgs.msg", "Twist"),
    PortType.WRENCH_STAMPED: ("geometry_msgs.msg", "WrenchStamped"),
    PortType.WRENCH: ("geometry_msgs.msg", "Wrench"),
    PortType.HEADER: ("std_msgs.msg", "Header"),
    PortType.IMAGE: ("sensor_msgs.msg", "Image"),
    PortType.CAMERA_INFO: ("sensor_msgs.msg", "CameraInfo"),
}
"""Port types that hold one ROS 2 message: the module and class a value must be an instance of."""


def message_class(port_type: PortType) -> type:
    """The ROS 2 message class of a message port type (imported on first use)."""
    import importlib

    module, name = MESSAGE_CLASSES[port_type]
    message_class: type = getattr(importlib.import_module(module), name)
    return message_class


def ros_name(port_type: PortType) -> str:
    """``geometry_msgs/PoseStamped`` for ``geometry_msgs::msg::PoseStamped``."""
    return port_type.value.replace("::msg::", "/")


EXPECTS_FROM_BLACKBOARD: dict[PortType, str] = {
    PortType.POSE_STAMPED_LIST: "a list of geometry_msgs/PoseStamped from the blackboard",
    PortType.ANY_LIST: "a list from the blackboard",
    **{t: f"a {ros_name(t)} from the blackboard" for t in MESSAGE_CLASSES},
}
"""What a conversion error says a message or vector port expects."""


_REFERENCE = re.compile(r"^\{\s*([@A-Za-z_=][\w.@/:-]*)?\s*\}$")


def parse_reference(text: str, port_name: str) -> str | None:
    """The blackboard key of ``{key}`` / ``{=}``, or None for a literal."""
    m = _REFERENCE.match(text.strip()) if isinstance(text, str) else None
    if not m:
        return None
    key = m.group(1)
    if key is None:
        raise ValueError("empty blackboard reference '{}'")
    return port_name if key == "=" else key


_EXPECTS = {
    PortType.FLOAT: "a number",
    PortType.INT: "an integer",
    PortType.UINT: "a non-negative integer",
    PortType.BOOL: "true or false",
    PortType.FLOAT_LIST: "a ';'-separated list of numbers",
    PortType.INT_LIST: "a ';'-separated list of integers",
    PortType.STRING_LIST: "a ';'-separated list of strings",
    PortType.NODE_STATUS: "SUCCESS, FAILURE, RUNNING or SKIPPED",
}
NODE_STATUSES = ("SUCCESS", "FAILURE", "RUNNING", "SKIPPED")


class ConversionError(ObjectiveError, ValueError):
    """A value does not fit its port type; the message says what was expected and what came."""


def _plain_number(text: str) -> str:
    """``text`` when it is written with ASCII characters and no underscores, as BT.CPP reads
    numbers; Python's own ``int``/``float`` would also take "٣٠", "３０" and "1_000"."""
    if not text.isascii() or "_" in text:
        raise ValueError(text)
    return text


def _float(text: str) -> float:
    return float(_plain_number(text))


def _int(text: str) -> int:
    text = _plain_number(text).strip()
    try:
        return int(text, 0) if text.lower().startswith(("0x", "-0x")) else int(text)
    except ValueError:
        value = float(text)  # "3.0" is accepted as 3, "3.5" is not
        if not value.is_integer():
            raise
        return int(value)


def _bool(text: str) -> bool:
    lowered = text.strip().lower()
    if lowered in ("true", "1"):
        return True
    if lowered in ("false", "0"):
        return False
    raise ValueError(text)


def _split(text: str) -> list[str]:
    text = text.strip()
    if not text:
        return []
    return [part.strip() for part in text.split(";")]


def _message_list(value: Any, port_type: PortType) -> list[Any]:
    """A vector port's value: a list (copied, so the blackboard's list is never changed in place).

    An empty literal is the empty vector; a PoseStamped vector accepts only PoseStamped elements.
    """
    if isinstance(value, str) and not value.strip():
        return []
    if not isinstance(value, (list, tuple)):
        raise ValueError(value)
    if port_type is PortType.POSE_STAMPED_LIST:
        pose_cls = message_class(PortType.POSE_STAMPED)
        if not all(isinstance(v, pose_cls) for v in value):
            raise ValueError(value)
    return list(value)


def convert(value: Any, port_type: PortType) -> Any:
    """Convert a string (or an already typed blackboard value) to ``port_type``.

    Raises ConversionError("expects a number, got 'fast'") when it does not fit.
    """
    try:
        if port_type in (PortType.ANY,):
            return value
        if port_type is PortType.STRING:
            return value if isinstance(value, str) else to_xml_string(value)
        if port_type in MESSAGE_CLASSES:
            if isinstance(value, message_class(port_type)):
                return value
            raise ValueError(value)
        if port_type in (PortType.POSE_STAMPED_LIST, PortType.ANY_LIST):
            return _message_list(value, port_type)
        if isinstance(value, str):
            if port_type is PortType.FLOAT:
                return _float(value)
            if port_type is PortType.INT:
                return _int(value)
            if port_type is PortType.UINT:
                result = _int(value)
                if result < 0:
                    raise ValueError(value)
                return result
            if port_type is PortType.BOOL:
                return _bool(value)
            if port_type is PortType.FLOAT_LIST:
                return [_float(p) for p in _split(value)]
            if port_type is PortType.INT_LIST:
                return [_int(p) for p in _split(value)]
            if port_type is PortType.STRING_LIST:
                return _split(value)
            if port_type is PortType.NODE_STATUS and value.strip() in NODE_STATUSES:
                return value.strip()
        # A typed value from the blackboard: accept what fits, coerce numbers sensibly.
        if port_type is PortType.FLOAT and isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if port_type in (PortType.INT, PortType.UINT) and isinstance(value, int) and not isinstance(value, bool):
            if port_type is PortType.UINT and value < 0:
                raise ValueError(value)
            return value
        if port_type in (PortType.INT, PortType.UINT) and isinstance(value, float) and value.is_integer():
            return convert(int(value), port_type)
        if port_type is PortType.BOOL and isinstance(value, bool):
            return value
        if port_type is PortType.FLOAT_LIST and isinstance(value, (list, tuple)):
            return [float(v) for v in value]
        if port_type is PortType.INT_LIST and isinstance(value, (list, tuple)):
            return [int(v) for v in value]
        if port_type is PortType.STRING_LIST and isinstance(value, (list, tuple)):
            return [str(v) for v in value]
        if hasattr(value, "tolist") and port_type in (PortType.FLOAT_LIST, PortType.INT_LIST):
            return convert(value.tolist(), port_type)
    except (ValueError, TypeError, OverflowError):
        pass
    is_message = hasattr(value, "get_fields_and_field_types")  # a ROS message: its repr is pages long
    got = f"a {type(value).__module__.split('.')[0]}/{type(value).__name__}" if is_message else repr(value)
    expected = _EXPECTS.get(port_type) or EXPECTS_FROM_BLACKBOARD.get(port_type, port_type.value)
    raise ConversionError(f"expects {expected}, got {got}")


def to_xml_string(value: Any) -> str:
    """The XML spelling of a typed value (inverse of ``convert`` for literals)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isfinite(value) and value.is_integer():
            return repr(value)
        return repr(value)
    if isinstance(value, (list, tuple)):
        return ";".join(to_xml_string(v) for v in value)
    return str(value)

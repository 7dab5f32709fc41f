"""ROS 2 message definitions (``ros2msg`` text) generated from rosidl Python message classes.

An MCAP file that ``ros2 bag`` and Foxglove can open stores, per message type, its definition as
ROS 2 ``.msg`` text with every nested type appended after a separator line and ``MSG: pkg/Type``
(the "concatenated" scheme of the MCAP ``ros2msg`` schema encoding). The ``.msg`` files are not
reliably findable at run time here (no ``AMENT_PREFIX_PATH``), but every generated Python class
carries its field names and types (``SLOT_TYPES``), which is all a decoder needs. Comments and
constants are not carried there, so the generated text has neither.
"""
from __future__ import annotations

import importlib
from typing import Any

from rosidl_parser import definition as idl

SEPARATOR = "=" * 80

_BASIC = {
    "boolean": "bool",
    "octet": "byte",
    "char": "char",
    "float": "float32",
    "double": "float64",
    "long double": "float64",
}


def type_name(msg_class: type) -> str:
    """``pkg/msg/Type`` (or ``pkg/srv/Type_Request``...), the name ROS 2 tools use for a class."""
    parts = msg_class.__module__.split(".")
    if len(parts) < 2 or parts[1] not in ("msg", "srv", "action"):
        raise TypeError(f"{msg_class.__module__}.{msg_class.__name__} is not a generated ROS 2 message class")
    return f"{parts[0]}/{parts[1]}/{msg_class.__name__}"


def _nested_class(t: idl.NamespacedType) -> type:
    module = importlib.import_module(".".join(t.namespaces))
    return getattr(module, t.name)


def _field_type(t: Any, nested: list[idl.NamespacedType]) -> str:
    """The .msg spelling of one rosidl type; nested message types are appended to ``nested``."""
    if isinstance(t, idl.Array):
        return f"{_field_type(t.value_type, nested)}[{t.size}]"
    if isinstance(t, idl.BoundedSequence):
        return f"{_field_type(t.value_type, nested)}[<={t.maximum_size}]"
    if isinstance(t, idl.UnboundedSequence):
        return f"{_field_type(t.value_type, nested)}[]"
    if isinstance(t, idl.BoundedString):
        return f"string<={t.maximum_size}"
    if isinstance(t, idl.UnboundedString):
        return "string"
    if isinstance(t, idl.BoundedWString):
        return f"wstring<={t.maximum_size}"
    if isinstance(t, idl.UnboundedWString):
        return "wstring"
    if isinstance(t, idl.BasicType):
        return _BASIC.get(t.typename, t.typename)
    if isinstance(t, idl.NamespacedType):
        nested.append(t)
        return f"{t.namespaces[0]}/{t.name}"
    raise TypeError(f"cannot write rosidl type {t!r} as .msg text")


def _fields_text(msg_class: type, nested: list[idl.NamespacedType]) -> str:
    names = list(msg_class.get_fields_and_field_types())
    return "\n".join(f"{_field_type(t, nested)} {n}" for n, t in zip(names, msg_class.SLOT_TYPES)) + "\n"


def message_definition(msg_class: type) -> str:
    """The concatenated ``ros2msg`` definition of ``msg_class`` and every type it contains."""
    nested: list[idl.NamespacedType] = []
    parts = [_fields_text(msg_class, nested)]
    seen: set[str] = set()
    while nested:
        t = nested.pop(0)
        name = f"{t.namespaces[0]}/{t.name}"
        if name in seen:
            continue
        seen.add(name)
        parts.append(f"{SEPARATOR}\nMSG: {name}\n{_fields_text(_nested_class(t), nested)}")
    return "".join(parts)


def message_class(name: str) -> type:
    """The Python class of ``pkg/msg/Type`` (also ``pkg/Type``, read as a msg)."""
    parts = name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3:
        raise ValueError(f"'{name}' is not a ROS 2 type name (expected pkg/msg/Type)")
    module = importlib.import_module(f"{parts[0]}.{parts[1]}")
    found = getattr(module, parts[2], None)
    if found is None and "_" in parts[2]:  # Action_Goal, Service_Request...: nested in their interface
        interface, _, member = parts[2].rpartition("_")
        found = getattr(getattr(module, interface, None), member, None)
    if found is None:
        raise ValueError(f"no type '{parts[2]}' in {parts[0]}.{parts[1]}")
    return found

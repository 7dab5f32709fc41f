"""ROS 2 message definitions (``ros2msg`` text) as ``ros2 bag record`` writes them into MCAP.

Per message type, an MCAP ``ros2msg`` schema holds the type's ``.msg`` text followed, for every
nested type, by a separator line and ``MSG: pkg/msg/Type`` and that type's text (the
"concatenated" scheme rosbag2 uses). The text is read from the ``.msg``/``.srv``/``.action``
files the interface packages install (``<prefix>/share/<pkg>/<kind>/<Type>.<kind>``, prefixes
from ``AMENT_PREFIX_PATH`` and the running interpreter's), so comments and constants are kept.
A type whose file cannot be found is described from its generated Python class instead
(``SLOT_TYPES``: fields and types, which is all a decoder needs, without constants).
"""
from __future__ import annotations

import importlib
import os
import re
import sys
from functools import lru_cache
from pathlib import Path
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
    result: type = getattr(module, t.name)
    return result


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
        result: str = _BASIC.get(t.typename, t.typename)
        return result
    if isinstance(t, idl.NamespacedType):
        nested.append(t)
        return f"{t.namespaces[0]}/{t.name}"  # as .msg files spell it; the MSG: line has pkg/msg/Type
    raise TypeError(f"cannot write rosidl type {t!r} as .msg text")


def _fields_text(msg_class: type[Any], nested: list[idl.NamespacedType]) -> str:
    names = list(msg_class.get_fields_and_field_types())
    return "\n".join(f"{_field_type(t, nested)} {n}" for n, t in zip(names, msg_class.SLOT_TYPES)) + "\n"


def _share_dirs() -> list[Path]:
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    return [Path(p) / "share" for p in dict.fromkeys(prefixes)]


# The sections of an interface file, in order: .srv request/response, .action goal/result/feedback.
_SECTIONS = {"Request": 0, "Response": 1, "Goal": 0, "Result": 1, "Feedback": 2}


@lru_cache(maxsize=None)
def interface_text(name: str) -> str | None:
    """The installed text of ``pkg/msg/Type`` (or one section of ``pkg/srv/T_Request``,
    ``pkg/action/T_Goal``...), or None when no installed file has it."""
    package, kind, type_ = name.split("/")
    section = 0
    if kind != "msg":
        base, _, part = type_.rpartition("_")
        if part not in _SECTIONS:
            return None
        type_, section = base, _SECTIONS[part]
    for share in _share_dirs():
        path = share / package / kind / f"{type_}.{kind}"
        if path.is_file():
            parts = re.split(r"^---[ \t]*$", path.read_text(encoding="utf-8"), flags=re.MULTILINE)
            if section < len(parts):
                text = parts[section].strip("\n")
                return text + "\n" if text else ""
    return None


def _definition_text(msg_class: type, nested: list[idl.NamespacedType]) -> str:
    """One type's own text: the installed file's when there is one, else generated."""
    generated = _fields_text(msg_class, nested)  # always walked: it finds the nested types
    installed = interface_text(type_name(msg_class))
    return generated if installed is None else installed


def message_definition(msg_class: type) -> str:
    """The concatenated ``ros2msg`` definition of ``msg_class`` and every type it contains."""
    nested: list[idl.NamespacedType] = []
    parts = [_definition_text(msg_class, nested)]
    seen: set[str] = set()
    while nested:
        t = nested.pop(0)
        name = "/".join((*t.namespaces, t.name))
        if name in seen:
            continue
        seen.add(name)
        parts.append(f"{SEPARATOR}\nMSG: {name}\n{_definition_text(_nested_class(t), nested)}")
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
    result: type = found
    return result

"""The run's events as ROS 2 messages, so a bag viewer shows them next to the robot.

- node status changes go to ``/behavior_tree/node_status`` (``std_msgs/String``, one JSON object:
  node index, name, status, message), a topic a plot or a state-transitions panel reads;
- every other event (policy requests, seams, rejections, warnings, ``LogMessage`` output) goes
  to ``/rosout`` as ``rcl_interfaces/Log``, the topic Foxglove's and rqt's log views read, at
  the level a user expects (rejections and warnings WARN, errors ERROR).
"""
from __future__ import annotations

import json
from typing import Any

from builtin_interfaces.msg import Time
from rcl_interfaces.msg import Log
from std_msgs.msg import String

NODE_STATUS_TOPIC = "/behavior_tree/node_status"
ROSOUT_TOPIC = "/rosout"

_LEVELS = {"debug": Log.DEBUG, "info": Log.INFO, "warning": Log.WARN, "warn": Log.WARN, "error": Log.ERROR,
           "critical": Log.FATAL}
_WARNING_KINDS = {"warning", "chunk_rejected", "policy_halted"}


def stamp_of(nanoseconds: int) -> Time:
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def event_message(kind: str, source: str, data: dict[str, Any], stamp_ns: int) -> tuple[str, Any]:
    """(topic, message) of one event of the run (``data`` JSON-ready), stamped ``stamp_ns``."""
    if kind == "node_status":
        return NODE_STATUS_TOPIC, node_status_message(data, source)
    return ROSOUT_TOPIC, log_message(kind, source, data, stamp_of(stamp_ns))


def node_status_message(data: dict[str, Any], name: str) -> String:
    return String(data=json.dumps({"node": data.get("node"), "name": name, "status": data.get("status"),
                                   "message": data.get("message", "")}, default=str))


def _words(data: dict[str, Any]) -> str:
    if set(data) == {"message"}:
        return str(data["message"])
    return " ".join(f"{key}={value}" for key, value in data.items() if key != "level")


def log_message(kind: str, source: str, data: dict[str, Any], stamp: Time) -> Log:
    """One event as a ``/rosout`` line: ``name`` is the node that emitted it."""
    if kind == "log":
        level = _LEVELS.get(str(data.get("level", "info")).lower(), Log.INFO)
        text = str(data.get("message", ""))
    else:
        level = Log.WARN if kind in _WARNING_KINDS else Log.INFO
        if kind == "policy_finished" and data.get("status") == "FAILURE":
            level = Log.ERROR
        text = f"{kind}: {_words(data)}" if data else kind
    return Log(stamp=stamp, level=level, name=source or "objective", msg=text, file="", function=kind, line=0)

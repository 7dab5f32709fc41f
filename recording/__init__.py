"""Recording a run: ``Recorder`` (run.mcap + events.jsonl) and the ``RecordingBus`` proxy it installs.

Names are imported when first used: the recording worker imports parts of this package and
must not pay for the rest (the robot's kinematics) before it starts reading.
"""
from __future__ import annotations

from importlib import import_module
from typing import Any

from .files import EVENTS_FILE, MCAP_FILE

__all__ = ["EVENTS_FILE", "MCAP_FILE", "McapRos2Writer", "Recorder", "RecordingBus"]
_WHERE = {"McapRos2Writer": ".mcap_writer", "Recorder": ".recorder", "RecordingBus": ".bus"}


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(_WHERE[name], __name__), name)

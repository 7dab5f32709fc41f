"""``Recorder``: one run recorded into a directory (``objective run --record DIR``).

- ``run.mcap``: the bus traffic, through a ``RecordingBus`` installed as ``context.bus``, with
  what a 3D viewer needs to draw the run (``/tf``, the robot's and the scene's markers:
  ``runtime.recording.scene_view``) and the run's events on ``/rosout`` and
  ``/behavior_tree/node_status`` (``runtime.recording.event_messages``);
- ``events.jsonl``: one JSON object per line, ``{"time", "kind", "source", "data"}``: first the
  tree (``kind: "tree"``, every node with its parent, so the tree can be drawn again later),
  then every event of the run's ``EventLog`` as it happens (node status changes, chunk
  requests, seams, rejections, warnings...), then the joint limits and the run's summary.

Whatever ends the run (success, failure, an error, SIGINT/SIGTERM), the summary is written and
says how (``status``). A process killed outright (SIGKILL) leaves a partial recording: every
event up to the kill (the file is line-buffered) and every flushed MCAP chunk
(``McapRos2Writer``); ``objective report`` renders what there is and says it is partial.

The report (plots, video, tree, page) is rendered from these two files alone
(``runtime.report``), so ``objective report DIR`` can redo it after the run.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Iterable, TextIO

from ..crash import CRASH_LOG
from ..errors import ObjectiveError
from ..events import Event
from .bag_metadata import BAG_METADATA_FILE, bag_metadata_yaml
from .bus import JOINT_STATES_HZ, RecordingBus
from .live import LiveOptions, LiveView
from .event_messages import NODE_STATUS_TOPIC, ROSOUT_TOPIC, log_message, node_status_message
from .mcap_writer import LATCHED_QOS, McapRos2Writer, to_nanoseconds, wall_clock_origin_ns
from .scene_view import ROBOT_MARKERS_TOPIC, SCENE_MARKERS_TOPIC, TF_STATIC_TOPIC, SceneView, stamp_of

MCAP_FILE = "run.mcap"
EVENTS_FILE = "events.jsonl"
JOINTS_FILE, LATENCY_FILE, VIDEO_FILE, TREE_FILE, HTML_FILE = (
    "joints.png", "latency.png", "cameras.mp4", "tree.svg", "report.html")
REPORT_FILES = (JOINTS_FILE, LATENCY_FILE, VIDEO_FILE, TREE_FILE, HTML_FILE)
"""Rendered by ``runtime.report``; a new recording into the same directory removes the old ones."""


def jsonable(value: Any) -> Any:
    """``value`` with numpy arrays/scalars as lists/numbers and non-finite floats as None."""
    if hasattr(value, "tolist"):
        value = value.tolist()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return str(value)


def _type_label(node: Any, kind: str) -> str:
    """What the node is: its XML ID, or ``SubTree`` (with the tree's ID when the instance is renamed)."""
    if kind == "SubTree":
        tree_id = getattr(node, "tree_id", "")
        return "SubTree" if tree_id in ("", node.name) else f"SubTree {tree_id}"
    return getattr(node, "xml_id", type(node).__name__)


def node_record(index: int, node: Any, ids: dict[int, int], tree: Any) -> dict[str, Any]:
    """One node of the tree as ``events.jsonl`` stores it."""
    kind = getattr(type(node), "kind", None)
    info = tree.info(node) if tree is not None else None
    parent = getattr(node, "parent", None)
    return {
        "id": index,
        "parent": ids.get(id(parent)) if parent is not None else None,
        "name": node.name,
        "type": _type_label(node, kind.value if kind is not None else ""),
        "kind": kind.value if kind is not None else type(node).__name__,
        "transparent": bool(getattr(node, "transparent", False)),
        "location": str(info.location) if info is not None else None,
    }


class Tee:
    """Writes each message to several sinks (the MCAP file and a live view)."""

    def __init__(self, sinks: list[Any]) -> None:
        self.sinks = sinks
        self.qos: dict[str, Any] = {}
        for sink in sinks:
            sink.qos = self.qos

    def flush_if_due(self) -> None:
        for sink in self.sinks:
            flush = getattr(sink, "flush_if_due", None)
            if flush is not None:
                flush()

    def write(self, topic: str, msg: Any, seconds: float) -> None:
        for sink in self.sinks:
            sink.write(topic, msg, seconds)

    def close(self) -> None:
        for sink in self.sinks:
            sink.close()


class Recorder:
    """Records a run into ``directory`` and/or serves it live to Foxglove (see the module doc).

    Install it before the world starts. With ``directory=None`` nothing is written to disk.
    """

    def __init__(self, directory: Path | str | None, context: Any, nodes: Iterable[Any] = (), tree: Any = None,
                 joint_states_hz: float = JOINT_STATES_HZ, live: LiveOptions | None = None) -> None:
        self.directory = Path(directory) if directory is not None else None
        self.clock_origin_ns = wall_clock_origin_ns(context.clock.now())
        self.live = LiveView(live, self.clock_origin_ns) if live is not None else None
        sinks: list[Any] = [] if self.live is None else [self.live]
        self.writer: McapRos2Writer | None = None
        self._events: TextIO | None = None
        if self.directory is not None:
            self.writer = self._open(self.directory)
            sinks.insert(0, self.writer)
            # Line-buffered: every event is in the file as soon as it happens, whatever ends the process.
            self._events = open(self.directory / EVENTS_FILE, "w", encoding="utf-8", buffering=1)
        self.sink = Tee(sinks)
        self.sink.qos.update({topic: LATCHED_QOS for topic in (TF_STATIC_TOPIC, ROBOT_MARKERS_TOPIC, SCENE_MARKERS_TOPIC)})
        self.context = context
        self.bus = RecordingBus(context.bus, self.sink, joint_states_hz)
        context.bus = self.bus
        view = SceneView(lambda: getattr(context, "scene", None), self.sink.write, self.stamp)
        self.bus.joint_state_listeners.append(view.joint_state)
        nodes = list(nodes)
        ids = {id(node): i for i, node in enumerate(nodes)}
        tree_id = getattr(tree, "tree_id", "")
        self._write({"time": context.clock.now(), "kind": "tree", "source": tree_id,
                     "data": {"nodes": [node_record(i, n, ids, tree) for i, n in enumerate(nodes)]}})
        context.events.subscribe(self._on_event)
        self.stopped = False

    def _open(self, directory: Path) -> McapRos2Writer:
        if directory.exists() and not directory.is_dir():
            raise ObjectiveError(f"--record {directory}: exists and is not a directory")
        try:
            directory.mkdir(parents=True, exist_ok=True)
            for name in (*REPORT_FILES, BAG_METADATA_FILE, CRASH_LOG):  # a previous run's files must not pass for this run's
                (directory / name).unlink(missing_ok=True)
            return McapRos2Writer(directory / MCAP_FILE, self.clock_origin_ns)
        except OSError as err:
            raise ObjectiveError(f"--record {directory}: cannot write there ({err.strerror})") from None

    def stamp(self, seconds: float) -> Any:
        """A ROS time stamp for ``seconds`` of the runtime clock (wall-clock based, like log times)."""
        return stamp_of(self.clock_origin_ns + to_nanoseconds(seconds))

    def _write(self, record: dict[str, Any]) -> None:
        if self._events is not None:
            self._events.write(json.dumps(jsonable(record), allow_nan=False) + "\n")

    def _on_event(self, event: Event) -> None:
        if self.stopped:
            return
        self._write({"time": event.time, "kind": event.kind, "source": event.source, "data": event.data})
        if event.kind == "node_status":
            self.sink.write(NODE_STATUS_TOPIC, node_status_message(event.data, event.source), event.time)
        else:
            self.sink.write(ROSOUT_TOPIC, log_message(event.kind, event.source, jsonable(event.data),
                                                      self.stamp(event.time)), event.time)

    def stop(self) -> None:
        """Stop recording (idempotent): the MCAP file is finished, the joint limits noted."""
        if self.stopped:
            return
        self.stopped = True
        try:
            self.sink.close()
            if self.writer is not None and self.directory is not None:
                w = self.writer
                (self.directory / BAG_METADATA_FILE).write_text(
                    bag_metadata_yaml(MCAP_FILE, w.topics, w.counts, w.first_ns, w.last_ns), encoding="utf-8")
        finally:
            limits = getattr(getattr(self.context, "scene", None), "limits", None)
            if limits is not None:
                joints = [{"name": j.name, "lower": j.lower, "upper": j.upper, "max_velocity": j.max_velocity}
                          for j in limits.joints]
                self._write({"time": self.context.clock.now(), "kind": "joint_limits", "source": "scene",
                             "data": {"joints": joints}})

    def finish(self, summary: dict[str, Any]) -> None:
        """Stop, append the run's summary and close ``events.jsonl``."""
        self.stop()
        self._write({"time": self.context.clock.now(), "kind": "run_summary", "source": "runner", "data": summary})
        self.close()

    def close(self) -> None:
        self.stop()
        if self._events is not None:
            self._events.close()
            self._events = None

"""``Recorder``: one run recorded into a directory (``objective run --record DIR``).

- ``run.mcap``: the bus traffic, through a ``RecordingBus`` installed as ``context.bus``, with
  what a 3D viewer needs to draw the run (``/tf``, the robot's and the scene's markers:
  ``recording.scene_view``) and the run's events on ``/rosout`` and
  ``/behavior_tree/node_status`` (``recording.event_messages``);
- ``events.jsonl``: one JSON object per line, ``{"time", "kind", "source", "data"}``: first the
  tree (``kind: "tree"``, every node with its parent, so the tree can be drawn again later),
  then every event of the run's ``EventLog`` as it happens (node status changes, chunk
  requests, seams, rejections, warnings...), then the joint limits and the run's summary.

Whatever ends the run (success, failure, an error, SIGINT/SIGTERM), the summary is written and
says how (``status``). A process killed outright (SIGKILL) leaves a partial recording: every
event up to the kill (the file is line-buffered) and every flushed MCAP chunk
(``McapRos2Writer``); ``objective report`` renders what there is and says it is partial.

With a directory, the files are written by the recording worker (``recording.report.worker``):
this process only serializes and hands the bytes over (``recording.handoff``). If the
worker cannot be started, this process writes them itself, as before. If the worker dies during
the run, ``run.mcap`` ends at the last chunk the worker flushed (it is read as partial: at most
``FLUSH_INTERVAL_S`` of messages and what sat in the pipe are lost) and this process goes on
writing ``events.jsonl`` itself, starting with the lines the worker did not get and a warning
that says what happened; the report is then rendered here.

A recording that cannot be written (a full disk) never stops the run: whichever process writes
it stops writing, and the run's summary, written into room kept for it from the start
(``recording.reserve``), says the recording is incomplete and why
(``recording_incomplete``).

The report (plots, video, tree, page) is rendered from these two files alone
(``recording.report``), so ``objective report DIR`` can redo it after the run.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
from pathlib import Path
from typing import IO, Any, Callable, Iterable, Protocol, runtime_checkable

from runtime.tree import node_info
from runtime.tree.crash import CRASH_LOG
from runtime.errors import ObjectiveError
from runtime.tree.events import Event
from .bag_metadata import BAG_METADATA_FILE, bag_metadata_yaml
from .bus import JOINT_STATES_HZ, RecordingBus
from .live import LiveOptions, LiveView
from .event_messages import event_message, stamp_of
from .files import EVENTS_FILE, MCAP_FILE, REPORT_FILES, open_existing, open_new, recording_held, write_new
from .handoff import Handoff
from .mcap_writer import LATCHED_QOS, McapRos2Writer, to_nanoseconds, wall_clock_origin_ns
from .reserve import append_line, release, reserve, why_not_written
from .scene_view import ROBOT_MARKERS_TOPIC, SCENE_MARKERS_TOPIC, SceneView
from .tf_model import TF_STATIC_TOPIC



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
        tree_id = node_info.tree_id(node)
        return "SubTree" if tree_id in ("", node.name) else f"SubTree {tree_id}"
    return node_info.xml_id(node)


def node_record(index: int, node: Any, ids: dict[int, int], tree: Any) -> dict[str, Any]:
    """One node of the tree as ``events.jsonl`` stores it."""
    kind = node_info.declared_kind(type(node))
    info = tree.info(node) if tree is not None else None
    parent = getattr(node, "parent", None)
    return {
        "id": index,
        "parent": ids.get(id(parent)) if parent is not None else None,
        "name": node.name,
        "type": _type_label(node, kind.value if kind is not None else ""),
        "kind": kind.value if kind is not None else type(node).__name__,
        "transparent": node_info.is_transparent(node),
        "location": str(info.location) if info is not None else None,
    }


@runtime_checkable
class BufferingSink(Protocol):
    """A sink that buffers what it is given (the MCAP writer, the hand-off to the recording
    worker): ``Tee.flush_if_due`` flushes it once per tick."""

    def flush_if_due(self) -> None:
        """Write out what is buffered when it is time to."""
        ...


class Tee:
    """Writes each message to several sinks (the MCAP file and a live view); a sink whose write
    fails (``OSError``: a full disk) is dropped and ``on_error`` told."""

    def __init__(self, sinks: list[Any]) -> None:
        self.sinks = sinks
        self.qos: dict[str, Any] = {}
        self.on_error: Callable[[Any, OSError], None] = lambda sink, err: None
        for sink in sinks:
            sink.qos = self.qos

    def flush_if_due(self) -> None:
        for sink in list(self.sinks):
            if isinstance(sink, BufferingSink):
                self._guarded(sink, sink.flush_if_due)

    def write(self, topic: str, msg: Any, seconds: float) -> None:
        for sink in list(self.sinks):
            self._guarded(sink, lambda: sink.write(topic, msg, seconds))

    def _guarded(self, sink: Any, write: Callable[[], None]) -> None:
        try:
            write()
        except OSError as err:
            self.sinks.remove(sink)
            self.on_error(sink, err)

    def close(self) -> None:
        for sink in self.sinks:
            sink.close()


class Recorder:
    """Records a run into ``directory`` and/or serves it live to Foxglove (see the module doc).

    Install it before the world starts. With ``directory=None`` nothing is written to disk.
    ``worker``: the recording worker (``directory`` only); the run asks it for the report.
    """

    def __init__(self, directory: Path | str | None, context: Any, nodes: Iterable[Any] = (), tree: Any = None,
                 joint_states_hz: float = JOINT_STATES_HZ, live: LiveOptions | None = None) -> None:
        self.directory = Path(directory) if directory is not None else None
        self.context = context
        self.clock_origin_ns = wall_clock_origin_ns(context.clock.now())
        self.live = LiveView(live, self.clock_origin_ns) if live is not None else None
        sinks: list[Any] = [] if self.live is None else [self.live]
        self.worker: Any = None
        self.handoff: Handoff | None = None
        self.writer: McapRos2Writer | None = None
        self._events: IO[str] | None = None
        self._lines: list[str] | None = None
        """Every line sent to the worker (while it writes ``events.jsonl``)."""
        self.incomplete: str | None = None
        """Why this process stopped writing the recording (a full disk); the run goes on."""
        if self.directory is not None:
            sinks.insert(0, self._open(self.directory))
        self.sink = Tee(sinks)
        self.sink.on_error = self._sink_failed
        self.sink.qos.update({topic: LATCHED_QOS for topic in (TF_STATIC_TOPIC, ROBOT_MARKERS_TOPIC, SCENE_MARKERS_TOPIC)})
        self.bus = RecordingBus(context.bus, self.sink, joint_states_hz)
        context.bus = self.bus
        tf_in_worker = self.handoff.tf_model if self.handoff is not None and self.live is None else None
        self.view = SceneView(lambda: getattr(context, "scene", None), self.sink.write, self.stamp, tf_in_worker)
        self.bus.joint_state_listeners.append(self.view.joint_state)
        nodes = list(nodes)
        ids = {id(node): i for i, node in enumerate(nodes)}
        tree_id = getattr(tree, "tree_id", "")
        self._write({"time": context.clock.now(), "kind": "tree", "source": tree_id,
                     "data": {"nodes": [node_record(i, n, ids, tree) for i, n in enumerate(nodes)]}})
        context.events.subscribe(self._on_event)
        self.stopped = False

    def _open(self, directory: Path) -> Handoff | McapRos2Writer:
        """Prepare ``directory`` and start the worker that writes it; the sink of the recording."""
        from .report.worker import ReportWorker

        if directory.exists() and not directory.is_dir():
            raise ObjectiveError(f"--record {directory}: exists and is not a directory")
        held = recording_held(directory)
        if held is not None:
            raise ObjectiveError(f"--record {directory}: already holds a recording ({held}); record into a new "
                                 "directory, or remove that one first")
        try:
            directory.mkdir(parents=True, exist_ok=True)
            for name in (*REPORT_FILES, BAG_METADATA_FILE, CRASH_LOG):  # a previous run's files must not pass for this run's
                (directory / name).unlink(missing_ok=True)
            open_new(directory / EVENTS_FILE).close()
            reserve(directory)
            self.worker = ReportWorker()
            self.worker.start()  # it also imports the report's libraries while the run goes on
            self.handoff = self.worker.record(directory, self.clock_origin_ns)
            if self.handoff is not None:
                self.handoff.on_lost = self._worker_lost
                self._lines = []
                return self.handoff
            self.writer = McapRos2Writer(directory / MCAP_FILE, self.clock_origin_ns)  # no worker: written here
            self._events = open_existing(directory / EVENTS_FILE, "a", "utf-8", buffering=1)
            return self.writer
        except OSError as err:
            raise ObjectiveError(f"--record {directory}: cannot write there ({err.strerror})") from None

    def _worker_lost(self, lost: Exception) -> None:
        """The worker died or hung mid-run: this process writes ``events.jsonl`` from now on, from
        its own copy of every line; ``run.mcap`` stays as the worker left it (partial), or, if the
        worker never wrote it, this process writes it from now on."""
        assert self.directory is not None and self.worker is not None and self._lines is not None
        self.worker.close()
        lines, self._lines = self._lines, None
        try:
            events = self.directory / EVENTS_FILE
            scratch = events.with_name(EVENTS_FILE + ".new")
            write_new(scratch, "".join(lines))
            os.replace(scratch, events)
            self._events = open_existing(events, "a", "utf-8", buffering=1)
            mcap = self.directory / MCAP_FILE
            now = self.context.clock.now()
            if mcap.is_file() and mcap.stat().st_size > 0:
                what = f"{MCAP_FILE} ends at the last chunk it wrote (partial)"
            else:
                self.writer = McapRos2Writer(mcap, self.clock_origin_ns)
                self.writer.qos = self.sink.qos
                self.sink.sinks[self.sink.sinks.index(self.handoff)] = self.writer
                self.view.tf_here()  # the worker computed /tf from the joint states
                what = f"{MCAP_FILE} holds what was recorded from {now:.2f} s on (partial)"
        except OSError as err:
            self._stop_writing(err)
            return
        self._write({"time": now, "kind": "warning", "source": "recorder",
                     "data": {"message": f"recording: {lost}: {what}; {EVENTS_FILE} is whole"}})

    def _sink_failed(self, sink: Any, err: OSError) -> None:
        if sink is self.live:
            self.context.logger.warning("live view: stopped serving the run (%s)", err)
        else:
            self._stop_writing(err)

    def _stop_writing(self, err: OSError) -> None:
        """This process cannot write the recording (a full disk): it stops writing, the run goes
        on, and the summary, written into the room kept for it (``recording.reserve``),
        says why the recording is incomplete."""
        assert self.directory is not None
        if self.incomplete is None:
            self.incomplete = why_not_written(err, str(self.directory), self.context.clock.now())
        release(self.directory)
        writer, self.writer = self.writer, None
        if writer is not None:
            if writer in self.sink.sinks:
                self.sink.sinks.remove(writer)
            writer.abandon()
        events, self._events = self._events, None
        if events is not None:
            with contextlib.suppress(OSError):
                events.close()

    def stamp(self, seconds: float) -> Any:
        """A ROS time stamp for ``seconds`` of the runtime clock (wall-clock based, like log times)."""
        return stamp_of(self.clock_origin_ns + to_nanoseconds(seconds))

    def _write(self, record: dict[str, Any], note: bool = True) -> dict[str, Any]:
        """``record`` as a line of ``events.jsonl`` (``note``: not also a message); returned JSON-ready."""
        record = jsonable(record)
        line = json.dumps(record, allow_nan=False) + "\n"
        if self._lines is not None:
            self._lines.append(line)  # kept until the end, in case the worker is lost
            assert self.handoff is not None  # lines are kept for the worker only
            self.handoff.event(line, note)
        elif self._events is not None:
            try:
                self._events.write(line)
            except OSError as err:
                self._stop_writing(err)
        return record

    def _on_event(self, event: Event) -> None:
        if self.stopped:
            return
        record = self._write({"time": event.time, "kind": event.kind, "source": event.source, "data": event.data},
                             note=False)
        handoff = self.handoff
        sinks = [s for s in self.sink.sinks if handoff is None or s is not handoff or handoff.closed]  # the worker makes its own
        if sinks:
            topic, msg = event_message(event.kind, event.source, record["data"],
                                       self.clock_origin_ns + to_nanoseconds(event.time))
            for sink in sinks:
                sink.write(topic, msg, event.time)

    def stop(self) -> None:
        """Stop recording (idempotent): no more events; the joint limits are noted."""
        if self.stopped:
            return
        self.stopped = True
        limits = getattr(getattr(self.context, "scene", None), "limits", None)
        if limits is not None:
            joints = [{"name": j.name, "lower": j.lower, "upper": j.upper, "max_velocity": j.max_velocity}
                      for j in limits.joints]
            self._write({"time": self.context.clock.now(), "kind": "joint_limits", "source": "scene",
                         "data": {"joints": joints}})

    def finish(self, summary: dict[str, Any]) -> None:
        """Stop, append the run's summary and close the recording."""
        self.stop()
        if self.handoff is not None:
            self.handoff.send()  # a worker lost by now is noted before the summary, which stays the last line
        if self.incomplete is not None:
            summary = {**summary, "recording_incomplete": self.incomplete}
        record = self._write({"time": self.context.clock.now(), "kind": "run_summary", "source": "runner", "data": summary})
        if self.incomplete is not None and self.directory is not None:
            append_line(self.directory / EVENTS_FILE, json.dumps(record, allow_nan=False) + "\n")
        self.close()

    def close(self) -> None:
        """Finish the files (the worker does, when it writes them: ``metadata.yaml`` included)."""
        self.stop()
        try:
            self.sink.close()
            if self.writer is not None and self.directory is not None:
                self.writer.close()  # (it may have replaced a worker lost while the sinks were closing)
                w = self.writer
                write_new(self.directory / BAG_METADATA_FILE,
                          bag_metadata_yaml(MCAP_FILE, w.topics, w.counts, w.first_ns, w.last_ns))
                release(self.directory)
        except OSError as err:
            self._stop_writing(err)
        finally:
            if self._events is not None:
                self._events.close()
                self._events = None


"""``RecordingSession``: the recording worker's side of a recorded run (see ``recording.handoff``).

It writes what the run sends: ``run.mcap`` (the run's serialized messages as they are, plus the
``/rosout`` and node status messages of its events), ``events.jsonl`` (each batch's lines in one
write) and, when the run says the recording is over, the MCAP summary section and
``metadata.yaml``. Meanwhile it builds the report's data (``recording.report.data.McapContents``), so
the report needs no reading back.

Crash safety as in the run before: ``events.jsonl`` gets each batch as it arrives, and the MCAP
chunk is closed and flushed every ``FLUSH_INTERVAL_S``. If the run dies (end of file without
``END``), everything received is flushed and the files are left as a killed run leaves them: no
run summary, no MCAP summary section (``objective report`` renders them as partial).

A write that fails (a full disk) stops the recording, never the run: the files keep what they
hold, the frames that follow are read and dropped, and the run's summary is still written, with
``recording_incomplete`` saying why (``objective report`` says the recording is incomplete).
"""
from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Any

from rclpy.serialization import serialize_message

from .report.data import McapContents, Recording, add_event, mark_unfinished
from .bag_metadata import BAG_METADATA_FILE, bag_metadata_yaml
from .bus import JOINT_STATES_TOPIC
from .event_messages import event_message
from .handoff import MESSAGE_HEADER, Frame
from .mcap_writer import LATCHED_QOS, McapRos2Writer, OfferedQos, SerializedMessage, to_nanoseconds
from .files import EVENTS_FILE, MCAP_FILE, open_existing, write_new
from .reserve import append_line, release, why_not_written
from .schema import type_name
from .tf_model import TF_STATIC_TOPIC, TF_TOPIC, TF_TYPE, TfModel, TfWriter


class RecordingSession:
    """Writes one recording from the frames the run sends (``take``)."""

    def __init__(self, directory: Path | str, clock_origin_ns: int) -> None:
        self.directory = Path(directory)
        self.clock_origin_ns = clock_origin_ns
        self.incomplete: str | None = None
        """Why the recording stopped before the run did (a write failed: a full disk)."""
        self._summary: dict[str, Any] | None = None
        self._lines = bytearray()
        self._channels: dict[int, tuple[int, str, str]] = {}
        """The run's channel id -> (MCAP channel id, topic, type name)."""
        self.recording = Recording(self.directory)
        self.contents = McapContents(self.recording, clock_origin_ns)
        self.tf: TfWriter | None = None
        """Set by the run's ``TF_MODEL``: ``/tf`` is computed here from each joint state."""
        self._tf_static_due = False
        self._tf_due: list[tuple[int, Any]] = []
        """Joint states (log time, ``JointStateArrays``) whose ``/tf`` is not written yet."""
        self._topic_channels: dict[str, int] = {}
        """Topic -> MCAP channel id: one channel per topic, whether the run or this worker writes
        it (``/tf`` comes from the run for a robot a ``TfModel`` cannot describe)."""
        self.ended = False
        try:
            self.writer = McapRos2Writer(self.directory / MCAP_FILE, clock_origin_ns)
            self._events = open_existing(self.directory / EVENTS_FILE)  # the run created it empty
        except OSError as err:
            self._stop_writing(err)

    def take(self, kind: Frame, payload: bytes) -> None:
        """One frame of the run's; a write that fails stops the recording (``_stop_writing``)."""
        if self.incomplete is not None:
            self._take_after_stop(kind, payload)
            return
        try:
            self._take(kind, payload)
        except OSError as err:
            self._stop_writing(err)

    def _take(self, kind: Frame, payload: bytes) -> None:
        if kind is Frame.MESSAGE:
            channel, log_time_ns = MESSAGE_HEADER.unpack_from(payload)
            mcap_channel, topic, name = self._channels[channel]
            data = payload[MESSAGE_HEADER.size:]
            self.writer.write_cdr(mcap_channel, data, log_time_ns)
            joint_state = self.contents.add(topic, name, log_time_ns, data)
            if self.tf is not None and topic == JOINT_STATES_TOPIC and joint_state is not None:
                self._tf_due.append((log_time_ns, joint_state))
        elif kind is Frame.CHANNEL:
            d = json.loads(payload)
            qos = OfferedQos(*d["qos"])
            self._channels[d["id"]] = (self._channel(d["topic"], d["type"], qos), d["topic"], d["type"])
        elif kind in (Frame.EVENT, Frame.NOTE):
            self._lines += payload
            record = json.loads(payload)
            add_event(record, self.recording)
            if record.get("kind") == "run_summary":
                self._summary = record
            if kind is Frame.EVENT:
                self._event_message(record)
        elif kind is Frame.TF_MODEL:
            self._write_tf()  # the joint states before it, with the model they came with
            model = json.loads(payload)  # null: the run computes /tf itself from now on
            self.tf = TfWriter(TfModel.from_json(model)) if model is not None else None
            self._tf_static_due = model is not None
        elif kind is Frame.END:
            self.end()

    def _write_tf(self) -> None:
        """``/tf`` (and ``/tf_static`` the first time) of the joint states taken since the last
        time, stamped like them: computed together, once per read from the pipe."""
        due, self._tf_due = self._tf_due, []
        if self.tf is None:
            return
        groups: dict[tuple[str, ...], list[tuple[int, Any]]] = {}
        for log_time_ns, state in due:
            if len(state.position) == len(state.name):  # (one without positions cannot place the robot)
                groups.setdefault(state.name, []).append((log_time_ns, state.position))
        if groups and self._tf_static_due:
            self._tf_static_due = False
            first_ns = min(states[0][0] for states in groups.values())
            self._write_own(TF_STATIC_TOPIC, self.tf.tf_static(first_ns), first_ns, LATCHED_QOS)
        for names, states in groups.items():
            stamps_ns = [log_time_ns for log_time_ns, _ in states]
            for log_time_ns, data in zip(stamps_ns, self.tf.tf(names, [p for _, p in states], stamps_ns)):
                self._write_own(TF_TOPIC, data, log_time_ns)

    def _channel(self, topic: str, type_name: str, qos: OfferedQos) -> int:
        channel = self._topic_channels.get(topic)
        if channel is None:
            channel = self._topic_channels[topic] = self.writer.open_channel(topic, type_name, qos)
        return channel

    def _write_own(self, topic: str, data: bytes, log_time_ns: int, qos: OfferedQos = OfferedQos()) -> None:
        """A ``TFMessage`` this worker computed, on ``topic``."""
        self.writer.write_cdr(self._channel(topic, TF_TYPE, qos), data, log_time_ns)
        self.contents.add(topic, TF_TYPE, log_time_ns, data)

    def _event_message(self, record: dict[str, Any]) -> None:
        stamp_ns = self.clock_origin_ns + to_nanoseconds(record["time"])
        topic, msg = event_message(record["kind"], record["source"], record["data"], stamp_ns)
        data = serialize_message(msg)
        self.writer.write(topic, SerializedMessage(type(msg), data), record["time"])
        self.contents.add(topic, type_name(type(msg)), stamp_ns, data)

    def flush_if_due(self) -> None:
        """After each read from the pipe: ``/tf``, the events to their file, the MCAP chunk when due."""
        if self.incomplete is not None:
            return
        try:
            self._write_tf()
            self._write_lines()
            self.writer.flush_if_due()
        except OSError as err:
            self._stop_writing(err)

    def _write_lines(self) -> None:
        if self._lines:
            self._events.write(self._lines)
            self._events.flush()
            self._lines.clear()

    def end(self) -> None:
        """The run is over: finish ``run.mcap`` (summary section), ``metadata.yaml`` and the report's data."""
        if self.ended:
            return
        self.ended = True
        self._write_tf()
        self._write_lines()
        self._events.close()
        w = self.writer
        w.close()
        write_new(self.directory / BAG_METADATA_FILE, bag_metadata_yaml(MCAP_FILE, w.topics, w.counts, w.first_ns, w.last_ns))
        release(self.directory)
        self._finish_data()

    def abandon(self) -> None:
        """The run died: everything received goes to the files, which stay partial."""
        if self.incomplete is not None:
            return
        try:
            self._write_tf()
            self._write_lines()
            self._events.close()
            self.writer.flush()
        except OSError as err:
            self._stop_writing(err)

    # -- a recording that cannot be written ---
    def _stop_writing(self, err: OSError) -> None:
        """A write failed (a full disk): stop recording, keep what the files hold (``run.mcap`` reads
        up to its last whole chunk), and keep draining the run's frames so the run goes on. The
        run's summary is still written, into the room kept for it (``recording.reserve``),
        saying why the recording is incomplete."""
        self.incomplete = why_not_written(err, str(self.directory), self.contents.end_time_s())
        release(self.directory)
        self._lines.clear()
        self._tf_due.clear()
        if getattr(self, "writer", None) is not None:
            self.writer.abandon()
        if getattr(self, "_events", None) is not None:
            with contextlib.suppress(OSError):
                self._events.close()
        if self._summary is not None:
            self._write_summary(self._summary)
        if self.ended:  # (it failed finishing the files)
            self._finish_data()

    def _take_after_stop(self, kind: Frame, payload: bytes) -> None:
        """Only the run's summary is written now; the end marks the recording incomplete."""
        if kind in (Frame.EVENT, Frame.NOTE):
            record = json.loads(payload)
            if record.get("kind") == "run_summary":
                self._write_summary(record)
        elif kind is Frame.END and not self.ended:
            self.ended = True
            self._finish_data()

    def _finish_data(self) -> None:
        self.contents.finish()
        mark_unfinished(self.recording)

    def _write_summary(self, record: dict[str, Any]) -> None:
        record["data"]["recording_incomplete"] = self.incomplete
        add_event(record, self.recording)
        self._summary = None
        append_line(self.directory / EVENTS_FILE, json.dumps(record) + "\n")


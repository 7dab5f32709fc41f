"""The recording worker writes the recording while the run goes on: what the run hands over
(``recording.handoff``), and what is left when one side of the pipe dies."""
from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from recording.handoff import Frame, Handoff, WorkerLost, read_frames, write_all
from recording.mcap_writer import LATCHED_QOS
from recording.session import RecordingSession
from recording.report import load_recording
from recording.report.worker import ReportWorker

from .test_interrupts import GRIPPER
from .test_recording import read_events, read_mcap, record_run

WAIT_XML = f"""<root BTCPP_format="4">
  <BehaviorTree ID="Hold Still">
    <Sequence><MoveGripperAction {GRIPPER} position="0.5"/><Wait name="hold" seconds="4"/></Sequence>
  </BehaviorTree>
</root>
"""


def handed_over(tmp_path: Path, *writes: tuple) -> tuple[Path, RecordingSession]:
    """Send ``writes`` (topic, message, seconds) and two events through a pipe into a session."""
    read_end, write_end = os.pipe()
    handoff = Handoff(write_end, str(tmp_path), clock_origin_ns=1_000_000_000)
    handoff.qos["/latched"] = LATCHED_QOS
    (tmp_path / "events.jsonl").write_bytes(b"")
    handoff.event(json.dumps({"time": 0.0, "kind": "tree", "source": "t", "data": {"nodes": []}}) + "\n", note=True)
    for topic, msg, seconds in writes:
        handoff.write(topic, msg, seconds)
    handoff.event(json.dumps({"time": 0.5, "kind": "log", "source": "say", "data": {"message": "hi"}}) + "\n")
    handoff.close()
    os.close(write_end)
    return tmp_path, worker_session(read_end)


def worker_session(read_end: int) -> RecordingSession:
    """What the worker does with the frames arriving on ``read_end`` (closed at the end)."""
    session = None
    for kind, payload in read_frames(read_end):
        if kind is Frame.START:
            session = RecordingSession(json.loads(payload)["directory"], json.loads(payload)["clock_origin_ns"])
        elif kind is not None:
            session.take(kind, payload)
    os.close(read_end)
    return session


def test_messages_and_events_handed_over_land_in_the_files_and_the_report_data(tmp_path):
    joints = JointState(name=["a"], position=[0.25], velocity=[0.0])
    directory, session = handed_over(tmp_path, ("/joint_states", joints, 0.1), ("/latched", String(data="x"), 0.2),
                                     ("/joint_states", joints, 0.3))
    assert session.ended
    messages = read_mcap(directory / "run.mcap")
    assert [t for t, _, _ in messages["/joint_states"]] == [1_100_000_000, 1_300_000_000]
    assert messages["/latched"][0][2].data == "x"
    assert messages["/rosout"][0][2].msg == "hi" and messages["/rosout"][0][0] == 1_500_000_000
    assert [e["kind"] for e in read_events(directory / "events.jsonl")] == ["tree", "log"]
    assert "durability: transient_local" in (directory / "metadata.yaml").read_text()
    recording = session.recording  # built as the messages arrived, as load_recording reads the files
    assert list(recording.joints.times) == pytest.approx([0.1, 0.3]) == list(load_recording(directory).joints.times)
    assert recording.topics == load_recording(directory).topics


def test_a_topic_that_changes_type_is_refused_in_the_run():
    read_end, write_end = os.pipe()
    handoff = Handoff(write_end, "/nowhere", 0)
    handoff.write("/x", String(data="a"), 0.0)
    with pytest.raises(TypeError, match="recording topic '/x' carries std_msgs/msg/String, got sensor_msgs/msg/JointState"):
        handoff.write("/x", JointState(), 0.1)
    os.close(read_end)
    os.close(write_end)


def test_a_worker_that_stops_reading_is_lost_within_the_stall_timeout():
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)
    started = time.monotonic()
    with pytest.raises(WorkerLost, match="read nothing for 0 s"):
        write_all(write_end, bytes(4 << 20), stall_timeout_s=0.2)  # more than any pipe holds
    assert time.monotonic() - started >= 0.2  # it waited the stall timeout out
    os.close(read_end)
    with pytest.raises(WorkerLost, match="stopped reading \\(it exited\\)"):
        write_all(write_end, b"x")
    os.close(write_end)


def test_a_lost_worker_is_reported_once_and_nothing_more_is_sent():
    read_end, write_end = os.pipe()
    handoff = Handoff(write_end, "/nowhere", 0)
    lost = []
    handoff.on_lost = lambda err: lost.append(str(err))
    os.close(read_end)
    handoff.write("/x", String(data="a"), 0.0)
    handoff.send()
    handoff.event('{"b": 2}\n')
    handoff.close()
    assert lost == ["the recording worker stopped reading (it exited)"] and handoff.closed
    os.close(write_end)


def test_a_worker_killed_mid_run_leaves_a_partial_mcap_and_the_run_finishes_the_events(tmp_path, monkeypatch):
    processes = []
    start = ReportWorker.start

    def remembered(self):
        start(self)
        processes.append(self.process)

    monkeypatch.setattr(ReportWorker, "start", remembered)

    def kill_the_worker() -> None:
        mcap = tmp_path / "rec" / "run.mcap"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (mcap.is_file() and mcap.stat().st_size > 2000):
            time.sleep(0.01)  # until the worker has flushed its first chunk (past the file's header)
        processes[0].kill()

    killer = threading.Thread(target=kill_the_worker)
    killer.start()
    code, rec = record_run(tmp_path, WAIT_XML, "--realtime")
    killer.join()
    assert code == 0
    events = read_events(rec / "events.jsonl")
    assert events[0]["kind"] == "tree" and events[-1]["kind"] == "run_summary"
    assert events[-1]["data"]["status"] == "SUCCESS"
    (warning,) = [e for e in events if e["kind"] == "warning"]
    assert warning["data"]["message"] == ("recording: the recording worker stopped reading (it exited): "
                                          "run.mcap ends at the last chunk it wrote (partial); events.jsonl is whole")
    hold = [e["data"]["status"] for e in events if e["kind"] == "node_status" and e["source"] == "hold"]
    assert hold == ["RUNNING", "SUCCESS"] and warning["time"] < events[-1]["time"]
    recording = load_recording(rec)  # the report was rendered here, from the files
    assert recording.partial and recording.partial[0].startswith("run.mcap ends early at ")
    assert 0.0 < recording.joints.times[-1] < warning["time"]
    assert "Partial recording" in (rec / "report.html").read_text() and (rec / "joints.svg").stat().st_size > 0
    assert not (rec / "metadata.yaml").exists()  # as for a killed recorder: `ros2 bag reindex` rebuilds it


def test_a_worker_that_dies_before_writing_run_mcap_leaves_it_to_the_run_with_tf(tmp_path, monkeypatch):
    """The worker computed /tf: the run's own writer computes it again, /tf_static and the
    robot's markers included, from the moment it took over."""
    import re
    import subprocess
    import sys

    def short_lived(self):
        self.process = subprocess.Popen([sys.executable, "-c", "pass"], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self.process.wait()  # gone before it read anything

    monkeypatch.setattr(ReportWorker, "start", short_lived)
    code, rec = record_run(tmp_path, WAIT_XML)
    assert code == 0
    (warning,) = [e for e in read_events(rec / "events.jsonl") if e["kind"] == "warning"]
    assert re.search(r"run\.mcap holds what was recorded from 0\.\d\d s on \(partial\)", warning["data"]["message"])
    messages = read_mcap(rec / "run.mcap")
    assert len(messages["/tf"]) == len(messages["/joint_states"]) > 100
    assert len(messages["/tf_static"]) == len(messages["/robot_markers"]) == 1
    assert [t for t, _, _ in messages["/tf"]] == [t for t, _, _ in messages["/joint_states"]]


def test_tf_from_the_worker_then_from_the_run_share_one_channel(tmp_path):
    """A new robot the ``TfModel`` cannot describe: the run says so (a null model) and sends
    ``/tf`` itself; the file still has one ``/tf`` channel, one message per joint state."""
    from sim.robot_model import planning_robot_model

    from recording.mcap_writer import SerializedMessage
    from recording.scene_view import LinkTree, TfEncoder, stamp_of, tf_model
    from tf2_msgs.msg import TFMessage

    robot = planning_robot_model()
    tree = LinkTree.of(robot)
    joints = JointState(name=list(robot.movable_joints), position=[0.1] * len(robot.movable_joints))
    read_end, write_end = os.pipe()
    handoff = Handoff(write_end, str(tmp_path), clock_origin_ns=1_000_000_000)
    (tmp_path / "events.jsonl").write_bytes(b"")
    handoff.tf_model(tf_model(robot, tree))
    handoff.write("/joint_states", joints, 0.1)  # the worker's /tf
    handoff.tf_model(None)
    tf = TfEncoder(tree, tree.moving).encode(robot.configuration(dict(zip(joints.name, joints.position))), stamp_of(0))
    handoff.write("/tf", SerializedMessage(TFMessage, tf.data), 0.2)  # the run's
    handoff.write("/joint_states", joints, 0.2)
    handoff.close()
    os.close(write_end)
    worker_session(read_end)
    with open(tmp_path / "run.mcap", "rb") as stream:
        channels = [c.topic for c in make_reader(stream).get_summary().channels.values()]
    assert channels.count("/tf") == 1 and channels.count("/tf_static") == 1
    assert [t for t, _, _ in read_mcap(tmp_path / "run.mcap")["/tf"]] == [1_100_000_000, 1_200_000_000]


def test_the_joint_map_gives_the_configuration_the_model_gives():
    from sim.robot_model import planning_robot_model
    import numpy as np

    from recording.scene_view import JointMap

    robot = planning_robot_model()
    followers = {c.joint for c in robot.couplings}
    drivers = tuple(reversed([j for j in robot.movable_joints if j not in followers]))
    for names in (drivers, tuple(robot.movable_joints)):
        positions = np.linspace(-0.5, 0.7, len(names))
        joint_map = JointMap.of(robot, names)
        assert joint_map is not None
        assert joint_map.configuration(positions) == pytest.approx(robot.configuration(dict(zip(names, positions))))
    assert len(JointMap.of(robot, drivers).q_index) > len(drivers)  # the coupled gripper joints follow theirs
    assert JointMap.of(robot, ("no_such_joint",)) is None


@pytest.mark.parametrize("frame_id, names, velocity, effort", [
    ("", ["shoulder_pan_joint", "elbow_joint", "robotiq_85_left_knuckle_joint"], [0.5, -0.25, 0.0], []),
    ("base", ["a", "bb", "ccc", "dddd", "eeeee"], [], [1.0, 2.0, 3.0, 4.0, 5.0]),
    ("x", [], [], []),
])
def test_joint_states_encoded_by_hand_decode_as_what_was_sent(frame_id, names, velocity, effort):
    """By rclpy (what the report reads them with) and by mcap-ros2-support (as Foxglove would)."""
    from builtin_interfaces.msg import Time
    from mcap_ros2._dynamic import generate_dynamic
    from rclpy.serialization import deserialize_message

    from recording.cdr import JointStateEncoder
    from recording.schema import message_definition

    decode = generate_dynamic("sensor_msgs/msg/JointState", message_definition(JointState))["sensor_msgs/msg/JointState"]
    encoder = JointStateEncoder()
    for k in range(2):  # the second time from the names encoded once
        msg = JointState(name=names, position=[0.1 * (i + k) for i in range(len(names))], velocity=velocity, effort=effort)
        msg.header.frame_id = frame_id
        msg.header.stamp = Time(sec=1_700_000_000 + k, nanosec=123_456_789)
        data = encoder.encode(msg)
        assert deserialize_message(data, JointState) == msg
        decoded = decode(data)
        assert (decoded.header.stamp.sec, decoded.header.stamp.nanosec, decoded.header.frame_id) == (
            1_700_000_000 + k, 123_456_789, frame_id)
        assert (decoded.name, list(decoded.position), list(decoded.velocity), list(decoded.effort)) == (
            names, list(msg.position), velocity, effort)

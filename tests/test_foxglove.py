"""Recordings a ROS user opens in Foxglove and sees the robot: the MCAP ros2 profile (channel
metadata, schema names, constants, epoch log times, every message decodes), ``/tf`` and the
markers that draw the robot and the scene, the tree's statuses and the run's events as topics;
and ``--live``, the same topics served to a Foxglove WebSocket client while the run goes on."""
from __future__ import annotations

import json
import re
import struct
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from runtime.app.cli import main
from recording.scene_view import LinkTree, TfEncoder, object_markers, stamp_of
from recording.mcap_writer import LATCHED_QOS, SENSOR_DATA_QOS, OfferedQos
from recording.report.data import clock_origin_ns
from tests.test_recording import CAMERAS, read_events, read_mcap, record_run

TYPE_NAME = re.compile(r"^[A-Za-z0-9_]+/(msg|srv|action)/[A-Za-z0-9_]+$")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, int]:
    started_ns = time.time_ns()
    code, rec = record_run(tmp_path_factory.mktemp("foxglove"))
    assert code == 0
    return rec, started_ns


@pytest.fixture(scope="module")
def messages(recorded) -> dict[str, list[tuple[int, str, Any]]]:
    return read_mcap(recorded[0] / "run.mcap")


def test_every_channel_follows_the_mcap_ros2_profile(recorded):
    rec, started_ns = recorded
    with open(rec / "run.mcap", "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        decoded = sum(1 for _ in reader.iter_decoded_messages())  # every message decodes
    assert decoded == summary.statistics.message_count > 0
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg", channel.topic
        assert TYPE_NAME.match(schema.name), schema.name
        nested = [line for line in schema.data.decode().splitlines() if line.startswith("MSG: ")]
        assert all(TYPE_NAME.match(line[5:]) for line in nested), (schema.name, nested)
        (profile,) = yaml.safe_load(channel.metadata["offered_qos_profiles"])
        assert profile["history"] == "keep_last" and profile["liveliness"] == "automatic", channel.topic
        assert profile["reliability"] == ("best_effort" if channel.topic in CAMERAS else "reliable"), channel.topic
        assert profile["deadline"] == {"sec": 9223372036, "nsec": 854775807}
    latched = {c.topic for c in summary.channels.values()
               if yaml.safe_load(c.metadata["offered_qos_profiles"])[0]["durability"] == "transient_local"}
    assert latched == {"/tf_static", "/robot_markers", "/planning_scene_markers"}
    # Log times are wall-clock: the run's start plus the runtime clock.
    origin = clock_origin_ns(rec / "run.mcap")
    assert started_ns - 10**9 < origin < time.time_ns()
    assert summary.statistics.message_start_time >= origin
    events = read_events(rec / "events.jsonl")
    sim_seconds = events[-1]["data"]["sim_seconds"]
    assert summary.statistics.message_end_time - origin == pytest.approx(sim_seconds * 1e9, abs=0.05e9)


def test_the_directory_is_a_rosbag2_bag(recorded):
    """metadata.yaml as ``ros2 bag record`` (Jazzy) writes it, agreeing with run.mcap."""
    rec = recorded[0]
    info = yaml.safe_load((rec / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    with open(rec / "run.mcap", "rb") as stream:
        summary = make_reader(stream).get_summary()
    stats = summary.statistics
    assert (info["version"], info["storage_identifier"], info["ros_distro"]) == (9, "mcap", "jazzy")
    assert info["relative_file_paths"] == ["run.mcap"] and info["message_count"] == stats.message_count
    assert info["starting_time"]["nanoseconds_since_epoch"] == stats.message_start_time
    assert info["duration"]["nanoseconds"] == stats.message_end_time - stats.message_start_time
    per_topic = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    channel_counts = {summary.channels[cid].topic: n for cid, n in stats.channel_message_counts.items()}
    assert {name: t["message_count"] for name, t in per_topic.items()} == channel_counts
    joint_states = per_topic["/joint_states"]["topic_metadata"]
    assert joint_states["type"] == "sensor_msgs/msg/JointState" and joint_states["serialization_format"] == "cdr"
    assert joint_states["offered_qos_profiles"][0]["reliability"] == "reliable"
    for qos in (OfferedQos(), SENSOR_DATA_QOS, LATCHED_QOS):  # the channel text and the bag's data agree
        assert yaml.safe_load(qos.yaml()) == [qos.profile()]


def test_schemas_carry_constants_from_the_installed_definitions(recorded):
    with open(recorded[0] / "run.mcap", "rb") as stream:
        schemas = {s.name: s.data.decode() for s in make_reader(stream).get_summary().schemas.values()}
    result = schemas["moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance_Result"]
    assert "int32 FORCE_TORQUE_THRESHOLD_EXCEEDED=-6" in result
    assert "uint8 WARN=30" in schemas["rcl_interfaces/msg/Log"]
    assert "\nMSG: geometry_msgs/msg/TransformStamped\n" in schemas["tf2_msgs/msg/TFMessage"]


def test_tf_follows_the_joint_states_and_matches_forward_kinematics(messages):
    from sim.planning import planning_robot_model

    robot = planning_robot_model()
    joint_states, tf = messages["/joint_states"], messages["/tf"]
    assert len(tf) == len(joint_states) and tf[0][1] == "tf2_msgs/msg/TFMessage"
    log_time, _, state = joint_states[-1]
    last = tf[-1][2]
    ((_, _, static),) = messages["/tf_static"]
    fixed = {t.child_frame_id for t in static.transforms}
    assert {"base", "gripper_base", "gripper_left_pad"} <= fixed and "shoulder_link" not in fixed
    frames = {t.child_frame_id: t for t in [*last.transforms, *static.transforms]}
    assert set(frames) == set(robot.link_names) - {"universe"} and len(frames) == len(last.transforms) + len(fixed)
    # Chain world -> ... -> wrist_3_link from the recorded transforms.
    pose, link = pin.SE3.Identity(), "wrist_3_link"
    while link != "world":
        t = frames[link].transform
        q = t.rotation
        pose = pin.SE3(pin.Quaternion(q.w, q.x, q.y, q.z).matrix(),
                       np.array([t.translation.x, t.translation.y, t.translation.z])) * pose
        link = frames[link].header.frame_id
    q = robot.configuration(dict(zip(state.name, state.position)))
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    expected = data.oMf[robot.frame_id("wrist_3_link")]
    np.testing.assert_allclose(pose.homogeneous, expected.homogeneous, atol=1e-9)
    stamp = last.transforms[0].header.stamp
    assert stamp.sec * 10**9 + stamp.nanosec == tf[-1][0]  # stamped like its log time, not in 1970


def test_markers_draw_the_robot_in_its_link_frames_and_the_scene_in_world(messages):
    (robot_row,) = messages["/robot_markers"]
    markers = robot_row[2].markers
    frames = {m.header.frame_id for m in markers}
    assert {"shoulder_link", "wrist_3_link", "gripper_base", "gripper_left_pad"} <= frames
    assert all(m.frame_locked and m.action == 0 for m in markers)
    hulls = [m for m in markers if m.type == 11]  # TRIANGLE_LIST
    assert hulls and all(len(m.points) % 3 == 0 and len(m.points) > 0 for m in hulls)
    scene = messages["/planning_scene_markers"][0][2].markers
    by_name = {m.ns: m for m in scene}
    assert {"table", "cube_red", "cube_green", "cube_blue"} <= set(by_name)
    assert by_name["table"].header.frame_id == "world" and by_name["cube_blue"].type == 1  # CUBE
    assert by_name["cube_blue"].scale.x == pytest.approx(0.03) and by_name["cube_blue"].color.b > 0.5


def test_tree_statuses_and_events_are_topics(recorded, messages):
    events = read_events(recorded[0] / "events.jsonl")
    statuses = [json.loads(row[2].data) for row in messages["/behavior_tree/node_status"]]
    status_events = [e for e in events if e["kind"] == "node_status"]
    assert [(s["name"], s["status"]) for s in statuses] == [(e["source"], e["data"]["status"]) for e in status_events]
    rosout = [row[2] for row in messages["/rosout"]]
    requested = [m for m in rosout if m.function == "chunk_requested"]
    assert requested and requested[0].name == "ExecutePolicy" and requested[0].level == 20
    assert requested[0].msg.startswith("chunk_requested: request_step=")
    assert len(requested) == sum(1 for e in events if e["kind"] == "chunk_requested")


def test_object_markers_delete_what_left_the_scene():
    from runtime.motion.scene.collision import Box
    from runtime.motion.scene.scene import WorldObject

    box = WorldObject("crate", Box((0.1, 0.2, 0.3)), tuple(np.eye(4).reshape(-1)))
    first = object_markers({"crate": box}, (), stamp_of(5))
    assert [(m.ns, m.action, m.scale.z) for m in first.markers] == [("crate", 0, pytest.approx(0.3))]
    second = object_markers({}, (), stamp_of(6), {"crate": 1})
    assert [(m.ns, m.id, m.action) for m in second.markers] == [("crate", 0, 2)]  # DELETE


# -- live view ---------------------------------------------------------------------------------
LIVE_XML = """<root BTCPP_format="4">
  <BehaviorTree ID="Live">
    <Sequence>
      <SwitchController activate_controllers="joint_trajectory_admittance_controller"
                        deactivate_controllers="velocity_force_controller"/>
      <Wait seconds="4"/>
    </Sequence>
  </BehaviorTree>
</root>
"""


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_live_view_serves_the_recording_topics_to_a_foxglove_client(tmp_path, capsys):
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    objective = tmp_path / "live.xml"
    objective.write_text(LIVE_XML)
    port = _free_port()
    codes: list[int] = []
    run = threading.Thread(target=lambda: codes.append(main(
        ["run", str(objective), "--world", "kinematic", "--realtime", "--live", str(port)])))
    run.start()
    received: dict[str, int] = {}
    try:
        deadline = time.monotonic() + 30
        ws = None
        while ws is None and time.monotonic() < deadline:
            try:
                ws = connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], open_timeout=2,
                             max_size=None)
            except OSError:
                time.sleep(0.1)
        assert ws is not None, "the live view never accepted a connection"
        with ws:
            subscribed: dict[int, str] = {}  # subscription id -> topic
            advertised: list[tuple[float, int, str]] = []  # (when, channel id, topic), not subscribed yet
            while time.monotonic() < deadline and not {"/joint_states", "/tf", "/robot_markers"} <= set(received):
                # Subscribe a moment after the advertisement, as a person would: the SDK's server
                # can refuse a subscription that arrives within microseconds of its advertise.
                due = [a for a in advertised if time.monotonic() - a[0] > 0.2]
                if due:
                    advertised = [a for a in advertised if a not in due]
                    subs = []
                    for _, channel_id, topic in due:
                        subscribed[len(subscribed) + 1] = topic
                        subs.append({"id": len(subscribed), "channelId": channel_id})
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                try:
                    frame = ws.recv(timeout=0.1)
                except TimeoutError:
                    continue
                except ConnectionClosed:  # the run ended
                    break
                if isinstance(frame, str):
                    op = json.loads(frame)
                    if op["op"] == "advertise":
                        for ch in op["channels"]:
                            assert ch["encoding"] == "cdr" and ch["schemaEncoding"] == "ros2msg", ch
                            advertised.append((time.monotonic(), ch["id"], ch["topic"]))
                elif frame[0] == 1:  # message data: opcode, subscription id, log time, payload
                    sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
                    topic = subscribed[sub_id]
                    received[topic] = received.get(topic, 0) + 1
                    assert log_time > 1_700_000_000 * 10**9  # wall-clock based, like the recording
    finally:
        run.join(timeout=20)
    assert not run.is_alive() and codes == [0]
    assert {"/joint_states", "/tf", "/robot_markers"} <= set(received), (received, subscribed)
    assert "live view: in Foxglove, open a Foxglove WebSocket connection to ws://127.0.0.1:" in capsys.readouterr().err


def test_live_port_in_use_is_bad_input(tmp_path, capsys):
    import socket

    objective = tmp_path / "live.xml"
    objective.write_text(LIVE_XML)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code = main(["run", str(objective), "--world", "kinematic", "--live", str(port)])
    assert code == 2
    err = capsys.readouterr().err
    assert f"--live: cannot serve on 127.0.0.1:{port}" in err and "Traceback" not in err


def test_live_needs_a_port_number(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["run", str(tmp_path / "x.xml"), "--live", "http"])
    assert exit_info.value.code == 2
    assert "expected a TCP port number (0-65535), got 'http'" in capsys.readouterr().err


def test_tf_cdr_is_what_rclpy_serializes():
    """The hand-written TFMessage encoder against two decoders (rclpy's C one and
    mcap-ros2-support's pure-Python one, from the recorded schema) and pinocchio's FK."""
    from mcap_ros2._dynamic import generate_dynamic
    from rclpy.serialization import deserialize_message
    from tf2_msgs.msg import TFMessage

    from recording.schema import message_definition

    from sim.planning import planning_robot_model

    robot = planning_robot_model()
    tree = LinkTree.of(robot)
    q = pin.randomConfiguration(robot.model, -np.ones(robot.model.nq), np.ones(robot.model.nq))
    data = TfEncoder(tree, tree.moving).encode(q, stamp_of(1_700_000_000_123_456_789)).data
    message = deserialize_message(data, TFMessage)
    python_decoded = generate_dynamic("tf2_msgs/msg/TFMessage", message_definition(TFMessage))["tf2_msgs/msg/TFMessage"](data)
    assert [(t.header.frame_id, t.child_frame_id, t.transform.rotation.w) for t in python_decoded.transforms] == [
        (t.header.frame_id, t.child_frame_id, t.transform.rotation.w) for t in message.transforms]
    assert [t.child_frame_id for t in message.transforms] == list(tree.moving)
    stamp = message.transforms[0].header.stamp
    assert (stamp.sec, stamp.nanosec) == (1_700_000_000, 123_456_789)
    reference = robot.model.createData()
    pin.framesForwardKinematics(robot.model, reference, q)
    for t in message.transforms:
        parent = t.header.frame_id
        expected = reference.oMf[robot.frame_id(t.child_frame_id)]
        if parent != "world":
            expected = reference.oMf[robot.frame_id(parent)].actInv(expected)
        r, p = t.transform.rotation, t.transform.translation
        got = pin.SE3(pin.Quaternion(r.w, r.x, r.y, r.z).matrix(), np.array([p.x, p.y, p.z]))
        np.testing.assert_allclose(got.homogeneous, expected.homogeneous, atol=1e-12)

"""``objective run --record DIR``: run.mcap (read back with mcap-ros2-support, as Foxglove would),
events.jsonl, and the RecordingBus proxy on its own."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import Image, JointState
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from runtime.io.bus import FixedLatency, InProcessBus
from runtime.io.clock import SimClock
from runtime.app.cli import main
from recording import McapRos2Writer, RecordingBus
from recording.schema import message_class, message_definition, type_name
from recording.report.data import clock_origin_ns
from runtime.io.timestamps import duration_msg, time_msg

CAMERAS = ("/scene_camera/color", "/wrist_camera/color", "/overview_camera/color")
CONTROLLER = "/joint_trajectory_admittance_controller"

# A short policy run (6 s of clock time) with a skipped node and a gripper, on the kinematic cell.
POLICY_XML = f"""<root BTCPP_format="4" main_tree_to_execute="Short Policy Run">
  <BehaviorTree ID="Short Policy Run">
    <Sequence>
      <SwitchController activate_controllers="joint_trajectory_admittance_controller"
                        deactivate_controllers="velocity_force_controller"/>
      <AlwaysFailure name="skipped check" _skipIf="true"/>
      <SetCollisionRule object_name="*" link_names="gripper" allow="true"/>
      <ExecutePolicy policy_service_name="/get_action_chunk" joint_group_name="manipulator"
          prompt="stack the blue cube on the green cube" total_action_steps="60" dt="0.1"
          committed_action_steps="20" goal_path_tolerance="0.3" policy_call_timeout="10.0"
          image_topics="{';'.join(CAMERAS)}" image_names="scene;wrist;overview"
          gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd"
          gripper_joint_name="robotiq_85_left_knuckle_joint"/>
    </Sequence>
  </BehaviorTree>
</root>
"""

HALTED_XML = """<root BTCPP_format="4">
  <BehaviorTree ID="Too Slow">
    <Timeout msec="300"><Wait name="long wait" seconds="5"/></Timeout>
  </BehaviorTree>
</root>
"""


def record_run(directory: Path, xml: str = POLICY_XML, *extra: str) -> tuple[int, dict[str, Any]]:
    """Run ``xml`` with ``--record directory/rec`` on the kinematic world; (exit code, JSON summary)."""
    directory.mkdir(parents=True, exist_ok=True)
    objective = directory / "objective.xml"
    objective.write_text(xml)
    code = main(["run", str(objective), "--world", "kinematic", "--policy-latency", "0.15", "--record",
                 str(directory / "rec"), "--json", *extra])
    return code, directory / "rec"


def read_mcap(path: Path) -> dict[str, list[tuple[int, str, Any]]]:
    """topic -> [(log_time ns, schema name, decoded message)], decoded by mcap-ros2-support."""
    out: dict[str, list[tuple[int, str, Any]]] = {}
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append((message.log_time, schema.name, decoded))
    return out


def read_events(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    code, rec = record_run(tmp_path_factory.mktemp("policy"))
    assert code == 0
    return rec


ORIGIN_NS: list[int] = [0]


@pytest.fixture(scope="module")
def messages(recording) -> dict[str, list[tuple[int, str, Any]]]:
    ORIGIN_NS[0] = clock_origin_ns(recording / "run.mcap")
    return read_mcap(recording / "run.mcap")


@pytest.fixture(scope="module")
def events(recording) -> list[dict[str, Any]]:
    return read_events(recording / "events.jsonl")


def of_kind(events: list[dict[str, Any]], kind: str) -> list[dict[str, Any]]:
    return [e for e in events if e["kind"] == kind]


# -- run.mcap ----------------------------------------------------------------------------------
def test_mcap_has_every_topic_with_its_ros_type(messages):
    types = {topic: rows[0][1] for topic, rows in messages.items()}
    expected = {
        "/joint_states": "sensor_msgs/msg/JointState",
        **{camera: "sensor_msgs/msg/Image" for camera in CAMERAS},
        "/get_action_chunk/request": "std_msgs/msg/String",
        "/get_action_chunk/response": "std_msgs/msg/String",
        "/get_action_chunk/chunk": "trajectory_msgs/msg/JointTrajectory",
        f"{CONTROLLER}/joint_trajectory": "trajectory_msgs/msg/JointTrajectory",
        f"{CONTROLLER}/follow_joint_trajectory/goal": "moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance_Goal",
        f"{CONTROLLER}/follow_joint_trajectory/feedback": "moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance_Feedback",
        f"{CONTROLLER}/follow_joint_trajectory/result": "moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance_Result",
        "/force_torque_sensor_broadcaster/wrench": "geometry_msgs/msg/WrenchStamped",
        "/controller_manager/switch_controller/request": "controller_manager_msgs/srv/SwitchController_Request",
        "/controller_manager/switch_controller/response": "controller_manager_msgs/srv/SwitchController_Response",
    }
    assert {t: types.get(t) for t in expected} == expected


def test_mcap_counts_match_the_policy_run(messages, events):
    requests = len(of_kind(events, "chunk_requested"))  # the warmup request included
    executed = of_kind(events, "chunk_executed")
    assert len(executed) == 3  # 60 steps, 20 committed per chunk
    assert len(messages["/get_action_chunk/request"]) == requests
    for camera in CAMERAS:  # one frame per camera per request: the frames the policy consumed
        assert len(messages[camera]) == requests
    # Every executed chunk was one trajectory goal to the controller (the only motions of this tree).
    assert len(messages[f"{CONTROLLER}/joint_trajectory"]) == len(executed)
    stamps = [row[2].header.stamp.sec + row[2].header.stamp.nanosec * 1e-9 for row in messages[f"{CONTROLLER}/joint_trajectory"]]
    assert stamps == pytest.approx([e["data"]["seam_time"] for e in executed], abs=1e-9)


def test_joint_states_are_recorded_at_50_hz_of_clock_time(messages, events):
    summary = of_kind(events, "run_summary")[0]["data"]
    rows = messages["/joint_states"]
    times = np.array([row[0] for row in rows]) * 1e-9
    assert np.diff(times).min() >= 0.02 - 1e-6
    assert len(rows) == pytest.approx(summary["sim_seconds"] * 50, abs=2)
    assert list(rows[-1][2].name)[-1] == "robotiq_85_left_knuckle_joint" and len(rows[-1][2].position) == 7


def test_policy_request_and_response_summaries(messages):
    requests = [json.loads(row[2].data) for row in messages["/get_action_chunk/request"]]
    responses = [json.loads(row[2].data) for row in messages["/get_action_chunk/response"]]
    first = requests[0]
    assert first["request"] == 1 and first["new_episode"] is True
    assert first["prompt"] == "stack the blue cube on the green cube"
    assert [i["topic"] for i in first["images"]] == list(CAMERAS)
    assert [i["name"] for i in first["images"]] == ["scene", "wrist", "overview"]
    assert first["images"][0]["width"] == 32 and first["images"][0]["encoding"] == "rgb8"
    assert len(first["joint_names"]) == 7
    answered = {r["request"]: r for r in responses}
    assert answered[2]["status_name"] == "CHUNK_PRODUCED" and answered[2]["latency"] == pytest.approx(0.15, abs=0.011)
    assert answered[2]["chunk_steps"] > 20
    # Camera frames are logged at the request instant (log times are wall-clock: origin + clock).
    camera_times = [row[0] - ORIGIN_NS[0] for row in messages[CAMERAS[0]]]
    assert camera_times == [int(round(r["time"] * 1e9)) for r in requests]


def test_wrench_and_feedback_come_from_the_controller_feedback(messages):
    feedback = messages[f"{CONTROLLER}/follow_joint_trajectory/feedback"]
    wrench = messages["/force_torque_sensor_broadcaster/wrench"]
    assert len(wrench) == len(feedback) > 10
    assert [row[0] for row in wrench] == [row[0] for row in feedback]
    stamp = lambda m: (m.header.stamp.sec, m.header.stamp.nanosec)  # noqa: E731
    assert [stamp(row[2]) for row in wrench] == [stamp(row[2]) for row in feedback]
    assert {len(row[2].actual.positions) for row in feedback} == {6}
    # The controller publishes feedback at 50 Hz; the recording keeps at most 25 per second.
    assert min(b[0] - a[0] for a, b in zip(feedback, feedback[1:])) >= 40_000_000 - 1


# -- events.jsonl ------------------------------------------------------------------------------
def test_events_start_with_the_tree_and_end_with_the_summary(events):
    assert events[0]["kind"] == "tree" and events[0]["source"] == "Short Policy Run"
    nodes = events[0]["data"]["nodes"]
    by_name = {n["name"]: n for n in nodes}
    assert by_name["ExecutePolicy"]["type"] == "ExecutePolicy"
    line = next(k for k, text in enumerate(POLICY_XML.splitlines(), 1) if "<ExecutePolicy" in text)
    assert by_name["ExecutePolicy"]["location"].endswith(f"objective.xml:{line}")
    root = [n for n in nodes if n["parent"] is None]
    assert len(root) == 1 and root[0]["kind"] == "Control"
    assert events[-1]["kind"] == "run_summary" and events[-1]["data"]["status"] == "SUCCESS"
    assert events[-1]["data"]["execute_policy"]["steps_executed"] == 60
    limits = of_kind(events, "joint_limits")[0]["data"]["joints"]
    assert {j["name"] for j in limits} >= {"shoulder_pan_joint", "robotiq_85_left_knuckle_joint"}


def test_events_carry_status_changes_and_chunk_timeline(events):
    nodes = events[0]["data"]["nodes"]
    policy = next(n["id"] for n in nodes if n["name"] == "ExecutePolicy")
    skipped = next(n["id"] for n in nodes if n["name"] == "skipped check")
    changes = [(e["data"]["node"], e["data"]["status"]) for e in of_kind(events, "node_status")]
    assert [s for n, s in changes if n == policy] == ["RUNNING", "SUCCESS"]
    assert any(s == "SKIPPED" for n, s in changes if n in (skipped, skipped + 1))
    executed = of_kind(events, "chunk_executed")
    assert [e["data"]["chunk"] for e in executed] == [1, 2, 3]
    assert all(set(e["data"]) >= {"seam_time", "request_step", "seam_step", "steps", "latency"} for e in executed)
    times = [e["time"] for e in events[1:-1]]
    assert times == sorted(times)


def test_a_halted_node_is_recorded_as_halted(tmp_path):
    code, rec = record_run(tmp_path, HALTED_XML)
    assert code == 1
    events = read_events(rec / "events.jsonl")
    wait = next(n["id"] for n in events[0]["data"]["nodes"] if n["name"] == "long wait")
    assert [(e["data"]["status"], e["data"]["message"]) for e in of_kind(events, "node_status") if e["data"]["node"] == wait] \
        == [("RUNNING", ""), ("INVALID", "halted")]
    assert (rec / "run.mcap").stat().st_size > 0


def test_recording_again_into_a_directory_replaces_the_old_report(tmp_path):
    stale = tmp_path / "rec" / "cameras.mp4"
    stale.parent.mkdir()
    stale.write_bytes(b"an older run's video")
    code, rec = record_run(tmp_path, HALTED_XML)
    assert code == 1 and not stale.exists()  # this run had no camera frames
    assert (rec / "report.html").is_file()


def test_a_second_recording_into_one_directory_is_refused(tmp_path, capsys):
    code, rec = record_run(tmp_path, HALTED_XML)
    assert code == 1
    first = (rec / "run.mcap").read_bytes()
    capsys.readouterr()
    code, _ = record_run(tmp_path, HALTED_XML)
    assert code == 2
    assert (f"error: --record {rec}: already holds a recording (run.mcap); record into a new directory, "
            "or remove that one first") in capsys.readouterr().err
    assert (rec / "run.mcap").read_bytes() == first  # the first run is kept


@pytest.mark.parametrize("planted", ["run.mcap", "events.jsonl"])
def test_a_recording_file_planted_as_a_link_is_refused_and_its_target_kept(tmp_path, capsys, planted):
    victim = tmp_path / "victim"
    victim.write_text("precious")
    (tmp_path / "rec").mkdir()
    (tmp_path / "rec" / planted).symlink_to(victim)
    code, rec = record_run(tmp_path, HALTED_XML)
    assert code == 2 and f"--record {rec}: already holds a recording ({planted})" in capsys.readouterr().err
    assert victim.read_text() == "precious"


def test_a_recording_writes_no_file_through_a_planted_link(tmp_path):
    """Every file of the directory is replaced, never written through a link left there."""
    rec = tmp_path / "rec"
    rec.mkdir()
    names = [".room-for-the-summary", "metadata.yaml", "report.html", "tree.svg", "joints.svg", "events.jsonl.new"]
    for name in names:
        (tmp_path / f"victim-{name}").write_text("precious")
        (rec / name).symlink_to(tmp_path / f"victim-{name}")
    code, _ = record_run(tmp_path, HALTED_XML)
    assert code == 1
    assert all((tmp_path / f"victim-{name}").read_text() == "precious" for name in names)
    assert (rec / "report.html").is_file() and not (rec / "report.html").is_symlink()


def test_the_bag_writer_replaces_a_link_instead_of_writing_through_it(tmp_path):
    victim = tmp_path / "victim"
    victim.write_text("precious")
    (tmp_path / "run.mcap").symlink_to(victim)
    McapRos2Writer(tmp_path / "run.mcap").close()
    assert victim.read_text() == "precious"
    assert not (tmp_path / "run.mcap").is_symlink() and (tmp_path / "run.mcap").stat().st_size > 0


def test_record_into_a_file_is_bad_input(tmp_path, capsys):
    target = tmp_path / "not-a-dir"
    target.write_text("x")
    (tmp_path / "o.xml").write_text(HALTED_XML)
    assert main(["run", str(tmp_path / "o.xml"), "--record", str(target)]) == 2
    assert f"--record {target}: exists and is not a directory" in capsys.readouterr().err


# -- the proxy and the writer on their own -----------------------------------------------------
def image(width: int = 4) -> Image:
    return Image(width=width, height=2, encoding="rgb8", step=3 * width, data=bytes(6 * width))


def test_recording_bus_names_frames_by_the_topic_they_were_read_from(tmp_path):
    clock = SimClock()
    bus = InProcessBus(clock)
    bus.set_latency("/policy", FixedLatency(0.2))
    frame = image()
    bus.create_lazy_publisher("/cam/color", Image, lambda: frame)
    chunk = JointTrajectory(joint_names=["a"], points=[JointTrajectoryPoint(positions=[0.5])])
    bus.create_service("/policy", GetActionChunk, lambda req: GetActionChunk.Response(status=1, chunk=chunk))
    writer = McapRos2Writer(tmp_path / "r.mcap")
    rec = RecordingBus(bus, writer)
    camera = rec.create_subscription("/cam/color", Image)
    client = rec.create_client("/policy", GetActionChunk)
    request = GetActionChunk.Request(image_names=["cam", "other"], images=[camera.latest, image(8)])
    request.robot_state = JointState(name=["a"], position=[0.25])
    future = client.call_async(request)
    assert rec.clock is clock and client.service_is_ready()  # everything else is forwarded
    for _ in range(3):  # ticks of 0.1 s: the answer is delivered (and recorded) at 0.2 s
        clock.advance(0.1)
        rec.spin_once()
    assert future.done() and future.result().status == 1
    cancelled = client.call_async(request)
    cancelled.cancel()
    clock.advance(0.3)
    rec.spin_once()
    writer.close()
    messages = read_mcap(tmp_path / "r.mcap")
    assert len(messages["/cam/color"]) == 2 and messages["/cam/color"][0][2].width == 4
    assert len(messages["/policy/images/other"]) == 2  # not read from any subscription
    responses = [json.loads(row[2].data) for row in messages["/policy/response"]]
    assert len(responses) == 1  # the cancelled call was never answered to anyone
    assert responses[0]["latency"] == pytest.approx(0.2) and responses[0]["status_name"] == "CHUNK_PRODUCED"
    assert messages["/policy/chunk"][0][0] == int(round(0.2 * 1e9))
    assert list(messages["/policy/chunk"][0][2].points[0].positions) == [0.5]


def test_other_services_are_recorded_with_their_own_types(tmp_path):
    bus = InProcessBus(SimClock(), FixedLatency(0.0))
    bus.create_service("/trigger", Trigger, lambda req: Trigger.Response(success=True, message="done"))
    writer = McapRos2Writer(tmp_path / "t.mcap")
    RecordingBus(bus, writer).create_client("/trigger", Trigger).call_async(Trigger.Request())
    writer.close()
    messages = read_mcap(tmp_path / "t.mcap")
    assert messages["/trigger/request"][0][1] == "std_srvs/srv/Trigger_Request"
    assert messages["/trigger/response"][0][2].message == "done"


def test_writer_round_trips_nested_messages_through_mcap_ros2(tmp_path):
    trajectory = JointTrajectory(joint_names=["j1", "j2"])
    trajectory.header.stamp = time_msg(12.5)
    trajectory.points = [JointTrajectoryPoint(positions=[0.1 * k, -0.2], velocities=[1.0, 2.0], time_from_start=duration_msg(0.05 * k))
                         for k in range(3)]
    writer = McapRos2Writer(tmp_path / "n.mcap")
    writer.write("/traj", trajectory, 12.5)
    with pytest.raises(TypeError, match="recording topic '/traj' carries trajectory_msgs/msg/JointTrajectory, got sensor_msgs/msg/JointState"):
        writer.write("/traj", JointState(), 13.0)
    writer.close()
    ((log_time, name, msg),) = read_mcap(tmp_path / "n.mcap")["/traj"]
    assert (log_time, name) == (12_500_000_000, "trajectory_msgs/msg/JointTrajectory")
    assert msg.header.stamp.sec == 12 and msg.header.stamp.nanosec == 500_000_000
    assert [list(p.positions) for p in msg.points] == [[0.0, -0.2], [0.1, -0.2], [0.2, -0.2]]
    assert msg.points[2].time_from_start.nanosec == 100_000_000


def test_message_definitions_follow_the_ros2msg_concatenation():
    """As rosbag2 writes them: the installed .msg text (comments and constants kept), then each
    nested type after a separator and ``MSG: pkg/msg/Type``."""
    text = message_definition(JointState)
    root = text.split("\n" + "=" * 80 + "\n")[0]
    assert root.startswith("# This is a message that holds data")
    assert [line for line in root.splitlines() if line and not line.startswith("#")] == [
        "std_msgs/Header header", "string[] name", "float64[] position", "float64[] velocity", "float64[] effort"]
    assert "\n" + "=" * 80 + "\nMSG: std_msgs/msg/Header\n" in text
    assert "\nMSG: builtin_interfaces/msg/Time\n" in text and "\nint32 sec\n" in text
    result = message_definition(message_class(
        "moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance_Result"))
    assert result.startswith("int32 SUCCESSFUL=0\n") and "int32 SUPERSEDED=-8\n" in result
    assert type_name(GetActionChunk.Request) == "moveit_pro_ml_msgs/srv/GetActionChunk_Request"
    assert message_class("moveit_pro_ml_msgs/srv/GetActionChunk_Request") is GetActionChunk.Request
    assert message_class("sensor_msgs/JointState") is JointState
    with pytest.raises(ValueError, match="no type 'Nope' in sensor_msgs.msg"):
        message_class("sensor_msgs/msg/Nope")

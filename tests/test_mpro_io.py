"""MoveIt Pro's message, service, time, file, camera and visualization behaviors, and the
tools/count_loadable.py count."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Empty
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from behaviors.frames import compose
from behaviors.messages import CallTriggerService, WaitForDuration
from behaviors.robot_state import ClearSnapshot, UpdatePlanningSceneService
from behaviors.vectors import pose_stamped
from behaviors.visualization import MARKER_TOPIC, PublishTF, VisualizePath, VisualizePose
from behaviors.yaml_files import LoadPoseStampedVectorFromYaml, SavePoseStampedToYaml, pose_from_dict, pose_to_dict, YamlFileError
from runtime.tree.behavior import Status
from runtime.tree.blackboard import Blackboard
from runtime.errors import SetupError, SourceLocation
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, run_file
from sim.sensor_topics import pinhole_camera_info
from tests.test_scene_behaviors import make_context, make_node, tick

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


def run_xml(registry: Registry, tmp_path: Path, body: str, world: str | None = None, max_seconds: float = 10.0):
    path = tmp_path / "tree.xml"
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">{body}</BehaviorTree></root>')
    return run_file(path, registry, RunOptions(world=world, max_seconds=max_seconds))


def advance(context, seconds: float) -> None:
    context.clock.advance(seconds)
    context.bus.spin_once()


# -- messages ---------------------------------------------------------------------------------------
def test_twist_and_wrench_round_trip_through_create_and_unpack(registry, tmp_path):
    result = run_xml(registry, tmp_path, """<Sequence>
      <CreateTwistStamped reference_frame="tcp" linear_velocity_xyz="0;0;0.05" angular_velocity_xyz="0.1;0;0" twist_stamped="{ts}"/>
      <UnpackTwistStampedMessage twist_stamped="{ts}" header="{th}" twist="{t}"/>
      <CreateWrenchStamped force_xyz="0;0;-5" torque_xyz="0;0.5;0" wrench_stamped="{ws}"/>
      <UnpackWrenchStampedMessage wrench_stamped="{ws}" header="{wh}" wrench="{w}"/>
      <CreateWrenchStamped name="short" force_xyz="0;-5" wrench_stamped="{bad}"/>
    </Sequence>""")
    assert (result.status, result.failing_node, result.reason) == ("FAILURE", "short", "force_xyz needs 3 values (x;y;z), got 2")


def test_publish_empty_reaches_a_subscriber_on_its_qos():
    context = make_context(None)
    reliable = context.bus.create_subscription("/done", Empty, reliable=True)
    from behaviors.messages import PublishEmpty

    assert tick(make_node(PublishEmpty, context, topic="/done")) is Status.SUCCESS
    assert reliable.count == 1
    tick(make_node(PublishEmpty, context, topic="/done", use_best_effort="true"))
    assert reliable.count == 1  # a reliable subscription does not hear a best-effort publisher


def test_wait_for_duration_runs_on_the_run_clock():
    context = make_context(None)
    node = make_node(WaitForDuration, context, delay_duration="0.05")
    assert tick(node) is Status.RUNNING
    for _ in range(4):
        advance(context, 0.01)
        assert tick(node) is Status.RUNNING
    advance(context, 0.01)
    assert tick(node) is Status.SUCCESS


def trigger_node(context, **ports: str):
    return make_node(CallTriggerService, context, service_name="/zero", **ports)


def test_call_trigger_service_succeeds_or_fails_with_the_servers_answer():
    context = make_context(None)
    answers = iter([(True, "zeroed"), (False, "sensor busy")])

    def handle(request: Trigger.Request) -> Trigger.Response:
        ok, message = next(answers)
        return Trigger.Response(success=ok, message=message)

    context.bus.create_service("/zero", Trigger, handle)
    for expected, message in ((Status.SUCCESS, "zeroed"), (Status.FAILURE, "service '/zero' answered failure: sensor busy")):
        node = trigger_node(context)
        status = tick(node)
        while status is Status.RUNNING:
            advance(context, 0.01)
            status = tick(node)
        assert (status, node.feedback_message) == (expected, message)


def test_call_trigger_service_gives_up_when_no_server_appears():
    context = make_context(None)
    node = trigger_node(context, wait_for_server_available_timeout="0.1")
    with pytest.raises(SetupError, match=r"^service '/zero' is not available after 0.1 s$"):  # the run ends as ERROR
        while tick(node) is Status.RUNNING:
            advance(context, 0.01)
    assert context.clock.now() == pytest.approx(0.1)


# -- frames -----------------------------------------------------------------------------------------
def test_transform_pose_with_pose_composes_in_the_transforms_frame():
    transform = pose_stamped("world", [1.0, 0.0, 0.0], [0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)], 0.0)
    point = pose_stamped("ignored", [0.5, 0.0, 0.0], [0, 0, 0, 1], 0.0)
    result = compose(transform, point, 2.0)
    p = result.pose.position
    assert result.header.frame_id == "world"
    assert (p.x, p.y, p.z) == pytest.approx((1.0, 0.5, 0.0))  # turned 90 degrees about z, then moved


# -- YAML files -------------------------------------------------------------------------------------
def test_pose_yaml_round_trip_and_errors_name_the_field():
    pose = pose_stamped("world", [0.1, 0.2, 0.3], [0, 0, 0, 1], 3.25)
    back = pose_from_dict(pose_to_dict(pose), "x")
    assert back == pose
    with pytest.raises(YamlFileError, match=r"poses.yaml document 2.pose.orientation lacks 'w'"):
        pose_from_dict({"pose": {"position": {"x": 0, "y": 0, "z": 0}, "orientation": {"x": 0, "y": 0, "z": 0}}}, "poses.yaml document 2")
    with pytest.raises(YamlFileError, match=r"x.pose.position.y is not a number: 'a'"):
        pose_from_dict({"pose": {"position": {"x": 0, "y": "a", "z": 0}, "orientation": {}}}, "x")


def file_node(cls, tmp_path: Path, blackboard: Blackboard | None = None, **ports: str):
    node = make_node(cls, make_context(None), blackboard or Blackboard(), **ports)
    node.location = SourceLocation(str(tmp_path / "objective.xml"), 3)  # files resolve next to the Objective
    return node


def test_save_then_load_poses_next_to_the_objective(tmp_path):
    blackboard = Blackboard()
    blackboard.set("pose", pose_stamped("world", [0.1, 0.2, 0.3], [0, 0, 0, 1], 0.0))
    save = file_node(SavePoseStampedToYaml, tmp_path, blackboard, message="{pose}", yaml_filename="grasp", namespace="first")
    assert tick(save) is Status.SUCCESS
    blackboard.set("pose", pose_stamped("world", [0.4, 0.5, 0.6], [0, 0, 0, 1], 0.0))
    keep = file_node(SavePoseStampedToYaml, tmp_path, blackboard, message="{pose}", yaml_filename="grasp", namespace="second", overwrite="false")
    assert tick(keep) is Status.SUCCESS
    saved = yaml.safe_load((tmp_path / "grasp.yaml").read_text())
    assert list(saved) == ["first", "second"]
    assert saved["second"]["pose"]["position"] == {"x": 0.4, "y": 0.5, "z": 0.6}
    assert not list(tmp_path.glob("*.partial"))  # written whole, nothing left behind

    (tmp_path / "path.yaml").write_text("---\n" + yaml.safe_dump(saved["first"]) + "---\n" + yaml.safe_dump(saved["second"]))
    load = file_node(LoadPoseStampedVectorFromYaml, tmp_path, blackboard, file_path="path.yaml", output="{poses}")
    assert tick(load) is Status.SUCCESS
    poses = blackboard.get("poses")
    assert [p.pose.position.x for p in poses] == [0.1, 0.4]
    assert all(isinstance(p, PoseStamped) for p in poses)


def test_load_poses_fails_on_a_missing_or_broken_file(tmp_path):
    missing = file_node(LoadPoseStampedVectorFromYaml, tmp_path, file_path="nope.yaml", output="{p}")
    assert tick(missing) is Status.FAILURE
    assert missing.feedback_message == f"no file {tmp_path / 'nope.yaml'}"
    (tmp_path / "bad.yaml").write_text("pose: [unclosed")
    broken = file_node(LoadPoseStampedVectorFromYaml, tmp_path, file_path="bad.yaml", output="{p}")
    assert tick(broken) is Status.FAILURE
    assert broken.feedback_message.startswith(f"{tmp_path / 'bad.yaml'} is not valid YAML:")


def test_files_outside_the_objectives_and_working_directories_are_refused(tmp_path):
    outside = "/etc/objective_runtime_test.yaml"
    node = file_node(SavePoseStampedToYaml, tmp_path / "sub", message="{pose}", yaml_filename=outside)
    node.blackboard.set("pose", PoseStamped())
    assert tick(node) is Status.FAILURE
    assert node.feedback_message.startswith(f"{outside} is outside the Objective's directory ({tmp_path / 'sub'})")
    assert not Path(outside).exists()


def test_a_bad_stamp_is_named():
    with pytest.raises(YamlFileError, match=r"p.header.stamp is not a valid time"):
        pose_from_dict({"header": {"stamp": {"sec": "soon"}}, "pose": {}}, "p")


def test_moveit_pro_pose_files_load(tmp_path):
    # The layout MoveIt Pro's example workspace stores (header.stamp sec/nanosec, frame_id, pose).
    (tmp_path / "place.yaml").write_text("""---
header:
  stamp:
    sec: 1700000000
    nanosec: 5
  frame_id: world
pose:
  position: {x: 0.5, y: 0.25, z: 0.6}
  orientation: {x: 0.0, y: 1.0, z: 0.0, w: 0.0}
""")
    blackboard = Blackboard()
    load = file_node(LoadPoseStampedVectorFromYaml, tmp_path, blackboard, file_path="place.yaml", output="{poses}")
    assert tick(load) is Status.SUCCESS
    (pose,) = blackboard.get("poses")
    assert (pose.header.stamp.sec, pose.header.frame_id, pose.pose.orientation.y) == (1700000000, "world", 1.0)


# -- scene stand-ins --------------------------------------------------------------------------------
def test_clear_snapshot_says_there_is_nothing_to_clear_and_point_clouds_fail():
    context = make_context(None)
    clear = make_node(ClearSnapshot, context)
    assert tick(clear) is Status.SUCCESS
    assert clear.feedback_message == "no point-cloud snapshot in this planning scene: nothing to clear"
    blackboard = Blackboard()
    blackboard.set("cloud", object())
    update = make_node(UpdatePlanningSceneService, context, blackboard, point_cloud="{cloud}")
    assert tick(update) is Status.FAILURE
    assert update.feedback_message == "the planning scene here has no point-cloud (octomap) layer: point clouds cannot be added"


# -- cameras ----------------------------------------------------------------------------------------
def test_pinhole_camera_info_matches_the_field_of_view():
    info = pinhole_camera_info("wrist_camera", 224, 224, 70.0)
    focal = info.k[0]
    assert 2 * math.degrees(math.atan((224 / 2) / focal)) == pytest.approx(70.0)
    assert (info.k[2], info.k[5], info.width, info.height) == (111.5, 111.5, 224, 224)


def test_get_image_and_camera_info_from_the_cell(registry, tmp_path):
    result = run_xml(registry, tmp_path, """<Sequence>
      <GetImage topic_name="/scene_camera/color" message_out="{image}"/>
      <GetCameraInfo topic_name="/scene_camera/camera_info" message_out="{info}"/>
      <GetImage name="no camera" topic_name="/side_camera/color" message_out="{other}" publisher_timeout_sec="0.2"/>
    </Sequence>""", world="kinematic")
    assert (result.status, result.failing_node) == ("FAILURE", "no camera")
    assert result.reason == "no publisher on '/side_camera/color' after 0.2 s"
    assert result.sim_seconds == pytest.approx(0.2, abs=0.02)


def test_the_cell_publishes_camera_info_for_each_camera():
    from runtime.io.bus import InProcessBus
    from runtime.io.clock import SimClock
    from sim.sensor_topics import CAMERA_INFO_TOPICS
    from sim.kinematic import create_kinematic

    from runtime.tree.behavior import RunContext
    from runtime.tree.events import EventLog

    clock = SimClock()
    context = RunContext(clock=clock, bus=InProcessBus(clock), events=EventLog(clock))
    world = create_kinematic({"policy": "none"})
    world.start(context)
    try:
        for name, topic in CAMERA_INFO_TOPICS.items():
            info = context.bus.create_subscription(topic, CameraInfo, reliable=False).latest
            assert (info.header.frame_id, info.width, info.height) == (f"{name}_camera", 32, 32)
    finally:
        world.close()


# -- visualization ----------------------------------------------------------------------------------
def test_visualize_pose_publishes_three_axes_and_a_label():
    context = make_context(None)
    markers = context.bus.create_subscription(MARKER_TOPIC, MarkerArray)
    blackboard = Blackboard()
    blackboard.set("pose", pose_stamped("world", [0.1, 0.2, 0.3], [0, 0, 0, 1], 0.0))
    node = make_node(VisualizePose, context, blackboard, pose="{pose}", marker_name="grasp", marker_size="0.1", marker_text="Grasp")
    assert tick(node) is Status.SUCCESS
    arrows = markers.latest.markers
    assert [m.type for m in arrows] == [Marker.ARROW] * 3 + [Marker.TEXT_VIEW_FACING]
    assert {m.ns for m in arrows} == {"grasp"} and arrows[3].text == "Grasp"
    tip = arrows[2].points[1]  # z axis, 10 cm long
    assert (tip.x, tip.y, tip.z) == pytest.approx((0.1, 0.2, 0.4))


def test_visualize_path_refuses_mixed_frames():
    context = make_context(None)
    blackboard = Blackboard()
    blackboard.set("path", [pose_stamped("world", [0, 0, 0], [0, 0, 0, 1], 0.0), pose_stamped("tcp", [0, 0, 0], [0, 0, 0, 1], 0.0)])
    node = make_node(VisualizePath, context, blackboard, path="{path}")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "the path's poses are in different frames (tcp, world): transform them to one first"


def test_publish_tf_publishes_at_its_rate_until_halted():
    context = make_context(None)
    received: list[TFMessage] = []
    context.bus.create_subscription("/tf", TFMessage, received.append)
    blackboard = Blackboard()
    blackboard.set("pose", pose_stamped("world", [0.1, 0.0, 0.0], [0, 0, 0, 1], 0.0))
    node = make_node(PublishTF, context, blackboard, pose="{pose}", child_frame_id="target", publish_rate="20")
    for _ in range(100):  # 1 s of 10 ms ticks
        assert tick(node) is Status.RUNNING
        advance(context, 0.01)
    assert len(received) == 20
    transform = received[0].transforms[0]
    assert (transform.header.frame_id, transform.child_frame_id, transform.transform.translation.x) == ("world", "target", 0.1)


# -- the count over a directory ---------------------------------------------------------------------
def test_count_loadable_counts_and_names_what_blocks(tmp_path):
    objectives = tmp_path / "cfg" / "objectives"
    objectives.mkdir(parents=True)
    (objectives / "ok.xml").write_text('<root BTCPP_format="4"><BehaviorTree ID="A"><ResetVector vector="{v}"/></BehaviorTree></root>')
    (objectives / "mtc.xml").write_text('<root BTCPP_format="4"><BehaviorTree ID="B"><SetupMTCPathIK/></BehaviorTree></root>')
    out = subprocess.run([sys.executable, str(ROOT / "tools" / "count_loadable.py"), str(tmp_path)], capture_output=True, text=True, check=True)
    assert out.stdout.splitlines() == ["1 of 2 Objectives load", "    1  missing: SetupMTCPathIK"]

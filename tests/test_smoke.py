"""`objective smoke-test`: the verdict on one GetActionChunk call, made the way ExecutePolicy makes it."""
from __future__ import annotations

import os
import subprocess
import sys
import threading
import uuid
from pathlib import Path

import numpy as np
import pytest
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import Image, JointState
from trajectory_msgs.msg import JointTrajectoryPoint

from runtime.app.cli import main
from policy.adapter import PolicyAdapter, array_to_multiarray
from policy.backend import PolicyResponse
from policy.images import rgb_to_image
from policy.smoke import (
    FAIL, PASS, SmokeConfig, SmokeReport, group_joints, judge_response, observed_state, run_smoke_test,
)

from .fakes import FakeBackend

pytestmark = pytest.mark.timeout(60)

ROOT = Path(__file__).resolve().parents[1]
ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
GRIPPER = "robotiq_85_left_knuckle_joint"
NAMES = ARM + [GRIPPER]
R = GetActionChunk.Response


def response(steps=5, names=NAMES, status=R.CHUNK_PRODUCED, message="", width=None, policy=None, offset=0):
    msg = R(status=status, message=message, native_control_period=0.1)
    msg.chunk.joint_names = list(names)
    width = len(names) if width is None else width
    msg.chunk.points = [JointTrajectoryPoint(positions=[0.1 * k] * width) for k in range(steps)]
    if policy is not None:
        msg.policy_action_chunk = array_to_multiarray(policy)
        msg.policy_action_chunk.layout.data_offset = offset
    return msg


def judged(msg, rtc=False, expected=None) -> dict[str, tuple[str, str]]:
    report = SmokeReport()
    judge_response(report, msg, NAMES, rtc, expected)
    return {c.name: (c.result, c.detail) for c in report.checks}


# --------------------------------------------------------------------------------------------
# The judgement (pure)
# --------------------------------------------------------------------------------------------
def test_good_chunk_passes_every_check():
    checks = judged(response(steps=50), expected=50)
    assert checks["status"] == (PASS, "CHUNK_PRODUCED")
    assert checks["step count"] == (PASS, "50 steps (as expected)")
    assert checks["joint names"] == (PASS, "echo robot_state.name (7 joints)")
    assert checks["positions"] == (PASS, "every value finite, one per joint")
    assert checks["control period"] == ("info", "0.1 s (10 Hz)")
    assert checks["policy_action_chunk"] == ("info", "empty (RTC off)")


@pytest.mark.parametrize("msg, rtc, expected, check, detail", [
    (response(steps=10), False, 50, "step count", "10 steps, expected 50"),
    (response(steps=0), False, None, "step count", "the chunk has no points"),
    (response(names=list(reversed(NAMES))), False, None, "joint names",
     f"[{', '.join(reversed(NAMES))}] differ from robot_state.name [{', '.join(NAMES)}]"),
    (response(width=6), False, None, "positions", "step 0 has 6 positions for 7 joints"),
    (response(), True, None, "policy_action_chunk", "empty, but RTC is on: the caller would send no carryover"),
    (response(policy=np.ones((5, 32)), offset=3), True, None, "policy_action_chunk",
     "data_offset is 3: the caller reads it as empty"),
    (response(policy=np.ones((4, 32))), True, None, "policy_action_chunk",
     "layout [4, 32] is not steps first with one row per step (5)"),
    (response(status=R.ERROR, message="cannot reach the inference server at http://127.0.0.1:9/infer"), False, None,
     "status", "ERROR: cannot reach the inference server at http://127.0.0.1:9/infer"),
    (response(status=R.UNKNOWN), False, None, "status", "UNKNOWN (the server never set a status)"),
])
def test_each_wiring_mistake_fails_its_check(msg, rtc, expected, check, detail):
    checks = judged(msg, rtc, expected)
    assert checks[check] == (FAIL, detail)


def test_nan_fails_naming_step_and_joint():
    msg = response()
    msg.chunk.points[3].positions[2] = float("nan")
    assert judged(msg)["positions"] == (FAIL, "step 3 joint 'elbow_joint' is nan")


def test_rtc_chunk_with_the_right_layout_passes():
    assert judged(response(policy=np.ones((5, 32))), rtc=True)["policy_action_chunk"] == (
        PASS, "5 x 32, steps first, data_offset 0")


def test_verdict_table():
    report = SmokeReport()
    report.add("service", PASS, "/get_action_chunk is available")
    report.add("status", FAIL, "ERROR: model still loading")
    assert report.table().splitlines() == [
        "CHECK    RESULT  DETAIL",
        "service  PASS    /get_action_chunk is available",
        "status   FAIL    ERROR: model still loading",
        "VERDICT: FAIL (1 of 2 checks failed)",
    ]
    assert not report.passed


def test_robot_state_is_the_group_then_the_gripper():
    state = JointState(name=[GRIPPER] + ARM[::-1], position=[0.5] + [float(i) for i in range(6)])
    names, positions = observed_state(state, ARM, GRIPPER)
    assert names == NAMES
    assert positions == [5.0, 4.0, 3.0, 2.0, 1.0, 0.0, 0.5]
    assert observed_state(JointState(name=ARM, position=[0.0] * 6), ARM, GRIPPER) == (
        f"[{GRIPPER}] not in the joint states (they name [{', '.join(ARM)}])")


@pytest.mark.parametrize("fields, reason", [
    (dict(image_topics=("/a", "/b"), image_names=("a",)), "2 image topics but 1 image names"),
    (dict(synthetic_images=True), "--synthetic-images needs --image-names"),
    (dict(expected_steps=0), "--expected-steps must be at least 1"),
    (dict(srdf=None), "--urdf and --srdf go together"),
    (dict(joint_group=None, urdf=None, srdf=None, joints=()), "name the joints the policy commands, base to tip"),
    (dict(joints=tuple(ARM)), "--joints names the joints itself"),
    (dict(joint_group=None, urdf=None, srdf=None, joints=("a", "b", "a")), "--joints names a joint twice: a;b;a"),
])
def test_bad_options_are_refused(fields, reason):
    values = {"joint_group": "manipulator", "urdf": Path("robot.urdf"), "srdf": Path("robot.srdf"), **fields}
    with pytest.raises(ValueError, match=reason):
        SmokeConfig("/get_action_chunk", **values)


def test_the_group_comes_from_the_robot_description(tmp_path):
    """No robot model of its own: the group's joints are read from --urdf/--srdf, base to tip."""
    from .test_scene import SRDF, URDF

    (tmp_path / "robot.urdf").write_text(URDF)
    (tmp_path / "robot.srdf").write_text(SRDF)
    described = SmokeConfig("/s", "arm", urdf=tmp_path / "robot.urdf", srdf=tmp_path / "robot.srdf")
    assert group_joints(described) == ("j1",)
    with pytest.raises(ValueError, match="gripper joint 'j1' is in the group 'arm'"):
        group_joints(SmokeConfig("/s", "arm", urdf=tmp_path / "robot.urdf", srdf=tmp_path / "robot.srdf",
                                 gripper_joint="j1"))
    assert group_joints(SmokeConfig("/s", joints=("a", "b"), gripper_joint="g")) == ("a", "b")


def test_cli_bad_input_exits_2(capsys):
    code = main(["smoke-test", "/get_action_chunk", "--joints", ";".join(ARM),
                 "--image-topics", "/scene_camera/color;/wrist_camera/color", "--image-names", "scene"])
    assert code == 2
    assert "error: 2 image topics but 1 image names" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------
# Over real ROS 2
# --------------------------------------------------------------------------------------------
def echo_backend() -> FakeBackend:
    """Answers 50 steps holding the observed joints."""
    return FakeBackend(lambda r: PolicyResponse.chunk(np.tile(r.joint_positions, (50, 1)), 0.1), name="echo")


@pytest.fixture
def cell():
    """A fake robot on ROS 2: joint states, one camera, and an adapter serving an echo backend."""
    from runtime.io.clock import WallClock
    from runtime.io.ros import RosBus

    tag = f"/t{uuid.uuid4().hex[:8]}"
    bus = RosBus(WallClock(), node_name="fake_cell")
    backend = echo_backend()
    PolicyAdapter(backend).serve(bus, f"{tag}/get_action_chunk")
    state = JointState(name=NAMES, position=[0.1, -1.2, 1.3, -1.6, -1.5, 0.2, 0.0])
    state.header.stamp.sec = 7
    bus.create_lazy_publisher(f"{tag}/joint_states", JointState, lambda: state, rate_hz=50.0)
    bus.create_lazy_publisher(f"{tag}/scene_camera/color", Image,
                              lambda: rgb_to_image(np.full((48, 64, 3), 90, np.uint8), "bgr8"), rate_hz=30.0)
    try:
        yield tag, backend
    finally:
        bus.close()


def config(tag: str, **fields) -> SmokeConfig:
    values = dict(gripper_joint=GRIPPER, image_topics=(f"{tag}/scene_camera/color",), image_names=("scene",),
                  prompt="stack the red cube on the blue cube", expected_steps=50, wait=5.0,
                  joint_states_topic=f"{tag}/joint_states")
    values.update(fields)
    return SmokeConfig(f"{tag}/get_action_chunk", joints=tuple(ARM), **values)


@pytest.mark.ros
def test_smoke_test_passes_against_a_working_adapter(cell):
    tag, backend = cell
    report = run_smoke_test(config(tag))
    assert report.passed, report.table()
    checks = {c.name: c for c in report.checks}
    assert checks["camera scene"].detail == f"{tag}/scene_camera/color: 64x48 bgr8"
    assert checks["joint states"].detail.startswith(f"7 joints from {tag}/joint_states: shoulder_pan_joint")
    [request] = backend.requests
    assert request.joint_names == NAMES and request.new_episode and request.stamp == 7.0
    assert np.allclose(request.joint_positions, [0.1, -1.2, 1.3, -1.6, -1.5, 0.2, 0.0])
    assert request.images["scene"].shape == (48, 64, 3)


@pytest.mark.ros
def test_a_camera_driver_publishing_best_effort_is_observed(cell):
    """A plain rclpy publisher with the sensor-data QoS (best-effort), as camera drivers use."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data

    tag, _ = cell
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("best_effort_camera", context=context)
    publisher = node.create_publisher(Image, f"{tag}/ir_camera/image_raw", qos_profile_sensor_data)
    frame = rgb_to_image(np.full((30, 40, 3), 50, np.uint8), "rgb8")
    timer = node.create_timer(0.02, lambda: publisher.publish(frame))
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinning = threading.Thread(target=lambda: executor.spin(), daemon=True)
    spinning.start()
    try:
        report = run_smoke_test(config(tag, image_topics=(f"{tag}/ir_camera/image_raw",), image_names=("ir",)))
    finally:
        node.destroy_timer(timer)
        executor.shutdown(timeout_sec=2)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        spinning.join(timeout=5)
    checks = {c.name: c for c in report.checks}
    assert checks["camera ir"].result == PASS and checks["camera ir"].detail == f"{tag}/ir_camera/image_raw: 40x30 rgb8"
    assert report.passed, report.table()


@pytest.mark.ros
def test_a_silent_camera_fails_naming_the_qos(cell):
    tag, _ = cell
    report = run_smoke_test(config(tag, image_topics=(f"{tag}/nothing/image_raw",), image_names=("none",), wait=0.5))
    assert [(c.name, c.result, c.detail) for c in report.checks][-1] == (
        "camera none", FAIL, f"no frame on {tag}/nothing/image_raw within 0.5 s (subscribed best-effort, so a reliable "
        "or best-effort publisher matches: is the driver publishing?)")


@pytest.mark.ros
def test_smoke_test_fails_rtc_without_a_policy_chunk(cell):
    tag, _ = cell
    report = run_smoke_test(config(tag, rtc=True))
    assert not report.passed
    assert {c.name: c.result for c in report.checks}["policy_action_chunk"] == FAIL


@pytest.mark.ros
def test_smoke_test_fails_when_the_service_is_missing():
    tag = f"/t{uuid.uuid4().hex[:8]}"
    report = run_smoke_test(config(tag, wait=0.3))
    assert [(c.name, c.result, c.detail) for c in report.checks] == [
        ("service", FAIL, f"{tag}/get_action_chunk did not appear within 0.3 s (start the adapter first)")]


@pytest.mark.ros
def test_smoke_test_command_prints_the_verdict_and_exits_0(cell):
    tag, _ = cell
    proc = subprocess.run(
        [sys.executable, "-m", "runtime.app.cli", "smoke-test", f"{tag}/get_action_chunk", "--joints", ";".join(ARM),
         "--gripper-joint", GRIPPER, "--image-names", "scene;wrist", "--synthetic-images", "--expected-steps", "50",
         "--joint-states-topic", f"{tag}/joint_states"],
        cwd=ROOT, env={**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}, capture_output=True, text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].split() == ["CHECK", "RESULT", "DETAIL"]
    assert lines[-1] == "VERDICT: PASS"
    assert any(line.split()[:2] == ["step", "count"] and "50 steps (as expected)" in line for line in lines)

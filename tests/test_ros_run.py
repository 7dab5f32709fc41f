"""`objective run --ros`: the runtime and its hosted cell on a real ROS 2 graph (loopback only).

The runner's node serves the kinematic cell's joint states, cameras, controllers and controller
manager on ROS 2; a separate node (another process's view) sees them, and ExecutePolicy calls a
policy served by another node, as it will call an adapter.
"""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.timeout(60)]

from controller_manager_msgs.srv import ListControllers  # noqa: E402
from moveit_pro_ml_msgs.srv import GetActionChunk  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint  # noqa: E402

from runtime.io.clock import WallClock  # noqa: E402
from runtime.errors import ObjectiveError  # noqa: E402
from runtime.tree.loader import load_tree  # noqa: E402
from runtime.tree.registry import Registry  # noqa: E402
from runtime.io.ros import RosBus  # noqa: E402
from runtime.app.runner import RunOptions, make_context, run_tree  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
OBJECTIVE = [sys.executable, "-m", "runtime.app.cli"]
R = GetActionChunk.Response
GRIPPER = "robotiq_85_left_knuckle_joint"
ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]


@pytest.fixture
def ros_env(monkeypatch) -> dict[str, str]:
    """A ROS domain of this test's own (other test runs on the machine use theirs), on loopback."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(random.randint(100, 199)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return dict(os.environ)


@pytest.fixture
def observer(ros_env):
    """A node of the test's own: what another process on the graph sees."""
    bus = RosBus(WallClock(), node_name="test_observer")
    yield bus
    bus.close()


def wait_for(condition: Callable[[], Any], bus: RosBus | None = None, timeout: float = 10.0, what: str = "it") -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if bus is not None:
            bus.spin_once()
        value = condition()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def objective(*args: str, env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen(
        [*OBJECTIVE, *args], cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def finish(proc: subprocess.Popen, timeout: float = 30.0) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"the runner did not stop within {timeout} s; stderr:\n{err}")
    return proc.returncode, out, err


# -- the CLI -------------------------------------------------------------------------------
def test_open_gripper_on_ros_succeeds_and_says_where_it_runs(ros_env):
    """Discovery stays on this machine when nothing in the environment opens it."""
    env = {k: v for k, v in ros_env.items() if k != "ROS_AUTOMATIC_DISCOVERY_RANGE"}
    code, out, err = finish(objective("run", "objectives/cell/open_gripper.xml", "--ros", "--realtime",
                                      "--world", "kinematic", "--json", env=env))
    assert code == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["status"] == "SUCCESS" and summary["world"]["gripper"] == 0.0
    assert set(summary["pacing"]) == {"late_ticks", "worst_tick_s", "period_s", "scheduling", "interval_p50_s", "interval_p99_s", "interval_max_s"}
    assert summary["pacing"]["scheduling"] == "default"
    domain = ros_env["ROS_DOMAIN_ID"]
    assert f"[INFO] running on ROS 2 as node /objective_runtime (ROS_DOMAIN_ID={domain}, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)" in err


def close_wait_open(tmp_path: Path, seconds: float) -> Path:
    path = tmp_path / "close_wait_open.xml"
    path.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>'
        '<MoveGripperAction gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd" position="0.5"/>'
        f'<Wait seconds="{seconds}"/>'
        '<MoveGripperAction gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd" position="0.0"/>'
        "</Sequence></BehaviorTree></root>"
    )
    return path


def test_the_hosted_cell_is_on_ros_while_the_run_lasts(ros_env, observer, tmp_path):
    joint_states = observer.create_subscription("/joint_states", JointState)
    controllers = observer.create_client("/controller_manager/list_controllers", ListControllers)
    runner = objective("run", str(close_wait_open(tmp_path, 4.0)), "--ros", "--world", "kinematic", "--json", env=ros_env)
    try:
        wait_for(lambda: joint_states.count >= 5, observer, what="/joint_states from the runner")
        assert list(joint_states.latest.name) == ARM + [GRIPPER]
        wait_for(controllers.service_is_ready, observer, what="/controller_manager/list_controllers")
        # the runner's services are discovered, and a policy is not among them: it serves none of its own
        assert observer.create_client("/get_action_chunk", GetActionChunk).service_is_ready() is False
        future = controllers.call_async(ListControllers.Request())
        states = {c.name: c.state for c in wait_for(lambda: future.done() and future.result(), observer,
                                                    what="the controller list").controller}
        assert states == {
            "joint_trajectory_admittance_controller": "inactive",
            "joint_trajectory_controller": "inactive",
            "velocity_force_controller": "active",
            "robotiq_gripper_controller": "active",
            "force_torque_sensor_broadcaster": "active",
        }
        # the gripper closes on the runner's side and the observer sees it move
        wait_for(lambda: joint_states.latest.position[-1] > 0.4, observer, what="the gripper to close")
    finally:
        code, out, err = finish(runner)
    assert code == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["status"] == "SUCCESS" and summary["world"]["gripper"] == 0.0
    assert summary["wall_seconds"] > 4.0  # the Objective waits 4 s on the wall clock


def test_sigterm_halts_the_run_and_the_node_leaves_the_graph(ros_env, observer, tmp_path):
    joint_states = observer.create_subscription("/joint_states", JointState)
    record = tmp_path / "rec"
    runner = objective("run", str(close_wait_open(tmp_path, 60.0)), "--ros", "--world", "kinematic", "--json",
                       "--record", str(record), env=ros_env)
    try:
        # the recording's report worker starts beside the runner: on a loaded machine that takes a while
        wait_for(lambda: joint_states.count >= 1, observer, timeout=30.0, what="/joint_states from the runner")
        # the tree runs: the gripper closes (the world publishes joint states before the first tick)
        wait_for(lambda: joint_states.latest.position[-1] > 0.05, observer, timeout=30.0, what="the gripper closing")
        runner.send_signal(signal.SIGTERM)
        code, out, err = finish(runner, timeout=10.0)
    finally:
        if runner.poll() is None:
            runner.kill()
    assert code == 143, err
    assert "INTERRUPTED after" in err and "interrupted by SIGTERM" in err and "Traceback" not in err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["status"] == "INTERRUPTED" and summary["signal"] == "SIGTERM" and summary["running_nodes"]
    last = json.loads((record / "events.jsonl").read_text().splitlines()[-1])
    assert last["kind"] == "run_summary" and last["data"]["status"] == "INTERRUPTED"
    assert (record / "report.html").exists()
    wait_for(lambda: "objective_runtime" not in observer.node.get_node_names(), observer,
             what="the runner's node to leave the graph")


def test_policy_latency_is_refused_with_ros(ros_env):
    code, out, err = finish(objective("run", "objectives/cell/open_gripper.xml", "--ros", "--world", "kinematic",
                                      "--policy-latency", "0.3", env=ros_env))
    assert code == 2
    assert err.strip() == (
        "error: --policy-latency models latency on the in-process bus; with --ros the policy's latency is real"
    )
    with pytest.raises(ObjectiveError):
        RunOptions(ros=True, policy_latency="0.3").check()


def test_the_discovery_range_opens_only_with_the_flag_and_only_with_ros(ros_env, capsys):
    from runtime.app.cli import main
    from runtime.io.ros.run import set_discovery_range

    assert main(["run", "objectives/cell/open_gripper.xml", "--discovery-range", "subnet"]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: --discovery-range sets who may discover the run's ROS 2 node: it needs --ros")
    assert set_discovery_range() == "LOCALHOST"  # (the fixture's)
    assert set_discovery_range("subnet") == "SUBNET" == os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"]


# -- ExecutePolicy against a policy served by another node -----------------------------------
def run_policy_over_ros(policy: Callable[[Any], Any], ports: str) -> Any:
    """Run ExecutePolicy (after switching to the trajectory controller) with ``--ros`` on the
    kinematic cell, against ``policy`` served by a node of its own, as an adapter would."""
    server = RosBus(WallClock(), node_name="scripted_policy")  # answers on its own threads, like an adapter
    server.create_service("/get_action_chunk", GetActionChunk, policy)
    options = RunOptions(ros=True, world="kinematic", max_seconds=20.0)
    context = make_context(options)
    xml = (
        '<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>'
        '<SwitchController activate_controllers="joint_trajectory_admittance_controller" deactivate_controllers="velocity_force_controller"/>'
        '<ExecutePolicy policy_service_name="/get_action_chunk" joint_group_name="manipulator" '
        f'dt="0.1" committed_action_steps="20" goal_path_tolerance="0.3" policy_call_timeout="3.0" {ports}/>'
        "</Sequence></BehaviorTree></root>"
    )
    try:
        return run_tree(load_tree(xml, Registry.from_entry_points(), context), context, options)
    finally:
        server.close()


def test_execute_policy_over_ros_calls_a_policy_served_by_another_node(ros_env):
    requests: list[Any] = []

    def policy(request: Any) -> Any:
        """Chunks that hold the observed state (a still arm is a valid motion).

        The warmup answers after 0.3 s: it seeds ExecutePolicy's latency estimate, so the first
        chunks are requested early. The estimate is the 90th percentile of recent round trips, so
        after ten fast calls the warmup no longer counts, and a loaded machine that stalls the
        real-time runner can make a chunk miss its seam by a few ticks: a pause
        (``stall_seconds``), not what this test is about, so only a long one fails it.
        """
        requests.append(request)
        if len(requests) == 1:
            time.sleep(0.3)
        names = list(request.robot_state.name)
        response = R(status=R.CHUNK_PRODUCED, native_control_period=0.1)
        position = [float(v) for v in request.robot_state.position]
        response.chunk = JointTrajectory(joint_names=names, points=[JointTrajectoryPoint(positions=position) for _ in range(30)])
        return response

    result = run_policy_over_ros(policy, (
        'total_action_steps="40" image_topics="/scene_camera/color;/wrist_camera/color" image_names="scene;wrist" '
        f'gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd" gripper_joint_name="{GRIPPER}" '
        'steps_executed="{steps}" chunks_received="{chunks}" status_message="{message}"'))
    assert result.status == "SUCCESS", result.reason
    assert result.blackboard["message"] == "executed 40 steps" and result.blackboard["steps"] == 40
    assert [r.new_episode for r in requests[:2]] == [True, True] and not any(r.new_episode for r in requests[2:])
    assert len(requests) == 1 + result.blackboard["chunks"]
    # the request carried real frames from the runner's cameras and the state from /joint_states
    assert list(requests[1].image_names) == ["scene", "wrist"] and requests[1].images[0].encoding == "rgb8"
    assert list(requests[1].robot_state.name) == ARM + [GRIPPER]
    latency = result.extra["execute_policy"]
    assert latency["latency_p50_s"] > 0.0  # a real round trip over DDS, measured on the wall clock


def test_a_failing_execute_policy_s_cancel_reaches_the_hosted_controller(ros_env, monkeypatch, capfd):
    """ExecutePolicy fails (not halted) while its trajectory goal runs: it cancels the goal, and
    the cancel is served by the hosted controller before the node leaves the graph."""
    from sim.controllers.admittance import JointTrajectoryAdmittanceController

    served: list[bool] = []
    on_cancel = JointTrajectoryAdmittanceController._on_cancel

    def recording(self, handle):
        served.append(on_cancel(self, handle))
        return served[-1]

    monkeypatch.setattr(JointTrajectoryAdmittanceController, "_on_cancel", recording)
    requests: list[Any] = []

    def policy(request: Any) -> Any:
        requests.append(request)
        if len(requests) == 1:
            time.sleep(0.3)  # seeds the latency estimate, as in the test above
        if len(requests) == 3:
            return R(status=R.ERROR, message="model lost its weights")
        response = R(status=R.CHUNK_PRODUCED, native_control_period=0.1)
        position = [float(v) for v in request.robot_state.position]
        response.chunk = JointTrajectory(joint_names=list(request.robot_state.name),
                                         points=[JointTrajectoryPoint(positions=position) for _ in range(30)])
        return response

    result = run_policy_over_ros(policy, 'total_action_steps="60"')
    assert result.status == "FAILURE"
    assert result.reason == "the policy answered ERROR for the chunk 2: model lost its weights"
    assert served == [True]
    assert "BusClosed" not in capfd.readouterr().err


def test_a_camera_that_stops_publishing_over_ros_stops_the_run_naming_its_topic(ros_env):
    """A camera driver of another node publishes at 20 Hz and stops once the policy has answered
    two chunks: the next request would feed the policy a frame older than max_observation_age
    (10 * dt = 1 s), so the run stops there, naming the topic."""
    import threading

    from sensor_msgs.msg import Image

    from policy.images import rgb_to_image

    camera = RosBus(WallClock(), node_name="thermal_camera_driver")
    publisher = camera.create_publisher("/thermal_camera/color", Image, reliable=False)
    frame = rgb_to_image(np.full((4, 6, 3), 200, np.uint8))
    stopped = threading.Event()

    def drive() -> None:
        while not stopped.wait(0.05):
            publisher.publish(frame)

    driver = threading.Thread(target=drive, daemon=True)
    requests: list[Any] = []

    def policy(request: Any) -> Any:
        requests.append(request)
        if len(requests) == 3:  # the warmup and two chunks: the camera stops
            stopped.set()
        response = R(status=R.CHUNK_PRODUCED, native_control_period=0.1)
        position = [float(v) for v in request.robot_state.position]
        response.chunk = JointTrajectory(joint_names=list(request.robot_state.name),
                                         points=[JointTrajectoryPoint(positions=position) for _ in range(30)])
        return response

    driver.start()
    try:
        result = run_policy_over_ros(policy, 'total_action_steps="80" image_topics="/thermal_camera/color" image_names="thermal"')
    finally:
        stopped.set()
        driver.join(timeout=5)
        camera.close()
    assert result.status == "FAILURE", result.reason
    assert result.reason.startswith("the newest message on '/thermal_camera/color' is ")
    assert result.reason.endswith(" s old, more than max_observation_age = 1.00 s: its publisher stopped or fell "
                                  "behind; the policy is not fed an old world, robot stopped")
    assert len(requests) == 3


@pytest.mark.parametrize("world, on_ros_time", [("robot", True), ("kinematic", False)])
def test_goal_stamps_are_in_ros_time_on_a_robot_and_in_the_run_s_time_with_a_hosted_cell(ros_env, world, on_ros_time):
    """A real robot's controllers read a goal's stamp as an instant of ROS time (the system clock
    without use_sim_time): a run on the `robot` world stamps its seams there; a hosted cell keeps
    the run's own clock, so its stamps are not moved."""
    from runtime.motion.samples import Samples
    from behaviors.trajectory_goal import trajectory_msg
    from runtime.io.timestamps import to_seconds

    context = make_context(RunOptions(ros=True, world=world))
    try:
        seam_s = context.clock.now() + 0.5
        samples = Samples(np.array([seam_s, seam_s + 0.1]), np.zeros((2, 1)), np.zeros((2, 1)), np.zeros((2, 1)))
        msg = trajectory_msg(samples, ["j"], seam_s, context.stamp_offset_s)
        expected = time.time() + 0.5 if on_ros_time else seam_s
        assert abs(to_seconds(msg.header.stamp) - expected) < 0.25
        assert [to_seconds(p.time_from_start) for p in msg.points] == pytest.approx([0.0, 0.1])
        assert to_seconds(trajectory_msg(samples, ["j"], 0.0, context.stamp_offset_s).header.stamp) == 0.0  # "start now" stays 0
    finally:
        context.bus.close()

"""ExecutePolicy end to end on the kinematic cell: every troubleshooting case of the guide with a
misbehaving policy or configuration, streaming continuity, RTC carryover, latency, halting."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import pytest
from moveit_pro_ml_msgs.srv import GetActionChunk
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

import runtime.io.bus as bus_module
from runtime.io.bus import FixedLatency
from runtime.errors import PortError
from runtime.tree.loader import load_tree
from recording.report.data import Recording
from recording.report.plots import stall_spans
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, make_context, run_tree
from runtime.motion.scene import Box, pose_matrix
from sim.kinematic import KinematicWorld
from sim.robot_model import ARM_JOINTS

R = GetActionChunk.Response
SERVICE = "/get_action_chunk"
GRIPPER = "robotiq_85_left_knuckle_joint"
CAMERAS = 'image_topics="/scene_camera/color;/wrist_camera/color" image_names="scene;wrist"'
GRIPPER_PORTS = f'gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd" gripper_joint_name="{GRIPPER}"'


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


@dataclass
class ScriptedPolicy:
    """A policy service whose answers a test writes: ``answer(call_index, request) -> Response``."""

    answer: Callable[[int, Any], Any]
    requests: list[Any] = field(default_factory=list)

    def __call__(self, request: Any) -> Any:
        self.requests.append(request)
        return self.answer(len(self.requests) - 1, request)


def chunk_response(names: list[str], rows: np.ndarray, period: float = 0.1, policy_rows: np.ndarray | None = None) -> Any:
    response = R(status=R.CHUNK_PRODUCED, native_control_period=period)
    response.chunk = JointTrajectory(joint_names=names, points=[JointTrajectoryPoint(positions=[float(v) for v in r]) for r in rows])
    if policy_rows is not None:
        steps, width = policy_rows.shape
        response.policy_action_chunk = Float64MultiArray(data=policy_rows.ravel().tolist())
        response.policy_action_chunk.layout.dim = [
            MultiArrayDimension(label="step", size=steps, stride=steps * width),
            MultiArrayDimension(label="action", size=width, stride=width),
        ]
    return response


def hold(steps: int = 50, velocity: np.ndarray | None = None, dt: float = 0.1) -> Callable[[int, Any], Any]:
    """Chunks that start at the observed state and move each joint at ``velocity`` rad/s."""

    def answer(index: int, request: Any) -> Any:
        start = np.array(request.robot_state.position)
        rate = np.zeros(len(start)) if velocity is None else np.append(velocity, np.zeros(len(start) - len(velocity)))
        rows = start + np.outer(np.arange(steps) * dt, rate)
        return chunk_response(list(request.robot_state.name), rows)

    return answer


def policy_xml(ports: str, prepare: bool = True, wrap: str | None = None, service: str = SERVICE) -> str:
    node = f'<ExecutePolicy policy_service_name="{service}" joint_group_name="manipulator" {ports} steps_executed="{{steps}}" chunks_received="{{chunks}}" rejection_reason="{{rejection}}" status_message="{{message}}"/>'
    if wrap:
        node = wrap.format(node=node)
    prep = '<SwitchController activate_controllers="joint_trajectory_admittance_controller" deactivate_controllers="velocity_force_controller"/>' if prepare else ""
    return f'<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>{prep}{node}</Sequence></BehaviorTree></root>'


@dataclass
class Run:
    result: Any
    world: KinematicWorld
    context: Any
    policy: ScriptedPolicy | None

    @property
    def summary(self) -> dict[str, Any]:
        return self.result.extra["execute_policy"]


def run_policy(
    registry: Registry,
    ports: str,
    policy: ScriptedPolicy | None = None,
    latency: Any = 0.02,
    prepare: bool = True,
    wrap: str | None = None,
    seed: int = 0,
    max_seconds: float = 60.0,
    world_options: dict[str, Any] | None = None,
    before: Callable[[Any, KinematicWorld], None] | None = None,
    service: str = SERVICE,
) -> Run:
    options = RunOptions(seed=seed, max_seconds=max_seconds, world="kinematic")
    context = make_context(options)
    world = KinematicWorld({"seed": seed, "policy": "none" if policy is not None else "oracle", **(world_options or {})})
    loaded = load_tree(policy_xml(ports, prepare, wrap, service), registry, context)
    if policy is not None:
        context.bus.create_service(SERVICE, GetActionChunk, policy)
    if latency is not None:
        context.bus.set_latency(SERVICE, latency if not isinstance(latency, (int, float)) else FixedLatency(latency))
    if before is not None:
        before(context, world)
    result = run_tree(loaded, context, options, world=world)
    return Run(result, world, context, policy)


BASE = 'total_action_steps="60" dt="0.1" committed_action_steps="20" goal_path_tolerance="0.3" policy_call_timeout="3.0"'


def plotted_stall_s(run: Run) -> float:
    """Seconds of stall the report's joint plot draws (red bands) from the run's events."""
    recording = Recording(Path("."), events=[dataclasses.asdict(e) for e in run.context.events.events])
    return sum(end - start for start, end in stall_spans(recording))


# -- the happy path ------------------------------------------------------------------------
def test_steps_run_for_total_action_steps_times_dt_and_report(registry):
    run = run_policy(registry, BASE, ScriptedPolicy(hold()))
    assert run.result.status == "SUCCESS", run.result.reason
    s = run.summary
    assert s["steps_executed"] == 60 and s["chunks"] == 3 and s["stall_seconds"] == 0.0 and s["rejections"] == 0
    assert run.result.blackboard["steps"] == 60 and run.result.blackboard["chunks"] == 3
    assert run.result.blackboard["message"] == "executed 60 steps"
    # Warmup plus three chunks; both the warmup and the first real request start an episode.
    assert [r.new_episode for r in run.policy.requests] == [True, True, False, False]


def test_request_carries_group_joints_then_gripper_and_one_frame_per_camera(registry):
    run = run_policy(registry, f'{BASE} {CAMERAS} {GRIPPER_PORTS} prompt="stack it"', ScriptedPolicy(hold()))
    assert run.result.status == "SUCCESS", run.result.reason
    request = run.policy.requests[1]
    assert list(request.robot_state.name) == list(ARM_JOINTS) + [GRIPPER]
    assert len(request.robot_state.position) == 7 and len(request.robot_state.velocity) == 0
    assert list(request.image_names) == ["scene", "wrist"] and len(request.images) == 2
    assert request.images[0].encoding == "rgb8" and request.prompt == "stack it"
    assert len(request.previous_action_chunk.data) == 0  # RTC is off


def test_no_more_actions_ends_with_success_and_the_message(registry):
    def answer(i, request):
        return hold()(i, request) if i < 2 else R(status=R.NO_MORE_ACTIONS, message="replay finished")

    run = run_policy(registry, BASE, ScriptedPolicy(answer))
    assert run.result.status == "SUCCESS"
    assert run.result.blackboard["message"] == "the policy has no more actions: replay finished"
    assert run.summary["chunks"] == 1


@pytest.mark.parametrize(
    "status, message, expected",
    [
        (R.ERROR, "model still loading", "the policy answered ERROR for the chunk 2: model still loading"),
        (R.UNKNOWN, "", "the policy answered UNKNOWN for the chunk 2: the policy left the status unset"),
    ],
)
def test_error_and_unknown_fail_with_the_reason(registry, status, message, expected):
    def answer(i, request):
        return hold()(i, request) if i < 2 else R(status=status, message=message)

    run = run_policy(registry, BASE, ScriptedPolicy(answer))
    assert run.result.status == "FAILURE" and run.result.failing_node == "ExecutePolicy"
    assert run.result.reason == expected


def test_every_run_of_a_retried_policy_is_counted(registry):
    # The policy fails its first run at chunk 2; RetryUntilSuccessful runs it again, to the end.
    def answer(i, request):
        return R(status=R.ERROR, message="lost the cube") if i == 2 else hold()(i, request)

    run = run_policy(registry, BASE, ScriptedPolicy(answer), wrap=RETRY)
    assert run.result.status == "SUCCESS", run.result.reason
    summary = run.summary
    assert [(r["chunks"], r["steps_executed"], r["message"]) for r in summary["runs"]] == [
        (1, 19, "the policy answered ERROR for the chunk 2: lost the cube"),  # stopped in chunk 1's window
        (3, 60, "executed 60 steps"),
    ]
    assert (summary["run_count"], summary["chunks"], summary["steps_executed"]) == (2, 4, 79)
    assert summary["message"] == "executed 60 steps" and len(run.policy.requests) == 7  # warmup + 2, then warmup + 3
    assert run.result.to_json()["execute_policy"]["chunks"] == 4


def test_a_retried_policy_builds_its_bus_clients_once(registry):
    # Built in setup(), reset in initialise(): the second run talks through the first run's clients.
    created: list[str] = []

    def count(context, world):
        for method in ("create_client", "create_action_client", "create_subscription"):
            def counted(name, *args, _original=getattr(context.bus, method), **kwargs):
                created.append(name)
                return _original(name, *args, **kwargs)
            setattr(context.bus, method, counted)

    def answer(i, request):
        return R(status=R.ERROR, message="lost the cube") if i == 2 else hold()(i, request)

    run = run_policy(registry, BASE, ScriptedPolicy(answer), wrap=RETRY, before=count)
    assert run.result.status == "SUCCESS", run.result.reason
    assert run.summary["run_count"] == 2
    assert (created.count(SERVICE), created.count("/joint_trajectory_admittance_controller/follow_joint_trajectory"),
            created.count("/joint_states")) == (1, 1, 1)


# -- start-up ------------------------------------------------------------------------------
SERVICES_HERE = "/controller_manager/list_controllers, /controller_manager/switch_controller, /protective_stop, /velocity_force_controller/zero_fts"


def test_missing_service_is_an_error_before_anything_moves(registry):
    run = run_policy(registry, BASE, None, world_options={"policy": "none"})
    assert (run.result.status, run.result.exit_code, run.result.ticks) == ("ERROR", 2, 0)
    assert run.result.reason == (
        f"<string>:1: ExecutePolicy: port 'policy_service_name': no service '/get_action_chunk' (services: {SERVICES_HERE})"
    )


RETRY = '<RetryUntilSuccessful num_attempts="3">{node}</RetryUntilSuccessful>'


def test_a_wrong_service_name_under_retry_waits_once_and_ends_as_error(registry):
    # The name comes from the blackboard, so only the running node can find it missing: it waits
    # 5 s once, and the error is not retried. The hint fits the run: no adapter in a headless run.
    wrap = "<Sequence><Script code=\"svc := '/get_action_chnk'\"/>" + RETRY + "</Sequence>"
    run = run_policy(registry, BASE, ScriptedPolicy(hold()), wrap=wrap, service="{svc}")
    assert (run.result.status, run.result.exit_code, run.result.failure_kind) == ("ERROR", 2, "SetupError")
    assert run.result.sim_seconds == pytest.approx(5.0, abs=0.05)  # one wait, not three
    assert run.result.reason == (
        "<string>:1: ExecutePolicy: not available after 5 s: policy service '/get_action_chnk' (in this run the world "
        "serves the policy chosen with --policy; services here: /controller_manager/list_controllers, "
        "/controller_manager/switch_controller, /get_action_chunk, /protective_stop, /velocity_force_controller/zero_fts)"
    )
    assert run.policy.requests == [] and run.summary["run_count"] == 1
    assert run.summary["message"] == run.result.blackboard["message"] == run.result.reason.removeprefix("<string>:1: ExecutePolicy: ")


def test_a_frame_typo_inside_a_retry_runs_the_policy_zero_times(registry):
    check = '<CheckObjectStacked top_object_name="cube_purple" bottom_object_name="cube_green"/>'
    wrap = '<RetryUntilSuccessful num_attempts="3"><Sequence>{node}' + check + "</Sequence></RetryUntilSuccessful>"
    run = run_policy(registry, BASE, ScriptedPolicy(hold()), wrap=wrap)
    assert (run.result.status, run.result.exit_code, run.result.ticks) == ("ERROR", 2, 0)
    assert run.result.reason.startswith(
        "<string>:1: CheckObjectStacked: port 'top_object_name': unknown frame 'cube_purple' "
        "(frames: cube_blue, cube_green, cube_red, table, world, base, shoulder_link, "
    )
    assert run.policy.requests == []


def test_a_frame_typo_the_tree_computes_ends_the_run_at_the_check_without_a_retry(registry):
    check = ("<Script code=\"top := 'cube_' .. 'purple'\"/>"
             '<CheckObjectStacked top_object_name="{{top}}" bottom_object_name="cube_green"/>')
    wrap = '<RetryUntilSuccessful num_attempts="3"><Sequence>{node}' + check + "</Sequence></RetryUntilSuccessful>"
    run = run_policy(registry, BASE, ScriptedPolicy(hold()), wrap=wrap)
    assert (run.result.status, run.result.exit_code, run.result.failing_node) == ("ERROR", 2, "CheckObjectStacked")
    assert run.result.reason.startswith("<string>:1: CheckObjectStacked: unknown frame 'cube_purple' (known: 'world', ")
    assert run.summary["run_count"] == 1 and len(run.policy.requests) == 4  # one policy run: warmup and 3 chunks


def test_a_camera_topic_the_world_lacks_ends_the_run_before_the_first_tick(registry):
    ports = f'{BASE} image_topics="/scene_camera/color;/thermal_camera/color" image_names="scene;thermal"'
    run = run_policy(registry, ports, ScriptedPolicy(hold()))
    assert (run.result.status, run.result.ticks) == ("ERROR", 0)
    assert run.result.reason.startswith("<string>:1: ExecutePolicy: port 'image_topics': no topic '/thermal_camera/color' "
                                        "(did you mean '/wrist_camera/color'?) (topics: ")
    assert run.policy.requests == []


def test_silent_camera_is_an_error_naming_the_topic(registry):
    """A topic read from the blackboard is known only when the node runs: it waits 5 s for a frame."""
    ports = f'{BASE} image_topics="{{cams}}" image_names="scene;thermal"'
    wrap = "<Sequence><Script code=\"cams := '/scene_camera/color;/thermal_camera/color'\"/>{node}</Sequence>"
    run = run_policy(registry, ports, ScriptedPolicy(hold()), wrap=wrap)
    assert run.result.status == "ERROR"
    assert run.result.reason == ("<string>:1: ExecutePolicy: not available after 5 s: a frame on camera topic "
                                 "'/thermal_camera/color' (subscribed best-effort, so a reliable or a best-effort "
                                 "publisher matches; is the camera driver publishing there?)")


def _counting_camera(reads: list[int]) -> Callable[[Any, KinematicWorld], None]:
    """A lazy ``/thermal_camera/color`` that counts its frames (on the in-process bus a read renders one)."""
    from policy.images import rgb_to_image
    from sensor_msgs.msg import Image

    def add(context, world):
        frame = rgb_to_image(np.full((4, 6, 3), 200, np.uint8))
        context.bus.create_lazy_publisher("/thermal_camera/color", Image, lambda: reads.append(1) or frame, reliable=False)

    return add


def test_cameras_are_read_once_the_rest_is_there_and_feed_the_warmup(registry):
    ports = f'{BASE} image_topics="/thermal_camera/color" image_names="thermal"'
    reads: list[int] = []
    run = run_policy(registry, ports, ScriptedPolicy(hold()), before=_counting_camera(reads))
    assert run.result.status == "SUCCESS", run.result.reason
    assert len(reads) == len(run.policy.requests) == 4  # one frame per request, the start-up check's included


def test_missing_service_and_camera_are_both_named_after_five_seconds(registry):
    ports = f'{BASE} image_topics="{{cams}}" image_names="thermal;night"'  # known when the node runs
    reads: list[int] = []
    wrap = ("<Sequence><Script code=\"svc := '/get_action_chunk'; cams := '/thermal_camera/color;/night_camera/color'\"/>"
            "{node}</Sequence>")
    run = run_policy(registry, ports, None, world_options={"policy": "none"}, before=_counting_camera(reads),
                     wrap=wrap, service="{svc}")
    assert run.result.reason == (
        "<string>:1: ExecutePolicy: not available after 5 s: policy service '/get_action_chunk' (in this run the world "
        f"serves the policy chosen with --policy; services here: {SERVICES_HERE}); "
        "a frame on camera topic '/night_camera/color' (subscribed best-effort, so a reliable or a best-effort "
        "publisher matches; is the camera driver publishing there?)"
    )
    assert len(reads) == 1  # read at the deadline only: nothing renders while the service is missing


def test_a_best_effort_camera_is_observed(registry):
    """Most ROS 2 camera drivers publish best-effort (sensor-data QoS); the cameras still match."""
    from policy.images import rgb_to_image
    from sensor_msgs.msg import Image

    def thermal_camera(context, world):
        frame = rgb_to_image(np.full((4, 6, 3), 200, np.uint8))
        context.bus.create_lazy_publisher("/thermal_camera/color", Image, lambda: frame, reliable=False)

    ports = f'{BASE} image_topics="/scene_camera/color;/thermal_camera/color" image_names="scene;thermal"'
    run = run_policy(registry, ports, ScriptedPolicy(hold()), before=thermal_camera)
    assert run.result.status == "SUCCESS", run.result.reason
    assert [(i.width, i.height) for i in run.policy.requests[1].images][1] == (6, 4)


def test_best_effort_joint_states_never_connect(registry):
    run = run_policy(registry, BASE, ScriptedPolicy(hold()), world_options={"joint_states_reliable": False})
    assert run.result.reason == ("<string>:1: ExecutePolicy: not available after 5 s: joint states on '/joint_states' "
                                 "(the publisher must use reliable QoS)")


def test_gripper_port_alone_is_a_load_error(registry):
    with pytest.raises(PortError) as err:
        run_policy(registry, f'{BASE} gripper_joint_name="{GRIPPER}"', ScriptedPolicy(hold()))
    assert str(err.value) == (
        "<string>:1: ExecutePolicy: gripper_command_action_name and gripper_joint_name must be set together: "
        "gripper_joint_name is set but gripper_command_action_name is empty"
    )


def test_image_lists_must_be_index_aligned_when_written(registry):
    with pytest.raises(PortError) as err:
        run_policy(registry, f'{BASE} image_topics="/scene_camera/color;/wrist_camera/color" image_names="scene"', ScriptedPolicy(hold()))
    assert str(err.value) == "<string>:1: ExecutePolicy: image_topics has 2 entries and image_names has 1; they must be index-aligned"


def test_image_lists_from_the_blackboard_of_different_lengths_are_an_error_when_the_node_starts(registry):
    wrap = "<Sequence><Script code=\"names := 'scene'\"/>{node}</Sequence>"
    ports = f'{BASE} image_topics="/scene_camera/color;/wrist_camera/color" image_names="{{names}}"'
    run = run_policy(registry, ports, ScriptedPolicy(hold()), wrap=wrap)
    assert (run.result.status, run.result.ticks) == ("ERROR", 3)  # SwitchController, the Script, ExecutePolicy
    assert run.result.reason == "<string>:1: ExecutePolicy: image_topics has 2 entries and image_names has 1; they must be index-aligned"


def test_group_with_two_tips_and_gripper_inside_the_group_fail_at_start(registry):
    gripper = ' gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd" gripper_joint_name="wrist_3_joint"'
    run = run_policy(registry, BASE + gripper, ScriptedPolicy(hold()))
    assert run.result.status == "ERROR"
    assert run.result.reason == ("<string>:1: ExecutePolicy: gripper joint 'wrist_3_joint' is inside the joint group "
                                 "'manipulator'; it must be outside it")


def test_warmup_timeout_names_policy_call_timeout(registry):
    run = run_policy(registry, BASE, ScriptedPolicy(hold()), latency=4.0)
    assert run.result.reason == (
        "warming up the policy service '/get_action_chunk' timed out after 3 s "
        "(raise policy_call_timeout, or make the server finish its own warmup before it reports ready)"
    )


# -- malformed chunks ----------------------------------------------------------------------
def _bad_chunk(mutate: Callable[[Any], None]) -> Callable[[int, Any], Any]:
    def answer(i, request):
        response = hold()(i, request)
        if i == 2:
            mutate(response)
        return response

    return answer


def _nan(response):
    response.chunk.points[3].positions[1] = float("nan")


def _short_row(response):
    response.chunk.points[0].positions = response.chunk.points[0].positions[:5]


def _swapped(response):
    names = list(response.chunk.joint_names)
    names[0], names[1] = names[1], names[0]
    response.chunk.joint_names = names


@pytest.mark.parametrize(
    "mutate, reason",
    [
        (_nan, "chunk 2 rejected: step 3 joint 'shoulder_lift_joint' is not finite (nan)"),
        (_short_row, "chunk 2 rejected: step 0 has 5 positions for 6 joint names"),
        (_swapped, "chunk 2 rejected: joint names do not match the joint group"),
    ],
)
def test_malformed_chunk_is_rejected_and_the_robot_stops(registry, mutate, reason):
    run = run_policy(registry, BASE, ScriptedPolicy(_bad_chunk(mutate)))
    assert run.result.status == "FAILURE"
    assert run.result.reason.startswith(reason)
    assert run.result.blackboard["rejection"] == run.result.reason
    assert run.summary["rejections"] == 1


def test_chunk_naming_another_gripper_joint_is_rejected(registry):
    def answer(i, request):
        response = hold()(i, request)
        response.chunk.joint_names = list(ARM_JOINTS) + ["finger_joint"]
        return response

    run = run_policy(registry, f"{BASE} {GRIPPER_PORTS}", ScriptedPolicy(answer))
    assert run.result.reason == (
        f"chunk 1 rejected: chunk names two gripper joints: the configured gripper joint is '{GRIPPER}', "
        "the chunk's extra joint is 'finger_joint'"
    )


def test_missing_gripper_joint_in_joint_states_fails_at_the_first_observation(registry):
    run = run_policy(registry, f'{BASE} gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd" gripper_joint_name="gripper_right_driver_joint"', ScriptedPolicy(hold()))
    assert run.result.status == "ERROR"
    assert run.result.reason == (
        "<string>:1: ExecutePolicy: the joint states on '/joint_states' do not include the gripper joint "
        "'gripper_right_driver_joint': it must be published alongside the arm joints"
    )


# -- the gripper column and the gripper's answers --------------------------------------------
def with_gripper_column(column: list[float], velocity: np.ndarray | None = None) -> Callable[[int, Any], Any]:
    """``hold`` chunks whose gripper column is ``column``, repeated to the chunk's length."""

    def answer(index: int, request: Any) -> Any:
        response = hold(velocity=velocity)(index, request)
        at = list(response.chunk.joint_names).index(GRIPPER)
        for k, point in enumerate(response.chunk.points):
            point.positions[at] = column[k % len(column)]
        return response

    return answer


def with_gripper(value: float, velocity: np.ndarray | None = None) -> Callable[[int, Any], Any]:
    """``hold`` chunks whose gripper column is ``value`` at every step."""
    return with_gripper_column([value], velocity)


def run_recording_gripper_goals(registry: Registry, answer: Callable[[int, Any], Any]) -> tuple[Run, list[float]]:
    """``run_policy`` with the gripper ports, and every goal the gripper controller received."""
    goals: list[float] = []
    hook = record_gripper_goals(goals)
    try:
        return run_policy(registry, f"{BASE} {GRIPPER_PORTS}", ScriptedPolicy(answer), before=hook), goals
    finally:
        hook.restore()


def record_gripper_goals(goals: list[float]) -> Callable[[Any, KinematicWorld], None]:
    """A ``before`` hook: every GripperCommand goal the gripper controller receives is recorded."""
    import sim.controllers.gripper as gripper_module

    original = gripper_module.GripperActionController._on_goal

    def recording(self, handle):
        goals.append(float(handle.request.command.position))
        return original(self, handle)

    def hook(context: Any, world: KinematicWorld) -> None:
        gripper_module.GripperActionController._on_goal = recording

    hook.restore = lambda: setattr(gripper_module.GripperActionController, "_on_goal", original)  # type: ignore[attr-defined]
    return hook


def test_a_gripper_column_100_times_too_large_is_rejected_like_an_arm_joint(registry):
    """A policy whose gripper values are 100x too large: the column is checked against the
    gripper joint's limits (0..0.8 rad) before anything is sent, and the chunk is rejected naming
    the step, the joint and the value."""
    run, goals = run_recording_gripper_goals(registry, with_gripper(0.6 * 100))
    assert run.result.status == "FAILURE"
    assert run.result.reason == (
        f"chunk 1 rejected: step 0: joint {GRIPPER} position 60.0000 rad exceeds the limit 0.8000 rad (policy step 1 of the run)"
    )
    assert run.result.blackboard["rejection"] == run.result.reason and run.summary["rejections"] == 1
    assert goals == [] and run.world.cell.gripper == 0.0  # nothing reached the gripper


@pytest.mark.parametrize("sent, expected", [(-0.0002, 0.0), (-0.0564, 0.0), (-0.08, 0.0), (0.8799, 0.8)])
def test_a_gripper_target_a_little_outside_the_limits_is_clamped_counted_and_warned_once(registry, sent, expected):
    """A learned policy's "open" comes out as -0.0002 rad (LeRobot's SmolVLA) or -0.0564 rad (a
    regression head trained again): within 10 % of the gripper's range (0.08 rad) it is the
    limit, that is what the gripper is sent, every such value is counted and the run warns once."""
    run, goals = run_recording_gripper_goals(registry, with_gripper(sent))
    assert run.result.status == "SUCCESS", run.result.reason
    assert run.summary["rejections"] == 0 and set(goals) <= {expected}
    assert run.summary["gripper_clamped"] == 3 * 50  # three chunks of 50 steps
    warned = [w for w in run.summary["warnings"] if "gripper column" in w]
    assert warned == [
        f"the policy's gripper column leaves the range 0.0000..0.8000 rad by up to {abs(sent - expected):.4f} rad (within the "
        "0.0800 rad band): such values are clamped into the range and counted (gripper_clamped); further out a chunk is rejected"
    ]


def test_a_gripper_target_at_the_limit_but_for_rounding_is_sent_at_the_limit_without_a_word(registry):
    """0.8 computed with rounding (a scripted policy's closed gripper) is the limit: clamped, not
    counted and not warned about (``safety.GRIPPER_ROUNDING_RAD``)."""
    run, goals = run_recording_gripper_goals(registry, with_gripper(0.8 + 2e-16 * 8))
    assert run.result.status == "SUCCESS", run.result.reason
    assert set(goals) <= {0.8} and run.summary["gripper_clamped"] == 0
    assert [w for w in run.summary["warnings"] if "gripper column" in w] == []


def test_a_gripper_target_beyond_the_band_is_rejected(registry):
    run = run_policy(registry, f"{BASE} {GRIPPER_PORTS}", ScriptedPolicy(with_gripper(-0.0801)))
    assert run.result.status == "FAILURE"
    assert run.result.reason == (
        f"chunk 1 rejected: step 0: joint {GRIPPER} position -0.0801 rad below the limit 0.0000 rad (policy step 1 of the run)"
    )
    assert run.summary["gripper_clamped"] == 0


@pytest.mark.parametrize("column, expected", [
    # open and closed every 0.1 s: 8 rad/s against the 2 rad/s of joint_limits.yaml
    ([0.0, 0.8], "step 1: joint {g} velocity 8.0000 rad/s exceeds the limit 2.0000 rad/s (policy step 2 of the run)"),
    # 1.5 rad/s one way, then the other: 30 rad/s^2 against 20
    ([0.0, 0.15], "step 2: joint {g} acceleration -30.0000 rad/s^2 exceeds the limit -20.0000 rad/s^2 (policy step 3 of the run)"),
])
def test_a_gripper_column_faster_than_the_gripper_limits_is_rejected(registry, column, expected):
    run, goals = run_recording_gripper_goals(registry, with_gripper_column(column))
    assert run.result.status == "FAILURE"
    assert run.result.reason == "chunk 1 rejected: " + expected.format(g=GRIPPER)
    assert goals == []  # nothing reached the gripper


def test_a_gripper_goal_the_controller_refuses_fails_the_run_with_the_reason(registry, monkeypatch):
    """A controller whose range is narrower than the model's refuses 0.7 rad: the refusal is
    read and ends the run."""
    import sim.controllers.gripper as gripper_module

    original = gripper_module.GripperActionController._on_goal
    monkeypatch.setattr(gripper_module.GripperActionController, "_on_goal",
                        lambda self, handle: False if handle.request.command.position > 0.5 else original(self, handle))
    run = run_policy(registry, f"{BASE} {GRIPPER_PORTS}", ScriptedPolicy(with_gripper(0.7, velocity=np.array([0.1, 0, 0, 0, 0, 0]))))
    assert run.result.status == "FAILURE"
    assert run.result.reason == "the gripper controller '/robotiq_gripper_controller/gripper_cmd' refused the goal to 0.7000 rad"
    assert run.result.sim_seconds < 1.5  # at the first gripper goal, not at the end of the run


def test_a_gripper_controller_switched_off_before_the_node_is_a_setup_error_before_the_first_tick(registry):
    switch = ('<SwitchController activate_controllers="joint_trajectory_admittance_controller" '
              'deactivate_controllers="velocity_force_controller;robotiq_gripper_controller"/>{node}')
    run = run_policy(registry, f"{BASE} {GRIPPER_PORTS}", ScriptedPolicy(with_gripper(0.4)), prepare=False, wrap=switch)
    assert (run.result.status, run.result.ticks) == ("ERROR", 0)
    assert "port 'gripper_command_action_name': action '/robotiq_gripper_controller/gripper_cmd' is served by controller " \
           "'robotiq_gripper_controller', which is not active when this node runs" in run.result.reason


def test_a_gripper_goal_aborted_by_an_inactive_controller_fails_the_run(registry):
    """The gripper controller was switched off (by names known only when the switch runs): it
    accepts and aborts every goal without moving, and the run notices."""
    switch = ("<Script code=\"off := 'velocity_force_controller;robotiq_gripper_controller'\"/>"
              '<SwitchController activate_controllers="joint_trajectory_admittance_controller" '
              'deactivate_controllers="{{off}}"/>{node}')
    run = run_policy(registry, f"{BASE} {GRIPPER_PORTS}", ScriptedPolicy(with_gripper(0.4)), prepare=False, wrap=switch)
    assert run.result.status == "FAILURE"
    assert run.result.reason == (
        "the gripper controller '/robotiq_gripper_controller/gripper_cmd' aborted the goal to 0.4000 rad "
        "with the fingers at 0.0000 rad, not stalled on an object"
    )


def test_a_grasp_that_stalls_on_a_cube_is_normal(registry, monkeypatch):
    """The oracle closes the gripper on the cube: that goal ends stalled, short of its target,
    and the run goes on to the stack (every gripper result is read; a stall fails nothing)."""
    import sim.controllers.gripper as gripper_module

    original = gripper_module.GripperActionController._result
    stalled: list[float] = []

    def result(self, reached=False, stalled_now=False, effort=0.0, **kw):
        value = original(self, reached, kw.get("stalled", stalled_now), effort)
        if value.stalled:
            stalled.append(value.position)
        return value

    monkeypatch.setattr(gripper_module.GripperActionController, "_result", result)
    ports = (f'total_action_steps="300" dt="0.1" committed_action_steps="20" goal_path_tolerance="0.3" '
             f'policy_call_timeout="3.0" prompt="stack the blue cube on the green cube" {GRIPPER_PORTS}')
    allow = '<SetCollisionRule object_name="*" link_names="gripper" allow="true"/>{node}'
    run = run_policy(registry, ports, None, seed=3, wrap=allow)
    assert run.result.status == "SUCCESS", run.result.reason
    assert run.summary["steps_executed"] == 300
    assert len(stalled) == 1 and 0.1 < stalled[0] < 0.8  # closed on the cube, short of 0.8 rad


# -- safety --------------------------------------------------------------------------------
def test_dt_mismatch_doubles_velocity_and_the_chunk_is_rejected_before_moving(registry):
    fast = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.8])  # rad/s at the policy's 10 Hz
    policy = ScriptedPolicy(hold(velocity=fast))
    run = run_policy(registry, BASE.replace('dt="0.1"', 'dt="0.05"'), policy)
    assert run.result.status == "FAILURE"
    assert "chunk 1 rejected: densified step" in run.result.reason
    # Blending from rest into 3.6 rad/s trips the acceleration limit first: the guide's case
    # "every chunk rejected for a velocity or acceleration limit: check dt first".
    assert re.search(r"joint wrist_3_joint (velocity \S+ rad/s exceeds the limit 3.1416|acceleration \S+ rad/s\^2 exceeds the limit 5.0000)", run.result.reason)
    assert any("trained at 0.1 s per step but dt is 0.05 s" in w for w in run.summary["warnings"])
    # Nothing moved: the rejected chunk never reached the controller.
    start = np.array([run.world.waypoints["Ready"][j] for j in ARM_JOINTS])
    assert np.allclose(run.world.cell.arm, start, atol=1e-9)


def without_envelope(context: Any, world: KinematicWorld) -> None:
    """A ``run_policy`` hook: the cell's scene without its Cartesian envelope (a test of another check)."""
    start = world.start

    def start_without_envelope(run_context: Any) -> None:
        start(run_context)
        run_context.scene.envelope = None

    world.start = start_without_envelope


def test_chunk_into_the_table_is_rejected_for_padding(registry):
    down = np.array([0.0, 0.6, 0.0, 0.0, 0.0, 0.0])  # shoulder_lift: the arm sweeps down to the table
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=down)), before=without_envelope)  # its keep-in box refuses it first
    assert run.result.status == "FAILURE"
    assert "world collision" in run.result.reason and "vs table" in run.result.reason
    assert run.result.reason.startswith("chunk 1 rejected: densified step")


def box_appears_ahead(turn: np.ndarray) -> Callable[[Any, KinematicWorld], None]:
    """A ``run_policy`` hook: one second in, a box appears in the planning scene where the
    gripper will be 0.5 s later on a motion turning the joints at ``turn`` rad/s."""

    def drop_a_box_at_one_second(context, world):
        step_to = world.step_to

        def step(t):
            step_to(t)
            if t >= 1.0 and "intruder" not in context.scene.objects:
                q = world.cell.arm + turn * 0.5
                tip = context.scene.link_pose(np.append(q, world.cell.gripper), "gripper_base")
                context.scene.add_object("intruder", Box((0.12, 0.12, 0.12)), pose_matrix(tip[:3, 3]))

        world.step_to = step

    return drop_a_box_at_one_second


def test_object_appearing_in_the_remaining_path_stops_the_robot(registry):
    turn = np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=turn)), before=box_appears_ahead(turn))
    assert run.result.status == "FAILURE"
    assert run.result.reason.startswith("the planning scene changed:")
    assert "intruder" in run.result.reason and run.result.reason.endswith("in the remaining path; robot stopped")
    assert run.result.sim_seconds == pytest.approx(1.0, abs=0.06)  # the scene is watched every 50 ms


def test_force_torque_spike_aborts_with_the_controller_reason(registry):
    def spike(context, world):
        def answer(i, request):
            if i == 2:
                world.cell.external_wrench = np.array([0.0, 0.0, 80.0, 0.0, 0.0, 0.0])
            return hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))(i, request)

        policy.answer = answer

    policy = ScriptedPolicy(hold())
    run = run_policy(registry, BASE, policy, before=spike)
    assert run.result.status == "FAILURE"
    assert run.result.reason.startswith("the controller aborted the motion:")
    assert "Fz" in run.result.reason and "45" in run.result.reason


# -- streaming ------------------------------------------------------------------------------
def _record_commands(world: KinematicWorld) -> list[tuple[float, np.ndarray]]:
    log: list[tuple[float, np.ndarray]] = []
    original = world.cell.command_arm

    def command_arm(position, velocity=None):
        log.append((world.cell.t, np.array(position, dtype=float)))
        original(position, velocity)

    world.cell.command_arm = command_arm  # type: ignore[method-assign]
    return log


def test_streamed_motion_has_no_velocity_jump_at_any_seam(registry):
    holder: dict[str, Any] = {}

    def install(context, world):
        holder["log"] = _record_commands(world)

    def wave(i, request):
        start = np.array(request.robot_state.position)
        rows = start + np.outer(np.sin(np.arange(50) * 0.15 + i), [0.05, 0.04, -0.03, 0.05, 0.05, 0.1])
        return chunk_response(list(request.robot_state.name), rows)

    run = run_policy(registry, BASE, ScriptedPolicy(wave), before=install)
    assert run.result.status == "SUCCESS", run.result.reason
    last_per_step = {t: p for t, p in holder["log"]}  # a controller switch may command twice in a step
    times = np.array(sorted(last_per_step))
    q = np.array([last_per_step[t] for t in times])
    v = np.diff(q, axis=0) / np.diff(times)[:, None]
    dv = np.abs(np.diff(v, axis=0))
    # 5 rad/s^2 is the acceleration limit: over one 2 ms control step velocity changes < 0.011 rad/s.
    assert dv.max() < 0.011, dv.max()
    assert np.abs(v[-1]).max() < 1e-6  # the last window ends at rest
    seams = [e.data["seam_time"] for e in run.context.events.of_kind("chunk_executed")]
    assert len(seams) == 3


def test_rtc_sends_the_unexecuted_tail_from_the_request_instant(registry):
    def answer(i, request):
        response = hold()(i, request)
        policy_rows = np.array([[1000.0 * i + k, -k] for k in range(50)])
        return chunk_response(list(request.robot_state.name), np.array([list(p.positions) for p in response.chunk.points]), policy_rows=policy_rows)

    ports = f'{BASE} policy_uses_real_time_chunking="true" guidance_horizon="7"'
    run = run_policy(registry, ports, ScriptedPolicy(answer), latency=0.25)
    assert run.result.status == "SUCCESS", run.result.reason
    warmup, first, second, third = run.policy.requests
    assert len(first.previous_action_chunk.data) == 0  # a new episode carries nothing over
    frozen = second.frozen_prefix_steps
    # Latency 0.25 s is measured on the 10 ms tick grid; frozen = ceil((0.25 + 2 ticks + 10%) / 0.1).
    assert frozen == 3
    tail = np.array(second.previous_action_chunk.data).reshape(-1, 2)
    # Chunk 1 found the arm at rest, so its step 0 is played at its seam (run step 3). Chunk 2 is
    # requested 3 steps before the next seam (3 + 20): at run step 20, which is chunk 1's step 17.
    assert tail[0, 0] == 1000.0 * 1 + 17 and len(tail) == 33
    assert second.previous_action_chunk.layout.data_offset == 0
    assert [d.label for d in second.previous_action_chunk.layout.dim] == ["step", "action"]
    assert list(second.previous_anchor_state.position) == list(first.robot_state.position)
    assert second.guidance_horizon == 7 and third.frozen_prefix_steps == frozen


def test_rtc_off_sends_no_carryover(registry):
    def answer(i, request):
        return chunk_response(list(request.robot_state.name), np.tile(request.robot_state.position, (50, 1)), policy_rows=np.ones((50, 2)))

    run = run_policy(registry, BASE, ScriptedPolicy(answer))
    assert run.result.status == "SUCCESS", run.result.reason
    assert len(run.policy.requests) == 4  # the warmup, then one request per 20-step window of the 60 steps
    assert [len(r.previous_action_chunk.data) for r in run.policy.requests] == [0, 0, 0, 0]
    assert [len(r.previous_anchor_state.position) for r in run.policy.requests] == [0, 0, 0, 0]


@pytest.mark.parametrize("latency", [0.0, 0.3, 0.6, 0.95])
def test_no_stalls_while_latency_is_within_half_the_committed_window(registry, latency):
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=latency)
    assert run.result.status == "SUCCESS", run.result.reason
    assert run.summary["stall_seconds"] == 0.0


def test_latency_beyond_the_window_keeps_the_arm_moving_and_warns(registry):
    # Each chunk can only be asked for once the previous one arrived, 2.5 s later: longer than the
    # 2 s window. Between windows the arm plays the chunk's steps beyond its window at the
    # policy's pace, and chunk 2 is asked for so that it lands as chunk 1's tail would start
    # slowing down: it never does (a runout at each window's end would cost 1.0 s of stall). The
    # guide's sizing rule still warns.
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=2.5)
    assert run.result.status == "SUCCESS", run.result.reason
    assert run.summary["stall_seconds"] == 0.0
    assert run.summary["steps_executed"] == 60 and run.summary["chunks"] == 2
    assert any("is below twice the measured latency 2.500 s" in w for w in run.summary["warnings"])


def test_heavy_tailed_latency_warns_once_during_the_run_with_the_figures(registry):
    """The warmup is fast (0.2 s) and so is the first chunk; then the policy slows to 1.2-1.3 s,
    more than half the committed window (1.9 s). The sizing rule is checked at every answer, not
    only at the warmup, so heavy-tailed latency warns, once, naming the estimate and how it was
    made."""
    from runtime.io.bus import TraceLatency

    run = run_policy(registry, BASE, ScriptedPolicy(hold()), latency=TraceLatency([0.2, 0.2, 1.2, 1.3, 0.2]))
    assert run.result.status == "SUCCESS", run.result.reason
    assert [w for w in run.summary["warnings"] if "below twice" in w] == [
        "(committed_action_steps - 1) * dt = 1.900 s is below twice the latency estimate 1.200 s (the 90th percentile "
        "of the last 3 round trips): chunks land after their committed window ends; the arm goes on along the chunk's "
        "steps beyond the window meanwhile, and pauses only once the latency passes about 2.500 s, half the 50-step "
        "chunk (committed_action_steps = 25 would cover it)"
    ]
    assert run.summary["stall_seconds"] == 0.0  # as the warning says


def test_a_latency_that_outgrows_the_chunk_s_tail_too_warns_a_second_time(registry):
    # As above, then one call takes 2.8 s: more than half the 50-step chunk (2.5 s), which the
    # arm plays beyond each window while it waits. The warning about pauses follows the first.
    from runtime.io.bus import TraceLatency

    run = run_policy(registry, BASE, ScriptedPolicy(hold()), latency=TraceLatency([0.2, 0.2, 1.2, 2.8, 0.2]))
    assert run.result.status == "SUCCESS", run.result.reason
    sizing = [w for w in run.summary["warnings"] if "below twice" in w]
    assert len(sizing) == 2 and "pauses only once the latency passes about 2.500 s" in sizing[0]
    assert sizing[1] == (
        "(committed_action_steps - 1) * dt = 1.900 s is below twice the latency estimate 2.800 s (the 90th percentile "
        "of the last 4 round trips) and longer than half the 50-step chunk (2.500 s): expect pauses at chunk boundaries "
        "(covering it would take committed_action_steps = 57, not below the chunk's 50 steps: a faster policy or longer chunks)"
    )


def test_committed_window_not_smaller_than_the_chunk_fails_at_the_first_chunk(registry):
    """The guide: committed_action_steps must be smaller than the policy's chunk size; a run
    that breaks the rule fails, it does not only warn."""
    run = run_policy(registry, BASE, ScriptedPolicy(hold(steps=20, velocity=np.array([0.1, 0, 0, 0, 0, 0]))))
    assert run.result.status == "FAILURE"
    assert run.result.reason == (
        "chunk 1 rejected: committed_action_steps (20) must be smaller than the policy's chunk size (20 steps): "
        "set committed_action_steps to at most 19"
    )
    assert run.summary["rejections"] == 1 and run.summary["chunks"] == 1
    start = np.array([run.world.waypoints["Ready"][j] for j in ARM_JOINTS])
    assert np.allclose(run.world.cell.arm, start, atol=1e-9)  # nothing moved


class SpikeAt:
    """Fixed latency, with one call (by index) slower."""

    def __init__(self, base: float, spike_index: int, spike: float) -> None:
        self.base, self.spike_index, self.spike, self.calls = base, spike_index, spike, 0

    def delay(self, measured_wall_s: float) -> float:
        self.calls += 1
        return self.spike if self.calls - 1 == self.spike_index else self.base


def test_chunk_arriving_just_after_the_window_ends_joins_its_tail_without_a_pause(registry):
    # Chunk 2 is requested one step before the committed window ends and arrives 5 ms before that
    # end: too late to take over there. It joins the motion still playing, chunk 1's steps beyond
    # its window (the tail), one step later: no pause, and every step is counted.
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=SpikeAt(0.05, 2, 0.095))
    assert run.result.status == "SUCCESS", run.result.reason
    assert run.summary["stall_seconds"] == 0.0
    assert run.summary["steps_executed"] == 60


def record_commanded_velocity(commanded: list[tuple[float, float]]) -> Callable[[Any, KinematicWorld], None]:
    """A ``before`` hook: every arm command appends (time, the first joint's commanded velocity)."""

    def hook(context: Any, world: KinematicWorld) -> None:
        command = world.cell.command_arm

        def recording(position, velocity=None):
            commanded.append((world.cell.t, 0.0 if velocity is None else float(velocity[0])))
            command(position, velocity)

        world.cell.command_arm = recording

    return hook


def refuse_as_late(monkeypatch, goal_number: int) -> list[float]:
    """The controller refuses its ``goal_number``-th trajectory goal (1-based) as if it arrived
    3 ms after its seam. Returns the arrival times of the goals, one per goal so far."""
    import sim.controllers.admittance as admittance

    parse, arrivals = admittance.parse_goal, []

    def delivered_late(request, joint_names, now, *args):
        goal = parse(request, joint_names, now, *args)
        arrivals.append(now)
        return dataclasses.replace(goal, seam_time=now - 0.003) if len(arrivals) == goal_number else goal

    monkeypatch.setattr(admittance, "parse_goal", delivered_late)
    return arrivals


def answer_late(monkeypatch, delay: float, which: Callable[[Any], bool]) -> None:
    """Action goals sent by a client for which ``which(client)`` holds (asked after the goal
    reached its server) are answered ``delay`` seconds later (``inf``: never)."""
    send = bus_module._InProcessActionClient.send_goal_async

    def slow(self, goal, feedback_callback=None):
        future = send(self, goal, feedback_callback)
        if not which(self):
            return future
        delayed = bus_module.Future(self.bus.clock, self.bus.clock.now() + delay)
        delayed.set_result(future.result())
        return delayed

    monkeypatch.setattr(bus_module._InProcessActionClient, "send_goal_async", slow)


@pytest.mark.parametrize("latency_s", [0.45, 0.5])
def test_a_first_chunk_is_played_from_its_step_0_at_the_first_step_at_or_after_it_arrives(registry, latency_s):
    # Chunk 1 is asked for at run step 0 and arrives 0.45 or 0.5 s later: either way its window
    # starts at step 5, the first step at or after the arrival, with the chunk's step 0 there (the
    # arm has rested there since the request), as both baselines of bench_streaming play a first
    # chunk. Arriving on the step itself, its goal cannot reach the controller before the next
    # tick (one tick plus twice the delivery time): it takes over then, within the step, and the
    # arm moves from the next control step on, not a whole step later.
    commanded: list[tuple[float, float]] = []
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=latency_s,
                     before=record_commanded_velocity(commanded))
    assert run.result.status == "SUCCESS", run.result.reason
    origin = run.context.events.of_kind("chunk_requested")[1].time  # the first real request (run step 0)
    first = run.context.events.of_kind("chunk_executed")[0].data
    assert (first["request_step"], first["seam_step"]) == (5, 5)
    assert first["seam_time"] == pytest.approx(origin + 0.5)
    takes_over = origin + (0.51 if latency_s == 0.5 else 0.5)
    assert first["takes_over_time"] == pytest.approx(takes_over)
    t, v = np.array(commanded).T
    assert np.abs(v[t <= takes_over + 1e-9]).max() < 1e-12  # at rest until the goal takes over
    assert t[t > takes_over + 1e-9][0] == pytest.approx(takes_over + 0.002) and v[t > takes_over + 1e-9][0] > 1e-6


def test_a_chunk_that_finds_the_arm_at_rest_starts_at_its_arrival_step_and_the_next_request_goes_out_then(registry):
    # Chunk 2 takes 8 s: chunk 1 (50 steps at 0.1 rad/s) has run out and the arm rests when it
    # lands, exactly on a step. As a first chunk does, its window starts at that step and its
    # goal takes over one tick later, within the step (not at the next step: 0.1 s more standing
    # still), and chunk 3 is asked for in the same tick.
    commanded: list[tuple[float, float]] = []
    ports = BASE.replace('policy_call_timeout="3.0"', 'policy_call_timeout="10.0"').replace('total_action_steps="60"', 'total_action_steps="100"')
    run = run_policy(registry, ports, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=SpikeAt(0.05, 2, 8.0),
                     before=record_commanded_velocity(commanded))
    assert run.result.status == "SUCCESS", run.result.reason
    requests = run.context.events.of_kind("chunk_requested")
    executed = run.context.events.of_kind("chunk_executed")
    arrival = requests[2].time + 8.0  # chunk 2's request (requests[0] is the warmup)
    second = executed[1].data
    assert second["seam_time"] == pytest.approx(arrival)
    assert second["takes_over_time"] == pytest.approx(arrival + 0.01)
    assert executed[1].time == pytest.approx(arrival) and requests[3].time == pytest.approx(arrival)
    t, v = np.array(commanded).T
    waiting = (t > arrival - 1.0) & (t <= arrival + 0.01 + 1e-9)
    assert np.abs(v[waiting]).max() < 1e-12  # at rest until the goal takes over
    assert v[t > arrival + 0.01 + 1e-9][0] > 1e-6


def test_a_one_step_run_whose_chunk_lands_on_a_step_is_started_at_the_next_step_when_the_arrival_step_is_too_short(registry):
    # total_action_steps = 1: the chunk's one step is played and the arm brought to rest at it.
    # Landing on a step, started there, the goal would take over 10 ms into the step and leave
    # 90 ms for the move from rest and back to rest: at 0.1 rad/s that is over the acceleration
    # limit. The planner then starts the window at the next step, with the whole step for it.
    ports = BASE.replace('total_action_steps="60"', 'total_action_steps="1"')
    run = run_policy(registry, ports, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=0.5)
    assert run.result.status == "SUCCESS", run.result.reason
    origin = run.context.events.of_kind("chunk_requested")[1].time
    first = run.context.events.of_kind("chunk_executed")[0].data
    assert (first["seam_time"], first["takes_over_time"]) == (pytest.approx(origin + 0.6), pytest.approx(origin + 0.6))
    assert run.summary["steps_executed"] == 1


def test_a_first_chunk_s_rejection_names_the_run_step_its_value_would_be_played_at(registry):
    # Chunk 1 arrives on step 5 and is played from its step 0 there, so its step 3 belongs to run
    # step 8: the rejection says so (policy step N of the run: the step the value is played at).
    def far_at_step_3(index: int, request: Any) -> Any:
        response = hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))(index, request)
        if index == 1:
            point = response.chunk.points[3]
            point.positions = [1000.0, *list(point.positions)[1:]]
        return response

    run = run_policy(registry, BASE, ScriptedPolicy(far_at_step_3), latency=0.5)
    assert run.result.status == "FAILURE"
    assert run.result.reason == ("chunk 1 rejected: step 3: joint shoulder_pan_joint position 1000.0000 rad exceeds the limit "
                                 "6.2832 rad (policy step 8 of the run)")


def test_a_chunk_later_than_the_window_keeps_the_arm_at_the_policy_s_pace_along_the_chunk(registry):
    # Chunk 2 is asked for one step before chunk 1's 2 s window ends and takes 2.0 s: it arrives
    # 1.9 s after that end, later than a whole window but well within chunk 1 (5 s). Meanwhile the
    # arm goes on along chunk 1's own steps beyond its window at full speed (0.1 rad/s, the
    # policy's pace), and chunk 2 takes over from that moving state where the arm is: the
    # commanded velocity never jumps, never slows, and no time is lost standing still (a runout at
    # the window's end would bring the arm to rest within 1 s and keep it still for 0.9 s).
    commanded: list[tuple[float, float]] = []
    velocity = np.array([0.1, 0, 0, 0, 0, 0])
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=velocity)), latency=SpikeAt(0.05, 2, 2.0),
                     before=record_commanded_velocity(commanded))
    assert run.result.status == "SUCCESS", run.result.reason
    assert run.summary["stall_seconds"] == 0.0
    executed = [e.data for e in run.context.events.of_kind("chunk_executed")]
    first, late = executed
    window_end = first["seam_time"] + first["steps"] * 0.1
    assert late["seam_time"] - window_end == pytest.approx(2.0)  # later than the 2 s window
    # Played from the chunk step the clock says: the arm kept the chunk's pace while it waited.
    assert late["request_step"] == 20
    assert run.summary["steps_executed"] == 60 and run.summary["chunks"] == 2  # the tail's steps count
    t, v = np.array(commanded).T
    between = (t > first["seam_time"] + 1.0) & (t < late["seam_time"] + 1.0)
    assert np.allclose(v[between], 0.1, atol=1e-3)  # full speed through the window's end and the seam
    assert np.max(np.abs(np.diff(v))) < 0.002  # rad/s per 2 ms control step: no jump anywhere


def test_a_chunk_that_never_comes_leaves_the_arm_at_rest_at_the_last_chunk_s_end(registry, monkeypatch):
    # Chunk 2 never comes (the policy hangs until policy_call_timeout, 10 s). The arm plays chunk
    # 1's window, then its steps beyond the window, and slows to rest at its last step (49 steps
    # of 0.01 rad from the start); the run then fails on the timeout. Every point the controller
    # received was one the checks (limits and collision) had passed.
    import sim.controllers.admittance as admittance
    from behaviors.execute_policy.checks import PointChecks

    checked: list[np.ndarray] = []
    check_path = PointChecks.path

    def recording_path(self, samples, window):
        reason = check_path(self, samples, window)
        if reason is None:
            checked.append(samples.positions)
        return reason

    received: list[np.ndarray] = []
    parse = admittance.parse_goal

    def recording_parse(request, *args):
        received.append(np.array([p.positions for p in request.joint_trajectory.points]))
        return parse(request, *args)

    monkeypatch.setattr(PointChecks, "path", recording_path)
    monkeypatch.setattr(admittance, "parse_goal", recording_parse)
    ports = BASE.replace('policy_call_timeout="3.0"', 'policy_call_timeout="10.0"')
    run = run_policy(registry, ports, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))),
                     latency=SpikeAt(0.05, 2, 30.0), max_seconds=30.0)
    assert run.result.status == "FAILURE"
    assert run.result.reason == "the policy service '/get_action_chunk' did not answer within policy_call_timeout = 10 s"
    start = np.array([run.world.waypoints["Ready"][j] for j in ARM_JOINTS])
    assert np.allclose(run.world.cell.arm - start, [0.49, 0, 0, 0, 0, 0], atol=1e-6)
    assert np.allclose(run.world.cell.arm_velocity_now, 0.0, atol=1e-9)
    assert run.summary["steps_executed"] == 49  # the window's 20 and the 29 beyond it
    assert len(received) == 1 and any(np.array_equal(goal, received[0]) for goal in checked)


def test_a_goal_that_reaches_the_controller_after_its_seam_while_moving_is_planned_again(registry, monkeypatch):
    # Chunk 3's goal reaches the controller 3 ms after its seam (a busy transport): the controller
    # refuses it and goes on with chunk 2's window and runout. ExecutePolicy plans chunk 3 again
    # from that moving state instead of failing the run, and the arm never stops dead.
    refuse_as_late(monkeypatch, 3)
    commanded: list[tuple[float, float]] = []
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=0.05,
                     before=record_commanded_velocity(commanded))
    assert run.result.status == "SUCCESS", run.result.reason
    assert run.summary["steps_executed"] == 60
    (late,) = [w for w in run.summary["warnings"] if "reached the controller" in w]
    assert re.fullmatch(r"chunk 3's goal reached the controller after t=\d+\.\d\d s, the moment it was meant to take "
                        r"over, so the controller went on with what it was playing; the chunk is planned again from "
                        r"what the arm is doing \(goals are now given 50 ms more to reach the controller\)", late), late
    t, v = np.array(commanded).T
    assert np.max(np.abs(np.diff(v))) < 0.002  # rad/s per control step: no dead stop, no jump


def test_goals_late_by_a_robot_clock_running_ahead_get_more_time_to_arrive_until_they_land(registry, monkeypatch):
    # From goal 2 on, the controller's clock runs 0.25 s ahead of the runtime's (a robot in its own
    # process, the runtime on its /clock): every seam planned with the measured delivery time is
    # already past when the goal lands. Each late refusal gives goals more time (50, 100, 200 ms):
    # the third retry lands, and the rest of the run keeps the 200 ms it learned.
    import sim.controllers.admittance as admittance

    parse, goals = admittance.parse_goal, []

    def robot_ahead(request, joint_names, now, *args):
        goal = parse(request, joint_names, now, *args)
        goals.append(goal.seam_time - now)
        return dataclasses.replace(goal, seam_time=goal.seam_time - 0.25) if len(goals) >= 2 else goal

    monkeypatch.setattr(admittance, "parse_goal", robot_ahead)
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=0.05)
    assert run.result.status == "SUCCESS", run.result.reason
    assert run.summary["steps_executed"] == 60
    late = [w for w in run.summary["warnings"] if "reached the controller" in w]
    assert [re.search(r"given (\d+) ms more", w).group(1) for w in late] == ["50", "100", "200"]
    assert min(goals[4:]) > 0.25  # every goal after the retries is planned to land with room to spare


def test_a_run_the_controller_finishes_early_on_its_own_clock_counts_every_step_it_played(registry, monkeypatch):
    # The controller's clock runs 0.35 s ahead of the runtime's: its one goal, a window that
    # comes to rest at its end (no steps beyond it), is over 0.35 s before the runtime's clock
    # gets there. The controller's success says every step was played: the count is the
    # window's, not the part of it the runtime's clock had reached.
    import sim.controllers.admittance as admittance
    from runtime.io.timestamps import time_msg, to_seconds

    parse = admittance.parse_goal

    def robot_ahead(request, joint_names, now, *args):
        stamp = request.joint_trajectory.header.stamp
        request.joint_trajectory.header.stamp = time_msg(to_seconds(stamp) - 0.35)
        return parse(request, joint_names, now, *args)

    monkeypatch.setattr(admittance, "parse_goal", robot_ahead)
    ports = BASE.replace('total_action_steps="60"', 'total_action_steps="10"').replace('committed_action_steps="20"', 'committed_action_steps="10"')
    run = run_policy(registry, ports, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=0.05)
    assert run.result.status == "SUCCESS", run.result.reason
    assert run.summary["message"] == "executed 10 steps"
    assert run.summary["steps_executed"] == 10 and run.result.blackboard["steps"] == 10


def refuse_third_goal_with(monkeypatch, code: int, text: str) -> None:
    """The controller refuses its third trajectory goal with ``code`` and ``text`` (a real
    controller words its refusals its own way), then behaves normally."""
    import sim.controllers.admittance as admittance

    take_over, goals = admittance.JointTrajectoryAdmittanceController._take_over, []

    def refuse(self, goal, now):
        goals.append(now)
        if len(goals) == 3:
            raise admittance.GoalError(code, text)
        return take_over(self, goal, now)

    monkeypatch.setattr(admittance.JointTrajectoryAdmittanceController, "_take_over", refuse)


def test_a_late_goal_planned_again_after_a_stall_counts_the_stall_once(registry, monkeypatch):
    # Chunk 2 takes 8 s: chunk 1's window (2 s) and its tail (26 steps at full speed, 2.6 s, then
    # the runout) are over and the arm rests when it lands. Its goal is refused as late and the
    # chunk is planned again from rest. The run's stall is the time from the end of chunk 1's
    # full-speed motion to the seam that was played; the refused plan's stall is not counted.
    arrivals = refuse_as_late(monkeypatch, 2)
    ports = BASE.replace('policy_call_timeout="3.0"', 'policy_call_timeout="10.0"').replace('total_action_steps="60"', 'total_action_steps="100"')
    run = run_policy(registry, ports, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=SpikeAt(0.05, 2, 8.0))
    assert run.result.status == "SUCCESS", run.result.reason
    assert len(arrivals) >= 3 and any("the chunk is planned again from what the arm is doing (goals are now given 50 ms more" in w
                                   for w in run.summary["warnings"])
    executed = [e.data for e in run.context.events.of_kind("chunk_executed")]
    first, refused, played = executed[:3]
    assert refused["chunk"] == played["chunk"] == 2 and played["takes_over_time"] > refused["takes_over_time"]
    full_speed_end = first["seam_time"] + first["steps"] * 0.1 + 2.6
    assert run.summary["stall_seconds"] == pytest.approx(played["seam_time"] - full_speed_end, abs=1e-4)
    assert plotted_stall_s(run) == pytest.approx(run.summary["stall_seconds"], abs=1e-4)  # the refused plan's stall is not drawn


def test_a_late_goal_is_recognised_by_its_result_code_not_its_wording(registry, monkeypatch):
    from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance as Action

    refuse_third_goal_with(monkeypatch, Action.Result.SEAM_AFTER_TRAJECTORY_END, "trajectory already finished")
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=0.05)
    assert run.result.status == "SUCCESS", run.result.reason  # planned again, as for our own controller's words
    assert run.summary["steps_executed"] == 60


def test_a_refusal_worded_like_a_late_goal_but_coded_otherwise_fails_the_run(registry, monkeypatch):
    from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance as Action

    refuse_third_goal_with(monkeypatch, Action.Result.INVALID_GOAL, "seam time exceeds the end of the current trajectory")
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=0.05)
    assert run.result.status == "FAILURE"
    assert "seam time exceeds the end of the current trajectory" in run.result.reason


def test_a_goal_answered_only_after_the_next_chunk_arrived_is_waited_for(registry, monkeypatch):
    # Chunk 1's goal reaches the controller after its seam and is refused, and the answer takes
    # 0.6 s to come back (a first goal over a new ROS connection), longer than the 0.5 s window:
    # chunk 2 arrives first. Stitched onto chunk 1's motion, which the controller never played,
    # its first point would be 25 mrad off the arm ("position deviation at the seam"). It waits
    # for the answer instead, and then takes over from where the arm really is; chunk 1 is dropped.
    arrivals = refuse_as_late(monkeypatch, 1)
    answer_late(monkeypatch, 0.6, lambda client: len(arrivals) == 1)
    ports = 'total_action_steps="20" dt="0.1" committed_action_steps="5" goal_path_tolerance="0.01" policy_call_timeout="3.0"'
    run = run_policy(registry, ports, ScriptedPolicy(hold(velocity=np.array([0.05, 0, 0, 0, 0, 0]))), latency=0.05)
    assert run.result.status == "SUCCESS", run.result.reason
    assert any("the next chunk, already here, is planned from what the arm is doing (goals are now given 50 ms more" in w
               for w in run.summary["warnings"])
    second = [e.data for e in run.context.events.of_kind("chunk_executed") if e.data["chunk"] == 2]
    assert len(second) == 1 and second[0]["request_step"] == second[0]["seam_step"]  # from its step 0: the arm never moved
    assert run.summary["steps_executed"] == 20


def abort_playing_goal_before(monkeypatch, goal_number: int) -> None:
    """The controller aborts the goal it plays (a force spike) just before its ``goal_number``-th
    trajectory goal (1-based) arrives, then handles that goal as usual: from rest."""
    import sim.controllers.admittance as admittance

    controller_class = admittance.JointTrajectoryAdmittanceController
    on_goal, goals = controller_class._on_goal, []

    def aborted_first(self, handle):
        goals.append(handle)
        if len(goals) == goal_number:
            t = self.clock.now()
            self._finish(t, "abort", admittance.Result(
                error_code=admittance.Result.FORCE_TORQUE_THRESHOLD_EXCEEDED,
                error_string=f"force-torque threshold exceeded at t={t:.3f} s: Fx = 50.00 N exceeds 45.00 N"))
        return on_goal(self, handle)

    monkeypatch.setattr(controller_class, "_on_goal", aborted_first)


SETTLE_AFTER = '<ForceSuccess>{node}</ForceSuccess><Wait seconds="1.0"/>'
"""Keeps the cell running a second after ExecutePolicy ends, to see where the arm comes to rest."""


@pytest.mark.parametrize("tolerance", ["0.3", "0.001"])
def test_a_goal_aborted_just_before_the_next_arrives_ends_the_run_with_its_abort(registry, monkeypatch, tolerance):
    # Goal 2 is aborted for a force spike just before goal 3 reaches the controller. With a wide
    # path tolerance the controller then accepts goal 3 from where the arm stopped; with a tight
    # one it refuses it ("position deviation at the seam"). Either way the run ends with the
    # abort that happened first, and the arm comes to rest: goal 3 does not play on.
    abort_playing_goal_before(monkeypatch, 3)
    ports = BASE.replace('goal_path_tolerance="0.3"', f'goal_path_tolerance="{tolerance}"')
    run = run_policy(registry, ports, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=0.05,
                     wrap=SETTLE_AFTER)
    (finished,) = run.context.events.of_kind("policy_finished")
    assert finished.data["status"] == "FAILURE"
    assert re.fullmatch(r"the controller aborted the motion: force-torque threshold exceeded at t=\d+\.\d{3} s: "
                        r"Fx = 50.00 N exceeds 45.00 N", finished.data["message"]), finished.data["message"]
    assert not run.world.controllers["joint_trajectory_admittance_controller"].executing
    assert np.allclose(run.world.cell.arm_velocity_now, 0.0, atol=1e-9)


def test_a_controller_that_never_acknowledges_a_goal_ends_the_run(registry, monkeypatch):
    answer_late(monkeypatch, float("inf"), lambda client: client.name.endswith("follow_joint_trajectory"))
    run = run_policy(registry, BASE, ScriptedPolicy(hold()))
    assert run.result.status == "FAILURE"
    assert run.result.reason == (
        "the controller '/joint_trajectory_admittance_controller/follow_joint_trajectory' did not acknowledge a goal within 5 s"
    )


def test_an_obstacle_on_the_chunk_s_path_beyond_the_window_stops_the_arm_before_it(registry):
    # A box stands where the gripper would be at chunk 1's step 40, beyond its 20-step window,
    # and chunk 2 never comes. The tail (the chunk's steps beyond the window, then the runout)
    # is checked like the window: it is cut short so that the arm comes to rest before the box,
    # never in collision, instead of running on along the chunk to its step 49.
    turn = np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])  # shoulder_pan, 0.03 rad per step
    offsets: dict[str, float] = {}

    def box_at_step_40(context, world):
        step_to = world.step_to

        def step(t):
            step_to(t)
            if "box" not in context.scene.objects:  # before the first chunk
                tip = context.scene.link_pose(np.append(start + turn * 4.0, world.cell.gripper), "gripper_base")
                context.scene.add_object("box", Box((0.12, 0.12, 0.12)), pose_matrix(tip[:3, 3]))
            offsets["max"] = max(offsets.get("max", 0.0), float(world.cell.arm[0] - start[0]))

        world.step_to = step

    start = np.array([KinematicWorld({"policy": "none"}).waypoints["Ready"][j] for j in ARM_JOINTS])
    ports = BASE.replace('policy_call_timeout="3.0"', 'policy_call_timeout="10.0"')
    run = run_policy(registry, ports, ScriptedPolicy(hold(velocity=turn)), latency=SpikeAt(0.05, 2, 30.0),
                     before=box_at_step_40, max_seconds=30.0)
    assert run.result.status == "FAILURE"
    assert run.result.reason == "the policy service '/get_action_chunk' did not answer within policy_call_timeout = 10 s"
    rest = float(run.world.cell.arm[0] - start[0])
    assert np.allclose(run.world.cell.arm_velocity_now, 0.0, atol=1e-9)
    # Further than the window and a 5-step runout (0.75 rad), short of the box.
    assert 0.75 < rest < 1.2 and offsets["max"] == pytest.approx(rest)
    assert rest == pytest.approx(0.03 * round(rest / 0.03), abs=1e-6)  # at rest on one of the chunk's steps


def test_chunk_arriving_early_after_a_spike_joins_at_the_end_of_the_committed_motion(registry):
    # A 2.8 s spike grows the latency estimate past the committed window; the next chunk is asked
    # for with a large frozen prefix but arrives in 0.1 s, and joins without a pause.
    ports = BASE.replace('total_action_steps="60"', 'total_action_steps="100"')
    run = run_policy(registry, ports, ScriptedPolicy(hold(velocity=np.array([0.1, 0, 0, 0, 0, 0]))), latency=SpikeAt(0.1, 2, 2.8))
    assert run.result.status == "SUCCESS", run.result.reason
    executed = [e.data for e in run.context.events.of_kind("chunk_executed")]
    requested = [e.data for e in run.context.events.of_kind("chunk_requested")][1:]  # the warmup's left out
    assert run.summary["steps_executed"] == 100
    first, spiked, early = executed[:3]
    # Chunk 3's frozen prefix would put its seam 31 steps after its request; it takes over where
    # chunk 2's window ends instead, 15 steps sooner.
    assert requested[2]["frozen_prefix_steps"] == 31
    assert early["seam_step"] == spiked["seam_step"] + spiked["steps"] < requested[2]["request_step"] + 31
    # The only pause of the run is the spike's, before chunk 2, and it is short: chunk 1's tail
    # played its 26 steps beyond the window at full speed (2.6 s) and was 0.1 s into its runout.
    pause_before_chunk_2 = spiked["seam_time"] - (first["seam_time"] + first["steps"] * 0.1 + 2.6)
    assert pause_before_chunk_2 == pytest.approx(0.1)
    assert run.summary["stall_seconds"] == pytest.approx(pause_before_chunk_2, abs=1e-4)
    assert plotted_stall_s(run) == pytest.approx(run.summary["stall_seconds"], abs=1e-4)


def test_halt_cancels_the_goal_and_the_robot_stops(registry):
    # The Timeout halts ExecutePolicy at 3 s; the Wait keeps the cell running for a second after.
    wrap = '<ForceSuccess><Timeout msec="3000">{node}</Timeout></ForceSuccess><Wait seconds="1.0"/>'
    run = run_policy(registry, BASE, ScriptedPolicy(hold(velocity=np.array([0.2, 0, 0, 0, 0, 0]))), wrap=wrap)
    assert run.result.status == "SUCCESS"
    assert [e.time for e in run.context.events.of_kind("policy_halted")] == [pytest.approx(3.0, abs=0.05)]
    controller = run.world.controllers["joint_trajectory_admittance_controller"]
    assert not controller.executing
    assert np.allclose(run.world.cell.arm_velocity_now, 0.0, atol=1e-9)


def test_same_seed_same_result(registry):
    a = run_policy(registry, BASE, None, seed=3, latency=0.05)
    b = run_policy(registry, BASE, None, seed=3, latency=0.05)
    assert a.result.status == b.result.status
    assert np.array_equal(a.world.cell.arm, b.world.cell.arm)
    assert a.summary == b.summary


@pytest.mark.parametrize("controller, action", [
    ("joint_trajectory_admittance_controller", ""),
    ("joint_trajectory_controller", 'controller_action_name="/joint_trajectory_controller/follow_joint_trajectory"'),
])
def test_a_trajectory_controller_switched_off_at_run_time_is_a_setup_error_naming_it(registry, controller, action):
    """The names of the switch are known only when it runs, so the check before the first tick
    cannot see it: the goal the inactive controller refuses ends the run as ERROR (a Retry would
    send the same goal to the same controller), naming the controller and what to do."""
    switch = (f"<Script code=\"off := '{controller}'\"/>"
              '<SwitchController deactivate_controllers="{{off}}"/>{node}')
    if controller == "joint_trajectory_controller":  # active first, then switched off by name at run time
        switch = f'<SwitchController activate_controllers="{controller}" automatic_deactivation="true"/>' + switch
    run = run_policy(registry, f"{BASE} {action}", ScriptedPolicy(hold()), wrap=switch, prepare=controller != "joint_trajectory_controller")
    assert run.result.status == "ERROR", run.result.reason
    assert f"the controller '/{controller}/" in run.result.reason
    assert "is the controller active (a SwitchController before this node)" in run.result.reason
    assert run.summary["steps_executed"] == 0

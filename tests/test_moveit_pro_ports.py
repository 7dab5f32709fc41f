"""MoveIt Pro's ports on the behaviors here, with MoveIt Pro's meaning: SwitchController
(timeout -1, activate_asap, automatic_activation, automatic_deactivation), the Move to Waypoint
SubTree (controller_names, controller_action_server, joint_group_name, link_padding, scale
factors, seed) and TransformPose's pose markers."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from controller_manager_msgs.msg import ChainConnection, ControllerState
from controller_manager_msgs.srv import ListControllers, SwitchController as SwitchSrv
from geometry_msgs.msg import PoseStamped
from visualization_msgs.msg import Marker, MarkerArray

from behaviors.controllers import SwitchController, plan_switch
from behaviors.poses import MARKER_TOPIC, TransformPose, matrix_to_pose, pose_markers
from runtime.tree.behavior import Status
from runtime.tree.blackboard import Blackboard
from runtime.errors import SetupError
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, RunResult, run_file
from runtime.motion.scene.collision import pose_matrix
from tests.test_scene_behaviors import make_context, make_node, make_scene, robot, tick  # noqa: F401

JTAC = "joint_trajectory_admittance_controller"
VELOCITY = "velocity_force_controller"
GRIPPER = "robotiq_gripper_controller"
ARM_POSITION = [f"joint_{i}/position" for i in range(1, 4)]
ARM_VELOCITY = [f"joint_{i}/velocity" for i in range(1, 4)]


def state(name: str, active: bool, needs: list[str], chained_to: tuple[str, ...] = ()) -> ControllerState:
    return ControllerState(
        name=name,
        state="active" if active else "inactive",
        claimed_interfaces=needs if active else [],
        required_command_interfaces=needs,
        chain_connections=[ChainConnection(name=c) for c in chained_to],
    )


CELL = [state(JTAC, False, ARM_POSITION + ARM_VELOCITY), state(VELOCITY, True, ARM_VELOCITY), state(GRIPPER, True, ["finger/position"])]


# -- which controllers a switch touches (pure) ----------------------------------------------------
def test_automatic_deactivation_takes_the_arm_from_whoever_holds_it():
    plan = plan_switch(CELL, [JTAC], [], automatic_deactivation=True)
    assert (plan.activate, plan.deactivate, plan.auto_deactivated) == ((JTAC,), (VELOCITY,), (VELOCITY,))


def test_without_it_only_the_named_controllers_switch():
    plan = plan_switch(CELL, [JTAC], [])
    assert (plan.activate, plan.deactivate) == ((JTAC,), ())


def test_automatic_activation_brings_up_the_controllers_a_chained_one_writes_to():
    states = [state("admittance", False, ["reference/x"], chained_to=("position_follower",)),
              state("position_follower", False, ARM_POSITION, chained_to=("low_level",)),
              state("low_level", True, ["motor/current"]), *CELL[1:]]
    plan = plan_switch(states, ["admittance"], [], automatic_activation=True, automatic_deactivation=True)
    assert plan.activate == ("admittance", "position_follower")  # low_level is already active
    assert plan.auto_activated == ("position_follower",)
    assert plan.deactivate == ()  # nothing holds joint_*/position


def test_controllers_already_in_the_requested_state_are_left_out():
    states = [state(JTAC, True, ARM_POSITION), state(VELOCITY, False, ARM_VELOCITY)]
    assert plan_switch(states, [JTAC], [VELOCITY], True, True).empty


# -- SwitchController against a controller manager of our own -----------------------------------
class FakeManager:
    """Answers ListControllers with the cell's states and records SwitchController requests."""

    def __init__(self, context, serve: bool = True) -> None:
        self.requests: list[SwitchSrv.Request] = []
        if serve:
            context.bus.create_service("/controller_manager/list_controllers", ListControllers, lambda r: ListControllers.Response(controller=CELL))
            context.bus.create_service("/controller_manager/switch_controller", SwitchSrv, self.switch)

    def switch(self, request: SwitchSrv.Request) -> SwitchSrv.Response:
        self.requests.append(request)
        return SwitchSrv.Response(ok=True, message="switched")


def run_node(context, node, seconds: float) -> Status:
    status = tick(node)
    while status is Status.RUNNING and context.clock.now() < seconds:
        context.clock.advance(0.01)
        context.bus.spin_once()
        status = tick(node)
    return status


def test_moveit_pro_s_switch_element_runs_as_written():
    context = make_context(None)
    manager = FakeManager(context)
    node = make_node(
        SwitchController, context, activate_controllers=JTAC, activate_asap="true", automatic_deactivation="true",
        automatic_activation="true", strictness="1", timeout="-1.000000", deactivate_controllers="",
        controller_list_action_name="/controller_manager/list_controllers",
        controller_switch_action_name="/controller_manager/switch_controller",
    )
    assert run_node(context, node, 1.0) is Status.SUCCESS
    (request,) = manager.requests
    assert (list(request.activate_controllers), list(request.deactivate_controllers)) == ([JTAC], [VELOCITY])
    assert request.activate_asap is True and request.strictness == SwitchSrv.Request.BEST_EFFORT
    assert (request.timeout.sec, request.timeout.nanosec) == (0, 0)  # ros2_control: zero is no limit
    assert node.feedback_message == f"switched; conflicting, deactivated: {VELOCITY}"


@pytest.mark.parametrize("timeout", ["-1.000000", "0"])
def test_a_timeout_of_zero_or_less_waits_without_limit(timeout):
    context = make_context(None)
    FakeManager(context, serve=False)  # no controller manager yet
    node = make_node(SwitchController, context, activate_controllers=JTAC, timeout=timeout)
    assert run_node(context, node, 120.0) is Status.RUNNING


def test_a_positive_timeout_still_ends_the_wait():
    context = make_context(None)
    node = make_node(SwitchController, context, activate_controllers=JTAC, timeout="1.5")
    with pytest.raises(SetupError, match=r"^service '/controller_manager/list_controllers' is not available after 1.5 s$"):
        run_node(context, node, 10.0)  # a missing service is a setup error: the run ends as ERROR
    assert context.clock.now() == pytest.approx(1.5, abs=0.011)


# -- on the cell ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


def run_tree(registry: Registry, tmp_path: Path, body: str) -> RunResult:
    path = tmp_path / "tree.xml"
    path.write_text(f'<root BTCPP_format="4"><BehaviorTree ID="Main"><Sequence>{body}</Sequence></BehaviorTree></root>')
    return run_file(path, registry, RunOptions(world="kinematic", max_seconds=30.0))


def test_the_cell_refuses_to_activate_the_trajectory_controller_over_the_velocity_one(registry, tmp_path):
    result = run_tree(registry, tmp_path, f'<SwitchController activate_controllers="{JTAC}"/>')
    assert result.status == "FAILURE"
    assert f"cannot activate '{JTAC}': its command interfaces are claimed by active controller '{VELOCITY}'" in result.reason


def test_with_automatic_deactivation_the_cell_switches_and_the_arm_moves(registry, tmp_path):
    result = run_tree(registry, tmp_path, f'<SwitchController activate_controllers="{JTAC}" automatic_deactivation="true" timeout="-1"/>'
                                          '<MoveToWaypoint waypoint_name="Home"/>')
    assert (result.status, result.reason) == ("SUCCESS", "")


def test_move_to_waypoint_runs_on_a_freshly_started_cell(registry, tmp_path):
    """The velocity controller holds the arm at start: the SubTree activates its controller first."""
    result = run_tree(registry, tmp_path, '<SubTree ID="Move to Waypoint" waypoint_name="Home"/>')
    assert (result.status, result.reason) == ("SUCCESS", "")


MOVEIT_PRO_CALL = ('<SubTree ID="Move to Waypoint" waypoint_name="Observe" joint_group_name="manipulator" '
                   f'controller_names="{JTAC}" controller_action_server="/{JTAC}/follow_joint_trajectory" '
                   'link_padding="0.01" velocity_scale_factor="{v}" acceleration_scale_factor="{v}" seed="0"/>')


def test_move_to_waypoint_takes_moveit_pro_s_ports_and_its_scale_factors_set_the_pace(registry, tmp_path):
    slow = run_tree(registry, tmp_path, MOVEIT_PRO_CALL.replace("{v}", "0.25"))
    fast = run_tree(registry, tmp_path, MOVEIT_PRO_CALL.replace("{v}", "1.0"))
    assert (slow.status, fast.status) == ("SUCCESS", "SUCCESS")
    assert fast.sim_seconds < 0.6 * slow.sim_seconds


@pytest.mark.parametrize(
    ("ports", "status", "reason"),
    [
        # What the cell does not have is an error of the setup, found before anything moves.
        ('controller_names="no_such_controller"', "ERROR", "SwitchController 'activate the trajectory controller': port "
         "'activate_controllers': unknown controller 'no_such_controller' (controllers: force_torque_sensor_broadcaster, "
         "joint_trajectory_admittance_controller, joint_trajectory_controller, robotiq_gripper_controller, velocity_force_controller)"),
        ('controller_action_server="/nowhere/follow_joint_trajectory"', "ERROR",
         "MoveToWaypoint: port 'controller_action_name': no action '/nowhere/follow_joint_trajectory' (actions: "),
        ('joint_group_name="gripper_arm"', "ERROR", "MoveToWaypoint: port 'joint_group_name': unknown joint group 'gripper_arm'"),
    ],
)
def test_move_to_waypoint_bad_ports_fail_naming_them(registry, tmp_path, ports, status, reason):
    result = run_tree(registry, tmp_path, f'<SubTree ID="Move to Waypoint" {ports}/>')
    assert result.status == status and reason in result.reason, result.reason


def test_move_to_waypoint_scale_outside_its_range_is_an_error_of_the_objective(registry, tmp_path):
    """A SubTree port is a string until the node inside reads it: then it is checked against the
    port's range like a literal, and the run ends as ERROR naming the port."""
    result = run_tree(registry, tmp_path, '<SubTree ID="Move to Waypoint" velocity_scale_factor="1.5"/>')
    assert result.status == "ERROR" and "port 'velocity_scaling_factor'" in result.reason
    assert "must be in (0, 1], got 1.5" in result.reason


def test_move_to_waypoint_link_padding_reaches_the_collision_check(registry, tmp_path):
    """Home sits about 0.27 m above the table: a padding bigger than that refuses the motion."""
    result = run_tree(registry, tmp_path, '<SubTree ID="Move to Waypoint" waypoint_name="Home" link_padding="0.5"/>')
    assert result.status == "FAILURE" and result.reason.startswith("the motion would collide: ")


# -- TransformPose markers ------------------------------------------------------------------------
def test_pose_markers_draw_the_axes_and_the_label():
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 degrees about z
    pose = matrix_to_pose("world", pose_matrix((0.1, 0.2, 0.3), rotation), stamp=2.0)
    markers = pose_markers(pose, "pre-place", "Pre-Place", 0.1, 5.0).markers
    assert [m.type for m in markers] == [Marker.ARROW] * 3 + [Marker.TEXT_VIEW_FACING]
    tips = [np.array([m.points[1].x, m.points[1].y, m.points[1].z]) for m in markers[:3]]
    np.testing.assert_allclose(tips, [[0.1, 0.3, 0.3], [0.0, 0.2, 0.3], [0.1, 0.2, 0.4]], atol=1e-12)
    assert markers[3].text == "Pre-Place" and markers[3].pose.position.z == pytest.approx(0.42)
    assert {(m.ns, m.header.frame_id, m.lifetime.sec) for m in markers} == {("pre-place", "world", 5)}
    assert len(pose_markers(pose, "n", "", 0.1, 0.0).markers) == 3  # no label


@pytest.mark.parametrize(("size", "lifetime", "message"), [
    (0.0, 0.0, "marker_size must be a positive length in metres, got 0.0"),
    (0.1, -1.0, "marker_lifetime must be 0 (forever) or a positive number of seconds, got -1.0"),
])
def test_pose_markers_refuse_sizes_and_lifetimes_that_draw_nothing(size, lifetime, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        pose_markers(PoseStamped(), "n", "", size, lifetime)


@pytest.mark.parametrize("visualize", ["true", "false"])
def test_transform_pose_publishes_markers_only_when_asked(robot, visualize):  # noqa: F811
    context = make_context(make_scene(robot))
    received: list[MarkerArray] = []
    context.bus.create_subscription(MARKER_TOPIC, MarkerArray, received.append)
    board = Blackboard()
    board.set("cube", matrix_to_pose("world", pose_matrix((0.0, 0.45, 0.015))))
    node = make_node(TransformPose, context, board, input_pose="{cube}", translation_xyz="0;0;0.1", output_pose="{out}",
                     visualize_pose=visualize, marker_text="Pre-Pick", marker_size="0.100000", marker_lifetime="0.000000")
    assert tick(node) is Status.SUCCESS
    context.bus.spin_once()
    if visualize == "false":
        assert received == []
        return
    (array,) = received
    assert [m.text for m in array.markers][-1] == "Pre-Pick"
    origin = array.markers[0].points[0]
    assert (origin.x, origin.y, origin.z) == pytest.approx((0.0, 0.45, 0.115))
    assert not math.isnan(array.markers[0].scale.x)

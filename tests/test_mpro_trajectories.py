"""PlanCartesianPath, ValidateTrajectory, ExecuteTrajectory, RetrieveWaypoint, GetJointState and
the example Objectives that use MoveIt Pro's behaviors, against the cell's planning scene and
the kinematic cell."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from trajectory_msgs.msg import JointTrajectory

from runtime.motion.samples import Samples
from behaviors.trajectory_goal import PlanningError
from behaviors.robot_state import GetJointState, group_joint_state
from behaviors.trajectories import (
    PlanCartesianPath,
    from_trajectory_msg,
    interpolate_line,
    parse_timing,
    resample,
    time_path,
    tip_offset_matrix,
)
from behaviors.trajectory_goal import trajectory_msg
from behaviors.poses import matrix_to_pose
from runtime.tree.blackboard import Blackboard
from runtime.tree.behavior import Status
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, run_file
from runtime.motion.scene.collision import pose_matrix
from runtime.motion.scene.kinematics import frame_pose
from runtime.motion.scene.limits import JointLimit, JointLimits
from sim.robot_model import ARM_JOINTS
from tests.test_scene_behaviors import HOME, make_context, make_node, make_scene, publish_joint_states, robot, tick  # noqa: F401

OBJECTIVES = Path(__file__).resolve().parent.parent / "objectives"
DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""The TCP orientation at Home: z pointing down, x along world +y."""


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


def run_xml(registry: Registry, tmp_path: Path, body: str, max_seconds: float = 30.0):
    path = tmp_path / "tree.xml"
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">{body}</BehaviorTree></root>')
    return run_file(path, registry, RunOptions(world="kinematic", max_seconds=max_seconds))


# -- pure pieces ----------------------------------------------------------------------------------
def test_interpolate_line_cuts_by_distance_and_angle():
    start, goal = np.eye(4), pose_matrix((0.1, 0.0, 0.0))
    poses = interpolate_line(start, goal, 0.01, 0.1)
    assert len(poses) == 10
    np.testing.assert_allclose(poses[0][:3, 3], [0.01, 0, 0], atol=1e-12)
    np.testing.assert_allclose(poses[-1], goal, atol=1e-12)


def test_time_path_stays_within_the_scaled_limits_and_stops_where_asked():
    limits = JointLimits((JointLimit("a", -10, 10, 2.0, 4.0), JointLimit("b", -10, 10, 1.0, 4.0)))
    path = np.stack([np.linspace(0, 1, 51), np.linspace(0, 2, 51)], axis=1)
    path = np.vstack([path, path[-1] + np.stack([np.linspace(0.02, 1, 50), np.zeros(50)], axis=1)])
    timing = time_path(path, {50}, limits, velocity_scale=0.5, acceleration_scale=0.5)
    samples = resample(timing, path, 500.0)
    assert np.all(np.abs(samples.velocities).max(axis=0) <= np.array([1.0, 0.5]) * 1.02)
    assert np.all(np.abs(samples.accelerations[1:-1]).max(axis=0) <= np.array([2.0, 2.0]) * 1.05)
    assert np.all(samples.velocities[0] == 0) and np.all(samples.velocities[-1] == 0)
    # at rest at the corner: the joint speed near t(50) is close to zero
    corner = int(np.argmin(np.abs(samples.times - timing.times[50])))
    assert np.abs(samples.velocities[corner]).max() < 0.01
    # joint b needs 2 rad at 0.5 rad/s at most: at least 4 s for the first piece
    assert timing.times[50] >= 4.0
    np.testing.assert_allclose(samples.positions[-1], path[-1], atol=1e-9)


def test_trajectory_timing_is_read_like_moveit_pro_writes_it():
    assert parse_timing("[{mode: time_optimal}]") == ("time_optimal", 1.0, 1.0)
    assert parse_timing("[{mode: time_optimal, velocity_scale_factor: 0.3}]") == ("time_optimal", 0.3, 1.0)
    with pytest.raises(PlanningError, match="trajectory_timing mode 'spline' is not supported"):
        parse_timing("[{mode: spline}]")
    with pytest.raises(PlanningError, match="velocity_scale_factor must be in"):
        parse_timing("[{mode: time_optimal, velocity_scale_factor: 2}]")
    with pytest.raises(PlanningError, match="tip_offset needs 6 values"):
        tip_offset_matrix([0.0, 0.0, 0.1])


def test_trajectory_message_round_trip_reorders_joints():
    samples = Samples(np.array([0.0, 0.5]), np.array([[1.0, 2.0], [3.0, 4.0]]), np.zeros((2, 2)), np.zeros((2, 2)))
    msg = trajectory_msg(samples, ("a", "b"))
    back = from_trajectory_msg(msg, ("b", "a"))
    np.testing.assert_allclose(back.positions, [[2.0, 1.0], [4.0, 3.0]])
    with pytest.raises(PlanningError, match="the trajectory lacks joints c"):
        from_trajectory_msg(msg, ("a", "c"))
    with pytest.raises(PlanningError, match="no points"):
        from_trajectory_msg(JointTrajectory(joint_names=["a"]), ("a",))


# -- PlanCartesianPath on the cell's planning scene ----------------------------------------------
def cell_scene(envelope: bool = True):
    """The cell's scene; ``envelope`` False: without its Cartesian envelope (a test of the collision check)."""
    from sim.planning import make_cell_scene

    cube = (np.array([0.3, 0.3, 0.015]), np.array([1.0, 0.0, 0.0, 0.0]))
    scene = make_cell_scene({"red": cube, "green": cube, "blue": cube})
    if not envelope:
        scene.envelope = None
    return scene


def plan(robot, targets: list[tuple[float, float, float]], envelope: bool = True, **ports: str):
    scene = cell_scene(envelope)
    context = make_context(scene)
    blackboard = Blackboard()
    blackboard.set("path", [matrix_to_pose("world", pose_matrix(p, DOWN)) for p in targets])
    node = make_node(PlanCartesianPath, context, blackboard, path="{path}", joint_trajectory_msg="{trajectory}", debug_solution="{tips}", **ports)
    publish_joint_states(context, HOME)  # after setup() subscribed, as the cell publishes every step
    status = tick(node)
    return status, node, blackboard, scene


def test_plan_cartesian_path_moves_the_tcp_in_a_straight_line_within_the_limits(robot):
    status, node, blackboard, scene = plan(robot, [(0.0, 0.45, 0.25), (0.05, 0.45, 0.25)])
    assert status is Status.SUCCESS, node.feedback_message
    samples = from_trajectory_msg(blackboard.get("trajectory"), ARM_JOINTS)
    np.testing.assert_allclose(samples.positions[0], HOME, atol=1e-9)  # starts where the arm is
    layout = scene.layout("manipulator", None)
    tcp = np.array([frame_pose(robot, layout(q), "tcp")[:3, 3] for q in samples.positions])
    np.testing.assert_allclose(tcp[-1], [0.05, 0.45, 0.25], atol=1e-3)
    # the first leg is straight down: x and y stay put until the TCP is at 0.25 m
    first_leg = tcp[tcp[:, 2] > 0.2505]
    assert np.abs(first_leg[:, :2] - [0.0, 0.45]).max() < 2e-3
    assert np.abs(samples.velocities).max() <= np.pi * 1.02
    assert len(blackboard.get("tips")) in (1 + 5 + 5, 1 + 6 + 5)  # the start, then 1 cm steps (Home is ~5 cm up)


def test_an_unreachable_waypoint_fails_naming_it(robot):
    # Stretching toward a point 2 m away, the arm either runs out of reach or jumps at the
    # workspace's edge: either way the plan fails at waypoint 1 and says which.
    status, node, _, _ = plan(robot, [(0.0, 0.45, 0.25), (2.0, 0.45, 0.25)])
    assert status is Status.FAILURE
    assert re.match(r"waypoint 1: (no IK solution near the arm's path at \(|joint \w+ jumps [0-9.]+ rad between two points 10 mm apart)", node.feedback_message)


def test_a_path_through_the_table_fails_as_a_collision(robot):
    status, node, _, _ = plan(robot, [(0.0, 0.45, -0.05)], envelope=False)  # the envelope's keep-in box refuses it first
    assert status is Status.FAILURE
    assert node.feedback_message.startswith("the planned path collides:")
    assert "table" in node.feedback_message


def test_plan_cartesian_path_refuses_an_empty_path_and_unknown_tips(robot):
    status, node, _, _ = plan(robot, [])
    assert (status, node.feedback_message) == (Status.FAILURE, "path is empty: give at least one pose")
    status, node, _, _ = plan(robot, [(0.0, 0.45, 0.25)], tip_links="grasp_link")
    assert (status, node.feedback_message) == (Status.FAILURE, "tip link 'grasp_link' is not a frame of the robot model")


# -- GetJointState ----------------------------------------------------------------------------------
def test_get_joint_state_needs_a_captured_scene(robot):
    context = make_context(make_scene(robot))
    blackboard = Blackboard()
    blackboard.set("planning_scene", "not a scene")
    node = make_node(GetJointState, context, blackboard)
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "planning_scene must come from GetCurrentPlanningScene, got a str"


def test_group_joint_state_names_missing_joints():
    from sensor_msgs.msg import JointState

    source = JointState(name=["a", "b"], position=[1.0, 2.0])
    assert list(group_joint_state(source, ("b",), 0.0).position) == [2.0]
    with pytest.raises(KeyError, match="the joint state lacks c"):
        group_joint_state(source, ("a", "c"), 0.0)


# -- on the kinematic cell --------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["cartesian_approach.xml", "foreach_poses.xml", "joint_state_check.xml", "camera_and_messages.xml"])
def test_example_objectives_succeed_on_the_cell(registry, name):
    result = run_file(OBJECTIVES / "examples" / name, registry, RunOptions(world="kinematic", max_seconds=60.0))
    assert (result.status, result.failing_node, result.reason) == ("SUCCESS", None, "")


def test_foreach_example_visits_the_three_poses_and_ends_on_the_last(registry):
    result = run_file(OBJECTIVES / "examples" / "foreach_poses.xml", registry, RunOptions(world="kinematic", max_seconds=60.0))
    assert (result.blackboard["visited"], result.blackboard["count"], result.blackboard["index"]) == (3, 3, 2)


def test_execute_trajectory_refuses_a_trajectory_planned_from_elsewhere(registry, tmp_path):
    result = run_xml(registry, tmp_path, """<Sequence>
      <SubTree ID="Move to Waypoint (JTC)" waypoint_name="Home"/>
      <CreatePoseStamped position_xyz="0;0.45;0.25" orientation_xyzw="0.7071068;0.7071068;0;0" pose_stamped="{p}"/>
      <ResetPoseStampedVector vector="{path}"/>
      <PushBackVector input_vector="{path}" element="{p}" output_vector="{path}"/>
      <PlanCartesianPath path="{path}"/>
      <SubTree ID="Move to Waypoint (JTC)" waypoint_name="Observe"/>
      <ExecuteTrajectory name="stale"/>
    </Sequence>""")
    assert (result.status, result.failing_node) == ("FAILURE", "stale")
    assert result.reason.startswith("the trajectory starts ")
    assert result.reason.endswith("from the arm's current position (joint wrist_1_joint; at most 0.01 rad): plan it from where the arm is")


def test_execute_trajectory_names_an_unknown_pipeline(registry, tmp_path):
    result = run_xml(registry, tmp_path, """<Sequence>
      <CreatePoseStamped pose_stamped="{p}"/>
      <ExecuteTrajectory name="ompl" execution_pipeline="ompl"/>
    </Sequence>""")
    assert (result.status, result.failing_node) == ("FAILURE", "ompl")
    assert result.reason == "execution_pipeline 'ompl' is not available (pipelines: jtac, jtc)"


@pytest.mark.parametrize("controller, pipeline", [("joint_trajectory_admittance_controller", "jtac"), ("joint_trajectory_controller", "jtc")])
def test_a_planned_trajectory_validates_executes_and_moves_the_arm(registry, tmp_path, controller, pipeline):
    result = run_xml(registry, tmp_path, """<Sequence>
      <SubTree ID="Move to Waypoint (JTC)" waypoint_name="Home" controller_names="CONTROLLER"
               controller_action_server="/CONTROLLER/follow_joint_trajectory"/>
      <RetrieveWaypoint waypoint_name="Home" waypoint_joint_state="{home}"/>
      <CreatePoseStamped position_xyz="0;0.45;0.12" orientation_xyzw="0.7071068;0.7071068;0;0" pose_stamped="{p}"/>
      <ResetPoseStampedVector vector="{path}"/>
      <PushBackVector input_vector="{path}" element="{p}" output_vector="{path}"/>
      <PlanCartesianPath path="{path}"/>
      <ValidateTrajectory name="planned one"/>
      <ExecuteTrajectory execution_pipeline="PIPELINE"/>
      <GetCurrentPlanningScene/>
      <GetJointState joint_positions="{q}"/>
      <GetElementOfVector vector_in="{q}" index="2" element="{elbow}"/>
    </Sequence>""".replace("CONTROLLER", controller).replace("PIPELINE", pipeline))
    assert (result.status, result.reason) == ("SUCCESS", "")
    # the elbow opened: the TCP went 18 cm down from Home
    assert result.blackboard["elbow"] > HOME[2] + 0.2


def test_validate_trajectory_finds_a_collision_with_the_table(robot):
    from behaviors.trajectories import ValidateTrajectory
    from runtime.motion.scene.kinematics import solve_ik

    scene = cell_scene(envelope=False)  # the envelope's keep-in box refuses it first
    below = solve_ik(robot, "manipulator", pose_matrix((0.0, 0.45, -0.03), DOWN), seeds=[HOME], frame="tcp")
    assert below.success
    path = np.linspace(HOME, below.positions, 20)
    samples = Samples(np.linspace(0, 2, 20), path, np.zeros_like(path), np.zeros_like(path))
    blackboard = Blackboard()
    blackboard.set("joint_trajectory_msg", trajectory_msg(samples, ARM_JOINTS))
    node = make_node(ValidateTrajectory, make_context(scene), blackboard, debug_solution="{why}")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message.startswith("the trajectory collides:") and "table" in node.feedback_message
    assert blackboard.get("why") == node.feedback_message.removeprefix("the trajectory ")


def execute_from_blackboard(samples: Samples) -> tuple[str, list]:
    """ExecuteTrajectory on ``samples`` (as a message on the blackboard) with the arm at Home:
    its status message, and the goals the controller received."""
    from behaviors.trajectories import ExecuteTrajectory
    from tests.test_pose_behaviors import RecordingController

    context = make_context(cell_scene())
    controller = RecordingController(context)
    blackboard = Blackboard()
    blackboard.set("joint_trajectory_msg", trajectory_msg(samples, ARM_JOINTS))
    node = make_node(ExecuteTrajectory, context, blackboard)
    publish_joint_states(context, HOME)
    assert tick(node) is Status.FAILURE
    return node.feedback_message, controller.goals


@pytest.mark.parametrize("quantity, value, expected", [
    ("velocities", 5.0, "joint shoulder_pan_joint velocity 5.0000 rad/s exceeds the limit 3.1416 rad/s"),
    ("accelerations", -20.0, "joint shoulder_pan_joint acceleration -20.0000 rad/s^2 exceeds the limit -5.0000 rad/s^2"),
])
def test_execute_trajectory_refuses_a_trajectory_over_the_velocity_or_acceleration_limits(robot, quantity, value, expected):
    path = np.tile(HOME, (3, 1)) + np.outer([0.0, 0.05, 0.1], [1, 0, 0, 0, 0, 0])
    derivatives = {"velocities": np.zeros_like(path), "accelerations": np.zeros_like(path)}
    derivatives[quantity][1, 0] = value  # point 1 of shoulder_pan_joint, as the blackboard holds it
    message, goals = execute_from_blackboard(Samples(np.array([0.0, 0.5, 1.0]), path, **derivatives))
    assert message == f"the trajectory breaks a joint limit at point 1 (t=0.500 s): {expected}"
    assert goals == []  # nothing reached the controller


def test_execute_trajectory_refuses_positions_alone_that_move_faster_than_the_limit(robot):
    # No velocities: shoulder_pan_joint goes 0.4 rad in 0.1 s between points 1 and 2, 4 rad/s at least.
    path = np.tile(HOME, (3, 1)) + np.outer([0.0, 0.05, 0.45], [1, 0, 0, 0, 0, 0])
    message, goals = execute_from_blackboard(Samples(np.array([0.0, 0.5, 0.6]), path, None, None))
    assert message == ("the trajectory moves faster than a joint limit from point 1 to point 2 (t=0.600 s): "
                       "joint shoulder_pan_joint velocity 4.0000 rad/s exceeds the limit 3.1416 rad/s "
                       "(the mean over that interval)")
    assert goals == []


def test_retrieve_waypoint_lists_the_known_waypoints(registry, tmp_path):
    result = run_xml(registry, tmp_path, '<RetrieveWaypoint name="r" waypoint_name="Look at table" waypoint_joint_state="{w}"/>')
    assert (result.status, result.ticks) == ("ERROR", 0)  # a waypoint the cell lacks: an error of the setup
    assert result.reason.endswith("RetrieveWaypoint 'r': port 'waypoint_name': unknown waypoint 'Look at table' "
                                  "(waypoints: Home, Observe, Ready)")


def test_move_to_waypoint_jtc_names_the_controllers_when_asked_for_an_unknown_one(registry, tmp_path):
    result = run_xml(registry, tmp_path, '<SubTree ID="Move to Waypoint (JTC)" waypoint_name="Home" controller_names="scaled_joint_trajectory_controller"/>')
    assert (result.status, result.ticks) == ("ERROR", 0)  # a controller the cell lacks: an error of the setup
    assert ("objectives/move_to_waypoint_jtc.xml:16: SwitchController: port 'activate_controllers': unknown controller "
            "'scaled_joint_trajectory_controller'") in result.reason
    assert "joint_trajectory_controller, " in result.reason  # the cell's controllers are listed


# -- a motion to where the arm already is ---------------------------------------------------------
HOME_ONCE = '<SubTree ID="Move to Waypoint" waypoint_name="Home"/>'
AT_HOME_AGAIN = """
  <SubTree ID="Move to Waypoint" waypoint_name="Home"/>
  <SubTree ID="Move to Waypoint (JTC)" waypoint_name="Home"/>
  <CreatePoseStamped reference_frame="tcp" pose_stamped="{p}"/>
  <ResetPoseStampedVector vector="{path}"/>
  <PushBackVector input_vector="{path}" element="{p}" output_vector="{path}"/>
  <PlanCartesianPath path="{path}"/>
  <ExecuteTrajectory/>"""


@pytest.mark.parametrize("world", ["kinematic", "vla_sim"])
def test_a_motion_to_where_the_arm_already_is_succeeds_at_once(registry, tmp_path, world):
    """Home, then Home again through both SubTrees and a Cartesian path to where the TCP is. On
    the kinematic cell the arm is exactly at Home: every motion after the first has no length
    and succeeds without moving the clock on (on main the controller refused it: "time_from_start
    must increase"). On MuJoCo the arm rests ~3 mrad from Home, so they are short motions."""
    results = []
    for body in (HOME_ONCE, HOME_ONCE + AT_HOME_AGAIN):
        path = tmp_path / "tree.xml"
        path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main"><Sequence>{body}</Sequence></BehaviorTree></root>')
        results.append(run_file(path, registry, RunOptions(world=world, max_seconds=30.0)))
    once, again = results
    assert (again.status, again.failing_node, again.reason) == ("SUCCESS", None, "")
    assert again.sim_seconds - once.sim_seconds <= (0.05 if world == "kinematic" else 1.0)


def test_a_plan_to_the_current_position_is_one_point_at_time_zero():
    from behaviors.motion import plan_point_to_point

    limits = JointLimits((JointLimit("a", -1, 1, 2.0, 4.0), JointLimit("b", -1, 1, 2.0, 4.0)))
    samples = plan_point_to_point(np.array([0.2, -0.3]), np.array([0.2, -0.3]), limits, 0.5, 0.5)
    assert (samples.duration_s, samples.positions.tolist()) == (0.0, [[0.2, -0.3]])
    timing = time_path(np.array([[0.2, -0.3], [0.2, -0.3]]), {1}, limits, 0.5, 0.5)
    assert resample(timing, np.array([[0.2, -0.3], [0.2, -0.3]]), 100.0).times.tolist() == [0.0]


def test_a_waypoint_name_the_tree_computes_is_checked_when_read(registry, tmp_path):
    result = run_xml(registry, tmp_path, "<Sequence><Script code=\"w := 'Look at table'\"/>"
                                         '<RetrieveWaypoint name="r" waypoint_name="{w}" waypoint_joint_state="{j}"/></Sequence>')
    assert (result.status, result.failure_kind) == ("ERROR", "SetupError")
    assert result.reason.endswith("RetrieveWaypoint 'r': unknown waypoint 'Look at table' (known: Home, Observe, Ready)")

"""MoveIt Pro's planning behaviors on the kinematic cell: PlanToJointGoal, ComputeInverseKinematics
and the MTC set, around a box, on both controller types, and their failures."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, run_file

DOWN = "0.7071068;0.7071068;0;0"
"""The TCP orientation at Home: z down, x along world +y."""
WALL = """<CreatePoseStamped position_xyz="0;0.45;0.10" pose_stamped="{wall_pose}"/>
      <AddCollisionBox object_id="wall" dimensions="0.04;0.30;0.20" pose="{wall_pose}"/>"""
"""A wall across the workspace, between the arm's left and right of it."""
LEFT, RIGHT = "-0.15;0.45;0.12", "0.15;0.45;0.12"


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


def run_xml(registry: Registry, tmp_path: Path, body: str, world: str = "kinematic", max_seconds: float = 60.0):
    path = tmp_path / "tree.xml"
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main"><Sequence>{body}</Sequence></BehaviorTree></root>')
    return run_file(path, registry, RunOptions(world=world, max_seconds=max_seconds))


def plan_to_pose(xyz: str, name: str = "to pose", execute: str = '<SubTree ID="Execute MTC Solution" solution="{mtc_solution}"/>') -> str:
    return f"""<CreatePoseStamped position_xyz="{xyz}" orientation_xyzw="{DOWN}" pose_stamped="{{target_pose}}"/>
      <InitializeMTCTask task_id="{name}" task="{{mtc_task}}" timeout="-1.000000"/>
      <SetupMTCCurrentState task="{{mtc_task}}"/>
      <SetupMTCPlanToPose name="{name}" task="{{mtc_task}}" target_pose="{{target_pose}}" ik_frame="tcp" link_padding="0.01"
                          planning_group_name="manipulator" max_iterations="5000" trajectory_sampling_rate="100"
                          velocity_scale_factor="1.000000" acceleration_scale_factor="1.000000" monitored_stage="current state"/>
      <PlanMTCTask task="{{mtc_task}}" solution="{{mtc_solution}}"/>
      <WaitForMTCSolutionApproval solution="{{mtc_solution}}"/>
      {execute}"""


TCP_AT = """<GetCurrentPlanningScene/>
      <GetJointState joint_positions="{q}"/>"""


@pytest.mark.parametrize("controller", ["joint_trajectory_admittance_controller", "joint_trajectory_controller"])
def test_a_wall_between_the_arm_and_its_goal_is_planned_around_on_both_controllers(registry, tmp_path, controller):
    execute = (f'<SubTree ID="Execute MTC Solution" solution="{{mtc_solution}}" controller_names="{controller}" '
               f'controller_action_name="/{controller}/follow_joint_trajectory"/>')
    result = run_xml(registry, tmp_path, f"""
      <SubTree ID="Move to Waypoint" waypoint_name="Home"/>
      {plan_to_pose(LEFT, "left", execute)}
      {WALL}
      {plan_to_pose(RIGHT, "right", execute)}
      {TCP_AT}""")
    assert (result.status, result.reason) == ("SUCCESS", "")
    assert result.blackboard["q"][0] < -2.0  # the pan turned right of Home (-1.87): the TCP is at x = +0.15


def ik_down_at(xyz: str) -> list[float]:
    """The IK solution (seeded from Home) of the TCP looking down (DOWN) at ``xyz``."""
    from runtime.motion.scene import solve_ik
    from sim.robot_model import planning_robot_model

    target = np.eye(4)
    target[:3, :3] = [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]  # DOWN
    target[:3, 3] = [float(v) for v in xyz.split(";")]
    return [round(float(v), 6) for v in solve_ik(planning_robot_model(), "manipulator", target, seeds=[load_home()], frame="tcp", random_restarts=0).positions]


def wall_blocks_the_straight_move(goal: list[float], start_xyz: str = LEFT) -> bool:
    """Whether the wall stops the straight joint move from the IK solution at ``start_xyz``
    (or Home) to ``goal``, as the planner checks it (10 mm padding)."""
    from runtime.motion.scene import Box, pose_matrix
    from runtime.motion.scene.planner import motion_is_free, scene_validity

    scene = cell_scene()
    scene.add_object("wall", Box((0.04, 0.30, 0.20)), pose_matrix((0.0, 0.45, 0.10)))
    is_free = scene_validity(scene, scene.layout("manipulator", None), 0.01, scene.snapshot(), None)
    return not motion_is_free(is_free, np.array(ik_down_at(start_xyz)), np.array(goal), 0.01)


def test_plan_to_joint_goal_and_move_to_joint_state_go_around_the_wall_that_blocks_the_straight_move(registry, tmp_path):
    right = ik_down_at(RIGHT)
    assert wall_blocks_the_straight_move(right)
    before = f"""<SubTree ID="Move to Waypoint" waypoint_name="Home"/>
      {plan_to_pose(LEFT, "left")}
      {WALL}"""
    moved = run_xml(registry, tmp_path, f'{before}<MoveToJointState joint_positions="{";".join(map(str, right))}" link_padding="0.01"/>{TCP_AT}')
    assert (moved.status, moved.reason) == ("SUCCESS", "")
    np.testing.assert_allclose(moved.blackboard["q"], right, atol=1e-3)
    planned = run_xml(registry, tmp_path, f"""{before}
      <CreatePoseStamped position_xyz="{RIGHT}" orientation_xyzw="{DOWN}" pose_stamped="{{p}}"/>
      <ResetPoseStampedVector vector="{{poses}}"/>
      <PushBackVector input_vector="{{poses}}" element="{{p}}" output_vector="{{poses}}"/>
      <ComputeInverseKinematics target_poses="{{poses}}" tip_links="tcp" link_padding="0.01" solution="{{right}}"/>
      <PlanToJointGoal joint_goal="{{right}}" link_padding="0.01" seed="0"/>
      <ValidateTrajectory link_padding="0.01"/>
      <ExecuteTrajectory link_padding="0.01"/>
      {TCP_AT}""")
    assert (planned.status, planned.reason) == ("SUCCESS", "")
    np.testing.assert_allclose(planned.blackboard["q"], right, atol=1e-3)


@pytest.mark.parametrize("subtree, controller", [("Move to Waypoint", "joint_trajectory_admittance_controller"),
                                                 ("Move to Waypoint (JTC)", "joint_trajectory_controller")])
def test_move_to_waypoint_plans_around_a_wall_between_the_arm_and_home(registry, tmp_path, subtree, controller):
    home = list(load_home())
    assert wall_blocks_the_straight_move(home, RIGHT)
    result = run_xml(registry, tmp_path, f"""<SubTree ID="Move to Waypoint" waypoint_name="Home"/>
      {plan_to_pose(RIGHT, "right")}
      {WALL}
      <SubTree ID="{subtree}" waypoint_name="Home" controller_names="{controller}"
               controller_action_server="/{controller}/follow_joint_trajectory"/>
      {TCP_AT}""")
    assert (result.status, result.reason) == ("SUCCESS", "")
    np.testing.assert_allclose(result.blackboard["q"], home, atol=1e-3)


def load_home() -> np.ndarray:
    from sim.robot_model import load_waypoints

    return np.array(list(load_waypoints()["Home"].values()))


def cell_scene():
    from sim.cell_model import CUBE_COLORS
    from sim.planning import make_cell_scene

    return make_cell_scene({c: (np.array([0.3, 0.1 * i, 0.015]), np.array([1.0, 0, 0, 0])) for i, c in enumerate(CUBE_COLORS)})


def tcp_position(q: list[float]) -> np.ndarray:
    scene = cell_scene()
    return scene.link_pose(np.array(q), "tcp", scene.layout("manipulator", None))[:3, 3]


PICK_TASK = f"""<CreatePoseStamped position_xyz="0.15;0.45;0.05" orientation_xyzw="{DOWN}" pose_stamped="{{grasp}}"/>
      <ResetPoseStampedVector vector="{{grasps}}"/>
      <PushBackVector input_vector="{{grasps}}" element="{{grasp}}" output_vector="{{grasps}}"/>
      <InitializeMTCTask task_id="pick" task="{{mtc_task}}" timeout="-1.000000"/>
      <SetupMTCCurrentState task="{{mtc_task}}"/>
      <SetupMTCSetCollisionRule task="{{mtc_task}}" name_a="gripper" name_b="wall" allow_collision="false"/>
      <SetupMTCConnectWithProRRT task="{{mtc_task}}" planning_group_name="manipulator" link_padding="0.01" max_iterations="5000"
                                 seed="0" trajectory_sampling_rate="100" velocity_scale_factor="1.000000" acceleration_scale_factor="1.000000"/>
      <SetupMTCMoveAlongFrameAxis name="approach" task="{{mtc_task}}" hand_frame="tcp" axis_frame="tcp" axis_x="0.0" axis_y="0.0" axis_z="1.0"
                                  max_distance="0.08" min_distance="0.05" velocity_scale="0.5" acceleration_scale="0.5"
                                  planning_group_name="manipulator" ignore_environment_collisions="false"/>
      <SetupMTCBatchPoseIK task="{{mtc_task}}" target_poses="{{grasps}}" ik_group="manipulator" end_effector_link="tcp"
                           end_effector_group="moveit_ee" ik_timeout_s="0.01" max_ik_solutions="4" monitored_stage="current state"/>
      <SetupMTCMoveAlongFrameAxis name="lift" task="{{mtc_task}}" hand_frame="tcp" axis_frame="world" axis_z="1.0"
                                  max_distance="0.1" min_distance="0.1" planning_group_name="manipulator"/>
      <PlanMTCTask task="{{mtc_task}}" solution="{{mtc_solution}}" max_solutions="1"/>"""


def test_a_pick_task_connects_over_the_wall_to_an_approach_and_lifts(registry, tmp_path):
    """Connect (RRT around the wall) -> approach 8 cm down the TCP axis -> the IK solution of the
    grasp -> lift 10 cm: split after the connect, the rest replayed through SetupMTCFromSolution."""
    result = run_xml(registry, tmp_path, f"""
      <SubTree ID="Move to Waypoint" waypoint_name="Home"/>
      {plan_to_pose(LEFT, "left")}
      {WALL}
      {PICK_TASK}
      <SplitMTCSolution solution_in="{{mtc_solution}}" index="2" solution_out_1="{{to_approach}}" solution_out_2="{{approach_and_lift}}"/>
      <SubTree ID="Execute MTC Solution" solution="{{to_approach}}"/>
      {TCP_AT.replace("{q}", "{q_approach}")}
      <InitializeMTCTask task_id="replay" task="{{replay_task}}"/>
      <SetupMTCFromSolution task="{{replay_task}}" solution="{{approach_and_lift}}"/>
      <PlanMTCTask task="{{replay_task}}" solution="{{replayed}}"/>
      <ExecuteMTCSolution solution="{{replayed}}" execution_pipeline="jtac"/>
      {TCP_AT}""")
    assert (result.status, result.reason) == ("SUCCESS", "")
    np.testing.assert_allclose(tcp_position(result.blackboard["q_approach"]), [0.15, 0.45, 0.13], atol=2e-3)
    np.testing.assert_allclose(tcp_position(result.blackboard["q"]), [0.15, 0.45, 0.15], atol=2e-3)


# -- bad input: FAILURE for what the world makes impossible, ERROR for a task set up wrong -----------
def mtc(body: str, task_id: str = "bad") -> str:
    return f"""<SubTree ID="Move to Waypoint" waypoint_name="Home"/>
      <InitializeMTCTask task_id="{task_id}" task="{{mtc_task}}"/>
      <SetupMTCCurrentState task="{{mtc_task}}"/>
      {body}
      <PlanMTCTask name="plan" task="{{mtc_task}}" solution="{{mtc_solution}}"/>"""


def to_pose(xyz: str, **ports: str) -> str:
    extra = " ".join(f'{k}="{v}"' for k, v in ports.items())
    return f"""<CreatePoseStamped position_xyz="{xyz}" orientation_xyzw="{DOWN}" pose_stamped="{{target}}"/>
      <SetupMTCPlanToPose name="reach" task="{{mtc_task}}" target_pose="{{target}}" ik_frame="tcp" {extra}/>"""


def test_an_unreachable_pose_fails_naming_the_stage(registry, tmp_path):
    result = run_xml(registry, tmp_path, mtc(to_pose("0;2.0;0.3")))
    assert (result.status, result.failing_node) == ("FAILURE", "plan")
    assert result.reason.startswith(f"task 'bad': SetupMTCPlanToPose 'reach' ({tmp_path / 'tree.xml'}:")
    assert "): the pose (0.000, 2.000, 0.300) for 'tcp' is unreachable: no IK solution (" in result.reason


def test_a_goal_in_collision_fails_naming_the_stage_and_the_contact(registry, tmp_path):
    result = run_xml(registry, tmp_path, WALL + mtc(to_pose("0;0.45;0.12")))
    assert (result.status, result.failing_node) == ("FAILURE", "plan")
    assert "SetupMTCPlanToPose 'reach'" in result.reason
    assert "every IK solution at (0.000, 0.450, 0.120) for 'tcp' is in collision: " in result.reason
    assert "vs wall" in result.reason


@pytest.mark.parametrize("box_at, which", [("-0.134;0.492;0.40", "goal"), ("0;0.45;0.40", "start")])
def test_a_joint_goal_or_a_start_in_collision_fails_naming_the_contact(registry, tmp_path, box_at, which):
    """A box in the gripper at Ready (the goal) or at Home (the start)."""
    result = run_xml(registry, tmp_path, f"""<SubTree ID="Move to Waypoint" waypoint_name="Home"/>
      <CreatePoseStamped position_xyz="{box_at}" pose_stamped="{{box_pose}}"/>
      <AddCollisionBox object_id="box" dimensions="0.05;0.05;0.05" pose="{{box_pose}}"/>
      <RetrieveWaypoint waypoint_name="Ready" waypoint_joint_state="{{ready}}"/>
      <PlanToJointGoal name="plan" joint_goal="{{ready}}" link_padding="0.01"/>""")
    assert (result.status, result.failing_node) == ("FAILURE", "plan")
    assert result.reason.startswith(f"the {which} state is in collision: world collision ")
    assert " vs box: " in result.reason


def test_a_task_with_no_stages_is_an_error(registry, tmp_path):
    result = run_xml(registry, tmp_path, """<InitializeMTCTask task_id="empty" task="{mtc_task}"/>
      <PlanMTCTask name="plan" task="{mtc_task}" solution="{mtc_solution}"/>""")
    assert (result.status, result.failing_node) == ("ERROR", "PlanMTCTask 'plan'")
    assert result.reason.endswith("task 'empty' has no stages: add SetupMTCCurrentState and the motions to plan")


def test_an_unknown_planning_group_or_frame_is_an_error_where_it_is_written(registry, tmp_path):
    group = run_xml(registry, tmp_path, mtc(to_pose("0.15;0.45;0.12", planning_group_name="arm")))
    assert (group.status, group.failing_node) == ("ERROR", "SetupMTCPlanToPose 'reach'")
    assert group.reason.endswith("SetupMTCPlanToPose 'reach': port 'planning_group_name': unknown joint group 'arm' (joint groups: gripper, manipulator)")
    frame = run_xml(registry, tmp_path, mtc(to_pose("0.15;0.45;0.12").replace('ik_frame="tcp"', 'ik_frame="grasp_link"')))
    assert (frame.status, frame.failing_node) == ("ERROR", "SetupMTCPlanToPose 'reach'")
    assert "SetupMTCPlanToPose 'reach': port 'ik_frame': unknown frame 'grasp_link' (" in frame.reason


def test_a_search_that_runs_out_fails_naming_the_stage(registry, tmp_path):
    iterations = run_xml(registry, tmp_path, WALL.replace("{wall_pose}", "{w}") + mtc(
        to_pose(LEFT) + to_pose(RIGHT, max_iterations="1", link_padding="0.01").replace('name="reach"', 'name="across"')))
    assert (iterations.status, iterations.failing_node) == ("FAILURE", "plan")
    assert "SetupMTCPlanToPose 'across'" in iterations.reason
    assert "no collision-free path found in 1 iterations (" in iterations.reason
    timeout = run_xml(registry, tmp_path, mtc(to_pose(LEFT)).replace('task_id="bad"', 'task_id="bad" timeout="0.000001"'))
    assert (timeout.status, timeout.failing_node) == ("FAILURE", "plan")
    assert "the task's planning timeout ran out before this stage (1e-06 s, InitializeMTCTask timeout)" in timeout.reason


@pytest.mark.parametrize("answer, status", [(True, "SUCCESS"), (False, "FAILURE")])
def test_approval_can_be_required_through_a_service(answer, status):
    from std_srvs.srv import SetBool

    from behaviors.mtc import MTCSolution, WaitForMTCSolutionApproval
    from runtime.tree.behavior import Status
    from runtime.tree.blackboard import Blackboard
    from tests.test_scene_behaviors import make_context, make_node, tick

    context = make_context(None)
    blackboard = Blackboard()
    blackboard.set("mtc_solution", MTCSolution("pick", ()))
    headless = make_node(WaitForMTCSolutionApproval, context, blackboard)
    assert tick(headless) is Status.SUCCESS
    node = make_node(WaitForMTCSolutionApproval, context, blackboard, require_approval="true")
    assert tick(node) is Status.RUNNING
    assert tick(node) is Status.RUNNING
    client = context.bus.create_client("/approve_mtc_solution", SetBool)
    assert client.service_is_ready()
    client.call_async(SetBool.Request(data=answer))
    context.bus.spin_once()
    assert tick(node) is Status[status]
    if not answer:
        assert node.feedback_message == "the solution was rejected through '/approve_mtc_solution'"
    late = client.call_async(SetBool.Request(data=True))  # served to the end of the run, answering no one
    context.clock.advance(0.1)
    context.bus.spin_once()
    assert late.result().success is False and late.result().message == "no MTC solution is waiting for approval"


# -- the example Objective: park, a box between the arm and the cubes, around it to Home, the policy ---
EXAMPLE = Path(__file__).resolve().parent.parent / "objectives" / "examples" / "plan_around_a_box.xml"
PARK, BARRIER_SIZE, BARRIER_AT = "-0.5;0.25;0.12", (0.04, 0.3, 0.25), (-0.36, 0.35, 0.125)


def test_the_barrier_of_the_example_blocks_the_straight_move_from_the_park_to_home():
    from runtime.motion.scene import Box, pose_matrix
    from runtime.motion.scene.planner import motion_is_free, scene_validity

    assert f'position_xyz="{PARK}"' in EXAMPLE.read_text()
    assert 'dimensions="0.04;0.3;0.25" position_xyz="-0.36;0.35;0.125"' in EXAMPLE.read_text()
    scene = cell_scene()
    scene.add_object("barrier", Box(BARRIER_SIZE), pose_matrix(BARRIER_AT))
    is_free = scene_validity(scene, scene.layout("manipulator", None), 0.01, scene.snapshot(), None)
    assert not motion_is_free(is_free, np.array(ik_down_at(PARK)), load_home(), 0.01)


@pytest.mark.parametrize("world", ["kinematic", "vla_sim"])
def test_the_example_plans_around_the_box_then_the_policy_stacks_the_cubes(registry, world):
    result = run_file(EXAMPLE, registry, RunOptions(world=world, seed=0, max_seconds=120.0))
    assert (result.status, result.reason) == ("SUCCESS", "")


@pytest.mark.ros
@pytest.mark.timeout(120)
def test_the_example_plans_around_the_box_over_ros(tmp_path):
    """The example up to Home (the policy is served by an adapter over ROS: not here), run with
    ``--ros``: the MTC task and the planned Move to Waypoint drive the hosted cell's controllers
    over a real ROS 2 graph (loopback)."""
    import os
    import random
    import subprocess
    import sys

    text = EXAMPLE.read_text()
    cut = text[:text.index("      <SetCollisionRule")] + "    </Sequence>\n  </BehaviorTree>\n</root>\n"
    tree = tmp_path / "to_home.xml"
    tree.write_text(cut)
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(100, 199)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    proc = subprocess.run([sys.executable, "-m", "runtime.app.cli", "run", str(tree), "--ros", "--world", "kinematic"],
                          cwd=EXAMPLE.parents[2], env=env, capture_output=True, text=True, timeout=100)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("SUCCESS after ")


def test_a_task_out_of_order_is_an_error_naming_the_stage(registry, tmp_path):
    late = run_xml(registry, tmp_path, """<InitializeMTCTask task_id="late" task="{mtc_task}"/>
      <SetupMTCSetCollisionRule task="{mtc_task}" name_a="gripper" name_b="cube_red"/>
      <SetupMTCCurrentState task="{mtc_task}"/>
      <PlanMTCTask name="plan" task="{mtc_task}" solution="{mtc_solution}"/>""")
    assert (late.status, late.failing_node) == ("ERROR", "PlanMTCTask 'plan'")
    assert "task 'late' must start with SetupMTCCurrentState, got SetupMTCSetCollisionRule (" in late.reason
    alone = run_xml(registry, tmp_path, mtc('<SetupMTCConnectWithProRRT task="{mtc_task}"/>', "alone"))
    assert (alone.status, alone.failing_node) == ("ERROR", "PlanMTCTask 'plan'")
    assert alone.reason.endswith(": a connect stage needs a SetupMTCBatchPoseIK after it to connect to")
    octomap = run_xml(registry, tmp_path, mtc('<SetupMTCSetCollisionRule name="rule" task="{mtc_task}" name_a="gripper" name_b="&lt;octomap&gt;"/>'))
    assert (octomap.status, octomap.failing_node) == ("ERROR", "SetupMTCSetCollisionRule 'rule'")
    assert octomap.reason.endswith("'<octomap>' is not in this planning scene: it has no octomap (point clouds are not kept here)")


def test_a_joint_goal_without_the_group_joints_fails_naming_them():
    from sensor_msgs.msg import JointState

    from behaviors.trajectory_goal import PlanningError
    from behaviors.planning import group_goal

    assert list(group_goal(JointState(name=["b", "a"], position=[2.0, 1.0]), ("a", "b"), "joint_goal")) == [1.0, 2.0]
    with pytest.raises(PlanningError, match="^joint_goal: the joint state lacks b, c$"):
        group_goal(JointState(name=["a"], position=[1.0]), ("a", "b", "c"), "joint_goal")
    with pytest.raises(PlanningError, match="^port 'joint_state' expects a sensor_msgs/JointState, got list$"):
        group_goal([1.0], ("a",), "joint_state")


@pytest.mark.ros
@pytest.mark.timeout(120)
def test_approval_is_asked_for_over_ros_and_a_rejection_fails_the_run(tmp_path, monkeypatch):
    """``require_approval="true"`` on a run with ``--ros``: the runner serves /approve_mtc_solution
    while it waits; another node's ``data: false`` fails the node, the arm never moving."""
    import os
    import random
    import subprocess
    import sys
    import time

    from std_srvs.srv import SetBool

    from runtime.io.clock import WallClock
    from runtime.io.ros import RosBus

    tree = tmp_path / "approve.xml"
    tree.write_text(f"""<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main"><Sequence>
      {plan_to_pose(LEFT, "left", execute="")}
      </Sequence></BehaviorTree></root>""".replace("<WaitForMTCSolutionApproval", '<WaitForMTCSolutionApproval name="ask" require_approval="true"'))
    monkeypatch.setenv("ROS_DOMAIN_ID", str(random.randint(100, 199)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env = dict(os.environ)
    runner = subprocess.Popen([sys.executable, "-m", "runtime.app.cli", "run", str(tree), "--ros", "--world", "kinematic"],
                              cwd=EXAMPLE.parents[2], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    bus = RosBus(WallClock(), node_name="test_approver")
    try:
        client = bus.create_client("/approve_mtc_solution", SetBool)
        deadline = time.monotonic() + 60.0
        while not client.service_is_ready():
            assert time.monotonic() < deadline, "the runner never served /approve_mtc_solution"
            bus.spin_once()
            time.sleep(0.05)
        future = client.call_async(SetBool.Request(data=False))
        while not future.done():
            assert time.monotonic() < deadline, "no answer from /approve_mtc_solution"
            bus.spin_once()
            time.sleep(0.02)
        assert future.result().message == "rejected"
        _, err = runner.communicate(timeout=60)
    finally:
        if runner.poll() is None:
            runner.kill()
            runner.communicate()
        bus.close()
    assert runner.returncode == 1, err
    assert "the solution was rejected through '/approve_mtc_solution'" in err.strip().splitlines()[-1]


def test_two_nodes_waiting_on_one_approval_service_is_an_error():
    from behaviors.mtc import MTCSolution, WaitForMTCSolutionApproval
    from runtime.tree.behavior import Status
    from runtime.tree.blackboard import Blackboard
    from runtime.errors import SetupError
    from tests.test_scene_behaviors import make_context, make_node, tick

    context = make_context(None)
    blackboard = Blackboard()
    blackboard.set("mtc_solution", MTCSolution("pick", ()))
    first = make_node(WaitForMTCSolutionApproval, context, blackboard, require_approval="true")
    second = make_node(WaitForMTCSolutionApproval, context, blackboard, require_approval="true")
    assert tick(first) is Status.RUNNING
    with pytest.raises(SetupError, match="^'/approve_mtc_solution' is already waiting for WaitForMTCSolutionApproval: give each"):
        tick(second)


def test_a_solution_replayed_from_elsewhere_fails_naming_the_gap(registry, tmp_path):
    result = run_xml(registry, tmp_path, f"""<SubTree ID="Move to Waypoint" waypoint_name="Home"/>
      {plan_to_pose(LEFT, "left")}
      <InitializeMTCTask task_id="again" task="{{replay_task}}"/>
      <SetupMTCFromSolution name="replay" task="{{replay_task}}" solution="{{mtc_solution}}"/>
      <PlanMTCTask name="plan" task="{{replay_task}}" solution="{{replayed}}"/>""")
    assert (result.status, result.failing_node) == ("FAILURE", "plan")
    assert result.reason.startswith(f"task 'again': SetupMTCFromSolution 'replay' ({tmp_path / 'tree.xml'}:")
    assert "rad away from the arm's current position (at most 0.01 rad)" in result.reason


@pytest.mark.parametrize("world, seed", [("kinematic", 0), ("vla_sim", 3)])
def test_the_mtc_pick_and_place_example_stacks_the_cubes(registry, world, seed):
    """MoveIt Pro-style Objective for this cell: approaches as connect + approach + batch IK tasks."""
    path = EXAMPLE.parent / "mtc_pick_and_place.xml"
    result = run_file(path, registry, RunOptions(world=world, seed=seed, max_seconds=60.0))
    assert (result.status, result.reason) == ("SUCCESS", "")

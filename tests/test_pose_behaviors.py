"""GetObjectPose, GetLatestTransform, TransformPose, IsPoseNearIdentity, CheckObjectStacked and
the `Check if One Cube Is on Another` SubTree, against the cell's planning scene."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState

from behaviors import poses
from behaviors.poses import (
    CheckObjectStacked,
    GetLatestTransform,
    GetObjectPose,
    IsPoseNearIdentity,
    TransformPose,
    matrix_to_pose,
    pose_to_matrix,
    stack_check,
)
from runtime.tree import builtin
from runtime.errors import SetupError
from runtime.tree.behavior import RunContext, Status
from runtime.tree.blackboard import Blackboard
from runtime.tree.loader import load_tree
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, make_context as make_run_context, run_tree
from runtime.motion.scene.collision import pose_matrix
from runtime.motion.scene.scene import PlanningScene
from sim.robot_model import ARM_JOINTS
from tests.test_scene_behaviors import HOME, make_context, make_node, make_scene, publish_joint_states, robot, tick  # noqa: F401

OBJECTIVES = Path(__file__).resolve().parent.parent / "objectives"
CUBE = 0.03


@pytest.fixture
def scene(robot) -> PlanningScene:
    return make_scene(robot)


@pytest.fixture
def context(scene) -> RunContext:
    return make_context(scene)


def rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def pose(x: float, y: float, z: float, rotation: np.ndarray | None = None, frame: str = "world") -> PoseStamped:
    return matrix_to_pose(frame, pose_matrix((x, y, z), rotation))


def position(msg: PoseStamped) -> tuple[float, float, float]:
    p = msg.pose.position
    return (p.x, p.y, p.z)


# -- pure math -------------------------------------------------------------------------------
def test_pose_matrix_round_trip_and_quaternion_spelling():
    m = pose_matrix((0.1, -0.2, 0.3), rot_z(2.5) @ rot_x(-1.0))
    msg = matrix_to_pose("tcp", m, stamp=12.25)
    assert msg.header.frame_id == "tcp"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 250_000_000)
    assert msg.pose.orientation.w >= 0
    np.testing.assert_allclose(pose_to_matrix(msg.pose), m, atol=1e-12)


def test_zero_quaternion_is_refused():
    msg = pose(0, 0, 0)
    msg.pose.orientation.w = 0.0
    with pytest.raises(ValueError, match=r"is not a rotation \(zero length\)"):
        pose_to_matrix(msg.pose)


@pytest.mark.parametrize("top_rotation", [np.eye(3), rot_x(math.pi / 2), rot_x(math.pi) @ rot_z(0.4)])
def test_stack_check_compares_centres_whatever_face_is_down(top_rotation):
    bottom = np.array([0.0, 0.45, 0.015])
    top = bottom + [0.012, 0.0, 0.03]  # 12 mm off the stacked point: inside 15 mm
    answer = stack_check(top, bottom, gripper_position=top + [0, 0, 0.2], stack_height=0.03, position_tolerance=0.015, min_clearance=0.05)
    assert answer.stacked
    assert answer.offset_error == pytest.approx(0.012)
    assert answer.clearance == pytest.approx(0.2)


def test_stack_check_reasons():
    bottom = np.array([0.0, 0.45, 0.015])
    off = stack_check(bottom + [0.0, 0.016, 0.03], bottom, bottom + [0, 0, 0.3], 0.03, 0.015, 0.05)
    assert not off.stacked
    assert off.reason == "not stacked: 16.0 mm from the stacked position (dx +0.0, dy +16.0, dz +0.0 mm), tolerance 15.0 mm"
    held = stack_check(bottom + [0.0, 0.0, 0.03], bottom, bottom + [0, 0, 0.03 + 0.049], 0.03, 0.015, 0.05)
    assert not held.stacked
    assert held.reason == "stacked but the gripper is 49.0 mm from the top object (needs 50.0 mm): not released"
    side_by_side = stack_check(bottom + [0.03, 0.0, 0.0], bottom, bottom + [0, 0, 0.3], 0.03, 0.015, 0.05)
    assert not side_by_side.stacked and side_by_side.offset_error == pytest.approx(math.hypot(0.03, 0.03))


# -- GetObjectPose ---------------------------------------------------------------------------
def test_get_object_pose_writes_a_world_pose(context, scene):
    scene.move_object("cube_red", pose_matrix((-0.1, 0.45, 0.015), rot_z(0.3)))
    board = Blackboard()
    context.clock.advance(1.5)
    node = make_node(GetObjectPose, context, board, object_name="cube_red", pose="{red}")
    assert tick(node) is Status.SUCCESS
    red = board.get("red")
    assert isinstance(red, PoseStamped)
    assert red.header.frame_id == "world" and red.header.stamp.sec == 1 and red.header.stamp.nanosec == 500_000_000
    assert position(red) == pytest.approx((-0.1, 0.45, 0.015))
    np.testing.assert_allclose(pose_to_matrix(red.pose)[:3, :3], rot_z(0.3), atol=1e-12)


def test_get_object_pose_of_an_unknown_object_is_a_setup_error_listing_the_objects(context):
    node = make_node(GetObjectPose, context, object_name="cube_yellow", pose="{p}")
    with pytest.raises(SetupError) as err:  # ERROR: no Retry or Fallback repeats it
        tick(node)
    assert str(err.value) == "no object 'cube_yellow' in the planning scene (objects: cube_blue, cube_green, cube_red, table)"


# -- GetLatestTransform ----------------------------------------------------------------------
def test_latest_transform_of_the_tcp_uses_the_current_joint_states(context, scene):
    board = Blackboard()
    node = make_node(GetLatestTransform, context, board, target_frame="world", source_frame="tcp", transform="{tcp}")
    publish_joint_states(context)
    assert tick(node) is Status.SUCCESS
    tcp = board.get("tcp")
    assert tcp.header.frame_id == "world"
    # Home puts the TCP at (0, 0.45, 0.30), pointing straight down (within the waypoint's rounding).
    assert position(tcp) == pytest.approx((0.0, 0.45, 0.30), abs=2e-3)
    np.testing.assert_allclose(pose_to_matrix(tcp.pose), scene.link_pose(np.array(HOME), "tcp"), atol=1e-12)
    assert pose_to_matrix(tcp.pose)[:3, 2] == pytest.approx((0, 0, -1), abs=1e-2)

    moved = (HOME[0] + 0.2,) + HOME[1:]
    publish_joint_states(context, moved)
    assert tick(node) is Status.SUCCESS
    np.testing.assert_allclose(pose_to_matrix(board.get("tcp").pose), scene.link_pose(np.array(moved), "tcp"), atol=1e-12)


def test_latest_transform_between_an_object_and_a_robot_frame(context, scene):
    board = Blackboard()
    node = make_node(GetLatestTransform, context, board, target_frame="tcp", source_frame="cube_green", transform="{t}")
    publish_joint_states(context)
    assert tick(node) is Status.SUCCESS
    t = board.get("t")
    assert t.header.frame_id == "tcp"
    expected = np.linalg.inv(scene.link_pose(np.array(HOME), "tcp")) @ scene.object_pose("cube_green")
    np.testing.assert_allclose(pose_to_matrix(t.pose), expected, atol=1e-12)
    # The cube lies 28.5 cm below the TCP: along the TCP's z axis, which points down.
    assert position(t)[2] == pytest.approx(0.30 - 0.015, abs=3e-3)


def test_latest_transform_failures_name_the_frame(context):
    unknown = make_node(GetLatestTransform, context, target_frame="world", source_frame="camera_link", transform="{t}")
    no_state = make_node(GetLatestTransform, context, target_frame="world", source_frame="tcp", transform="{t}")
    with pytest.raises(SetupError) as err:
        tick(unknown)
    assert str(err.value).startswith("unknown frame 'camera_link' (known: 'world', robot links (base, shoulder_link,")
    assert str(err.value).endswith("or scene objects (cube_blue, cube_green, cube_red, table))")
    assert tick(no_state) is Status.FAILURE
    assert no_state.feedback_message == "no joint states on '/joint_states' yet"


def test_world_and_objects_need_no_joint_states(context):
    board = Blackboard()
    node = make_node(GetLatestTransform, context, board, target_frame="cube_red", source_frame="cube_blue", transform="{t}")
    assert tick(node) is Status.SUCCESS
    assert position(board.get("t")) == pytest.approx((0.2, 0.0, 0.0))


# -- TransformPose ---------------------------------------------------------------------------
def test_transform_pose_applies_the_offset_in_the_pose_axes_then_changes_frame(context, scene):
    board = Blackboard()
    # A grasp pose for a cube turned 90 degrees about x: its own z axis points along world -y.
    board.set("cube", pose(0.1, 0.45, 0.015, rot_x(math.pi / 2)))
    node = make_node(
        TransformPose, context, board,
        input_pose="{cube}", target_frame_id="world", translation_xyz="0;0;0.1", quaternion_xyzw="1;0;0;0", output_pose="{out}",
    )
    assert tick(node) is Status.SUCCESS
    out = board.get("out")
    assert out.header.frame_id == "world"
    assert position(out) == pytest.approx((0.1, 0.45 - 0.1, 0.015))
    np.testing.assert_allclose(pose_to_matrix(out.pose)[:3, :3], rot_x(math.pi / 2) @ rot_x(math.pi), atol=1e-12)


def test_transform_pose_into_a_robot_frame_round_trips_to_identity(context):
    board = Blackboard()
    lookup = make_node(GetLatestTransform, context, board, target_frame="world", source_frame="tcp", transform="{tcp_in_world}")
    into_tcp = make_node(TransformPose, context, board, input_pose="{tcp_in_world}", target_frame_id="tcp", output_pose="{tcp_in_tcp}")
    near = make_node(IsPoseNearIdentity, context, board, pose="{tcp_in_tcp}", position_tolerance="1e-9", rotation_tolerance="1e-9")
    publish_joint_states(context)
    assert [tick(n) for n in (lookup, into_tcp, near)] == [Status.SUCCESS] * 3


def test_transform_pose_bad_input(context):
    board = Blackboard()
    board.set("text", "not a pose")
    board.set("p", pose(0, 0, 0))
    wrong_type = make_node(TransformPose, context, board, input_pose="{text}", output_pose="{o}")
    assert tick(wrong_type) is Status.FAILURE
    assert wrong_type.feedback_message == "port 'input_pose' expects a geometry_msgs/PoseStamped, got str"
    short = make_node(TransformPose, context, board, input_pose="{p}", translation_xyz="0;1", output_pose="{o}")
    assert tick(short) is Status.FAILURE
    assert short.feedback_message == "translation_xyz needs 3 values (x;y;z), got 2"
    zero = make_node(TransformPose, context, board, input_pose="{p}", quaternion_xyzw="0;0;0;0", output_pose="{o}")
    assert tick(zero) is Status.FAILURE
    assert zero.feedback_message == "quaternion_xyzw [0.0, 0.0, 0.0, 0.0] is not a rotation (zero length)"
    board.set("q", pose(0, 0, 0, frame="gripper_finger"))
    unknown = make_node(TransformPose, context, board, input_pose="{q}", output_pose="{o}")
    with pytest.raises(SetupError, match="^unknown frame 'gripper_finger'"):
        tick(unknown)


# -- IsPoseNearIdentity ----------------------------------------------------------------------
@pytest.mark.parametrize(
    ("msg", "expected"),
    [
        (pose(0.006, 0.0, -0.008), Status.SUCCESS),  # 10.0 mm: on the tolerance
        (pose(0.0, 0.0101, 0.0), Status.FAILURE),
        (pose(0.0, 0.0, 0.0, rot_z(0.0099)), Status.SUCCESS),
        (pose(0.0, 0.0, 0.0, rot_x(-0.0101)), Status.FAILURE),
    ],
)
def test_near_identity_default_tolerances(context, msg, expected):
    board = Blackboard()
    board.set("p", msg)
    node = make_node(IsPoseNearIdentity, context, board, pose="{p}")
    assert tick(node) is expected


def test_near_identity_messages(context):
    board = Blackboard()
    board.set("p", pose(0.02, 0.0, 0.0, rot_z(0.5)))
    node = make_node(IsPoseNearIdentity, context, board, pose="{p}", position_tolerance="0.05", rotation_tolerance="0.1")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "not near identity: position 20.0 mm (tolerance 50.0), rotation 0.5000 rad (tolerance 0.1000)"
    board.set("p", [1, 2, 3])
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "port 'pose' expects a geometry_msgs/PoseStamped, got list"


# -- CheckObjectStacked --------------------------------------------------------------------------
def place_on_green(scene: PlanningScene, dx: float = 0.0, rotation: np.ndarray | None = None) -> None:
    green = scene.object_pose("cube_green")[:3, 3]
    scene.move_object("cube_blue", pose_matrix(green + [dx, 0.0, CUBE], rotation))


def check_node(context, **ports):
    return make_node(CheckObjectStacked, context, top_object_name="cube_blue", bottom_object_name="cube_green", **ports)


def test_cubes_apart_are_not_stacked(context):
    node = check_node(context)
    publish_joint_states(context)
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == (
        "cube_blue on cube_green: not stacked: 104.4 mm from the stacked position (dx +100.0, dy +0.0, dz -30.0 mm), tolerance 15.0 mm"
    )


def test_blue_on_green_with_the_gripper_away_is_stacked(context, scene):
    place_on_green(scene, dx=0.01, rotation=rot_x(math.pi / 2) @ rot_z(0.3))
    node = check_node(context)
    publish_joint_states(context)
    assert tick(node) is Status.SUCCESS
    assert node.feedback_message.startswith("cube_blue on cube_green: stacked: 10.0 mm from the stacked position")


def test_a_cube_still_held_above_is_not_stacked(context, scene):
    # The cube sits at the TCP (held in the fingers) right above the green one.
    node = check_node(context)
    publish_joint_states(context)
    tcp = scene.link_pose(np.array(HOME), "tcp")
    scene.move_object("cube_green", pose_matrix(tcp[:3, 3] - [0.0, 0.0, CUBE]))
    scene.move_object("cube_blue", tcp)
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == (
        "cube_blue on cube_green: stacked but the gripper is 0.0 mm from the top object (needs 50.0 mm): not released"
    )


def test_same_object_twice_is_refused(context):
    node = make_node(CheckObjectStacked, context, top_object_name="cube_red", bottom_object_name="cube_red")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "top_object_name and bottom_object_name are both 'cube_red'"


# -- the SubTree, run by the runner against a minimal world -----------------------------------------
class SceneOnlyWorld:
    """A world that only fills the planning scene and publishes joint states every step."""

    name = "scene_only"

    def __init__(self, scene: PlanningScene) -> None:
        self.scene = scene

    def start(self, context: RunContext) -> None:
        context.scene = self.scene
        self.publisher = context.bus.create_publisher("/joint_states", JointState)

    def step_to(self, t: float) -> None:
        self.publisher.publish(JointState(name=list(ARM_JOINTS), position=list(HOME)))

    def reset(self, seed: int) -> None:
        pass

    def summary(self) -> dict:
        return {}

    def close(self) -> None:
        pass


@pytest.fixture(scope="module")
def registry() -> Registry:
    registry = Registry()
    builtin.register(registry)
    registry.register_all(poses.NODES)
    return registry


def run_check(registry, scene, tmp_path, subtree: str = '<SubTree ID="Check if One Cube Is on Another"/>'):
    path = tmp_path / "check.xml"
    path.write_text(f'<root BTCPP_format="4"><BehaviorTree ID="Main">{subtree}</BehaviorTree></root>')
    options = RunOptions(max_seconds=1.0)
    context = make_run_context(options)
    loaded = load_tree(path, registry, context, objectives_dir=OBJECTIVES)
    return run_tree(loaded, context, options, world=SceneOnlyWorld(scene))


def test_subtree_defaults_check_blue_on_green(registry, scene, tmp_path):
    apart = run_check(registry, scene, tmp_path)
    assert (apart.status, apart.ticks, apart.failing_node) == ("FAILURE", 1, "top cube on bottom cube")
    assert apart.reason.startswith("cube_blue on cube_green: not stacked: 104.4 mm")
    place_on_green(scene)
    stacked = run_check(registry, scene, tmp_path)
    assert (stacked.status, stacked.ticks) == ("SUCCESS", 1)


def test_subtree_colors_are_ports(registry, scene, tmp_path):
    place_on_green(scene)  # blue on green, so red on blue is not
    result = run_check(registry, scene, tmp_path, '<SubTree ID="Check if One Cube Is on Another" top_color="red" bottom_color="blue"/>')
    assert result.status == "FAILURE"
    assert result.reason.startswith("cube_red on cube_blue: not stacked")


def test_subtree_guards_a_reactive_fallback(registry, scene, tmp_path):
    # Once the check passes, the ReactiveFallback stops ticking its RUNNING branch.
    subtree = """<ReactiveFallback>
      <SubTree ID="Check if One Cube Is on Another"/>
      <Sequence><Script code="polls := 1"/><Wait seconds="10"/></Sequence>
    </ReactiveFallback>"""
    place_on_green(scene)
    result = run_check(registry, scene, tmp_path, subtree)
    assert (result.status, result.ticks) == ("SUCCESS", 1)
    assert "polls" not in result.blackboard


# -- MoveToPose (IK + a checked joint motion) against a controller that records the goal ----------
class RecordingController:
    """Accepts one trajectory goal, remembers it and reports success at once."""

    def __init__(self, context: RunContext) -> None:
        from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance

        self.goals: list = []
        self.result_type = FollowJointTrajectoryWithAdmittance.Result
        context.bus.create_action_server(
            "/joint_trajectory_admittance_controller/follow_joint_trajectory", FollowJointTrajectoryWithAdmittance, self.on_goal
        )

    def on_goal(self, handle) -> bool:
        self.goals.append(handle.request)
        handle.succeed(self.result_type())
        return True


@pytest.fixture
def motion_context(robot) -> RunContext:
    from runtime.motion.scene.limits import load_joint_limits
    from sim.robot_model import GRIPPER_DRIVER_JOINT, JOINT_LIMITS_PATH

    joints = ARM_JOINTS + (GRIPPER_DRIVER_JOINT,)
    limits = load_joint_limits(JOINT_LIMITS_PATH, dict(zip(joints, zip(*robot.position_limits(joints)))))
    scene = make_scene(robot)
    scene.limits = limits
    return make_context(scene)


def run_move(context: RunContext, board: Blackboard, **ports) -> tuple[Status, object, RecordingController]:
    from behaviors.motion_pose import MoveToPose

    controller = RecordingController(context)
    node = make_node(MoveToPose, context, board, **ports)
    status = Status.RUNNING
    for _ in range(5):
        status = tick(node)
        publish_joint_states(context)
        if status is not Status.RUNNING:
            break
    return status, node, controller


def test_move_to_pose_puts_the_tcp_above_the_cube(motion_context):
    board = Blackboard()
    scene = motion_context.scene
    flip = pose_matrix((0.0, 0.0, 0.1), rot_x(math.pi))  # 10 cm above, pointing down
    board.set("target", matrix_to_pose("cube_blue", flip))
    status, node, controller = run_move(motion_context, board, target_pose="{target}")
    assert status is Status.SUCCESS, node.feedback_message
    (goal,) = controller.goals
    final = np.array(goal.joint_trajectory.points[-1].positions)
    reached = scene.link_pose(final, "tcp")
    np.testing.assert_allclose(reached[:3, 3], scene.object_pose("cube_blue")[:3, 3] + [0, 0, 0.1], atol=5e-4)
    assert reached[:3, 2] == pytest.approx((0, 0, -1), abs=5e-3)
    first = np.array(goal.joint_trajectory.points[0].positions)
    np.testing.assert_allclose(first, HOME, atol=1e-9)  # starts where the robot is


def test_move_to_pose_out_of_reach_fails_with_the_ik_error(motion_context):
    board = Blackboard()
    board.set("far", pose(2.0, 0.0, 0.5))
    status, node, controller = run_move(motion_context, board, target_pose="{far}")
    assert status is Status.FAILURE
    assert node.feedback_message.startswith("no IK solution puts 'tcp' at (2.000, 0.000, 0.500) in 'world': best is ")
    assert controller.goals == []


def test_move_to_pose_refuses_a_colliding_target(motion_context):
    board = Blackboard()
    for cube in ("cube_red", "cube_green", "cube_blue"):
        motion_context.scene.remove_object(cube)  # only the table is in the way
    board.set("into_table", pose(0.0, 0.45, 0.0, rot_x(math.pi)))  # the TCP at the table top
    status, node, controller = run_move(motion_context, board, target_pose="{into_table}")
    assert status is Status.FAILURE
    assert node.feedback_message.startswith("the motion would collide: step ")
    assert "vs table" in node.feedback_message
    assert controller.goals == []


# -- end to end: the shipped Objective on the kinematic cell ------------------------------------
def test_check_objective_fails_on_the_initial_layout():
    from runtime.app.runner import run_file

    result = run_file(OBJECTIVES / "check_cube_on_cube.xml", Registry.from_entry_points(), RunOptions(seed=0, world="kinematic"))
    assert (result.status, result.ticks, result.failing_node) == ("FAILURE", 1, "top cube on bottom cube")
    assert result.reason.startswith("cube_blue on cube_green: not stacked: ")
    assert result.reason.endswith("tolerance 15.0 mm")


@pytest.mark.parametrize(
    ("instance", "status", "reason"),
    [
        ('<SubTree ID="Move to Waypoint"/>', "SUCCESS", ""),  # the default: Home
        ('<SubTree ID="Move to Waypoint" waypoint_name="Observe"/>', "SUCCESS", ""),
        # A waypoint the cell does not have: ERROR before anything moves, at the line of the SubTree call.
        ('<SubTree ID="Move to Waypoint" waypoint_name="Nowhere"/>', "ERROR",
         "move.xml:3: SubTree 'Move to Waypoint': objectives/move_to_waypoint.xml:18: MoveToWaypoint: "
         "port 'waypoint_name': unknown waypoint 'Nowhere' (waypoints: Home, Observe, Ready)"),
    ],
)
def test_move_to_waypoint_subtree_on_the_cell(tmp_path, instance, status, reason):
    from runtime.app.runner import run_file

    path = tmp_path / "move.xml"
    path.write_text(f"""<root BTCPP_format="4"><BehaviorTree ID="Main"><Sequence>
      <SwitchController activate_controllers="joint_trajectory_admittance_controller" deactivate_controllers="velocity_force_controller"/>
      {instance}
    </Sequence></BehaviorTree></root>""")
    result = run_file(path, Registry.from_entry_points(), RunOptions(world="kinematic", max_seconds=20.0))
    assert result.status == status and result.reason.endswith(reason), result.reason

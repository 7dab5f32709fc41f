"""SetCollisionRule, AttachObject, DetachObject and ResetSim against a real planning scene.

The scene is the cell's own robot model (sim/robot_model.py + sim/config) with the table and
three cubes as world objects; joint states come over an InProcessBus, as the cell publishes them.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sensor_msgs.msg import JointState

from behaviors.scene import AttachObject, DetachObject, SetCollisionRule
from behaviors.sim_control import ResetSim
from runtime.tree.behavior import RunContext, Status
from runtime.tree.blackboard import Blackboard
from runtime.io.bus import InProcessBus
from runtime.io.clock import SimClock
from runtime.tree.events import EventLog
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, RunResult, run_file
from runtime.motion.scene.collision import Box, pose_matrix
from runtime.motion.scene.model import RobotModel
from runtime.motion.scene.scene import PlanningScene
from sim.layouts import layout
from sim.robot_model import ARM_JOINTS, GRIPPER_DRIVER_JOINT, WAYPOINTS_PATH, load_waypoints, planning_robot_model

HOME = tuple(load_waypoints(WAYPOINTS_PATH)["Home"][j] for j in ARM_JOINTS)
"""The cell's Home waypoint: TCP pointing straight down at (0, 0.45, 0.30)."""
CUBE = 0.03
CUBES = {"cube_red": (-0.1, 0.45), "cube_green": (0.0, 0.45), "cube_blue": (0.1, 0.45)}


@pytest.fixture(scope="session")
def robot() -> RobotModel:
    return planning_robot_model()


def make_scene(robot: RobotModel) -> PlanningScene:
    scene = PlanningScene(robot, "manipulator", GRIPPER_DRIVER_JOINT)
    scene.add_object("table", Box((1.2, 1.1, 0.04)), pose_matrix((0.0, 0.3, -0.02)), fixed=True)
    scene.allow("table", ["base", "shoulder_link"])  # the robot stands on the table
    for name, (x, y) in CUBES.items():
        scene.add_object(name, Box((CUBE, CUBE, CUBE)), pose_matrix((x, y, CUBE / 2)))
    return scene


class FakeWorld:
    """Records resets; ``refuse`` makes reset raise as a world does for a bad seed."""

    def __init__(self, refuse: str | None = None) -> None:
        self.resets: list[int] = []
        self.refuse = refuse

    def reset(self, seed: int) -> None:
        if self.refuse:
            raise ValueError(self.refuse)
        self.resets.append(seed)


def make_context(scene: PlanningScene | None, world: Any = None) -> RunContext:
    clock = SimClock()
    return RunContext(clock=clock, bus=InProcessBus(clock), events=EventLog(clock), scene=scene, world=world)


def publish_joint_states(context: RunContext, arm: tuple[float, ...] = HOME, gripper: float = 0.0) -> None:
    """What the cell publishes: the arm joints, then the gripper under its ROS name."""
    publisher = context.bus.create_publisher("/joint_states", JointState)
    publisher.publish(JointState(name=list(ARM_JOINTS) + [GRIPPER_DRIVER_JOINT], position=list(arm) + [gripper]))


def make_node(cls: type, context: RunContext, blackboard: Blackboard | None = None, **ports: str) -> Any:
    node = cls(cls.__name__)
    node.bind(context, blackboard or Blackboard(), ports)
    node.setup()
    return node


def tick(node: Any) -> Status:
    node.tick_once()
    return node.status


@pytest.fixture
def scene(robot) -> PlanningScene:
    return make_scene(robot)


@pytest.fixture
def context(scene) -> RunContext:
    ctx = make_context(scene)
    return ctx


# -- SetCollisionRule ---------------------------------------------------------------------------
def test_allow_a_group_then_forbid_it_again(context, scene):
    gripper_links = scene.robot.group("gripper").links
    node = make_node(SetCollisionRule, context, object_name="cube_blue", link_names="gripper")
    assert tick(node) is Status.SUCCESS
    assert all(scene.is_allowed("cube_blue", link) for link in gripper_links)
    assert not scene.is_allowed("cube_red", "gripper_left_pad")
    assert not scene.is_allowed("cube_blue", "wrist_3_link")
    assert node.feedback_message == "allowed contact between cube_blue and gripper"

    forbid = make_node(SetCollisionRule, context, object_name="cube_blue", link_names="gripper", allow="false")
    assert tick(forbid) is Status.SUCCESS
    assert not any(scene.is_allowed("cube_blue", link) for link in gripper_links)


def test_star_allows_the_objects_in_the_scene_now_but_never_the_table(context, scene):
    node = make_node(SetCollisionRule, context, object_name="*", link_names="gripper_left_pad;gripper_right_pad")
    assert tick(node) is Status.SUCCESS
    assert node.feedback_message == "allowed contact between cube_blue, cube_green, cube_red and gripper_left_pad, gripper_right_pad"
    for obj in ("cube_red", "cube_green", "cube_blue"):
        assert scene.is_allowed(obj, "gripper_left_pad") and scene.is_allowed(obj, "gripper_right_pad")
    assert not scene.is_allowed("table", "gripper_left_pad")  # fixed: a rule must name it
    scene.add_object("box", Box((0.1, 0.1, 0.1)), np.eye(4))
    assert not scene.is_allowed("box", "gripper_left_pad")  # appeared after the rule: an obstacle
    forbid = make_node(SetCollisionRule, context, object_name="*", link_names="gripper", allow="false")
    assert tick(forbid) is Status.SUCCESS
    assert not any(scene.is_allowed(obj, "gripper_left_pad") for obj in ("cube_red", "cube_green", "cube_blue", "box"))
    named = make_node(SetCollisionRule, context, object_name="table", link_names="gripper_left_pad")
    assert tick(named) is Status.SUCCESS and scene.is_allowed("table", "gripper_left_pad")


def test_allowed_contact_changes_what_the_collision_check_reports(context, scene):
    # The blue cube between the fingers, closed on it at Home: a collision until the rule allows it.
    row = np.array(HOME + (0.8,))
    scene.move_object("cube_blue", scene.link_pose(row, "tcp"))
    hit = scene.check_state(row, padding=0.0)
    assert hit is not None and "cube_blue" in (hit.first, hit.second)
    assert tick(make_node(SetCollisionRule, context, object_name="cube_blue", link_names="gripper")) is Status.SUCCESS
    assert scene.check_state(row, padding=0.0) is None


def test_unknown_object_fails_and_lists_the_objects(context):
    node = make_node(SetCollisionRule, context, object_name="cube_purple", link_names="gripper")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == (
        "no object 'cube_purple' in the planning scene (objects: cube_blue, cube_green, cube_red, table, or * for all)"
    )


def test_unknown_link_fails_and_lists_links_and_groups(context, scene):
    node = make_node(SetCollisionRule, context, object_name="cube_blue", link_names="gripper_base;left_finger")
    assert tick(node) is Status.FAILURE
    message = node.feedback_message
    assert message.startswith("unknown robot link or group 'left_finger' (links: base, shoulder_link,")
    assert message.endswith("; groups: manipulator, gripper)")
    assert not scene.is_allowed("cube_blue", "gripper_base")  # nothing half-applied


def test_without_a_scene_the_rule_fails_clearly():
    node = make_node(SetCollisionRule, make_context(None), object_name="cube_blue", link_names="gripper")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "this run has no planning scene (no world was started)"


# -- AttachObject / DetachObject --------------------------------------------------------------
def test_attach_carries_the_object_with_the_link_and_detach_leaves_it_there(context, scene):
    home = np.array(HOME + (0.0,))
    scene.move_object("cube_blue", scene.link_pose(home, "tcp"))
    attach = make_node(AttachObject, context, object_name="cube_blue", link_name="gripper_base", touch_links="gripper")
    detach = make_node(DetachObject, context, object_name="cube_blue")
    publish_joint_states(context)  # after the nodes subscribed, as the cell publishes every step
    assert tick(attach) is Status.SUCCESS
    assert attach.feedback_message == "'cube_blue' attached to 'gripper_base'"
    (attachment,) = scene.attachments
    assert (attachment.name, attachment.link) == ("cube_blue", "gripper_base")
    assert "gripper_left_pad" in attachment.touch_links
    assert "cube_blue" not in scene.objects

    # The arm moves (shoulder pan +0.3 rad): the carried cube moves with the hand.
    moved = (HOME[0] + 0.3,) + HOME[1:]
    publish_joint_states(context, moved)
    expected = scene.link_pose(np.array(moved + (0.0,)), "tcp")
    np.testing.assert_allclose(scene.object_world_pose("cube_blue", np.array(moved + (0.0,))), expected, atol=1e-9)

    assert tick(detach) is Status.SUCCESS
    assert scene.attachments == ()
    np.testing.assert_allclose(scene.object_pose("cube_blue"), expected, atol=1e-9)


def test_attach_needs_joint_states(context):
    node = make_node(AttachObject, context, object_name="cube_blue", link_name="gripper_base")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "cannot attach 'cube_blue': no joint states on '/joint_states' yet"


def test_attach_refuses_unknown_names(context):
    node = make_node(AttachObject, context, object_name="cube_blue", link_name="hand")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message.startswith("'hand' is not a robot link (links: base, shoulder_link,")
    node = make_node(AttachObject, context, object_name="sphere", link_name="gripper_base")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "no world object 'sphere' in the planning scene (objects: cube_blue, cube_green, cube_red, table)"


def test_attach_twice_and_detach_unattached_fail(context):
    first = make_node(AttachObject, context, object_name="cube_red", link_name="gripper_base")
    again = make_node(AttachObject, context, object_name="cube_red", link_name="wrist_3_link")
    publish_joint_states(context)
    assert tick(first) is Status.SUCCESS
    assert tick(again) is Status.FAILURE
    assert again.feedback_message == "'cube_red' is already attached to 'gripper_base'"
    detach = make_node(DetachObject, context, object_name="cube_green")
    assert tick(detach) is Status.FAILURE
    assert detach.feedback_message == "'cube_green' is not attached (attached objects: cube_red)"


# -- ResetSim ---------------------------------------------------------------------------------------
def test_reset_sim_resets_then_succeeds_on_the_next_tick(scene):
    world = FakeWorld()
    node = make_node(ResetSim, make_context(scene, world), seed="7")
    assert tick(node) is Status.RUNNING
    assert world.resets == [7]
    assert tick(node) is Status.SUCCESS
    assert world.resets == [7]
    assert node.feedback_message == "world reset with seed 7"


def test_reset_sim_default_seed_is_zero(scene):
    world = FakeWorld()
    node = make_node(ResetSim, make_context(scene, world))
    tick(node)
    assert world.resets == [0]


def test_reset_sim_without_a_world_fails(scene):
    node = make_node(ResetSim, make_context(scene, None), seed="1")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "this run hosts no simulated world to reset (ResetSim works only against a simulated cell)"


def test_reset_sim_reports_a_refused_seed(scene):
    node = make_node(ResetSim, make_context(scene, FakeWorld(refuse="no room for cube 'blue'")), seed="3")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "the world refused the reset with seed 3: no room for cube 'blue'"


# -- end to end: `objective run` on the kinematic cell (same controllers and topics, no physics) ---
OBJECTIVES = Path(__file__).resolve().parent.parent / "objectives"


@pytest.fixture(scope="module")
def all_behaviors() -> Registry:
    return Registry.from_entry_points()


def run_on_cell(registry: Registry, source: Path | str, seed: int) -> RunResult:
    return run_file(source, registry, RunOptions(seed=seed, world="kinematic", max_seconds=60.0))


def test_scripted_pick_and_place_stacks_blue_on_green(all_behaviors):
    """Pick with MoveToPose/MoveGripperAction/SetCollisionRule, place, go Home, then the check."""
    result = run_on_cell(all_behaviors, OBJECTIVES / "examples" / "pick_and_place_scripted.xml", seed=3)
    assert (result.status, result.reason) == ("SUCCESS", "")
    cubes = result.extra["world"]["cubes"]
    green, blue = np.array(cubes["green"]), np.array(cubes["blue"])
    assert blue - green == pytest.approx([0.0, 0.0, 0.03], abs=2e-3)
    assert result.extra["world"]["gripper"] < 0.05  # released: the gripper is open again


def test_reset_sim_puts_the_cubes_of_a_new_layout(all_behaviors, tmp_path):
    # Stack, reset with seed 5, then the check fails again: the cubes are back apart.
    path = tmp_path / "reset.xml"
    path.write_text("""<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence>
      <SubTree ID="Pick and Place Scripted"/>
      <ResetSim seed="5"/>
      <SubTree ID="Check if One Cube Is on Another"/>
    </Sequence>
  </BehaviorTree>
</root>""")
    options = RunOptions(seed=3, world="kinematic", max_seconds=60.0)
    result = run_file(path, all_behaviors, options, search_paths=[OBJECTIVES / "examples"])
    assert (result.status, result.failing_node) == ("FAILURE", "top cube on bottom cube")
    assert result.reason.startswith("cube_blue on cube_green: not stacked")
    x, y, _ = layout(5)["blue"]
    assert result.extra["world"]["cubes"]["blue"] == pytest.approx([x, y, 0.015], abs=1e-4)

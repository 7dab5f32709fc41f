"""Collision objects (AddCollisionBox, MoveCollisionObject, RemoveCollisionObject) and boxes placed
in the simulated cell (PlaceSimBox, RemoveSimBox): what they do to the planning scene and the
cell, every bad input, and the shipped example in which an object appears in the path of a
running policy and the robot stops."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from runtime.app.cli import main
from runtime.tree.loader import load_tree
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, make_context, run_tree
from sim.kinematic import KinematicWorld
from sim.mujoco_cell import MujocoCell
from sim.robot_model import ARM_JOINTS, load_waypoints
from sim.world import create_vla_sim

EXAMPLE = Path("objectives/examples/obstacle_appears.xml")
HOME = np.array([load_waypoints()["Home"][j] for j in ARM_JOINTS])
TCP_POSE = '<GetLatestTransform target_frame="world" source_frame="tcp" transform="{tcp}"/>'
"""At the kinematic cell's start (the Ready waypoint) the TCP is at (-0.134, 0.492, 0.332), pointing down."""


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


def run_xml(capsys, tmp_path: Path, body: str, *args: str) -> tuple[int, dict]:
    path = tmp_path / "t.xml"
    path.write_text(f'<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>{body}</Sequence></BehaviorTree></root>')
    code = main(["run", str(path), "--world", "kinematic", "--json", *args])
    return code, json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def box_below_tcp(object_id: str = "box", extra: str = "", offset: str = "0;0;0.2") -> str:
    """A 10 cm box 20 cm below the TCP (the TCP's z points down)."""
    return (f'<TransformPose input_pose="{{tcp}}" translation_xyz="{offset}" output_pose="{{where}}"/>'
            f'<AddCollisionBox object_id="{object_id}" dimensions="0.1;0.1;0.1" pose="{{where}}" {extra}/>')


# -- the planning-scene behaviors ---------------------------------------------------------------
def run_in_world(registry: Registry, body: str) -> tuple[object, object]:
    context = make_context(RunOptions(world="kinematic"))
    world = KinematicWorld({"seed": 0, "policy": "none"})
    xml = f'<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>{body}</Sequence></BehaviorTree></root>'
    return run_tree(load_tree(xml, registry, context), context, RunOptions(world="kinematic"), world=world), context


def test_added_box_sits_where_its_pose_says_and_moves(registry):
    result, context = run_in_world(registry, TCP_POSE + box_below_tcp())
    assert result.status == "SUCCESS", result.reason
    box = context.scene.objects["box"]
    np.testing.assert_allclose(box.matrix[:3, 3], [-0.134, 0.492, 0.132], atol=2e-3)
    assert box.shape.size == (0.1, 0.1, 0.1)
    move = '<TransformPose input_pose="{tcp}" translation_xyz="0;0.1;0.2" output_pose="{moved}"/><MoveCollisionObject object_id="box" pose="{moved}"/>'
    result, context = run_in_world(registry, TCP_POSE + box_below_tcp() + move)
    assert result.status == "SUCCESS", result.reason
    np.testing.assert_allclose(context.scene.objects["box"].matrix[:3, 3], [-0.034, 0.492, 0.132], atol=2e-3)  # TCP y is world +x at Ready


def test_removed_box_is_gone(capsys, tmp_path):
    check = '<GetObjectPose object_name="box" pose="{p}"/>'
    code, summary = run_xml(capsys, tmp_path, TCP_POSE + box_below_tcp() + check + '<RemoveCollisionObject object_id="box"/>' + check)
    assert code == 2 and summary["failing_node"] == "GetObjectPose"  # naming an object the scene lacks: ERROR
    assert "GetObjectPose: no object 'box' in the planning scene (objects: " in summary["reason"]
    assert "box" not in summary["reason"].split("(objects: ")[1]


def test_an_existing_id_needs_overwrite(capsys, tmp_path):
    code, summary = run_xml(capsys, tmp_path, TCP_POSE + box_below_tcp("table"))
    assert code == 1 and summary["failing_node"] == "AddCollisionBox"
    assert summary["reason"] == "object 'table' is already in the planning scene (set overwrite=true to replace it)"
    code, summary = run_xml(capsys, tmp_path, TCP_POSE + box_below_tcp("box") + box_below_tcp("box", 'overwrite="true"', "0;0;0.25"))
    assert code == 0, summary["reason"]


@pytest.mark.parametrize(
    "node, reason",
    [
        ('<AddCollisionBox object_id="box" dimensions="0.1;0.1;0.1" pose="{dims}"/>', "port 'pose' expects a geometry_msgs/PoseStamped, got str"),
        ('<AttachObject object_name="cube_red"/><RemoveCollisionObject object_id="cube_red"/>', "'cube_red' is attached to the robot: detach it (DetachObject) first"),
    ],
)
def test_bad_input_at_run_time_fails_the_node_with_a_reason(capsys, tmp_path, node, reason):
    code, summary = run_xml(capsys, tmp_path, TCP_POSE + node, "--set", "dims=0.1;-0.1;0.1")
    assert code == 1, summary
    assert summary["reason"].startswith(reason), summary["reason"]


@pytest.mark.parametrize("node", ['<RemoveCollisionObject object_id="ghost"/>', '<MoveCollisionObject object_id="ghost" pose="{tcp}"/>'])
def test_an_unknown_object_is_a_setup_error_before_anything_moves(capsys, tmp_path, node):
    code, summary = run_xml(capsys, tmp_path, TCP_POSE + node)
    assert code == 2 and summary["status"] == "ERROR" and summary["ticks"] == 0, summary
    assert "port 'object_id': unknown object 'ghost' (objects: cube_blue, cube_green, cube_red, table)" in summary["reason"]


@pytest.mark.parametrize(
    "node, reason",
    [
        ('<AddCollisionBox object_id="box" dimensions="{dims}" pose="{tcp}"/>',
         "AddCollisionBox: port 'dimensions' (from '{dims}') item 2 must be in (0, 100] m, got -0.1"),
        ('<TransformPose input_pose="{tcp}" translation_xyz="{nan}" output_pose="{nan_pose}"/>'
         '<AddCollisionBox object_id="box" dimensions="0.1;0.1;0.1" pose="{nan_pose}"/>',
         "TransformPose: port 'translation_xyz' (from '{nan}') item 2 must be in [-100, 100] m, got nan"),
    ],
)
def test_out_of_range_values_from_the_blackboard_end_the_run_as_an_error(capsys, tmp_path, node, reason):
    """A value read at run time is checked against the port's range like a literal: the run stops
    (ERROR, exit 2) naming the port, before a box with a negative size or a NaN pose is made."""
    code, summary = run_xml(capsys, tmp_path, TCP_POSE + node, "--set", "dims=0.1;-0.1;0.1", "--set", "nan=0;nan;0")
    assert (code, summary["status"]) == (2, "ERROR"), summary
    assert reason in summary["reason"] and "Traceback" not in summary["reason"], summary["reason"]
    assert "box" not in summary.get("world", {}).get("boxes", {})


@pytest.mark.parametrize(
    "node, message",
    [
        ('<AddCollisionBox object_id="box" dimensions="0.1;0.1" pose="{p}"/>', "AddCollisionBox: port 'dimensions' needs 3 values, got 2"),
        ('<AddCollisionBox object_id="box" dimensions="0.1;0;0.1" pose="{p}"/>', "AddCollisionBox: port 'dimensions' item 2 must be in (0, 100] m, got 0.0"),
        ('<AddCollisionBox object_id="" dimensions="0.1;0.1;0.1" pose="{p}"/>', "AddCollisionBox: port 'object_id': object_id must name one object, got ''"),
        ('<RemoveCollisionObject object_id="*"/>', "RemoveCollisionObject: port 'object_id': object_id must name one object, got '*'"),
        ('<MoveCollisionObject object_id="box" pose="0;0;1"/>', "MoveCollisionObject: port 'pose' needs a geometry_msgs/PoseStamped from the blackboard, e.g. {pose} written by GetLatestTransform or TransformPose; got the text '0;0;1'"),
        ('<PlaceSimBox object_id="b" dimensions="0.1;0.1;0.1" position_xyz="0;nan;0.2"/>', "PlaceSimBox: port 'position_xyz' item 2 must be in [-100, 100] m, got nan"),
        ('<PlaceSimBox object_id="b" dimensions="0.1;0.1;0.1" position_xyz="0;0.5;0.2" orientation_xyzw="0;0;0;0"/>', "PlaceSimBox: port 'orientation_xyzw': 0;0;0;0 is not a rotation (zero length)"),
        ('<PlaceSimBox object_id="b" dimensions="0.1;inf;0.1" position_xyz="0;0.5;0.2"/>', "PlaceSimBox: port 'dimensions' item 2 must be in (0, 100] m, got inf"),
    ],
)
def test_bad_literals_are_load_time_errors(capsys, tmp_path, node, message):
    code, summary = run_xml(capsys, tmp_path, node)
    assert code == 2 and summary["status"] == "ERROR"
    assert summary["reason"] == f"{tmp_path / 't.xml'}:1: {message}"


# -- boxes placed in the cell -------------------------------------------------------------------
def test_placed_box_is_mirrored_into_the_planning_scene_and_removed_with_it(capsys, tmp_path):
    place = '<PlaceSimBox object_id="crate" dimensions="0.2;0.2;0.1" position_xyz="0.3;0.3;0.05"/>'
    code, summary = run_xml(capsys, tmp_path, place + '<GetObjectPose object_name="crate" pose="{p}"/>')
    assert code == 0, summary["reason"]
    assert summary["world"]["boxes"] == {"crate": {"size_m": [0.2, 0.2, 0.1], "position_m": [0.3, 0.3, 0.05], "in_planning_scene": True}}
    code, summary = run_xml(capsys, tmp_path, place + '<RemoveSimBox object_id="crate"/><GetObjectPose object_name="crate" pose="{p}"/>')
    assert code == 2 and "GetObjectPose: no object 'crate' in the planning scene" in summary["reason"]
    assert "boxes" not in summary["world"]


def test_a_box_kept_out_of_the_planning_scene_is_only_in_the_cell(capsys, tmp_path):
    place = '<PlaceSimBox object_id="crate" dimensions="0.2;0.2;0.1" position_xyz="0.3;0.3;0.05" add_to_planning_scene="false"/>'
    code, summary = run_xml(capsys, tmp_path, place + '<GetObjectPose object_name="crate" pose="{p}"/>')
    assert code == 2 and "GetObjectPose: no object 'crate' in the planning scene" in summary["reason"]
    assert summary["world"]["boxes"]["crate"]["in_planning_scene"] is False


def test_a_reset_takes_placed_boxes_away(capsys, tmp_path):
    place = '<PlaceSimBox object_id="crate" dimensions="0.2;0.2;0.1" position_xyz="0.3;0.3;0.05"/>'
    code, summary = run_xml(capsys, tmp_path, place + '<ResetSim seed="2"/><GetObjectPose object_name="crate" pose="{p}"/>')
    assert code == 2 and "GetObjectPose: no object 'crate' in the planning scene" in summary["reason"]


@pytest.mark.parametrize(
    "node, reason",
    [
        ('<RemoveSimBox object_id="ghost"/>', "no box 'ghost' was placed in the cell (placed: none)"),
        ('<PlaceSimBox object_id="table" dimensions="0.1;0.1;0.1" position_xyz="0.3;0.3;0.05"/>', "'table' is already an object of the planning scene: pick another name"),
    ],
)
def test_bad_box_requests_fail_with_a_reason(capsys, tmp_path, node, reason):
    code, summary = run_xml(capsys, tmp_path, node)
    assert code == 1 and summary["reason"].startswith(reason), summary["reason"]


def test_a_box_placed_at_an_unknown_frame_is_a_setup_error(capsys, tmp_path):
    node = '<PlaceSimBox object_id="b" dimensions="0.1;0.1;0.1" position_xyz="0;0;0" reference_frame="moon"/>'
    code, summary = run_xml(capsys, tmp_path, node)
    assert code == 2 and summary["status"] == "ERROR" and summary["failure_kind"] == "SetupError"
    assert summary["ticks"] == 0  # found before anything moves
    assert "PlaceSimBox: port 'reference_frame': unknown frame 'moon' (frames: cube_blue, cube_green, cube_red, table, world, base, " in summary["reason"]


def test_a_box_cannot_appear_inside_the_robot_or_a_cube():
    cell = MujocoCell(arm=HOME, seed=0)
    blue = cell.cube_pose("blue")[0]
    with pytest.raises(ValueError, match=r"box 'b' would overlap 'cube_blue' by \d+\.\d mm: place it where nothing is"):
        cell.place_box("b", np.full(3, 0.1), blue, np.array([1.0, 0, 0, 0]))
    with pytest.raises(ValueError, match=r"box 'b' would overlap 'gripper_\w+' by"):
        cell.place_box("b", np.full(3, 0.1), np.array([0.0, 0.45, 0.30]), np.array([1.0, 0, 0, 0]))
    cell.place_box("b", np.full(3, 0.1), np.array([0.4, 0.1, 0.05]), np.array([1.0, 0, 0, 0]))  # resting on the table
    for _ in range(5):
        cell.step(0.002)
    assert np.abs(cell.cube_pose("blue")[0] - blue).max() < 1e-4  # nothing was pushed
    for k, x in enumerate((-0.5, -0.4, -0.3)):
        cell.place_box(f"c{k}", np.full(3, 0.05), np.array([x, 0.0, 0.025]), np.array([1.0, 0, 0, 0]))
    with pytest.raises(ValueError, match=r"^all 4 box slots of the cell are taken \(b, c0, c1, c2\): remove one first$"):
        cell.place_box("d", np.full(3, 0.05), np.array([0.5, 0.0, 0.025]), np.array([1.0, 0, 0, 0]))
    cell.place_box("b", np.full(3, 0.05), np.array([0.5, 0.0, 0.025]), np.array([1.0, 0, 0, 0]))  # moving one is fine
    cell.close()


# -- an object appears in the path of a running policy ------------------------------------------
PLACE_SIM_BOX = """<PlaceSimBox object_id="obstacle" dimensions="0.3;0.3;0.06"
                       reference_frame="tcp" position_xyz="0;0;0.08"/>"""
ADD_COLLISION_BOX = (TCP_POSE + '<TransformPose input_pose="{tcp}" translation_xyz="0;0;0.08" output_pose="{where}"/>'
                     '<AddCollisionBox object_id="obstacle" dimensions="0.3;0.3;0.06" pose="{where}"/>')


def run_example_then_wait(registry: Registry, world, planning_scene_only: bool = False) -> tuple[object, object]:
    """The shipped example under ForceSuccess, then a 1 s Wait, so the stop can be seen
    (``planning_scene_only``: the box added with AddCollisionBox instead of PlaceSimBox)."""
    text = EXAMPLE.read_text()
    assert PLACE_SIM_BOX in text
    if planning_scene_only:
        text = text.replace(PLACE_SIM_BOX, ADD_COLLISION_BOX)
    wrapper = ('<BehaviorTree ID="Wrapper"><Sequence><ForceSuccess><SubTree ID="Obstacle Appears During the Policy"/>'
               '</ForceSuccess><Wait seconds="1.0"/></Sequence></BehaviorTree></root>')
    text = text.replace('main_tree_to_execute="Obstacle Appears During the Policy"', 'main_tree_to_execute="Wrapper"').replace("</root>", wrapper)
    options = RunOptions(seed=0, max_seconds=30.0, world=world.name, policy_latency="0.05")
    context = make_context(options)
    loaded = load_tree(text, registry, context, objectives_dir=Path("objectives"))
    return run_tree(loaded, context, options, world=world), context


def assert_stopped_for_the_obstacle(result, context, world, in_the_cell: bool = True) -> None:
    assert result.status == "SUCCESS", result.reason  # the Wait after ForceSuccess ran
    finished = context.events.of_kind("policy_finished")
    assert [e.data["status"] for e in finished] == ["FAILURE"]
    message = finished[0].data["message"]
    assert message.startswith("the planning scene changed: step ")
    assert "vs obstacle" in message and message.endswith("in the remaining path; robot stopped")
    assert not world.controllers["joint_trajectory_admittance_controller"].executing
    if in_the_cell:
        assert result.extra["world"]["boxes"]["obstacle"]["in_planning_scene"] is True
    else:
        assert "boxes" not in result.extra["world"] and "obstacle" in context.scene.objects


def test_example_an_object_appears_and_the_robot_stops_kinematic(registry, capsys):
    code = main(["run", str(EXAMPLE), "--world", "kinematic", "--json", "--policy-latency", "0.05"])
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 1 and summary["failing_node"] == "ExecutePolicy"
    assert summary["reason"].startswith("the planning scene changed: ") and "vs obstacle" in summary["reason"]
    assert summary["sim_seconds"] < 2.5  # found within 50 ms of the box appearing, long before any grasp
    world = KinematicWorld({"seed": 0, "policy_latency": "0.05"})
    result, context = run_example_then_wait(registry, world)
    assert_stopped_for_the_obstacle(result, context, world)
    assert np.allclose(world.cell.arm_velocity_now, 0.0, atol=1e-9)


def test_a_box_added_to_the_planning_scene_mid_run_stops_the_robot(registry):
    world = KinematicWorld({"seed": 0, "policy_latency": "0.05"})
    result, context = run_example_then_wait(registry, world, planning_scene_only=True)
    assert_stopped_for_the_obstacle(result, context, world, in_the_cell=False)
    assert np.allclose(world.cell.arm_velocity_now, 0.0, atol=1e-9)


def test_example_an_object_appears_and_the_robot_stops_on_the_physics_cell(registry):
    world = create_vla_sim({"seed": 0, "policy_latency": "0.05", "image_size": 64})
    result, context = run_example_then_wait(registry, world)
    assert_stopped_for_the_obstacle(result, context, world)
    assert np.abs(world.cell.arm_velocity()).max() < 0.01  # at rest (rad/s), the servos settling
    assert result.extra["world"]["peak_force_n"] < 10.0  # it stopped before touching the box

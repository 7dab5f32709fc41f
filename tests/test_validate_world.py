"""`objective validate`: every error of a file, each at its file:line (and the line of the SubTree
call it is inside); BehaviorTree.CPP's rule for one entry wired to ports of two types; with
`--world NAME`, the names the world knows (frames, objects, groups, joints, waypoints, services
and actions with their types)."""
from __future__ import annotations

from pathlib import Path

import behaviortreepy as bt
import pytest

from runtime.app.cli import main
from runtime.tree.loader import validate
from runtime.tree.registry import Registry

LOOPS = ("LoopInt", "LoopDouble", "LoopString", "LoopBool")


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


def write(tmp_path: Path, body: str, name: str = "t.xml", extra: str = "") -> Path:
    path = tmp_path / name
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="T">\n<BehaviorTree ID="T">\n{body}\n</BehaviorTree>\n{extra}</root>\n')
    return path


def validate_cli(capsys, *args: str) -> tuple[int, list[str], str]:
    code = main(["validate", *args])
    out, err = capsys.readouterr()
    return code, err.splitlines(), out


def test_every_error_of_a_file_is_reported_at_its_line(registry, tmp_path, capsys):
    path = write(tmp_path, """<Sequence>
  <Sequense><Sleep msec="slow"/></Sequense>
  <Sleep msec="fast"/>
  <MoveGripperAction max_effort="-1" speed="2"/>
  <AlwaysSuccess/>
</Sequence>""")
    code, errors, out = validate_cli(capsys, str(path))
    assert (code, out) == (2, "")
    assert errors == [
        f"error: {path}:4: Sequense: unknown node 'Sequense'; did you mean 'Sequence' or 'AsyncSequence'?",
        f"error: {path}:4: Sleep: port 'msec' expects a non-negative integer, got 'slow'",  # inside the broken node
        f"error: {path}:5: Sleep: port 'msec' expects a non-negative integer, got 'fast'",
        f"error: {path}:6: MoveGripperAction: unknown port 'speed' (ports: gripper_command_action_name, max_effort, position, timeout)",
        f"error: {path}:6: MoveGripperAction: missing required port 'position'",
        f"error: {path}:6: MoveGripperAction: port 'max_effort' must be in [0, 10000] N, got -1.0",
    ]


def test_an_error_inside_a_subtree_names_the_callers_line(registry, tmp_path, capsys):
    library = """<BehaviorTree ID="Wait Then Sleep">
  <Sequence><Sleep msec="{ms}"/><LoopDouble queue="1.5" value="{n}"><AlwaysSuccess/></LoopDouble></Sequence>
</BehaviorTree>
"""
    path = write(tmp_path, """<Sequence>
  <LoopInt queue="1;2" value="{count}"><AlwaysSuccess/></LoopInt>
  <SubTree ID="Wait Then Sleep" ms="10" n="{count}"/>
</Sequence>""", extra=library)
    code, errors, _ = validate_cli(capsys, str(path))
    assert code == 2
    assert errors == [
        f"error: {path}:5: SubTree 'Wait Then Sleep': {path}:9: LoopDouble: port 'value' (double) is wired to "
        f"blackboard entry '{{n}}', whose type is int (port 'value' of LoopInt at {path}:4): BehaviorTree.CPP refuses "
        "one entry with two types (use another entry, or ports of one type)"
    ]


@pytest.mark.parametrize(("first", "second"), [(a, b) for a in LOOPS for b in LOOPS])
def test_one_entry_for_two_port_types_is_refused_exactly_where_behaviortree_cpp_refuses_it(registry, first, second):
    xml = f"""<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>
<{first} queue="1" value="{{v}}"><AlwaysSuccess/></{first}>
<{second} queue="1" value="{{v}}"><AlwaysSuccess/></{second}>
</Sequence></BehaviorTree></root>"""
    try:
        bt.BehaviorTreeFactory().create_tree_from_text(xml)
        btcpp_refuses = False
    except Exception as err:  # noqa: BLE001 - BT.CPP's RuntimeError
        btcpp_refuses = "was initially created with type" in str(err)
    errors = validate(xml, registry).errors
    assert bool(errors) == btcpp_refuses, [str(e) for e in errors]
    assert btcpp_refuses == (first != second and first != "LoopString")  # a string entry converts when read


# -- --world -----------------------------------------------------------------------------------
def test_without_a_world_names_are_not_checked(registry, tmp_path, capsys):
    path = write(tmp_path, '<CheckObjectStacked top_object_name="cube_purple" bottom_object_name="cube_green"/>')
    code, errors, out = validate_cli(capsys, str(path))
    assert (code, errors) == (0, []) and out.startswith(f"ok: {path}: T (1 nodes)")


def test_validate_with_a_world_reports_every_name_it_lacks(registry, tmp_path, capsys):
    path = write(tmp_path, """<Sequence>
  <SubTree ID="Move to Waypoint" waypoint_name="Hme"/>
  <CheckObjectStacked top_object_name="cube_purple" bottom_object_name="cube_green" gripper_frame="tcp"/>
  <ExecutePolicy policy_service_name="/get_action_chunk" joint_group_name="manipulatr" total_action_steps="10"
      controller_action_name="/robotiq_gripper_controller/gripper_cmd"
      gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd" gripper_joint_name="robotiq_85_left_knucle_joint"
      image_topics="/scene_camera/color;/wrist_camera/color" image_names="scene"/>
</Sequence>""")
    code, errors, out = validate_cli(capsys, str(path), "--world", "kinematic")
    assert (code, out) == (2, "")
    assert errors[0] == (
        f"error: {path}:4: SubTree 'Move to Waypoint': objectives/move_to_waypoint.xml:18: MoveToWaypoint: "
        "port 'waypoint_name': unknown waypoint 'Hme' (did you mean 'Home'?) (waypoints: Home, Observe, Ready)"
    )
    assert errors[1].startswith(f"error: {path}:5: CheckObjectStacked: port 'top_object_name': unknown frame "
                                "'cube_purple' (frames: cube_blue, cube_green, cube_red, table, world, ")
    assert errors[2] == (f"error: {path}:6: ExecutePolicy: image_topics has 2 entries and image_names has 1; "
                         "they must be index-aligned")
    # the ExecutePolicy whose image lists disagree still has its names checked
    assert errors[3:5] == [
        f"error: {path}:6: ExecutePolicy: port 'joint_group_name': unknown joint group 'manipulatr' "
        "(did you mean 'manipulator'?) (joint groups: gripper, manipulator)",
        f"error: {path}:6: ExecutePolicy: port 'controller_action_name': action '/robotiq_gripper_controller/gripper_cmd' "
        "is a control_msgs/action/GripperCommand, not a moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance "
        "or a control_msgs/action/FollowJointTrajectory",
    ]
    assert len(errors) == 6 and errors[5].startswith(
        f"error: {path}:6: ExecutePolicy: port 'gripper_joint_name': unknown joint 'robotiq_85_left_knucle_joint' "
        "(did you mean 'robotiq_85_left_knuckle_joint'?) (joints: elbow_joint, ")


def test_the_shipped_objectives_validate_against_their_world(registry, capsys):
    objectives = sorted(str(p) for p in Path("objectives").glob("*.xml")) + sorted(str(p) for p in Path("objectives/moveit_pro").glob("*.xml"))
    code, errors, out = validate_cli(capsys, *objectives, "--world", "vla_sim")
    assert (code, errors) == (0, []) and out.count("ok: ") == len(objectives)


def test_a_world_option_it_refuses_is_bad_input(registry, tmp_path, capsys):
    path = write(tmp_path, "<AlwaysSuccess/>")
    code, errors, _ = validate_cli(capsys, str(path), "--world", "kinematic", "--world-option", "image_size=big")
    assert (code, errors) == (2, ["error: world 'kinematic': option 'image_size' must be a whole number, got 'big'"])


# -- validate --world checks at least what run checks, and every error of a node -----------------
POLICY = ('<ExecutePolicy policy_service_name="/get_action_chunk" joint_group_name="{group}" total_action_steps="20" '
          'image_topics="{topics}" image_names="{names}"/>')
SWITCH = ('<SwitchController activate_controllers="joint_trajectory_admittance_controller" '
          'deactivate_controllers="velocity_force_controller"/>')
NOT_ACTIVE = ("port 'controller_action_name': action '/joint_trajectory_admittance_controller/follow_joint_trajectory' is "
              "served by controller 'joint_trajectory_admittance_controller', which is not active when this node runs: "
              "activate it before (SwitchController activate_controllers=\"joint_trajectory_admittance_controller\"; "
              "active: force_torque_sensor_broadcaster, robotiq_gripper_controller, velocity_force_controller)")


def test_validate_world_reports_every_error_of_a_node(tmp_path, capsys):
    """A wrong joint_group_name and mismatched image_names showed only the latter."""
    path = write(tmp_path, f"<Sequence>{SWITCH}{POLICY.format(group='manipulatr', topics='/scene_camera/color;/wrist_camera/color', names='scene')}</Sequence>")
    code, errors, _ = validate_cli(capsys, str(path), "--world", "kinematic")
    assert code == 2
    assert errors == [
        f"error: {path}:3: ExecutePolicy: image_topics has 2 entries and image_names has 1; they must be index-aligned",
        f"error: {path}:3: ExecutePolicy: port 'joint_group_name': unknown joint group 'manipulatr' (did you mean "
        "'manipulator'?) (joint groups: gripper, manipulator)",
    ]


@pytest.mark.parametrize("body, problem", [
    (f"<Sequence>{SWITCH}{POLICY.format(group='manipulator', topics='/thermal_camera/color', names='thermal')}</Sequence>",
     "port 'image_topics': no topic '/thermal_camera/color'"),
    (POLICY.format(group="manipulator", topics="", names=""), NOT_ACTIVE),
], ids=["camera-topic", "no-switch-controller"])
def test_validate_world_and_run_refuse_what_failed_seconds_into_the_run(tmp_path, capsys, body, problem):
    """A missing camera topic failed 5 s into the run; an ExecutePolicy without a SwitchController
    before it failed with "controller ... is not active". Both validated."""
    path = write(tmp_path, body)
    code, errors, _ = validate_cli(capsys, str(path), "--world", "kinematic")
    assert code == 2 and len(errors) == 1 and errors[0].startswith(f"error: {path}:3: ExecutePolicy: {problem}"), errors
    code = main(["run", str(path), "--world", "kinematic", "--json"])
    summary = __import__("json").loads(capsys.readouterr().out.splitlines()[-1])
    assert (code, summary["status"], summary["ticks"]) == (2, "ERROR", 0)  # before the first tick
    assert summary["reason"].startswith(f"{path}:3: ExecutePolicy: {problem}")


def test_validate_world_checks_a_name_a_script_computes(tmp_path, capsys):
    """top_color="purple" in the shipped check validated; run refused it in its first tick."""
    path = write(tmp_path, '<SubTree ID="Check if One Cube Is on Another" top_color="purple" bottom_color="green"/>')
    code, errors, _ = validate_cli(capsys, str(path), "--world", "kinematic")
    assert code == 2
    assert errors[0].startswith(f"error: {path}:3: SubTree 'Check if One Cube Is on Another': ")
    assert "CheckObjectStacked 'top cube on bottom cube': port 'top_object_name': unknown frame 'cube_purple'" in errors[0]
    assert len(errors) == 1

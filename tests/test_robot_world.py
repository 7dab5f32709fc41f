"""World ``robot``: a user's URDF + SRDF + joint limits as the planning scene, no simulator."""
from __future__ import annotations

import json

import pytest

from runtime.app.cli import main
from tests.test_scene import SRDF, URDF

LIMITS = """joint_limits:
  j1: {has_velocity_limits: true, max_velocity: 1.0, has_acceleration_limits: true, max_acceleration: 2.0}
  fa: {has_velocity_limits: true, max_velocity: 0.1, has_acceleration_limits: true, max_acceleration: 1.0}
"""


@pytest.fixture
def robot_files(tmp_path):
    (tmp_path / "robot.urdf").write_text(URDF)
    (tmp_path / "robot.srdf").write_text(SRDF)
    (tmp_path / "limits.yaml").write_text(LIMITS)
    (tmp_path / "move.xml").write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Move">'
        '<MoveToJointState joint_group_name="arm" joint_positions="0.5" timeout="0.2"/>'
        "</BehaviorTree></root>"
    )
    return tmp_path


def world_args(d, *extra: str) -> list[str]:
    return [
        "run", str(d / "move.xml"), "--world", "robot", "--json",
        "--world-option", f"urdf={d / 'robot.urdf'}", "--world-option", f"srdf={d / 'robot.srdf'}",
        "--world-option", f"joint_limits={d / 'limits.yaml'}", *extra,
    ]


def test_behaviors_plan_against_your_robot(robot_files, capsys):
    # The group, its limits and the scene come from the files; nothing serves a controller on this
    # in-process bus (over --ros the drivers would), so the action is named before anything moves.
    code = main(world_args(robot_files, "--world-option", "group=arm"))
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert (code, summary["ticks"]) == (2, 0)
    assert summary["reason"].endswith("port 'controller_action_name': no action "
                                      "'/joint_trajectory_admittance_controller/follow_joint_trajectory' (actions: none)")
    assert summary["world"]["group"] == "arm"


def test_a_group_the_srdf_lacks_is_named(robot_files, capsys):
    (robot_files / "move.xml").write_text((robot_files / "move.xml").read_text().replace('joint_group_name="arm"', 'joint_group_name="manipulator"'))
    code = main(world_args(robot_files, "--world-option", "group=arm"))
    assert code == 2
    assert "port 'joint_group_name': unknown joint group 'manipulator' (joint groups: arm, hand)" in capsys.readouterr().out


@pytest.mark.parametrize(
    "drop, message",
    [("urdf", "world 'robot': option 'urdf' is required (--world-option urdf=PATH)")],
)
def test_missing_description_is_bad_input(robot_files, capsys, drop, message):
    args = [a for a in world_args(robot_files) if not a.startswith(f"{drop}=")]
    args.remove("--world-option")
    assert main(args) == 2
    assert message in capsys.readouterr().err


def test_a_urdf_its_parser_refuses_is_bad_input_not_a_bug(robot_files, capsys):
    (robot_files / "robot.urdf").write_text('<robot name="x"><joint name="j" type="revolute"><parent link="a"/></joint></robot>')
    assert main(world_args(robot_files)) == 2
    err = capsys.readouterr().err
    assert f"\nerror: world 'robot': {robot_files / 'robot.urdf'}: " in f"\n{err}" and "internal error" not in err

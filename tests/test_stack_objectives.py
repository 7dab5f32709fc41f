"""The shipped stacking Objectives through the CLI, on the kinematic cell (fast) — with the
embedded oracle, with a replay of recorded chunks, and with a bad policy spec."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from runtime.app.cli import main
from policy.replay import RecordedChunk, write_replay
from sim.robot_model import ARM_JOINTS, GRIPPER_DRIVER_JOINT, load_waypoints

OBJECTIVES = Path(__file__).resolve().parent.parent / "objectives"


def run_cli(capsys, *args: str) -> tuple[int, dict]:
    code = main(["run", *args, "--json"])
    out = capsys.readouterr().out.strip().splitlines()
    return code, json.loads(out[-1])


def test_stack_cubes_succeeds_and_reports_the_policy_and_the_check(capsys):
    code, summary = run_cli(capsys, "objectives/stack_cubes.xml", "--world", "kinematic", "--seed", "3", "--policy-latency", "0.2")
    assert code == 0, summary["reason"]
    policy = summary["execute_policy"]
    assert policy["steps_executed"] == 300 and policy["rejections"] == 0 and policy["stall_seconds"] == 0.0
    assert policy["chunks"] == 15 and policy["latency_max_s"] == pytest.approx(0.2, abs=0.011)
    assert summary["stack_check"]["stacked"] is True
    assert summary["blackboard"]["policy_message"] == "executed 300 steps"
    assert policy["warnings"] == []  # the Objective's real-time chunking is used by the embedded policy


@pytest.mark.parametrize("seed", [0, 1])
def test_one_slow_inference_pauses_the_stack_once_and_the_estimate_recovers(capsys, tmp_path, seed):
    """A single 3 s policy call as the second streamed request (replayed with --policy-latency
    trace:FILE: warmup, first request, then the slow one, then 50 ms). The oracle re-plans, and
    its next chunk is blended in within the acceleration limits; the arm pauses once (briefly:
    the chunk's tail covers most of the wait), the sizing warning is given once with the figures,
    the estimate is back at 50 ms by the end, and the cubes are stacked."""
    trace = tmp_path / "latency.txt"
    trace.write_text("0.05\n0.05\n3.0\n0.05\n")
    code, summary = run_cli(capsys, "objectives/stack_cubes.xml", "--world", "kinematic", "--seed", str(seed),
                            "--policy-latency", f"trace:{trace}")
    assert code == 0, summary["reason"]
    policy = summary["execute_policy"]
    assert policy["steps_executed"] == 300 and policy["rejections"] == 0
    assert policy["latency_max_s"] == 3.0 and policy["latency_estimate_s"] == 0.05
    # Asked 0.1 s before chunk 1's window ends, answered 3 s later: meanwhile the arm plays the
    # chunk's 26 steps beyond the window at full speed (2.6 s), and stands 0.4 s (not 3 s).
    assert policy["stall_seconds"] == pytest.approx(0.4, abs=0.011)
    sizing = [w for w in policy["warnings"] if "below twice" in w]
    assert sizing == [
        "(committed_action_steps - 1) * dt = 1.900 s is below twice the latency estimate 3.000 s (the 90th percentile "
        "of the last 3 round trips) and longer than half the 50-step chunk (2.500 s): expect pauses at chunk boundaries "
        "(covering it would take committed_action_steps = 61, not below the chunk's 50 steps: a faster policy or longer chunks)"
    ]
    assert summary["stack_check"]["stacked"] is True


def test_stack_until_check_stops_the_policy_as_soon_as_the_stack_is_there(capsys):
    code, summary = run_cli(capsys, "objectives/stack_cubes_until_check.xml", "--world", "kinematic", "--seed", "3")
    assert code == 0, summary["reason"]
    assert summary["execute_policy"]["steps_executed"] < 300
    assert summary["execute_policy"]["message"] == "halted: goals cancelled, robot stopped"


def test_replayed_chunks_end_with_no_more_actions(capsys, tmp_path):
    home = load_waypoints()["Home"]
    row = [home[j] for j in ARM_JOINTS] + [0.0]
    names = list(ARM_JOINTS) + [GRIPPER_DRIVER_JOINT]
    replay = tmp_path / "hold.jsonl"
    write_replay(replay, [RecordedChunk(names, np.tile(row, (50, 1)), 0.1) for _ in range(4)])
    # The check fails (nothing was stacked), but the policy run itself ends with SUCCESS.
    code, summary = run_cli(capsys, "objectives/stack_cubes.xml", "--world", "kinematic", "--policy", f"replay:{replay}")
    assert code == 1 and summary["failing_node"] == "top cube on bottom cube"
    policy = summary["execute_policy"]
    assert policy["message"] == "the policy has no more actions: replay of 'hold.jsonl' finished after 4 chunks"
    # The warmup and the first request both start an episode, so all four chunks are played.
    assert policy["chunks"] == 4


def test_unknown_policy_spec_is_bad_input(capsys):
    assert main(["run", "objectives/stack_cubes.xml", "--world", "kinematic", "--policy", "bogus"]) == 2
    assert ("world 'kinematic': policy 'bogus' is unknown (expected oracle, replay:FILE, lerobot:DIR, "
            "FILE.py:FACTORY, MODULE:FACTORY, http(s)://HOST:PORT or none)") in capsys.readouterr().err


# -- a policy that drives the gripper straight down into the table --------------------------------
POLICY_OBJECTIVES = sorted(
    str(p.relative_to(OBJECTIVES.parent)) for p in OBJECTIVES.rglob("*.xml") if "policy_service_name=" in p.read_text()
)


def straight_down_policy():
    """GetActionChunk answers that move the TCP straight down 2 cm a step (0.2 m/s) from where
    the arm is (IK along the line), gripper as observed."""
    from moveit_pro_ml_msgs.srv import GetActionChunk
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from runtime.motion.scene.kinematics import IkSolver, frame_pose
    from sim.planning import make_cell_scene

    cube = (np.array([0.3, 0.3, 0.015]), np.array([1.0, 0.0, 0.0, 0.0]))
    scene = make_cell_scene({"red": cube, "green": cube, "blue": cube})
    solver = IkSolver(scene.robot, "manipulator", "tcp", None)
    layout = scene.layout("manipulator", None)

    def answer(request):
        names = list(request.robot_state.name)
        state = np.array(request.robot_state.position)
        arm = state[: len(ARM_JOINTS)]
        tcp = frame_pose(scene.robot, layout(arm), "tcp")
        rows, q = [], arm
        for k in range(50):
            target = tcp.copy()
            target[2, 3] = tcp[2, 3] - 0.02 * k
            solution = solver.solve(target, [q], random_restarts=0)
            q = solution.positions if solution.success else q
            rows.append(np.append(q, state[len(ARM_JOINTS):]))
        response = GetActionChunk.Response(status=GetActionChunk.Response.CHUNK_PRODUCED, native_control_period=0.1)
        response.chunk = JointTrajectory(joint_names=names, points=[JointTrajectoryPoint(positions=r.tolist()) for r in rows])
        return response

    return answer


def test_every_shipped_objective_that_runs_a_policy_is_listed():
    assert POLICY_OBJECTIVES == [
        "objectives/examples/obstacle_appears.xml",
        "objectives/examples/plan_around_a_box.xml",
        "objectives/moveit_pro/stack_cubes_with_the_vla_policy.xml",
        "objectives/stack_cubes.xml",
        "objectives/stack_cubes_jtc.xml",
        "objectives/stack_cubes_learned.xml",
        "objectives/stack_cubes_lerobot.xml",
        "objectives/stack_cubes_until_check.xml",
    ]


@pytest.mark.parametrize("objective, world", [(o, "kinematic") for o in POLICY_OBJECTIVES] + [("objectives/stack_cubes.xml", "vla_sim")])
def test_a_policy_driving_the_gripper_into_the_table_is_rejected_before_it_moves(objective, world, monkeypatch):
    """Only the contacts a task needs are allowed: the gripper may touch the cubes, never the
    table, so the first chunk of a straight-down policy is refused naming a gripper link and
    the table before anything moves (on main the `*` rule of stack_cubes.xml let the TCP go to
    z = -0.096 m on the kinematic cell and strike the table at 53 N on vla_sim)."""
    from moveit_pro_ml_msgs.srv import GetActionChunk

    from runtime.tree.loader import load_tree
    from runtime.tree.registry import Registry
    from runtime.app.runner import RunOptions, make_context, run_tree

    # The collision rules are under test: the cell's Cartesian envelope (whose keep-in box the chunk
    # leaves too, and which is checked first) is left out.
    monkeypatch.setattr("sim.planning.load_envelope", lambda *args: None)
    options = RunOptions(seed=0, max_seconds=30.0, world=world, world_options={"policy": "none"})
    context = make_context(options)
    loaded = load_tree(OBJECTIVES.parent / objective, Registry.from_entry_points(), context)
    context.bus.create_service("/get_action_chunk", GetActionChunk, straight_down_policy())
    result = run_tree(loaded, context, options)
    assert (result.status, result.failing_node) == ("FAILURE", "ExecutePolicy"), result.reason
    assert re.match(r"chunk 1 rejected: densified step \d+ \(t=[0-9.]+ s\): world collision gripper_\w+ vs table: ", result.reason), result.reason
    assert result.extra["world"]["peak_force_n"] < 10.0  # the first chunk never moved the arm: nothing was touched


# -- a mistake of the setup is an ERROR: no Retry repeats it ---------------------------------------
def _retried(tmp_path: Path, replace: dict[str, str]) -> Path:
    """objectives/stack_cubes.xml with its ExecutePolicy inside RetryUntilSuccessful (3 attempts) and ``replace`` applied."""
    text = (OBJECTIVES / "stack_cubes.xml").read_text()
    text = text.replace("<ExecutePolicy", '<RetryUntilSuccessful num_attempts="3"><ExecutePolicy')
    text = text.replace('status_message="{policy_message}"/>', 'status_message="{policy_message}"/></RetryUntilSuccessful>')
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "retried.xml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("replace, reason", [
    ({'prompt="stack the blue cube on the green cube"': 'prompt=""'},
     "the policy answered ERROR for the warmup: cannot read the prompt ''"),
    ({'gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd"': "", 'gripper_joint_name="robotiq_85_left_knuckle_joint"': ""},
     "the policy answered ERROR for the warmup: oracle needs exactly one gripper joint after the arm joints"),
], ids=["empty-prompt", "oracle-without-gripper"])
def test_a_policy_refusing_the_warmup_is_a_setup_error_no_retry_repeats(capsys, tmp_path, replace, reason):
    """Both ended FAILURE, and a Retry asked the policy the same three times."""
    code, summary = run_cli(capsys, str(_retried(tmp_path, replace)), "--world", "kinematic")
    assert (code, summary["status"]) == (2, "ERROR")
    assert reason in summary["reason"], summary["reason"]
    assert summary["execute_policy"]["run_count"] == 1


def test_a_goal_to_a_controller_that_is_not_running_is_a_setup_error(capsys, tmp_path):
    """The controller's name comes from the blackboard, so only the goal finds it inactive."""
    path = tmp_path / "inactive.xml"
    path.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>'
        "<Script code=\"ctl := '/joint_trajectory_admittance_controller/follow_joint_trajectory'\"/>"
        '<RetryUntilSuccessful num_attempts="3"><MoveToWaypoint waypoint_name="Home" controller_action_name="{ctl}"/></RetryUntilSuccessful>'
        "</Sequence></BehaviorTree></root>")
    code, summary = run_cli(capsys, str(path), "--world", "kinematic")
    assert (code, summary["status"]) == (2, "ERROR")
    assert summary["reason"].endswith("MoveToWaypoint: controller '/joint_trajectory_admittance_controller/follow_joint_trajectory' "
                                      "refused the motion: controller joint_trajectory_admittance_controller is not active"), summary["reason"]

"""``objectives/stack_cubes_jtc.xml``, the worked example on the stock ``joint_trajectory_controller``,
on the physics cell (``vla_sim``) over the in-process bus, in both trajectory-replacement modes;
and a push the planning scene does not know of, stopped by the wrench topic.

The default suite runs a few seeds; the 20-seed sweep of each mode is ``-m slow``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, RunResult, run_file

ROOT = Path(__file__).resolve().parent.parent
OBJECTIVE = ROOT / "objectives" / "stack_cubes_jtc.xml"
CUBE = 0.03


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


def run(registry: Registry, path: Path, seed: int, replacement: str) -> RunResult:
    options = RunOptions(seed=seed, world="vla_sim", policy_latency="0.05", max_seconds=60.0,
                         world_options={"allow_trajectory_replacement": replacement})
    return run_file(path, registry, options)


def assert_stacked(result: RunResult) -> None:
    assert (result.status, result.reason) == ("SUCCESS", "")
    policy = result.extra["execute_policy"]
    assert policy["steps_executed"] == 300 and policy["rejections"] == 0
    cubes = result.extra["world"]["cubes"]
    offset = np.array(cubes["blue"]) - np.array(cubes["green"])
    assert np.linalg.norm(offset - [0.0, 0.0, CUBE]) < 0.015, cubes
    assert 0 < result.extra["world"]["peak_force_n"] < 45.0  # measured on the JTC too, below the default threshold


@pytest.mark.parametrize("replacement", ["true", "false"])
@pytest.mark.parametrize("seed", [0, 3])
def test_stack_cubes_jtc_stacks_in_both_replacement_modes(registry, seed, replacement):
    assert_stacked(run(registry, OBJECTIVE, seed, replacement))


@pytest.mark.slow
@pytest.mark.timeout(3600)
@pytest.mark.parametrize("replacement", ["true", "false"])
def test_stack_cubes_jtc_stacks_on_every_seed_of_the_sweep(registry, replacement):
    failures = {}
    for seed in range(20):
        result = run(registry, OBJECTIVE, seed, replacement)
        if result.status != "SUCCESS":
            failures[seed] = result.reason
    assert not failures, failures


PUSH = """<root BTCPP_format="4" main_tree_to_execute="Push">
  <BehaviorTree ID="Push">
    <Sequence>
      <SubTree ID="Prepare for Policy on JTC"/>
      <PlaceSimBox object_id="hidden" dimensions="0.4;0.4;0.04" reference_frame="tcp" position_xyz="0;0;0.05"
                   add_to_planning_scene="false"/>
      <ExecutePolicy policy_service_name="/push_down" joint_group_name="manipulator" total_action_steps="60" dt="0.1"
                     committed_action_steps="20" goal_path_tolerance="0.3" policy_call_timeout="3.0"
                     controller_action_name="/joint_trajectory_controller/follow_joint_trajectory"
                     wrench_topic="/force_torque_sensor_broadcaster/wrench"/>
    </Sequence>
  </BehaviorTree>
</root>"""


def test_a_push_into_an_object_the_scene_does_not_know_stops_the_arm_on_the_jtc(registry):
    """The policy drives the gripper down (shoulder_lift at 0.15 rad/s) into a box placed in the
    cell but not in the planning scene: nothing is refused, the contact is felt on the wrench
    topic, the goal is cancelled and the arm comes to rest."""
    from moveit_pro_ml_msgs.srv import GetActionChunk

    from runtime.io.bus import FixedLatency
    from runtime.tree.loader import load_tree
    from runtime.app.runner import make_context, run_tree
    from sim.world import create_vla_sim
    from tests.test_execute_policy import ScriptedPolicy, hold

    options = RunOptions(seed=0, world="vla_sim", max_seconds=30.0)
    context = make_context(options)
    loaded = load_tree(PUSH, registry, context)
    context.bus.create_service("/push_down", GetActionChunk, ScriptedPolicy(hold(velocity=np.array([0.0, 0.15, 0.0, 0.0, 0.0, 0.0]))))
    context.bus.set_latency("/push_down", FixedLatency(0.05))
    world = create_vla_sim({"seed": 0, "policy": "none"})
    result = run_tree(loaded, context, options, world=world)
    assert result.status == "FAILURE"
    assert result.reason.startswith("force-torque threshold exceeded on '/force_torque_sensor_broadcaster/wrench': F")
    assert result.reason.endswith("; goal cancelled, robot stopped")
    jtc = world.controllers["joint_trajectory_controller"]
    assert not jtc.executing  # the goal was cancelled: the controller decelerates to rest, then holds
    assert np.abs(jtc.trajectory.sample(result.sim_seconds + 0.5).velocity).max() == 0.0


def test_an_obstacle_appearing_mid_run_stops_the_arm_on_the_jtc(registry, tmp_path):
    """objectives/examples/obstacle_appears.xml on the stock JTC: one second into the oracle's run a
    box appears below the gripper; ExecutePolicy's scene watch cancels the goal."""
    example = (ROOT / "objectives" / "examples" / "obstacle_appears.xml").read_text()
    on_jtc = example.replace(
        'activate_controllers="joint_trajectory_admittance_controller"\n                        deactivate_controllers="velocity_force_controller"',
        'activate_controllers="joint_trajectory_controller" automatic_deactivation="true"',
    ).replace(
        '<SubTree ID="Move to Waypoint" waypoint_name="Home"/>',
        '<SubTree ID="Move to Waypoint" waypoint_name="Home" controller_names="joint_trajectory_controller" '
        'controller_action_server="/joint_trajectory_controller/follow_joint_trajectory"/>',
    ).replace(
        'policy_service_name="/get_action_chunk"',
        'policy_service_name="/get_action_chunk" controller_action_name="/joint_trajectory_controller/follow_joint_trajectory" '
        'wrench_topic="/force_torque_sensor_broadcaster/wrench"',
    )
    assert on_jtc.count("joint_trajectory_controller") == 4 and "admittance" not in on_jtc.split("-->")[1]
    path = tmp_path / "obstacle_appears_jtc.xml"
    path.write_text(on_jtc)
    result = run_file(path, registry, RunOptions(seed=0, world="vla_sim", policy_latency="0.05", max_seconds=30.0))
    assert result.status == "FAILURE"
    assert result.reason.startswith("the planning scene changed:") and "obstacle" in result.reason
    assert result.reason.endswith("in the remaining path; robot stopped")

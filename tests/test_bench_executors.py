"""The benchmark executors of ``benchmarks/executors`` (synchronous, LeRobot's queue, newest-wins
and positions_upsampling on the JTC) on the kinematic cell, beside the unsafe-points probe: each
stacks the cubes with the oracle through the benchmark's Objective; the synchronous executor
refuses a chunk ExecutePolicy's checks refuse, the peers play it as at home and the probe counts
the unsafe points the controller commanded; each ends a run it cannot execute with ExecutePolicy's
reasons (a malformed chunk, a policy that does not answer, a controller it cannot drive)."""
from __future__ import annotations

import importlib.util
from typing import Any

import numpy as np
import pytest
from moveit_pro_ml_msgs.srv import GetActionChunk

from benchmarks.executors import register
from benchmarks.executors.objectives import Executor, objective_xml
from runtime.io.bus import FixedLatency
from runtime.tree.loader import load_tree
from runtime.tree.registry import Registry

needs_lerobot = pytest.mark.skipif(importlib.util.find_spec("lerobot") is None,
                                   reason="the LeRobot extra is not installed (make lerobot)")
LEROBOT_RTC = pytest.param("ExecuteWithLeRobotRtc", marks=needs_lerobot)
"""LeRobot's rollout RTC queue runs LeRobot's own code: only where the extra is installed."""
from runtime.app.runner import RunOptions, make_context, run_file, run_tree
from sim.kinematic import KinematicWorld
from tests.test_execute_policy import ScriptedPolicy, chunk_response, hold

SERVICE = "/get_action_chunk"
JTC = "/joint_trajectory_controller/follow_joint_trajectory"
TURN = np.array([0.1, 0, 0, 0, 0, 0])
"""rad/s of the scripted policies' chunks: a start from rest in one step needs about 3.5 rad/s^2
through the executors that do not smooth (LeRobot's queue, newest-wins), within the 5 rad/s^2 limit."""


@pytest.fixture(scope="module")
def registry() -> Registry:
    registry = Registry.from_entry_points()
    register(registry)
    return registry


def small_xml(node: str, ports: str = "") -> str:
    """The executor on the JTC, beside the unsafe-points probe: 60 steps, no gripper, no cameras."""
    return (f'<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>'
            f'<SwitchController activate_controllers="joint_trajectory_controller" automatic_deactivation="true"/>'
            f'<Parallel success_count="1" failure_count="1">'
            f'<{node} policy_service_name="{SERVICE}" joint_group_name="manipulator" total_action_steps="60" dt="0.1" '
            f'committed_action_steps="20" goal_path_tolerance="0.3" policy_call_timeout="3.0" controller_action_name="{JTC}" '
            f'steps_executed="{{steps}}" chunks_received="{{chunks}}" status_message="{{message}}" {ports}/>'
            f'<CountUnsafeCommands joint_group_name="manipulator"/></Parallel>'
            f'</Sequence></BehaviorTree></root>')


def run(registry: Registry, xml: str, policy: ScriptedPolicy | None = None, latency_s: float = 0.2, seed: int = 0,
        max_seconds: float = 90.0, world: KinematicWorld | None = None) -> Any:
    options = RunOptions(seed=seed, max_seconds=max_seconds, world="kinematic")
    context = make_context(options)
    world = world or KinematicWorld({"seed": seed, "policy": "none" if policy is not None else "oracle"})
    loaded = load_tree(xml, registry, context)
    if policy is not None:
        context.bus.create_service(SERVICE, GetActionChunk, policy)
    context.bus.set_latency(SERVICE, FixedLatency(latency_s))
    return run_tree(loaded, context, options, world=world)


@pytest.mark.parametrize("executor", [Executor.SYNC, Executor.NEWEST_WINS, Executor.JTC_UPSAMPLING], ids=lambda e: e.value)
def test_the_synchronous_newest_wins_and_upsampling_executors_stack_the_cubes_with_the_oracle(registry, executor):
    result = run(registry, objective_xml(executor), seed=3, latency_s=0.5)
    assert (result.status, result.reason) == ("SUCCESS", "")
    assert result.blackboard["steps_executed"] == 300
    assert result.blackboard["policy_message"] == "executed 300 steps"
    summary = result.extra["bench_executor"]
    assert summary["rejections"] == 0 and summary["chunks"] >= 300 // 49
    probe = result.extra["unsafe_points"]
    assert probe["count"] == 0 and probe["probed"] > 2500  # every tick of the run, about 30 s


@pytest.mark.parametrize("executor", [Executor.RTC, Executor.SYNC], ids=lambda e: e.value)
def test_on_the_physics_cell_a_motion_from_rest_starts_where_the_controller_holds_the_arm(registry, executor, tmp_path):
    """At rest at Home the physics cell's arm sags a few mrad off the Home its JTC commands; a
    chunk that started from the measured state would make the JTC (interpolating from what it
    commands) jump there within one control step (about 160 rad/s^2 on the elbow). Started from
    the controller's reference, nothing the controller commands is unsafe."""
    path = tmp_path / "bench.xml"
    path.write_text(objective_xml(executor))
    result = run_file(path, registry, RunOptions(seed=100, world="vla_sim", max_seconds=60.0))
    assert (result.status, result.reason) == ("SUCCESS", "")
    probe = result.extra["unsafe_points"]
    assert (probe["count"], probe["first"]) == (0, "")
    assert probe["probed"] > 2500


def test_lerobots_queue_joins_the_oracles_second_chunk_with_a_jump_the_probe_counts(registry):
    """The oracle is a function of time; LeRobot's client tags its first observation timestep 0
    and plays that chunk's step 0 (the observed state) at the first control step, so the first
    chunk runs one step behind the oracle's clock and the second, tagged by the action played,
    does not: where they are aggregated (0.3 old + 0.7 new) the knots jump by 0.7 of a step.
    LeRobot checks nothing: the arm plays the jump and the probe counts it."""
    result = run(registry, objective_xml(Executor.LEROBOT), seed=3, latency_s=0.0)
    assert (result.status, result.blackboard["steps_executed"]) == ("SUCCESS", 300)
    probe = result.extra["unsafe_points"]
    assert probe["count"] > 0
    assert "joint shoulder_lift_joint acceleration " in probe["first"] and "exceeds the limit" in probe["first"]


def test_the_synchronous_executor_rests_while_the_policy_infers(registry):
    policy = ScriptedPolicy(hold(velocity=TURN))
    result = run(registry, small_xml("ExecuteChunksSynchronously"), policy, latency_s=1.0)
    assert (result.status, result.blackboard["message"]) == ("SUCCESS", "executed 60 steps")
    # Warmup, then three chunks of 20 steps, each asked for once the arm rests.
    assert result.blackboard["chunks"] == 3 and len(policy.requests) == 4
    assert result.extra["bench_executor"]["latency_p50_s"] == pytest.approx(1.0, abs=0.02)
    # Each chunk starts where the last ended: 20 steps at 0.1 rad/s = 0.2 rad on joint 0.
    starts = [r.robot_state.position[0] for r in policy.requests[1:]]
    assert np.diff(starts) == pytest.approx([0.2, 0.2], abs=0.005)


def test_the_lerobot_queue_asks_when_half_a_chunk_is_left(registry):
    policy = ScriptedPolicy(hold(velocity=TURN))
    result = run(registry, small_xml("ExecuteWithLeRobotQueue"), policy, latency_s=0.2)
    assert (result.status, result.blackboard["message"]) == ("SUCCESS", "executed 60 steps")
    assert result.extra["bench_executor"]["queue"]  # says whose queue ran
    # 50-step chunks: a new observation once 25 or fewer actions are queued.
    assert result.blackboard["chunks"] == 3


@needs_lerobot
def test_lerobots_rtc_engine_asks_at_its_queue_threshold_with_the_leftover_and_the_worst_delay(registry):
    """LeRobot's rollout RTC engine on the sim clock: 50-step chunks, a request once the queue
    holds 30 actions or fewer, with the queue's unexecuted actions cut to execution_horizon (10)
    and ceil(worst latency / dt) frozen steps: the 0.2 s answer is read at the tick after it
    (0.21 s), so 3, and each chunk replaces the queue from its step 3."""
    policy = ScriptedPolicy(hold(velocity=TURN))
    result = run(registry, small_xml("ExecuteWithLeRobotRtc"), policy, latency_s=0.2)
    assert (result.status, result.blackboard["message"]) == ("SUCCESS", "executed 60 steps")
    assert result.extra["bench_executor"]["queue"] == "lerobot (policies.rtc.ActionQueue, RTC enabled)"
    first, second = policy.requests[1], policy.requests[2]  # after the warmup
    assert (first.frozen_prefix_steps, len(first.previous_action_chunk.data)) == (0, 0)
    assert second.frozen_prefix_steps == 3 and second.guidance_horizon == 10
    assert [d.size for d in second.previous_action_chunk.layout.dim] == [10, 6]
    # Asked 17 control steps after the first chunk merged (47 actions down to 30), with the arm about
    # two knots along (0.01 rad each) from the observed start: 0.19 rad.
    assert second.robot_state.position[0] - first.robot_state.position[0] == pytest.approx(0.19, abs=0.015)


@pytest.mark.parametrize("node, count, first", [("ExecuteNewestWinsOnJtc", 16, "step 0 (t=2.450 s)"),
                                                 ("ExecuteOnJtcWithUpsampling", 14, "step 0 (t=2.430 s)")])
def test_newest_wins_and_upsampling_drag_the_arm_back_to_the_state_a_late_chunk_observed(registry, node, count, first):
    """Chunk 2 starts where the arm was when it was asked for (0.2 s and a step before it
    plays): both play it at once, so the arm turns back, past the acceleration limit: the run
    goes on, as at home, and the probe counts the points."""
    policy = ScriptedPolicy(hold(velocity=TURN))
    result = run(registry, small_xml(node), policy, latency_s=0.2)
    assert (result.status, result.blackboard["message"]) == ("SUCCESS", "executed 60 steps")
    probe = result.extra["unsafe_points"]
    assert probe["count"] == count
    assert probe["first"].startswith(f"{first}: joint shoulder_pan_joint acceleration -")
    assert result.blackboard["chunks"] == 4 and len(policy.requests) == 5  # warmup, then every 2 s


def jump_at_step_10(index: int, request: Any) -> Any:
    """Chunks from the observed state that jump 0.6 rad on joint 0 at step 10 (6 rad/s)."""
    rows = np.tile(np.array(request.robot_state.position), (50, 1))
    rows[10:, 0] += 0.6
    return chunk_response(list(request.robot_state.name), rows)


def test_a_chunk_the_checks_refuse_ends_the_synchronous_run_with_the_reason(registry):
    result = run(registry, small_xml("ExecuteChunksSynchronously"), ScriptedPolicy(jump_at_step_10))
    assert (result.status, result.failure_kind) == ("FAILURE", "acceleration limit")
    assert result.reason.startswith("chunk 1 rejected: densified ")
    assert "shoulder_pan_joint" in result.reason
    assert result.extra["unsafe_points"]["count"] == 0


@pytest.mark.parametrize("node", ["ExecuteWithLeRobotQueue", LEROBOT_RTC, "ExecuteNewestWinsOnJtc",
                                  "ExecuteOnJtcWithUpsampling"])
def test_the_peers_play_a_jump_their_homes_do_not_check_and_the_probe_counts_it(registry, node):
    result = run(registry, small_xml(node), ScriptedPolicy(jump_at_step_10))
    assert result.status == "SUCCESS"
    probe = result.extra["unsafe_points"]
    assert probe["count"] > 50  # 0.6 rad in one step: 6 rad/s, past the velocity limit for many ticks
    assert "shoulder_pan_joint" in probe["first"] and "exceeds the limit" in probe["first"]


def with_rows(rows_of: Any) -> ScriptedPolicy:
    return ScriptedPolicy(lambda i, request: rows_of(request))


@pytest.mark.parametrize("node", ["ExecuteChunksSynchronously", "ExecuteWithLeRobotQueue", LEROBOT_RTC, "ExecuteNewestWinsOnJtc",
                                  "ExecuteOnJtcWithUpsampling"])
def test_malformed_chunks_and_a_silent_policy_end_with_the_reason(registry, node):
    def nan_rows(request: Any) -> Any:
        rows = np.tile(np.array(request.robot_state.position), (50, 1))
        rows[4, 2] = np.nan
        return chunk_response(list(request.robot_state.name), rows)

    result = run(registry, small_xml(node), with_rows(nan_rows))
    assert (result.status, result.failure_kind) == ("FAILURE", "malformed chunk")
    assert result.reason == "chunk 1 rejected: step 4 joint 'elbow_joint' is not finite (nan)"

    def renamed(request: Any) -> Any:
        names = list(request.robot_state.name)
        names[0] = "base_joint"
        return chunk_response(names, np.tile(np.array(request.robot_state.position), (50, 1)))

    result = run(registry, small_xml(node), with_rows(renamed))
    assert result.status == "FAILURE" and result.reason.startswith("chunk 1 rejected: joint names do not match the joint group")

    result = run(registry, small_xml(node), ScriptedPolicy(hold()), latency_s=4.0)  # the warmup never answers in 3 s
    assert (result.status, result.failure_kind) == ("FAILURE", "policy timeout")
    assert result.reason == (f"warming up the policy service '{SERVICE}' timed out after 3 s (raise policy_call_timeout, or make "
                             "the server finish its own warmup before it reports ready)")


@pytest.mark.parametrize("node", ["ExecuteWithLeRobotQueue", LEROBOT_RTC, "ExecuteNewestWinsOnJtc",
                                  "ExecuteOnJtcWithUpsampling"])
def test_the_jtc_executors_refuse_the_admittance_controller(registry, node):
    xml = small_xml(node).replace(JTC, "/joint_trajectory_admittance_controller/follow_joint_trajectory").replace(
        'activate_controllers="joint_trajectory_controller"', 'activate_controllers="joint_trajectory_admittance_controller"')
    result = run(registry, xml, ScriptedPolicy(hold()))
    assert result.status == "ERROR"
    assert f"{node} streams to a joint_trajectory_controller" in result.reason
    assert "MoveIt Pro's admittance controller" in result.reason


@pytest.mark.parametrize("node", ["ExecuteChunksSynchronously", "ExecuteWithLeRobotQueue", LEROBOT_RTC, "ExecuteNewestWinsOnJtc",
                                  "ExecuteOnJtcWithUpsampling"])
def test_a_missing_policy_service_is_an_error_before_anything_moves(registry, node):
    """The ports name what they need (ExecutePolicy's), so the world check finds the missing service."""
    options = RunOptions(seed=0, max_seconds=30.0, world="kinematic")
    context = make_context(options)
    world = KinematicWorld({"seed": 0, "policy": "none"})
    result = run_tree(load_tree(small_xml(node), registry, context), context, options, world=world)
    assert result.status == "ERROR" and result.sim_seconds == 0.0
    assert f"{node}: port 'policy_service_name': no service '{SERVICE}' (services: " in result.reason


@pytest.mark.parametrize("node", ["ExecuteChunksSynchronously", "ExecuteNewestWinsOnJtc"])
def test_a_reading_over_the_threshold_on_the_wrench_topic_fails_with_execute_policys_kind_and_reason(registry, node):
    """The force-torque watch is the session's: an executor's run ends as ExecutePolicy's does."""
    world = KinematicWorld({"seed": 0, "policy": "none"})
    wrench = "/force_torque_sensor_broadcaster/wrench"

    def push_at_call_2(index: int, request: Any) -> Any:
        if index == 2:
            world.cell.external_wrench = np.array([0.0, 0.0, -80.0, 0.0, 0.0, 0.0])
        return hold(velocity=TURN)(index, request)

    result = run(registry, small_xml(node, f'wrench_topic="{wrench}"'), ScriptedPolicy(push_at_call_2), world=world)
    assert (result.status, result.failure_kind) == ("FAILURE", "force-torque threshold")
    assert result.reason == (f"force-torque threshold exceeded on '{wrench}': Fz = -80.00 N exceeds the absolute threshold "
                             "45.00 N; goal cancelled, robot stopped")
    assert not world.controllers["joint_trajectory_controller"].executing

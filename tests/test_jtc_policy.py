"""ExecutePolicy and the motion behaviors on the stock ``joint_trajectory_controller`` (JTC).

The controller interface follows the type served under ``controller_action_name``; a wrench topic
stands in for the admittance controller's force-torque abort. On the kinematic cell (fast), with
the scripted policies of ``test_execute_policy``; the physics cell for contact.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped

from behaviors.wrench_watch import WrenchWatch, threshold_crossing
from runtime.io.bus import FixedLatency, InProcessBus
from runtime.io.clock import SimClock
from tests.test_execute_policy import BASE, ScriptedPolicy, _record_commands, box_appears_ahead, hold, registry, run_policy  # noqa: F401

JTC = "/joint_trajectory_controller/follow_joint_trajectory"
WRENCH = "/force_torque_sensor_broadcaster/wrench"
ON_JTC = '<Sequence><SwitchController activate_controllers="joint_trajectory_controller" automatic_deactivation="true"/>{node}</Sequence>'
TURN = np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])


def on_jtc(ports: str) -> str:
    return f'{BASE} controller_action_name="{JTC}" {ports}'


def commanded(registry, ports: str, wrap: str | None, world_options: dict[str, Any] | None = None) -> tuple[Any, np.ndarray, np.ndarray]:
    """Run the turning policy; the run, and the arm commands (times, positions) once per control step."""
    holder: dict[str, Any] = {}

    def record(context, world):
        holder["log"] = _record_commands(world)

    run = run_policy(registry, ports, ScriptedPolicy(hold(velocity=TURN)), prepare=wrap is None, wrap=wrap,
                     world_options=world_options, before=record)
    times = np.array([t for t, _ in holder["log"]])
    positions = np.array([p for _, p in holder["log"]])
    last = np.append(np.diff(times) > 1e-9, True)  # the last command of each control step
    return run, times[last], positions[last]


@pytest.mark.parametrize("replacement", ["true", "false"])
def test_a_policy_plays_on_the_jtc_as_on_the_admittance_controller_in_both_modes(registry, replacement):
    run, times, q = commanded(registry, on_jtc(""), ON_JTC, {"allow_trajectory_replacement": replacement})
    assert (run.result.status, run.result.reason) == ("SUCCESS", "")
    assert run.summary["steps_executed"] == 60 and run.summary["chunks"] >= 3
    velocity = np.diff(q[:, 0]) / np.diff(times)
    assert np.abs(np.diff(velocity)).max() < 0.02  # no velocity jump at any seam (0.02 rad/s per 2 ms)
    reference, ref_times, ref_q = commanded(registry, BASE, None)
    assert reference.result.status == "SUCCESS"
    # The same motion from its start (the controller switch before it takes wall-clock latency).
    times, ref_times = times - motion_start(times, q), ref_times - motion_start(ref_times, ref_q)
    common = np.arange(0.0, min(times[-1], ref_times[-1]), 0.002)
    difference = np.abs(np.interp(common, times, q[:, 0]) - np.interp(common, ref_times, ref_q[:, 0]))
    assert difference.max() < 1e-6  # measured: 5e-12 rad


def motion_start(times: np.ndarray, q: np.ndarray) -> float:
    """When the commanded joint 0 first leaves where it started (by 1 urad)."""
    return float(times[np.argmax(np.abs(q[:, 0] - q[0, 0]) > 1e-6)])


def test_an_action_served_with_another_type_is_an_error_naming_both_types(registry):
    """In process the world's names are checked before the first tick: the port names the action
    and both types it may have."""
    ports = f'{BASE} controller_action_name="/robotiq_gripper_controller/gripper_cmd"'
    run = run_policy(registry, ports, ScriptedPolicy(hold()))
    assert (run.result.status, run.result.failure_kind) == ("ERROR", "SetupError")
    assert run.result.reason.endswith(
        "ExecutePolicy: port 'controller_action_name': action '/robotiq_gripper_controller/gripper_cmd' is a control_msgs/action/GripperCommand, not a moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance or a control_msgs/action/FollowJointTrajectory"
    )
    assert run.policy.requests == []  # nothing was asked of the policy


def test_the_controller_link_names_both_types_when_the_served_type_is_another():
    """Over ROS 2 the graph may still be starting before the first tick: then the node's own link
    finds the type when the action appears, and says the same."""
    from behaviors.controller_link import ControllerTypeError, controller_kind

    with pytest.raises(ControllerTypeError) as caught:
        controller_kind("/robotiq_gripper_controller/gripper_cmd", ["control_msgs/action/GripperCommand"])
    assert str(caught.value) == (
        "controller action '/robotiq_gripper_controller/gripper_cmd' is served with type control_msgs/action/GripperCommand; "
        "expected moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance (MoveIt Pro's admittance controller) "
        "or control_msgs/action/FollowJointTrajectory (ros2_controllers' joint_trajectory_controller)"
    )


def _spike_at_call(index: int, wrench: np.ndarray, velocity: np.ndarray = TURN * 0.3):
    def install(context, world):
        def answer(i, request):
            if i == index:
                world.cell.external_wrench = wrench
            return hold(velocity=velocity)(i, request)

        install.policy.answer = answer

    install.policy = ScriptedPolicy(hold())
    return install


def test_a_reading_over_the_threshold_on_the_wrench_topic_cancels_the_jtc_goal_and_fails(registry):
    spike = _spike_at_call(2, np.array([0.0, 0.0, -80.0, 0.0, 0.0, 0.0]))
    run = run_policy(registry, on_jtc(f'wrench_topic="{WRENCH}"'), spike.policy, prepare=False, wrap=ON_JTC, before=spike)
    assert (run.result.status, run.result.failure_kind) == ("FAILURE", "force-torque threshold")
    assert run.result.reason == (
        f"force-torque threshold exceeded on '{WRENCH}': Fz = -80.00 N exceeds the absolute threshold 45.00 N; "
        "goal cancelled, robot stopped"
    )
    jtc = run.world.controllers["joint_trajectory_controller"]
    assert not jtc.executing
    assert np.abs(jtc.trajectory.sample(run.result.sim_seconds + 1.0).velocity).max() == 0.0  # brought to rest


def test_with_the_admittance_controller_the_reason_says_which_abort_tripped(registry):
    spike = _spike_at_call(2, np.array([0.0, 0.0, 80.0, 0.0, 0.0, 0.0]))
    run = run_policy(registry, f'{BASE} wrench_topic="{WRENCH}"', spike.policy, before=spike)
    assert run.result.status == "FAILURE"
    assert run.result.reason.startswith("the controller aborted the motion: force-torque threshold exceeded")


def test_a_wrench_topic_that_never_publishes_fails_at_start_naming_it(registry):
    run = run_policy(registry, on_jtc('wrench_topic="/nobody/wrench"'), ScriptedPolicy(hold()), prepare=False, wrap=ON_JTC)
    assert (run.result.status, run.result.failure_kind) == ("ERROR", "SetupError")  # a topic the robot lacks
    assert "a reading on wrench topic '/nobody/wrench'" in run.result.reason


@pytest.mark.parametrize("reliable", [True, False])
def test_the_wrench_watch_hears_reliable_and_best_effort_publishers(reliable):
    bus = InProcessBus(SimClock(), default_latency=FixedLatency(0.0))
    watch = WrenchWatch(bus, "/ft", (45.0, 45.0, 45.0, 10.0, 10.0, 10.0))
    msg = WrenchStamped()
    msg.wrench.torque.y = -12.5
    bus.create_publisher("/ft", WrenchStamped, reliable=reliable).publish(msg)
    assert watch.crossing() == "Ty = -12.50 N m exceeds the absolute threshold 10.00 N m"


def test_the_first_axis_over_its_threshold_is_named_and_nan_counts_as_over():
    limits = (45.0, 45.0, 45.0, 10.0, 10.0, 10.0)
    assert threshold_crossing((0, 0, 44.9, 9.9, 0, 0), limits) is None
    assert threshold_crossing((0, 50.0, 0, 0, 0, 11.0), limits) == "Fy = 50.00 N exceeds the absolute threshold 45.00 N"
    assert threshold_crossing((0, 0, 0, float("nan"), 0, 0), limits).startswith("Tx = nan N m")


def test_an_object_appearing_in_the_path_stops_the_arm_on_the_jtc(registry):
    run = run_policy(registry, on_jtc(""), ScriptedPolicy(hold(velocity=TURN)), prepare=False, wrap=ON_JTC,
                     before=box_appears_ahead(TURN))
    assert run.result.status == "FAILURE"
    assert run.result.reason.startswith("the planning scene changed:") and "intruder" in run.result.reason
    assert not run.world.controllers["joint_trajectory_controller"].executing


def test_move_to_waypoint_on_an_action_of_another_type_is_an_error_too(registry, tmp_path):
    from tests.test_mpro_trajectories import run_xml

    result = run_xml(registry, tmp_path, '<MoveToWaypoint waypoint_name="Home" controller_action_name="/robotiq_gripper_controller/gripper_cmd"/>')
    assert result.status == "ERROR"
    assert "port 'controller_action_name': action '/robotiq_gripper_controller/gripper_cmd' is a control_msgs/action/GripperCommand, not a moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance or a control_msgs/action/FollowJointTrajectory" in result.reason


def test_a_jtc_goal_aborted_just_before_the_next_arrives_ends_the_run_with_its_abort(registry, monkeypatch):
    # The JTC aborts the goal it plays (a path tolerance violation) just before the third goal
    # arrives, then takes that goal from where the arm stopped. A goal it preempts ends aborted
    # too, with INVALID_GOAL; this one is no preemption: the run ends with it.
    import sim.controllers.jtc as jtc

    on_goal, goals = jtc.JointTrajectoryController._on_goal, []

    def aborted_first(self, handle):
        goals.append(handle)
        if len(goals) == 3 and self._goal is not None:
            self._end_goal("abort", jtc.Result(error_code=jtc.Result.PATH_TOLERANCE_VIOLATED,
                                               error_string="Aborted due to path tolerance violation"))
            self._stop(self.clock.now())
        return on_goal(self, handle)

    monkeypatch.setattr(jtc.JointTrajectoryController, "_on_goal", aborted_first)
    run = run_policy(registry, on_jtc(""), ScriptedPolicy(hold(velocity=TURN)), prepare=False, wrap=ON_JTC)
    assert (run.result.status, run.result.reason) == ("FAILURE", "the controller aborted the motion: Aborted due to path tolerance violation")
    assert len(goals) == 3

"""The stock pieces in the cell: ``joint_trajectory_controller`` (JTC) and ``force_torque_sensor_broadcaster``.

The sampling model (``sim.controllers.jtc_trajectory``) is checked against the polynomials JTC
uses (linear, cubic, quintic from the fields present) and against its trajectory replacement
(merge at arrival, ros2_controllers #2419; hard replace). The controller runs against the
``FakeHardware`` of ``test_controllers`` (perfect tracking, one step late).
"""
from __future__ import annotations

import numpy as np
import pytest
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance, JointTrajectoryControllerState
from geometry_msgs.msg import WrenchStamped
from hypothesis import given, settings
from hypothesis import strategies as st
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from runtime.io.bus import STATUS_ABORTED, STATUS_SUCCEEDED
from runtime.io.timestamps import duration_msg, time_msg, to_seconds
from controller_manager_msgs.srv import SwitchController

from runtime.io.bus import FixedLatency, InProcessBus
from runtime.io.clock import SimClock
from sim.controllers import (
    FT_BROADCASTER,
    JTC_ACTION,
    JTC_CONTROLLER,
    JTC_TOPIC,
    SWITCH_SERVICE,
    VELOCITY_CONTROLLER,
    WRENCH_TOPIC,
    ControllersConfig,
    JtcParams,
    make_controllers,
)
from sim.controllers.jtc_trajectory import JtcPoints, JtcTrajectory, merge_at_arrival, replace_at_arrival
from sim.controllers.trajectory import TrajectoryState
from tests.test_controllers import ARM, HOME, Cell, FakeHardware

Result = FollowJointTrajectory.Result
REST = TrajectoryState(np.zeros(1), np.zeros(1), np.zeros(1))
finite = st.floats(-3.0, 3.0)


# -- the sampling model --------------------------------------------------------------------------
def _one_segment(h, p0, p1, v=None, a=None) -> JtcTrajectory:
    points = JtcPoints.build(np.array([0.0, h]), np.array([[p0], [p1]]),
                             None if v is None else np.array([[v[0]], [v[1]]]), None if a is None else np.array([[a[0]], [a[1]]]))
    return JtcTrajectory(points, 0.0, points.state(0))


@settings(max_examples=60, deadline=None)
@given(h=st.floats(0.01, 2.0), p0=finite, p1=finite, tau=st.floats(0.0, 1.0))
def test_positions_only_points_are_joined_by_a_line(h, p0, p1, tau):
    state = _one_segment(h, p0, p1).sample(tau * h * 0.999)
    assert state.position[0] == pytest.approx(p0 + (p1 - p0) * tau * 0.999, abs=1e-9)
    assert state.velocity[0] == pytest.approx((p1 - p0) / h, rel=1e-9, abs=1e-9)
    assert state.acceleration[0] == pytest.approx(0.0, abs=1e-6)


@settings(max_examples=60, deadline=None)
@given(h=st.floats(0.05, 2.0), p0=finite, p1=finite, v0=finite, v1=finite)
def test_points_with_velocities_are_joined_by_a_cubic(h, p0, p1, v0, v1):
    trajectory = _one_segment(h, p0, p1, v=(v0, v1))
    start, middle, end = (trajectory.sample(t) for t in (0.0, h / 2, h * (1 - 1e-9)))
    assert (start.position[0], start.velocity[0]) == pytest.approx((p0, v0), abs=1e-9)
    assert (end.position[0], end.velocity[0]) == pytest.approx((p1, v1), abs=1e-6)
    # a cubic's acceleration is linear in time: the middle is the mean of the ends
    scale = 1.0 + abs(start.acceleration[0]) + abs(end.acceleration[0])
    assert middle.acceleration[0] == pytest.approx((start.acceleration[0] + end.acceleration[0]) / 2, abs=1e-6 * scale)


@settings(max_examples=60, deadline=None)
@given(h=st.floats(0.05, 2.0), p0=finite, p1=finite, v0=finite, v1=finite, a0=finite, a1=finite)
def test_points_with_velocities_and_accelerations_are_joined_by_a_quintic(h, p0, p1, v0, v1, a0, a1):
    trajectory = _one_segment(h, p0, p1, v=(v0, v1), a=(a0, a1))
    start, end = trajectory.sample(0.0), trajectory.sample(h * (1 - 1e-12))
    assert (start.position[0], start.velocity[0], start.acceleration[0]) == pytest.approx((p0, v0, a0), abs=1e-9)
    assert (end.position[0], end.velocity[0], end.acceleration[0]) == pytest.approx((p1, v1, a1), rel=1e-5, abs=1e-5)


def test_after_the_last_point_jtc_holds_it():
    trajectory = _one_segment(1.0, 0.0, 1.0)
    assert trajectory.sample(5.0).position[0] == 1.0 and trajectory.sample(5.0).velocity[0] == 0.0


def _old() -> JtcTrajectory:
    """A trajectory playing from t=0: 0 -> 1 rad over 2 s, quintic, at rest at both ends."""
    times = np.linspace(0.0, 2.0, 21)
    s = times / 2.0
    positions = (10 * s**3 - 15 * s**4 + 6 * s**5)[:, None]
    velocities = ((30 * s**2 - 60 * s**3 + 30 * s**4) / 2.0)[:, None]
    accelerations = ((60 * s - 180 * s**2 + 120 * s**3) / 4.0)[:, None]
    points = JtcPoints.build(times, positions, velocities, accelerations)
    return JtcTrajectory(points, 0.0, points.state(0))


def test_merge_at_arrival_keeps_the_old_path_until_the_stamp_then_plays_the_new_points():
    old = _old()
    new = JtcPoints.build(np.array([0.0, 0.5]), np.array([[old.sample(1.2).position[0]], [0.2]]),
                          np.array([[old.sample(1.2).velocity[0]], [0.0]]), np.array([[old.sample(1.2).acceleration[0]], [0.0]]))
    merged = merge_at_arrival(old, new, stamp_s=1.2, now_s=0.7, before=old.sample(0.7))
    for t in (0.75, 0.9, 1.0, 1.19):
        assert merged.sample(t).position[0] == pytest.approx(old.sample(t).position[0], abs=1e-12)
    assert merged.sample(1.7).position[0] == pytest.approx(0.2)
    assert merged.sample(1.2).velocity[0] == pytest.approx(old.sample(1.2).velocity[0])


def test_merge_at_arrival_bridges_from_the_old_spline_when_the_new_points_start_later():
    old = _old()
    new = JtcPoints.build(np.array([0.3, 0.8]), np.array([[0.9], [0.9]]), np.zeros((2, 1)), np.zeros((2, 1)))
    merged = merge_at_arrival(old, new, stamp_s=1.0, now_s=0.5, before=old.sample(0.5))
    bridge = old.sample(1.0)
    assert 1.0 in merged.points.times
    for t in (1.0 - 1e-4, 1.0 + 1e-4):  # position and velocity continuous through the bridge point
        assert merged.sample(t).position[0] == pytest.approx(bridge.position[0], abs=1e-3)
        assert merged.sample(t).velocity[0] == pytest.approx(bridge.velocity[0], abs=1e-2)


def test_a_past_stamp_hands_over_now_in_both_modes():
    old = _old()
    new = JtcPoints.build(np.array([0.5]), np.array([[0.3]]), np.zeros((1, 1)), np.zeros((1, 1)))
    now = 1.0
    merged = merge_at_arrival(old, new, stamp_s=0.4, now_s=now, before=old.sample(now))
    replaced = replace_at_arrival(new, stamp_s=0.0, now_s=now, before=old.sample(now))
    assert merged.end_time == pytest.approx(1.5) and replaced.end_time == pytest.approx(1.5)
    assert merged.sample(1.5).position[0] == replaced.sample(1.5).position[0] == 0.3


def test_hard_replace_interpolates_from_the_state_at_arrival_to_the_first_point():
    old = _old()
    new = JtcPoints.build(np.array([0.0, 0.5]), np.array([[0.8], [0.9]]), np.zeros((2, 1)), np.zeros((2, 1)))
    replaced = replace_at_arrival(new, stamp_s=1.2, now_s=0.7, before=old.sample(0.7))
    assert replaced.sample(0.7).position[0] == pytest.approx(old.sample(0.7).position[0])
    assert replaced.sample(1.2).position[0] == pytest.approx(0.8)
    assert replaced.sample(0.95).position[0] != pytest.approx(old.sample(0.95).position[0], abs=1e-4)  # not the old path


# -- the controller ------------------------------------------------------------------------------
@pytest.fixture
def cell() -> JtcCell:
    return jtc_cell(JtcParams())


class JtcCell(Cell):
    """``test_controllers.Cell`` with the JTC configured by ``params`` and active."""

    def __init__(self, params: JtcParams) -> None:
        self.clock = SimClock()
        self.bus = InProcessBus(self.clock, default_latency=FixedLatency(0.0))
        self.hw = FakeHardware(self.clock)
        self.manager = make_controllers(self.bus, self.hw, self.clock, ControllersConfig(joint_trajectory=params))
        self.jtc = self.manager[JTC_CONTROLLER]
        self.trajectory_client = self.bus.create_action_client(JTC_ACTION, FollowJointTrajectory)
        self.switch_client = self.bus.create_client(SWITCH_SERVICE, SwitchController)
        response = self.switch([JTC_CONTROLLER], [VELOCITY_CONTROLLER])
        assert response.ok, response.message


def jtc_cell(params: JtcParams) -> JtcCell:
    return JtcCell(params)


def trajectory(times, positions, velocities=None, stamp=0.0, names=ARM) -> JointTrajectory:
    msg = JointTrajectory(joint_names=list(names))
    if stamp:
        msg.header.stamp = time_msg(stamp)
    for k, t in enumerate(times):
        point = JointTrajectoryPoint(positions=[float(v) for v in positions[k]], time_from_start=duration_msg(t))
        if velocities is not None:
            point.velocities = [float(v) for v in velocities[k]]
        msg.points.append(point)
    return msg


def jtc_goal(msg: JointTrajectory, path_position=0.0, goal_position=0.0, goal_time=0.0) -> FollowJointTrajectory.Goal:
    goal = FollowJointTrajectory.Goal(trajectory=msg, goal_time_tolerance=duration_msg(goal_time))
    if path_position:
        goal.path_tolerance = [JointTolerance(name=j, position=path_position) for j in ARM]
    if goal_position:
        goal.goal_tolerance = [JointTolerance(name=j, position=goal_position) for j in ARM]
    return goal


def send(cell: Cell, goal):
    return cell.trajectory_client.send_goal_async(goal).result()


def move(offset: float, seconds: float = 1.0) -> JointTrajectory:
    target = HOME + offset
    return trajectory([seconds / 2, seconds], [(HOME + target) / 2, target], [np.full(6, offset / seconds), np.zeros(6)])


def test_a_goal_plays_and_succeeds_as_jtc_reports_it(cell):
    handle = send(cell, jtc_goal(move(0.2)))
    assert handle.accepted
    cell.run(1.2)
    outcome = handle.get_result_async().result()
    assert (outcome.status, outcome.result.error_code, outcome.result.error_string) == (STATUS_SUCCEEDED, Result.SUCCESSFUL, "Goal successfully reached!")
    np.testing.assert_allclose(cell.hw.q, HOME + 0.2, atol=1e-9)


@pytest.mark.parametrize("msg, reason", [
    (trajectory([1.0], [HOME[:5]], names=ARM[:5]), "don't match the controller joints"),
    (trajectory([1.0], [HOME], [np.full(6, 0.1)]), "velocity of last trajectory point of joint shoulder_pan_joint is not zero"),
    (trajectory([0.5, 0.5], [HOME, HOME]), "time between points 0 and 1 is not strictly increasing"),
    (trajectory([1.0], [HOME], stamp=0.001), "that ends in the past"),
    (trajectory([], []), "empty trajectory received"),
])
def test_invalid_goals_are_rejected_with_the_reason_logged(cell, msg, reason):
    cell.run(2.0)
    assert not send(cell, jtc_goal(msg)).accepted
    assert reason in cell.jtc.last_rejection


def test_an_inactive_jtc_rejects_goals(cell):
    cell.switch([VELOCITY_CONTROLLER], [JTC_CONTROLLER])
    assert not send(cell, jtc_goal(move(0.1))).accepted
    assert "is not running" in cell.jtc.last_rejection


def test_a_new_goal_preempts_the_active_one_with_its_abort_result(cell):
    first = send(cell, jtc_goal(move(0.2, 2.0)))
    cell.run(0.5)
    second = send(cell, jtc_goal(move(0.1)))
    outcome = first.get_result_async().result()  # delivered at once (#2422)
    assert (outcome.status, outcome.result.error_code, outcome.result.error_string) == (
        STATUS_ABORTED, Result.INVALID_GOAL, "Current goal preempted by new incoming action.")
    cell.run(1.5)
    assert second.get_result_async().result().status == STATUS_SUCCEEDED


def test_a_joint_off_its_path_aborts_and_the_arm_stops(cell):
    cell.hw.stuck_joint = 0
    handle = send(cell, jtc_goal(move(0.3), path_position=0.05))
    cell.run(1.0)
    outcome = handle.get_result_async().result()
    assert (outcome.status, outcome.result.error_code, outcome.result.error_string) == (
        STATUS_ABORTED, Result.PATH_TOLERANCE_VIOLATED, "Aborted due to path tolerance violation")
    cell.run(0.5)
    assert np.abs(cell.hw.qd).max() < 1e-9


def test_without_a_goal_position_tolerance_a_stopped_arm_succeeds_wherever_it_is(cell):
    cell.hw.stuck_joint = 2
    handle = send(cell, jtc_goal(move(0.1)))
    cell.run(1.2)
    assert handle.get_result_async().result().result.error_string == "Goal successfully reached!"  # as JTC: velocity alone
    assert cell.hw.q[2] == HOME[2]


def test_a_goal_not_settled_within_its_goal_time_aborts(cell):
    cell.hw.stuck_joint = 2
    handle = send(cell, jtc_goal(move(0.1), goal_position=0.01, goal_time=0.2))
    cell.run(1.5)
    outcome = handle.get_result_async().result()
    assert (outcome.status, outcome.result.error_code) == (STATUS_ABORTED, Result.GOAL_TOLERANCE_VIOLATED)
    assert outcome.result.error_string.startswith("Aborted due to goal_time_tolerance exceeding by 0.2")


def test_the_topic_interface_plays_a_trajectory(cell):
    cell.bus.create_publisher(JTC_TOPIC, JointTrajectory).publish(move(-0.1))
    cell.run(1.2)
    np.testing.assert_allclose(cell.hw.q, HOME - 0.1, atol=1e-9)


def take_over_at(cell: JtcCell, seam: float = 1.0) -> np.ndarray:
    """A 2 s goal, then at t=0.6 s a goal stamped ``seam`` that starts from its state there; the
    final position."""
    send(cell, jtc_goal(move(0.3, 2.0)))
    cell.run(0.6)
    state = cell.jtc.trajectory.sample(seam)
    nxt = trajectory([0.0, 1.0], [state.position, state.position + 0.1], [state.velocity, np.zeros(6)], stamp=seam)
    send(cell, jtc_goal(nxt))
    cell.run(2.0)
    return state.position + 0.1


@pytest.mark.parametrize("replacement", [True, False])
def test_a_goal_stamped_ahead_takes_over_continuously_in_both_modes(replacement):
    cell = jtc_cell(JtcParams(allow_trajectory_replacement=replacement, interpolate_from_desired_state=True))
    end = take_over_at(cell)
    velocity = cell.commanded_velocity()
    assert np.abs(np.diff(velocity, axis=0)).max() < 0.02  # no velocity jump anywhere
    np.testing.assert_allclose(cell.hw.q, end, atol=1e-9)


def test_by_default_a_new_trajectory_starts_from_the_measured_state():
    """JTC's default: the command steps back to where the arm is (here one control step behind)."""
    cell = jtc_cell(JtcParams())
    take_over_at(cell)
    times = [entry[0] for entry in cell.hw.log]
    k = times.index(min(times, key=lambda t: abs(t - 0.6)))
    np.testing.assert_allclose(cell.hw.log[k][1], cell.hw.log[k - 1][1], atol=1e-12)  # the measured position at arrival


def test_the_controller_state_carries_the_reference_the_measured_feedback_and_their_error(cell):
    state = cell.bus.create_subscription("/joint_trajectory_controller/controller_state", JointTrajectoryControllerState,
                                         reliable=False)
    cell.hw.stuck_joint = 2
    send(cell, jtc_goal(move(0.1)))
    cell.run(1.2)
    msg = state.latest
    assert list(msg.joint_names) == list(ARM)
    np.testing.assert_allclose(msg.reference.positions, HOME + 0.1, atol=1e-9)  # it holds the goal's last point
    np.testing.assert_allclose(msg.feedback.positions, cell.hw.q, atol=1e-12)  # where the arm is: joint 3 stuck
    assert msg.error.positions[2] == pytest.approx(0.1) and max(abs(e) for k, e in enumerate(msg.error.positions) if k != 2) < 1e-9
    assert to_seconds(msg.header.stamp) == pytest.approx(cell.clock.now())


def test_the_broadcaster_publishes_the_wrist_wrench_while_active(cell):
    readings = cell.bus.create_subscription(WRENCH_TOPIC, WrenchStamped, reliable=False)
    cell.hw.external_wrench = np.array([1.0, 2.0, -30.0, 0.1, 0.2, 0.3])
    msg = readings.latest
    assert (msg.wrench.force.z, msg.wrench.torque.z, msg.header.frame_id) == (-30.0, 0.3, "world")
    assert cell.switch([], [FT_BROADCASTER]).ok
    cell.hw.external_wrench = np.zeros(6)
    assert readings.latest.wrench.force.z == -30.0  # nothing new while inactive

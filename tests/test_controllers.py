"""The simulated controllers: trajectory maths, the admittance JTC, the manager and the gripper.

Most tests drive the controllers against ``FakeHardware``, a kinematic arm that tracks the last
command perfectly (one control step late, like a stiff servo) and lets a test inject a wrench,
block a joint or put an object between the fingers. The loop is the world's: at 500 Hz,
``manager.update(t, dt)``, then the hardware step, then the clock.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Duration
from control_msgs.action import GripperCommand
from controller_manager_msgs.srv import ListControllers, SwitchController
from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from runtime.io.bus import STATUS_ABORTED, STATUS_CANCELED, STATUS_SUCCEEDED, FixedLatency, InProcessBus
from runtime.io.clock import SimClock
from sim.controllers import (
    BEST_EFFORT,
    GRIPPER_ACTION,
    LIST_SERVICE,
    STRICT,
    SWITCH_SERVICE,
    TRAJECTORY_ACTION,
    TRAJECTORY_CONTROLLER,
    VELOCITY_COMMAND_TOPIC,
    VELOCITY_CONTROLLER,
    AdmittanceParams,
    SeamError,
    Trajectory,
    TrajectoryState,
    make_controllers,
    stitch,
    stop_trajectory,
)
from sim.controllers.admittance import GoalError, parse_goal
from sim.controllers.trajectory import blend_duration
from runtime.io.timestamps import time_msg

Action = FollowJointTrajectoryWithAdmittance
Result = Action.Result
DT = 0.002
ARM = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
HOME = np.array([0.0, -1.57, 1.57, -1.57, -1.57, 0.0])
JACOBIAN = np.array(
    [
        [0.0, 0.4, 0.3, 0.1, 0.0, 0.0],
        [0.5, 0.0, 0.0, 0.0, 0.1, 0.0],
        [0.0, 0.5, 0.4, 0.1, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
        [0.0, 1.0, 1.0, 1.0, 0.0, 0.0],
        [1.0, 0.0, 0.0, 0.0, 0.0, 1.0],
    ]
)


class FakeHardware:
    """A kinematic cell: the arm goes where it was commanded at the next step, unless blocked."""

    arm_joint_names = ARM
    gripper_joint_name = "robotiq_85_left_knuckle_joint"

    def __init__(self, clock: SimClock) -> None:
        self.clock = clock
        self.q = HOME.copy()
        self.qd = np.zeros(6)
        self.command_q = HOME.copy()
        self.command_qd = np.zeros(6)
        self.external_wrench = np.zeros(6)
        self.stuck_joint: int | None = None
        self.gripper = 0.0
        self.gripper_qd = 0.0
        self.gripper_target = 0.0
        self.gripper_effort = 0.0
        self.gripper_speed = 2.0  # rad/s
        self.finger_obstacle: float | None = None  # the fingers cannot close past this (a cube)
        self.log: list[tuple[float, np.ndarray, np.ndarray]] = []

    def time(self) -> float:
        return self.clock.now()

    def arm_position(self) -> np.ndarray:
        return self.q.copy()

    def arm_velocity(self) -> np.ndarray:
        return self.qd.copy()

    def command_arm(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        self.command_q = np.array(position, dtype=float)
        self.command_qd = np.zeros(6) if velocity is None else np.array(velocity, dtype=float)

    def gripper_position(self) -> float:
        return self.gripper

    def gripper_velocity(self) -> float:
        return self.gripper_qd

    def command_gripper(self, position: float, max_effort: float) -> None:
        self.gripper_target, self.gripper_effort = position, max_effort

    def wrench(self) -> np.ndarray:
        return self.external_wrench.copy()

    def wrist_jacobian(self) -> np.ndarray:
        return JACOBIAN.copy()

    def step(self, dt: float) -> None:
        self.log.append((self.clock.now(), self.command_q.copy(), self.command_qd.copy()))
        new_q = self.command_q.copy()
        if self.stuck_joint is not None:
            new_q[self.stuck_joint] = self.q[self.stuck_joint]
        self.qd = (new_q - self.q) / dt
        self.q = new_q
        limit = self.finger_obstacle if self.finger_obstacle is not None and self.gripper_target > self.finger_obstacle else self.gripper_target
        move = float(np.clip(limit - self.gripper, -self.gripper_speed * dt, self.gripper_speed * dt))
        self.gripper += move
        self.gripper_qd = move / dt


class Cell:
    def __init__(self) -> None:
        self.clock = SimClock()
        self.bus = InProcessBus(self.clock, default_latency=FixedLatency(0.0))
        self.hw = FakeHardware(self.clock)
        self.manager = make_controllers(self.bus, self.hw, self.clock)
        self.jtc = self.manager[TRAJECTORY_CONTROLLER]
        self.trajectory_client = self.bus.create_action_client(TRAJECTORY_ACTION, Action)
        self.gripper_client = self.bus.create_action_client(GRIPPER_ACTION, GripperCommand)
        self.switch_client = self.bus.create_client(SWITCH_SERVICE, SwitchController)

    def run(self, seconds: float) -> None:
        for _ in range(int(round(seconds / DT))):
            self.manager.update(self.clock.now(), DT)
            self.hw.step(DT)
            self.clock.advance(DT)
            self.bus.spin_once()

    def switch(self, activate=(), deactivate=(), strictness=STRICT) -> SwitchController.Response:
        request = SwitchController.Request(
            activate_controllers=list(activate), deactivate_controllers=list(deactivate), strictness=strictness
        )
        future = self.switch_client.call_async(request)
        self.bus.spin_once()
        return future.result()

    def activate_trajectory_controller(self) -> None:
        response = self.switch([TRAJECTORY_CONTROLLER], [VELOCITY_CONTROLLER])
        assert response.ok, response.message

    def send(self, goal) -> "GoalWatch":
        handle = self.trajectory_client.send_goal_async(goal).result()
        assert handle.accepted
        return GoalWatch(handle)

    def commanded_velocity(self) -> np.ndarray:
        """Commanded joint velocity per step, from the commanded positions (what the servo sees)."""
        q = np.array([entry[1] for entry in self.hw.log])
        return np.diff(q, axis=0) / DT


class GoalWatch:
    def __init__(self, handle) -> None:
        self.handle = handle
        self.future = handle.get_result_async()

    def done(self) -> bool:
        return self.future.done()

    @property
    def status(self) -> int:
        return self.future.result().status

    @property
    def result(self):
        return self.future.result().result


def _duration(seconds: float) -> Duration:
    sec = math.floor(seconds)
    return Duration(sec=int(sec), nanosec=int(round((seconds - sec) * 1e9)))


def goal(
    times,
    positions,
    velocities=None,
    stamp: float = 0.0,
    path_tolerance: float = 0.05,
    thresholds=(),
    joint_names=ARM,
    goal_time_tolerance: float = 0.5,
    stiffness=(),
) -> Action.Goal:
    trajectory = JointTrajectory(joint_names=list(joint_names))
    if stamp:
        trajectory.header.stamp = time_msg(stamp)
    for k, (t, p) in enumerate(zip(times, positions)):
        point = JointTrajectoryPoint(positions=[float(v) for v in p], time_from_start=_duration(t))
        if velocities is not None:
            point.velocities = [float(v) for v in velocities[k]]
        trajectory.points.append(point)
    return Action.Goal(
        joint_trajectory=trajectory,
        path_tolerance=path_tolerance,
        goal_time_tolerance=goal_time_tolerance,
        absolute_force_torque_threshold=list(thresholds),
        admittance_stiffness=list(stiffness),
    )


def ramp_goal(start: np.ndarray, delta: np.ndarray, duration: float, **kwargs) -> Action.Goal:
    """From ``start`` at rest to ``start + delta`` at rest (a densified min-jerk profile)."""
    times = np.linspace(0.0, duration, 21)
    s = times / duration
    shape = 10 * s**3 - 15 * s**4 + 6 * s**5
    rate = (30 * s**2 - 60 * s**3 + 30 * s**4) / duration
    return goal(times, start + np.outer(shape, delta), np.outer(rate, delta), **kwargs)


@pytest.fixture
def cell() -> Cell:
    return Cell()


# ---------------------------------------------------------------------------------------------
# Pure trajectory maths
# ---------------------------------------------------------------------------------------------
def test_quintic_pieces_match_their_knots_and_derivatives():
    tr = Trajectory(np.array([1.0, 2.0]), np.array([[0.0], [1.0]]), np.array([[0.5], [-0.2]]), np.array([[0.3], [0.1]]))
    end = tr.sample(2.0 - 1e-9)
    assert end.position[0] == pytest.approx(1.0, abs=1e-6)
    assert end.velocity[0] == pytest.approx(-0.2, abs=1e-6)
    assert end.acceleration[0] == pytest.approx(0.1, abs=1e-5)
    t, eps = 1.37, 1e-6
    assert tr.sample(t).velocity[0] == pytest.approx((tr.sample(t + eps).position[0] - tr.sample(t - eps).position[0]) / (2 * eps), rel=1e-6)
    # Outside the knots the trajectory holds its end points at rest.
    assert tr.sample(5.0).position[0] == 1.0 and tr.sample(5.0).velocity[0] == 0.0


def test_positions_only_trajectory_uses_finite_differences_and_ends_at_rest():
    tr = Trajectory.from_points(np.array([0.0, 1.0, 2.0, 3.0]), np.array([[0.0], [1.0], [2.0], [2.5]]))
    np.testing.assert_allclose(tr.velocities[:, 0], [1.0, 1.0, 0.75, 0.0])
    assert tr.accelerations[-1, 0] == 0.0
    end = tr.sample(3.0 - 1e-9)
    assert end.position[0] == pytest.approx(2.5) and end.velocity[0] == pytest.approx(0.0, abs=1e-6)


def test_trajectory_times_must_increase():
    with pytest.raises(ValueError, match=r"times must increase strictly: point 2 at t=1.000000 s follows t=1.500000 s"):
        Trajectory.from_points(np.array([0.0, 1.5, 1.0]), np.zeros((3, 2)))


def _line(t0: float, t1: float, q0: float, q1: float, n: int = 11) -> Trajectory:
    times = np.linspace(t0, t1, n)
    q = np.linspace(q0, q1, n)[:, None] * np.ones((1, 2))
    v = np.full_like(q, (q1 - q0) / (t1 - t0))
    return Trajectory(times, q, v, np.zeros_like(q))


def test_stitch_follows_current_until_the_seam_and_is_continuous_there():
    current = Trajectory.from_points(np.array([0.0, 1.0, 2.0]), np.array([[0.0, 0.0], [0.5, 0.2], [1.0, 0.0]]))
    seam = 1.3
    at_seam = current.sample(seam)
    new_times = seam + np.array([0.0, 0.5, 1.0])
    new = Trajectory.from_points(
        new_times,
        np.vstack([at_seam.position, at_seam.position + [0.3, -0.1], at_seam.position + [0.4, -0.1]]),
        np.vstack([at_seam.velocity, [0.4, -0.1], [0.0, 0.0]]),
    )
    result = stitch(current, new, seam, path_tolerance=0.01)
    for t in (0.2, 0.9, 1.29):
        np.testing.assert_allclose(result.sample(t).position, current.sample(t).position, atol=1e-12)
    before, after = result.sample(seam - 1e-7), result.sample(seam + 1e-7)
    np.testing.assert_allclose(before.position, after.position, atol=1e-6)
    np.testing.assert_allclose(before.velocity, after.velocity, atol=1e-5)
    np.testing.assert_allclose(before.acceleration, after.acceleration, atol=1e-3)
    np.testing.assert_allclose(result.sample(seam + 1.0).position, new.positions[-1])
    assert result.end_time == pytest.approx(seam + 1.0)


def test_stitch_rejects_a_seam_after_the_end_of_the_current_trajectory():
    current = _line(0.0, 2.0, 0.0, 1.0)
    new = _line(2.5, 3.0, 1.0, 1.2)
    with pytest.raises(SeamError) as err:
        stitch(current, new, 2.5, path_tolerance=0.1)
    assert str(err.value) == (
        "seam time exceeds the end of the current trajectory (seam t=2.5000 s, trajectory ends at t=2.0000 s)"
    )


def test_stitch_rejects_position_and_velocity_deviation_at_the_seam():
    current = _line(0.0, 2.0, 0.0, 1.0)  # 0.5 rad/s on both joints
    jumped = Trajectory(np.array([1.0, 2.0]), np.array([[0.5, 0.58], [1.0, 1.0]]), np.array([[0.5, 0.5], [0.5, 0.5]]), np.zeros((2, 2)))
    with pytest.raises(SeamError, match=r"position deviation at the seam on elbow_joint: 0.0800 rad exceeds the path tolerance 0.0500"):
        stitch(current, jumped, 1.0, path_tolerance=0.05, joint_names=("shoulder_pan_joint", "elbow_joint"))
    fast = Trajectory(np.array([1.0, 2.0]), np.array([[0.5, 0.5], [1.0, 1.0]]), np.array([[0.5, 0.7], [0.5, 0.5]]), np.zeros((2, 2)))
    with pytest.raises(SeamError, match=r"velocity deviation at the seam on joint 1: 0.2000 rad/s exceeds the path tolerance 0.0500"):
        stitch(current, fast, 1.0, path_tolerance=0.05)
    # Within the tolerance the join is accepted, and zero tolerance means no check.
    stitch(current, jumped, 1.0, path_tolerance=0.1)
    stitch(current, fast, 1.0, path_tolerance=0.0)


def test_a_first_point_off_the_held_reference_fades_in_instead_of_jumping():
    # The servos sag a few mrad under the gripper's weight, so a first chunk planned from the
    # measured position starts that far from the reference the controller holds. Closing 3 mrad
    # in the chunk's first 10 ms interval asked ~150 rad/s^2 (and a jolt on the wrist sensor).
    held = Trajectory.hold(0.0, np.zeros(2))
    times = 1.0 + np.arange(41) * 0.01
    start = np.array([0.003, -0.002])
    new = Trajectory(times, start + np.outer(times - 1.0, [0.05, 0.0]), np.tile([0.05, 0.0], (41, 1)), np.zeros((41, 2)))
    result = stitch(held, new, 1.0, path_tolerance=0.3, allow_after_end=True, blend_acceleration=1.0, min_blend_time=0.05)
    at_seam = result.sample(1.0)
    np.testing.assert_allclose(at_seam.position, 0.0, atol=1e-12)
    np.testing.assert_allclose(at_seam.velocity, 0.0, atol=1e-12)
    accelerations = np.array([result.sample(t).acceleration for t in np.arange(1.0, 1.4, 0.0005)])
    assert np.abs(accelerations).max() <= 1.0 + 1e-6
    deviation = TrajectoryState(-start, np.array([-0.05, 0.0]), np.zeros(2))
    duration = blend_duration(deviation, 1.0, 0.05)
    assert 0.05 < duration < 0.5
    for t in (1.0 + duration, 1.0 + duration + 0.05, 1.4):  # after the fade: the goal's own trajectory, exactly
        np.testing.assert_allclose(result.sample(t).position, new.sample(t).position, atol=1e-12)
        np.testing.assert_allclose(result.sample(t).velocity, new.sample(t).velocity, atol=1e-12)


def test_an_exact_seam_point_is_joined_without_any_fade():
    current = _line(0.0, 2.0, 0.0, 1.0)
    new = _line(1.0, 3.0, 0.5, 1.5)
    result = stitch(current, new, 1.0, path_tolerance=0.1)
    np.testing.assert_array_equal(result.times, np.concatenate([current.times[current.times < 1.0], new.times]))


def test_stop_trajectory_decelerates_to_rest_without_a_jump():
    stop = stop_trajectory(TrajectoryState(np.array([0.2]), np.array([1.0]), np.array([0.0])), 3.0, 0.2)
    velocities = np.array([stop.sample(t).velocity[0] for t in np.linspace(3.0, 3.2, 41)])
    assert velocities[0] == pytest.approx(1.0)
    assert velocities[-1] == pytest.approx(0.0, abs=1e-9)
    assert np.all(np.diff(velocities) <= 1e-12)  # monotone: no reversal
    assert stop.sample(3.5).position[0] == pytest.approx(0.2 + 1.0 * 0.2 / 2)


# ---------------------------------------------------------------------------------------------
# Controller manager
# ---------------------------------------------------------------------------------------------
def _states(cell: Cell) -> dict[str, str]:
    future = cell.bus.create_client(LIST_SERVICE, ListControllers).call_async(ListControllers.Request())
    return {c.name: c.state for c in future.result().controller}


def test_list_controllers_reports_the_start_state_and_claimed_interfaces(cell):
    response = cell.bus.create_client(LIST_SERVICE, ListControllers).call_async(ListControllers.Request()).result()
    by_name = {c.name: c for c in response.controller}
    assert {n: c.state for n, c in by_name.items()} == {
        "joint_trajectory_admittance_controller": "inactive",
        "joint_trajectory_controller": "inactive",
        "velocity_force_controller": "active",
        "robotiq_gripper_controller": "active",
        "force_torque_sensor_broadcaster": "active",
    }
    assert "shoulder_pan_joint/position" in by_name["velocity_force_controller"].claimed_interfaces
    assert by_name["joint_trajectory_admittance_controller"].claimed_interfaces == []
    assert by_name["robotiq_gripper_controller"].claimed_interfaces == ["robotiq_85_left_knuckle_joint/position"]
    assert by_name["joint_trajectory_controller"].type == "joint_trajectory_controller/JointTrajectoryController"
    assert by_name["force_torque_sensor_broadcaster"].claimed_interfaces == []
    assert by_name["force_torque_sensor_broadcaster"].required_state_interfaces[0] == "wrist_ft_sensor/force.x"


def test_strict_switch_fails_whole_on_an_unknown_controller(cell):
    response = cell.switch([TRAJECTORY_CONTROLLER, "nope_controller"], [VELOCITY_CONTROLLER], STRICT)
    assert not response.ok
    assert "cannot activate 'nope_controller': no such controller" in response.message
    assert _states(cell)[TRAJECTORY_CONTROLLER] == "inactive"
    assert _states(cell)[VELOCITY_CONTROLLER] == "active"


def test_best_effort_switch_does_what_it_can(cell):
    response = cell.switch([TRAJECTORY_CONTROLLER, "nope_controller"], [VELOCITY_CONTROLLER], BEST_EFFORT)
    assert response.ok
    assert "skipped (BEST_EFFORT): cannot activate 'nope_controller'" in response.message
    assert _states(cell)[TRAJECTORY_CONTROLLER] == "active"
    assert _states(cell)[VELOCITY_CONTROLLER] == "inactive"


def test_activating_a_conflicting_controller_names_both(cell):
    response = cell.switch([TRAJECTORY_CONTROLLER], [], STRICT)
    assert not response.ok
    assert response.message == (
        "switch refused (STRICT): cannot activate 'joint_trajectory_admittance_controller': its command "
        "interfaces are claimed by active controller 'velocity_force_controller' (deactivate it in the same switch)"
    )
    assert cell.switch([VELOCITY_CONTROLLER], [], STRICT).message.endswith("cannot activate 'velocity_force_controller': it is already active")


def test_a_controller_executing_a_goal_refuses_to_deactivate(cell):
    cell.activate_trajectory_controller()
    watch = cell.send(ramp_goal(HOME, np.full(6, 0.2), 1.0))
    cell.run(0.1)
    response = cell.switch([VELOCITY_CONTROLLER], [TRAJECTORY_CONTROLLER], STRICT)
    assert not response.ok
    assert "cannot deactivate 'joint_trajectory_admittance_controller': it is executing goal" in response.message
    assert "cancel it first" in response.message
    # BEST_EFFORT cannot do it either: the velocity controller would conflict with the busy one.
    response = cell.switch([VELOCITY_CONTROLLER], [TRAJECTORY_CONTROLLER], BEST_EFFORT)
    assert response.ok and "it is executing goal" in response.message
    assert _states(cell)[TRAJECTORY_CONTROLLER] == "active" and _states(cell)[VELOCITY_CONTROLLER] == "inactive"
    cell.run(1.2)
    assert watch.status == STATUS_SUCCEEDED
    assert cell.switch([VELOCITY_CONTROLLER], [TRAJECTORY_CONTROLLER], STRICT).ok


def test_inactive_trajectory_controller_aborts_goals_with_a_reason(cell):
    watch = cell.send(ramp_goal(HOME, np.full(6, 0.1), 1.0))
    assert watch.done()
    assert watch.status == STATUS_ABORTED
    assert watch.result.error_code == Result.INVALID_GOAL
    assert watch.result.error_string == "controller joint_trajectory_admittance_controller is not active"


# ---------------------------------------------------------------------------------------------
# The admittance JTC
# ---------------------------------------------------------------------------------------------
def test_trajectory_is_followed_and_succeeds_holding_the_last_point(cell):
    cell.activate_trajectory_controller()
    delta = np.array([0.3, -0.2, 0.1, 0.0, 0.2, -0.4])
    feedback = []
    handle = cell.trajectory_client.send_goal_async(ramp_goal(HOME, delta, 1.0), feedback.append).result()
    watch = GoalWatch(handle)
    cell.run(0.5)
    np.testing.assert_allclose(cell.hw.q, HOME + 0.5 * delta, atol=0.01)
    cell.run(0.6)
    assert watch.status == STATUS_SUCCEEDED and watch.result.error_code == Result.SUCCESSFUL
    np.testing.assert_allclose(cell.hw.q, HOME + delta, atol=1e-6)
    assert 19 <= len(feedback) <= 22  # 20 Hz over the 1 s trajectory
    assert list(feedback[-1].joint_names) == list(ARM)
    cell.run(0.5)
    np.testing.assert_allclose(cell.hw.q, HOME + delta, atol=1e-6)


def test_joint_names_in_another_order_are_reordered(cell):
    cell.activate_trajectory_controller()
    order = [2, 0, 1, 5, 4, 3]
    target = HOME + np.array([0.1, 0.2, 0.3, 0.0, 0.0, 0.0])
    watch = cell.send(goal([0.0, 1.0], [HOME[order], target[order]], joint_names=[ARM[i] for i in order]))
    cell.run(1.2)
    assert watch.status == STATUS_SUCCEEDED
    np.testing.assert_allclose(cell.hw.q, target, atol=1e-6)


def test_wrong_joint_names_are_rejected_naming_them(cell):
    cell.activate_trajectory_controller()
    names = list(ARM[:5]) + ["gripper_joint"]
    watch = cell.send(goal([0.0, 1.0], [HOME, HOME], joint_names=names))
    assert watch.status == STATUS_ABORTED and watch.result.error_code == Result.INVALID_JOINTS
    assert "missing ['wrist_3_joint'], unknown ['gripper_joint']" in watch.result.error_string


def test_idle_goal_far_from_the_current_position_is_rejected(cell):
    cell.activate_trajectory_controller()
    start = HOME + np.array([0.0, 0.0, 0.2, 0.0, 0.0, 0.0])
    watch = cell.send(goal([0.0, 1.0], [start, start], path_tolerance=0.05))
    assert watch.status == STATUS_ABORTED and watch.result.error_code == Result.INVALID_GOAL
    assert watch.result.error_string.startswith(
        "position deviation at the seam on elbow_joint: 0.2000 rad exceeds the path tolerance 0.0500"
    )


def test_new_goal_is_stitched_at_the_seam_without_stopping(cell):
    cell.activate_trajectory_controller()
    first = cell.send(ramp_goal(HOME, np.full(6, 0.4), 2.0))
    cell.run(0.6)
    seam = 1.0
    state = cell.jtc.reference.sample(seam)
    times = np.linspace(0.0, 1.0, 11)
    positions = state.position + np.outer(times, state.velocity)  # keep going at the seam's velocity
    second = cell.send(goal(times, positions, np.tile(state.velocity, (11, 1)), stamp=seam, path_tolerance=0.01))
    assert not second.done()
    assert first.done() and first.status == STATUS_CANCELED
    assert first.result.error_code == Result.SUPERSEDED
    assert first.result.error_string == "superseded by a new goal taking over at t=1.0000 s"
    cell.run(0.6)
    q = np.array([entry[1] for entry in cell.hw.log])
    t = np.array([entry[0] for entry in cell.hw.log])
    around = (t > seam - 0.05) & (t < seam + 0.05)
    velocity = np.diff(q[around], axis=0) / DT
    assert np.min(np.abs(velocity[:, 0])) > 0.2  # never stopped at the seam
    assert np.max(np.abs(np.diff(velocity, axis=0))) < 0.05  # and no velocity jump
    cell.run(0.9)
    assert second.status == STATUS_SUCCEEDED
    np.testing.assert_allclose(cell.hw.q, positions[-1], atol=1e-6)


def test_idle_goal_starting_a_few_mrad_off_is_faded_in_within_the_blend_acceleration(cell):
    cell.activate_trajectory_controller()
    cell.run(0.1)
    start = HOME + np.array([0.0, 0.003, -0.003, 0.002, 0.0, 0.0])  # where a sagging arm is measured
    times = np.arange(21) * 0.01
    watch = cell.send(goal(times, np.tile(start, (21, 1)), np.zeros((21, 6)), path_tolerance=0.05))
    cell.run(0.5)
    assert watch.status == STATUS_SUCCEEDED
    commanded = np.array([entry[1] for entry in cell.hw.log])
    acceleration = np.diff(commanded, n=2, axis=0) / DT**2
    assert np.abs(acceleration).max() < 1.1  # seam_blend_acceleration, sampled at 2 ms
    np.testing.assert_allclose(cell.hw.q, start, atol=1e-9)


def test_late_seam_is_rejected_and_the_running_goal_continues(cell):
    cell.activate_trajectory_controller()
    first = cell.send(ramp_goal(HOME, np.full(6, 0.2), 1.0))
    cell.run(0.5)
    late = cell.send(goal([0.0, 0.5], [HOME + 0.2, HOME + 0.3], stamp=1.25))
    assert late.status == STATUS_ABORTED and late.result.error_code == Result.SEAM_AFTER_TRAJECTORY_END
    assert late.result.error_string == (
        "seam time exceeds the end of the current trajectory (seam t=1.2500 s, trajectory ends at t=1.0000 s)"
    )
    cell.run(0.6)
    assert first.status == STATUS_SUCCEEDED


def test_seam_in_the_past_is_an_old_header_timestamp(cell):
    cell.activate_trajectory_controller()
    cell.send(ramp_goal(HOME, np.full(6, 0.2), 1.0))
    cell.run(0.5)
    old = cell.send(goal([0.0, 0.5], [HOME, HOME + 0.3], stamp=0.3))
    assert old.result.error_code == Result.OLD_HEADER_TIMESTAMP
    assert old.result.error_string == "seam time t=0.3000 s is already past (now t=0.5000 s)"


def test_deviation_at_the_seam_is_rejected_through_the_action(cell):
    cell.activate_trajectory_controller()
    first = cell.send(ramp_goal(HOME, np.full(6, 0.4), 2.0))
    cell.run(0.5)
    state = cell.jtc.reference.sample(1.0)
    jumped = state.position + np.array([0.0, 0.0, 0.0, 0.0, 0.05, 0.0])
    watch = cell.send(goal([0.0, 1.0], [jumped, jumped + 0.1], [state.velocity, np.zeros(6)], stamp=1.0, path_tolerance=0.02))
    assert watch.result.error_code == Result.INVALID_GOAL
    assert watch.result.error_string.startswith("position deviation at the seam on wrist_2_joint: 0.0500 rad exceeds the path tolerance 0.0200")
    assert not first.done()


def test_tracking_error_beyond_the_path_tolerance_aborts(cell):
    cell.activate_trajectory_controller()
    cell.hw.stuck_joint = 1
    watch = cell.send(ramp_goal(HOME, np.full(6, 0.3), 1.0, path_tolerance=0.02))
    cell.run(1.0)
    assert watch.status == STATUS_ABORTED
    assert watch.result.error_code == Result.PATH_TOLERANCE_VIOLATED
    assert "on shoulder_lift_joint: error 0.02" in watch.result.error_string
    assert "exceeds the path tolerance 0.0200 rad" in watch.result.error_string
    assert not cell.jtc.executing


def test_force_torque_threshold_aborts_with_a_smooth_stop(cell):
    cell.activate_trajectory_controller()
    delta = np.array([0.6, 0.0, 0.0, 0.0, 0.0, 0.0])
    watch = cell.send(ramp_goal(HOME, delta, 2.0, thresholds=[45, 45, 45, 10, 10, 10]))
    cell.run(1.0)  # full speed: 0.56 rad/s on shoulder_pan_joint
    cell.hw.external_wrench = np.array([0.0, 0.0, -60.0, 0.0, 0.0, 0.0])
    abort_step = len(cell.hw.log)
    cell.run(0.01)
    assert watch.status == STATUS_ABORTED
    assert watch.result.error_code == Result.FORCE_TORQUE_THRESHOLD_EXCEEDED
    assert "Fz = -60.00 N, beyond the absolute threshold 45.00 N" in watch.result.error_string
    cell.hw.external_wrench = np.zeros(6)
    cell.run(0.5)
    pan = cell.commanded_velocity()[:, 0]
    assert pan[abort_step - 2] > 0.5
    after = pan[abort_step - 2 :]
    assert np.max(np.abs(np.diff(after))) < 0.05  # decelerates, no jump to a standstill
    assert np.all(np.abs(after[int(0.25 / DT) :]) < 1e-6)  # at rest within about 0.2 s
    travelled = cell.hw.q[0] - (HOME[0] + 0.5 * delta[0])
    assert 0.05 < travelled < 0.5 * 0.6  # kept moving a little while stopping, stopped short of the goal


def test_external_wrench_produces_a_compliant_offset_that_springs_back(cell):
    cell.activate_trajectory_controller()
    cell.run(0.1)
    push = np.array([21.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    cell.hw.external_wrench = push
    cell.run(1.0)
    params = AdmittanceParams()
    expected = (push[0] - params.deadband[0]) / params.stiffness[0]  # 1 cm
    assert cell.jtc.cartesian_offset[0] == pytest.approx(expected, rel=0.02)
    np.testing.assert_allclose(JACOBIAN @ (cell.hw.q - HOME), [expected, 0, 0, 0, 0, 0], atol=2e-4)
    cell.hw.external_wrench = np.zeros(6)
    cell.run(1.0)
    np.testing.assert_allclose(cell.hw.q, HOME, atol=1e-4)


def test_goal_stiffness_changes_the_compliance(cell):
    cell.activate_trajectory_controller()
    watch = cell.send(goal([0.0, 3.0], [HOME, HOME], stiffness=[500, 500, 500, 50, 50, 50]))
    cell.hw.external_wrench = np.array([0.0, 11.0, 0.0, 0.0, 0.0, 0.0])
    cell.run(1.5)
    assert cell.jtc.cartesian_offset[1] == pytest.approx(10.0 / 500, rel=0.02)
    assert not watch.done()  # yielding is not a tracking error


def test_cancel_stops_smoothly_and_reports_canceled(cell):
    cell.activate_trajectory_controller()
    watch = cell.send(ramp_goal(HOME, np.full(6, 0.6), 2.0))
    cell.run(1.0)
    cancel = watch.handle.cancel_goal_async()
    assert cancel.result() is True
    cancel_step = len(cell.hw.log)
    cell.run(0.5)
    assert watch.status == STATUS_CANCELED
    assert watch.result.error_code == Result.CANCELED
    velocity = cell.commanded_velocity()[cancel_step - 2 :, 3]
    assert velocity[0] > 0.5
    assert np.max(np.abs(np.diff(velocity))) < 0.05
    assert np.all(np.abs(velocity[int(0.25 / DT) :]) < 1e-6)
    assert cell.switch([VELOCITY_CONTROLLER], [TRAJECTORY_CONTROLLER]).ok  # no longer busy


def test_goal_tolerance_violated_when_the_arm_cannot_settle(cell):
    cell.activate_trajectory_controller()
    watch = cell.send(ramp_goal(HOME, np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.03]), 0.5, path_tolerance=0.05, goal_time_tolerance=0.2))
    cell.run(0.25)
    cell.hw.stuck_joint = 5  # stuck about half-way: within the path tolerance, short of the goal
    cell.run(0.5)
    assert watch.status == STATUS_ABORTED and watch.result.error_code == Result.GOAL_TOLERANCE_VIOLATED
    assert watch.result.error_string.startswith("goal not reached 0.200 s after the trajectory ended at t=0.500 s: wrist_3_joint: error 0.01")


def test_malformed_goals_are_rejected_with_reasons(cell):
    cell.activate_trajectory_controller()
    cases = [
        (goal([0.0, 1.0], [HOME, HOME + [math.nan, 0, 0, 0, 0, 0]]), "point 1 positions[0] (shoulder_pan_joint) is not finite: nan"),
        (goal([0.5, 0.5], [HOME, HOME]), "time_from_start must increase: point 1 at 0.5000 s follows point 0 at 0.5000 s"),
        (goal([0.0, 1.0], [HOME, HOME], thresholds=[45, 45, 45]), "absolute_force_torque_threshold needs 6 values (Fx Fy Fz Tx Ty Tz) or none, got 3"),
        (goal([0.0, 1.0], [HOME, HOME], stiffness=[0, 1, 1, 1, 1, 1]), "admittance axis x has zero stiffness and zero damping: the arm would drift without bound"),
        (goal([0.0], [HOME]), "the last point's time_from_start must be > 0"),
    ]
    for bad, message in cases:
        watch = cell.send(bad)
        assert watch.status == STATUS_ABORTED and watch.result.error_code == Result.INVALID_GOAL
        assert watch.result.error_string == message


def test_goal_points_are_read_in_arm_joint_order_and_the_first_bad_one_is_named():
    times, positions, velocities = [0.0, 0.5, 1.0], np.array([HOME, HOME + 0.1, HOME + 0.2]), np.arange(18.0).reshape(3, 6)
    given = parse_goal(goal(times, positions[:, ::-1], velocities[:, ::-1], stamp=3.0, joint_names=ARM[::-1]), ARM, 0.0, AdmittanceParams())
    np.testing.assert_array_equal(given.trajectory.times, [3.0, 3.5, 4.0])
    np.testing.assert_array_equal(given.trajectory.positions, positions)
    np.testing.assert_array_equal(given.trajectory.velocities, velocities)
    # point 1's velocity is checked before point 2's positions; point 0 has no flaw
    bad = goal(times, positions, velocities)
    bad.joint_trajectory.points[2].positions = HOME[:5].tolist()
    bad.joint_trajectory.points[1].velocities = [0.0, 0.0, math.inf, 0.0, 0.0, 0.0]
    with pytest.raises(GoalError, match=r"^point 1 velocities\[2\] \(elbow_joint\) is not finite: inf$"):
        parse_goal(bad, ARM, 0.0, AdmittanceParams())
    bad.joint_trajectory.points[1].velocities = velocities[1].tolist()
    with pytest.raises(GoalError, match=r"^point 2 has 5 positions, expected 6$"):
        parse_goal(bad, ARM, 0.0, AdmittanceParams())


# ---------------------------------------------------------------------------------------------
# Velocity controller
# ---------------------------------------------------------------------------------------------
def test_velocity_commands_move_the_arm_and_stop_when_they_cease(cell):
    publisher = cell.bus.create_publisher(VELOCITY_COMMAND_TOPIC, Float64MultiArray)
    for _ in range(25):  # 0.25 s of 0.4 rad/s on the elbow, a command every 10 ms
        publisher.publish(Float64MultiArray(data=[0.0, 0.0, 0.4, 0.0, 0.0, 0.0]))
        cell.run(0.01)
    assert cell.hw.q[2] == pytest.approx(HOME[2] + 0.1, abs=0.002)
    cell.run(0.5)  # silence: the last command (t=0.24 s) lapses after 0.1 s
    assert cell.hw.q[2] == pytest.approx(HOME[2] + 0.4 * 0.34, abs=0.002)
    assert np.all(cell.hw.qd == 0.0)
    velocity = cell.manager[VELOCITY_CONTROLLER]
    publisher.publish(Float64MultiArray(data=[0.1, 0.2]))
    assert velocity.last_error.endswith("expected 6 velocities (shoulder_pan_joint, shoulder_lift_joint, elbow_joint, wrist_1_joint, wrist_2_joint, wrist_3_joint), got 2")
    cell.activate_trajectory_controller()
    publisher.publish(Float64MultiArray(data=[0.4] * 6))
    cell.run(0.1)
    assert velocity.last_error == "controller velocity_force_controller is not active: velocity command ignored"
    assert cell.hw.q[2] == pytest.approx(HOME[2] + 0.4 * 0.34, abs=0.002)


# ---------------------------------------------------------------------------------------------
# Gripper
# ---------------------------------------------------------------------------------------------
def _gripper_goal(position: float, effort: float = 50.0) -> GripperCommand.Goal:
    g = GripperCommand.Goal()
    g.command.position, g.command.max_effort = position, effort
    return g


def test_gripper_reaches_its_goal(cell):
    handle = cell.gripper_client.send_goal_async(_gripper_goal(0.8)).result()
    result = handle.get_result_async()
    cell.run(0.3)
    assert not result.done()
    cell.run(0.3)
    outcome = result.result()
    assert outcome.status == STATUS_SUCCEEDED
    assert outcome.result.reached_goal and not outcome.result.stalled
    assert outcome.result.position == pytest.approx(0.8, abs=0.01)
    assert cell.hw.gripper_effort == 50.0


def test_gripper_closing_on_a_cube_reports_a_stall_and_keeps_squeezing(cell):
    cell.hw.finger_obstacle = 0.45
    handle = cell.gripper_client.send_goal_async(_gripper_goal(0.8, 0.0)).result()
    cell.run(0.6)
    outcome = handle.get_result_async().result()
    assert outcome.status == STATUS_SUCCEEDED
    assert outcome.result.stalled and not outcome.result.reached_goal
    assert outcome.result.position == pytest.approx(0.45)
    assert outcome.result.effort == 100.0  # max_effort 0 = the default force
    assert cell.hw.gripper_target == 0.8  # still squeezing: the cube stays held


def test_a_new_gripper_goal_preempts_the_running_one(cell):
    first = cell.gripper_client.send_goal_async(_gripper_goal(0.8)).result()
    cell.run(0.1)
    second = cell.gripper_client.send_goal_async(_gripper_goal(0.0)).result()
    assert first.get_result_async().result().status == STATUS_CANCELED
    cell.run(0.3)
    assert second.get_result_async().result().result.reached_goal
    assert cell.hw.gripper == pytest.approx(0.0)


def test_gripper_rejects_positions_outside_its_range(cell):
    handle = cell.gripper_client.send_goal_async(_gripper_goal(1.2)).result()
    assert not handle.accepted
    assert cell.manager["robotiq_gripper_controller"].last_rejection.endswith("position 1.2 is outside [0 (open), 0.8 (closed)]")


def test_reset_ends_goals_and_holds_the_new_state(cell):
    cell.activate_trajectory_controller()
    watch = cell.send(ramp_goal(HOME, np.full(6, 0.3), 1.0))
    cell.run(0.5)
    cell.hw.q = np.zeros(6)  # the world teleports the arm
    cell.manager.reset()
    assert watch.status == STATUS_ABORTED
    assert watch.result.error_string == "the simulation was reset at t=0.500 s"
    cell.run(0.2)
    np.testing.assert_allclose(cell.hw.q, np.zeros(6), atol=1e-9)


def test_seam_at_the_end_up_to_stamp_rounding_joins_the_last_points_velocity():
    # Stamps travel as integer nanoseconds: a seam "at the end" can land a nanosecond after it.
    # It must join the moving end state, not the hold that follows the trajectory.
    current = Trajectory(np.array([0.0, 1.0]), np.array([[0.0], [1.0]]), np.array([[1.0], [1.0]]), np.zeros((2, 1)))
    new = Trajectory(np.array([1.0 + 1e-9, 2.0]), np.array([[1.0], [2.0]]), np.array([[1.0], [1.0]]), np.zeros((2, 1)))
    stitched = stitch(current, new, 1.0 + 1e-9, path_tolerance=0.3)
    assert stitched.sample(1.0 + 1e-9).velocity[0] == pytest.approx(1.0)

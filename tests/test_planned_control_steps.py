"""A tick's control steps planned ahead (``ControllerManager.advance``) run exactly as step by
step ``update`` calls would: same physics bit for bit, same results, same feedback, including
ticks in which the admittance wakes up, a check ends the goal, or a cancel arrives."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from builtin_interfaces.msg import Duration
from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from runtime.io.bus import FixedLatency, InProcessBus
from runtime.io.clock import SimClock
from sim.cell_model import CellOptions
from sim.controllers import (
    TRAJECTORY_ACTION,
    TRAJECTORY_CONTROLLER,
    VELOCITY_CONTROLLER,
    ControllerManager,
    Trajectory,
    make_controllers,
)
from sim.controllers.admittance import JointTrajectoryAdmittanceController
from sim.mujoco_cell import MujocoCell
from sim.robot_model import ARM_JOINTS, load_waypoints

HOME = np.array([load_waypoints()["Home"][j] for j in ARM_JOINTS])
DT = 0.002
TICK_STEPS = 5
SETTLE_S = 1.8
"""Seconds under the hold before the goal: the switch's transient wakes the admittance, which
comes to rest (offsets below 1e-12) after about 1.5 s."""
Result = FollowJointTrajectoryWithAdmittance.Result


@dataclass(frozen=True)
class GoalSpec:
    """A smooth motion by ``offset`` over ``duration_s``, from Home or from where the arm is."""

    offset: np.ndarray
    duration_s: float
    path_tolerance: float
    thresholds: list[float]
    from_measured: bool = False

    def message(self, measured: np.ndarray):
        start = measured if self.from_measured else HOME
        trajectory = JointTrajectory(joint_names=list(ARM_JOINTS))
        points = 50
        for k in range(points + 1):
            s = k / points
            point = JointTrajectoryPoint(positions=(start + s * s * (3 - 2 * s) * self.offset).tolist())
            nanoseconds = int(round(self.duration_s * s * 1e9))
            point.time_from_start = Duration(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)
            trajectory.points.append(point)
        return FollowJointTrajectoryWithAdmittance.Goal(
            joint_trajectory=trajectory, path_tolerance=self.path_tolerance, absolute_force_torque_threshold=self.thresholds
        )


def trajectory_control() -> tuple[SimClock, InProcessBus, MujocoCell, ControllerManager]:
    """A fresh cell (seed 0, at Home) whose trajectory controller is active."""
    clock = SimClock()
    bus = InProcessBus(clock, default_latency=FixedLatency(0.0))
    cell = MujocoCell(CellOptions(image_width=32, image_height=32), HOME, seed=0)
    manager = make_controllers(bus, cell, clock)
    assert manager.switch([TRAJECTORY_CONTROLLER], [VELOCITY_CONTROLLER]).ok
    return clock, bus, cell, manager


def run(planned: bool, goal: GoalSpec, seconds: float, push: np.ndarray | None = None, push_at_s: float = 0.0,
        cancel_at_s: float | None = None) -> dict:
    """``goal`` on a fresh cell, ticked at 100 Hz: by ``advance`` (planned) or step by step."""
    clock, bus, cell, manager = trajectory_control()
    client = bus.create_action_client(TRAJECTORY_ACTION, FollowJointTrajectoryWithAdmittance)
    feedback: list[tuple] = []

    def tick() -> None:
        times, now = [], cell.t
        for _ in range(TICK_STEPS):
            times.append(now)
            now += DT
        if planned:
            manager.advance(times, DT, cell.step)
        else:
            for t in times:
                manager.update(t, DT)
                cell.step(DT)
        clock.advance(DT * TICK_STEPS)
        bus.spin_once()

    for _ in range(int(round(SETTLE_S / (DT * TICK_STEPS)))):
        tick()
    handle = client.send_goal_async(goal.message(cell.arm_position()), lambda f: feedback.append(
        (f.header.stamp.sec, f.header.stamp.nanosec, tuple(f.desired.positions), tuple(f.actual.velocities),
         f.wrench.force.z))).result()
    result = handle.get_result_async()
    start, states = cell.t, []
    while cell.t - start < seconds:
        elapsed = cell.t - start
        if push is not None and elapsed >= push_at_s:
            cell.external_wrench = push
        if cancel_at_s is not None and elapsed >= cancel_at_s and not result.done():
            handle.cancel_goal_async()
            cancel_at_s = None
        tick()
        states.append(np.concatenate([cell.data.qpos, cell.data.qvel]).copy())
    controller = manager[TRAJECTORY_CONTROLLER]
    cell.close()
    outcome = result.result().result if result.done() else None
    return {
        "states": np.array(states),
        "result": None if outcome is None else (outcome.error_code, outcome.error_string),
        "feedback": feedback,
        "peaks": (controller.peak_force_n, controller.peak_torque_nm),
    }


@pytest.fixture
def planned_steps(monkeypatch):
    """Counts control steps run the quick way, by their index in the tick, and the fallbacks."""
    counts = {"planned": [0] * TICK_STEPS, "fell_back": [0] * TICK_STEPS}
    original = JointTrajectoryAdmittanceController.planned_update

    def counting(self, plan, k):
        done = original(self, plan, k)
        counts["planned" if done else "fell_back"][k] += 1
        return done

    monkeypatch.setattr(JointTrajectoryAdmittanceController, "planned_update", counting)
    return counts


def assert_same(planned: dict, stepwise: dict) -> None:
    assert planned["result"] == stepwise["result"]
    assert planned["feedback"] == stepwise["feedback"]
    assert planned["peaks"] == stepwise["peaks"]
    assert planned["states"].shape == stepwise["states"].shape
    assert np.array_equal(planned["states"], stepwise["states"])  # bit for bit


OFFSET = np.array([0.1, -0.08, 0.1, 0.0, 0.0, 0.15])
"""A gentle motion over 2 s: its inertial wrench stays inside the admittance's deadband."""
LOOSE = [60.0] * 3 + [10.0] * 3


def test_a_motion_that_a_push_interrupts_mid_tick_runs_as_step_by_step(planned_steps):
    goal = GoalSpec(OFFSET, 2.0, 0.3, LOOSE)
    push = np.array([0.0, 0.0, -15.0, 0.0, 0.0, 0.0])  # inside the thresholds, outside the deadband
    planned = run(True, goal, 2.5, push, push_at_s=0.8)
    stepwise = run(False, goal, 2.5, push, push_at_s=0.8)
    assert_same(planned, stepwise)
    assert planned["result"] == (Result.SUCCESSFUL, "")
    assert sum(planned_steps["planned"]) > 100
    # The push lands in the physics of a tick's first step: the wrench leaves the deadband at its second.
    assert planned_steps["fell_back"][1] >= 1


def test_an_ft_abort_inside_the_deadband_and_its_stop_match(planned_steps):
    # A threshold under the deadband (1 N): the quick path's own F/T check must hand the step over.
    goal = GoalSpec(OFFSET, 2.0, 0.3, [0.5] * 3 + [10.0] * 3)
    push = np.array([0.0, 0.0, -0.8, 0.0, 0.0, 0.0])
    planned = run(True, goal, 1.0, push, push_at_s=0.5)
    stepwise = run(False, goal, 1.0, push, push_at_s=0.5)
    assert_same(planned, stepwise)
    assert planned["result"][0] == Result.FORCE_TORQUE_THRESHOLD_EXCEEDED
    assert "Fz" in planned["result"][1]
    assert sum(planned_steps["fell_back"][1:]) >= 1


def test_a_path_tolerance_abort_in_a_resting_stretch_matches(planned_steps):
    # The servos sag ~2.5 mrad under the gripper's weight, a little more as the arm moves: a
    # tolerance just above the sag is crossed 1.8 s into the motion, with the admittance at rest.
    goal = GoalSpec(OFFSET, 2.0, 0.00255, LOOSE, from_measured=True)
    planned = run(True, goal, 2.5)
    stepwise = run(False, goal, 2.5)
    assert_same(planned, stepwise)
    assert planned["result"][0] == Result.PATH_TOLERANCE_VIOLATED
    assert "elbow_joint" in planned["result"][1]
    assert sum(planned_steps["fell_back"]) >= 1


def test_a_cancel_and_the_goal_end_match():
    goal = GoalSpec(OFFSET, 2.0, 0.3, LOOSE)
    planned = run(True, goal, 1.0, cancel_at_s=0.5)
    stepwise = run(False, goal, 1.0, cancel_at_s=0.5)
    assert_same(planned, stepwise)
    assert planned["result"][0] == Result.CANCELED


def test_sampling_a_tick_at_once_equals_sampling_each_step():
    rng = np.random.default_rng(7)
    for _ in range(300):
        n = int(rng.integers(1, 12))
        knots = np.cumsum(rng.uniform(0.005, 0.05, size=n))
        trajectory = Trajectory.from_points(knots, rng.normal(size=(n, 6)))
        start = float(knots[0] - 0.02 + rng.uniform(0.0, knots[-1] - knots[0] + 0.04))
        times = [start + k * DT for k in range(TICK_STEPS)]
        if rng.uniform() < 0.3:  # exactly on a knot (the last one: the end's own state)
            knot = float(knots[int(rng.integers(0, n))])
            times = [knot - 2 * DT, knot - DT, knot, knot + DT, knot + 2 * DT]
        positions, velocities = trajectory.sample_many(times)
        for k, t in enumerate(times):
            state = trajectory.sample(t)
            assert np.array_equal(positions[k], state.position) and np.array_equal(velocities[k], state.velocity)


def test_a_tick_without_control_steps_does_nothing():
    # Real time: the clock may move less than a control period between two ticks.
    _, _, cell, manager = trajectory_control()
    before = cell.data.qpos.copy()
    manager.advance([], DT, cell.step)
    assert cell.t == 0.0 and np.array_equal(cell.data.qpos, before)
    positions, velocities = manager[TRAJECTORY_CONTROLLER].reference.sample_many([])
    assert positions.shape == velocities.shape == (0, 6)
    cell.close()

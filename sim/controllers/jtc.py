"""``joint_trajectory_controller``: ros2_controllers' stock JTC, as the simulated cell runs it.

Serves ``/joint_trajectory_controller/follow_joint_trajectory``
(``control_msgs/action/FollowJointTrajectory``) and subscribes to
``/joint_trajectory_controller/joint_trajectory`` (``trajectory_msgs/JointTrajectory``). What it
does is what ros2_controllers' JTC does with the cell's parameters (``JtcParams``; its sources:
``joint_trajectory_controller.cpp``, ``trajectory.cpp``, ``tolerances.hpp``):

- **Goal validation** (a rejected goal gets no result, only a reason in the log, as from JTC):
  the controller must be active; joint names must be exactly the controller's joints (partial
  goals are off); at least one point; the last point's velocities zero; a goal with a non-zero
  stamp must not end in the past; ``time_from_start`` strictly increasing; every given field
  has one value per joint; no efforts. Non-finite values are refused too (JTC does not check,
  the simulator must not take them).
- **Interpolation** linear, cubic or quintic from the fields present (``jtc_trajectory``), from
  the measured state when a trajectory arrives (the state last commanded with
  ``interpolate_from_desired_state``).
- **A new trajectory while one plays**: merged at its arrival with ``allow_trajectory_replacement``
  (the default, ros2_controllers #2419), else it replaces the old one from its stamp. A new goal
  preempts the active one: that goal is aborted with INVALID_GOAL, "Current goal preempted by
  new incoming action." (its result delivered, #2422).
- **Tolerances** per goal (``path_tolerance``, ``goal_tolerance`` per joint, ``goal_time_tolerance``;
  0 keeps the default, -1 erases it) over the defaults (no path tolerance, no goal position
  tolerance, ``stopped_velocity_tolerance`` 0.01 rad/s, goal time 0 = wait as long as it takes).
  Before the last point's time a joint off its path (desired - actual beyond its position or
  velocity tolerance) aborts with PATH_TOLERANCE_VIOLATED; after it, the goal succeeds once every
  joint is within its goal tolerance, or aborts with GOAL_TOLERANCE_VIOLATED after the goal time.
- **Cancel, abort, deactivation**: the arm comes to rest smoothly (``stop_trajectory``), as JTC
  with ``constraints.decelerate_on_cancel`` does.

Feedback (desired, actual, error) goes out at ``action_monitor_rate`` (20 Hz). The controller's
state (``control_msgs/msg/JointTrajectoryControllerState`` on ``~/controller_state``: the
reference it commands, the measured feedback, their error) is published as JTC publishes it,
produced when read (in process) or at ``STATE_RATE_HZ`` while it has subscribers (over ROS 2). The trajectory is
sampled at the control step's own time (JTC commands the sample one control period ahead, for the
hardware's next write; the simulated hardware applies a command at once).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTrajectoryControllerState
from trajectory_msgs.msg import JointTrajectory

from runtime.io.bus import Bus, ServerGoalHandle
from runtime.io.clock import Clock
from runtime.io.timestamps import time_msg, to_seconds

from ..hardware import Hardware
from .base import ArmController, ControllersConfig, JtcParams
from .jtc_trajectory import JtcPoints, JtcTrajectory, merge_at_arrival, replace_at_arrival
from .trajectory import TIME_EPS, TrajectoryState, stop_trajectory

STATE_RATE_HZ = 50.0
"""Hz of ``~/controller_state`` over ROS 2 (the rate of ros2_controllers' JTC
``state_publish_rate`` default)."""

Result = FollowJointTrajectory.Result
FLOAT_EPSILON = float(np.finfo(np.float32).eps)
"""JTC's "zero" for a last point's velocity (``std::numeric_limits<float>::epsilon()``)."""
ERASE_TOLERANCE = -1.0
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Tolerances:
    """Per-joint (position, velocity) tolerances along the path and at the goal; 0 = not checked."""

    path_position: np.ndarray
    path_velocity: np.ndarray
    goal_position: np.ndarray
    goal_velocity: np.ndarray
    goal_time_s: float

    @classmethod
    def defaults(cls, joints: int, params: JtcParams) -> Tolerances:
        zeros = np.zeros(joints)
        return cls(zeros, zeros, zeros, np.full(joints, params.stopped_velocity_tolerance), params.goal_time)


def resolve_tolerance(default: float, requested: float) -> float:
    """A goal's tolerance over the default: > 0 replaces it, -1 erases it (0, not checked), 0 keeps
    it; other negative values are illegal (ValueError)."""
    if requested > 0.0:
        return requested
    if abs(requested - ERASE_TOLERANCE) < FLOAT_EPSILON:
        return 0.0
    if requested < 0.0:
        raise ValueError(f"illegal tolerance {requested}")
    return default


def goal_tolerances(goal, joints: tuple[str, ...], default: Tolerances) -> Tolerances:
    """The tolerances of ``goal`` over ``default``. As JTC: a tolerance naming an unknown joint or
    holding an illegal value makes the whole goal run with the defaults (logged)."""
    try:
        goal_time = resolve_tolerance(default.goal_time_s, to_seconds(goal.goal_time_tolerance))
        columns = {name: getattr(default, name).copy() for name in ("path_position", "path_velocity", "goal_position", "goal_velocity")}
        for prefix, entries in (("path", goal.path_tolerance), ("goal", goal.goal_tolerance)):
            for entry in entries:
                if entry.name not in joints:
                    raise ValueError(f"joint '{entry.name}' in {prefix}_tolerance is not a controller joint")
                j = joints.index(entry.name)
                for kind in ("position", "velocity"):
                    column = columns[f"{prefix}_{kind}"]
                    column[j] = resolve_tolerance(column[j], getattr(entry, kind))
    except ValueError as err:
        log.warning("goal tolerances: %s; using the default tolerances", err)
        return default
    return Tolerances(**columns, goal_time_s=goal_time)


def first_violation(error: np.ndarray, tolerance: np.ndarray) -> int | None:
    """Index of the first joint whose |error| exceeds its tolerance (> 0), or None."""
    bad = (tolerance > 0.0) & (np.abs(error) > tolerance)
    return int(np.argmax(bad)) if bad.any() else None


def validate_trajectory(msg: JointTrajectory, joints: tuple[str, ...], now_s: float) -> str | None:
    """Why JTC would refuse ``msg`` (None: it accepts it). The checks run in JTC's order."""
    names = list(msg.joint_names)
    if len(names) != len(joints):
        return f"joints on incoming trajectory {names} don't match the controller joints {list(joints)}"
    if not msg.points:
        return "empty trajectory received"
    for name in names:
        if name not in joints:
            return f"incoming joint {name} doesn't match the controller's joints"
    last = msg.points[-1]
    for name, velocity in zip(names, last.velocities):
        if abs(velocity) > FLOAT_EPSILON:
            return f"velocity of last trajectory point of joint {name} is not zero: {velocity:.15f}"
    stamp = to_seconds(msg.header.stamp)
    if stamp != 0.0:
        end = stamp + to_seconds(last.time_from_start)
        if end < now_s:
            return f"received trajectory with non-zero start time ({stamp:.6f}) that ends in the past ({end:.6f})"
    previous = None
    for k, point in enumerate(msg.points):
        t = to_seconds(point.time_from_start)
        if previous is not None and t <= previous:
            return f"time between points {k - 1} and {k} is not strictly increasing, it is {previous:.6f} and {t:.6f} respectively"
        previous = t
        for field_name, may_be_empty in (("positions", False), ("velocities", True), ("accelerations", True)):
            values = getattr(point, field_name)
            if may_be_empty and len(values) == 0:
                continue
            if len(values) != len(names):
                return f"mismatch between joint_names size ({len(names)}) and {field_name} ({len(values)}) at point #{k}"
            if not all(math.isfinite(v) for v in values):
                return f"point #{k} has a non-finite value in {field_name}"
        if len(point.effort) > 0:
            return "trajectories with effort fields are only supported for controllers using the 'effort' command interface"
    return None


def read_points(msg: JointTrajectory, joints: tuple[str, ...]) -> JtcPoints:
    """A validated message's points, times from its start, columns in the controller's joint order."""
    order = [list(msg.joint_names).index(j) for j in joints]
    points = list(msg.points)
    times = np.array([to_seconds(p.time_from_start) for p in points])

    def column(field_name: str) -> tuple[np.ndarray, np.ndarray]:
        given = np.array([len(getattr(p, field_name)) > 0 for p in points])
        rows = [np.asarray(getattr(p, field_name), dtype=float)[order] if g else np.zeros(len(joints)) for p, g in zip(points, given)]
        return np.array(rows), given

    positions, _ = column("positions")
    velocities, has_velocity = column("velocities")
    accelerations, has_acceleration = column("accelerations")
    return JtcPoints(times, positions, velocities, accelerations, has_velocity, has_acceleration)


class JointTrajectoryController(ArmController):
    type_name = "joint_trajectory_controller/JointTrajectoryController"

    def __init__(self, name: str, bus: Bus, hardware: Hardware, clock: Clock, config: ControllersConfig) -> None:
        super().__init__(name, hardware, clock, config)
        self.params: JtcParams = config.joint_trajectory
        self.action_name = f"/{name}/follow_joint_trajectory"
        self.topic = f"/{name}/joint_trajectory"
        self.joint_names = tuple(hardware.arm_joint_names)
        self._defaults = Tolerances.defaults(len(self.joint_names), self.params)
        self._tolerances = self._defaults
        self._trajectory = JtcTrajectory.hold(clock.now(), hardware.arm_position())
        self._holding = True  # JTC's rt_is_holding_: a hold or a stop, no tolerance checks
        self._goal: ServerGoalHandle | None = None
        self._last_feedback = -math.inf
        self.last_rejection = ""
        """Why the last goal or topic message was refused ("" if none was)."""
        self.peak_force_n = 0.0
        """Largest |force| (N, vector norm) at the wrist sensor while playing a trajectory (the
        cell's measurement for the run summary; a JTC reads no wrench)."""
        self.peak_torque_nm = 0.0
        bus.create_action_server(self.action_name, FollowJointTrajectory, self._on_goal, self._on_cancel)
        bus.create_subscription(self.topic, JointTrajectory, self._on_topic)
        self.state_topic = f"/{name}/controller_state"
        bus.create_lazy_publisher(self.state_topic, JointTrajectoryControllerState, self.controller_state, rate_hz=STATE_RATE_HZ)

    def controller_state(self) -> JointTrajectoryControllerState:
        """``~/controller_state`` now: the reference commanded, the measured feedback, the error."""
        now = self.clock.now()
        reference, feedback = self._trajectory.sample(now), self._measured_state()
        msg = JointTrajectoryControllerState()
        msg.header.stamp = time_msg(now)
        msg.joint_names = list(self.joint_names)
        msg.reference.positions, msg.reference.velocities = reference.position.tolist(), reference.velocity.tolist()
        msg.reference.accelerations = reference.acceleration.tolist()
        msg.feedback.positions, msg.feedback.velocities = feedback.position.tolist(), feedback.velocity.tolist()
        msg.error.positions = (reference.position - feedback.position).tolist()
        msg.error.velocities = (reference.velocity - feedback.velocity).tolist()
        msg.speed_scaling_factor = 1.0
        return msg

    # -- ros2_control lifecycle ---
    def busy_reason(self) -> str | None:
        if self._goal is not None:
            return f"it is executing goal {self._goal.goal_id[:8]} (cancel it first)"
        return None

    def on_activate(self, t: float) -> None:
        self._trajectory = JtcTrajectory.hold(t, self.hardware.arm_position())
        self._holding = True
        self.hardware.command_arm(self._trajectory.points.positions[0], np.zeros(len(self.joint_names)))

    def on_reset(self, t: float) -> None:
        self._end_goal("abort", Result(error_code=Result.INVALID_GOAL, error_string=f"the simulation was reset at t={t:.3f} s"))
        self.on_activate(t)

    def on_deactivate(self, t: float) -> None:
        self._end_goal("abort", Result(error_code=Result.INVALID_GOAL, error_string="Aborted due to controller deactivation"))
        self._stop(t)

    # -- introspection (tests) ---
    @property
    def trajectory(self) -> JtcTrajectory:
        return self._trajectory

    @property
    def executing(self) -> bool:
        return self._goal is not None

    # -- inputs (called by the bus between control steps) ---
    def _on_goal(self, handle: ServerGoalHandle) -> bool:
        now = self.clock.now()
        if not self.active:
            return self._refuse(f"can't accept new action goals: controller {self.name} is not running")
        problem = validate_trajectory(handle.request.trajectory, self.joint_names, now)
        if problem is not None:
            return self._refuse(problem)
        self._end_goal("abort", Result(error_code=Result.INVALID_GOAL, error_string="Current goal preempted by new incoming action."))
        self._install(handle.request.trajectory, now)
        self._goal = handle
        self._tolerances = goal_tolerances(handle.request, self.joint_names, self._defaults)
        return True

    def _on_topic(self, msg: JointTrajectory) -> None:
        now = self.clock.now()
        if not self.active:
            return
        problem = validate_trajectory(msg, self.joint_names, now)
        if problem is not None:
            self._refuse(problem)
            return
        self._install(msg, now)

    def _on_cancel(self, handle: ServerGoalHandle) -> bool:
        if self._goal is handle:
            self._end_goal("canceled", Result())
            self._stop(self.clock.now())
        return True

    def _refuse(self, reason: str) -> bool:
        self.last_rejection = reason
        log.error("%s: %s", self.name, reason)
        return False

    def _install(self, msg: JointTrajectory, now: float) -> None:
        points = read_points(msg, self.joint_names)
        stamp = to_seconds(msg.header.stamp)
        before = self._trajectory.sample(now) if self.params.interpolate_from_desired_state else self._measured_state()
        if self.params.allow_trajectory_replacement and not self._holding and len(self._trajectory.points) > 1:
            self._trajectory = merge_at_arrival(self._trajectory, points, stamp, now, before)
        else:
            self._trajectory = replace_at_arrival(points, stamp, now, before)
        self._holding = False

    # -- control loop ---
    def update(self, t: float, dt: float) -> None:
        desired = self._trajectory.sample(t)
        if not self._holding:
            self._supervise(t, desired)
            if self._holding:
                desired = self._trajectory.sample(t)
        self.hardware.command_arm(desired.position, desired.velocity)

    def _supervise(self, t: float, desired: TrajectoryState) -> None:
        fx, fy, fz, tx, ty, tz = np.asarray(self.hardware.wrench(), dtype=float).tolist()
        self.peak_force_n = max(self.peak_force_n, math.hypot(fx, fy, fz))
        self.peak_torque_nm = max(self.peak_torque_nm, math.hypot(tx, ty, tz))
        actual = self._measured_state()
        position_error = desired.position - actual.position
        velocity_error = desired.velocity - actual.velocity
        tol = self._tolerances
        before_last_point = t < self._trajectory.end_time
        if self._goal is not None:
            self._publish_feedback(t, desired, actual)
        if before_last_point:
            j = first_violation(position_error, tol.path_position)
            if j is None:
                j = first_violation(velocity_error, tol.path_velocity)
            if j is not None:
                log.warning("%s: path tolerance violated on %s at t=%.3f s", self.name, self.joint_names[j], t)
                self._end_goal("abort", Result(error_code=Result.PATH_TOLERANCE_VIOLATED, error_string="Aborted due to path tolerance violation"))
                self._stop(t)
            return
        outside = first_violation(position_error, tol.goal_position)
        if outside is None:
            outside = first_violation(velocity_error, tol.goal_velocity)
        if outside is None:
            self._end_goal("succeed", Result(error_code=Result.SUCCESSFUL, error_string="Goal successfully reached!"))
            self._trajectory = JtcTrajectory.hold(t, self._trajectory.points.positions[-1])
            self._holding = True
            return
        late_s = t - self._trajectory.end_time
        if tol.goal_time_s != 0.0 and late_s > tol.goal_time_s + TIME_EPS:
            self._end_goal("abort", Result(error_code=Result.GOAL_TOLERANCE_VIOLATED,
                                           error_string=f"Aborted due to goal_time_tolerance exceeding by {late_s:.6f} seconds"))
            self._stop(t)

    def _stop(self, t: float) -> None:
        """Decelerate to rest from the commanded state, then hold."""
        if not self.active:
            return
        stop = stop_trajectory(self._trajectory.sample(t), t, self.config.stop_time)
        points = JtcPoints.build(stop.times, stop.positions, stop.velocities, stop.accelerations)
        self._trajectory = JtcTrajectory(points, t, points.state(0))
        self._holding = True

    def _end_goal(self, how: str, result) -> None:
        goal, self._goal = self._goal, None
        if goal is None or not goal.is_active:
            return
        {"succeed": goal.succeed, "abort": goal.abort, "canceled": goal.canceled}[how](result)

    def _measured_state(self) -> TrajectoryState:
        """The state JTC reads from its state interfaces: positions and velocities (no accelerations)."""
        q = np.asarray(self.hardware.arm_position(), dtype=float)
        return TrajectoryState(q, np.asarray(self.hardware.arm_velocity(), dtype=float), np.zeros_like(q))

    def _publish_feedback(self, t: float, desired: TrajectoryState, actual: TrajectoryState) -> None:
        if t - self._last_feedback < 1.0 / self.config.feedback_rate - TIME_EPS:
            return
        self._last_feedback = t
        assert self._goal is not None
        feedback = FollowJointTrajectory.Feedback()
        feedback.header.stamp = time_msg(t)
        feedback.joint_names = list(self.joint_names)
        for point, state in ((feedback.desired, desired), (feedback.actual, actual)):
            point.positions, point.velocities = state.position.tolist(), state.velocity.tolist()
        feedback.error.positions = (desired.position - actual.position).tolist()
        feedback.error.velocities = (desired.velocity - actual.velocity).tolist()
        self._goal.publish_feedback(feedback)

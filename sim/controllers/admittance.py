"""``joint_trajectory_admittance_controller``: follows joint trajectories, stitched at seams, compliant.

Serves ``/joint_trajectory_admittance_controller/follow_joint_trajectory``
(``moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance``), the action
ExecutePolicy streams its chunks to.

How a goal is handled (times on the runtime clock; ``now`` is when the goal arrives):

- The seam is the goal's ``header.stamp`` (zero stamp = now); each point's ``time_from_start``
  counts from it.
- While a goal is executing, the new trajectory takes over at the seam without stopping: the seam
  must not lie after the end of the current trajectory ("seam time exceeds the end of the current
  trajectory") nor in the past (OLD_HEADER_TIMESTAMP); when the new trajectory has a point at the
  seam, its position and velocity (when the goal gives velocities) must match the current
  trajectory's there within the goal's ``path_tolerance``. The superseded goal ends CANCELED with error_code SUPERSEDED.
- While idle the controller holds its last reference, and a goal starts at its seam (now, or
  later) from there; a first point at the seam must match the held position within
  ``path_tolerance``. A late goal whose seam lies after the end of the last trajectory and is
  already past gets the same "seam time exceeds..." message as while executing.
- Rejections are delivered as accept-and-abort with an error_code and error_string, because a
  rejected ROS goal carries no reason.

While executing, every control step checks, in this order:
1. F/T: any |wrench axis| above the goal's absolute threshold aborts with
   FORCE_TORQUE_THRESHOLD_EXCEEDED naming the axis, its value and the threshold.
2. Path: any joint farther than ``path_tolerance`` from the reference aborts with
   PATH_TOLERANCE_VIOLATED. The reference is the trajectory plus the admittance offset, i.e.
   exactly what is commanded: yielding to a push is intended motion, not a tracking error.
3. End: after the last point's time the arm must settle within the goal tolerance
   (``ControllersConfig.goal_position_tolerance``, or ``path_tolerance`` when tighter) before
   ``goal_time_tolerance`` elapses (0 = ``ControllersConfig.default_goal_time_tolerance``), else
   GOAL_TOLERANCE_VIOLATED; then SUCCESSFUL, holding the last point.
Every abort and a cancel bring the arm to rest smoothly (``stop_trajectory``: zero velocity within
``ControllersConfig.stop_time``, position/velocity/acceleration continuous), never a jump.

The controller keeps the largest force and torque (vector norms) it read while executing a goal
(``peak_force_n``, ``peak_torque_nm``; the world reports them in its run summary).

Admittance (see ``compliance``) runs on every control step while the controller is active, with
the stiffness/damping of the latest accepted goal (empty = the configured defaults).

The quick path (``plan_steps``/``planned_update``, which the controller manager uses for a
tick's control steps): most steps nothing reacts (the admittance rests under a wrench inside its
deadband, no check fires), so a step's command is the reference alone and the tick's references
are sampled in one pass. A planned step does exactly what ``update`` would do; the first step at
which anything would react (the wrench leaves the deadband, a check would end the goal, a cancel,
a new goal) is left to ``update``, and so is the rest of that tick.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance

from runtime.io.timestamps import time_msg, to_seconds
from runtime.io.bus import Bus, ServerGoalHandle
from runtime.io.clock import Clock
from runtime.errors import ObjectiveError

from ..hardware import Hardware
from .base import FT_STATE_INTERFACES, Controller, ControllersConfig, arm_command_interfaces, arm_state_interfaces
from .compliance import AdmittanceParams, AdmittanceState, admittance_step, damped_pseudo_inverse, inside_deadband
from .trajectory import (
    TIME_EPS,
    SeamError,
    Trajectory,
    TrajectoryState,
    path_violation,
    stitch,
    stop_trajectory,
    within_path_tolerance,
    within_thresholds,
    wrench_violation,
)

Action = FollowJointTrajectoryWithAdmittance
Result = FollowJointTrajectoryWithAdmittance.Result


class GoalError(ObjectiveError, ValueError):
    """A goal that cannot be executed, with the error_code to report."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class ParsedGoal:
    """A validated goal, in the hardware's joint order and on absolute clock time."""

    seam_time: float
    zero_stamp: bool
    trajectory: Trajectory
    velocities_given: bool
    path_tolerance: float
    goal_time_tolerance: float
    force_torque_threshold: np.ndarray | None
    admittance: AdmittanceParams


def _finite_nonnegative(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value) or value < 0:
        raise GoalError(Result.INVALID_GOAL, f"{name} must be finite and >= 0, got {value}")
    return value


def parse_goal(goal, arm_joints: tuple[str, ...], now: float, admittance: AdmittanceParams) -> ParsedGoal:
    """Validate a FollowJointTrajectoryWithAdmittance goal; raise GoalError naming the problem."""
    trajectory = goal.joint_trajectory
    path_tolerance = _finite_nonnegative("path_tolerance", goal.path_tolerance)
    goal_time_tolerance = _finite_nonnegative("goal_time_tolerance", goal.goal_time_tolerance)

    names = list(trajectory.joint_names)
    duplicates = sorted({n for n in names if names.count(n) > 1})
    missing = [j for j in arm_joints if j not in names]
    unknown = [n for n in names if n not in arm_joints]
    if duplicates or missing or unknown:
        parts = [f"{label} {values}" for label, values in (("missing", missing), ("unknown", unknown), ("duplicated", duplicates)) if values]
        raise GoalError(
            Result.INVALID_JOINTS,
            f"joint names {names} must be exactly the arm joints {list(arm_joints)} (any order): " + ", ".join(parts),
        )
    order = [names.index(j) for j in arm_joints]

    points = list(trajectory.points)
    if not points:
        raise GoalError(Result.INVALID_GOAL, "the trajectory has no points")
    fields = ["positions"]
    for field_name in ("velocities", "accelerations"):
        given = [len(getattr(p, field_name)) > 0 for p in points]
        if any(given) and not all(given):
            k = given.index(not given[0])
            raise GoalError(Result.INVALID_GOAL, f"{field_name} must be given for every point or for none (point {k} differs from point 0)")
        if given[0]:
            fields.append(field_name)
    columns: dict[str, np.ndarray | None] = {"velocities": None, "accelerations": None}
    columns.update(_point_columns(points, fields, names, order))
    positions = columns.pop("positions")
    assert positions is not None  # _point_columns always has them
    times = np.array([float(p.time_from_start.sec) + float(p.time_from_start.nanosec) * 1e-9 for p in points])
    if times[0] < 0:
        raise GoalError(Result.INVALID_GOAL, f"point 0 has a negative time_from_start ({times[0]:.4f} s)")
    not_increasing = np.flatnonzero(np.diff(times) <= 0)
    if not_increasing.size:
        k = int(not_increasing[0]) + 1
        raise GoalError(
            Result.INVALID_GOAL,
            f"time_from_start must increase: point {k} at {times[k]:.4f} s follows point {k - 1} at {times[k - 1]:.4f} s",
        )
    if times[-1] <= 0:
        raise GoalError(Result.INVALID_GOAL, "the last point's time_from_start must be > 0")

    thresholds = None
    if len(goal.absolute_force_torque_threshold) > 0:
        thresholds = np.asarray(goal.absolute_force_torque_threshold, dtype=float)
        if thresholds.size != 6:
            raise GoalError(Result.INVALID_GOAL, f"absolute_force_torque_threshold needs 6 values (Fx Fy Fz Tx Ty Tz) or none, got {thresholds.size}")
        for i, value in enumerate(thresholds):
            if math.isnan(value) or value <= 0:
                raise GoalError(Result.INVALID_GOAL, f"absolute_force_torque_threshold[{i}] must be > 0, got {value}")
    try:
        params = admittance.with_goal(goal.admittance_stiffness, goal.admittance_damping)
    except ValueError as exc:
        raise GoalError(Result.INVALID_GOAL, str(exc)) from None

    stamp = to_seconds(trajectory.header.stamp)
    zero_stamp = stamp == 0.0
    seam = now if zero_stamp else stamp
    return ParsedGoal(
        seam_time=seam,
        zero_stamp=zero_stamp,
        trajectory=Trajectory.from_points(seam + times, positions, columns["velocities"], columns["accelerations"]),
        velocities_given=columns["velocities"] is not None,
        path_tolerance=path_tolerance,
        goal_time_tolerance=goal_time_tolerance,
        force_torque_threshold=thresholds,
        admittance=params,
    )


def _point_columns(points: list, fields: list[str], names: list[str], order: list[int]) -> dict[str, np.ndarray]:
    """Each of ``fields`` of every point as a (points, joints) array in arm-joint order.

    A goal has hundreds of points, so a well-formed one is read in one pass per field; otherwise
    point by point, and GoalError names the first point (then field) with a wrong count or a
    value that is not finite.
    """
    rows = {f: [getattr(p, f) for p in points] for f in fields}
    if all(len(r) == len(order) for f in fields for r in rows[f]):
        arrays = {f: np.array(rows[f], dtype=float) for f in fields}
        if all(np.isfinite(a).all() for a in arrays.values()):
            return {f: a[:, order] for f, a in arrays.items()}
    columns = {f: np.empty((len(points), len(order))) for f in fields}
    for k in range(len(points)):
        for f in fields:
            values = np.asarray(rows[f][k], dtype=float)
            if values.size != len(order):
                raise GoalError(Result.INVALID_GOAL, f"point {k} has {values.size} {f}, expected {len(order)}")
            if not np.all(np.isfinite(values)):
                j = int(np.argmax(~np.isfinite(values)))
                raise GoalError(Result.INVALID_GOAL, f"point {k} {f}[{j}] ({names[j]}) is not finite: {values[j]}")
            columns[f][k] = values[order]
    return columns


@dataclass
class _ActiveGoal:
    handle: ServerGoalHandle
    goal: ParsedGoal
    cancel_requested: bool = False


@dataclass(frozen=True)
class StepPlan:
    """A tick's control steps planned ahead: the reference at each of ``times`` (rows of
    ``positions``/``velocities``), and the state the plan assumes (the same goal, reference and
    resting admittance), with the limits the quick path checks, read once."""

    times: list[float]
    goal: _ActiveGoal | None
    reference: Trajectory
    compliance: AdmittanceState
    positions: np.ndarray
    velocities: np.ndarray
    position_rows: list[list[float]]
    deadband: list[float]
    thresholds: list[float] | None
    path_tolerance: float


class JointTrajectoryAdmittanceController(Controller):
    type_name = "moveit_pro_controllers/JointTrajectoryAdmittanceController"

    def __init__(self, name: str, bus: Bus, hardware: Hardware, clock: Clock, config: ControllersConfig) -> None:
        super().__init__(name, hardware, clock, config)
        self.action_name = f"/{name}/follow_joint_trajectory"
        self.joint_names = tuple(hardware.arm_joint_names)
        self._reference = Trajectory.hold(clock.now(), hardware.arm_position())
        self._goal: _ActiveGoal | None = None
        self._params = config.admittance
        self._compliance = AdmittanceState()
        self._no_offset = np.zeros(len(self.joint_names))
        self._joint_offset = self._no_offset
        self._pseudo_inverse: np.ndarray | None = None
        self._pseudo_inverse_time = -math.inf
        self._last_feedback = -math.inf
        self.peak_force_n = 0.0
        """Largest |force| (N, vector norm) read from the wrist sensor while executing a goal."""
        self.peak_torque_nm = 0.0
        """Largest |torque| (N m, vector norm) read from the wrist sensor while executing a goal."""
        bus.create_action_server(self.action_name, Action, self._on_goal, self._on_cancel)

    # -- ros2_control lifecycle ---
    @property
    def command_interfaces(self) -> tuple[str, ...]:
        return arm_command_interfaces(self.hardware)

    @property
    def state_interfaces(self) -> tuple[str, ...]:
        return arm_state_interfaces(self.hardware) + FT_STATE_INTERFACES

    def busy_reason(self) -> str | None:
        if self._goal is not None:
            return f"it is executing goal {self._goal.handle.goal_id[:8]} (cancel it first)"
        return None

    def on_activate(self, t: float) -> None:
        self._reference = Trajectory.hold(t, self.hardware.arm_position())
        self._params = self.config.admittance
        self._compliance = AdmittanceState()
        self._joint_offset = self._no_offset
        self._pseudo_inverse = None
        self.hardware.command_arm(self._reference.positions[0], np.zeros(len(self.joint_names)))

    def on_reset(self, t: float) -> None:
        goal, self._goal = self._goal, None
        if goal is not None and goal.handle.is_active:
            goal.handle.abort(Result(error_code=Result.INVALID_GOAL, error_string=f"the simulation was reset at t={t:.3f} s"))
        self.on_activate(t)

    # -- introspection (tests, events) ---
    @property
    def executing(self) -> bool:
        return self._goal is not None

    @property
    def reference(self) -> Trajectory:
        """The trajectory being followed (a hold after the last point), without the admittance offset."""
        return self._reference

    @property
    def joint_offset(self) -> np.ndarray:
        """The admittance offset added to the reference at the last control step (joint space)."""
        return self._joint_offset.copy()

    @property
    def cartesian_offset(self) -> np.ndarray:
        return self._compliance.offset.copy()

    # -- action server callbacks (called by the bus, between control steps) ---
    def _on_goal(self, handle: ServerGoalHandle) -> bool:
        now = self.clock.now()
        try:
            if not self.active:
                raise GoalError(Result.INVALID_GOAL, f"controller {self.name} is not active")
            goal = parse_goal(handle.request, self.joint_names, now, self.config.admittance)
            self._reference = self._take_over(goal, now)
        except GoalError as exc:
            handle.abort(Result(error_code=exc.code, error_string=exc.args[0]))
            return True
        previous, self._goal = self._goal, _ActiveGoal(handle, goal)
        self._params = goal.admittance
        if previous is not None and previous.handle.is_active:
            previous.handle.canceled(
                Result(error_code=Result.SUPERSEDED, error_string=f"superseded by a new goal taking over at t={goal.seam_time:.4f} s")
            )
        return True

    def _take_over(self, goal: ParsedGoal, now: float) -> Trajectory:
        """The reference after stitching ``goal`` in, or GoalError saying why it cannot be."""
        current = self._reference
        seam = goal.seam_time
        executing = self._goal is not None
        past_end = seam > current.end_time + TIME_EPS
        if past_end and (executing or seam < now - TIME_EPS):
            raise GoalError(
                Result.SEAM_AFTER_TRAJECTORY_END,
                "seam time exceeds the end of the current trajectory "
                f"(seam t={seam:.4f} s, trajectory ends at t={current.end_time:.4f} s)",
            )
        if seam < now - TIME_EPS:
            raise GoalError(Result.OLD_HEADER_TIMESTAMP, f"seam time t={seam:.4f} s is already past (now t={now:.4f} s)")
        try:
            stitched = stitch(
                current,
                goal.trajectory,
                seam,
                goal.path_tolerance,
                self.joint_names,
                allow_after_end=not executing,
                check_velocity=goal.velocities_given,
                blend_acceleration=self.config.seam_blend_acceleration,
                min_blend_time=self.config.min_seam_blend_time,
            )
        except SeamError as exc:
            raise GoalError(Result.INVALID_GOAL, str(exc)) from None
        return stitched.trimmed_before(now)

    def _on_cancel(self, handle: ServerGoalHandle) -> bool:
        if self._goal is None or self._goal.handle is not handle:
            return False
        self._goal.cancel_requested = True
        return True

    # -- control loop ---
    def on_deactivate(self, t: float) -> None:
        if self._goal is not None:  # the manager refuses this; kept so a handle never dangles
            self._finish(t, "abort", Result(error_code=Result.INVALID_GOAL, error_string=f"controller {self.name} was deactivated"))

    def update(self, t: float, dt: float) -> None:
        goal = self._goal
        if goal is not None and (goal.cancel_requested or goal.handle.is_cancel_requested):
            self._finish(t, "canceled", Result(error_code=Result.CANCELED, error_string="canceled by the client"))

        wrench = np.asarray(self.hardware.wrench(), dtype=float)
        compliance = self._compliance = admittance_step(self._compliance, wrench, self._params, dt)
        offset_rate = None
        if compliance.at_rest:  # nothing to add (most steps: the wrench is inside the deadband)
            self._joint_offset = self._no_offset
        else:
            pseudo_inverse = self._wrist_pseudo_inverse(t)
            self._joint_offset, offset_rate = pseudo_inverse @ compliance.offset, pseudo_inverse @ compliance.rate

        desired = self._reference.sample(t)
        command, velocity = self._with_offset(desired, offset_rate)
        if self._goal is not None:
            reference = self._reference
            self._supervise(t, wrench, command, desired.velocity)
            if self._reference is not reference:  # a stop began: same position at t, new velocity
                command, velocity = self._with_offset(self._reference.sample(t), offset_rate)
        self.hardware.command_arm(command, velocity)

    def plan_steps(self, times: list[float]) -> StepPlan | None:
        """The reference at each of ``times`` (a tick's control steps), sampled in one pass, when
        those steps may run the quick way: the admittance rests, no cancel is pending, and a goal
        does not reach its end within them (the settle check is ``update``'s). None otherwise."""
        goal = self._goal
        if not self._compliance.at_rest:
            return None
        parsed = None
        if goal is not None:
            if goal.cancel_requested or goal.handle.is_cancel_requested or times[-1] >= self._reference.end_time - TIME_EPS:
                return None
            parsed = goal.goal
        positions, velocities = self._reference.sample_many(times)
        thresholds = parsed.force_torque_threshold if parsed is not None else None
        return StepPlan(
            times=times,
            goal=goal,
            reference=self._reference,
            compliance=self._compliance,
            positions=positions,
            velocities=velocities,
            position_rows=positions.tolist(),
            deadband=self._params.deadband_values,
            thresholds=thresholds.tolist() if thresholds is not None else None,
            path_tolerance=parsed.path_tolerance if parsed is not None else 0.0,
        )

    def planned_update(self, plan: StepPlan, k: int) -> bool:
        """Control step ``k`` of ``plan``, exactly as ``update(plan.times[k], dt)`` would run it,
        when nothing reacts in it; False, having done nothing, when something would (the wrench
        leaves the deadband, an F/T or path check fails, the goal, reference or admittance is not
        the plan's, a cancel is pending): then ``update`` must run this step."""
        goal = self._goal
        if goal is not plan.goal or self._reference is not plan.reference or self._compliance is not plan.compliance:
            return False
        if goal is not None and (goal.cancel_requested or goal.handle.is_cancel_requested):
            return False
        wrench = np.asarray(self.hardware.wrench(), dtype=float).tolist()
        if not inside_deadband(wrench, plan.deadband):
            return False
        command, velocity = plan.positions[k], plan.velocities[k]
        if goal is not None:
            actual = np.asarray(self.hardware.arm_position(), dtype=float)
            if not within_thresholds(wrench, plan.thresholds):
                return False
            if not within_path_tolerance(actual.tolist(), plan.position_rows[k], plan.path_tolerance):
                return False
            self._record_step(plan.times[k], goal, command, velocity, actual, wrench)
        self._joint_offset = self._no_offset
        self.hardware.command_arm(command, velocity)
        return True

    def _with_offset(self, desired: TrajectoryState, offset_rate: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity to command: the reference plus the admittance offset (None: at rest)."""
        if offset_rate is None:
            return desired.position, desired.velocity
        return desired.position + self._joint_offset, desired.velocity + offset_rate

    def _wrist_pseudo_inverse(self, t: float) -> np.ndarray:
        """The damped pseudo-inverse of the wrist Jacobian, at most ``jacobian_refresh_period`` old."""
        age = t - self._pseudo_inverse_time
        if self._pseudo_inverse is None or not 0.0 <= age < self.config.jacobian_refresh_period - TIME_EPS:
            self._pseudo_inverse = damped_pseudo_inverse(self.hardware.wrist_jacobian())
            self._pseudo_inverse_time = t
        return self._pseudo_inverse

    def _supervise(self, t: float, wrench: np.ndarray, command: np.ndarray, desired_velocity: np.ndarray) -> None:
        goal = self._goal
        assert goal is not None
        parsed = goal.goal
        actual = np.asarray(self.hardware.arm_position(), dtype=float)
        self._record_step(t, goal, command, desired_velocity, actual, wrench.tolist())
        ft = wrench_violation(wrench, parsed.force_torque_threshold)
        if ft is not None:
            self._finish(t, "abort", Result(error_code=Result.FORCE_TORQUE_THRESHOLD_EXCEEDED, error_string=f"force-torque threshold exceeded at t={t:.3f} s: {ft}"))
            return
        path = path_violation(actual, command, parsed.path_tolerance, self.joint_names)
        if path is not None:
            self._finish(t, "abort", Result(error_code=Result.PATH_TOLERANCE_VIOLATED, error_string=f"path tolerance violated at t={t:.3f} s on {path}"))
            return
        end = self._reference.end_time
        if t < end - TIME_EPS:
            return
        tolerance = self.config.goal_position_tolerance
        if parsed.path_tolerance > 0:
            tolerance = min(tolerance, parsed.path_tolerance)
        settle = path_violation(actual, command, tolerance, self.joint_names)
        if settle is None:
            self._finish(t, "succeed", Result(error_code=Result.SUCCESSFUL, error_string=""))
            return
        allowed = parsed.goal_time_tolerance or self.config.default_goal_time_tolerance
        if t > end + allowed + TIME_EPS:
            self._finish(
                t,
                "abort",
                Result(
                    error_code=Result.GOAL_TOLERANCE_VIOLATED,
                    error_string=f"goal not reached {allowed:.3f} s after the trajectory ended at t={end:.3f} s: {settle}",
                ),
            )

    def _record_step(
        self, t: float, goal: _ActiveGoal, command: np.ndarray, desired_velocity: np.ndarray, actual: np.ndarray, wrench: list[float]
    ) -> None:
        """What every control step of a goal leaves behind: feedback when due, the peak wrench."""
        if t - self._last_feedback >= 1.0 / self.config.feedback_rate - TIME_EPS:
            self._publish_feedback(t, goal, command, desired_velocity, actual, wrench)
        fx, fy, fz, tx, ty, tz = wrench
        force_n, torque_nm = math.hypot(fx, fy, fz), math.hypot(tx, ty, tz)
        if force_n > self.peak_force_n:  # as max(peak, force): a NaN reading leaves the peak
            self.peak_force_n = force_n
        if torque_nm > self.peak_torque_nm:
            self.peak_torque_nm = torque_nm

    def _finish(self, t: float, how: str, result) -> None:
        """End the current goal; anything but success also brings the arm smoothly to rest."""
        goal = self._goal
        assert goal is not None
        self._goal = None
        if how != "succeed":
            self._reference = stop_trajectory(self._reference.sample(t), t, self.config.stop_time)
        if not goal.handle.is_active:
            return
        if how == "succeed":
            goal.handle.succeed(result)
        elif how == "canceled":
            goal.handle.canceled(result)
        else:
            goal.handle.abort(result)

    def _publish_feedback(
        self, t: float, goal: _ActiveGoal, command: np.ndarray, desired_velocity: np.ndarray, actual: np.ndarray, wrench: list[float]
    ) -> None:
        self._last_feedback = t
        velocity = np.asarray(self.hardware.arm_velocity(), dtype=float)
        # Fill the sub-messages the constructor already built (building messages dominates here).
        feedback = Action.Feedback()
        feedback.header.stamp = time_msg(t)
        feedback.joint_names = list(self.joint_names)
        for point, positions, velocities in (
            (feedback.desired, command, desired_velocity),
            (feedback.actual, actual, velocity),
            (feedback.error, command - actual, desired_velocity - velocity),
        ):
            point.positions, point.velocities = positions.tolist(), velocities.tolist()
        force, torque = feedback.wrench.force, feedback.wrench.torque
        force.x, force.y, force.z, torque.x, torque.y, torque.z = wrench
        goal.handle.publish_feedback(feedback)

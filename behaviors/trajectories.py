"""MoveIt Pro's trajectory nodes: plan a Cartesian path, validate a trajectory, execute it, and
read a saved waypoint.

``PlanCartesianPath`` moves a robot frame along straight lines through a vector of poses: the
lines are cut every ``ik_cartesian_space_density`` metres, each cut is solved by IK seeded with
the previous solution (so the arm keeps its configuration), a joint step larger than
``ik_joint_space_density`` is a jump and fails the plan, and the joint path is timed within the
velocity and acceleration limits (scaled), stopping at each waypoint. The result is checked
against the limits and the planning scene before it is written. ``ExecuteTrajectory`` sends it
to the admittance controller after checking again, from where the arm is now.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
import yaml
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from runtime.tree.behavior import Behavior, Status
from runtime.tree.resources import WAYPOINTS
from runtime.errors import SetupError
from runtime.tree.ports import InputPort, NameKind, Names, OutputPort, PortInfo, PortType, Range
from runtime.motion.scene import JointLimits, SceneSnapshot
from runtime.motion.scene.kinematics import frame_pose, solve_ik
from runtime.io.timestamps import time_msg

from .action_goal import Goal, GoalState
from .controller_link import CONTROLLER_ACTION_TYPES, ControllerKind, ControllerLink, GoalTolerances, trajectory_goal
from runtime.motion.samples import Samples
from .poses import FrameError, ReadsRobotState, RobotState, matrix_to_pose, pose_in_world
from .safety import MotionSafety, SafetyError, make_safety
from .trajectory_goal import DEFAULT_CONTROLLER, GOAL_TIME_TOLERANCE_S, NO_MOTION_S, PlanningError, SendsTrajectoryGoal, trajectory_msg
from .waiting import Deadline, when_ready

JTC_ACTION = "/joint_trajectory_controller/follow_joint_trajectory"
START_TOLERANCE_RAD = 0.01
"""How far the arm may be from a trajectory's first point when it is executed."""
TIMING_MODES = ("time_optimal", "cartesian_trapezoidal")


# -- pure planning pieces --------------------------------------------------------------------------
def interpolate_line(start: NDArray[np.float64], goal: NDArray[np.float64], step_m: float, step_rad: float) -> list[NDArray[np.float64]]:
    """Poses (4x4) from ``start`` (excluded) to ``goal`` (included) along a straight line, with
    the orientation slerped, no two more than ``step_m`` or ``step_rad`` apart."""
    from scipy.spatial.transform import Rotation, Slerp  # scipy.spatial: ~0.3 s, imported on first use

    distance = float(np.linalg.norm(goal[:3, 3] - start[:3, 3]))
    rotations = Rotation.from_matrix(np.stack([start[:3, :3], goal[:3, :3]]))
    angle = float((rotations[0].inv() * rotations[1]).magnitude())
    count = max(1, int(np.ceil(max(distance / step_m, angle / step_rad))))
    slerp = Slerp([0.0, 1.0], rotations)
    out = []
    for f in np.linspace(0.0, 1.0, count + 1)[1:]:
        m = np.eye(4)
        m[:3, :3] = slerp([f]).as_matrix()[0]
        m[:3, 3] = start[:3, 3] + f * (goal[:3, 3] - start[:3, 3])
        out.append(m)
    return out


@dataclass(frozen=True)
class PathTiming:
    """When each point of a joint path is reached (s) and the path speed there (joint-space m/s-like units)."""

    times: NDArray[np.float64]
    speeds: NDArray[np.float64]


def time_path(path: NDArray[np.float64], stops: set[int], limits: JointLimits, velocity_scale: float, acceleration_scale: float) -> PathTiming:
    """Timing of a joint path (N, J) followed as fast as the scaled velocity and acceleration
    limits allow, at rest at the first, the last and every ``stops`` index.

    The path is piecewise linear; along each piece the speed is bounded by the joint velocity
    limits and changes at a constant rate no larger than the acceleration limits allow (a
    forward and a backward pass over the squared path speed).
    """
    n = len(path)
    if n < 2:
        return PathTiming(np.zeros(n), np.zeros(n))
    lengths, speed_cap, accel_cap = _piece_caps(path, limits, velocity_scale, acceleration_scale)
    v2 = np.empty(n)  # squared path speed at each point: capped by the pieces on either side
    v2[0], v2[-1] = 0.0, 0.0
    v2[1:-1] = np.minimum(speed_cap[:-1], speed_cap[1:]) ** 2
    for i in stops:
        if 0 < i < n - 1:
            v2[i] = 0.0
    for i in range(n - 1):  # forward: accelerate no faster than the limit allows
        v2[i + 1] = min(v2[i + 1], v2[i] + 2.0 * accel_cap[i] * lengths[i])
    for i in range(n - 2, -1, -1):  # backward: decelerate in time
        v2[i] = min(v2[i], v2[i + 1] + 2.0 * accel_cap[i] * lengths[i])
    speeds = np.sqrt(np.maximum(v2, 0.0))
    mean = (speeds[:-1] + speeds[1:]) / 2.0
    dt = np.divide(lengths, mean, out=np.zeros_like(lengths), where=mean > 0)
    return PathTiming(np.concatenate([[0.0], np.cumsum(dt)]), speeds)


def _piece_caps(path: NDArray[np.float64], limits: JointLimits, velocity_scale: float, acceleration_scale: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Each piece's length and the largest path speed and acceleration its joint limits allow."""
    deltas = np.diff(path, axis=0)
    lengths = np.linalg.norm(deltas, axis=1)
    directions = np.divide(np.abs(deltas), lengths[:, None], out=np.zeros_like(deltas), where=lengths[:, None] > 0)
    caps = []
    for limit in (limits.max_velocity * velocity_scale, limits.max_acceleration * acceleration_scale):
        with np.errstate(divide="ignore"):
            cap = np.min(np.where(directions > 0, limit / np.where(directions > 0, directions, 1.0), np.inf), axis=1)
        caps.append(np.where(np.isfinite(cap), cap, 0.0))
    return lengths, caps[0], caps[1]


def resample(timing: PathTiming, path: NDArray[np.float64], rate_hz: float) -> Samples:
    """The timed path at ``rate_hz``: along each piece the speed changes at a constant rate, so
    the position there follows ``s = v0 t + a t^2 / 2``; velocities and accelerations are
    finite differences (zero at both ends). A path of no length is its last point alone."""
    times, speeds = timing.times, timing.speeds
    duration = float(times[-1])
    if duration < NO_MOTION_S:
        return Samples.at_rest(path[-1])
    count = max(2, int(np.ceil(duration * rate_hz)) + 1)
    t = np.linspace(0.0, duration, count)
    piece = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(path) - 2)
    tau = t - times[piece]
    dt = times[piece + 1] - times[piece]
    accel = np.divide(speeds[piece + 1] - speeds[piece], dt, out=np.zeros_like(dt), where=dt > 0)
    travelled = speeds[piece] * tau + 0.5 * accel * tau ** 2
    length = np.linalg.norm(path[piece + 1] - path[piece], axis=1)
    fraction = np.clip(np.divide(travelled, length, out=np.ones_like(length), where=length > 0), 0.0, 1.0)
    positions = path[piece] + fraction[:, None] * (path[piece + 1] - path[piece])
    velocities = np.gradient(positions, t, axis=0) if duration > 0 else np.zeros_like(positions)
    velocities[0] = velocities[-1] = 0.0
    accelerations = np.gradient(velocities, t, axis=0) if duration > 0 else np.zeros_like(positions)
    # float64 already (no copy): typed so for numpy 2.2's stubs, where a gradient is floating[Any]
    return Samples(np.asarray(t, dtype=np.float64), positions, np.asarray(velocities, dtype=np.float64),
                   np.asarray(accelerations, dtype=np.float64))


def resample_within(timing: PathTiming, path: NDArray[np.float64], rate_hz: float, limits: JointLimits) -> Samples:
    """``resample``, slowed down evenly where its velocities or accelerations exceed the joint
    limits: ``time_path`` bounds the speed along each piece, not the turn from one piece to the
    next, which adds a little acceleration where the IK points bend the joint path."""
    samples = resample(timing, path, rate_hz)
    for _ in range(5):
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = max(float(np.max(np.abs(samples.velocities) / limits.max_velocity)),
                        float(np.max(np.abs(mean_velocities(samples)) / limits.max_velocity, initial=0.0)),
                        float(np.sqrt(np.max(np.abs(samples.accelerations) / limits.max_acceleration))))
        if ratio <= 1.0:
            break
        stretch = 1.01 * ratio
        timing = PathTiming(timing.times * stretch, timing.speeds / stretch)
        samples = resample(timing, path, rate_hz)
    return samples


def resample_within_envelope(timing: PathTiming, path: NDArray[np.float64], rate_hz: float, safety: MotionSafety) -> Samples:
    """``resample_within``, slowed down evenly further where the tool's linear or angular speed
    exceeds the Cartesian envelope: a path timed by the joint limits alone can move the tool
    faster than the cell allows (a planned detour at full joint speed passes 1 m/s)."""
    samples = resample_within(timing, path, rate_hz, safety.limits)
    for _ in range(5):
        ratio = safety.tool_speed_ratio(samples)
        if ratio <= 1.0:
            break
        stretch = 1.01 * ratio
        timing = PathTiming(timing.times * stretch, timing.speeds / stretch)
        samples = resample(timing, path, rate_hz)
    return samples


def parse_timing(text: str) -> tuple[str, float, float]:
    """MoveIt Pro's ``trajectory_timing`` ("[{mode: time_optimal, velocity_scale_factor: 0.5}]"):
    the mode and the velocity and acceleration scale factors it sets (1.0 when unset)."""
    try:
        data = yaml.safe_load(text) if text.strip() else [{}]
    except yaml.YAMLError as err:
        raise PlanningError(f"trajectory_timing is not YAML: {err}") from None
    if isinstance(data, dict):
        data = [data]
    if not isinstance(data, list) or not data or not isinstance(data[0], dict):
        raise PlanningError(f"trajectory_timing must be a list of mappings like [{{mode: time_optimal}}], got {text!r}")
    if len(data) > 1:
        raise PlanningError(f"trajectory_timing with {len(data)} entries: only one timing for the whole path is supported")
    entry = data[0]
    mode = str(entry.get("mode", "time_optimal"))
    if mode not in TIMING_MODES:
        raise PlanningError(f"trajectory_timing mode '{mode}' is not supported (supported: {', '.join(TIMING_MODES)})")
    scales = []
    for key in ("velocity_scale_factor", "acceleration_scale_factor"):
        value = entry.get(key, 1.0)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= 1:
            raise PlanningError(f"trajectory_timing {key} must be in (0, 1], got {value!r}")
        scales.append(float(value))
    return mode, scales[0], scales[1]


def tip_offset_matrix(values: list[float]) -> NDArray[np.float64]:
    """MoveIt Pro's ``tip_offset`` x;y;z;roll;pitch;yaw (m, rad) as a 4x4 in the tip's frame."""
    if len(values) != 6:
        raise PlanningError(f"tip_offset needs 6 values (x;y;z;roll;pitch;yaw), got {len(values)}")
    from scipy.spatial.transform import Rotation  # scipy.spatial: ~0.3 s, imported on first use

    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("xyz", values[3:]).as_matrix()
    m[:3, 3] = values[:3]
    return m


def from_trajectory_msg(msg: JointTrajectory, joints: tuple[str, ...]) -> Samples:
    """The trajectory's points in ``joints`` order; PlanningError when it does not fit."""
    missing = [j for j in joints if j not in msg.joint_names]
    if missing:
        raise PlanningError(f"the trajectory lacks joints {', '.join(missing)} (it has {', '.join(msg.joint_names) or 'none'})")
    if not msg.points:
        raise PlanningError("the trajectory has no points")
    order = [list(msg.joint_names).index(j) for j in joints]
    n = len(order)

    def column(values: Any) -> NDArray[np.float64]:
        values = list(values)
        return np.array([values[i] for i in order]) if len(values) == len(msg.joint_names) else np.zeros(n)

    times = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points])
    if np.any(np.diff(times) <= 0) and len(times) > 1:
        raise PlanningError("the trajectory's time_from_start values do not increase")
    positions = np.stack([column(p.positions) for p in msg.points])
    velocities = np.stack([column(p.velocities) for p in msg.points])
    accelerations = np.stack([column(p.accelerations) for p in msg.points])
    return Samples(times, positions, velocities, accelerations)


def subdivide(samples: Samples, step_rad: float) -> Samples:
    """Extra points between a trajectory's points, none more than ``step_rad`` apart in any joint
    (for collision checks of a coarse trajectory; positions only)."""
    times, rows = [samples.times[0]], [samples.positions[0]]
    for i in range(1, len(samples)):
        a, b = samples.positions[i - 1], samples.positions[i]
        count = max(1, int(np.ceil(np.max(np.abs(b - a)) / step_rad)))
        for f in np.linspace(0.0, 1.0, count + 1)[1:]:
            rows.append(a + f * (b - a))
            times.append(samples.times[i - 1] + f * (samples.times[i] - samples.times[i - 1]))
    zeros = np.zeros((len(rows), samples.positions.shape[1]))
    return Samples(np.array(times), np.array(rows), zeros, zeros)


def mean_velocities(samples: Samples) -> NDArray[np.float64]:
    """Each joint's mean velocity from every point to the next ((N - 1, J)): whatever the
    controller plays between two points, it moves at least this fast somewhere between them (a
    trajectory of positions alone says nothing more)."""
    steps, dt = np.diff(samples.positions, axis=0), np.diff(samples.times)[:, None]
    velocities: NDArray[np.float64] = np.divide(steps, dt, out=np.zeros_like(steps), where=dt > 0)
    return velocities


def check_motion(safety: MotionSafety, samples: Samples, padding_m: float, check_step_rad: float,
                 snapshot: SceneSnapshot | None = None) -> str | None:
    """The first point of a motion outside the position, velocity or acceleration limits or the
    Cartesian envelope, or the first interval between two points whose mean velocity exceeds a
    limit (a joint's, or the TCP's speed at the interval's end with those mean joint velocities),
    or else its first collision (with the collision rules of ``snapshot``, default the scene's
    now), as a sentence; or None."""
    outside = safety.first_limit_violation(samples)
    if outside is not None:
        return f"breaks a {outside.family} at point {outside.step} (t={outside.time:.3f} s): {outside.what}"
    if len(samples) > 1:
        steps = Samples(samples.times[1:], samples.positions[1:], mean_velocities(samples), np.zeros_like(samples.positions[1:]))
        fast = safety.first_limit_violation(steps)
        if fast is not None:
            return (f"moves faster than a {fast.family} from point {fast.step} to point {fast.step + 1} "
                    f"(t={fast.time:.3f} s): {fast.what} (the mean over that interval)")
    collision = safety.first_collision(snapshot or safety.snapshot(), subdivide(samples, check_step_rad), padding_m)
    return None if collision is None else f"collides: {collision}"


@dataclass(frozen=True)
class CartesianPlan:
    samples: Samples
    tip_poses: list[NDArray[np.float64]]
    """World poses of the tip at the IK points (for debug_solution and VisualizePath)."""


def plan_cartesian(
    safety: MotionSafety,
    start: NDArray[np.float64],
    targets: list[NDArray[np.float64]],
    tip: str,
    offset: NDArray[np.float64],
    position_only: bool,
    step_m: float,
    max_joint_step_rad: float,
    velocity_scale: float,
    acceleration_scale: float,
    rate_hz: float,
) -> CartesianPlan:
    """Plan straight tip lines from the current state through ``targets`` (world 4x4s of the
    offset tip). Raises PlanningError naming the waypoint and the reason."""
    robot = safety.scene.robot
    current = frame_pose(robot, safety.layout(start), tip) @ offset
    inverse_offset = np.linalg.inv(offset)
    rows, tip_poses, stops = [start], [current], set()
    q = start
    for w, target in enumerate(targets):
        for pose in interpolate_line(current, target, step_m, step_m * 10):
            result = solve_ik(
                robot, safety.group, pose @ inverse_offset, seeds=[q], frame=tip, random_restarts=0,
                position_only=position_only, position_tolerance=1e-4, orientation_tolerance=1e-3,
            )
            if not result.success:
                p = pose[:3, 3]
                raise PlanningError(
                    f"waypoint {w}: no IK solution near the arm's path at ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) "
                    f"({result.position_error * 1000:.1f} mm, {result.orientation_error:.3f} rad away)"
                )
            jump = float(np.max(np.abs(result.positions - q)))
            if jump > max_joint_step_rad:
                joint = safety.group_joints[int(np.argmax(np.abs(result.positions - q)))]
                raise PlanningError(
                    f"waypoint {w}: joint {joint} jumps {jump:.3f} rad between two points {step_m * 1000:.0f} mm apart "
                    f"(more than ik_joint_space_density {max_joint_step_rad:.3f} rad): the path crosses a singularity or a joint limit"
                )
            q = result.positions
            rows.append(q)
            tip_poses.append(pose)
        current = target
        stops.add(len(rows) - 1)
    path = np.array(rows)
    timing = time_path(path, stops, safety.limits, velocity_scale, acceleration_scale)
    return CartesianPlan(resample_within_envelope(timing, path, rate_hz, safety), tip_poses)


# -- nodes -------------------------------------------------------------------------------------
class PlanCartesianPath(ReadsRobotState, Behavior):
    """MoveIt Pro's PlanCartesianPath."""

    needs_world = True
    description: ClassVar[str] = (
        "Plan a joint trajectory that moves a tip frame in straight lines through a vector of poses "
        "(IK along the lines, limits and collisions checked); it does not move the robot: ExecuteTrajectory does."
    )
    ports = (
        InputPort("path", PortType.POSE_STAMPED_LIST, description="Waypoints for the tip (PoseStamped, any known frame)."),
        InputPort("planning_group_name", PortType.STRING, "manipulator", "SRDF joint group to move.", names=Names(NameKind.JOINT_GROUP)),
        InputPort("tip_links", PortType.STRING_LIST, "tcp", "Robot frame that follows the path (one).", names=Names(NameKind.FRAME)),
        InputPort("tip_offset", PortType.FLOAT_LIST, "0;0;0;0;0;0", "Offset x;y;z;roll;pitch;yaw (m, rad) of the followed point in the tip frame.", valid=Range(-10, 10, "m, rad")),
        InputPort("position_only", PortType.BOOL, False, "Follow positions only; the orientation is free."),
        InputPort("blending_radius", PortType.FLOAT, 0.02, "Accepted for compatibility; the path stops at each waypoint (no blending).", valid=Range(0, 1, "m")),
        InputPort("ik_cartesian_space_density", PortType.FLOAT, 0.01, "Distance (m) between IK points along the lines.", valid=Range(0.0001, 1, "m")),
        InputPort("ik_joint_space_density", PortType.FLOAT, 0.1, "Largest joint step (rad) between IK points; more is a jump.", valid=Range(0.001, 3.15, "rad")),
        InputPort("trajectory_sampling_rate", PortType.UINT, 100, "Points per second of the output trajectory (Hz).", valid=Range(1, 10000, "Hz")),
        InputPort("velocity_scale_factor", PortType.FLOAT, 1.0, "Fraction of the joint velocity limits, in (0, 1].", valid=Range(0, 1, min_open=True)),
        InputPort("acceleration_scale_factor", PortType.FLOAT, 1.0, "Fraction of the joint acceleration limits, in (0, 1].", valid=Range(0, 1, min_open=True)),
        InputPort("trajectory_timing", PortType.STRING, "[{mode: time_optimal}]", "Timing (YAML): mode time_optimal, optional velocity/acceleration_scale_factor."),
        InputPort("max_optimizer_iterations", PortType.UINT, 1, "Accepted for compatibility (no post-optimisation here).", valid=Range(0, 100000)),
        InputPort("link_padding", PortType.FLOAT, 0.01, "Clearance (m) required from world objects.", valid=Range(0, 0.5, "m")),
        OutputPort("joint_trajectory_msg", PortType.JOINT_TRAJECTORY, "The planned trajectory.", default="{joint_trajectory_msg}"),
        OutputPort("debug_solution", PortType.POSE_STAMPED_LIST, "The tip poses the IK solved (world frame), for VisualizePath."),
    )

    def update(self) -> Status:
        try:
            plan, joints = self._plan(self.state())
        except (PlanningError, SafetyError, FrameError, ValueError) as err:
            return self.fail(str(err))
        now = self.context.clock.now()
        self.set_output("joint_trajectory_msg", trajectory_msg(plan.samples, joints))
        self.set_output("debug_solution", [matrix_to_pose("world", m, now) for m in plan.tip_poses])
        self.feedback_message = f"{len(plan.tip_poses)} IK points, {plan.samples.times[-1]:.2f} s"
        return Status.SUCCESS

    def _plan(self, state: RobotState) -> tuple[CartesianPlan, tuple[str, ...]]:
        scene = self.context.scene
        safety = make_safety(scene, self.get_input("planning_group_name"), None)
        tips = [t for t in self.get_input("tip_links") if t]
        if len(tips) != 1:
            raise PlanningError(f"tip_links must name exactly one frame here, got {len(tips)} ({', '.join(tips) or 'none'})")
        tip = tips[0]
        if not scene.robot.has_frame(tip):
            raise PlanningError(f"tip link '{tip}' is not a frame of the robot model")
        path = self.get_input("path")
        if not path:
            raise PlanningError("path is empty: give at least one pose")
        _, timing_velocity, timing_acceleration = parse_timing(self.get_input("trajectory_timing"))
        velocity = self.get_input("velocity_scale_factor") * timing_velocity
        acceleration = self.get_input("acceleration_scale_factor") * timing_acceleration
        for name, value in (("velocity_scale_factor", velocity), ("acceleration_scale_factor", acceleration)):
            if not 0 < value <= 1:
                raise PlanningError(f"{name} must be in (0, 1], got {value}")
        step = self.get_input("ik_cartesian_space_density")
        joint_step = self.get_input("ik_joint_space_density")
        rate = self.get_input("trajectory_sampling_rate")
        if not step > 0 or not joint_step > 0 or not rate > 0:
            raise PlanningError("ik_cartesian_space_density, ik_joint_space_density and trajectory_sampling_rate must be positive")
        targets = [pose_in_world(scene, p, state) for p in path]
        start = state.positions(safety.group_joints)
        plan = plan_cartesian(
            safety, start, targets, tip, tip_offset_matrix(self.get_input("tip_offset")), self.get_input("position_only"),
            step, joint_step, velocity, acceleration, float(rate),
        )
        problem = check_motion(safety, plan.samples, self.get_input("link_padding"), joint_step / 2)
        if problem:
            raise PlanningError(f"the planned path {problem}")
        return plan, safety.group_joints


class ValidateTrajectory(Behavior):
    """MoveIt Pro's ValidateTrajectory."""

    needs_world = True
    description: ClassVar[str] = (
        "SUCCESS when a joint trajectory stays within the position, velocity and acceleration limits and collision-free in the planning scene; "
        "FAILURE naming the first problem."
    )
    ports = (
        InputPort("joint_trajectory_msg", PortType.JOINT_TRAJECTORY, "{joint_trajectory_msg}", "The trajectory to check."),
        InputPort("planning_group_name", PortType.STRING, "manipulator", "SRDF joint group the trajectory moves.", names=Names(NameKind.JOINT_GROUP)),
        InputPort("planning_scene_msg", PortType.ANY, "", "Accepted for compatibility; the run's current planning scene is used."),
        InputPort("cartesian_space_step", PortType.FLOAT, 0.02, "Accepted for compatibility (checks are spaced by joint_space_step).", valid=Range(0.0001, 1, "m")),
        InputPort("joint_space_step", PortType.FLOAT, 0.05, "Largest joint step (rad) between checked states.", valid=Range(0.001, 3.15, "rad")),
        InputPort("link_padding", PortType.FLOAT, 0.0, "Clearance (m) required from world objects.", valid=Range(0, 0.5, "m")),
        OutputPort("debug_solution", PortType.ANY, "The problem found (a sentence), or empty."),
    )

    def update(self) -> Status:
        try:
            safety = make_safety(self.context.scene, self.get_input("planning_group_name"), None)
            samples = from_trajectory_msg(self.get_input("joint_trajectory_msg"), safety.group_joints)
            step = self.get_input("joint_space_step")
            if not step > 0:
                raise PlanningError(f"joint_space_step must be positive, got {step}")
            problem = check_motion(safety, samples, self.get_input("link_padding"), step)
        except (PlanningError, SafetyError) as err:
            return self.fail(str(err))
        self.set_output("debug_solution", problem or "")
        if problem:
            return self.fail(f"the trajectory {problem}")
        self.feedback_message = f"valid: {len(samples)} points, {samples.times[-1]:.2f} s"
        return Status.SUCCESS


PIPELINE_ACTIONS = {"jtac": DEFAULT_CONTROLLER, "jtc": JTC_ACTION}
"""MoveIt Pro's execution pipelines and the controller action each one uses by default."""


class ExecuteTrajectory(ReadsRobotState, SendsTrajectoryGoal):
    """MoveIt Pro's ExecuteTrajectory, on the admittance controller or a stock JTC."""

    needs_world = True
    description: ClassVar[str] = (
        "Execute a joint trajectory on the trajectory controller (the admittance controller or a stock JTC, whichever type "
        "controller_action_name serves) after checking it starts where the arm is, within the limits and collision-free; "
        "fails when the controller aborts."
    )
    ports: ClassVar[tuple[PortInfo, ...]] = (
        InputPort("joint_trajectory_msg", PortType.JOINT_TRAJECTORY, "{joint_trajectory_msg}", "The trajectory, e.g. from PlanCartesianPath."),
        InputPort("execution_pipeline", PortType.STRING, "jtac", "jtac (admittance controller) or jtc (joint_trajectory_controller): picks the default controller_action_name."),
        InputPort("controller_action_name", PortType.STRING, "", "The controller's action (empty: the pipeline's, /joint_trajectory_admittance_controller/... or /joint_trajectory_controller/...).",
                  names=Names(NameKind.ACTION, CONTROLLER_ACTION_TYPES)),
        InputPort("planning_group_name", PortType.STRING, "manipulator", "SRDF joint group the trajectory moves (for the checks).", names=Names(NameKind.JOINT_GROUP)),
        InputPort("path_position_tolerance", PortType.FLOAT_LIST, "0.1", "Tracking error (rad) before the controller aborts (one value, or one per joint: the smallest is used).", valid=Range(0, 10, "rad", min_open=True)),
        InputPort("goal_position_tolerance", PortType.FLOAT_LIST, "0.01", "Accepted for compatibility (the controller checks path_position_tolerance).", valid=Range(0, 10, "rad")),
        InputPort("goal_duration_tolerance", PortType.FLOAT, -1.0, "Seconds the goal may run late (-1: the controller's default of 1 s).", valid=Range(-1, 3600, "s")),
        InputPort("absolute_force_torque_threshold", PortType.FLOAT_LIST, "", "Fx;Fy;Fz;Tx;Ty;Tz (N, Nm) that abort the motion (empty: none).", valid=Range(0, 100000, "N, N m", min_open=True)),
        InputPort("admittance_parameters_msg", PortType.ANY, "", "Not supported here: the controller keeps its own admittance parameters."),
        InputPort("link_padding", PortType.FLOAT, 0.0, "Clearance (m) required from world objects for the pre-check.", valid=Range(0, 0.5, "m")),
        InputPort("timeout", PortType.FLOAT, 5.0, "Seconds to wait for the controller and the joint states.", valid=Range(0, 3600, "s", min_open=True)),
    )

    def initialise(self) -> None:
        self.error: str | None = None
        self.goal = Goal()
        pipeline = self.get_input("execution_pipeline").strip().lower()
        if pipeline not in PIPELINE_ACTIONS:
            self.error = f"execution_pipeline '{pipeline}' is not available (pipelines: {', '.join(PIPELINE_ACTIONS)})"
            return
        if self.is_port_set("admittance_parameters_msg"):
            self.error = "admittance_parameters_msg is not supported: the cell's controller keeps its own admittance parameters"
            return
        self.action = self.get_input("controller_action_name") or PIPELINE_ACTIONS[pipeline]
        self.controller = ControllerLink(self.context.bus, self.action, self.location, self.xml_id)
        self.deadline = Deadline(self, self.get_input("timeout"))

    def update(self) -> Status:
        if self.error:
            return self.fail(self.error)
        if self.goal.state is GoalState.NONE:
            ready = when_ready(self.controller.ready, self.deadline, f"controller action '{self.action}'")
            if ready is not True:
                return self.fail(ready) if isinstance(ready, str) else Status.RUNNING
            try:
                goal = self._goal()
            except (PlanningError, SafetyError, FrameError) as err:
                return self.fail(str(err))
            if goal is None:
                return Status.SUCCESS
            self.goal = Goal.send(self.controller.client, goal)
        return self.follow_goal("trajectory")

    def _goal(self) -> Any:
        """The controller goal for the checked trajectory; None when it has no length (the arm
        is already at its only point, so there is nothing to send)."""
        safety = make_safety(self.context.scene, self.get_input("planning_group_name"), None)
        return self.checked_goal(safety, from_trajectory_msg(self.get_input("joint_trajectory_msg"), safety.group_joints))

    def checked_goal(self, safety: MotionSafety, samples: Samples) -> Any:
        """The controller goal for ``samples`` once they pass ExecuteTrajectory's checks (they
        start where the arm is, within the limits, collision-free); None when they have no
        length. Raises PlanningError naming the first problem."""
        now = self.state().positions(safety.group_joints)
        gap = np.abs(samples.positions[0] - now)
        if float(gap.max()) > START_TOLERANCE_RAD:
            joint = safety.group_joints[int(np.argmax(gap))]
            raise PlanningError(
                f"the trajectory starts {float(gap.max()):.3f} rad away from the arm's current position (joint {joint}; "
                f"at most {START_TOLERANCE_RAD} rad): plan it from where the arm is"
            )
        problem = check_motion(safety, samples, self.get_input("link_padding"), 0.05)
        if problem:
            raise PlanningError(f"the trajectory {problem}")
        if samples.duration_s < NO_MOTION_S:
            return None
        tolerances = self.get_input("path_position_tolerance")
        threshold = self.get_input("absolute_force_torque_threshold")
        if tolerances and min(tolerances) <= 0:
            raise PlanningError(f"path_position_tolerance must be positive, got {tolerances}")
        if threshold and len(threshold) != 6:
            raise PlanningError(f"absolute_force_torque_threshold needs 6 values (Fx;Fy;Fz;Tx;Ty;Tz), got {len(threshold)}")
        if threshold and self.controller.kind is ControllerKind.JTC:
            raise PlanningError(f"absolute_force_torque_threshold needs the admittance controller: '{self.action}' is a "
                                "joint_trajectory_controller, whose goal has no force-torque abort")
        duration_tolerance = self.get_input("goal_duration_tolerance")
        tolerances = GoalTolerances(float(min(tolerances)) if tolerances else 0.1,
                                    GOAL_TIME_TOLERANCE_S if duration_tolerance < 0 else float(duration_tolerance),
                                    tuple(float(v) for v in threshold))
        assert self.controller.kind is not None  # the controller is ready
        return trajectory_goal(self.controller.kind, trajectory_msg(samples, safety.group_joints), tolerances)

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID:
            self.goal = self.goal.cancel()


class RetrieveWaypoint(Behavior):
    """MoveIt Pro's RetrieveWaypoint: a saved waypoint's joint positions."""

    description: ClassVar[str] = "Write a named waypoint of the cell (sim/config/waypoints.yaml) as a JointState of a group's joints."
    ports = (
        InputPort("waypoint_name", PortType.STRING, description="Name of the waypoint, e.g. Home.", names=Names(NameKind.WAYPOINT)),
        InputPort("joint_group_name", PortType.STRING, "manipulator", "SRDF joint group whose joints are written.", names=Names(NameKind.JOINT_GROUP)),
        OutputPort("waypoint_joint_state", PortType.JOINT_STATE, "The waypoint's positions for the group's joints."),
        OutputPort("joint_positions", PortType.FLOAT_LIST, "The same positions as a vector of numbers (not in MoveIt Pro)."),
    )
    needs_world = True

    def update(self) -> Status:
        waypoints = self.context.resources.get(WAYPOINTS) or {}
        name = self.get_input("waypoint_name")
        if name not in waypoints:
            raise SetupError(f"unknown waypoint '{name}' (known: {', '.join(sorted(waypoints)) or 'none are defined'})")
        try:
            joints = make_safety(self.context.scene, self.get_input("joint_group_name"), None).group_joints
        except SafetyError as err:
            return self.fail(str(err))
        missing = [j for j in joints if j not in waypoints[name]]
        if missing:
            return self.fail(f"waypoint '{name}' does not set {', '.join(missing)}")
        msg = JointState(name=list(joints), position=[float(waypoints[name][j]) for j in joints])
        msg.header.stamp = time_msg(self.context.clock.now())
        self.set_output("waypoint_joint_state", msg)
        self.set_output("joint_positions", list(msg.position))
        return Status.SUCCESS


NODES = (PlanCartesianPath, ValidateTrajectory, ExecuteTrajectory, RetrieveWaypoint)

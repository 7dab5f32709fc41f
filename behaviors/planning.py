"""MoveIt Pro's free-space planning behaviors: PlanToJointGoal and ComputeInverseKinematics, and
the pieces the MTC stages share with them (``behaviors.mtc``).

A free-space motion is planned by ``runtime.motion.scene.planner`` (a straight joint move when it is
free, otherwise OMPL's RRT-Connect with shortcutting) on the planning scene's own collision checks,
then timed within the joint velocity and acceleration limits (scaled), at rest at each corner of
the path, and checked with ExecuteTrajectory's checks (``check_motion``) before it is written.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import JointState

from runtime.tree.behavior import Behavior, Status
from runtime.errors import SetupError
from runtime.tree.ports import InputPort, NameKind, Names, OutputPort, PortType, Range
from runtime.motion.scene import CollisionResult, SceneSnapshot
from runtime.motion.scene.planner import PathPlanningError, PlannerSettings, Validity, plan_path, scene_validity, segment_states
from runtime.motion.scene.kinematics import IkSolver
from runtime.io.timestamps import time_msg

from runtime.motion.samples import Samples
from .poses import FrameError, ReadsRobotState, known_frames, pose_in_world
from .robot_state import group_joint_state
from .safety import MotionSafety, SafetyError, make_safety
from .trajectories import check_motion, resample_within_envelope, time_path
from .trajectory_goal import PlanningError, trajectory_msg

CHECK_STEP_RAD = 0.05
"""Joint step between the states ``check_motion`` checks (ExecuteTrajectory's)."""
PLANNING_TIMEOUT_S = 1.0
"""Seconds one free-space search may take (not a port in MoveIt Pro)."""
IK_RESTARTS = 32
"""Random IK seeds tried after the current state, for a collision-free solution."""


@dataclass(frozen=True)
class Motion:
    """How a free-space motion is planned and timed (MoveIt Pro's ports)."""

    padding_m: float = 0.0
    velocity_scale: float = 1.0
    acceleration_scale: float = 1.0
    rate_hz: float = 100.0
    max_iterations: int = 5000
    seed: int = 0
    timeout_s: float = PLANNING_TIMEOUT_S

    def __post_init__(self) -> None:
        for name, value in (("velocity_scale_factor", self.velocity_scale), ("acceleration_scale_factor", self.acceleration_scale)):
            if not 0 < value <= 1:
                raise PlanningError(f"{name} must be in (0, 1], got {value:g}")


def safety_for(scene: Any, group: str) -> MotionSafety:
    """``make_safety`` for a planning group; an unknown group is a SetupError (ERROR)."""
    try:
        return make_safety(scene, group, None)
    except SafetyError as err:
        raise SetupError(str(err)) from None


TIMING_STEP_RAD = 0.01
"""Joint-space length of the pieces a path is cut into for ``time_path`` (whose speed changes at
a constant rate along each piece: short pieces make the speed profile follow the limits)."""


def timed(safety: MotionSafety, waypoints: NDArray[np.float64], motion: Motion) -> Samples:
    """A joint polyline timed within the scaled limits, at rest at each corner (so it follows
    the straight segments the planner checked), sampled at ``motion.rate_hz``."""
    rows, stops = [waypoints[0]], set()
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        rows.extend(segment_states(a, b, TIMING_STEP_RAD))
        stops.add(len(rows) - 1)
    path = np.array(rows)
    timing = time_path(path, stops, safety.limits, motion.velocity_scale, motion.acceleration_scale)
    return resample_within_envelope(timing, path, motion.rate_hz, safety)


def state_validity(safety: MotionSafety, padding_m: float, snapshot: SceneSnapshot, gripper_position: float | None) -> Validity:
    """The planner's state check: collision-free in ``snapshot`` with ``padding_m``, and inside
    the Cartesian envelope's boxes and cone with the planner's margin (``MotionSafety.pose_check``)."""
    collision_free = scene_validity(safety.scene, safety.layout, padding_m, snapshot, gripper_position)
    inside_envelope = safety.pose_check()

    def is_free(q: NDArray[np.float64]) -> bool:
        return collision_free(q) and inside_envelope(q)

    return is_free


def plan_free_motion(safety: MotionSafety, start: NDArray[np.float64], goal: NDArray[np.float64], motion: Motion,
                     snapshot: SceneSnapshot) -> Samples:
    """A collision-free, timed motion from ``start`` to ``goal`` that passes ExecuteTrajectory's
    checks; PlanningError naming the reason otherwise."""
    is_free = state_validity(safety, motion.padding_m, snapshot, None)
    settings = PlannerSettings(timeout_s=motion.timeout_s, max_iterations=motion.max_iterations, seed=motion.seed)
    try:
        path = plan_path(is_free, start, goal, safety.limits.lower, safety.limits.upper, settings)
    except PathPlanningError as err:
        if err.in_collision is None:
            raise PlanningError(str(err)) from None
        q = start if err.in_collision == "start" else goal
        reason: CollisionResult | str | None = safety.scene.check_state(q, motion.padding_m, snapshot=snapshot, layout=safety.layout)
        if reason is None:
            reason = "it lies within 5 mm or 1 deg of the Cartesian envelope's edge, the margin the planner keeps from it"
        raise PlanningError(f"{err}: {reason}") from None
    samples = timed(safety, path.waypoints, motion)
    problem = check_motion(safety, samples, motion.padding_m, CHECK_STEP_RAD, snapshot)
    if problem:
        raise PlanningError(f"the planned motion {problem}")
    return samples


def collision_free_ik(safety: MotionSafety, target: NDArray[np.float64], tip: str, seed_q: NDArray[np.float64], padding_m: float,
                      snapshot: SceneSnapshot, count: int = 1, rng_seed: int = 0) -> list[NDArray[np.float64]]:
    """Up to ``count`` distinct collision-free joint solutions putting ``tip`` at ``target``
    (world 4x4): seeded from ``seed_q`` first, then from ``IK_RESTARTS`` random seeds.
    PlanningError when there is none, saying whether no solution reaches the pose or every one
    found collides."""
    if not safety.scene.robot.has_frame(tip):
        raise SetupError(f"unknown frame '{tip}' (known: {known_frames(safety.scene)})")
    solver = IkSolver(safety.scene.robot, safety.group, tip)
    is_free = scene_validity(safety.scene, safety.layout, padding_m, snapshot, None)
    rng = np.random.default_rng(rng_seed)
    lower, upper = np.maximum(solver.lower, -math.pi), np.minimum(solver.upper, math.pi)
    seeds = [seed_q] + [rng.uniform(lower, upper) for _ in range(IK_RESTARTS)]
    found: list[NDArray[np.float64]] = []
    nearest, collision = None, None
    for seed in seeds:
        result = solver.solve(target, seeds=[seed], random_restarts=0)
        if not result.success:
            if nearest is None or result.position_error < nearest.position_error:
                nearest = result
            continue
        q = result.positions
        if any(np.allclose(q, other, atol=1e-3) for other in found):
            continue
        if not is_free(q):
            collision = collision or safety.scene.check_state(q, padding_m, snapshot=snapshot, layout=safety.layout)
            continue
        found.append(q)
        if len(found) >= count:
            break
    if found:
        return found
    p = target[:3, 3]
    where = f"({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) for '{tip}'"
    if collision is not None:
        raise PlanningError(f"every IK solution at {where} is in collision: {collision}")
    assert nearest is not None  # no solution and none in collision: every seed failed
    raise PlanningError(f"the pose {where} is unreachable: no IK solution "
                        f"({nearest.position_error * 1000:.1f} mm, {nearest.orientation_error:.3f} rad away at best)")


def group_goal(joint_state: Any, joints: tuple[str, ...], port: str) -> NDArray[np.float64]:
    """The group's joint values from a JointState; PlanningError naming the missing joints."""
    if not isinstance(joint_state, JointState):
        raise PlanningError(f"port '{port}' expects a sensor_msgs/JointState, got {type(joint_state).__name__}")
    try:
        return np.array(group_joint_state(joint_state, joints, 0.0).position, dtype=float)
    except KeyError as err:
        raise PlanningError(f"{port}: {err.args[0]}") from None


GROUP_PORT = InputPort("planning_group_name", PortType.STRING, "manipulator", "SRDF joint group to move.", names=Names(NameKind.JOINT_GROUP))
MOTION_PORTS = (
    InputPort("velocity_scale_factor", PortType.FLOAT, 1.0, "Fraction of the joint velocity limits, in (0, 1].", valid=Range(0, 1, min_open=True)),
    InputPort("acceleration_scale_factor", PortType.FLOAT, 1.0, "Fraction of the joint acceleration limits, in (0, 1].", valid=Range(0, 1, min_open=True)),
    InputPort("link_padding", PortType.FLOAT, 0.0, "Clearance (m) required from world objects.", valid=Range(0, 0.5, "m")),
    InputPort("max_iterations", PortType.UINT, 5000, "RRT-Connect iterations before the search gives up.", valid=Range(1, 10**7)),
    InputPort("trajectory_sampling_rate", PortType.UINT, 100, "Points per second of the trajectory (Hz).", valid=Range(1, 10000, "Hz")),
)
SEED_PORT = InputPort("seed", PortType.INT, 0, "Seed of the planner's random generator: the same seed plans the same path.", valid=Range(-(2**31), 2**31 - 1))


def motion_from_ports(node: Behavior) -> Motion:
    """The ``Motion`` of a node with ``MOTION_PORTS`` (and ``seed`` when it has one)."""
    has_seed = any(p.name == "seed" for p in node.ports)
    return Motion(node.get_input("link_padding"), node.get_input("velocity_scale_factor"), node.get_input("acceleration_scale_factor"),
                  float(node.get_input("trajectory_sampling_rate")), int(node.get_input("max_iterations")),
                  int(node.get_input("seed")) if has_seed else 0)


class PlanToJointGoal(ReadsRobotState, Behavior):
    """MoveIt Pro's PlanToJointGoal."""

    needs_world = True
    description: ClassVar[str] = (
        "Plan a collision-free joint trajectory from the current state to a joint goal (a straight joint move when it is free, "
        "RRT-Connect around obstacles otherwise), timed within the limits; it does not move the robot: ExecuteTrajectory does."
    )
    ports = (
        InputPort("joint_goal", PortType.JOINT_STATE, description="The goal: positions of the group's joints (other joints are ignored)."),
        GROUP_PORT,
        *MOTION_PORTS,
        SEED_PORT,
        InputPort("orientation_constraint", PortType.ANY, "", "Not supported here: a goal with one fails."),
        OutputPort("joint_trajectory_msg", PortType.JOINT_TRAJECTORY, "The planned trajectory.", default="{joint_trajectory_msg}"),
    )

    def update(self) -> Status:
        safety = safety_for(self.context.scene, self.get_input("planning_group_name"))
        if self.is_port_set("orientation_constraint"):
            return self.fail("orientation_constraint is not supported: the planner here plans without path constraints")
        try:
            motion = motion_from_ports(self)
            goal = group_goal(self.get_input("joint_goal"), safety.group_joints, "joint_goal")
            start = self.state().positions(safety.group_joints)
            samples = plan_free_motion(safety, start, goal, motion, safety.snapshot())
        except (PlanningError, FrameError) as err:
            return self.fail(str(err))
        self.set_output("joint_trajectory_msg", trajectory_msg(samples, safety.group_joints))
        self.feedback_message = f"{len(samples)} points, {samples.duration_s:.2f} s"
        return Status.SUCCESS


class ComputeInverseKinematics(ReadsRobotState, Behavior):
    """MoveIt Pro's ComputeInverseKinematics, for one tip."""

    needs_world = True
    description: ClassVar[str] = (
        "Solve IK for a tip pose: joint positions of the group, collision-free in the planning scene, "
        "nearest the current state first; FAILURE when the pose is unreachable or every solution collides."
    )
    ports = (
        InputPort("target_poses", PortType.POSE_STAMPED_LIST, description="One pose (any known frame) for the one tip."),
        InputPort("tip_links", PortType.STRING_LIST, "grasp_link", "The robot frame placed at the pose (one; this cell's tool frame is tcp).", names=Names(NameKind.FRAME)),
        GROUP_PORT,
        InputPort("ik_timeout_s", PortType.FLOAT, 0.01, "Accepted for compatibility: the solver tries the current state and 32 random seeds.", valid=Range(0, 60, "s")),
        InputPort("link_padding", PortType.FLOAT, 0.0, "Clearance (m) the solution keeps from world objects.", valid=Range(0, 0.5, "m")),
        InputPort("planning_scene_msg", PortType.ANY, "", "Accepted for compatibility; the run's current planning scene is used."),
        OutputPort("solution", PortType.JOINT_STATE, "The solution: a JointState of the group's joints.", default="{solution}"),
    )

    def update(self) -> Status:
        scene = self.context.scene
        safety = safety_for(scene, self.get_input("planning_group_name"))
        tips = [t for t in self.get_input("tip_links") if t]
        poses = self.get_input("target_poses")
        if len(tips) != 1:
            raise SetupError(f"tip_links must name exactly one frame here, got {len(tips)} ({', '.join(tips) or 'none'})")
        if len(poses) != 1:
            return self.fail(f"target_poses must hold one pose for the one tip, got {len(poses)}")
        try:
            state = self.state()
            target = pose_in_world(scene, poses[0], state)
            start = state.positions(safety.group_joints)
            q = collision_free_ik(safety, target, tips[0], start, self.get_input("link_padding"), safety.snapshot())[0]
        except (PlanningError, FrameError) as err:
            return self.fail(str(err))
        msg = JointState(name=list(safety.group_joints), position=[float(v) for v in q])
        msg.header.stamp = time_msg(self.context.clock.now())
        self.set_output("solution", msg)
        return Status.SUCCESS


NODES = (PlanToJointGoal, ComputeInverseKinematics)

"""MoveIt Pro's MoveIt Task Constructor (MTC) behaviors: a task built stage by stage on the
blackboard, planned as a whole, approved, executed.

A task (``MTCTask``) is an immutable blackboard value: ``InitializeMTCTask`` writes an empty one
and every ``SetupMTC*`` node writes it back with one stage more. ``PlanMTCTask`` plans the stages
in order from the robot's current state into a solution (``MTCSolution``): a list of steps, each a
timed motion of one stage or a collision-rule change; it fails naming the stage without a
solution. ``ExecuteMTCSolution`` runs the steps: a rule change is applied to the planning scene,
a motion goes through ExecuteTrajectory's checks and to the trajectory controller.

How the stages chain (MTC's propagation, as MoveIt Pro's Objectives use it):

- ``SetupMTCCurrentState`` starts the task at the robot's current state (it must come first).
- ``SetupMTCPlanToPose``, ``SetupMTCPlanToRobotState``: a free-space motion from the state
  before to an IK solution of the pose / to the joint state.
- ``SetupMTCMoveAlongFrameAxis``: a straight Cartesian motion of ``hand_frame`` along an axis.
- ``SetupMTCSetCollisionRule``: allows (or forbids) contact for the stages after it.
- ``SetupMTCConnectWithProRRT`` then ``SetupMTCBatchPoseIK`` (a generator): the IK solutions
  of the poses are the states to reach; the stages between the two are planned backwards from
  each solution (an approach along an axis ends at the solution), and the connect stage plans a
  free-space motion from the state before it to the start of that chain. The first solution for
  which all of this plans is taken. The stages after the generator continue from its solution.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from std_srvs.srv import SetBool

from runtime.tree.behavior import Behavior, RunContext, Status
from runtime.tree.resources import Resource
from runtime.errors import SetupError
from runtime.tree.ports import InOutPort, InputPort, NameKind, Names, OutputPort, PortType, Range
from runtime.motion.scene import ANY, SceneSnapshot
from runtime.motion.scene.kinematics import frame_pose

from .action_goal import Goal, GoalState
from runtime.motion.samples import Samples
from .trajectory_goal import PlanningError
from .planning import (
    CHECK_STEP_RAD, GROUP_PORT, MOTION_PORTS, SEED_PORT, Motion, collision_free_ik, group_goal, motion_from_ports, plan_free_motion,
    safety_for,
)
from .poses import FrameError, ReadsRobotState, frame_in_world, known_frames, pose_in_world
from .safety import MotionSafety
from .trajectories import ExecuteTrajectory, START_TOLERANCE_RAD, check_motion, plan_cartesian
from .waiting import when_ready

OCTOMAP = "<octomap>"
CARTESIAN_STEP_M = 0.01
"""Distance between IK points of a MoveAlongFrameAxis line."""
CARTESIAN_JOINT_STEP_RAD = 0.1
"""Largest joint step between two IK points of such a line; more is a jump."""


# -- the task and its stages (blackboard values) ------------------------------------------------
@dataclass(frozen=True)
class Stage:
    """One stage: the node that set it up (``label``: its XML id, its name if given, its line)
    and its parameters, read from the node's ports when it ran."""

    kind: str
    """The XML id of the node that set it up (``SetupMTCPlanToPose``...)."""
    label: str
    params: dict[str, Any] = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class MTCTask:
    task_id: str
    timeout_s: float
    """Seconds PlanMTCTask may plan the whole task; negative: no limit (each search still stops
    after its own planning timeout)."""
    stages: tuple[Stage, ...] = ()

    def with_stage(self, stage: Stage) -> MTCTask:
        return replace(self, stages=self.stages + (stage,))


@dataclass(frozen=True)
class SolutionStep:
    """A timed motion of one stage's group (``samples``, ``joints``), or a collision-rule change
    (``rule``: object, links, allowed) applied to the planning scene when execution reaches it."""

    stage: str
    group: str = ""
    joints: tuple[str, ...] = ()
    samples: Samples | None = None
    rule: tuple[str, str, bool] | None = None


@dataclass(frozen=True)
class MTCSolution:
    task_id: str
    steps: tuple[SolutionStep, ...]

    @property
    def motions(self) -> list[SolutionStep]:
        return [s for s in self.steps if s.samples is not None]


def as_task(value: Any, port: str = "task") -> MTCTask:
    if not isinstance(value, MTCTask):
        raise SetupError(f"port '{port}' expects an MTC task (from InitializeMTCTask), got {type(value).__name__}")
    return value


def as_solution(value: Any, port: str = "solution") -> MTCSolution:
    if not isinstance(value, MTCSolution):
        raise SetupError(f"port '{port}' expects an MTC solution (from PlanMTCTask), got {type(value).__name__}")
    return value


# -- planning a task (pure, but for the scene it reads) -------------------------------------------
class StageFailure(PlanningError):
    """A stage has no solution: FAILURE naming it."""


@dataclass
class TaskPlanner:
    """Plans a task's stages in order (see the module's docstring). ``start`` is the group's
    current state, ``scene`` the planning scene; ``deadline`` a ``time.monotonic()`` or None."""

    scene: Any
    task: MTCTask
    start: dict[str, float]
    deadline: float | None = None

    def plan(self) -> MTCSolution:
        stages = self.task.stages
        if not stages:
            raise SetupError(f"task '{self.task.task_id}' has no stages: add SetupMTCCurrentState and the motions to plan")
        if stages[0].kind not in ("SetupMTCCurrentState", "SetupMTCFromSolution"):
            raise SetupError(f"task '{self.task.task_id}' must start with SetupMTCCurrentState, got {stages[0].label} first")
        snapshots = self._snapshots()
        steps: list[SolutionStep] = []
        state: dict[str, float] = dict(self.start)
        i = 0
        while i < len(stages):
            stage = stages[i]
            if stage.kind == "SetupMTCCurrentState":
                if i != 0:
                    raise SetupError(f"{stage.label}: SetupMTCCurrentState must be the task's first stage")
            elif stage.kind == "SetupMTCFromSolution":
                steps += self._replay(stage, state, snapshots[i])
                state = self._end_of(steps, state)
            elif stage.kind == "SetupMTCSetCollisionRule":
                steps.append(SolutionStep(stage.label, rule=stage.params["rule"]))
            elif stage.kind == "SetupMTCConnectWithProRRT":
                j = next((k for k in range(i + 1, len(stages)) if stages[k].kind == "SetupMTCBatchPoseIK"), None)
                if j is None:
                    raise SetupError(f"{stage.label}: a connect stage needs a SetupMTCBatchPoseIK after it to connect to")
                connected, state = self._connect(i, j, state, snapshots)
                steps += connected
                i = j
            elif stage.kind == "SetupMTCBatchPoseIK":
                raise SetupError(f"{stage.label}: SetupMTCBatchPoseIK needs a SetupMTCConnectWithProRRT before it (nothing connects to its solutions)")
            else:
                step = self._forward(stage, state, snapshots[i])
                steps.append(step)
                state = self._end_of([step], state)
            i += 1
        return MTCSolution(self.task.task_id, tuple(steps))

    # -- pieces
    def _snapshots(self) -> list[SceneSnapshot]:
        """The collision rules each stage is planned with: the scene's now, changed by every
        SetupMTCSetCollisionRule before the stage."""
        snapshot = self.scene.snapshot()
        out = []
        for stage in self.task.stages:
            out.append(snapshot)
            if stage.kind == "SetupMTCSetCollisionRule":
                obj, links, allowed = stage.params["rule"]
                snapshot = self.scene.snapshot_with_rule(snapshot, obj, links, allowed)
        return out

    def _motion(self, stage: Stage, seed_offset: int = 0) -> Motion:
        motion: Motion = stage.params["motion"]
        timeout = motion.timeout_s
        if self.deadline is not None:
            left = self.deadline - time.monotonic()
            if left <= 0:
                raise StageFailure(f"{stage.label}: the task's planning timeout ran out before this stage "
                                   f"({self.task.timeout_s:g} s, InitializeMTCTask timeout)")
            timeout = min(timeout, left)
        return replace(motion, timeout_s=timeout, seed=motion.seed + seed_offset)

    def _safety(self, stage: Stage) -> MotionSafety:
        return safety_for(self.scene, stage.params["group"])

    def _row(self, safety: MotionSafety, state: dict[str, float], stage: Stage) -> NDArray[np.float64]:
        missing = [j for j in safety.group_joints if j not in state]
        if missing:
            raise SetupError(f"{stage.label}: the state before this stage lacks joints {', '.join(missing)}")
        return np.array([state[j] for j in safety.group_joints])

    @staticmethod
    def _end_of(steps: list[SolutionStep], state: dict[str, float]) -> dict[str, float]:
        out = dict(state)
        for step in steps:
            if step.samples is not None:
                out.update(zip(step.joints, (float(v) for v in step.samples.positions[-1])))
        return out

    def _forward(self, stage: Stage, state: dict[str, float], snapshot: SceneSnapshot) -> SolutionStep:
        safety = self._safety(stage)
        start = self._row(safety, state, stage)
        try:
            if stage.kind == "SetupMTCPlanToPose":
                goal = collision_free_ik(safety, stage.params["target"], stage.params["ik_frame"], start,
                                         stage.params["motion"].padding_m, snapshot)[0]
                samples = plan_free_motion(safety, start, goal, self._motion(stage), snapshot)
            elif stage.kind == "SetupMTCPlanToRobotState":
                goal = group_goal(stage.params["joint_state"], safety.group_joints, "joint_state")
                samples = plan_free_motion(safety, start, goal, self._motion(stage), snapshot)
            elif stage.kind == "SetupMTCMoveAlongFrameAxis":
                samples = along_axis(safety, start, stage, snapshot, backward=False)
            else:
                raise SetupError(f"{stage.label}: {stage.kind} cannot be planned here")
        except StageFailure:
            raise
        except PlanningError as err:
            raise StageFailure(f"{stage.label}: {err}") from None
        return SolutionStep(stage.label, stage.params["group"], safety.group_joints, samples)

    def _connect(self, i: int, j: int, state: dict[str, float], snapshots: list[SceneSnapshot]) -> tuple[list[SolutionStep], dict[str, float]]:
        """Stages ``i`` (connect) .. ``j`` (BatchPoseIK): the steps and the state after them."""
        stages = self.task.stages
        connect, generator = stages[i], stages[j]
        safety = self._safety(connect)
        start = self._row(safety, state, connect)
        chain = stages[i + 1:j]
        for stage in chain:
            if stage.kind not in ("SetupMTCMoveAlongFrameAxis", "SetupMTCSetCollisionRule"):
                raise SetupError(f"{stage.label}: between SetupMTCConnectWithProRRT and SetupMTCBatchPoseIK only "
                                 "SetupMTCMoveAlongFrameAxis and SetupMTCSetCollisionRule can be planned (backwards from the IK solution)")
        try:
            candidates = batch_ik(self._safety(generator), generator, start, snapshots[j])
        except PlanningError as err:
            raise StageFailure(f"{generator.label}: {err}") from None
        last: StageFailure | None = None
        for n, goal in enumerate(candidates):
            try:
                backward: list[SolutionStep] = []
                chain_start = goal
                for k in range(j - 1, i, -1):  # backwards from the IK solution
                    stage = stages[k]
                    if stage.kind == "SetupMTCSetCollisionRule":
                        backward.append(SolutionStep(stage.label, rule=stage.params["rule"]))
                        continue
                    stage_safety = self._safety(stage)
                    try:
                        samples = along_axis(stage_safety, chain_start, stage, snapshots[k], backward=True)
                    except PlanningError as err:
                        raise StageFailure(f"{stage.label}: {err}") from None
                    backward.append(SolutionStep(stage.label, stage.params["group"], stage_safety.group_joints, samples))
                    chain_start = samples.positions[0]
                try:
                    samples = plan_free_motion(safety, start, chain_start, self._motion(connect, n), snapshots[i])
                except StageFailure:
                    raise
                except PlanningError as err:
                    raise StageFailure(f"{connect.label}: {err}") from None
                steps = [SolutionStep(connect.label, connect.params["group"], safety.group_joints, samples)] + backward[::-1]
                after = dict(state)
                after.update(zip(safety.group_joints, (float(v) for v in goal)))
                return steps, after
            except StageFailure as err:
                last = err
        assert last is not None
        if len(candidates) > 1:
            raise StageFailure(f"{last} (and for the other {len(candidates) - 1} IK solutions of {generator.label})")
        raise last

    def _replay(self, stage: Stage, state: dict[str, float], snapshot: SceneSnapshot) -> list[SolutionStep]:
        solution: MTCSolution = stage.params["solution"]
        motions = solution.motions
        if motions:
            first = motions[0]
            assert first.samples is not None  # a motion
            gap = np.abs(first.samples.positions[0] - np.array([state.get(j, np.nan) for j in first.joints]))
            if not np.all(np.isfinite(gap)) or float(gap.max()) > START_TOLERANCE_RAD:
                raise StageFailure(f"{stage.label}: the solution starts {float(np.nanmax(gap)):.3f} rad away from the "
                                   f"arm's current position (at most {START_TOLERANCE_RAD} rad)")
        for step in motions:
            assert step.samples is not None  # a motion
            problem = check_motion(safety_for(self.scene, step.group), step.samples, 0.0, CHECK_STEP_RAD, snapshot)
            if problem:
                raise StageFailure(f"{stage.label}: the solution's step '{step.stage}' {problem}")
        return list(solution.steps)


def along_axis(safety: MotionSafety, q: NDArray[np.float64], stage: Stage, snapshot: SceneSnapshot, backward: bool) -> Samples:
    """MoveAlongFrameAxis: ``hand_frame`` along the axis (in ``axis_frame`` at ``q``) for
    ``max_distance`` m, else ``min_distance``; ``backward``: the motion that ends at ``q``."""
    p = stage.params
    robot = safety.scene.robot
    hand = frame_pose(robot, safety.layout(q), p["hand_frame"])
    axis_rotation = np.eye(3) if p["axis_frame"] in ("world", "universe") else (
        frame_pose(robot, safety.layout(q), p["axis_frame"])[:3, :3] if robot.has_frame(p["axis_frame"]) else p["axis_frame_pose"][:3, :3])
    direction = axis_rotation @ p["axis"]
    motion: Motion = p["motion"]
    padding = 0.0
    if p["ignore_environment_collisions"]:
        snapshot = SceneSnapshot(tuple(sorted(set(snapshot.rules) | {(ANY, ANY, True)})), snapshot.attachments)
    problem: PlanningError | None = None
    for distance in dict.fromkeys((p["max_distance"], p["min_distance"])):
        target = hand.copy()
        target[:3, 3] += (-1.0 if backward else 1.0) * distance * direction
        try:
            plan = plan_cartesian(safety, q, [target], p["hand_frame"], np.eye(4), False, CARTESIAN_STEP_M, CARTESIAN_JOINT_STEP_RAD,
                                  motion.velocity_scale, motion.acceleration_scale, motion.rate_hz)
            found = check_motion(safety, plan.samples, padding, CARTESIAN_JOINT_STEP_RAD / 2, snapshot)
            if found:
                raise PlanningError(f"the {distance:g} m move {found}")
        except PlanningError as err:
            problem = problem or err
            continue
        samples = plan.samples
        if backward:  # the same motion played in reverse: it ends at q
            end = samples.times[-1]
            samples = Samples(end - samples.times[::-1], samples.positions[::-1].copy(), -samples.velocities[::-1], samples.accelerations[::-1].copy())
        return samples
    assert problem is not None
    raise problem


def batch_ik(safety: MotionSafety, stage: Stage, seed_q: NDArray[np.float64], snapshot: SceneSnapshot) -> list[NDArray[np.float64]]:
    """SetupMTCBatchPoseIK's candidates: up to ``max_ik_solutions`` collision-free solutions
    for each target pose, in the poses' order."""
    out: list[NDArray[np.float64]] = []
    problems = []
    for k, target in enumerate(stage.params["targets"]):
        try:
            out += collision_free_ik(safety, target, stage.params["ik_frame"], seed_q, 0.0, snapshot, stage.params["max_solutions"], rng_seed=k)
        except PlanningError as err:
            problems.append(f"pose {k}: {err}")
    if not out:
        raise PlanningError("; ".join(problems) if problems else "no target poses")
    return out


# -- nodes ---------------------------------------------------------------------------------------
TASK_PORT = InOutPort("task", PortType.ANY, "{mtc_task}", "The MTC task (from InitializeMTCTask); this node adds its stage to it.")


class SetsUpStage(ReadsRobotState, Behavior):
    """A SetupMTC* node: reads the task, adds its stage, writes the task back."""

    needs_world = True

    def stage_params(self) -> dict[str, Any]:
        raise NotImplementedError

    def update(self) -> Status:
        task = as_task(self.get_input("task"))
        try:
            params = self.stage_params()
        except (PlanningError, FrameError) as err:
            return self.fail(str(err))
        label = self.xml_id if self.name in ("", self.xml_id) else f"{self.xml_id} '{self.name}'"
        if self.location is not None:
            label += f" ({self.location})"
        self.set_output("task", task.with_stage(Stage(self.xml_id, label, params)))
        return Status.SUCCESS

    def group_params(self) -> dict[str, Any]:
        group = self.get_input("planning_group_name")
        safety_for(self.context.scene, group)  # an unknown group is an ERROR here, where it is written
        return {"group": group}


class InitializeMTCTask(Behavior):
    """MoveIt Pro's InitializeMTCTask."""

    description: ClassVar[str] = "Write a new, empty MTC task to the blackboard; SetupMTC* nodes add its stages, PlanMTCTask plans it."
    ports = (
        InputPort("task_id", PortType.STRING, "", "The task's name (in messages)."),
        InputPort("timeout", PortType.FLOAT, -1.0, "Seconds PlanMTCTask may plan the whole task; -1: no limit.", valid=Range(-1, 3600, "s")),
        OutputPort("task", PortType.ANY, "The new task.", default="{mtc_task}"),
    )

    def update(self) -> Status:
        timeout = self.get_input("timeout")
        self.set_output("task", MTCTask(self.get_input("task_id") or "task", float(timeout) if timeout > 0 else -1.0))
        return Status.SUCCESS


class SetupMTCCurrentState(SetsUpStage):
    """MoveIt Pro's SetupMTCCurrentState."""

    description: ClassVar[str] = "Start the task at the robot's current state (read when PlanMTCTask runs); the task's first stage."
    ports = (TASK_PORT,)

    def stage_params(self) -> dict[str, Any]:
        return {}


class SetupMTCPlanToPose(SetsUpStage):
    """MoveIt Pro's SetupMTCPlanToPose."""

    description: ClassVar[str] = "Add a stage: a collision-free free-space motion to a pose of ik_frame (IK, then RRT-Connect)."
    ports = (
        TASK_PORT,
        InputPort("target_pose", PortType.POSE_STAMPED, description="Where ik_frame goes (any known frame, resolved now)."),
        InputPort("ik_frame", PortType.STRING, "grasp_link", "The robot frame placed at target_pose (this cell's tool frame is tcp).", names=Names(NameKind.FRAME)),
        GROUP_PORT,
        *MOTION_PORTS,
        InputPort("monitored_stage", PortType.STRING, "current state", "Accepted for compatibility: the stage plans from the state before it."),
        InputPort("orientation_constraint", PortType.ANY, "", "Not supported here: a stage with one fails."),
    )

    def stage_params(self) -> dict[str, Any]:
        if self.is_port_set("orientation_constraint"):
            raise PlanningError("orientation_constraint is not supported: the planner here plans without path constraints")
        frame = self.get_input("ik_frame")
        if not self.context.scene.robot.has_frame(frame):
            raise SetupError(f"unknown ik_frame '{frame}' (known: {known_frames(self.context.scene)})")
        target = pose_in_world(self.context.scene, self.get_input("target_pose"), self.state())
        return {**self.group_params(), "ik_frame": frame, "target": target, "motion": motion_from_ports(self)}


class SetupMTCPlanToRobotState(SetsUpStage):
    """MoveIt Pro's SetupMTCPlanToRobotState."""

    description: ClassVar[str] = "Add a stage: a collision-free free-space motion to a joint state (RRT-Connect when the straight move is blocked)."
    ports = (
        TASK_PORT,
        InputPort("joint_state", PortType.JOINT_STATE, description="The goal: positions of the group's joints."),
        GROUP_PORT,
        *MOTION_PORTS,
        SEED_PORT,
    )

    def stage_params(self) -> dict[str, Any]:
        return {**self.group_params(), "joint_state": self.get_input("joint_state"), "motion": motion_from_ports(self)}


class SetupMTCConnectWithProRRT(SetsUpStage):
    """MoveIt Pro's SetupMTCConnectWithProRRT."""

    description: ClassVar[str] = (
        "Add a stage: a free-space motion (RRT-Connect) from the state before it to the start of the stages after it, "
        "up to and including a SetupMTCBatchPoseIK whose IK solutions they reach."
    )
    ports = (TASK_PORT, GROUP_PORT, *MOTION_PORTS, SEED_PORT)

    def stage_params(self) -> dict[str, Any]:
        return {**self.group_params(), "motion": motion_from_ports(self)}


class SetupMTCMoveAlongFrameAxis(SetsUpStage):
    """MoveIt Pro's SetupMTCMoveAlongFrameAxis."""

    description: ClassVar[str] = (
        "Add a stage: hand_frame moves in a straight line along an axis of axis_frame, max_distance (or at least min_distance); "
        "before a SetupMTCBatchPoseIK it is the approach that ends at the IK solution."
    )
    ports = (
        TASK_PORT,
        InputPort("hand_frame", PortType.STRING, "grasp_link", "The robot frame that moves (this cell's tool frame is tcp).", names=Names(NameKind.FRAME)),
        InputPort("axis_frame", PortType.STRING, "world", "The frame the axis is expressed in: world, a robot frame or a scene object.", names=Names(NameKind.FRAME)),
        InputPort("axis_x", PortType.FLOAT, 0.0, "Axis x component (the axis is normalised).", valid=Range(-1000, 1000)),
        InputPort("axis_y", PortType.FLOAT, 0.0, "Axis y component (the axis is normalised).", valid=Range(-1000, 1000)),
        InputPort("axis_z", PortType.FLOAT, 1.0, "Axis z component (the axis is normalised).", valid=Range(-1000, 1000)),
        InputPort("max_distance", PortType.FLOAT, 0.1, "Distance (m) to move.", valid=Range(0, 10, "m", min_open=True)),
        InputPort("min_distance", PortType.FLOAT, 0.1, "Shortest acceptable distance (m) when max_distance does not plan.", valid=Range(0, 10, "m", min_open=True)),
        InputPort("velocity_scale", PortType.FLOAT, 1.0, "Fraction of the joint velocity limits, in (0, 1].", valid=Range(0, 1, min_open=True)),
        InputPort("acceleration_scale", PortType.FLOAT, 1.0, "Fraction of the joint acceleration limits, in (0, 1].", valid=Range(0, 1, min_open=True)),
        GROUP_PORT,
        InputPort("ignore_environment_collisions", PortType.BOOL, False, "true: contact with world objects is allowed during this move."),
    )

    def stage_params(self) -> dict[str, Any]:
        axis = np.array([self.get_input("axis_x"), self.get_input("axis_y"), self.get_input("axis_z")], dtype=float)
        norm = float(np.linalg.norm(axis))
        if not norm > 1e-9:
            raise SetupError("axis_x, axis_y and axis_z are all zero: give the axis to move along")
        scene = self.context.scene
        hand, axis_frame = self.get_input("hand_frame"), self.get_input("axis_frame")
        if not scene.robot.has_frame(hand):
            raise SetupError(f"unknown hand_frame '{hand}' (known: {known_frames(scene)})")
        robot_frame = scene.robot.has_frame(axis_frame) or axis_frame in ("world", "universe")
        params = {**self.group_params(), "hand_frame": hand, "axis_frame": axis_frame, "axis": axis / norm,
                  "max_distance": float(self.get_input("max_distance")), "min_distance": float(self.get_input("min_distance")),
                  "ignore_environment_collisions": bool(self.get_input("ignore_environment_collisions")),
                  "motion": Motion(0.0, self.get_input("velocity_scale"), self.get_input("acceleration_scale"))}
        if not robot_frame:
            params["axis_frame_pose"] = frame_in_world(scene, axis_frame, self.state())  # a scene object: SetupError when unknown
        return params


class SetupMTCSetCollisionRule(SetsUpStage):
    """MoveIt Pro's SetupMTCSetCollisionRule."""

    description: ClassVar[str] = "Add a stage: allow (or forbid) contact between a robot link or group and a world object for the stages after it."
    ports = (
        TASK_PORT,
        InputPort("name_a", PortType.STRING, description="A robot link or group, or a world object."),
        InputPort("name_b", PortType.STRING, description="A world object, or a robot link or group."),
        InputPort("allow_collision", PortType.BOOL, True, "true: contact is allowed; false: forbidden again."),
    )

    def stage_params(self) -> dict[str, Any]:
        scene = self.context.scene
        a, b = self.get_input("name_a"), self.get_input("name_b")
        if OCTOMAP in (a, b):
            raise SetupError(f"'{OCTOMAP}' is not in this planning scene: it has no octomap (point clouds are not kept here)")

        def is_robot(name: str) -> bool:
            return name in scene.robot.link_names or name in scene.robot.group_names or name in {x.name for x in scene.attachments}

        def is_object(name: str) -> bool:
            return name == ANY or name in scene.objects

        if is_robot(a) and is_object(b):
            obj, links = b, a
        elif is_robot(b) and is_object(a):
            obj, links = a, b
        else:
            raise SetupError(f"name_a '{a}' and name_b '{b}' must be a robot link or group and a world object "
                             f"(groups: {', '.join(scene.robot.group_names)}; objects: {', '.join(sorted(scene.objects)) or 'none'})")
        return {"rule": (obj, links, bool(self.get_input("allow_collision")))}


class SetupMTCBatchPoseIK(SetsUpStage):
    """MoveIt Pro's SetupMTCBatchPoseIK."""

    description: ClassVar[str] = (
        "Add a stage: collision-free IK solutions of end_effector_link at each target pose, the states a preceding "
        "SetupMTCConnectWithProRRT connects to (the first that plans is taken)."
    )
    ports = (
        TASK_PORT,
        InputPort("target_poses", PortType.POSE_STAMPED_LIST, description="Candidate poses (any known frame, resolved now), tried in order."),
        InputPort("ik_group", PortType.STRING, "manipulator", "SRDF joint group solved for.", names=Names(NameKind.JOINT_GROUP)),
        InputPort("end_effector_link", PortType.STRING, "grasp_link", "The robot frame placed at the poses (this cell's tool frame is tcp).", names=Names(NameKind.FRAME)),
        InputPort("end_effector_group", PortType.STRING, "moveit_ee", "Accepted for compatibility (the group's own links are checked)."),
        InputPort("ik_timeout_s", PortType.FLOAT, 0.01, "Accepted for compatibility: each pose tries the current state and 32 random seeds.", valid=Range(0, 60, "s")),
        InputPort("max_ik_solutions", PortType.UINT, 4, "Most distinct solutions kept per pose.", valid=Range(1, 1000)),
        InputPort("monitored_stage", PortType.STRING, "current state", "Accepted for compatibility."),
    )

    def stage_params(self) -> dict[str, Any]:
        scene = self.context.scene
        group = self.get_input("ik_group")
        safety_for(scene, group)
        frame = self.get_input("end_effector_link")
        if not scene.robot.has_frame(frame):
            raise SetupError(f"unknown end_effector_link '{frame}' (known: {known_frames(scene)})")
        poses = self.get_input("target_poses")
        if not poses:
            raise PlanningError("target_poses is empty: give at least one pose")
        state = self.state()
        return {"group": group, "ik_frame": frame, "targets": [pose_in_world(scene, p, state) for p in poses],
                "max_solutions": int(self.get_input("max_ik_solutions"))}


class SetupMTCFromSolution(SetsUpStage):
    """MoveIt Pro's SetupMTCFromSolution."""

    description: ClassVar[str] = "Add a stage that replays a solution planned before (checked again when PlanMTCTask runs)."
    ports = (TASK_PORT, InputPort("solution", PortType.ANY, description="An MTC solution (from PlanMTCTask or SplitMTCSolution)."))

    def stage_params(self) -> dict[str, Any]:
        return {"solution": as_solution(self.get_input("solution"))}


class PlanMTCTask(ReadsRobotState, Behavior):
    """MoveIt Pro's PlanMTCTask."""

    needs_world = True
    description: ClassVar[str] = (
        "Plan an MTC task's stages from the robot's current state; FAILURE naming the stage without a solution, "
        "ERROR for a task set up wrong (no stages, unknown group or frame)."
    )
    ports = (
        InputPort("task", PortType.ANY, "{mtc_task}", "The task to plan."),
        InputPort("max_solutions", PortType.UINT, 1, "Accepted for compatibility: the first solution found is kept.", valid=Range(1, 1000)),
        OutputPort("solution", PortType.ANY, "The solution (for ExecuteMTCSolution).", default="{mtc_solution}"),
    )

    def update(self) -> Status:
        task = as_task(self.get_input("task"))
        scene = self.context.scene
        try:
            state = self.state().subscription.latest
            if state is None:
                raise FrameError(f"no joint states on '{self.state().topic}' yet")
            deadline = time.monotonic() + task.timeout_s if task.timeout_s > 0 else None
            solution = TaskPlanner(scene, task, dict(zip(state.name, state.position)), deadline).plan()
        except (PlanningError, FrameError) as err:
            return self.fail(f"task '{task.task_id}': {err}")
        self.set_output("solution", solution)
        motions = solution.motions
        self.feedback_message = f"{len(solution.steps)} steps, {sum(m.samples.duration_s for m in motions if m.samples is not None):.2f} s of motion"
        return Status.SUCCESS


class SplitMTCSolution(Behavior):
    """MoveIt Pro's SplitMTCSolution."""

    description: ClassVar[str] = "Split a solution's steps at index: steps [0, index) and [index, end)."
    ports = (
        InputPort("solution_in", PortType.ANY, description="The MTC solution to split."),
        InputPort("index", PortType.UINT, description="The first step of the second part.", valid=Range(0, 100000)),
        OutputPort("solution_out_1", PortType.ANY, "Steps before index."),
        OutputPort("solution_out_2", PortType.ANY, "Steps from index on."),
    )

    def update(self) -> Status:
        solution = as_solution(self.get_input("solution_in"), "solution_in")
        index = int(self.get_input("index"))
        if index > len(solution.steps):
            raise SetupError(f"index {index} is past the solution's {len(solution.steps)} steps "
                             f"({', '.join(s.stage for s in solution.steps) or 'none'})")
        self.set_output("solution_out_1", MTCSolution(solution.task_id, solution.steps[:index]))
        self.set_output("solution_out_2", MTCSolution(solution.task_id, solution.steps[index:]))
        return Status.SUCCESS


APPROVAL_SERVICE = "/approve_mtc_solution"


@dataclass
class ApprovalDesk:
    """One approval service of a run: served from the first wait until the run ends (so an
    answer always goes back to its caller), handing each answer to the node waiting, if any."""

    waiting: str | None = None
    """The label of the node waiting for an answer, or None."""
    answer: tuple[bool, str] | None = None

    def take(self, request: Any) -> Any:
        if self.waiting is None:
            return SetBool.Response(success=False, message="no MTC solution is waiting for approval")
        self.answer = (bool(request.data), "")
        return SetBool.Response(success=True, message="approved" if request.data else "rejected")


APPROVAL_DESKS: Resource[dict[str, ApprovalDesk]] = Resource("mtc.approval_desks")
"""The run's approval desks by the service each serves."""


def approval_desk(context: RunContext, service: str) -> ApprovalDesk:
    """The run's desk serving ``service`` (created and served on first use)."""
    desks = context.resources.setdefault(APPROVAL_DESKS, dict)
    if service not in desks:
        desk = ApprovalDesk()
        context.bus.create_service(service, SetBool, desk.take)
        desks[service] = desk
    return desks[service]


class WaitForMTCSolutionApproval(Behavior):
    """MoveIt Pro's WaitForMTCSolutionApproval, without a user interface."""

    description: ClassVar[str] = (
        "Approve a solution: at once when run headless (the default); with require_approval, wait for a call of "
        "approval_service (std_srvs/SetBool: true approves, false rejects)."
    )
    ports = (
        InputPort("solution", PortType.ANY, "{mtc_solution}", "The solution to approve."),
        InputPort("cartesian_path_links", PortType.STRING_LIST, "", "Accepted for compatibility (no user interface draws paths here)."),
        InputPort("require_approval", PortType.BOOL, False, "Not in MoveIt Pro. true: wait for a call of approval_service."),
        InputPort("approval_service", PortType.STRING, APPROVAL_SERVICE,
                  "Not in MoveIt Pro. The std_srvs/SetBool service, served from the first wait to the end of the run."),
    )

    def initialise(self) -> None:
        self.desk: ApprovalDesk | None = None

    def update(self) -> Status:
        solution = as_solution(self.get_input("solution"))
        if not self.get_input("require_approval"):
            self.feedback_message = f"approved: no user interface (headless), {len(solution.steps)} steps"
            return Status.SUCCESS
        service = self.get_input("approval_service")
        if self.desk is None:
            self.desk = approval_desk(self.context, service)
            if self.desk.waiting is not None:
                raise SetupError(f"'{service}' is already waiting for {self.desk.waiting}: give each "
                                 "WaitForMTCSolutionApproval that may wait at the same time its own approval_service")
            self.desk.waiting, self.desk.answer = self.xml_id if self.name == self.xml_id else self.name, None
            self.feedback_message = f"waiting for approval on '{service}'"
        if self.desk.answer is None:
            return Status.RUNNING
        approved, _ = self.desk.answer
        self._leave()
        if approved:
            return Status.SUCCESS
        return self.fail(f"the solution was rejected through '{service}'")

    def _leave(self) -> None:
        if self.desk is not None:
            self.desk.waiting, self.desk.answer = None, None
            self.desk = None

    def terminate(self, new_status: Status) -> None:
        if getattr(self, "desk", None) is not None:
            self._leave()


class ExecuteMTCSolution(ExecuteTrajectory):
    """MoveIt Pro's ExecuteMTCSolution, on the admittance controller or a stock JTC."""

    description: ClassVar[str] = (
        "Execute an MTC solution step by step: a collision-rule change is applied to the planning scene, a motion is checked "
        "as ExecuteTrajectory checks it (starts where the arm is, within the limits, collision-free) and sent to the trajectory "
        "controller; fails naming the step when a check fails or the controller aborts."
    )
    ports = (InputPort("solution", PortType.ANY, "{mtc_solution}", "The solution (from PlanMTCTask)."),) + tuple(
        p for p in ExecuteTrajectory.ports if p.name not in ("joint_trajectory_msg", "planning_group_name"))

    def initialise(self) -> None:
        super().initialise()
        self.steps: list[SolutionStep] = []
        self.index = 0

    def update(self) -> Status:
        if self.error:
            return self.fail(self.error)
        if self.index == 0 and not self.steps:
            self.steps = list(as_solution(self.get_input("solution")).steps)
        while True:
            if self.goal.state is GoalState.NONE:
                if self.index >= len(self.steps):
                    return Status.SUCCESS
                ready = when_ready(self.controller.ready, self.deadline, f"controller action '{self.action}'")
                if ready is not True:
                    return self.fail(ready) if isinstance(ready, str) else Status.RUNNING
                step = self.steps[self.index]
                self.index += 1
                if step.rule is not None:
                    obj, links, allowed = step.rule
                    (self.context.scene.allow if allowed else self.context.scene.disallow)(obj, links)
                    continue
                assert step.samples is not None  # not a rule: a motion
                try:
                    goal = self.checked_goal(safety_for(self.context.scene, step.group), step.samples)
                except (PlanningError, FrameError) as err:
                    return self.fail(f"step {self.index - 1} '{step.stage}': {err}")
                if goal is None:
                    continue
                self.goal = Goal.send(self.controller.client, goal)
            status = self.follow_goal(f"motion of step {self.index - 1} '{self.steps[self.index - 1].stage}'")
            if status is not Status.SUCCESS:
                return status
            self.goal = Goal()


NODES = (
    InitializeMTCTask, SetupMTCCurrentState, SetupMTCPlanToPose, SetupMTCPlanToRobotState, SetupMTCConnectWithProRRT,
    SetupMTCMoveAlongFrameAxis, SetupMTCSetCollisionRule, SetupMTCBatchPoseIK, SetupMTCFromSolution, PlanMTCTask,
    SplitMTCSolution, WaitForMTCSolutionApproval, ExecuteMTCSolution,
)

"""MoveToJointState and MoveToWaypoint: a time-optimal point-to-point motion within the limits.

The motion is planned with ruckig (jerk-limited, time-optimal, from rest to rest), sampled,
checked against the planning scene before anything moves, and sent to the trajectory controller
as one goal: the admittance controller's or a stock JTC's, whichever type is served under
``controller_action_name`` (``controller_link``). When something in the planning scene blocks
that motion, it is planned around instead (``behaviors.planning.plan_free_motion``: RRT-Connect,
shortcut, timed within the limits and at rest at each corner).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from ruckig import InputParameter, Result, Ruckig, Trajectory
from sensor_msgs.msg import JointState

from runtime.io.bus import Subscription
from runtime.tree.behavior import Status
from runtime.tree.resources import WAYPOINTS
from runtime.tree.ports import InputPort, NameKind, Names, PortType, Range

from runtime.motion.scene import JointLimits, SceneSnapshot
from runtime.errors import SetupError
from .action_goal import Goal, GoalState
from .controller_link import CONTROLLER_ACTION_TYPES, ControllerLink, GoalTolerances, trajectory_goal
from .planning import Motion, plan_free_motion
from runtime.motion.samples import Samples
from .safety import SafetyError, make_safety
from .trajectory_goal import DEFAULT_CONTROLLER, GOAL_TIME_TOLERANCE_S, NO_MOTION_S, PlanningError, SendsTrajectoryGoal, trajectory_msg
from .waiting import Deadline, when_ready

SAMPLE_PERIOD = 0.02
JERK_PER_ACCELERATION = 10.0  # 1/s: max jerk = 10 x max acceleration


def plan_point_to_point(
    start: NDArray[np.float64],
    goal: NDArray[np.float64],
    limits: JointLimits,
    velocity_scale: float,
    acceleration_scale: float,
    period: float = SAMPLE_PERIOD,
) -> Samples:
    """Rest-to-rest, time-optimal, jerk-limited motion from ``start`` to ``goal``, sampled;
    one point at time 0 when the arm is already at ``goal`` (see ``NO_MOTION_S``)."""
    for name, value in (("velocity_scaling", velocity_scale), ("acceleration_scaling", acceleration_scale)):
        if not 0 < value <= 1:
            raise PlanningError(f"{name} must be in (0, 1], got {value}")
    outside = limits.check(goal)
    if outside is not None:
        raise PlanningError(f"target outside the joint limits: {outside.what}")
    dof = len(start)
    otg, inp, trajectory = Ruckig(dof), InputParameter(dof), Trajectory(dof)
    inp.current_position, inp.target_position = list(start), list(goal)
    inp.max_velocity = list(limits.max_velocity * velocity_scale)
    inp.max_acceleration = list(limits.max_acceleration * acceleration_scale)
    inp.max_jerk = list(limits.max_acceleration * acceleration_scale * JERK_PER_ACCELERATION)
    result = otg.calculate(inp, trajectory)
    if result not in (Result.Working, Result.Finished):
        raise PlanningError(f"ruckig could not plan the motion: {result}")
    if trajectory.duration < NO_MOTION_S:
        return Samples.at_rest(goal)
    count = max(2, int(np.ceil(trajectory.duration / period)) + 1)
    times = np.linspace(0.0, trajectory.duration, count)
    states = [trajectory.at_time(t) for t in times]
    p, v, a = (np.array([s[i] for s in states]) for i in range(3))
    return Samples(times, p, v, a)


class _MoveToJoints(SendsTrajectoryGoal):
    """Shared lifecycle: resolve the target, plan, check, send, wait for the controller."""

    needs_world = True
    joint_states: Subscription | None = None
    """The start state's subscription, from ``initialise`` until the node stops."""
    common_ports = (
        InputPort("joint_group_name", PortType.STRING, "manipulator", "SRDF joint group to move.", names=Names(NameKind.JOINT_GROUP)),
        InputPort("velocity_scaling_factor", PortType.FLOAT, 0.5, "Fraction of the joint velocity limits, in (0, 1].", valid=Range(0.0, 1.0, min_open=True)),
        InputPort("acceleration_scaling_factor", PortType.FLOAT, 0.5, "Fraction of the joint acceleration limits, in (0, 1].", valid=Range(0.0, 1.0, min_open=True)),
        InputPort("link_padding", PortType.FLOAT, 0.01, "Meters of clearance required from world objects.", valid=Range(0.0, 0.5, "m")),
        InputPort("path_tolerance", PortType.FLOAT, 0.1, "Radians of tracking error before the controller aborts.", valid=Range(0.0, math.pi, "rad", min_open=True)),
        InputPort("controller_action_name", PortType.STRING, DEFAULT_CONTROLLER,
                  "The trajectory controller's action: FollowJointTrajectoryWithAdmittance or control_msgs FollowJointTrajectory.",
                  names=Names(NameKind.ACTION, CONTROLLER_ACTION_TYPES)),
        InputPort("joint_states_topic", PortType.STRING, "/joint_states", "Where the start state is read."),
        InputPort("timeout", PortType.FLOAT, 5.0, "Seconds to wait for the controller and the joint states.", valid=Range(0.0, 3600.0, "s", min_open=True)),
    )

    def target(self, joints: tuple[str, ...]) -> NDArray[np.float64]:
        raise NotImplementedError

    def initialise(self) -> None:
        self.goal = Goal()
        try:
            self.safety = make_safety(self.context.scene, self.get_input("joint_group_name"), None)
        except SafetyError as err:  # e.g. an unknown joint group: ERROR, never retried
            raise SetupError(str(err)) from None
        bus = self.context.bus
        self.action = self.get_input("controller_action_name")
        self.controller = ControllerLink(bus, self.action, self.location, self.xml_id)
        self.topic = self.get_input("joint_states_topic")
        self.joint_states = bus.create_subscription(self.topic, JointState)
        self.deadline = Deadline(self, self.get_input("timeout"))

    def update(self) -> Status:
        if self.goal.state is GoalState.NONE:
            return self._plan_and_send()
        return self.follow_goal("motion")

    def _plan_and_send(self) -> Status:
        ready = when_ready(self.controller.ready, self.deadline, f"controller action '{self.action}'")
        if ready is not True:
            return self.fail(ready) if isinstance(ready, str) else Status.RUNNING
        assert self.joint_states is not None  # subscribed in setup
        state = self.joint_states.latest
        if state is None:
            if self.deadline.expired:
                return self.fail(f"no joint states on '{self.topic}' after {self.deadline.seconds:g} s")
            return Status.RUNNING
        joints = self.safety.group_joints
        by_name = dict(zip(state.name, state.position))
        missing = [j for j in joints if j not in by_name]
        if missing:
            return self.fail(f"joint states on '{self.topic}' lack {', '.join(missing)}")
        start = np.array([by_name[j] for j in joints])
        try:
            goal = self.target(joints)
            samples = plan_point_to_point(
                start, goal, self.safety.limits, self.get_input("velocity_scaling_factor"), self.get_input("acceleration_scaling_factor")
            )
        except (PlanningError, SafetyError) as err:
            return self.fail(str(err))
        if samples.duration_s == 0:
            return Status.SUCCESS
        outside = self.safety.first_limit_violation(samples)
        if outside is not None:
            return self.fail(f"the motion is outside the {outside.family}s: {outside}")
        snapshot = self.safety.snapshot()
        collision = self.safety.first_collision(snapshot, samples, self.get_input("link_padding"))
        if collision is not None:
            try:
                samples = self._around(start, goal, snapshot)
            except PlanningError as err:
                return self.fail(f"the motion would collide: {collision}; no way around it: {err}")
        assert self.controller.kind is not None  # the controller is ready
        goal = trajectory_goal(self.controller.kind, trajectory_msg(samples, joints),
                               GoalTolerances(self.get_input("path_tolerance"), GOAL_TIME_TOLERANCE_S))
        self.goal = Goal.send(self.controller.client, goal)
        return Status.RUNNING

    def _around(self, start: NDArray[np.float64], goal: NDArray[np.float64], snapshot: SceneSnapshot) -> Samples:
        """The motion planned around what blocks the straight one (``behaviors.planning``)."""
        seed = int(self.get_input("seed")) if any(p.name == "seed" for p in self.ports) else 0
        motion = Motion(self.get_input("link_padding"), self.get_input("velocity_scaling_factor"),
                        self.get_input("acceleration_scaling_factor"), 1.0 / SAMPLE_PERIOD, seed=seed)
        return plan_free_motion(self.safety, start, goal, motion, snapshot)

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID:
            self.goal = self.goal.cancel()
        if self.joint_states is not None:
            self.context.bus.destroy_subscription(self.joint_states)
            self.joint_states = None


class MoveToJointState(_MoveToJoints):
    """Move the joint group to explicit joint positions, time-optimally within the limits."""

    description = "Move a joint group to the given joint positions (within the limits; planned around obstacles that block the straight motion)."
    ports = (InputPort("joint_positions", PortType.FLOAT_LIST, description="Target positions in the group's joint order (rad).", valid=Range(-4 * math.pi, 4 * math.pi, "rad")),) + _MoveToJoints.common_ports

    def target(self, joints: tuple[str, ...]) -> NDArray[np.float64]:
        values = np.asarray(self.get_input("joint_positions"), dtype=float)
        if len(values) != len(joints):
            raise PlanningError(f"joint_positions has {len(values)} values but group '{self.get_input('joint_group_name')}' has {len(joints)} joints ({', '.join(joints)})")
        return values


class MoveToWaypoint(_MoveToJoints):
    """Move the joint group to a named waypoint of the cell (e.g. ``Home``)."""

    description = "Move a joint group to a named waypoint (e.g. Home) from the cell's waypoints file, planned around obstacles that block the straight motion."
    ports = (
        InputPort("waypoint_name", PortType.STRING, description="Name of the waypoint, e.g. Home.", names=Names(NameKind.WAYPOINT)),
        InputPort("seed", PortType.INT, 0, "Seed of the planner that plans around obstacles blocking the straight motion: the same seed plans the same path.",
                  valid=Range(-(2**31), 2**31 - 1)),
    ) + _MoveToJoints.common_ports

    def target(self, joints: tuple[str, ...]) -> NDArray[np.float64]:
        self.get_input("seed")  # read so that a seed that is not an integer fails here, naming the port
        waypoints = self.context.resources.get(WAYPOINTS) or {}
        name = self.get_input("waypoint_name")
        if name not in waypoints:
            known = ", ".join(sorted(waypoints)) or "none are defined"
            raise SetupError(f"unknown waypoint '{name}' (known: {known})")
        positions = waypoints[name]
        missing = [j for j in joints if j not in positions]
        if missing:
            raise PlanningError(f"waypoint '{name}' does not set {', '.join(missing)}")
        return np.array([positions[j] for j in joints], dtype=float)


NODES = (MoveToJointState, MoveToWaypoint)

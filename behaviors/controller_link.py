"""The link from a behavior to the trajectory controller: which action type it serves, and goals for it.

Two controller interfaces, chosen by the type served under the configured action name (read from
the bus: the ROS graph over ``RosBus``, the in-process servers otherwise):

- ``ControllerKind.ADMITTANCE``: MoveIt Pro's ``joint_trajectory_admittance_controller``
  (``moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance``): path tolerance,
  goal time tolerance and the force-torque abort travel in the goal; a goal's stamp is its seam.
- ``ControllerKind.JTC``: ros2_controllers' ``joint_trajectory_controller`` and its variants (UR's
  scaled JTC) (``control_msgs/action/FollowJointTrajectory``): the path tolerance travels as one
  ``JointTolerance`` per joint, the goal time tolerance as a Duration; there is no force-torque
  abort in the goal (watch a wrench topic instead). A new goal merges into the playing one at its
  stamp (``allow_trajectory_replacement``, ros2_controllers #2419) or replaces it from its stamp.

A name served with any other type is a setup mistake: ``ControllerTypeError`` (an ERROR, exit 2)
names the expected and the found types.

``jtc_stream_points`` builds the points of a streamed chunk's JTC goal so that both replacement
modes play what was planned (see its docstring).
"""
from __future__ import annotations

import enum
import importlib
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray
from control_msgs.msg import JointTolerance
from trajectory_msgs.msg import JointTrajectory

from runtime.errors import ObjectiveError, SourceLocation
from runtime.io.timestamps import duration_msg

from runtime.motion.samples import Samples

TIME_EPS_S = 1e-6
"""Seconds within which two sample times are the same instant (stamps travel as nanoseconds)."""
END_VELOCITY_EPS = 1e-6
"""rad/s: a last point's velocity below this is sent as exactly zero (JTC refuses a non-zero one)."""


class ControllerKind(enum.Enum):
    """The trajectory action a controller serves, by its ROS type name."""

    ADMITTANCE = "moveit_pro_controllers_msgs/action/FollowJointTrajectoryWithAdmittance"
    JTC = "control_msgs/action/FollowJointTrajectory"

    @property
    def action_type(self) -> Any:
        """The generated action class (untyped): ``Goal``, ``Result``, ``Feedback``."""
        package, _, name = self.value.split("/")
        return getattr(importlib.import_module(f"{package}.action"), name)

    @property
    def label(self) -> str:
        return {ControllerKind.ADMITTANCE: "MoveIt Pro's admittance controller",
                ControllerKind.JTC: "ros2_controllers' joint_trajectory_controller"}[self]


CONTROLLER_ACTION_TYPES = tuple(kind.action_type for kind in ControllerKind)
"""The action types a trajectory controller may serve (for a port's ``Names``)."""


class ControllerTypeError(ObjectiveError):
    """The configured controller action is served with a type no behavior here can drive."""


def controller_kind(name: str, served_types: list[str]) -> ControllerKind | None:
    """The kind of controller serving action ``name`` with ``served_types`` (None: not served
    yet). Raises ControllerTypeError (without a location) for any other type."""
    for kind in ControllerKind:
        if kind.value in served_types:
            return kind
    if not served_types:
        return None
    expected = " or ".join(f"{k.value} ({k.label})" for k in ControllerKind)
    raise ControllerTypeError(f"controller action '{name}' is served with type {', '.join(served_types)}; expected {expected}")


class ControllerLink:
    """The action client of the trajectory controller under ``name``, of the type the bus finds
    served there. ``ready()`` is polled until the server is up; ``kind`` and ``client`` are set then.
    ``location`` and ``node`` place a ControllerTypeError in the Objective."""

    def __init__(self, bus: Any, name: str, location: SourceLocation | None = None, node: str | None = None) -> None:
        self.bus, self.name = bus, name
        self.location, self.node = location, node
        self.kind: ControllerKind | None = None
        self.client: Any = None

    def ready(self) -> bool:
        """Whether the controller's action server is up (raises ControllerTypeError on a wrong type)."""
        if self.client is None:
            try:
                kind = controller_kind(self.name, self.bus.action_types(self.name))
            except ControllerTypeError as err:
                raise ControllerTypeError(err.what, self.location, self.node) from None
            if kind is None:
                return False
            self.kind, self.client = kind, self.bus.create_action_client(self.name, kind.action_type)
        ready: bool = self.client.server_is_ready()
        return ready


def controller_topic(action_name: str, topic: str) -> str:
    """The controller's topic ``topic`` beside its action ``action_name`` (both in the
    controller's namespace): ``/jtc/follow_joint_trajectory`` -> ``/jtc/<topic>``."""
    return action_name.rstrip("/").rsplit("/", 1)[0] + "/" + topic


def reference_position(state: Any, joints: Sequence[str]) -> NDArray[np.float64] | None:
    """The reference a ``JointTrajectoryControllerState`` says the controller commands to
    ``joints`` (in that order); None without a state or when it lacks one of them."""
    if state is None or len(state.reference.positions) != len(state.joint_names):
        return None
    names = list(state.joint_names)
    if any(j not in names for j in joints):
        return None
    return np.array([state.reference.positions[names.index(j)] for j in joints], dtype=float)


@dataclass(frozen=True)
class GoalTolerances:
    """What a trajectory goal carries besides the trajectory."""

    path_rad: float
    """Position deviation along the path that aborts the goal (0: none)."""
    goal_time_s: float
    """Seconds after the last point's time allowed to settle."""
    force_torque_threshold: tuple[float, ...] = ()
    """Fx Fy Fz Tx Ty Tz abort limits (admittance only; empty: none)."""


def trajectory_goal(kind: ControllerKind, trajectory: JointTrajectory, tolerances: GoalTolerances) -> Any:
    """The goal that plays ``trajectory`` on a controller of ``kind``."""
    goal = kind.action_type.Goal()
    if kind is ControllerKind.ADMITTANCE:
        goal.joint_trajectory = trajectory
        goal.path_tolerance = float(tolerances.path_rad)
        goal.goal_time_tolerance = float(tolerances.goal_time_s)
        goal.absolute_force_torque_threshold = [float(v) for v in tolerances.force_torque_threshold]
        return goal
    goal.trajectory = trajectory
    if tolerances.path_rad > 0:
        goal.path_tolerance = [JointTolerance(name=name, position=float(tolerances.path_rad)) for name in trajectory.joint_names]
    goal.goal_time_tolerance = duration_msg(tolerances.goal_time_s)
    return goal


def goal_trajectory(goal: Any) -> JointTrajectory:
    """The trajectory of a goal of either kind."""
    return goal.joint_trajectory if hasattr(goal, "joint_trajectory") else goal.trajectory


@dataclass(frozen=True)
class JtcStreamGoal:
    """The points of a streamed chunk's JTC goal: ``samples`` (every field given) stamped at
    ``stamp_s``, except that the point at ``seam_index`` goes without accelerations."""

    stamp_s: float
    samples: Samples
    seam_index: int


def jtc_stream_points(previous: Samples | None, new: Samples, lands_s: float) -> JtcStreamGoal:
    """The points of a streamed chunk's goal for a JTC: ``new`` (samples from the seam on) behind
    the part of the motion already sent (``previous``, the samples of the goal the controller
    plays) that lies between the goal's landing and the seam.

    The goal starts where the arm will be when it lands: at the first sample of ``previous`` at or
    after ``lands_s`` (the latest instant the goal is expected at the controller), stamped there.
    - A JTC that merges at arrival keeps playing its trajectory up to that stamp, then these
      points: the same knots as before up to the seam, the new ones after it: it passes through
      every checked sample, the seam at the planned step.
    - A JTC that replaces at arrival plays these points from its stamp, interpolating from its
      state at arrival to the first one when the goal lands before it (a short bridge between two
      states of the planned motion), and plays the knots from where the clock is when it lands
      later: a continuous motion either way.
    JTC joins two points by a quintic when both carry accelerations, by a cubic when they carry
    velocities only. A seam is continuous in position and velocity but not in acceleration, so the
    seam's point goes without accelerations: the cubics on either side of it take the step, where
    one quintic knot would force a single acceleration on both sides and overshoot the checked
    ones next to it. (The playing motion's sample at the seam is used when there is one: a window's
    end always is.) Without a previous motion, or when the seam is no later than the landing, the
    goal is ``new`` from its seam. The last point's velocities below ``END_VELOCITY_EPS`` are made
    exactly zero, as JTC requires of a goal's end.
    """
    seam_s = float(new.times[0])
    parts = [new]
    if previous is not None:
        keep = (previous.times >= lands_s - TIME_EPS_S) & (previous.times <= seam_s + TIME_EPS_S)
        if keep.any():
            lead = _rows(previous, keep)
            parts = [lead, _rows(new, new.times > lead.times[-1] + TIME_EPS_S)]
    points = Samples(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("times", "positions", "velocities", "accelerations")))
    if np.all(np.abs(points.velocities[-1]) < END_VELOCITY_EPS):
        velocities = points.velocities.copy()
        velocities[-1] = 0.0
        points = Samples(points.times, points.positions, velocities, points.accelerations)
    seam_index = int(np.argmin(np.abs(points.times - seam_s)))
    return JtcStreamGoal(float(points.times[0]), points, seam_index)


def _rows(samples: Samples, keep: NDArray[np.bool_]) -> Samples:
    return Samples(samples.times[keep], samples.positions[keep], samples.velocities[keep], samples.accelerations[keep])

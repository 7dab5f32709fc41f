"""MoveIt Pro's velocity-force nodes: PublishVelocityForceCommand and ForceExceedsThreshold.

MoveIt Pro's velocity-force controller takes a Cartesian twist and wrench. The cell's
``velocity_force_controller`` takes joint velocities (``<namespace>/commands``,
``std_msgs/Float64MultiArray``), so ``PublishVelocityForceCommand`` turns the twist into joint
velocities itself: the twist is read in the tip frame (``tcp``), rotated into world axes, and
mapped through the damped pseudo-inverse of the tip's Jacobian at the current joint state, at
every publication. Force control is not available on the cell: a command that asks for it
fails. ``ForceExceedsThreshold`` watches the wrist force-torque topic.
"""
from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from geometry_msgs.msg import WrenchStamped
from std_msgs.msg import Float64MultiArray

from runtime.tree.behavior import Behavior, Status
from runtime.tree.decorators import elapsed
from runtime.tree.ports import InputPort, NameKind, Names, PortType, Range
from runtime.motion.scene.kinematics import frame_jacobian, frame_pose

from .poses import FrameError, ReadsRobotState
from .safety import SafetyError, make_safety
from .waiting import Deadline, release_subscription

DAMPING = 1e-4
"""Damping of the pseudo-inverse (keeps joint speeds bounded near singularities)."""
PUBLISHER_WAIT_S = 5.0


# -- pure math -------------------------------------------------------------------------------------
def joint_velocities(jacobian_world: NDArray[np.float64], tip_rotation: NDArray[np.float64], twist_tip: NDArray[np.float64], damping: float = DAMPING) -> NDArray[np.float64]:
    """Joint velocities that move the tip with ``twist_tip`` (vx vy vz wx wy wz in the tip's axes):
    ``J^T (J J^T + d I)^-1 [R v; R w]`` with ``J`` in world axes at the tip."""
    twist_world = np.concatenate([tip_rotation @ twist_tip[:3], tip_rotation @ twist_tip[3:]])
    j = np.asarray(jacobian_world)
    return j.T @ np.linalg.solve(j @ j.T + damping * np.eye(j.shape[0]), twist_world)


def masked_twist(linear: Any, angular: Any, axes: list[int]) -> NDArray[np.float64]:
    """The twist's six components with the axes not velocity-controlled set to zero."""
    values = np.array([linear.x, linear.y, linear.z, angular.x, angular.y, angular.z], dtype=float)
    masked: NDArray[np.float64] = values * (np.asarray(axes, dtype=float) != 0)
    return masked


def check_axes(velocity_axes: list[int], force_axes: list[int]) -> str | None:
    for name, axes in (("velocity_controlled_axes", velocity_axes), ("force_controlled_axes", force_axes)):
        if len(axes) != 6 or any(a not in (0, 1) for a in axes):
            return f"{name} needs six 0/1 values (x;y;z;rx;ry;rz), got {axes}"
    if any(force_axes):
        return (
            "force control is not available: the cell's velocity_force_controller takes joint velocities only "
            "(set force_controlled_axes to 0;0;0;0;0;0)"
        )
    return None


def commands_topic(topic: str) -> str:
    """``/velocity_force_controller/command`` -> ``/velocity_force_controller/commands``."""
    namespace = topic.rstrip("/").rsplit("/", 1)[0] if topic.rstrip("/").count("/") > 1 else topic.rstrip("/")
    return f"{namespace}/commands"


# -- nodes ------------------------------------------------------------------------------------------
class PublishVelocityForceCommand(ReadsRobotState, Behavior):
    """MoveIt Pro's PublishVelocityForceCommand, for the cell's joint-velocity controller."""

    needs_world = True
    description: ClassVar[str] = (
        "Move the tip (tcp) with a Cartesian twist, in its own axes, through the velocity_force_controller (joint velocities "
        "through the tip's Jacobian), publishing at publish_rate; RUNNING until halted, then the arm stops. "
        "Force control is not available on this cell."
    )
    ports = (
        InputPort("twist", PortType.TWIST, description="Velocity of the tip, in its own axes (e.g. from UnpackTwistStampedMessage)."),
        InputPort("wrench", PortType.WRENCH, description="Wrench to apply; must be accompanied by force_controlled_axes 0 here."),
        InputPort("velocity_controlled_axes", PortType.INT_LIST, "1;1;1;1;1;1", "Twist components used (x;y;z;rx;ry;rz, 1 = used).", valid=Range(0, 1)),
        InputPort("force_controlled_axes", PortType.INT_LIST, "0;0;0;0;0;0", "Force-controlled axes; any 1 fails: not on this cell.", valid=Range(0, 1)),
        InputPort("wrench_gain", PortType.FLOAT, 0.0, "Accepted for compatibility (no force control here).", valid=Range(0, 1000)),
        InputPort("publish_rate", PortType.UINT, 50, "Commands per second of run-clock time (Hz).", valid=Range(1, 1000, "Hz")),
        InputPort("velocity_force_controller_command_topic", PortType.STRING, "/velocity_force_controller/command",
                  "The controller's command topic; joint velocities go to its namespace's /commands."),
        InputPort("planning_group_name", PortType.STRING, "manipulator", "SRDF joint group the controller moves.", names=Names(NameKind.JOINT_GROUP)),
        InputPort("tip_link", PortType.STRING, "tcp", "Robot frame the twist moves (not in MoveIt Pro, where the controller sets it).", names=Names(NameKind.FRAME)),
    )

    def initialise(self) -> None:
        self.last_s: float | None = None
        self.publisher = self.context.bus.create_publisher(
            commands_topic(self.get_input("velocity_force_controller_command_topic")), Float64MultiArray
        )

    def update(self) -> Status:
        problem = check_axes(self.get_input("velocity_controlled_axes"), self.get_input("force_controlled_axes"))
        if problem:
            return self.fail(problem)
        rate = self.get_input("publish_rate")
        if rate <= 0:
            return self.fail(f"publish_rate must be positive, got {rate}")
        now = self.context.clock.now()
        if self.last_s is not None and not elapsed(self.last_s, now, 1000.0 / rate):
            return Status.RUNNING
        try:
            velocities = self._joint_velocities()
        except (SafetyError, FrameError, ValueError) as err:
            return self.fail(str(err))
        self.publisher.publish(Float64MultiArray(data=velocities.tolist()))
        self.last_s = now
        return Status.RUNNING

    def _joint_velocities(self) -> NDArray[np.float64]:
        scene = self.context.scene
        safety = make_safety(scene, self.get_input("planning_group_name"), None)
        tip = self.get_input("tip_link")
        if not scene.robot.has_frame(tip):
            raise ValueError(f"tip_link '{tip}' is not a frame of the robot model")
        q_full = safety.layout(self.state().positions(safety.group_joints))
        twist = self.get_input("twist")
        rotation = frame_pose(scene.robot, q_full, tip)[:3, :3]
        jacobian = frame_jacobian(scene.robot, q_full, tip, safety.group_joints)
        return joint_velocities(jacobian, rotation, masked_twist(twist.linear, twist.angular, self.get_input("velocity_controlled_axes")))

    def terminate(self, new_status: Status) -> None:
        publisher = getattr(self, "publisher", None)
        if new_status is Status.INVALID and publisher is not None:  # halted: stop now, not at the command timeout
            publisher.publish(Float64MultiArray(data=[0.0] * len(self.context.scene.robot.group(self.get_input("planning_group_name")).joints)))


class ForceExceedsThreshold(Behavior):
    """MoveIt Pro's ForceExceedsThreshold."""

    needs_world = True
    description: ClassVar[str] = (
        "RUNNING until the force magnitude on a WrenchStamped topic exceeds force_threshold in "
        "minimum_consecutive_wrench_values readings in a row (the newest one each tick), then SUCCESS; "
        "FAILURE if the topic has no publisher within 5 s."
    )
    ports = (
        InputPort("wrench_topic_name", PortType.STRING, "/force_torque_sensor_broadcaster/wrench", "The force-torque topic."),
        InputPort("force_threshold", PortType.FLOAT, description="Force magnitude (N) to exceed.", valid=Range(0, 100000, "N")),
        InputPort("minimum_consecutive_wrench_values", PortType.UINT, 1, "Readings in a row above the threshold.", valid=Range(0, 100000)),
        InputPort("hand_frame_name", PortType.STRING, "tcp", "Accepted for compatibility: a force's magnitude is the same in every frame."),
        InputPort("wrench_frame_name", PortType.STRING, "world", "Accepted for compatibility (see hand_frame_name)."),
    )

    def initialise(self) -> None:
        self.topic = self.get_input("wrench_topic_name")
        self.over = 0
        self.last: WrenchStamped | None = None
        self.subscription = self.context.bus.create_subscription(self.topic, WrenchStamped, reliable=False)
        self.deadline = Deadline(self, PUBLISHER_WAIT_S)

    def update(self) -> Status:
        if not self.subscription.has_publishers():
            if self.deadline.expired:
                return self.fail(f"no publisher on '{self.topic}' after {PUBLISHER_WAIT_S:g} s")
            return Status.RUNNING
        msg = self.subscription.latest  # one reading per tick: the newest one
        if msg is not None and msg is not self.last:
            self.last = msg
            f = msg.wrench.force
            above = math.sqrt(f.x * f.x + f.y * f.y + f.z * f.z) > self.get_input("force_threshold")
            self.over = self.over + 1 if above else 0
        needed = max(1, self.get_input("minimum_consecutive_wrench_values"))
        if self.over >= needed:
            self.feedback_message = f"force above {self.get_input('force_threshold'):g} N in {self.over} readings in a row"
            return Status.SUCCESS
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        release_subscription(self)


NODES = (PublishVelocityForceCommand, ForceExceedsThreshold)

"""The policy session's bus links: the GetActionChunk client (``PolicyLink``), the controller action
(``ControllerLink``), the gripper action (``GripperStream``), the joint states, the controller's
state, the cameras and the wrench watch.

``connect`` builds them for a config's names, once: again only when a name read from the
blackboard changed between runs (the old subscriptions are destroyed then). What the robot reports
through them is read here too: where a motion from rest starts, and the gripper's position.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray
from control_msgs.action import GripperCommand
from control_msgs.msg import JointTrajectoryControllerState
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import Image, JointState

from runtime.tree.behavior import Behavior

from . import config as cfg
from ..controller_link import ControllerLink, controller_topic, reference_position
from ..wrench_watch import WrenchWatch
from .gripper import GripperStream
from .observation import robot_state
from .policy_link import PolicyLink


@dataclass
class SessionLinks:
    """The bus links of the names in ``names`` (``connect``)."""

    names: tuple[object, ...]
    policy: PolicyLink
    controller: ControllerLink
    gripper: GripperStream | None
    joint_states: Any
    controller_state: Any
    """The controller's ``~/controller_state`` (where a motion from rest starts)."""
    cameras: list[Any] = field(default_factory=list)
    wrench: WrenchWatch | None = None

    def reset(self) -> None:
        """Forget the previous run (the request in flight, gripper targets, a force-torque crossing)."""
        for part in (self.policy, self.gripper, self.wrench):
            if part is not None:
                part.reset()

    def close(self, bus: Any) -> None:
        """Destroy the subscriptions (the links are built again for other names)."""
        for sub in [self.joint_states, self.controller_state, *self.cameras, self.wrench.subscription if self.wrench else None]:
            if sub is not None:
                bus.destroy_subscription(sub)

    def rest_position(self, joints: Sequence[str], joint_states_topic: str) -> NDArray[np.float64]:
        """Where a motion from rest starts: the reference the controller commands, when it
        publishes its state (``~/controller_state``) for ``joints``, else the measured positions
        of the newest joint state. A JTC that interpolates from its desired state (as a JTC that
        plays streamed goals should) starts the next trajectory from its reference; at rest under
        load the measured state lies off it (a few mrad in the simulated cell), and a first point
        there would be a jump the controller plays within one control step."""
        reference = reference_position(self.controller_state.latest, joints)
        if reference is not None:
            return reference
        state = robot_state(self.joint_states.latest, joints, None, joint_states_topic)
        return np.asarray(state.position, dtype=float)

    def gripper_position(self, joint: str) -> float | None:
        """``joint``'s position in the newest joint state (None without a joint or a state)."""
        state = self.joint_states.latest
        if not joint or state is None or joint not in state.name:
            return None
        return float(state.position[list(state.name).index(joint)])


def link_names(config: cfg.PolicyRunConfig) -> tuple[object, ...]:
    """The names (and the thresholds) the links are built for."""
    return (config.policy_service_name, config.controller_action_name,
            config.gripper_command_action_name if config.has_gripper else None,
            config.joint_states_topic, config.image_topics, config.wrench_topic, config.absolute_force_torque_threshold)


def connect(node: Behavior, config: cfg.PolicyRunConfig, links: SessionLinks | None) -> SessionLinks:
    """The links for ``config``'s names: ``links`` when they were built for the same names, else
    new ones (``links``' subscriptions destroyed)."""
    names = link_names(config)
    if links is not None and links.names == names:
        return links
    bus = node.context.bus
    if links is not None:
        links.close(bus)
    return SessionLinks(
        names=names,
        policy=PolicyLink(bus.create_client(config.policy_service_name, GetActionChunk)),
        controller=ControllerLink(bus, config.controller_action_name, node.location, node.xml_id),
        gripper=(GripperStream(bus.create_action_client(config.gripper_command_action_name, GripperCommand),
                               config.gripper_command_action_name) if config.has_gripper else None),
        joint_states=bus.create_subscription(config.joint_states_topic, JointState, reliable=True),
        controller_state=bus.create_subscription(controller_topic(config.controller_action_name, "controller_state"),
                                                 JointTrajectoryControllerState, reliable=False),
        # Best-effort matches both kinds of camera driver (most publish best-effort sensor-data QoS).
        cameras=[bus.create_subscription(t, Image, reliable=False) for t in config.image_topics],
        wrench=WrenchWatch(bus, config.wrench_topic, config.absolute_force_torque_threshold) if config.wrench_topic else None,
    )

"""ExecutePolicy's ports (the guide's table, with its defaults), the run's config read from them
(``read_config``) and their validation."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray

from control_msgs.action import FollowJointTrajectory, GripperCommand
from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import Image, JointState

from runtime.tree.behavior import Behavior
from runtime.tree.ports import Direction, InputPort, NameKind, Names, OutputPort, PortType, Range
from runtime.errors import ObjectiveError
from runtime.motion.scene import EnvelopeOverrides

DEFAULT_CONTROLLER_ACTION = "/joint_trajectory_admittance_controller/follow_joint_trajectory"

PORTS = (
    InputPort("policy_service_name", PortType.STRING, description="GetActionChunk service that serves the policy.",
              names=Names(NameKind.SERVICE, GetActionChunk)),
    InputPort("joint_group_name", PortType.STRING, description="SRDF joint group the policy commands; must resolve to one tip.",
              names=Names(NameKind.JOINT_GROUP)),
    InputPort("total_action_steps", PortType.UINT, description="Run length in policy steps; the motion lasts total_action_steps * dt seconds.", valid=Range(1, 1_000_000)),
    InputPort("prompt", PortType.STRING, "", "Task instruction passed to the policy."),
    InputPort("dt", PortType.FLOAT, 0.05, "Seconds per policy step: 1 / the rate the policy was trained at.", valid=Range(0.001, 10.0, "s")),
    InputPort("committed_action_steps", PortType.UINT, 32, "Steps executed from each chunk before the next takes over; smaller than the policy's chunk size, and (committed - 1) * dt should cover twice the latency.", valid=Range(1, 10_000)),
    InputPort("num_interpolation_points", PortType.UINT, 100, "Densified points per chunk: the sampling density of the limit and collision checks.", valid=Range(2, 10_000)),
    InputPort("link_padding", PortType.FLOAT, 0.01, "Meters of padding around the robot for the world collision check (self-collision is unpadded).", valid=Range(0.0, 0.5, "m")),
    InputPort("policy_tracking_weight", PortType.FLOAT, 300.0, "How closely the smoothing spline follows the chunk: lower if the motion oscillates, higher if it lags.", valid=Range(0.0, 1e6, min_open=True)),
    InputPort("policy_uses_real_time_chunking", PortType.BOOL, False, "Send the unexecuted tail of the previous policy_action_chunk for RTC guidance."),
    InputPort("policy_call_timeout", PortType.FLOAT, 3.0, "Seconds allowed for one service round trip, warmup included.", valid=Range(0.0, 600.0, "s", min_open=True)),
    InputPort("goal_path_tolerance", PortType.FLOAT, 0.01, "Radians of deviation the controller accepts along the path and where chunks join.", valid=Range(0.0, math.pi, "rad")),
    InputPort("absolute_force_torque_threshold", PortType.FLOAT_LIST, "45;45;45;10;10;10", "Per-axis abort limits Fx;Fy;Fz;Tx;Ty;Tz (N, Nm).", valid=Range(0.0, 100_000.0, "N or Nm", min_open=True),
              length=6),
    InputPort("controller_action_name", PortType.STRING, DEFAULT_CONTROLLER_ACTION, "The trajectory controller's action: the admittance controller's FollowJointTrajectoryWithAdmittance or a joint_trajectory_controller's control_msgs FollowJointTrajectory (the type served decides).",
              names=Names(NameKind.ACTION, (FollowJointTrajectoryWithAdmittance, FollowJointTrajectory))),
    InputPort("gripper_command_action_name", PortType.STRING, "", "GripperCommand action; set together with gripper_joint_name.",
              names=Names(NameKind.ACTION, GripperCommand)),
    InputPort("gripper_joint_name", PortType.STRING, "", "Single-DOF gripper joint appended to the observation and streamed from the chunk.",
              names=Names(NameKind.JOINT)),
    InputPort("guidance_horizon", PortType.UINT, 0, "RTC: steps past the frozen prefix kept close to the previous chunk; 0 = the server's setting.", valid=Range(0, 10_000)),
    InputPort("image_topics", PortType.STRING_LIST, "", "Camera topics (sensor_msgs/Image), ';'-separated.",
              names=Names(NameKind.TOPIC, Image)),
    InputPort("image_names", PortType.STRING_LIST, "", "Names the policy knows the cameras by, index-aligned with image_topics."),
    InputPort("joint_states_topic", PortType.STRING, "/joint_states", "sensor_msgs/JointState topic (reliable QoS).",
              names=Names(NameKind.TOPIC, JointState)),
    InputPort("max_observation_age", PortType.FLOAT, 0.0, "Seconds since it arrived after which a camera frame or joint state is too old to feed the policy: the run stops, naming the topic; 0 = 10 * dt.", valid=Range(0.0, 600.0, "s")),
    InputPort("wrench_topic", PortType.STRING, "", "geometry_msgs/WrenchStamped topic (e.g. /force_torque_sensor_broadcaster/wrench) watched against absolute_force_torque_threshold: the first reading over it stops the run; empty: not watched."),
    InputPort("max_tcp_speed", PortType.FLOAT, 0.0, "TCP linear speed limit (m/s) for this run, at most the cell's (cartesian_limits.yaml); 0 = the cell's.", valid=Range(0.0, 100.0, "m/s")),
    InputPort("max_tcp_angular_speed", PortType.FLOAT, 0.0, "TCP angular speed limit (rad/s) for this run, at most the cell's; 0 = the cell's.", valid=Range(0.0, 1000.0, "rad/s")),
    InputPort("tcp_keep_in_box", PortType.FLOAT_LIST, "", "A box xmin;ymin;zmin;xmax;ymax;zmax (m, world) the TCP stays inside for this run, besides the cell's; empty = none.",
              valid=Range(-1000.0, 1000.0, "m")),
    InputPort("tool_axis_max_angle", PortType.FLOAT, 0.0, "Degrees the tool axis may tilt from the cell's cone direction (straight down without one), at most the cell's; 0 = the cell's.", valid=Range(0.0, 180.0, "deg")),
    OutputPort("steps_executed", PortType.UINT, "Policy steps executed."),
    OutputPort("chunks_received", PortType.UINT, "Chunks received with CHUNK_PRODUCED (the warmup's excluded)."),
    OutputPort("rejection_reason", PortType.STRING, "Why a chunk was rejected (empty when none was)."),
    OutputPort("status_message", PortType.STRING, "The run's final message."),
)


OBSERVATION_AGE_STEPS = 10
"""Policy steps (``dt``) an observation may have aged when it is fed to the policy, by default: at
``dt = 0.1`` a publisher that stopped is found within a second, while the worked example's 10 Hz
cameras over ROS 2 on a loaded machine (frames up to 0.55 s old, measured) still pass."""


class ConfigError(ObjectiveError, ValueError):
    pass


@dataclass(frozen=True)
class PolicyRunConfig:
    policy_service_name: str
    joint_group_name: str
    total_action_steps: int
    prompt: str
    dt: float
    committed_action_steps: int
    num_interpolation_points: int
    link_padding: float
    policy_tracking_weight: float
    policy_uses_real_time_chunking: bool
    policy_call_timeout: float
    goal_path_tolerance: float
    absolute_force_torque_threshold: tuple[float, ...]
    controller_action_name: str
    gripper_command_action_name: str
    gripper_joint_name: str
    guidance_horizon: int
    image_topics: tuple[str, ...]
    image_names: tuple[str, ...]
    joint_states_topic: str
    max_observation_age: float
    wrench_topic: str
    max_tcp_speed: float = 0.0
    max_tcp_angular_speed: float = 0.0
    tcp_keep_in_box: tuple[float, ...] = ()
    tool_axis_max_angle: float = 0.0

    @property
    def envelope_overrides(self) -> EnvelopeOverrides:
        """The ports that tighten the cell's Cartesian envelope for this run."""
        return EnvelopeOverrides(self.max_tcp_speed, self.max_tcp_angular_speed, self.tcp_keep_in_box, self.tool_axis_max_angle)

    @property
    def has_gripper(self) -> bool:
        return bool(self.gripper_joint_name)

    @property
    def observation_age_limit_s(self) -> float:
        """``max_observation_age``, or ``OBSERVATION_AGE_STEPS`` policy steps when it is 0."""
        return self.max_observation_age or OBSERVATION_AGE_STEPS * self.dt


TUPLE_PORTS = ("absolute_force_torque_threshold", "image_topics", "image_names", "tcp_keep_in_box")
"""The ports read as lists that ``PolicyRunConfig`` keeps as tuples."""


def read_config(node: Behavior, fixed: Mapping[str, Any]) -> PolicyRunConfig:
    """The run's config from ``node``'s input ports; ``fixed``: the values of the fields the node
    has no port for."""
    fields = PolicyRunConfig.__dataclass_fields__
    values = {p.name: node.get_input(p.name) for p in node.ports if p.direction is Direction.INPUT and p.name in fields}
    for key in TUPLE_PORTS:
        if key in values:
            values[key] = tuple(values[key])
    return PolicyRunConfig(**values, **fixed)


COMBINED_PORTS = ("gripper_command_action_name", "gripper_joint_name", "image_topics", "image_names",
                  "absolute_force_torque_threshold")
"""The ports ``validate`` checks together (the rest is checked port by port)."""


def validate(config: PolicyRunConfig | Any) -> None:
    """Raise ConfigError naming the port(s) when the combination cannot run (``config``: anything
    with the ``COMBINED_PORTS`` as attributes)."""
    if bool(config.gripper_command_action_name) != bool(config.gripper_joint_name):
        given, missing = (
            ("gripper_joint_name", "gripper_command_action_name")
            if config.gripper_joint_name
            else ("gripper_command_action_name", "gripper_joint_name")
        )
        raise ConfigError(f"gripper_command_action_name and gripper_joint_name must be set together: {given} is set but {missing} is empty")
    if len(config.image_topics) != len(config.image_names):
        raise ConfigError(
            f"image_topics has {len(config.image_topics)} entries and image_names has {len(config.image_names)}; they must be index-aligned"
        )
    if len(set(config.image_names)) != len(config.image_names):
        raise ConfigError(f"image_names repeats a name: {';'.join(config.image_names)}")
    # Each numeric port's own range (PORTS, valid=...) was checked when it was read.
    if len(config.absolute_force_torque_threshold) != 6:
        raise ConfigError(
            "absolute_force_torque_threshold needs 6 positive values Fx;Fy;Fz;Tx;Ty;Tz, "
            f"got {';'.join(str(v) for v in config.absolute_force_torque_threshold)}"
        )


def committed_window_problem(window_steps: int, chunk_steps: int) -> str | None:
    """The guide's rule for the first chunk: ``committed_action_steps`` must be smaller than the
    policy's chunk size, or no next chunk can take over before this one runs out."""
    if window_steps < chunk_steps:
        return None
    return (f"committed_action_steps ({window_steps}) must be smaller than the policy's chunk size "
            f"({chunk_steps} steps): set committed_action_steps to at most {max(1, chunk_steps - 1)}")


@dataclass(frozen=True)
class ShapingConfig:
    """The run's settings a chunk's motion is planned with (from ``config.PolicyRunConfig``)."""

    dt: float
    committed_action_steps: int
    policy_tracking_weight: float
    num_interpolation_points: int
    max_acceleration: NDArray[np.float64]

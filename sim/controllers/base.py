"""What every simulated controller shares: a name, claimed interfaces and an active flag.

As in ros2_control, a controller claims command interfaces while it is active, only active
controllers act on goals and commands, and the controller manager calls ``update`` at the control
rate for the active ones. Subclasses override the ``on_activate``/``on_deactivate``/``update``
hooks and ``busy_reason`` (why it must not be deactivated right now).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from runtime.io.clock import Clock

from ..hardware import Hardware
from .compliance import AdmittanceParams


@dataclass(frozen=True)
class JtcParams:
    """The JTC parameters the cell runs with (ros2_controllers' names and defaults)."""

    allow_trajectory_replacement: bool = True
    """Merge a trajectory arriving while one plays (#2419); False: replace it from the new one's stamp."""
    stopped_velocity_tolerance: float = 0.01
    """rad/s: ``constraints.stopped_velocity_tolerance``, the goal's velocity tolerance."""
    goal_time: float = 0.0
    """Seconds: ``constraints.goal_time`` (0 = no limit to settle after the last point)."""
    interpolate_from_desired_state: bool = False
    """A new trajectory starts from the state last commanded; False (JTC's default): from the
    measured state, so the command steps back by the tracking error when a goal arrives."""


@dataclass
class ControllersConfig:
    """Tunables of the simulated controllers (defaults suit the UR5e + 2F-85 cell)."""

    feedback_rate: float = 20.0
    """Hz at which action feedback is published (the control loop itself runs at 500 Hz); 20 Hz is
    ros2_controllers' JTC default ``action_monitor_rate``. Every trajectory controller uses it."""
    stop_time: float = 0.2
    """Seconds to decelerate to rest on cancel, F/T abort or path-tolerance abort."""
    goal_position_tolerance: float = 0.01
    """Radians within which the arm must settle at a trajectory's last point (capped by the goal's
    path_tolerance when that is tighter)."""
    default_goal_time_tolerance: float = 1.0
    """Seconds allowed to settle after the last point when a goal's goal_time_tolerance is 0."""
    seam_blend_acceleration: float = 1.0
    """rad/s^2: a goal whose point at its seam differs from the reference there (within its
    path_tolerance) has the difference faded out with at most this acceleration, not closed in
    its first interval (see ``trajectory.stitch``)."""
    min_seam_blend_time: float = 0.05
    """Seconds: the shortest such fade."""
    admittance: AdmittanceParams = field(default_factory=AdmittanceParams)
    jacobian_refresh_period: float = 0.01
    """Seconds for which the admittance reuses the damped pseudo-inverse of the wrist Jacobian
    (0 = recompute it every control step). See ``compliance`` for the (tiny) approximation."""
    velocity_command_timeout: float = 0.1
    """The velocity controller stops the arm when no command arrived for this long (seconds)."""
    max_joint_velocity: float = math.pi
    """rad/s; velocity commands are clipped to it (the UR5e's published limit)."""
    gripper_position_tolerance: float = 0.01
    """Radians of the driver joint within which a gripper goal counts as reached."""
    gripper_stall_velocity: float = 0.02
    """rad/s below which the fingers count as not moving."""
    gripper_stall_time: float = 0.1
    """Seconds the fingers must stay still, short of the target, to report a stall."""
    gripper_start_grace: float = 0.2
    """Seconds after a gripper goal starts before a stall can be reported (the fingers accelerate)."""
    gripper_default_effort: float = 100.0
    """Newtons used when a GripperCommand asks for max_effort 0."""
    gripper_max_position: float = 0.8
    """Driver joint position when fully closed (0 is open)."""
    joint_trajectory: JtcParams = field(default_factory=JtcParams)
    """Parameters of the stock ``joint_trajectory_controller``."""


class Controller:
    """Base of the simulated controllers: lifecycle and bookkeeping, no behaviour of its own."""

    type_name = "controller_interface/ControllerInterface"

    def __init__(self, name: str, hardware: Hardware, clock: Clock, config: ControllersConfig) -> None:
        self.name = name
        self.hardware = hardware
        self.clock = clock
        self.config = config
        self.active = False

    # -- what the controller manager asks ---
    @property
    def command_interfaces(self) -> tuple[str, ...]:
        """Command interfaces claimed while active (two controllers may not share one)."""
        return ()

    @property
    def state_interfaces(self) -> tuple[str, ...]:
        return ()

    def busy_reason(self) -> str | None:
        """Why this controller must not be deactivated now (None when it may)."""
        return None

    def activate(self, t: float) -> None:
        self.active = True
        self.on_activate(t)

    def deactivate(self, t: float) -> None:
        self.on_deactivate(t)
        self.active = False

    def reset(self, t: float) -> None:
        """The world was reset (the robot teleported): end any goal, hold the state as it is now."""
        if self.active:
            self.on_reset(t)

    # -- hooks ---
    def on_activate(self, t: float) -> None:
        pass

    def on_reset(self, t: float) -> None:
        self.on_activate(t)

    def on_deactivate(self, t: float) -> None:
        pass

    def update(self, t: float, dt: float) -> None:
        """One control step at time ``t`` (called only while active)."""

    def plan_steps(self, times: list[float]) -> Any | None:
        """Work for the control steps at ``times`` (one tick's), done ahead in one pass, that
        ``planned_update`` then uses; None (the default): every step runs ``update``."""
        return None

    def planned_update(self, plan: Any, k: int) -> bool:
        """Control step ``k`` of ``plan``, exactly as ``update`` would run it, or False, having
        done nothing, when this step needs ``update`` after all (then so do the tick's others)."""
        return False

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, {'active' if self.active else 'inactive'})"


class ArmController(Controller):
    """A controller that commands the arm: it claims the arm joints' position and velocity."""

    @property
    def command_interfaces(self) -> tuple[str, ...]:
        return arm_command_interfaces(self.hardware)

    @property
    def state_interfaces(self) -> tuple[str, ...]:
        return arm_state_interfaces(self.hardware)


def arm_command_interfaces(hardware: Hardware) -> tuple[str, ...]:
    return tuple(f"{joint}/{kind}" for joint in hardware.arm_joint_names for kind in ("position", "velocity"))


def arm_state_interfaces(hardware: Hardware) -> tuple[str, ...]:
    return tuple(f"{joint}/{kind}" for joint in hardware.arm_joint_names for kind in ("position", "velocity"))


FT_STATE_INTERFACES = tuple(
    f"wrist_ft_sensor/{axis}" for axis in ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")
)

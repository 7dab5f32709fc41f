"""``velocity_force_controller``: joint velocity commands on a topic, integrated into arm targets.

Listens on ``/velocity_force_controller/commands`` (``std_msgs/Float64MultiArray``, one velocity
per arm joint in the hardware's order, rad/s). Each control step integrates the latest command
into the position target and sends both to the hardware. A command older than
``ControllersConfig.velocity_command_timeout`` counts as zero, so the arm stops when its commander
goes quiet. Velocities are clipped to ``max_joint_velocity``. Commands that arrive while the
controller is inactive, or are malformed, are ignored and the reason is kept in ``last_error``.
``/<name>/zero_fts`` (``std_srvs/Trigger``) zeroes the wrist force-torque sensor at its current
reading, as MoveIt Pro's velocity-force controller does.
"""
from __future__ import annotations

import math

import numpy as np
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from runtime.io.bus import Bus
from runtime.io.clock import Clock

from ..hardware import Hardware
from .base import ArmController, ControllersConfig


class VelocityForceController(ArmController):
    type_name = "moveit_pro_controllers/VelocityForceController"

    def __init__(self, name: str, bus: Bus, hardware: Hardware, clock: Clock, config: ControllersConfig) -> None:
        super().__init__(name, hardware, clock, config)
        self.topic = f"/{name}/commands"
        self.last_error: str | None = None
        self._command = np.zeros(len(hardware.arm_joint_names))
        self._command_time = -math.inf
        self._target = np.asarray(hardware.arm_position(), dtype=float).copy()
        self._subscription = bus.create_subscription(self.topic, Float64MultiArray, self._on_command)
        bus.create_service(f"/{name}/zero_fts", Trigger, self._zero_fts)

    def _zero_fts(self, request: Trigger.Request) -> Trigger.Response:
        self.hardware.tare_wrench()
        return Trigger.Response(success=True, message="force-torque sensor zeroed")

    def _on_command(self, msg: Float64MultiArray) -> None:
        if not self.active:
            self.last_error = f"controller {self.name} is not active: velocity command ignored"
            return
        values = np.asarray(msg.data, dtype=float)
        expected = len(self.hardware.arm_joint_names)
        if values.size != expected:
            self.last_error = f"{self.topic}: expected {expected} velocities ({', '.join(self.hardware.arm_joint_names)}), got {values.size}"
            return
        if not np.all(np.isfinite(values)):
            self.last_error = f"{self.topic}: velocity command contains non-finite values {values.tolist()}"
            return
        limit = self.config.max_joint_velocity
        self._command = np.clip(values, -limit, limit)
        self._command_time = self.clock.now()
        self.last_error = None

    def on_activate(self, t: float) -> None:
        self._target = np.asarray(self.hardware.arm_position(), dtype=float).copy()
        self._command = np.zeros_like(self._target)
        self._command_time = -math.inf
        self.hardware.command_arm(self._target, np.zeros_like(self._target))

    def commanded_velocity(self, t: float) -> np.ndarray:
        """The velocity in force at ``t`` (zero once the last command is older than the timeout)."""
        if t - self._command_time > self.config.velocity_command_timeout:
            return np.zeros_like(self._command)
        return self._command.copy()

    def update(self, t: float, dt: float) -> None:
        velocity = self.commanded_velocity(t)
        self._target = self._target + velocity * dt
        self.hardware.command_arm(self._target.copy(), velocity)

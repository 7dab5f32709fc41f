"""``robotiq_gripper_controller``: the GripperCommand action server for the 2F-85.

Serves ``/robotiq_gripper_controller/gripper_cmd`` (``control_msgs/action/GripperCommand``).
Position is the driver joint in radians, 0.0 open to 0.8 closed; ``max_effort`` 0 means the
configured default force. A goal finishes successfully either with ``reached_goal`` (within
``gripper_position_tolerance`` of the target) or with ``stalled`` (the fingers stopped short of the
target, e.g. closed on a cube: the hardware keeps squeezing with ``max_effort``, so the cube stays
held). A new goal preempts the running one, which ends CANCELED; a cancel holds the fingers where
they are. Goals to an inactive controller are accepted and aborted at once (the result carries the
current position and ``reached_goal`` false); malformed goals (position outside [0, 0.8], effort
negative or not finite) are rejected, with the reason kept in ``last_rejection``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from control_msgs.action import GripperCommand

from runtime.io.bus import Bus, ServerGoalHandle
from runtime.io.clock import Clock

from ..hardware import Hardware
from .base import Controller, ControllersConfig


@dataclass
class _GripperGoal:
    handle: ServerGoalHandle
    target: float
    effort: float
    start: float
    still_since: float | None = None
    cancel_requested: bool = False


class GripperActionController(Controller):
    type_name = "position_controllers/GripperActionController"

    def __init__(self, name: str, bus: Bus, hardware: Hardware, clock: Clock, config: ControllersConfig) -> None:
        super().__init__(name, hardware, clock, config)
        self.action_name = f"/{name}/gripper_cmd"
        self.last_rejection: str | None = None
        self._goal: _GripperGoal | None = None
        self._last_feedback = -math.inf
        bus.create_action_server(self.action_name, GripperCommand, self._on_goal, self._on_cancel)

    @property
    def command_interfaces(self) -> tuple[str, ...]:
        return (f"{self.hardware.gripper_joint_name}/position",)

    @property
    def state_interfaces(self) -> tuple[str, ...]:
        joint = self.hardware.gripper_joint_name
        return (f"{joint}/position", f"{joint}/velocity")

    def busy_reason(self) -> str | None:
        if self._goal is not None:
            return f"it is executing gripper goal {self._goal.handle.goal_id[:8]} (cancel it first)"
        return None

    def _result(self, reached: bool = False, stalled: bool = False, effort: float = 0.0) -> GripperCommand.Result:
        return GripperCommand.Result(
            position=float(self.hardware.gripper_position()), effort=float(effort), stalled=stalled, reached_goal=reached
        )

    def _on_goal(self, handle: ServerGoalHandle) -> bool:
        command = handle.request.command
        position, effort = float(command.position), float(command.max_effort)
        top = self.config.gripper_max_position
        if not math.isfinite(position) or not -1e-6 <= position <= top + 1e-6:
            self.last_rejection = f"{self.action_name}: position {position} is outside [0 (open), {top} (closed)]"
            return False
        if not math.isfinite(effort) or effort < 0:
            self.last_rejection = f"{self.action_name}: max_effort must be finite and >= 0, got {effort}"
            return False
        if not self.active:
            handle.abort(self._result())
            return True
        if self._goal is not None and self._goal.handle.is_active:
            self._goal.handle.canceled(self._result())
        effort = effort or self.config.gripper_default_effort
        position = min(max(position, 0.0), top)
        self._goal = _GripperGoal(handle, position, effort, self.clock.now())
        self.hardware.command_gripper(position, effort)
        return True

    def _on_cancel(self, handle: ServerGoalHandle) -> bool:
        if self._goal is None or self._goal.handle is not handle:
            return False
        self._goal.cancel_requested = True
        return True

    def on_reset(self, t: float) -> None:
        self.on_deactivate(t)

    def on_deactivate(self, t: float) -> None:
        if self._goal is not None and self._goal.handle.is_active:
            self._goal.handle.abort(self._result())
        self._goal = None

    def update(self, t: float, dt: float) -> None:
        goal = self._goal
        if goal is None:
            return
        if not goal.handle.is_active:  # finished elsewhere (e.g. preempted)
            self._goal = None
            return
        position = float(self.hardware.gripper_position())
        if goal.cancel_requested or goal.handle.is_cancel_requested:
            self.hardware.command_gripper(position, goal.effort)
            self._goal = None
            goal.handle.canceled(self._result())
            return
        self._publish_feedback(t, goal, position)
        if abs(position - goal.target) <= self.config.gripper_position_tolerance:
            self._goal = None
            goal.handle.succeed(self._result(reached=True))
            return
        moving = abs(float(self.hardware.gripper_velocity())) > self.config.gripper_stall_velocity
        if moving or t - goal.start < self.config.gripper_start_grace:
            goal.still_since = None
            return
        if goal.still_since is None:
            goal.still_since = t
        if t - goal.still_since >= self.config.gripper_stall_time - 1e-9:
            self._goal = None
            goal.handle.succeed(self._result(stalled=True, effort=goal.effort))

    def _publish_feedback(self, t: float, goal: _GripperGoal, position: float) -> None:
        if t - self._last_feedback < 1.0 / self.config.feedback_rate - 1e-9:
            return
        self._last_feedback = t
        goal.handle.publish_feedback(
            GripperCommand.Feedback(position=position, effort=0.0, stalled=False, reached_goal=False)
        )

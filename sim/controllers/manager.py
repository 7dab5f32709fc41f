"""The controller manager: which controllers run, switched with ros2_control's semantics.

Serves ``/controller_manager/switch_controller`` and ``/controller_manager/list_controllers``
(``controller_manager_msgs``). ``make_controllers`` builds the cell's controllers:

=====================================  ================  ==============================================
controller                             at start          talks on
=====================================  ================  ==============================================
joint_trajectory_admittance_controller inactive          action .../follow_joint_trajectory (admittance)
joint_trajectory_controller            inactive          action .../follow_joint_trajectory (control_msgs),
                                                         topic .../joint_trajectory
velocity_force_controller              active            topic /velocity_force_controller/commands
robotiq_gripper_controller             active            action .../gripper_cmd
force_torque_sensor_broadcaster        active            topic /force_torque_sensor_broadcaster/wrench
=====================================  ================  ==============================================

The three arm controllers claim the same command interfaces: one of them is active at a time.
(Joint states are published by the world, not by a broadcaster here.)

Switching, as ros2_control does it: deactivations happen before activations, in one control
step. STRICT (2) refuses the whole switch on any problem, naming every problem; BEST_EFFORT (1,
and 0 like ros2_control) performs what it can and names what it skipped. Problems: an unknown
controller, activating an active one or deactivating an inactive one, activating a controller
whose command interfaces (the arm's position/velocity commands) are held by an active controller
that the same switch does not deactivate, and deactivating a controller that is executing a goal
(cancel the goal first). ``timeout`` and ``activate_asap`` are accepted and have nothing to wait
for: the simulated switch is immediate.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from controller_manager_msgs.msg import ControllerState
from controller_manager_msgs.srv import ListControllers, SwitchController

from runtime.io.bus import Bus
from runtime.io.clock import Clock

from ..hardware import Hardware
from .admittance import JointTrajectoryAdmittanceController
from .base import Controller, ControllersConfig
from .broadcaster import ForceTorqueSensorBroadcaster
from .gripper import GripperActionController
from .jtc import JointTrajectoryController
from .velocity import VelocityForceController

SWITCH_SERVICE = "/controller_manager/switch_controller"
LIST_SERVICE = "/controller_manager/list_controllers"
BEST_EFFORT = SwitchController.Request.BEST_EFFORT
STRICT = SwitchController.Request.STRICT


@dataclass(frozen=True)
class SwitchOutcome:
    ok: bool
    message: str


class ControllerManager:
    """Holds the controllers, switches them and runs the active ones each control step."""

    def __init__(self, bus: Bus, clock: Clock, controllers: list[Controller]) -> None:
        self.clock = clock
        self.controllers: dict[str, Controller] = {c.name: c for c in controllers}
        bus.create_service(SWITCH_SERVICE, SwitchController, self._on_switch)
        bus.create_service(LIST_SERVICE, ListControllers, self._on_list)

    def __getitem__(self, name: str) -> Controller:
        return self.controllers[name]

    def active_names(self) -> list[str]:
        return [name for name, c in self.controllers.items() if c.active]

    def update(self, t: float, dt: float) -> None:
        """Run every active controller once (the world calls this at 500 Hz, before each physics step)."""
        for controller in self.controllers.values():
            if controller.active:
                controller.update(t, dt)

    def advance(self, times: list[float], dt: float, step_physics: Callable[[float], None]) -> None:
        """One tick: a control step at each of ``times`` (``dt`` apart), each followed by
        ``step_physics(dt)``. The same as ``update`` then ``step_physics`` at each time, but a
        controller that can plan the tick ahead (``Controller.plan_steps``) runs its steps the
        quick way until one needs ``update``, and ``update`` runs the rest of its tick."""
        if not times:  # a tick shorter than a control period (real time, or a clock just started)
            return
        controllers = list(self.controllers.values())
        plans = [c.plan_steps(times) if c.active else None for c in controllers]
        for k, t in enumerate(times):
            for i, controller in enumerate(controllers):
                if not controller.active:
                    continue
                plan = plans[i]
                if plan is not None:
                    if controller.planned_update(plan, k):
                        continue
                    plans[i] = None
                controller.update(t, dt)
            step_physics(dt)

    def reset(self) -> None:
        """After the world teleports the robot (ResetSim): active controllers end their goals
        (aborted) and hold the new state instead of pulling the arm back to the old one."""
        t = self.clock.now()
        for controller in self.controllers.values():
            controller.reset(t)

    # -- switching ---
    def switch(self, activate: list[str], deactivate: list[str], strictness: int = STRICT) -> SwitchOutcome:
        if strictness == 0:
            strictness = BEST_EFFORT
        if strictness not in (BEST_EFFORT, STRICT):
            return SwitchOutcome(False, f"strictness must be {BEST_EFFORT} (BEST_EFFORT) or {STRICT} (STRICT), got {strictness}")
        problems: list[str] = []
        leaving: list[Controller] = []
        for name in dict.fromkeys(deactivate):
            controller = self._lookup(name, "deactivate", problems)
            if controller is None:
                continue
            if not controller.active:
                problems.append(f"cannot deactivate '{name}': it is not active")
                continue
            busy = controller.busy_reason()
            if busy is not None:
                problems.append(f"cannot deactivate '{name}': {busy}")
                continue
            leaving.append(controller)

        claimed = {
            interface: c.name
            for c in self.controllers.values()
            if c.active and c not in leaving
            for interface in c.command_interfaces
        }
        entering: list[Controller] = []
        for name in dict.fromkeys(activate):
            controller = self._lookup(name, "activate", problems)
            if controller is None:
                continue
            if controller.active and controller not in leaving:
                problems.append(f"cannot activate '{name}': it is already active")
                continue
            holders = sorted({claimed[i] for i in controller.command_interfaces if i in claimed})
            if holders:
                problems.append(
                    f"cannot activate '{name}': its command interfaces are claimed by active controller "
                    + ", ".join(f"'{h}'" for h in holders)
                    + " (deactivate it in the same switch)"
                )
                continue
            entering.append(controller)
            claimed.update({i: controller.name for i in controller.command_interfaces})

        if strictness == STRICT and problems:
            return SwitchOutcome(False, "switch refused (STRICT): " + "; ".join(problems))
        t = self.clock.now()
        for controller in leaving:
            controller.deactivate(t)
        for controller in entering:
            controller.activate(t)
        done = (
            f"activated {[c.name for c in entering]}, deactivated {[c.name for c in leaving]}; "
            f"active now: {self.active_names()}"
        )
        if problems:
            done += "; skipped (BEST_EFFORT): " + "; ".join(problems)
        return SwitchOutcome(True, done)

    def _lookup(self, name: str, verb: str, problems: list[str]) -> Controller | None:
        controller = self.controllers.get(name)
        if controller is None:
            problems.append(f"cannot {verb} '{name}': no such controller (loaded: {', '.join(self.controllers)})")
        return controller

    def controller_states(self) -> list[ControllerState]:
        return [
            ControllerState(
                name=c.name,
                state="active" if c.active else "inactive",
                type=c.type_name,
                claimed_interfaces=list(c.command_interfaces) if c.active else [],
                required_command_interfaces=list(c.command_interfaces),
                required_state_interfaces=list(c.state_interfaces),
            )
            for c in self.controllers.values()
        ]

    # -- services ---
    def _on_switch(self, request: SwitchController.Request) -> SwitchController.Response:
        outcome = self.switch(list(request.activate_controllers), list(request.deactivate_controllers), request.strictness)
        return SwitchController.Response(ok=outcome.ok, message=outcome.message)

    def _on_list(self, request: ListControllers.Request) -> ListControllers.Response:
        return ListControllers.Response(controller=self.controller_states())


TRAJECTORY_CONTROLLER = "joint_trajectory_admittance_controller"
JTC_CONTROLLER = "joint_trajectory_controller"
FT_BROADCASTER = "force_torque_sensor_broadcaster"
VELOCITY_CONTROLLER = "velocity_force_controller"
GRIPPER_CONTROLLER = "robotiq_gripper_controller"


def make_controllers(bus: Bus, hardware: Hardware, clock: Clock, config: ControllersConfig | None = None) -> ControllerManager:
    """The cell's controllers on ``bus``: the velocity and gripper controllers and the F/T
    broadcaster active, the two trajectory controllers inactive."""
    config = config or ControllersConfig()
    manager = ControllerManager(
        bus,
        clock,
        [
            JointTrajectoryAdmittanceController(TRAJECTORY_CONTROLLER, bus, hardware, clock, config),
            JointTrajectoryController(JTC_CONTROLLER, bus, hardware, clock, config),
            VelocityForceController(VELOCITY_CONTROLLER, bus, hardware, clock, config),
            GripperActionController(GRIPPER_CONTROLLER, bus, hardware, clock, config),
            ForceTorqueSensorBroadcaster(FT_BROADCASTER, bus, hardware, clock, config),
        ],
    )
    t = clock.now()
    manager[VELOCITY_CONTROLLER].activate(t)
    manager[GRIPPER_CONTROLLER].activate(t)
    manager[FT_BROADCASTER].activate(t)
    return manager

"""SwitchController: activate and deactivate ros2_control controllers through the controller manager."""
from __future__ import annotations

import enum

from controller_manager_msgs.srv import ListControllers, SwitchController as SwitchSrv

from runtime.behavior import Behavior, Status
from runtime.ports import InputPort, PortType, Range
from runtime.timestamps import duration_msg

from .waiting import Deadline, when_ready


class Phase(enum.Enum):
    WAIT = 1
    LIST = 2
    SWITCH = 3


STRICTNESS = {"BEST_EFFORT": SwitchSrv.Request.BEST_EFFORT, "STRICT": SwitchSrv.Request.STRICT, "1": 1, "2": 2}


class SwitchController(Behavior):
    """Activate and/or deactivate controllers. Controllers already in the requested state are
    left alone, so the node is idempotent: running it twice succeeds twice."""

    needs_world = True
    description = "Activate and deactivate ros2_control controllers (already-active ones are skipped)."
    ports = (
        InputPort("activate_controllers", PortType.STRING_LIST, "", "Controllers to activate, ';'-separated."),
        InputPort("deactivate_controllers", PortType.STRING_LIST, "", "Controllers to deactivate, ';'-separated."),
        InputPort("strictness", PortType.STRING, "STRICT", "STRICT: all or nothing; BEST_EFFORT: switch what can be switched."),
        InputPort("timeout", PortType.FLOAT, 3.0, "Seconds to wait for the controller manager and the switch.", valid=Range(0.0, 3600.0, "s", min_open=True)),
        InputPort("controller_list_action_name", PortType.STRING, "/controller_manager/list_controllers", "ListControllers service."),
        InputPort("controller_switch_action_name", PortType.STRING, "/controller_manager/switch_controller", "SwitchController service."),
    )

    def initialise(self) -> None:
        self.error = None
        self.activate = [c for c in self.get_input("activate_controllers") if c]
        self.deactivate = [c for c in self.get_input("deactivate_controllers") if c]
        strictness = self.get_input("strictness").strip().upper()
        if strictness not in STRICTNESS:
            self.error = f"strictness must be STRICT or BEST_EFFORT, got '{strictness}'"
            return
        self.strictness = STRICTNESS[strictness]
        overlap = sorted(set(self.activate) & set(self.deactivate))
        if overlap:
            self.error = f"controllers both activated and deactivated: {', '.join(overlap)}"
            return
        if not self.activate and not self.deactivate:
            self.error = "nothing to switch: activate_controllers and deactivate_controllers are both empty"
            return
        bus = self.context.bus
        self.lister = bus.create_client(self.get_input("controller_list_action_name"), ListControllers)
        self.switcher = bus.create_client(self.get_input("controller_switch_action_name"), SwitchSrv)
        self.deadline = Deadline(self, self.get_input("timeout"))
        self.phase, self.future = Phase.WAIT, None

    def update(self) -> Status:
        if self.error:
            return self.fail(self.error)
        if self.phase is Phase.WAIT:
            for client in (self.lister, self.switcher):
                ready = when_ready(client.service_is_ready, self.deadline, f"service '{client.name}'")
                if ready is not True:
                    return self.fail(ready) if isinstance(ready, str) else Status.RUNNING
            self.future = self.lister.call_async(ListControllers.Request())
            self.phase = Phase.LIST
        if self.phase is Phase.LIST:
            if not self.future.done():
                return self._waiting("listing controllers")
            states = {c.name: c.state for c in self.future.result().controller}
            unknown = [c for c in self.activate + self.deactivate if c not in states]
            if unknown and self.strictness == SwitchSrv.Request.STRICT:
                return self.fail(f"unknown controllers: {', '.join(unknown)} (known: {', '.join(sorted(states))})")
            request = SwitchSrv.Request()
            request.activate_controllers = [c for c in self.activate if states.get(c) != "active"]
            request.deactivate_controllers = [c for c in self.deactivate if states.get(c) == "active"]
            if not request.activate_controllers and not request.deactivate_controllers:
                self.feedback_message = "controllers already in the requested state"
                return Status.SUCCESS
            request.strictness = self.strictness
            remaining = max(0.0, self.deadline.until - self.context.clock.now())
            request.timeout = duration_msg(remaining)
            self.future = self.switcher.call_async(request)
            self.phase = Phase.SWITCH
        if not self.future.done():
            return self._waiting("switching controllers")
        response = self.future.result()
        if not response.ok:
            return self.fail(f"the controller manager refused the switch: {response.message or 'no reason given'}")
        self.feedback_message = response.message
        return Status.SUCCESS

    def _waiting(self, what: str) -> Status:
        if self.deadline.expired:
            return self.fail(f"{what} took longer than {self.deadline.seconds:g} s")
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        if getattr(self, "future", None) is not None and new_status is Status.INVALID:
            self.future.cancel()


NODES = (SwitchController,)

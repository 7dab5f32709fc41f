"""SwitchController: activate and deactivate ros2_control controllers through the controller manager.

Besides the lists given, the node can work out what else the switch needs from the controller
manager's ListControllers answer (``plan_switch``, a pure function): with
``automatic_deactivation`` the active controllers that hold a command interface a controller to
activate needs are deactivated in the same switch, and with ``automatic_activation`` the inactive
controllers that a controller to activate is chained to (its ``chain_connections``: it writes
their reference interfaces) are activated with it. MoveIt Pro's Objectives set both, with an
empty ``deactivate_controllers``, to take the arm over from whichever controller holds it.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any, Sequence

from controller_manager_msgs.msg import ControllerState
from controller_manager_msgs.srv import ListControllers, SwitchController as SwitchSrv

from runtime.tree.behavior import Behavior, Status
from runtime.errors import SetupError
from runtime.tree.ports import InputPort, NameKind, Names, PortType, Range
from runtime.io.bus import Future
from runtime.io.timestamps import duration_msg

from .waiting import Deadline, when_ready


class Phase(enum.Enum):
    WAIT = 1
    LIST = 2
    SWITCH = 3


STRICTNESS = {"BEST_EFFORT": SwitchSrv.Request.BEST_EFFORT, "STRICT": SwitchSrv.Request.STRICT, "1": 1, "2": 2}
ACTIVE = "active"


@dataclass(frozen=True)
class SwitchPlan:
    """The switch to request, once the controllers' states are known."""

    activate: tuple[str, ...]
    deactivate: tuple[str, ...]
    auto_activated: tuple[str, ...]
    """Added by ``automatic_activation``: controllers the requested ones are chained to."""
    auto_deactivated: tuple[str, ...]
    """Added by ``automatic_deactivation``: active controllers holding a command interface needed."""

    @property
    def empty(self) -> bool:
        return not self.activate and not self.deactivate


def plan_switch(
    states: Sequence[ControllerState],
    activate: Sequence[str],
    deactivate: Sequence[str],
    automatic_activation: bool = False,
    automatic_deactivation: bool = False,
) -> SwitchPlan:
    """The request for ListControllers' ``states``. Controllers already in the requested state are
    left out, so the same switch run twice succeeds twice; unknown names stay in ``activate`` for
    the controller manager to refuse (STRICT) or skip (BEST_EFFORT)."""
    by_name = {c.name: c for c in states}
    wanted = list(dict.fromkeys(activate))
    chained: list[str] = []
    if automatic_activation:
        queue = list(wanted)
        while queue:
            state = by_name.get(queue.pop(0))
            for link in state.chain_connections if state is not None else []:
                if link.name not in wanted and link.name not in chained:
                    chained.append(link.name)
                    queue.append(link.name)
    turning_on = [c for c in wanted + chained if c not in by_name or by_name[c].state != ACTIVE]
    conflicting: list[str] = []
    if automatic_deactivation:
        needed = {i for c in turning_on if c in by_name for i in by_name[c].required_command_interfaces}
        keep = set(wanted) | set(chained) | set(deactivate)
        conflicting = [c.name for c in states if c.state == ACTIVE and c.name not in keep and needed.intersection(c.claimed_interfaces)]
    turning_off = [c for c in dict.fromkeys([*deactivate, *conflicting]) if c in by_name and by_name[c].state == ACTIVE]
    return SwitchPlan(tuple(turning_on), tuple(turning_off), tuple(c for c in chained if c in turning_on), tuple(conflicting))


class SwitchController(Behavior):
    """Activate and/or deactivate controllers. Controllers already in the requested state are
    left alone, so the node is idempotent: running it twice succeeds twice."""

    needs_world = True
    description = "Activate and deactivate ros2_control controllers (already-active ones are skipped)."
    ports = (
        InputPort("activate_controllers", PortType.STRING_LIST, "", "Controllers to activate, ';'-separated.",
                  names=Names(NameKind.CONTROLLER, activates=True)),
        InputPort("deactivate_controllers", PortType.STRING_LIST, "", "Controllers to deactivate, ';'-separated.",
                  names=Names(NameKind.CONTROLLER, activates=False)),
        InputPort("strictness", PortType.STRING, "STRICT", "STRICT (2): all or nothing; BEST_EFFORT (1): switch what can be switched."),
        InputPort("timeout", PortType.FLOAT, 3.0, "Seconds to wait for the controller manager and the switch; 0 or negative: no limit (MoveIt Pro writes -1).",
                  valid=Range(-3600.0, 3600.0, "s")),
        InputPort("activate_asap", PortType.BOOL, False, "Passed to the controller manager: activate as soon as the hardware interfaces are ready."),
        InputPort("automatic_activation", PortType.BOOL, False, "Also activate the controllers the ones to activate are chained to."),
        InputPort("automatic_deactivation", PortType.BOOL, False, "Also deactivate the active controllers that hold a command interface the ones to activate need."),
        InputPort("controller_list_action_name", PortType.STRING, "/controller_manager/list_controllers", "ListControllers service.",
                  names=Names(NameKind.SERVICE, ListControllers)),
        InputPort("controller_switch_action_name", PortType.STRING, "/controller_manager/switch_controller", "SwitchController service.",
                  names=Names(NameKind.SERVICE, SwitchSrv)),
    )

    def lenient_names(self) -> tuple[str, ...]:
        """BEST_EFFORT switches what it can: unknown controllers are no error then (``runtime.app.world_check``),
        nor when the strictness is known only when the node runs."""
        strictness = self.bindings["strictness"]
        strict = strictness.key is None and STRICTNESS.get(str(strictness.literal).strip().upper()) == SwitchSrv.Request.STRICT
        return () if strict else ("activate_controllers", "deactivate_controllers")

    def initialise(self) -> None:
        self.error = None
        self.activate = [c for c in self.get_input("activate_controllers") if c]
        self.deactivate = [c for c in self.get_input("deactivate_controllers") if c]
        strictness = self.get_input("strictness").strip().upper()
        if strictness not in STRICTNESS:
            self.error = f"strictness must be STRICT (2) or BEST_EFFORT (1), got '{strictness}'"
            return
        self.strictness = STRICTNESS[strictness]
        overlap = sorted(set(self.activate) & set(self.deactivate))
        if overlap:
            self.error = f"controllers both activated and deactivated: {', '.join(overlap)}"
            return
        if not self.activate and not self.deactivate:
            self.error = "nothing to switch: activate_controllers and deactivate_controllers are both empty"
            return
        timeout = self.get_input("timeout")
        if math.isnan(timeout):
            self.error = "timeout must be a number of seconds, got nan"
            return
        self.limited = 0 < timeout < math.inf
        self.activate_asap = self.get_input("activate_asap")
        self.automatic = (self.get_input("automatic_activation"), self.get_input("automatic_deactivation"))
        bus = self.context.bus
        self.lister = bus.create_client(self.get_input("controller_list_action_name"), ListControllers)
        self.switcher = bus.create_client(self.get_input("controller_switch_action_name"), SwitchSrv)
        self.deadline = Deadline(self, timeout if self.limited else math.inf)
        self.phase = Phase.WAIT
        self.future: Future[Any] | None = None

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
            assert self.future is not None  # the listing's call
            if not self.future.done():
                return self._waiting("listing controllers")
            states = list(self.future.result().controller)
            known = {c.name for c in states}
            unknown = [c for c in self.activate + self.deactivate if c not in known]
            if unknown and self.strictness == SwitchSrv.Request.STRICT:  # an error of the setup: ERROR, never retried
                raise SetupError(f"unknown controllers: {', '.join(unknown)} (known: {', '.join(sorted(known))})")
            plan = plan_switch(states, self.activate, self.deactivate, *self.automatic)
            if plan.empty:
                self.feedback_message = "controllers already in the requested state"
                return Status.SUCCESS
            request = SwitchSrv.Request()
            request.activate_controllers = list(plan.activate)
            request.deactivate_controllers = list(plan.deactivate)
            request.strictness = self.strictness
            request.activate_asap = self.activate_asap
            # The service's timeout: what is left of ours, or zero (ros2_control: no limit).
            request.timeout = duration_msg(max(0.0, self.deadline.until - self.context.clock.now()) if self.limited else 0.0)
            self.plan = plan
            self.future = self.switcher.call_async(request)
            self.phase = Phase.SWITCH
        assert self.future is not None  # the switch's call
        if not self.future.done():
            return self._waiting("switching controllers")
        response = self.future.result()
        if not response.ok:
            return self.fail(f"the controller manager refused the switch: {response.message or 'no reason given'}")
        extra = [f"{label}: {', '.join(names)}" for label, names in
                 (("chained, activated too", self.plan.auto_activated), ("conflicting, deactivated", self.plan.auto_deactivated)) if names]
        self.feedback_message = "; ".join([response.message, *extra]) if extra else response.message
        return Status.SUCCESS

    def _waiting(self, what: str) -> Status:
        if self.deadline.expired:
            return self.fail(f"{what} took longer than {self.deadline.seconds:g} s")
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        future = getattr(self, "future", None)
        if future is not None and new_status is Status.INVALID:
            future.cancel()


NODES = (SwitchController,)

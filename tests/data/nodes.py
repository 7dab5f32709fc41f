"""Test-only node classes: typed ports, outputs, failures with reasons, a robot-ish node."""
from __future__ import annotations

from typing import Any, ClassVar

from runtime.tree.behavior import Behavior, NodeKind, Status
from runtime.tree.ports import InputPort, OutputPort, PortType, Range
from runtime.tree.registry import Registry


class Typed(Behavior):
    """Multiplies x by n into out."""

    description: ClassVar[str] = "Writes x * n to out."
    ports = (
        InputPort("x", PortType.FLOAT, description="A number.", valid=Range(-1e6, 1e6)),
        InputPort("n", PortType.INT, 3, "How many times.", valid=Range(0, 100)),
        InputPort("flag", PortType.BOOL, False, "A switch."),
        OutputPort("out", PortType.FLOAT, "x * n."),
    )

    def update(self) -> Status:
        self.set_output("out", self.get_input("x") * self.get_input("n"))
        return Status.SUCCESS


class Copy(Behavior):
    """Copies the value of 'source' (any type) to the entry named by 'target'."""

    ports = (InputPort("source", PortType.ANY), OutputPort("target"))

    def update(self) -> Status:
        self.set_output("target", self.get_input("source"))
        return Status.SUCCESS


class FailWith(Behavior):
    ports = (InputPort("reason", PortType.STRING, "it broke"),)

    def update(self) -> Status:
        return self.fail(self.get_input("reason"))


class Forever(Behavior):
    """RUNNING until halted; remembers every terminate call."""

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.terminated: list[Status] = []

    def update(self) -> Status:
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        self.terminated.append(new_status)


class Robot(Behavior):
    """Needs a world; reports how often it was ticked in the run summary."""

    needs_world: ClassVar[bool] = True

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.ticks = 0

    def update(self) -> Status:
        self.ticks += 1
        assert self.context.world is not None
        return Status.SUCCESS

    def run_summary(self) -> dict[str, Any]:
        return {"robot": {"ticks": self.ticks}}


class Check(Behavior):
    kind: ClassVar[NodeKind] = NodeKind.CONDITION
    ports = (InputPort("value", PortType.BOOL),)

    def update(self) -> Status:
        return Status.SUCCESS if self.get_input("value") else self.fail("value is false")


class Crash(Behavior):
    """A bug: RUNNING for 'after' ticks, then an exception nobody expected."""

    ports = (InputPort("after", PortType.INT, 0, "Ticks before it raises.", valid=Range(0, 1000)),)

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.ticks = 0

    def update(self) -> Status:
        self.ticks += 1
        if self.ticks > self.get_input("after"):
            raise RuntimeError("sensor exploded")
        return Status.RUNNING


class BrokenAtLoad(Behavior):
    """A bug in a node's own load-time check."""

    def check_literals(self) -> None:
        raise KeyError("calibration")

    def update(self) -> Status:
        return Status.SUCCESS


TEST_NODES = (Typed, Copy, FailWith, Forever, Robot, Check, Crash, BrokenAtLoad)


def make_registry() -> Registry:
    """The runtime's own nodes plus the test nodes (no plug-ins: tests stay fast and isolated)."""
    from runtime.tree import builtin

    registry = Registry()
    builtin.register(registry)
    registry.register_all(TEST_NODES)
    return registry

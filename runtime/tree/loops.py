"""BT.CPP's Loop decorators: run the child once per element of a queue (LoopInt ... LoopString).

BT.CPP ``LoopNode<T>`` (include/behaviortree_cpp/decorators/loop_node.h, 4.10). ``queue`` is a
literal (``"1;2;3"``) or a blackboard entry holding a list or such a string; each time the child
is not RUNNING the next element is popped into ``value`` and the child is ticked. The node is
RUNNING while elements remain (one child run per tick at most, so it never loops inside a tick),
FAILURE as soon as the child fails, and ``if_empty`` (SUCCESS by default) once the queue is
empty. A queue read from the blackboard is copied when the loop starts, as 4.10 does with a
``std::vector``: the entry itself is left as it is.
"""
from __future__ import annotations

from typing import Any, ClassVar

from .behavior import Status
from .controls import COMPLETED, DecoratorNode, TickGenerator, halt_child
from .decorators import STATUS_BY_NAME
from runtime.errors import PortError
from .ports import ConversionError, InOutPort, InputPort, OutputPort, PortType, convert


class _Loop(DecoratorNode):
    element_type: ClassVar[PortType]

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.child_running = False
        self.queue: list[Any] | None = None

    def _elements(self, raw: Any) -> list[Any]:
        """The queue's elements, converted to the element type."""
        try:
            if isinstance(raw, str):
                text = raw.strip()
                parts = [part.strip() for part in text.split(";")] if text else []
            elif isinstance(raw, (list, tuple)) or hasattr(raw, "tolist"):
                parts = list(raw.tolist() if hasattr(raw, "tolist") else raw)
            else:
                raise ConversionError(f"expects a list or a ';'-separated string, got {raw!r}")
            return [convert(part, self.element_type) for part in parts]
        except ConversionError as err:
            raise PortError(f"port 'queue' {err}", self.location, self.xml_id) from None

    def check_literals(self) -> None:
        queue = self.bindings["queue"]
        if queue.key is None:
            self._elements(queue.literal)  # a bad literal is a load-time error

    def run(self) -> TickGenerator:
        if self.status is Status.INVALID:
            self.child_running = False
            self.queue = None
        popped = False
        if not self.child_running:
            if self.queue is None:
                self.queue = self._elements(self.get_input("queue"))
            if self.queue:
                self.set_output("value", self.queue.pop(0))
                popped = True
        if not popped and not self.child_running:
            return STATUS_BY_NAME[self.get_input("if_empty")]
        self.status = Status.RUNNING
        result = yield from self.tick_child(self.child)
        self.child_running = result is Status.RUNNING
        if result in COMPLETED:
            halt_child(self.child)
        return Status.FAILURE if result is Status.FAILURE else Status.RUNNING

    def halt(self) -> None:
        self.child_running = False
        self.queue = None
        super().halt()


def _loop(name: str, element: PortType, noun: str) -> type[_Loop]:
    """BT.CPP ``LoopNode<T>`` registered as ``name``, popping elements of type ``element``."""
    ports = (
        InOutPort("queue", PortType.ANY, description="The elements: a ';'-separated literal, or an entry holding a list."),
        InputPort("if_empty", PortType.NODE_STATUS, "SUCCESS", "Status to return if the queue is empty: SUCCESS, FAILURE, SKIPPED."),
        OutputPort("value", element, "The element the child runs with."),
    )
    description = f"Runs its child once per {noun} of 'queue', each written to 'value'; then returns if_empty."
    namespace = {"element_type": element, "ports": ports, "description": description, "__module__": __name__}
    return type(name, (_Loop,), namespace)


LoopInt = _loop("LoopInt", PortType.INT, "integer")
LoopBool = _loop("LoopBool", PortType.BOOL, "boolean")
LoopDouble = _loop("LoopDouble", PortType.FLOAT, "number")
LoopString = _loop("LoopString", PortType.STRING, "string")
NODES = (LoopInt, LoopBool, LoopDouble, LoopString)

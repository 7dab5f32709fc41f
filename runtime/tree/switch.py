"""BT.CPP's Switch2 ... Switch6: tick the child whose case matches a value (the last child is the default).

BT.CPP ``SwitchNode<N>`` (include/behaviortree_cpp/controls/switch_node.h, src/controls/switch_node.cpp,
4.10). ``variable`` is compared with ``case_1`` ... ``case_N`` in order, as text first, then as
whole integers, then as real numbers (within float epsilon); the first match is ticked, else the
default (last) child. A variable that cannot be read (unset, missing entry) selects the default.
When the match changes while another child is RUNNING, that child is halted first.

4.8.2 read ``"1abc"`` as the integer 1; 4.10 (BT.CPP #1178) requires the whole text to be a
number, and so does this module.
"""
from __future__ import annotations

from typing import Any, ClassVar

from .behavior import Status
from .controls import SKIPPED, ControlNode, TickGenerator, halt_child
from runtime.errors import PortError
from .ports import InputPort, PortType

FLOAT_EPSILON = 1.1920928955078125e-07


def _as_int(text: str) -> int | None:
    stripped = text.strip()
    if stripped != text or not stripped or not (stripped.lstrip("-").isdigit() and stripped.count("-") <= 1):
        return None
    return int(stripped)


def _as_real(text: str) -> float | None:
    if text != text.strip() or not text or "_" in text or text.startswith("+") or text.lower() in ("nan", "inf", "-inf", "infinity", "-infinity"):
        return None
    try:
        return float(text)
    except ValueError:
        return None


def cases_match(variable: str, case: str) -> bool:
    """BT.CPP ``CheckStringEquality``: equal text, equal whole integers, or reals within float epsilon."""
    if variable == case:
        return True
    a, b = _as_int(variable), _as_int(case)
    if a is not None and b is not None and a == b:
        return True
    x, y = _as_real(variable), _as_real(case)
    return x is not None and y is not None and abs(x - y) <= FLOAT_EPSILON


class _Switch(ControlNode):
    cases: ClassVar[int]

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.running_child = -1

    @classmethod
    def check_children(cls, n: int) -> str | None:
        wanted = cls.cases + 1
        return None if n == wanted else f"{cls.__name__} needs {wanted} children ({cls.cases} cases and the default), got {n}"

    def _read(self, port: str) -> str | None:
        if not self.is_port_set(port):
            return None
        try:
            value: str | None = self.get_input(port)
            return value
        except PortError:  # BT.CPP: getInput fails, the case (or the variable) is passed over
            return None

    def selected(self) -> int:
        variable = self._read("variable")
        if variable is None:
            return self.cases
        for index in range(self.cases):
            case = self._read(f"case_{index + 1}")
            if case is not None and cases_match(variable, case):
                return index
        return self.cases

    def run(self) -> TickGenerator:
        match = self.selected()
        if self.running_child not in (-1, match):
            halt_child(self.children[self.running_child])
        self.status = Status.RUNNING
        result = yield from self.tick_child(self.children[match])
        if result is SKIPPED:
            self.running_child = -1
            return SKIPPED
        if result is Status.RUNNING:
            self.running_child = match
        else:
            self.reset_children()
            self.running_child = -1
        return result

    def halt(self) -> None:
        self.running_child = -1
        super().halt()


def _ports(cases: int) -> tuple[Any, ...]:
    return (
        InputPort("variable", PortType.STRING, None, "The value compared with each case."),
        *(InputPort(f"case_{i}", PortType.STRING, None, f"Value that selects child {i}.") for i in range(1, cases + 1)),
    )


def _switch(cases: int) -> type[_Switch]:
    return type(
        f"Switch{cases}",
        (_Switch,),
        {
            "cases": cases,
            "ports": _ports(cases),
            "description": (
                f"Ticks the child whose case_1..case_{cases} equals 'variable' (as text or as a number); "
                f"the last of its {cases + 1} children is the default."
            ),
            "__module__": __name__,
            "__doc__": f"BT.CPP ``SwitchNode<{cases}>``.",
        },
    )


Switch2, Switch3, Switch4, Switch5, Switch6 = (_switch(n) for n in range(2, 7))
NODES = (Switch2, Switch3, Switch4, Switch5, Switch6)

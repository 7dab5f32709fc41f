"""Run one BT.CPP v4 XML tree in our runtime and in BehaviorTree.CPP (behaviortreepy), tick by tick.

Both engines get the same two scripted leaves, registered under the same IDs, whose behaviour is
spelled in their ``name`` (BT.CPP's Python bindings give simple nodes no ports):

* ``<Step name="a:RRS"/>`` — a stateful action (BT.CPP ``StatefulActionNode``): each time it is
  ticked it returns the next letter of ``RRS`` (R=RUNNING, S=SUCCESS, F=FAILURE), cycling; it
  records ``start`` (first tick of a run), ``run`` (later ticks) and ``halt`` (halted while
  RUNNING). Like a BT.CPP stateful action, once finished it returns the same status without
  running again until its parent resets it.
* ``<Check name="c:SF"/>`` — a condition returning the next letter on every tick; records
  ``check``.

A case file is a BTCPP_format="4" XML document starting with a comment of ``key: value`` lines:

    ticks: 6           how many ticks to run (default 5)
    main: Top          BT.CPP creates this tree by ID (``createTree``) instead of from the file's
                       main_tree_to_execute; ours picks the main tree itself
    since: 4.10        the BT.CPP release the case needs (behaviortreepy is 4.8.2: such cases hold
                       expectations taken from that release's source and are not run in BT.CPP)
    dt_ms: 100         time between ticks: our SimClock advances, BT.CPP sleeps (wall time)
    keys: n x          blackboard entries compared after every tick
    expect: RUNNING SUCCESS ...   the statuses both engines must produce (ERROR: the tick raised;
                       REFUSED alone: the tree is refused at load)
    refused: TEXT      with ``expect: REFUSED``, what both engines' load errors say

Our side ticks through ``runtime.tree.controls.tick_tree``, the one tick loop the runner uses; BT.CPP
is ticked with ``tickExactlyOnce`` (one pass per tick, the semantics ``tick_tree`` implements; its
``tickOnce`` re-ticks on a wake-up signal and never returns from an endless synchronous loop).

``run_ours`` and ``run_btcpp`` return a ``Run``: per tick the root's status, the leaves' events
and the listed blackboard values.
"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from runtime.tree import builtin
from runtime.tree.behavior import Behavior, NodeKind, RunContext, Status
from runtime.io.bus import InProcessBus
from runtime.io.clock import SimClock
from runtime.tree.controls import COMPLETED, tick_tree
from runtime.errors import LoadError
from runtime.tree.events import EventLog
from runtime.tree.registry import Registry
from runtime.tree.resources import Resource

TRACE: Resource[list[tuple[str, str]]] = Resource("conformance.trace")
"""What the traced nodes did, in order: (label, event)."""


def trace_of(context: RunContext) -> list[tuple[str, str]]:
    trace = context.resources.get(TRACE)
    assert trace is not None, "the harness sets the trace before the tree loads"
    return trace


CASES_DIR = Path(__file__).parent / "cases"
LETTERS = {"R": "RUNNING", "S": "SUCCESS", "F": "FAILURE"}
REFUSED = "REFUSED"
"""The one status of a case whose tree is refused at load."""
_HEADER = re.compile(r"^\s*(ticks|main|since|dt_ms|keys|expect|refused)\s*:\s*(.*?)\s*$", re.MULTILINE)


@dataclass(frozen=True)
class Case:
    name: str
    xml: str
    ticks: int = 5
    main: str = ""
    since: str = ""
    dt_ms: int = 0
    keys: tuple[str, ...] = ()
    expect: tuple[str, ...] = ()
    refused: str = ""

    @classmethod
    def load(cls, path: Path) -> Case:
        xml = path.read_text()
        comment = re.search(r"<!--(.*?)-->", xml, re.DOTALL)
        fields = dict(_HEADER.findall(comment.group(1))) if comment else {}
        case = cls(
            name=path.stem,
            xml=xml,
            ticks=int(fields.get("ticks", 5)),
            main=fields.get("main", ""),
            since=fields.get("since", ""),
            dt_ms=int(fields.get("dt_ms", 0)),
            keys=tuple(fields.get("keys", "").split()),
            expect=tuple(fields.get("expect", "").split()),
            refused=fields.get("refused", ""),
        )
        return case


def all_cases() -> list[Case]:
    return [Case.load(p) for p in sorted(CASES_DIR.glob("*.xml"))]


@dataclass
class Run:
    statuses: list[str] = field(default_factory=list)
    events: list[list[tuple[str, str]]] = field(default_factory=list)
    values: list[dict[str, Any]] = field(default_factory=list)
    error: str | None = None


def _script(name: str) -> tuple[str, str]:
    label, _, letters = name.partition(":")
    if not letters or set(letters) - set(LETTERS):
        raise ValueError(f"scripted leaf name {name!r} must look like 'label:RRS' (letters R, S, F)")
    return label, letters


def _number_or_text(value: Any) -> Any:
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, (int, float)):
        return float(value)
    try:
        return float(value)
    except (TypeError, ValueError):
        return str(value)


# -- our engine ------------------------------------------------------------------------------------
class Step(Behavior):
    """The scripted stateful action, for our runtime (see the module docstring)."""

    kind: ClassVar[NodeKind] = NodeKind.ACTION
    description: ClassVar[str] = "Test leaf: returns the statuses spelled after ':' in its name."

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.label, self.letters = _script(name)
        self.count = 0
        self.fresh = True

    def record(self, event: str) -> None:
        trace_of(self.context).append((self.label, event))

    def tick(self):  # type: ignore[override]
        if self.status in COMPLETED:  # BT.CPP StatefulActionNode: a finished node is not re-run
            yield self
            return
        yield from super().tick()

    def initialise(self) -> None:
        self.fresh = True

    def update(self) -> Status:
        self.record("start" if self.fresh else "run")
        self.fresh = False
        letter = self.letters[self.count % len(self.letters)]
        self.count += 1
        return Status[LETTERS[letter]]

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID and self.status is Status.RUNNING:
            self.record("halt")


class Check(Behavior):
    """The scripted condition, for our runtime."""

    kind: ClassVar[NodeKind] = NodeKind.CONDITION
    description: ClassVar[str] = "Test condition: returns the statuses spelled after ':' in its name."

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.label, self.letters = _script(name)
        self.count = 0

    def update(self) -> Status:
        trace_of(self.context).append((self.label, "check"))
        letter = self.letters[self.count % len(self.letters)]
        self.count += 1
        return Status[LETTERS[letter]]


def _our_value(board: Any, key: str) -> Any:
    value = board.get(key) if board.has(key) else None
    return None if value is None else _number_or_text(value)


def run_ours(case: Case) -> Run:
    from runtime.tree.loader import load_tree

    registry = Registry()
    builtin.register(registry)
    registry.register_all((Step, Check))
    clock = SimClock()
    context = RunContext(clock=clock, bus=InProcessBus(clock), events=EventLog(clock))
    trace: list[tuple[str, str]] = []
    context.resources.set(TRACE, trace)
    try:
        tree = load_tree(case.xml, registry, context)
    except LoadError as err:
        return Run(statuses=[REFUSED], error=str(err))
    run = Run()
    for index in range(case.ticks):
        if index and case.dt_ms:
            clock.advance(case.dt_ms / 1000.0)
        try:
            result = tick_tree(tree.root).status
        except Exception as err:  # noqa: BLE001 - the comparison records that the tick raised
            run.error = f"{type(err).__name__}: {err}"
            run.statuses.append("ERROR")
            run.events.append(list(trace))
            break
        run.statuses.append("SKIPPED" if result is Status.INVALID else result.name)
        run.events.append(list(trace))
        run.values.append({key: _our_value(tree.blackboard, key) for key in case.keys})
        trace.clear()
    return run


# -- BehaviorTree.CPP --------------------------------------------------------------------------------
def _bt_value(board: Any, key: str) -> Any:
    if key not in board.get_keys():
        return None
    try:
        return float(board.get_double(key))
    except Exception:  # noqa: BLE001 - not a number: read it as text
        pass
    try:
        return str(board.get_string(key))
    except Exception:  # noqa: BLE001 - an entry created for a port and never written
        return None


def run_btcpp(case: Case) -> Run:
    import behaviortreepy as bt

    trace: list[tuple[str, str]] = []
    counts: dict[str, int] = {}

    def next_status(node: Any) -> Any:
        label, letters = _script(node.name())
        index = counts.get(node.name(), 0)
        counts[node.name()] = index + 1
        return getattr(bt.NodeStatus, LETTERS[letters[index % len(letters)]])

    def on_start(node: Any) -> Any:
        trace.append((_script(node.name())[0], "start"))
        return next_status(node)

    def on_running(node: Any) -> Any:
        trace.append((_script(node.name())[0], "run"))
        return next_status(node)

    def on_halted(node: Any) -> None:
        trace.append((_script(node.name())[0], "halt"))

    def check(node: Any) -> Any:
        trace.append((_script(node.name())[0], "check"))
        return next_status(node)

    factory = bt.BehaviorTreeFactory()
    factory.register_simple_stateful_action("Step", on_start, on_running, on_halted)
    factory.register_simple_condition("Check", check)
    try:
        if case.main:
            factory.register_behavior_tree_from_text(case.xml)
            tree = factory.create_tree(case.main)
        else:
            tree = factory.create_tree_from_text(case.xml)
    except Exception as err:  # noqa: BLE001 - BT.CPP's load errors have no common Python class
        return Run(statuses=[REFUSED], error=f"{type(err).__name__}: {err}")
    board = tree.root_blackboard()
    run = Run()
    for index in range(case.ticks):
        if index and case.dt_ms:
            time.sleep(case.dt_ms / 1000.0)
        try:
            result = tree.tick_exactly_once()
        except Exception as err:  # noqa: BLE001
            run.error = f"{type(err).__name__}: {err}"
            run.statuses.append("ERROR")
            run.events.append(list(trace))
            break
        run.statuses.append(result.name)
        run.events.append(list(trace))
        run.values.append({key: _bt_value(board, key) for key in case.keys})
        trace.clear()
    tree.halt_tree()
    return run


def run_in_runner(case: Case) -> tuple[str, int]:
    """Run the case with ``runtime.app.runner.run_tree``, the loop ``objective run`` uses.

    Returns how the run ended ("SUCCESS", "FAILURE", "SKIPPED" or "ERROR") and after how many
    ticks; the runner ticks every ``dt_ms`` (10 ms when the case sets none).
    """
    from runtime.errors import ObjectiveError
    from runtime.tree.loader import load_tree
    from runtime.app.runner import RunOptions, make_context, run_tree

    registry = Registry()
    builtin.register(registry)
    registry.register_all((Step, Check))
    options = RunOptions(tick_hz=1000.0 / (case.dt_ms or 10), max_seconds=(case.ticks * (case.dt_ms or 10) + 1) / 1000.0)
    context = make_context(options)
    context.resources.set(TRACE, [])
    tree = load_tree(case.xml, registry, context, case.main or None)
    try:
        result = run_tree(tree, context, options)
    except ObjectiveError:
        return "ERROR", round(context.clock.now() * 1000.0 / (case.dt_ms or 10))
    return result.status, result.ticks

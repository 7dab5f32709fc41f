"""The base every XML-nameable node builds on: ports, blackboard access and the run context.

Leaves subclass ``Behavior`` (a ``py_trees.behaviour.Behaviour``) and write the usual small
lifecycle methods: ``initialise`` when a run of the node starts, ``update`` once per tick, and
``terminate`` when it ends or is halted (``new_status == INVALID``: stop what you started).
A node reports why it failed in ``feedback_message``; the runner prints it.
"""
from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Iterator, Protocol, runtime_checkable

import py_trees

from .blackboard import Blackboard
from runtime.errors import PortError, SourceLocation, did_you_mean
from .ports import ConversionError, Direction, PortInfo, convert, parse_reference, range_problem
from .resources import Resources

if TYPE_CHECKING:
    from runtime.io.bus import Bus
    from runtime.io.clock import Clock
    from .events import EventLog
    from .world import Scene, World

Status = py_trees.common.Status


@runtime_checkable
class SummarisesRun(Protocol):
    """A node that adds facts to the run's summary (ExecutePolicy: its chunks, latencies and
    stalls); the runner merges them into the summary, the progress line and the Objective server's
    feedback show them while it runs."""

    def run_summary(self) -> dict[str, Any] | None:
        """JSON-serialisable facts of this node's runs so far (None or empty: none)."""
        ...


class NodeKind(enum.Enum):
    ACTION = "Action"
    CONDITION = "Condition"
    CONTROL = "Control"
    DECORATOR = "Decorator"
    SUBTREE = "SubTree"


@dataclass
class RunContext:
    """What every node of one run shares: time, the bus, the world model, the event log.

    ``scene`` is the planning scene the world fills in (None for trees that never move a robot);
    ``world`` is the simulated world when the run hosts one (behaviors must not reach into it: it
    exists for world-level nodes such as ResetSim and for the runner); both are protocols of
    ``runtime.tree.world``. ``resources`` holds per-run objects that plug-ins share, each under a
    typed key of ``runtime.tree.resources`` (the world's ``WAYPOINTS``; ExecutePolicy's runs). ``tick_period_s`` is the clock
    time between two ticks of the tree (the runner's ``1 / tick_hz``). ``stamp_offset_s`` is what
    turns a time on ``clock`` into a stamp the robot's controllers read: 0 when they keep the run's
    time (in process, a hosted cell, a robot on ``/clock`` with ``--use-sim-time``); on a real robot
    over ROS 2, the ROS time (the system clock) at the run's clock zero.
    """

    clock: Clock
    bus: Bus
    events: EventLog
    scene: Scene | None = None
    world: World | None = None
    seed: int = 0
    tick_period_s: float = 0.01
    stamp_offset_s: float = 0.0
    resources: Resources = field(default_factory=Resources)
    logger: logging.Logger = field(default_factory=lambda: logging.getLogger("objective"))


@dataclass
class PortBinding:
    """The value a port gets in one node instance: a converted literal, or a blackboard key."""

    info: PortInfo
    literal: Any = None
    key: str | None = None


class NodeMixin:
    """Ports and blackboard access shared by leaves, controls, decorators and SubTrees."""

    ports: ClassVar[tuple[PortInfo, ...]] = ()
    description: ClassVar[str] = ""
    kind: ClassVar[NodeKind] = NodeKind.ACTION
    needs_world: ClassVar[bool] = False
    """True for nodes that talk to a robot or a simulated cell: the runner starts a world for them."""

    # Set by ``bind`` (the loader calls it right after construction).
    bindings: dict[str, PortBinding]
    blackboard: Blackboard
    context: RunContext
    location: SourceLocation | None
    xml_id: str

    @classmethod
    def port_info(cls) -> dict[str, PortInfo]:
        return {p.name: p for p in cls.ports}

    def bind(
        self,
        context: RunContext,
        blackboard: Blackboard,
        values: dict[str, str] | None = None,
        location: SourceLocation | None = None,
        xml_id: str | None = None,
    ) -> None:
        """Attach this instance to a run and bind its ports from XML strings.

        Unknown ports, missing required ports and unconvertible literals raise ``PortError``.
        """
        self.context = context
        self.blackboard = blackboard
        self.location = location
        self.xml_id = xml_id or type(self).__name__
        self.bindings = make_bindings(type(self), values or {}, location, self.xml_id)
        for binding in self.bindings.values():
            if binding.key is not None:
                blackboard.declare(binding.key)  # as BT.CPP creates a port's entry when it builds the tree
        self.check_literals()

    def check_literals(self) -> None:
        """Override to reject bad literal port values at load time (beyond their type).

        Raise PortError/LoadError; ``self.bindings``, ``self.location`` and ``self.xml_id`` are set.
        """

    # -- reading and writing ports ----------------------------------------------------------
    def get_input(self, name: str) -> Any:
        """The port's value now: a literal, or the referenced blackboard entry converted.

        Raises PortError when a referenced entry is missing, does not convert or is outside the
        port's valid range.
        """
        binding = self.bindings[name]
        if binding.key is None:
            return binding.literal
        if not self.blackboard.has(binding.key) or self.blackboard.get(binding.key) is None:
            raise PortError(
                f"port '{name}' reads {self.blackboard.unset_reason(binding.key)}",
                self.location,
                self.xml_id,
            )
        raw = self.blackboard.get(binding.key)
        try:
            value = convert(raw, binding.info.type)
        except ConversionError as err:
            raise PortError(f"port '{name}' (from '{{{binding.key}}}') {err}", self.location, self.xml_id) from None
        problem = range_problem(binding.info, value)
        if problem is not None:
            raise PortError(f"port '{name}' (from '{{{binding.key}}}') {problem}", self.location, self.xml_id)
        return value

    def set_output(self, name: str, value: Any) -> None:
        """Write an output port; does nothing when the XML left the port unconnected."""
        binding = self.bindings[name]
        if binding.info.direction is Direction.INPUT:
            raise PortError(f"port '{name}' is an input port", self.location, self.xml_id)
        if binding.key is not None:
            self.blackboard.set(binding.key, value)

    def is_port_set(self, name: str) -> bool:
        binding = self.bindings[name]
        return binding.key is not None or binding.literal not in (None, "")


def make_bindings(
    cls: type[NodeMixin],
    values: dict[str, str],
    location: SourceLocation | None,
    xml_id: str,
) -> dict[str, PortBinding]:
    """Check XML attribute values against ``cls.ports`` and convert the literals.

    Every port is checked: the PortError raised is the first problem, and its ``also`` holds
    the others (``objective validate`` reports each).
    """
    infos = cls.port_info()
    problems: list[PortError] = []
    for name in values:
        if name not in infos:
            known = ", ".join(sorted(infos)) or "none"
            problems.append(PortError(f"unknown port '{name}'{did_you_mean(name, infos)} (ports: {known})", location, xml_id))
    bindings: dict[str, PortBinding] = {}
    for name, info in infos.items():
        try:
            bindings[name] = _binding(name, info, values, location, xml_id)
        except PortError as err:
            problems.append(err)
    if problems:
        problems[0].also = tuple(problems[1:])
        raise problems[0]
    return bindings


def _binding(name: str, info: PortInfo, values: dict[str, str], location: SourceLocation | None, xml_id: str) -> PortBinding:
    """Port ``name``'s binding from its XML value (or its default); PortError if it has none that works."""
    if name in values:
        raw: Any = values[name]
    elif info.required:
        raise PortError(f"missing required port '{name}'", location, xml_id)
    else:
        # an output's default, if any, is the "{key}" it writes when the XML leaves it unset
        raw = info.default if info.direction is not Direction.OUTPUT or isinstance(info.default, str) else None
    if raw is None:
        return PortBinding(info)
    try:
        key = parse_reference(raw, name) if isinstance(raw, str) else None
    except ValueError as err:
        raise PortError(f"port '{name}': {err}", location, xml_id) from None
    if key is not None:
        return PortBinding(info, key=key)
    if info.direction is Direction.OUTPUT:
        raise PortError(
            f"output port '{name}' must name a blackboard entry like '{{{name}}}', got {raw!r}",
            location,
            xml_id,
        )
    try:
        literal = convert(raw, info.type)
    except ConversionError as err:
        raise PortError(f"port '{name}' {err}", location, xml_id) from None
    problem = range_problem(info, literal)
    if problem is not None:
        raise PortError(f"port '{name}' {problem}", location, xml_id)
    return PortBinding(info, literal=literal)


class Behavior(NodeMixin, py_trees.behaviour.Behaviour):
    """A leaf the XML can name: an Action (does something) or a Condition (checks something)."""

    kind: ClassVar[NodeKind] = NodeKind.ACTION
    failure_kind: str | None = None
    """What kind of failure this node's last FAILURE was (``fail(reason, kind)``), for grouping
    runs by it; None when the node does not say."""

    def __init__(self, name: str) -> None:
        super().__init__(name=name)

    def tick(self) -> Iterator[py_trees.behaviour.Behaviour]:
        """py_trees' ``Behaviour.tick``, less its debug line (formatted at every tick of every
        leaf, logged or not) and its list of every status per tick: initialise unless RUNNING,
        update, stop on a result other than RUNNING, then yield this node."""
        if self.status != Status.RUNNING:
            self.failure_kind = None
            self.initialise()
        new_status = self.update()
        if not isinstance(new_status, Status):
            self.logger.error(f"A behaviour returned an invalid status, setting to INVALID [{new_status}][{self.name}]")
            new_status = Status.INVALID
        if new_status != Status.RUNNING:
            self.stop(new_status)
        self.status = new_status
        yield self

    def fail(self, reason: str, kind: str | None = None) -> Status:
        """Record why this node fails (and what kind of failure it is) and return FAILURE
        (``return self.fail("...")``)."""
        self.feedback_message = reason
        self.failure_kind = kind
        return Status.FAILURE


class Condition(Behavior):
    """A leaf that answers in the tick it runs and never returns RUNNING."""

    kind: ClassVar[NodeKind] = NodeKind.CONDITION

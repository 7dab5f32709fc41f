"""Control nodes with BehaviorTree.CPP v4 semantics, built on py_trees composites.

Every node here re-implements py_trees' ``tick()`` generator so that it does exactly what the
matching BT.CPP 4.8 ``tick()`` does (the source files are named in each class docstring). The
rules below are shared by controls, decorators (``runtime.tree.decorators``) and the pre/post
condition guard (``runtime.tree.conditions``).

How a BT.CPP status maps onto py_trees
    IDLE is ``Status.INVALID``; RUNNING, SUCCESS and FAILURE are themselves. py_trees has no
    SKIPPED, so a node that is skipped in a tick sets ``node.skipped = True`` for that tick and
    leaves its status alone (BT.CPP also keeps the old status of a skipped node: normally IDLE).
    ``tick_child`` turns that into the tick result ``SKIPPED`` (an alias of ``Status.INVALID``:
    a child can never legitimately *return* INVALID, so as a result it can only mean skipped).
    Any node that passes its child's result through (a SubTree, say) should copy ``skipped``.

Halting versus resetting
    BT.CPP distinguishes ``haltChild`` (call ``halt`` on a RUNNING child, then set it IDLE) from
    ``resetStatus`` (set IDLE, no callback). ``halt_child`` calls ``child.stop(INVALID)`` only on
    a RUNNING child — for a leaf that is ``terminate(INVALID)``, "stop what you started" — and
    otherwise just sets the status back to INVALID. So a leaf's ``terminate(INVALID)`` runs only
    when it is preempted, never after it already finished. Our composites' ``stop(INVALID)`` is
    BT.CPP's ``halt()``: it halts running children and resets the others.

One tick is one pass
    ``tick_tree`` ticks the root once (BT.CPP ``tickExactlyOnce``) and is the only tick loop:
    the runner and the conformance suite both call it. No node loops inside a tick: Repeat,
    RetryUntilSuccessful, SequenceWithMemory, AsyncSequence/AsyncFallback and the Loop nodes
    return RUNNING after a child that completed synchronously (it was IDLE before the tick),
    exactly where BT.CPP 4.x emits its wake-up signal, and go on at the next tick. BT.CPP's
    ``tickOnce`` re-ticks the whole tree at once on that signal, which finishes a
    ``Repeat num_cycles="3"`` of a synchronous child within one call but never returns from
    ``num_cycles="-1"`` (measured with behaviortreepy: the process spins at 100 % CPU and no
    Timeout, ``_while`` or Parallel sibling can stop it). Here every iteration is a tick, so a
    loop is always interruptible and the runner's clock, Timeouts and halts reach it.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any, ClassVar, Generator, Iterator

import py_trees

from . import node_info
from .behavior import NodeKind, NodeMixin, Status
from runtime.errors import ObjectiveError
from .ports import INT32_MAX, INT32_MIN, InputPort, PortType, Range

Behaviour = py_trees.behaviour.Behaviour
TickGenerator = Generator[Behaviour, None, Status]

SKIPPED = Status.INVALID
"""As the *result* of a child's tick (never as a stored status): the child was skipped."""

COMPLETED = (Status.SUCCESS, Status.FAILURE)


# -- the node protocol shared by controls, decorators and condition guards --------------------
def tick_child(child: Behaviour) -> TickGenerator:
    """Tick ``child`` (yielding what it visits, as py_trees expects) and return its result.

    Use it as ``result = yield from tick_child(child)``; ``result`` is RUNNING, SUCCESS,
    FAILURE or SKIPPED.
    """
    yield from child.tick()
    if node_info.is_skipped(child):
        return SKIPPED
    if child.status is Status.INVALID:
        raise ObjectiveError(
            "returned INVALID from a tick: a node must return RUNNING, SUCCESS or FAILURE",
            node_info.location(child),
            f"{node_info.xml_id(child)} '{child.name}'",
        )
    return child.status


def halt_child(child: Behaviour) -> None:
    """BT.CPP ``haltChild``: halt the child if it is RUNNING, then set it back to idle."""
    if child.status is Status.RUNNING:
        child.stop(Status.INVALID)
    reset_status(child)


def reset_status(node: Behaviour) -> None:
    """BT.CPP ``resetStatus``: back to idle without any callback (the node already finished)."""
    node.status = Status.INVALID


Visit = tuple[Behaviour, Status, str]
"""A node that reported in a tick, with the status and feedback message it reported."""


@dataclass(frozen=True)
class Tick:
    """What one tick of the tree gave: the root's result and every node that reported."""

    status: Status
    """RUNNING, SUCCESS, FAILURE or SKIPPED (``Status.INVALID``)."""
    visited: list[Visit]
    """Post-order: each node visited, with the status and message it had when it reported."""


def tick_tree(root: Behaviour) -> Tick:
    """One tick of the tree (BT.CPP ``tickExactlyOnce``): the runner's and the tests' only tick loop.

    Like BT.CPP's tree, a root that completed is set back to idle so its next tick starts a
    fresh run.
    """
    visited = [(node, node.status, node.feedback_message) for node in root.tick()]
    result = SKIPPED if node_info.is_skipped(root) else root.status
    if result in COMPLETED:
        reset_status(root)
    return Tick(result, visited)


def tick_root(root: Behaviour) -> Status:
    """``tick_tree(root).status``: one tick, for callers that only need the result."""
    return tick_tree(root).status


def _at_tree_root(node: Behaviour) -> bool:
    """True when only transparent wrappers (condition guards) sit above ``node``."""
    parent = node.parent
    while parent is not None and node_info.is_transparent(parent):
        parent = parent.parent
    return parent is None


# -- base classes --------------------------------------------------------------------------------
class _BtComposite(NodeMixin, py_trees.composites.Composite):
    """What controls and decorators share: BT.CPP's tick/halt protocol on a py_trees composite.

    Subclasses write ``run(self)``, a generator holding BT.CPP's ``tick()`` body (children are
    ticked with ``yield from tick_child(child)``) that returns the node's result, and extend
    ``halt()`` to reset their own state.
    """

    skipped: bool

    def __init__(self, name: str) -> None:
        super().__init__(name=name, children=None)
        self.skipped = False

    def add_child(self, child: Behaviour) -> Any:
        return super().add_child(child)

    @abc.abstractmethod
    def run(self) -> TickGenerator:
        """BT.CPP's ``tick()`` of this node: tick children via ``yield from self.tick_child``."""

    def tick(self) -> Iterator[Behaviour]:
        result = yield from self.run()
        self.skipped = result is SKIPPED
        if not self.skipped:  # BT.CPP keeps the previous status of a skipped node
            self.status = result
        yield self

    def tick_child(self, child: Behaviour) -> TickGenerator:
        self.current_child = child
        return (yield from tick_child(child))

    def was_active(self) -> bool:
        """BT.CPP ``isStatusActive(status())`` at the start of a tick.

        A node that finished keeps SUCCESS/FAILURE until its parent resets it; the tree resets
        its root itself, which ``tick_root`` does and a plain py_trees tick does not, so a root
        that finished counts as idle here.
        """
        if self.status is Status.INVALID:
            return False
        return self.status is Status.RUNNING or not _at_tree_root(self)

    def halt(self) -> None:
        """BT.CPP ``halt()``: halt running children, reset the others, become idle."""
        for child in self.children:
            halt_child(child)
        self.current_child = None

    def stop(self, new_status: Status = Status.INVALID) -> None:
        if new_status is Status.INVALID:
            self.halt()
        self.terminate(new_status)
        self.status = new_status
        self.iterator = self.tick()

    def reset_children(self) -> None:
        """BT.CPP ``resetChildren``: the same as halting every child."""
        for child in self.children:
            halt_child(child)

    def fail_now(self, what: str) -> ObjectiveError:
        return ObjectiveError(what, self.location, f"{self.xml_id} '{self.name}'")


class ControlNode(_BtComposite):
    """A node with one or more children that decides which to tick."""

    kind: ClassVar[NodeKind] = NodeKind.CONTROL

    @classmethod
    def check_children(cls, n: int) -> str | None:
        return None if n >= 1 else f"a {cls.__name__} needs at least one child, got none"


class DecoratorNode(_BtComposite):
    """A node with exactly one child whose result it transforms.

    Like BT.CPP's ``DecoratorNode::executeTick``, a child that finished (SUCCESS or FAILURE) is
    set back to idle after every tick of the decorator.
    """

    kind: ClassVar[NodeKind] = NodeKind.DECORATOR

    @classmethod
    def check_children(cls, n: int) -> str | None:
        return None if n == 1 else f"a decorator takes exactly one child, got {n}"

    def add_child(self, child: Behaviour) -> Any:
        if self.children:
            raise ValueError(f"decorator '{self.name}' already has a child")
        return super().add_child(child)

    @property
    def child(self) -> Behaviour:
        return self.children[0]

    def tick(self) -> Iterator[Behaviour]:
        for visited in super().tick():
            if visited is self and self.child.status in COMPLETED:
                reset_status(self.child)
            yield visited


# -- sequences and fallbacks ---------------------------------------------------------------------
class _InOrder(ControlNode):
    """What Sequence, Fallback, their variants and TryCatch share: a position and a skip count."""

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.index = 0
        self.skipped_count = 0

    def finish(self, count: int, result: Status) -> Status:
        """Every one of ``count`` children is done: start over next time; SKIPPED if all were skipped."""
        all_skipped = self.skipped_count == count
        self.reset_children()
        self.index = 0
        self.skipped_count = 0
        return SKIPPED if all_skipped else result

    def halt(self) -> None:
        self.index = 0
        self.skipped_count = 0
        super().halt()


class _Ordered(_InOrder):
    """Sequence and Fallback: tick children in order until one returns ``stops_on``.

    ``yields_between_children`` (AsyncSequence, AsyncFallback): RUNNING after a child that
    finished at once without deciding, and the next child goes on at the next tick.
    """

    stops_on: ClassVar[Status]
    completes_with: ClassVar[Status]
    yields_between_children: ClassVar[bool] = False

    def run(self) -> TickGenerator:
        count = len(self.children)
        if not self.was_active():
            self.skipped_count = 0
        self.status = Status.RUNNING
        while self.index < count:
            child = self.children[self.index]
            was_idle = child.status is Status.INVALID
            result = yield from self.tick_child(child)
            if result is Status.RUNNING:
                return Status.RUNNING
            if result is self.stops_on:
                self.reset_children()
                self.index = 0
                return result
            self.index += 1
            if result is SKIPPED:
                self.skipped_count += 1
            elif self.yields_between_children and was_idle and self.index < count:
                return Status.RUNNING
        return self.finish(count, self.completes_with)


class Sequence(_Ordered):
    """BT.CPP ``SequenceNode`` (src/controls/sequence_node.cpp)."""

    description: ClassVar[str] = (
        "Ticks its children in order while they succeed; SUCCESS when all succeed, FAILURE at the "
        "first failure (then it starts over). A RUNNING child is resumed next tick without "
        "re-ticking the ones before it. Skipped children are passed over; all skipped: skipped."
    )
    stops_on = Status.FAILURE
    completes_with = Status.SUCCESS


class SequenceWithMemory(_InOrder):
    """BT.CPP ``SequenceWithMemory`` (src/controls/sequence_with_memory_node.cpp)."""

    description: ClassVar[str] = (
        "Like Sequence, but a failure does not send it back to the first child: the next tick "
        "retries the child that failed. Halting it keeps its place too."
    )

    def run(self) -> TickGenerator:
        count = len(self.children)
        if not self.was_active():
            self.skipped_count = 0
        self.status = Status.RUNNING
        while self.index < count:
            child = self.children[self.index]
            was_idle = child.status is Status.INVALID
            result = yield from self.tick_child(child)
            if result is Status.RUNNING:
                return Status.RUNNING
            if result is Status.FAILURE:
                for later in self.children[self.index:]:
                    halt_child(later)
                return Status.FAILURE
            self.index += 1
            if result is SKIPPED:
                self.skipped_count += 1
            elif was_idle and self.index < count:
                return Status.RUNNING  # yield between synchronous children (see the module docstring)
        return self.finish(count, Status.SUCCESS)

    def halt(self) -> None:
        # Keeps its place on purpose: BT.CPP's SequenceWithMemory::halt resets neither counter.
        ControlNode.halt(self)


class Fallback(_Ordered):
    """BT.CPP ``FallbackNode`` (src/controls/fallback_node.cpp)."""

    description: ClassVar[str] = (
        "Ticks its children in order until one succeeds; SUCCESS at the first success, FAILURE "
        "when all fail. A RUNNING child is resumed next tick. Skipped children are passed over."
    )
    stops_on = Status.SUCCESS
    completes_with = Status.FAILURE


class AsyncSequence(Sequence):
    """BT.CPP ``SequenceNode`` registered as ``AsyncSequence`` (make_async = true)."""

    description: ClassVar[str] = (
        "Like Sequence, but returns RUNNING after each child that succeeded at once and ticks the "
        "next one at the next tick, so a long chain of quick children can be interrupted."
    )
    yields_between_children = True


class AsyncFallback(Fallback):
    """BT.CPP ``FallbackNode`` registered as ``AsyncFallback`` (make_async = true)."""

    description: ClassVar[str] = (
        "Like Fallback, but returns RUNNING after each child that failed at once and tries the "
        "next one at the next tick."
    )
    yields_between_children = True


class ReactiveSequence(ControlNode):
    """BT.CPP ``ReactiveSequence`` (src/controls/reactive_sequence.cpp)."""

    description: ClassVar[str] = (
        "Ticks every child from the first on every tick: FAILURE as soon as one fails (halting "
        "the running one), RUNNING at the first running child (halting any other), SUCCESS when "
        "all succeed. Use it to guard a long action with conditions checked every tick."
    )

    @classmethod
    def check_child_ids(cls, ids: list[str]) -> str | None:
        """BT.CPP's rule at load (``VerifyXML``, since 4.7): at most one AsyncSequence child. Two
        would take turns, each halting the other when it returns RUNNING, and never finish."""
        positions = [str(index + 1) for index, node_id in enumerate(ids) if node_id == "AsyncSequence"]
        if len(positions) <= 1:
            return None
        return (f"a ReactiveSequence cannot have more than one async child (BehaviorTree.CPP refuses it too): "
                f"children {', '.join(positions[:-1])} and {positions[-1]} are AsyncSequences, which would halt "
                f"each other in turn and never finish")

    def run(self) -> TickGenerator:
        all_skipped = True
        self.status = Status.RUNNING
        for index, child in enumerate(self.children):
            result = yield from self.tick_child(child)
            all_skipped = all_skipped and result is SKIPPED
            if result is Status.RUNNING:
                for other in self.children:
                    if other is not child:
                        halt_child(other)
                return Status.RUNNING
            if result is Status.FAILURE:
                self.reset_children()
                return Status.FAILURE
            if result is SKIPPED:
                halt_child(child)
        self.reset_children()
        return SKIPPED if all_skipped else Status.SUCCESS


class ReactiveFallback(ControlNode):
    """BT.CPP ``ReactiveFallback`` (src/controls/reactive_fallback.cpp)."""

    description: ClassVar[str] = (
        "Ticks every child from the first on every tick: SUCCESS as soon as one succeeds "
        "(halting the running one), RUNNING at the first running child (halting any other), "
        "FAILURE when all fail. Use it to stop an action once a check passes."
    )

    def run(self) -> TickGenerator:
        all_skipped = True
        self.status = Status.RUNNING
        for child in self.children:
            result = yield from self.tick_child(child)
            all_skipped = all_skipped and result is SKIPPED
            if result is Status.RUNNING:
                for other in self.children:
                    if other is not child:
                        halt_child(other)
                return Status.RUNNING
            if result is Status.SUCCESS:
                self.reset_children()
                return Status.SUCCESS
            if result is SKIPPED:
                halt_child(child)
        self.reset_children()
        return SKIPPED if all_skipped else Status.FAILURE


# -- parallel ------------------------------------------------------------------------------------
def resolve_threshold(value: int, children: int) -> int:
    """BT.CPP's reading of a Parallel count: negative counts from the end (-1 = all)."""
    return max(children + value + 1, 0) if value < 0 else value


class Parallel(ControlNode):
    """BT.CPP ``ParallelNode`` (src/controls/parallel_node.cpp)."""

    description: ClassVar[str] = (
        "Ticks all children every tick (finished ones are not ticked again): SUCCESS once "
        "success_count children succeeded, FAILURE once failure_count failed or success became "
        "impossible; then halts the rest. Negative counts mean 'all but N-1' (-1 = all)."
    )
    ports = (
        InputPort("success_count", PortType.INT, -1, "Children that must succeed (-1: all of them).", valid=Range(INT32_MIN, INT32_MAX)),
        InputPort("failure_count", PortType.INT, 1, "Children whose failure fails the Parallel (-1: all).", valid=Range(INT32_MIN, INT32_MAX)),
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.completed: set[int] = set()
        self.success_count = 0
        self.failure_count = 0

    def clear(self) -> None:
        self.completed.clear()
        self.success_count = 0
        self.failure_count = 0

    def run(self) -> TickGenerator:
        count = len(self.children)
        success_port = self.get_input("success_count")
        required_success = resolve_threshold(success_port, count)
        required_failure = resolve_threshold(self.get_input("failure_count"), count)
        if count < required_success:
            raise self.fail_now(
                f"success_count={success_port} needs {required_success} children to succeed, but it has {count}"
            )
        if count < required_failure:
            raise self.fail_now(
                f"failure_count needs {required_failure} children to fail, but it has {count}"
            )
        self.status = Status.RUNNING
        skipped = 0
        for index, child in enumerate(self.children):
            if index not in self.completed:
                result = yield from self.tick_child(child)
                if result is SKIPPED:
                    skipped += 1
                elif result is Status.SUCCESS:
                    self.completed.add(index)
                    self.success_count += 1
                elif result is Status.FAILURE:
                    self.completed.add(index)
                    self.failure_count += 1
            # BT.CPP checks the thresholds after each child, ticked or not.
            if self.success_count >= required_success or (
                success_port < 0 and self.success_count + skipped >= required_success
            ):
                self.clear()
                self.reset_children()
                return Status.SUCCESS
            if count - self.failure_count < required_success or self.failure_count == required_failure:
                self.clear()
                self.reset_children()
                return Status.FAILURE
        return SKIPPED if skipped == count else Status.RUNNING

    def halt(self) -> None:
        self.clear()
        super().halt()


class ParallelAll(ControlNode):
    """BT.CPP ``ParallelAllNode`` (src/controls/parallel_all_node.cpp)."""

    description: ClassVar[str] = (
        "Ticks all children until every one has finished; then FAILURE if at least max_failures "
        "of them failed, else SUCCESS."
    )
    ports = (
        InputPort("max_failures", PortType.INT, 1, "Failures that make it fail (-1: all children).", valid=Range(INT32_MIN, INT32_MAX)),
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.completed: set[int] = set()
        self.failure_count = 0

    def run(self) -> TickGenerator:
        count = len(self.children)
        max_failures = self.get_input("max_failures")
        threshold = resolve_threshold(max_failures, count)
        if count < threshold:
            raise self.fail_now(f"max_failures={max_failures} is more than its {count} children")
        self.status = Status.RUNNING
        skipped = 0
        for index, child in enumerate(self.children):
            if index in self.completed:
                continue
            result = yield from self.tick_child(child)
            if result is SKIPPED:
                skipped += 1
            elif result in COMPLETED:
                self.completed.add(index)
                if result is Status.FAILURE:
                    self.failure_count += 1
        if skipped == count:
            return SKIPPED
        if skipped + len(self.completed) >= count:
            self.reset_children()
            self.completed.clear()
            failed = self.failure_count >= threshold
            self.failure_count = 0
            return Status.FAILURE if failed else Status.SUCCESS
        return Status.RUNNING

    def halt(self) -> None:
        self.completed.clear()
        self.failure_count = 0
        super().halt()


# -- conditionals --------------------------------------------------------------------------------
class _TwoOrThreeChildren(ControlNode):
    @classmethod
    def check_children(cls, n: int) -> str | None:
        return None if n in (2, 3) else f"{cls.__name__} takes 2 or 3 children, got {n}"


class IfThenElse(_TwoOrThreeChildren):
    """BT.CPP ``IfThenElseNode`` (src/controls/if_then_else_node.cpp)."""

    description: ClassVar[str] = (
        "The first child is the condition: on SUCCESS it runs the second child, on FAILURE the "
        "third (or fails when there are only two). The condition is not re-checked while the "
        "chosen branch is RUNNING."
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.branch = 0

    def run(self) -> TickGenerator:
        self.status = Status.RUNNING
        if self.branch == 0:
            condition = yield from self.tick_child(self.children[0])
            if condition is Status.RUNNING:
                return Status.RUNNING
            if condition is Status.SUCCESS:
                self.branch = 1
            elif condition is Status.FAILURE:
                if len(self.children) < 3:
                    return Status.FAILURE
                self.branch = 2
            else:
                # BT.CPP 4.8 throws "Something unexpected happened in IfThenElseNode" here.
                raise self.fail_now("its condition (first child) was skipped; it must return SUCCESS or FAILURE")
        result = yield from self.tick_child(self.children[self.branch])
        if result is Status.RUNNING:
            return Status.RUNNING
        self.reset_children()
        self.branch = 0
        return result

    def halt(self) -> None:
        self.branch = 0
        super().halt()


class WhileDoElse(_TwoOrThreeChildren):
    """BT.CPP ``WhileDoElseNode`` (src/controls/while_do_else_node.cpp)."""

    description: ClassVar[str] = (
        "Re-checks the condition (first child) every tick: while it succeeds, ticks the second "
        "child; when it fails, halts the second and ticks the third (or fails with only two)."
    )

    def run(self) -> TickGenerator:
        self.status = Status.RUNNING
        condition = yield from self.tick_child(self.children[0])
        if condition is Status.RUNNING:
            return Status.RUNNING
        three = len(self.children) == 3
        if condition is Status.SUCCESS:
            if three:
                halt_child(self.children[2])
            result = yield from self.tick_child(self.children[1])
        elif condition is Status.FAILURE:
            if not three:
                result = Status.FAILURE
            else:
                halt_child(self.children[1])
                result = yield from self.tick_child(self.children[2])
        else:
            # BT.CPP 4.8 ends in "you are not allowed to set manually the status to IDLE" here.
            raise self.fail_now("its condition (first child) was skipped; it must return SUCCESS or FAILURE")
        if result is Status.RUNNING:
            return Status.RUNNING
        self.reset_children()
        return result


class TryCatch(_InOrder):
    """BT.CPP 4.10 ``TryCatchNode`` (src/controls/try_catch_node.cpp)."""

    description: ClassVar[str] = (
        "Runs every child but the last as a Sequence (the try block): SUCCESS when they all "
        "succeed. When one fails, the last child (catch) runs to completion and TryCatch returns "
        "FAILURE. With catch_on_halt=true, halting it during the try block runs the catch child too."
    )
    ports = (
        InputPort("catch_on_halt", PortType.BOOL, False, "Run the catch child when halted during the try block."),
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.in_catch = False

    @classmethod
    def check_children(cls, n: int) -> str | None:
        return None if n >= 2 else f"TryCatch needs at least 2 children (try block and catch), got {n}"

    def run(self) -> TickGenerator:
        if not self.was_active():
            self.skipped_count = 0
            self.in_catch = False
        self.status = Status.RUNNING
        try_count = len(self.children) - 1
        while not self.in_catch and self.index < try_count:
            result = yield from self.tick_child(self.children[self.index])
            if result is Status.RUNNING:
                return Status.RUNNING
            if result is Status.FAILURE:
                self.reset_children()
                self.index = 0
                self.in_catch = True  # the catch child runs in this same tick
            else:
                self.index += 1
                if result is SKIPPED:
                    self.skipped_count += 1
        if self.in_catch:
            result = yield from self.tick_child(self.children[-1])
            if result is Status.RUNNING:
                return Status.RUNNING
            self.reset_children()
            self.index = 0
            self.in_catch = False
            return Status.FAILURE
        return self.finish(try_count, Status.SUCCESS)

    def halt(self) -> None:
        if self.get_input("catch_on_halt") and not self.in_catch and self.status is Status.RUNNING:
            for child in self.children[:-1]:
                halt_child(child)
            catch = self.children[-1]
            for _ in tick_child(catch):  # best-effort cleanup, synchronously, inside the halt
                pass
            if catch.status is Status.RUNNING:
                halt_child(catch)
        self.in_catch = False
        super().halt()


NODES = (
    Sequence,
    AsyncSequence,
    SequenceWithMemory,
    Fallback,
    AsyncFallback,
    ReactiveSequence,
    ReactiveFallback,
    Parallel,
    ParallelAll,
    IfThenElse,
    WhileDoElse,
    TryCatch,
)

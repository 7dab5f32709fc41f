"""Nodes that react to a blackboard entry being written: WasEntryUpdated, SkipUnlessUpdated, WaitValueUpdate.

BT.CPP counts the writes of every entry (its ``sequence_id``; here ``Blackboard.version``); each
of these nodes remembers the count it saw last, so "updated" means "written since this node last
looked" (the first look after any write counts). ``entry`` names the entry, as ``{key}`` or as a
bare key. Sources: src/actions/updated_action.cpp and src/decorators/updated_decorator.cpp.
"""
from __future__ import annotations

from typing import ClassVar

from .behavior import Behavior, PortBinding, Status
from .blackboard import Blackboard
from .controls import SKIPPED, DecoratorNode, TickGenerator
from .ports import InputPort, PortType

_ENTRY = InputPort("entry", PortType.ANY, description="Entry to check: '{key}' or the key itself.")


class _WatchesEntry:
    """The entry's key and the write count seen last (0: never written)."""

    last_seen: int = 0
    # The node's own (NodeMixin's), which every class that mixes this in is.
    bindings: dict[str, PortBinding]
    blackboard: Blackboard

    def entry_key(self) -> str:
        binding = self.bindings["entry"]
        return binding.key if binding.key is not None else str(binding.literal)

    def updated(self) -> bool:
        """True when the entry exists and was written since the last call."""
        board = self.blackboard
        key = self.entry_key()
        if not board.has(key):
            return False
        current, previous = board.version(key), self.last_seen
        self.last_seen = current
        changed: bool = current != previous
        return changed


class WasEntryUpdated(_WatchesEntry, Behavior):
    """BT.CPP ``EntryUpdatedAction``."""

    description: ClassVar[str] = (
        "SUCCESS if the entry was written since this node last checked it, FAILURE if not (or if it does not exist)."
    )
    ports = (_ENTRY,)

    def update(self) -> Status:
        return Status.SUCCESS if self.updated() else self.fail(f"entry '{self.entry_key()}' was not updated")


class _EntryUpdatedDecorator(_WatchesEntry, DecoratorNode):
    """BT.CPP ``EntryUpdatedDecorator``: tick the child only when the entry was written."""

    if_not_updated: ClassVar[Status]
    ports = (_ENTRY,)

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.still_running = False

    def run(self) -> TickGenerator:
        if not self.still_running and not self.updated():
            return self.if_not_updated
        result = yield from self.tick_child(self.child)
        self.still_running = result is Status.RUNNING
        return result

    def halt(self) -> None:
        self.still_running = False
        super().halt()


class SkipUnlessUpdated(_EntryUpdatedDecorator):
    description: ClassVar[str] = (
        "Ticks its child only if the entry was written since the last check; otherwise it is skipped."
    )
    if_not_updated = SKIPPED


class WaitValueUpdate(_EntryUpdatedDecorator):
    description: ClassVar[str] = (
        "Returns RUNNING until the entry is written, then ticks its child."
    )
    if_not_updated = Status.RUNNING


NODES = (WasEntryUpdated, SkipUnlessUpdated, WaitValueUpdate)

"""Blackboards with BehaviorTree.CPP semantics: one per tree, SubTrees isolated unless remapped.

A SubTree instance gets its own ``Blackboard`` whose ``parent`` is the caller's. Keys listed in
``remapping`` (``port="{key}"`` on the SubTree node) read and write the parent's ``key``;
with ``autoremap`` every other key also goes to the parent. ``@key`` always means the root's key.
There is no global state: two trees in one process never share entries.
"""
from __future__ import annotations

from typing import Any, Iterator


class Blackboard:
    def __init__(
        self,
        parent: Blackboard | None = None,
        remapping: dict[str, str] | None = None,
        autoremap: bool = False,
    ) -> None:
        self.parent = parent
        self.remapping = dict(remapping or {})
        self.autoremap = autoremap
        self._entries: dict[str, Any] = {}

    @property
    def root(self) -> Blackboard:
        node = self
        while node.parent is not None:
            node = node.parent
        return node

    def _route(self, key: str) -> tuple[Blackboard, str] | None:
        """Where ``key`` lives if it belongs to an ancestor; None when it is local."""
        if key.startswith("@"):
            return self.root, key[1:]
        if self.parent is not None:
            if key in self.remapping:
                return self.parent, self.remapping[key]
            if self.autoremap and key not in self._entries:
                return self.parent, key
        return None

    def has(self, key: str) -> bool:
        route = self._route(key)
        if route is not None:
            board, mapped = route
            return board.has(mapped) if board is not self else mapped in self._entries
        return key in self._entries

    def get(self, key: str) -> Any:
        route = self._route(key)
        if route is not None:
            board, mapped = route
            if board is self:
                return self._entries[mapped]
            return board.get(mapped)
        if key not in self._entries:
            raise KeyError(key)
        return self._entries[key]

    def get_or(self, key: str, default: Any = None) -> Any:
        return self.get(key) if self.has(key) else default

    def set(self, key: str, value: Any) -> None:
        route = self._route(key)
        if route is not None:
            board, mapped = route
            if board is self:
                self._entries[mapped] = value
            else:
                board.set(mapped, value)
            return
        self._entries[key] = value

    def set_local(self, key: str, value: Any) -> None:
        """Write here even if the key is remapped (used for a SubTree's literal port values)."""
        self._entries[key] = value

    def unset(self, key: str) -> None:
        self._entries.pop(key, None)

    def items(self) -> Iterator[tuple[str, Any]]:
        """The entries stored on this blackboard (not its parent's)."""
        return iter(sorted(self._entries.items()))

    def __repr__(self) -> str:
        return f"Blackboard({dict(self._entries)!r}, remapping={self.remapping!r}, autoremap={self.autoremap})"

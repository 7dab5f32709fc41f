"""Blackboards with BehaviorTree.CPP semantics: one per tree, SubTrees isolated unless remapped.

A SubTree instance gets its own ``Blackboard`` whose ``parent`` is the caller's. Keys listed in
``remapping`` (``port="{key}"`` on the SubTree node) read and write the parent's ``key``;
with ``autoremap`` every other key also goes to the parent, except private keys (a leading
``_``), which stay in the SubTree as in BT.CPP. ``@key`` always means the root's key.
There is no global state: two trees in one process never share entries.

An entry can exist without a value: the loader ``declare``s every entry a port names
(``{key}``) when it builds the tree, as BT.CPP creates them, so a script may assign it with
``=``. Such an entry ``has`` the key, ``get`` gives None, and ``items`` leaves it out until it is
written. ``version`` counts the writes of an entry (BT.CPP's ``sequence_id``), for
WasEntryUpdated and friends.
"""
from __future__ import annotations

from typing import Any, Callable, Iterator


def is_private(key: str) -> bool:
    """BT.CPP's private keys (``_name``): never shared by ``_autoremap``."""
    return key.startswith("_")


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
        self._versions: dict[str, int] = {}

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
            if self.autoremap and key not in self._entries and not is_private(key):
                return self.parent, key
        return None

    def has(self, key: str) -> bool:
        """True when the entry exists (it may have no value yet: see ``declare``)."""
        board, mapped = self._owner(key)
        return mapped in board._entries

    def get(self, key: str) -> Any:
        """The entry's value (None for a declared entry never written); KeyError if it does not exist."""
        board, mapped = self._owner(key)
        if mapped not in board._entries:
            raise KeyError(key)
        return board._entries[mapped]

    def owner(self, key: str) -> tuple[Blackboard, str]:
        """The blackboard that stores ``key`` (after SubTree remapping), and the key's name there."""
        return self._owner(key)

    def _owner(self, key: str) -> tuple[Blackboard, str]:
        """The blackboard that stores ``key``, and the key's name there."""
        board, mapped = self, key
        route = board._route(mapped)
        while route is not None:
            if route[0] is board:
                return board, route[1]
            board, mapped = route
            route = board._route(mapped)
        return board, mapped

    def set(self, key: str, value: Any) -> None:
        board, mapped = self._owner(key)
        board._store(mapped, value)

    def _store(self, key: str, value: Any) -> None:
        self._entries[key] = value
        self._versions[key] = self._versions.get(key, 0) + 1

    def declare(self, key: str) -> None:
        """Create the entry without a value if it does not exist (BT.CPP creates port entries at load)."""
        board, mapped = self._owner(key)
        board._entries.setdefault(mapped, None)

    def version(self, key: str) -> int:
        """How many times the entry was written (0: never, or it does not exist)."""
        board, mapped = self._owner(key)
        return board._versions.get(mapped, 0)

    def set_local(self, key: str, value: Any) -> None:
        """Write here even if the key is remapped (used for a SubTree's literal port values)."""
        self._store(key, value)

    def unset(self, key: str) -> None:
        """Remove the entry if it is stored here (as BT.CPP, remapped entries are left alone)."""
        self._entries.pop(key, None)
        self._versions.pop(key, None)

    def items(self) -> Iterator[tuple[str, Any]]:
        """The entries stored on this blackboard (not its parent's) that hold a value."""
        return iter(sorted((k, v) for k, v in self._entries.items() if v is not None))

    def local_entries(self) -> dict[str, Any]:
        """Every entry stored on this blackboard, declared ones (None) included: a copy."""
        return dict(self._entries)

    def unset_reason(self, key: str, holds: Callable[[Blackboard, str], bool] | None = None) -> str:
        """Why reading ``key`` here finds no value, in the words of the tree that wrote the key:
        ``entry 'k', remapped to the caller's 'c', which is not set``, with a hint when a caller
        holds ``key`` but this SubTree's blackboard does not share it. ``holds(board, key)`` says
        whether an entry has a value (default: it holds one now)."""
        holds = holds or (lambda board, name: board._entries.get(name) is not None)
        text = f"blackboard entry '{key}'"
        board, mapped = self, key
        route = board._route(mapped)
        while route is not None and route[0] is not board:
            whose = "the root's" if mapped.startswith("@") else "the caller's"
            board, mapped = route
            text += f", remapped to {whose} '{mapped}'"
            route = board._route(mapped)
        text += ", which is not set"
        if board.parent is not None and not is_private(mapped):
            caller: Blackboard | None = board.parent
            while caller is not None and not holds(*caller.owner(mapped)):
                caller = caller.parent
            if caller is not None:
                text += (f"; a caller has '{mapped}', but this SubTree's blackboard is its own: pass it as a port "
                         f"({mapped}=\"{{{mapped}}}\") or set _autoremap=\"true\" on the SubTree")
        return text

    def __repr__(self) -> str:
        return f"Blackboard({dict(self._entries)!r}, remapping={self.remapping!r}, autoremap={self.autoremap})"

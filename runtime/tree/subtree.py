"""The SubTree node: runs a BehaviorTree defined elsewhere, on a blackboard of its own.

``<SubTree ID="Pick" target="{goal}" speed="0.5" _autoremap="false"/>`` becomes a ``SubTree``
node with exactly one child (the root of the ``Pick`` tree). It is transparent: it ticks its
child and returns the child's result (skipped included), and halting it halts the child, as
BT.CPP's ``SubTreeNode`` does. What makes it a SubTree is the blackboard its descendants were
bound to (built by the loader): a child of the caller's blackboard whose ``remapping`` maps
``target`` to the caller's ``goal``, with ``speed`` stored locally as the literal string ``"0.5"``.
"""
from __future__ import annotations

from typing import ClassVar

from .behavior import NodeKind
from .blackboard import Blackboard
from .controls import DecoratorNode, TickGenerator


class SubTree(DecoratorNode):
    kind: ClassVar[NodeKind] = NodeKind.SUBTREE
    description: ClassVar[str] = (
        "Runs the BehaviorTree named by ID with an isolated blackboard; ports remap entries "
        "('{key}'), set literals, and _autoremap shares every entry with the caller."
    )

    # Filled by the loader: which tree this instance runs and how its blackboard is wired.
    tree_id: str
    child_blackboard: Blackboard
    remapping: dict[str, str]
    literals: dict[str, str]
    autoremap: bool

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.tree_id = name
        self.remapping = {}
        self.literals = {}
        self.autoremap = False

    @classmethod
    def check_children(cls, n: int) -> str | None:
        return None if n == 1 else f"a SubTree runs exactly one tree root, got {n} children"

    def run(self) -> TickGenerator:
        result = yield from self.tick_child(self.child)
        self.feedback_message = self.child.feedback_message
        return result

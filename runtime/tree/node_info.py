"""What any node of a tree says about itself, read with the default a node that does not say gets.

A tree holds our nodes (``runtime.tree.behavior.NodeMixin``: ``bind`` gives them an XML ID, a
source location, a blackboard and port bindings; their classes declare a kind and ports) and
plain py_trees behaviours, which have none of these; a condition guard (``ConditionGuard``) is
``transparent`` and carries the XML ID and kind of the node it wraps; a skipped node sets
``skipped`` for the tick. Each function here is the one place that reads its attribute off a node
(or a node's class) of any of these kinds.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Mapping

if TYPE_CHECKING:
    from runtime.errors import SourceLocation
    from .behavior import NodeKind, PortBinding
    from .blackboard import Blackboard
    from .ports import PortInfo


def xml_id(node: object) -> str:
    """The node's ID in the XML (``Wait``, ``Sequence``); its class name for a node that has none."""
    value: str = getattr(node, "xml_id", type(node).__name__)
    return value


def kind(node: object) -> NodeKind | None:
    """The node's kind (Action, Condition, Control ...), a condition guard's the one of the node it
    wraps; None for a node that has none."""
    value: NodeKind | None = getattr(node, "kind", None)
    return value


def declared_kind(cls: type) -> NodeKind | None:
    """The kind a node class declares (``NodeMixin.kind``); None for a class that declares none
    (a plain py_trees class, a condition guard)."""
    value: NodeKind | None = getattr(cls, "kind", None)
    return value


def ports(cls: type) -> tuple[PortInfo, ...]:
    """The ports a node class declares (``NodeMixin.ports``); none for a plain py_trees class."""
    value: tuple[PortInfo, ...] = getattr(cls, "ports", ())
    return value


def needs_world(cls: type) -> bool:
    """Whether a node class talks to a robot or a simulated cell (``NodeMixin.needs_world``)."""
    return bool(getattr(cls, "needs_world", False))


def location(node: object) -> SourceLocation | None:
    """Where the node is written in the XML; None for a node that was not loaded from a file."""
    value: SourceLocation | None = getattr(node, "location", None)
    return value


def tree_id(node: object) -> str:
    """The ID of the tree a SubTree node runs; ``""`` for any other node."""
    value: str = getattr(node, "tree_id", "")
    return value


def blackboard(node: object) -> Blackboard | None:
    """The blackboard the node's ports read and write; None for a node bound to none."""
    value: Blackboard | None = getattr(node, "blackboard", None)
    return value


def has_bindings(node: object) -> bool:
    """Whether the node's ports are bound (``NodeMixin.bind`` got as far as them)."""
    return hasattr(node, "bindings")


def bindings(node: object) -> Mapping[str, PortBinding]:
    """The node's port bindings by port name; empty for a node that has none."""
    value: Mapping[str, PortBinding] = getattr(node, "bindings", {})
    return value


def is_transparent(node: object) -> bool:
    """Whether the node is a wrapper that is no node of the tree in BT.CPP's sense (a condition guard)."""
    return bool(getattr(node, "transparent", False))


def is_skipped(node: object) -> bool:
    """True when ``node`` was skipped in the tick it just ran."""
    return bool(getattr(node, "skipped", False))


def failure_kind(node: object) -> str | None:
    """What kind of failure the node's last FAILURE was (``Behavior.fail``); None when it does not say."""
    value: str | None = getattr(node, "failure_kind", None)
    return value

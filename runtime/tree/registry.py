"""Which XML IDs name which node classes.

The runtime registers its own nodes (controls, decorators, utilities) through the same
entry-point group a user's package uses: ``objective.behaviors``. Each entry point names a
callable ``register(registry)``.
"""
from __future__ import annotations

from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Callable, Iterable

from .behavior import NodeKind, NodeMixin

BEHAVIOR_GROUP = "objective.behaviors"
WORLD_GROUP = "objective.worlds"
DEFAULT_WORLD_GROUP = "objective.default_world"
"""One entry, named after a world of ``objective.worlds``: the world a run starts when none is
named. The installation chooses it (this project's pyproject names ``vla_sim``), not the engine."""


@dataclass(frozen=True)
class NodeSpec:
    id: str
    cls: type[NodeMixin]

    @property
    def kind(self) -> NodeKind:
        return self.cls.kind


class Registry:
    def __init__(self) -> None:
        self._specs: dict[str, NodeSpec] = {}

    def register(self, cls: type[NodeMixin], id: str | None = None) -> type[NodeMixin]:
        node_id = id or cls.__name__
        existing = self._specs.get(node_id)
        if existing is not None and existing.cls is not cls:
            raise ValueError(
                f"node ID '{node_id}' is registered twice: {existing.cls.__module__}.{existing.cls.__qualname__} "
                f"and {cls.__module__}.{cls.__qualname__}"
            )
        self._specs[node_id] = NodeSpec(node_id, cls)
        return cls

    def register_all(self, classes: Iterable[type[NodeMixin]]) -> None:
        for cls in classes:
            self.register(cls)

    def get(self, node_id: str) -> NodeSpec | None:
        return self._specs.get(node_id)

    def __contains__(self, node_id: str) -> bool:
        return node_id in self._specs

    def specs(self) -> list[NodeSpec]:
        return [self._specs[k] for k in sorted(self._specs)]

    @classmethod
    def from_entry_points(cls, group: str = BEHAVIOR_GROUP) -> Registry:
        """A registry holding every node that installed packages declare; an ObjectiveError naming
        what to install when a module one of them imports is missing (ROS 2, an interface package)."""
        from runtime.extras import naming_missing_modules

        registry = cls()
        for ep in sorted(entry_points(group=group), key=lambda e: e.name):
            with naming_missing_modules(f"the behaviors of '{ep.name}' ({ep.value}) cannot load"):
                register: Callable[[Registry], None] = ep.load()
                register(registry)
        return registry


def default_world_name() -> str:
    """The world named in ``objective.default_world``; ObjectiveError when none or several are."""
    from runtime.errors import ObjectiveError

    names = sorted({ep.name for ep in entry_points(group=DEFAULT_WORLD_GROUP)})
    if len(names) == 1:
        return names[0]
    known = ", ".join(sorted({ep.name for ep in entry_points(group=WORLD_GROUP)})) or "none installed"
    if not names:
        raise ObjectiveError(f"this tree needs a world and none is named: pass --world NAME (worlds: {known})")
    raise ObjectiveError(f"installed packages name {len(names)} default worlds ({', '.join(names)}): "
                         f"pass --world NAME (worlds: {known})")

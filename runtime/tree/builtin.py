"""Registers the runtime's own nodes (controls, decorators, utilities, scripts) into a registry."""
from __future__ import annotations

from .registry import Registry


def register(registry: Registry) -> None:
    from . import controls, decorators, loops, script_nodes, switch, updates, utility

    registry.register_all(controls.NODES)
    registry.register_all(switch.NODES)
    registry.register_all(decorators.NODES)
    registry.register_all(loops.NODES)
    registry.register_all(updates.NODES)
    registry.register_all(utility.NODES)
    registry.register_all(script_nodes.NODES)

"""The project's behaviors, one module per family; each module exports ``NODES``.

``register`` is the ``objective.behaviors`` entry point (see pyproject.toml): the CLI calls it
to learn every behavior's XML ID, which is its class name.
"""
from __future__ import annotations

from runtime.registry import Registry


def register(registry: Registry) -> None:
    from . import controllers, gripper, motion, motion_pose, poses, scene, scene_objects, sim_control
    from .execute_policy import behavior as execute_policy

    for module in (controllers, gripper, motion, motion_pose, scene, scene_objects, poses, sim_control, execute_policy):
        registry.register_all(module.NODES)

"""The project's behaviors, one module per family; each module exports ``NODES``.

``register`` is the ``objective.behaviors`` entry point (see pyproject.toml): the CLI calls it
to learn every behavior's XML ID, which is its class name.
"""
from __future__ import annotations

from runtime.tree.registry import Registry


def register(registry: Registry) -> None:
    from . import controllers, gripper, motion, motion_pose, poses, scene, scene_objects, sim_control
    from .execute_policy import behavior as execute_policy

    for module in (controllers, gripper, motion, motion_pose, scene, scene_objects, poses, sim_control, execute_policy):
        registry.register_all(module.NODES)
    register_moveit_pro(registry)


def register_moveit_pro(registry: Registry) -> None:
    """MoveIt Pro's everyday behaviors (docs/moveit-pro-behaviors.md)."""
    from . import cameras, frames, messages, mtc, planning, robot_state, trajectories, vectors, velocity_force, visualization, yaml_files

    for module in (vectors, frames, yaml_files, trajectories, planning, mtc, robot_state, messages, velocity_force, cameras, visualization):
        registry.register_all(module.NODES)

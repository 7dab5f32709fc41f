"""The cell's planning scene follows the simulated cubes, and says when it changed."""
from __future__ import annotations

import numpy as np

from sim.cell_model import CUBE_COLORS
from sim.planning import cube_object, make_cell_scene, sync_cubes


def resting_cubes() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return {c: (np.array([0.4 + 0.1 * i, 0.1, 0.015]), np.array([1.0, 0.0, 0.0, 0.0])) for i, c in enumerate(CUBE_COLORS)}


def test_cubes_at_rest_leave_the_scene_version_alone():
    poses = resting_cubes()
    scene = make_cell_scene(poses)
    synced = sync_cubes(scene, poses)
    version = scene.version
    jittered = {c: (p + 1e-7, q) for c, (p, q) in poses.items()}
    synced = sync_cubes(scene, jittered, synced)
    assert scene.version == version


def test_a_moved_cube_is_moved_in_the_scene_and_bumps_the_version():
    poses = resting_cubes()
    scene = make_cell_scene(poses)
    synced = sync_cubes(scene, poses)
    version = scene.version
    color = "blue"
    moved = dict(poses)
    moved[color] = (poses[color][0] + np.array([0.0, 0.002, 0.0]), poses[color][1])
    sync_cubes(scene, moved, synced)
    assert scene.version != version
    assert np.allclose(scene.object_pose(cube_object(color))[:3, 3], moved[color][0])


def test_a_carried_cube_is_skipped_then_placed_where_the_world_has_it_once_released():
    poses = resting_cubes()
    scene = make_cell_scene(poses)
    color = "green"
    name = cube_object(color)
    q = np.zeros(7)  # a layout row: the six arm joints and the gripper
    scene.attach(name, "gripper_base", pose_in_link=np.eye(4))
    synced = sync_cubes(scene, poses)
    assert color not in synced
    scene.detach(name, q)  # left where the gripper was; the world has it elsewhere
    assert not np.allclose(scene.object_pose(name)[:3, 3], poses[color][0])
    sync_cubes(scene, poses, synced)
    assert np.allclose(scene.object_pose(name)[:3, 3], poses[color][0])

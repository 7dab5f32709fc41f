"""The cell's planning scene follows the simulated cubes, and says when it changed."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.motion.scene import Box
from sim.cell_model import CUBE_COLORS
from sim.planning import CubeContact, cube_object, make_cell_scene, sync_cubes
from sim.robot_model import ARM_JOINTS, load_waypoints
from sim.kinematic import create_kinematic


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
    rotated = dict(moved)
    rotated[color] = (moved[color][0], np.array([0.0, 0.0, 0.0, 2.0]))  # 180 degrees about z, not normalised
    sync_cubes(scene, rotated, synced)
    np.testing.assert_allclose(scene.object_pose(cube_object(color))[:3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-15)


def test_a_cube_pose_that_is_not_finite_is_refused_naming_the_cube():
    poses = resting_cubes()
    scene = make_cell_scene(poses)
    broken = dict(poses)
    broken["red"] = (np.array([0.4, np.nan, 0.015]), poses["red"][1])
    with pytest.raises(ValueError, match="the world reports a pose of cube 'red' that is not finite"):
        sync_cubes(scene, broken)


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


# -- who may touch the cubes (cube_contact) ------------------------------------------------------
def home_row() -> np.ndarray:
    home = load_waypoints()["Home"]
    return np.array([home[j] for j in ARM_JOINTS] + [0.0])


def scene_with_cube_at(link: str, contact: CubeContact, name: str = "cube_blue"):
    """The cell's scene with the arm at Home and ``name`` (a cube, or a new box) centred on ``link``."""
    scene = make_cell_scene(resting_cubes(), cube_contact=contact)
    q = home_row()
    pose = scene.link_pose(q, link)
    if name in scene.objects:
        scene.move_object(name, pose)
    else:
        scene.add_object(name, Box((0.03, 0.03, 0.03)), pose)
    return scene, q


def test_by_default_the_gripper_may_touch_the_cubes():
    for link in ("gripper_left_pad", "gripper_right_follower"):
        scene, q = scene_with_cube_at(link, CubeContact.GRIPPER)
        assert scene.check_state(q) is None


def test_by_default_the_arm_keeps_its_distance_from_the_cubes():
    scene, q = scene_with_cube_at("wrist_2_link", CubeContact.GRIPPER)
    hit = scene.check_state(q)
    assert hit is not None and "vs cube_blue" in str(hit) and "gripper" not in str(hit)


def test_an_object_that_appears_is_an_obstacle_to_the_gripper_too():
    scene, q = scene_with_cube_at("gripper_left_pad", CubeContact.GRIPPER, name="intruder")
    hit = scene.check_state(q)
    assert hit is not None and "gripper_" in str(hit) and "vs intruder" in str(hit)


def test_the_strict_scene_forbids_every_contact_until_allowed():
    scene, q = scene_with_cube_at("gripper_left_pad", CubeContact.NONE)
    hit = scene.check_state(q)
    assert hit is not None and "gripper_" in str(hit) and "vs cube_blue" in str(hit)
    scene.allow("cube_blue", "gripper")  # what an Objective's SetCollisionRule does
    assert scene.check_state(q) is None


def test_an_explicit_rule_still_forbids_a_cube_the_default_allows():
    scene, q = scene_with_cube_at("gripper_left_pad", CubeContact.GRIPPER)
    scene.disallow("cube_blue", "gripper")
    assert "vs cube_blue" in str(scene.check_state(q))


def test_cube_contact_option_names_its_values():
    assert CubeContact.parse(" Gripper ") is CubeContact.GRIPPER
    with pytest.raises(ValueError, match="cube_contact must be gripper or none, got 'fingers'"):
        CubeContact.parse("fingers")
    with pytest.raises(ValueError, match="cube_contact must be gripper or none, got 'all'"):
        create_kinematic({"cube_contact": "all"})

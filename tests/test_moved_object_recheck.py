"""A path found free, checked again after one cube moved, checks only that cube's pairs and
gives the answer of checking everything again.

``PlanningScene.check_path(..., free_at=version)`` is how ExecutePolicy's scene watch checks the
rest of its committed motion after the cubes moved. On random paths near the table (with and
without a carried box), a cube is put somewhere along the path, often into it: the first
colliding step, its pair and its distance must be those of the full check.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st

from runtime.motion.scene import pose_matrix
from sim.planning import cube_object

from .test_path_early_out import CUBES, cell_scene, key, make_path, paths

moves = st.fixed_dictionaries({
    "cube": st.sampled_from(sorted(CUBES)),
    "at": st.floats(0.0, 1.0),  # where along the path the cube is put
    "offset": st.lists(st.floats(-0.12, 0.12), min_size=3, max_size=3),
    "yaw": st.floats(-np.pi, np.pi),
    "elsewhere": st.booleans(),  # or near where it was, far from the path
})


def place(scene, name: str, position: np.ndarray, yaw: float) -> None:
    c, s = np.cos(yaw), np.sin(yaw)
    scene.move_object(name, pose_matrix(position, np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])))


@settings(max_examples=80, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(paths, moves)
def test_checking_the_moved_cube_gives_the_full_answer(p, move):
    scene = cell_scene(p["carrying"])
    Q = make_path(p)
    times = np.arange(len(Q)) * 0.01
    name = cube_object(move["cube"])
    before = scene.object_pose(name)
    try:
        assume(scene.check_path(Q, times, p["padding"]) is None)  # the premise: found free
        free_at = scene.version
        if move["elsewhere"]:
            position = before[:3, 3] + np.array(move["offset"]) * 0.1
        else:
            row = Q[int(move["at"] * (len(Q) - 1))]
            position = scene.link_pose(row, "gripper_base")[:3, 3] + np.array(move["offset"])
        place(scene, name, position, move["yaw"])
        full = scene.check_path(Q, times, p["padding"])
        again = scene.check_path(Q, times, p["padding"], free_at=free_at)
        event("hit" if full is not None else "free")
        assert key(again) == key(full)
        if full is not None:
            assert again.distance == pytest.approx(full.distance, abs=2e-6)
    finally:
        scene.move_object(name, before)


def test_nothing_moved_since_is_free_and_a_new_object_means_a_full_check():
    scene = cell_scene(False)
    Q = make_path({"start": 0, "offset": [0.0] * 6, "delta": [0.3, 0.0, 0.0, 0.0, 0.0, 0.0], "wiggle": [0.0] * 6,
                   "frequency": 0.0, "points": 50, "gripper": 0.2})
    assert scene.check_path(Q, None, 0.01) is None
    assert scene.check_path(Q, None, 0.01, free_at=scene.version) is None
    structure, poses = scene.version
    from runtime.motion.scene import Box

    scene.add_object("wall", Box((2.0, 2.0, 2.0)), pose_matrix([0.0, 0.0, 0.5]))  # around the robot
    try:
        hit = scene.check_path(Q, None, 0.01, free_at=(structure, poses))
        assert hit is not None and hit.second == "wall"  # not trusted: the set of objects changed
    finally:
        scene.remove_object("wall")

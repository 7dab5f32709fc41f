"""runtime.motion.scene.planner: collision-free joint paths on the planning scene's own checks."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.motion.scene import Box, pose_matrix, solve_ik
from runtime.motion.scene.planner import (
    PathPlanningError, PlannerSettings, motion_is_free, plan_path, scene_validity, segment_states,
)
from sim.cell_model import CUBE_COLORS
from sim.planning import make_cell_scene

HOME = np.array([-1.8732, -1.7159, 1.7867, -1.6416, -1.5708, -0.3024])
WALL_SIZE_M = (0.04, 0.30, 0.20)
WALL_CENTER_M = (0.0, 0.45, 0.10)


def cell_with_wall():
    cubes = {c: (np.array([0.3 + 0.05 * i, 0.1, 0.015]), np.array([1.0, 0.0, 0.0, 0.0])) for i, c in enumerate(CUBE_COLORS)}
    scene = make_cell_scene(cubes)
    scene.add_object("wall", Box(WALL_SIZE_M), pose_matrix(WALL_CENTER_M), fixed=True)
    return scene


def tcp_down_at(scene, xyz) -> np.ndarray:
    target = np.eye(4)
    target[:3, :3] = np.diag([1.0, -1.0, -1.0])
    target[:3, 3] = xyz
    result = solve_ik(scene.robot, "manipulator", target, seeds=[HOME], frame="tcp", random_restarts=0)
    assert result.success
    return result.positions


@pytest.fixture(scope="module")
def problem():
    scene = cell_with_wall()
    layout = scene.layout("manipulator", scene.gripper_joint)
    is_free = scene_validity(scene, layout, 0.01, scene.snapshot(), 0.0)
    start, goal = tcp_down_at(scene, (-0.15, 0.45, 0.12)), tcp_down_at(scene, (0.15, 0.45, 0.12))
    return scene, is_free, start, goal


def bounds(scene):
    return scene.limits.subset(scene.layout().group.joints).lower, scene.limits.subset(scene.layout().group.joints).upper


def test_a_wall_between_start_and_goal_is_planned_around(problem):
    scene, is_free, start, goal = problem
    assert not motion_is_free(is_free, start, goal, 0.025)  # the straight move goes through the wall
    path = plan_path(is_free, start, goal, *bounds(scene), PlannerSettings(seed=3))
    assert not path.straight
    assert np.array_equal(path.waypoints[0], start) and np.array_equal(path.waypoints[-1], goal)
    for a, b in zip(path.waypoints[:-1], path.waypoints[1:]):  # every state along it, 5 mrad apart
        assert all(is_free(q) for q in segment_states(a, b, 0.005))
    assert path.length_rad < 3 * float(np.linalg.norm(goal - start))  # shortcut: not a random walk


def test_the_same_seed_gives_the_same_path(problem):
    scene, is_free, start, goal = problem
    a = plan_path(is_free, start, goal, *bounds(scene), PlannerSettings(seed=7))
    b = plan_path(is_free, start, goal, *bounds(scene), PlannerSettings(seed=7))
    assert np.array_equal(a.waypoints, b.waypoints)


def test_a_free_straight_move_is_the_path(problem):
    scene, is_free, start, _ = problem
    goal = tcp_down_at(scene, (-0.15, 0.35, 0.2))
    path = plan_path(is_free, start, goal, *bounds(scene))
    assert path.straight and path.search_s == 0.0
    assert np.array_equal(path.waypoints, np.stack([start, goal]))


def test_a_goal_in_collision_is_named(problem):
    scene, is_free, start, _ = problem
    inside_wall = tcp_down_at(scene, (0.0, 0.45, 0.12))
    with pytest.raises(PathPlanningError, match="^the goal state is in collision$"):
        plan_path(is_free, start, inside_wall, *bounds(scene))
    with pytest.raises(PathPlanningError, match="^the start state is in collision$"):
        plan_path(is_free, inside_wall, start, *bounds(scene))


def test_a_goal_outside_the_bounds_is_named(problem):
    scene, is_free, start, _ = problem
    goal = start.copy()
    goal[2] = 3.5
    with pytest.raises(PathPlanningError, match=r"^the goal is outside the joint bounds: joint 2 at 3.5000 rad, bounds \[-3.1415, 3.1415\] rad$"):
        plan_path(is_free, start, goal, *bounds(scene))


def test_no_path_within_the_timeout_is_named():
    # Two free rooms with no door between them: the search runs out its time.
    def is_free(q: np.ndarray) -> bool:
        return abs(q[0]) > 0.5

    with pytest.raises(PathPlanningError, match=r"^no collision-free path found within 0.05 s$"):
        plan_path(is_free, np.array([-1.0, 0.0]), np.array([1.0, 0.0]), np.array([-2.0, -2.0]), np.array([2.0, 2.0]),
                  PlannerSettings(timeout_s=0.05, max_iterations=10**9))
    with pytest.raises(PathPlanningError, match=r"^no collision-free path found in 20 iterations \(\d+\.\d\d s\)$"):
        plan_path(is_free, np.array([-1.0, 0.0]), np.array([1.0, 0.0]), np.array([-2.0, -2.0]), np.array([2.0, 2.0]),
                  PlannerSettings(timeout_s=5.0, max_iterations=20))


def test_without_ompl_a_search_is_an_error_naming_it(monkeypatch):
    """The straight move needs nothing more; a search needs OMPL, and says so."""
    import sys

    from runtime.errors import SetupError

    monkeypatch.setitem(sys.modules, "ompl", None)
    lower, upper = np.array([-2.0, -2.0]), np.array([2.0, 2.0])
    assert plan_path(lambda q: True, np.array([-1.0, 0.0]), np.array([1.0, 0.0]), lower, upper).straight
    with pytest.raises(SetupError, match=r"^planning around an obstacle needs OMPL, a core dependency that is not importable here \(.*\): pip install ompl==2.0.1$"):
        plan_path(lambda q: abs(q[0]) > 0.5 or abs(q[1]) > 1.0, np.array([-1.0, 0.0]), np.array([1.0, 0.0]), lower, upper)

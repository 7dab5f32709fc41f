"""MoveIt Pro's own vla_sim Objective (objectives/moveit_pro/, unchanged) stacks the cubes here.

The file is PickNik's, byte for byte: it switches controllers with MoveIt Pro's ``strictness="2"``
and ``timeout="-1.000000"``, opens the gripper, calls the ``Move to Waypoint`` SubTree and runs
``ExecutePolicy`` with no SetCollisionRule. It has no stack check of its own, so the tests look
at the cubes in the world afterwards.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from runtime.tree.loader import validate
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, RunResult, run_file

OBJECTIVE = Path(__file__).resolve().parent.parent / "objectives" / "moveit_pro" / "stack_cubes_with_the_vla_policy.xml"
UPSTREAM_SHA256 = "6410fefbb528af46348fe6e69994906272d7bd86a0591654719c85230433f358"
"""PickNikRobotics/moveit_pro_example_ws@f9f967b7, src/vla_sim/objectives/stack_cubes_with_the_vla_policy.xml."""
CUBE = 0.03


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


def run(registry: Registry, seed: int, world: str = "vla_sim", **world_options: str) -> RunResult:
    options = RunOptions(seed=seed, world=world, policy_latency="0.05", max_seconds=60.0, world_options=world_options)
    return run_file(OBJECTIVE, registry, options)


def assert_blue_on_green(result: RunResult) -> None:
    assert (result.status, result.reason) == ("SUCCESS", "")
    assert result.extra["execute_policy"]["steps_executed"] == 300
    assert result.extra["execute_policy"]["rejections"] == 0
    cubes = result.extra["world"]["cubes"]
    offset = np.array(cubes["blue"]) - np.array(cubes["green"])
    assert np.linalg.norm(offset - [0.0, 0.0, CUBE]) < 0.015, cubes  # the stack check's tolerance
    assert result.extra["world"]["gripper"] < 0.05  # released


def test_the_objective_is_picknik_s_file_unchanged():
    assert hashlib.sha256(OBJECTIVE.read_bytes()).hexdigest() == UPSTREAM_SHA256


def test_it_validates_with_its_subtree_from_the_library(registry):
    (tree,) = validate(OBJECTIVE, registry).trees_or_raise()
    assert tree.tree_id == "Stack Cubes with the VLA Policy"
    ids = [n.xml_id for n in tree.nodes]
    assert ids[:4] == ["Sequence", "SwitchController", "MoveGripperAction", "Move to Waypoint"]
    assert "ExecutePolicy" in ids


@pytest.mark.parametrize("seed", [0, 3, 7])
def test_it_stacks_blue_on_green_on_the_physics_cell(registry, seed):
    assert_blue_on_green(run(registry, seed))


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_it_stacks_blue_on_green_on_ten_more_layouts(registry):
    failures = {}
    for seed in range(10, 20):
        result = run(registry, seed)
        try:
            assert_blue_on_green(result)
        except AssertionError as err:
            failures[seed] = f"{result.reason or err}"
    assert not failures, failures


def test_with_the_strict_scene_the_grasp_is_a_collision(registry):
    """cube_contact=none: the cubes are obstacles to every link until an Objective allows contact,
    which this Objective never does, so the policy's grasp stops the robot."""
    result = run(registry, 3, world="kinematic", cube_contact="none")
    assert result.status == "FAILURE" and result.failing_node == "ExecutePolicy"
    assert "world collision gripper_" in result.reason and "vs cube_blue" in result.reason

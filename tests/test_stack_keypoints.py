"""The stack's keypoints (policy/stack_keypoints.py): the arm's chain against pinocchio, the
keypoints against the oracle's plan, the configuration's round trip and its errors."""
from __future__ import annotations

import math

import numpy as np
import pytest

from policy.cube_locator import layout_features
from policy.stack_keypoints import (
    FINE_SCALE_RAD,
    KeypointConfig,
    KeypointError,
    StackGeometry,
    keypoint_feature_count,
    keypoint_features,
    stack_keypoints,
    stack_poses,
)


@pytest.fixture(scope="module")
def chain():
    from sim.robot_model import arm_chain

    return arm_chain()


@pytest.fixture(scope="module")
def config(chain):
    from sim.cell_model import HOME_CONFIGURATION

    return KeypointConfig(chain, np.asarray(HOME_CONFIGURATION), StackGeometry(grasp_height_m=0.022), 0.015)


def test_the_chains_tool_pose_is_pinocchios_tcp(chain):
    from sim.oracle import SceneKinematics
    from sim.robot_model import planning_robot_model

    kinematics = SceneKinematics(planning_robot_model())
    assert chain.joint_names == kinematics.joint_names
    for q in np.random.default_rng(3).uniform(-3.0, 3.0, (20, 6)):
        assert chain.tool_pose(q) == pytest.approx(kinematics.tcp_pose(q), abs=1e-12)


def yaw_quaternion(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


@pytest.mark.parametrize("seed", [40000, 40006, 100, 149])
def test_the_keypoints_are_where_the_oracles_plan_stops(config, seed):
    """The oracle's plan for the layout, sampled where each of its segments ends, against the keypoints."""
    from sim.layouts import layout
    from sim.oracle import OracleConfig, SceneKinematics, plan_stack
    from sim.robot_model import planning_robot_model

    placed = layout(seed)
    keypoints = stack_keypoints(layout_features([placed["blue"], placed["green"]]), config)
    poses = [(np.array([x, y, 0.015]), yaw_quaternion(yaw)) for x, y, yaw in (placed["blue"], placed["green"])]
    plan = plan_stack(SceneKinematics(planning_robot_model()), config.home_rad, 0.0, *poses,
                      OracleConfig(grasp_height=0.022))
    ends = plan.boundaries()
    arm, _ = plan.sample(np.array([ends[name][1] for name in ("pre_grasp", "descend", "transfer", "place")]) - 1e-9)
    assert keypoints == pytest.approx(arm, abs=1e-3)
    # and the tool is where the stack's poses say, to the solver's tolerance
    assert config.chain.tool_pose(keypoints[1])[:3, 3] == pytest.approx([*placed["blue"][:2], 0.015 + 0.022], abs=1e-5)


def test_the_poses_point_down_and_square_the_cubes():
    poses = stack_poses((0.4, 0.1, 0.015), 0.3, (0.5, -0.1, 0.015), -0.7, 0.0, StackGeometry())
    assert poses.grasp_yaw_rad == pytest.approx(0.3)
    assert poses.place_yaw_rad == pytest.approx(-0.7 + math.pi / 2 - math.pi / 2 + math.pi / 2)  # closest to 0.3
    assert poses.pre_grasp[:3, 3] == pytest.approx([0.4, 0.1, 0.015 + 0.018 + 0.10])
    assert poses.place[:3, 3] == pytest.approx([0.5, -0.1, 0.015 + 0.03 + 0.002 + 0.018])
    assert poses.grasp[:3, 2] == pytest.approx([0.0, 0.0, -1.0])


def test_the_features_are_the_keypoints_offsets_from_the_observed_arm_then_their_fine_copy():
    keypoints = np.arange(24.0).reshape(4, 6) * 0.01
    arm = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]) * 0.01
    features = keypoint_features(arm, keypoints)
    assert features.shape == (48,) == (keypoint_feature_count(6),)
    assert features[:6] == pytest.approx(keypoints[0] - arm)
    assert features[18:24] == pytest.approx(keypoints[3] - arm)
    assert features[24:30] == pytest.approx(np.tanh((keypoints[0] - arm) / FINE_SCALE_RAD))
    assert features[24] == pytest.approx(np.tanh(-0.01 / 0.05))  # 1 cm-ish off: -0.197, where the offset reads -0.01
    batched = keypoint_features(np.stack([arm, arm + 0.5]), np.stack([keypoints, keypoints]))
    assert batched.shape == (2, 48)
    assert batched[0] == pytest.approx(features) and batched[1, :6] == pytest.approx(keypoints[0] - arm - 0.5)


def test_the_configuration_round_trips_and_broken_ones_name_what_is_wrong(config):
    again = KeypointConfig.from_json(config.to_json(), "ck/objective_policy.json")
    assert again.geometry == config.geometry and again.cube_center_z_m == config.cube_center_z_m
    cubes = np.array([-0.15, 0.55, 0.1, 0.15, 0.45, -0.2])
    assert stack_keypoints(cubes, again) == pytest.approx(stack_keypoints(cubes, config), abs=1e-12)
    broken = config.to_json()
    del broken["arm_chain"]["axes"]
    with pytest.raises(KeypointError, match="ck/objective_policy.json: arm_chain needs joint_names, placements, axes"):
        KeypointConfig.from_json(broken, "ck/objective_policy.json")
    broken = config.to_json()
    broken["home_rad"] = [0.0, 0.0]
    with pytest.raises(KeypointError, match=r"stack_keypoints.home_rad must be \(6,\) finite numbers"):
        KeypointConfig.from_json(broken, "ck/objective_policy.json")
    broken = config.to_json()
    broken["grasp_height_m"] = "high"
    with pytest.raises(KeypointError, match="stack_keypoints needs numbers grasp_height_m"):
        KeypointConfig.from_json(broken, "ck/objective_policy.json")


def test_a_cube_out_of_reach_is_named(config):
    with pytest.raises(KeypointError, match=r"no joint solution for the tool at \[3.0, 0.1, 0.137\]"):
        stack_keypoints(np.array([3.0, 0.1, 0.0, 0.15, 0.45, 0.0]), config)
    with pytest.raises(KeypointError, match="the located cubes must be 6 finite numbers"):
        stack_keypoints(np.array([np.nan, 0.1, 0.0, 0.15, 0.45, 0.0]), config)

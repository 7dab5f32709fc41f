"""The learned stacking policy: its perception stage (always run) and the whole pipeline in miniature
(frames played, a few training steps, saved, served, a chunk answered; skipped without `make lerobot`)."""
from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from policy.cube_locator import (
    CameraView,
    CubeLocatorConfig,
    CubeNotFound,
    PinholeCamera,
    locate_cubes,
    painted_frame,
    plane_points,
    square_yaw,
)
from runtime.errors import ObjectiveError

DOWN = PinholeCamera((0.1, 0.4, 1.0), ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), 60.0)
"""A camera 1 m above (0.1, 0.4), looking straight down, image up = world +y."""


def test_the_pixel_below_a_downward_camera_lands_below_it_and_image_up_is_world_y():
    rows, columns = np.array([49.5, 0.0]), np.array([49.5, 49.5])  # the centre, then the top row
    points = plane_points(DOWN, rows, columns, 100, 100, 0.0)
    assert points[0] == pytest.approx([0.1, 0.4], abs=1e-9)
    half_width_m = math.tan(math.radians(30.0)) * 1.0
    assert points[1] == pytest.approx([0.1, 0.4 + half_width_m * 99.0 / 100.0], abs=1e-9)


@pytest.mark.parametrize("yaw_deg", [-44.0, -20.0, 0.0, 13.0, 30.0])
def test_square_yaw_reads_the_face_heading_of_a_filled_square(yaw_deg):
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-1, 1, 41)), axis=-1).reshape(-1, 2)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    points = grid @ np.array([[c, s], [-s, c]]) + [0.3, 0.5]
    assert math.degrees(square_yaw(points)) == pytest.approx(yaw_deg, abs=0.5)


def locator_for(cell):
    from tools.train_learned import locator_config

    return locator_config(cell)


def test_the_cubes_are_located_within_5_mm_of_the_simulators_poses_from_home():
    """The perception alone against the simulator's true cube poses, arm at Home, 224 px frames."""
    from sim.cell_model import HOME_CONFIGURATION, CellOptions
    from sim.mujoco_cell import MujocoCell

    cell = MujocoCell(CellOptions(image_width=224, image_height=224))
    try:
        config = locator_for(cell)
        errors_m = []
        for seed in range(2000, 2008):
            cell.reset(seed, np.array(HOME_CONFIGURATION))
            located = locate_cubes({name: cell.render(name) for name in config.images()}, config)
            for color, cube in zip(config.colors, located):
                position, _ = cell.cube_pose(color)
                errors_m.append(math.hypot(cube.x_m - position[0], cube.y_m - position[1]))
    finally:
        cell.close()
    assert max(errors_m) < 0.005, [round(e * 1000, 1) for e in errors_m]


def test_a_cube_missing_from_the_frame_is_named():
    view = CameraView("scene", DOWN, 0.015)
    config = CubeLocatorConfig(position=view, yaw=view)
    only_green = painted_frame(("green",), size=64)
    with pytest.raises(CubeNotFound, match=r"the blue cube is not in the 'scene' frame \(0 blue pixels, at least 4 wanted\)"):
        locate_cubes({"scene": only_green}, config)


def test_the_configuration_round_trips_and_a_broken_one_names_its_file():
    view = CameraView("scene", DOWN, 0.015)
    config = CubeLocatorConfig(position=view, yaw=CameraView("overview", DOWN, 0.03))
    assert CubeLocatorConfig.from_json(json.loads(json.dumps(config.to_json())), "x") == config
    with pytest.raises(ObjectiveError, match="ck/objective_policy.json: cube_locator is not a valid locator configuration"):
        CubeLocatorConfig.from_json({"position": {"image": "scene"}}, "ck/objective_policy.json")


def test_layouts_that_reach_the_held_out_seeds_are_refused():
    from tools.train_learned import frame_settings, parse_args

    with pytest.raises(SystemExit, match="held-out seeds 100..101"):
        frame_settings(parse_args([]), (98, 99, 100, 101))


needs_lerobot = pytest.mark.skipif(
    importlib.util.find_spec("lerobot") is None or importlib.util.find_spec("torch") is None,
    reason="LeRobot is not installed (make lerobot)",
)


@pytest.fixture(scope="module")
def tiny_learned(tmp_path_factory):
    """Two layouts played, two training steps, saved as `make learned-policy` saves it."""
    from tools.train_learned import main

    root = tmp_path_factory.mktemp("learned")
    out = root / "ck"
    assert main(["--out", str(out), "--cache", str(root / "frames"), "--layouts", "2", "--layout-seed", "50000",
                 "--workers", "1", "--steps", "2", "--batch", "4", "--eval-episodes", "0",
                 "--validation-layouts", "1"]) == 0
    return out


def test_the_demonstrations_start_where_the_objective_hands_the_policy_the_arm():
    """Prepare for Policy moves to the Home waypoint, not the cell's reset pose: the plans start there."""
    import xml.etree.ElementTree as ET

    from sim.robot_model import load_waypoints
    from tools.train_learned import frame_settings, parse_args

    prepare = ET.parse(Path(__file__).resolve().parent.parent / "objectives" / "stack_cubes.xml").getroot()
    moves = [n.get("waypoint_name") for n in prepare.iter("SubTree") if n.get("ID") == "Move to Waypoint"]
    assert moves == ["Home"]
    home = load_waypoints()["Home"]
    settings = frame_settings(parse_args([]), (40000,))
    assert settings.home == pytest.approx([home[name] for name in settings.joint_names[:6]] + [0.0])
    assert settings.home[:6] == pytest.approx((-1.8732, -1.7159, 1.7867, -1.6416, -1.5708, -0.3024))


@needs_lerobot
def test_the_pipeline_saves_a_lerobot_checkpoint_with_its_perception_and_data(tiny_learned):
    from lerobot.configs.policies import PreTrainedConfig

    config = PreTrainedConfig.from_pretrained(tiny_learned)
    assert (config.type, config.objective) == ("multi_task_dit", "flow_matching")
    assert config.text_encoder_name == str(tiny_learned / "clip")
    metadata = json.loads((tiny_learned / "objective_policy.json").read_text())
    assert metadata["cube_locator"]["position"]["image"] == "scene"
    assert metadata["cube_locator"]["yaw"]["image"] == "overview"
    assert metadata["relative_actions"] is True
    assert (metadata["noise_scale"], metadata["chunk_samples"]) == (1.0, 16)
    assert len(metadata["action_range"]["min"]) == len(metadata["action_range"]["max"]) == 7
    training = metadata["training"]
    assert (training["seed"], training["steps"], training["layout_seeds"]) == (0, 2, [50000, 50001])
    assert len(training["data_sha256"]) == 64
    assert metadata["stack_keypoints"]["home_rad"] == pytest.approx([-1.8732, -1.7159, 1.7867, -1.6416, -1.5708, -0.3024])
    assert training["unseen_fit_rad"] > 0


@needs_lerobot
def test_the_served_policy_locates_the_cubes_and_answers_a_chunk_that_rtc_guides(tiny_learned):
    from policy.backend import PolicyRequest
    from policy.lerobot_backend import make_lerobot_backend
    from sim.cell_model import HOME_CONFIGURATION, CellOptions
    from sim.layouts import layout
    from sim.mujoco_cell import MujocoCell

    backend = make_lerobot_backend(tiny_learned)
    backend.load()
    cell = MujocoCell(CellOptions(image_width=224, image_height=224))
    try:
        cell.reset(120, np.array(HOME_CONFIGURATION))
        images = {name: cell.render(name) for name in ("scene", "wrist", "overview")}
    finally:
        cell.close()
    names = backend.joint_names
    request = PolicyRequest("stack the blue cube on the green cube", names, np.r_[HOME_CONFIGURATION, 0.0], images,
                            new_episode=True)
    first = backend.infer(request)
    assert first.message == "" and first.actions.shape == (50, 7) and first.policy_actions.shape == (50, 7)
    assert first.actions[0] == pytest.approx(request.joint_positions, abs=0.5)  # relative to the observed joints
    trained_range = json.loads((tiny_learned / "objective_policy.json").read_text())["action_range"]
    assert np.all(first.actions >= np.array(trained_range["min"]) - 1e-6)  # never beyond the labels it was shown
    assert np.all(first.actions <= np.array(trained_range["max"]) + 1e-6)
    placed = layout(120)
    assert backend.located[[0, 1, 3, 4]] == pytest.approx([*placed["blue"][:2], *placed["green"][:2]], abs=0.005)
    leftover = first.policy_actions[20:] + 0.5  # a previous chunk the policy would not answer now
    guided = backend.infer(PolicyRequest(request.prompt, names, request.joint_positions, images,
                                         previous_action_chunk=leftover, frozen_prefix_steps=3, guidance_horizon=10,
                                         previous_anchor_positions=request.joint_positions))
    assert backend.last_rtc.inference_delay == 3 and backend.last_rtc.execution_horizon == 13
    # the frozen prefix follows the previous chunk's leftover, where an unguided chunk (the first) lands anywhere
    unguided_gap = np.abs(first.policy_actions[:3] - leftover[:3]).max()
    assert np.abs(guided.policy_actions[:3] - leftover[:3]).max() < 0.1 * unguided_gap
    unanchored = backend.infer(PolicyRequest(request.prompt, names, request.joint_positions, images,
                                             previous_action_chunk=leftover, frozen_prefix_steps=3))
    assert unanchored.message == ("this policy's chunks are relative to the observed joints: previous_action_chunk needs "
                                  "previous_anchor_state (the joints of the request that answered it)")
    # every episode starts the sampler's noise from the checkpoint's seed: its chunks do not depend
    # on the episodes answered before it
    assert np.array_equal(backend.infer(request).actions, first.actions)
    backend.action_range = None  # unclipped, the two-step model's chunk leaves the labels' range
    assert np.any(backend.infer(request).actions > np.array(trained_range["max"]) + 1e-3) or \
        np.any(backend.infer(request).actions < np.array(trained_range["min"]) - 1e-3)
    missing = backend.infer(PolicyRequest(request.prompt, names, request.joint_positions, {"wrist": images["wrist"]},
                                          new_episode=True))
    assert missing.message == ("the policy locates the cubes in images [scene, overview]; the request has no "
                               "[scene, overview] (request images [wrist])")

"""Approach frames (tools/approach_frames.py): training frames of the approach to the first cube made
from the oracle's plan, labelled as `objective record-demos` labels the same instants (skipped
without `make lerobot`, which brings torch and the cell's renderer together)."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

needs_lerobot = pytest.mark.skipif(
    importlib.util.find_spec("lerobot") is None or importlib.util.find_spec("torch") is None,
    reason="the LeRobot extra is not in this venv (make lerobot builds .venv-lerobot on Python 3.11; make test runs this file there)",
)

HOME = (-1.8732, -1.7137, 1.7892, -1.6396, -1.5708, -0.3024, 0.0029)
JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
          "robotiq_85_left_knuckle_joint")
PROMPT = "stack the blue cube on the green cube"


def settings(**changes):
    from tools.approach_frames import ApproachSettings

    values = dict(seeds=(40000,), steps=(0, 10, 400), home=HOME, joint_names=JOINTS, cameras=("wrist", "overview"),
                  image_size=64, crops=(("overview", (0.25, 0.25, 0.75, 0.75)),), size=32, chunk=50, control_period_s=0.1,
                  gripper_velocity=0.5, motion_noise_rad=0.0)
    values.update(changes)
    return ApproachSettings(**values)


@needs_lerobot
def test_approach_frames_are_the_plan_s_instants_before_the_grasp_labelled_with_the_plan(tmp_path, monkeypatch):
    from sim.cell_model import CellOptions
    from sim.mujoco_cell import MujocoCell
    from sim.oracle import OracleConfig, SceneKinematics, plan_stack
    from sim.robot_model import planning_robot_model
    from tools import approach_frames

    frames = approach_frames.make_approach_frames(settings(), PROMPT, tmp_path, workers=1)
    # Step 400 (40 s) is past the grasp: only steps 0 and 10 are taken.
    assert len(frames) == 2 and frames.seeds == [40000, 40000]
    assert frames.action.shape == (2, 50, 7) and frames.state.shape == (2, 7)
    assert frames.images["observation.images.overview"].shape == (2, 3, 32, 32)
    cell = MujocoCell(CellOptions(image_width=64, image_height=64))
    cell.reset(40000, np.array(HOME[:6]))
    plan = plan_stack(SceneKinematics(planning_robot_model()), np.array(HOME[:6]), HOME[6], cell.cube_pose("blue"),
                      cell.cube_pose("green"), OracleConfig(max_gripper_velocity=0.5))
    cell.close()
    arm, gripper = plan.sample(1.0 + 0.1 * np.arange(50))
    np.testing.assert_allclose(frames.action[1].numpy(), np.column_stack([arm, gripper]), atol=1e-5)
    # The state is one policy step behind the label, as a recorded arm is; at Home it is Home.
    np.testing.assert_allclose(frames.state[0].numpy(), HOME, atol=1e-5)
    np.testing.assert_allclose(frames.state[1, :6].numpy(), plan.sample(np.array([0.9]))[0][0], atol=1e-5)
    assert not np.array_equal(frames.images["observation.images.wrist"][0], frames.images["observation.images.wrist"][1])
    batch = frames.batch(np.array([1, 0]))
    assert batch["task"] == [PROMPT, PROMPT] and not batch["action_is_pad"].any()
    assert float(batch["observation.images.overview"].max()) <= 1.0
    # Made once: the same settings read the cache file; other settings make another.
    monkeypatch.setattr(approach_frames, "_render_part", lambda *a: pytest.fail("rendered again"))
    assert approach_frames.make_approach_frames(settings(), PROMPT, tmp_path, workers=1).seeds == [40000, 40000]
    assert len(list(tmp_path.glob("*.npz"))) == 1
    with pytest.raises(pytest.fail.Exception, match="rendered again"):
        approach_frames.make_approach_frames(settings(motion_noise_rad=0.04), PROMPT, tmp_path, workers=1)


@needs_lerobot
def test_motion_noise_moves_the_frame_s_arm_and_never_the_label(tmp_path):
    from tools.approach_frames import make_approach_frames

    clean = make_approach_frames(settings(steps=(10,)), PROMPT, tmp_path, workers=1)
    noisy = make_approach_frames(settings(steps=(10,), motion_noise_rad=0.04), PROMPT, tmp_path, workers=1)
    np.testing.assert_array_equal(clean.action.numpy(), noisy.action.numpy())
    offset = np.abs(noisy.state[0, :6].numpy() - clean.state[0, :6].numpy())
    assert 0.0 < offset.max() <= 0.04 and noisy.state[0, 6] == clean.state[0, 6]


@needs_lerobot
def test_a_batch_mixes_demonstration_and_approach_rows():
    import torch

    from tools.demo_training import joined

    first = {"observation.state": torch.zeros(2, 7), "task": ["a", "a"]}
    second = {"observation.state": torch.ones(1, 7), "task": ["b"]}
    both = joined(first, second)
    assert both["task"] == ["a", "a", "b"] and both["observation.state"][:, 0].tolist() == [0.0, 0.0, 1.0]

"""Plan frames (tools/plan_frames.py): the oracle's plan played straight into the cell, labelled as
`objective record-demos` labels the same instants, checked against a recording of the same layout
(skipped without `make lerobot`, which brings torch, LeRobot's dataset and the cell together)."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

needs_lerobot = pytest.mark.skipif(
    importlib.util.find_spec("lerobot") is None or importlib.util.find_spec("torch") is None,
    reason="the LeRobot extra is not installed (make lerobot)",
)

JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
          "robotiq_85_left_knuckle_joint")
PROMPT = "stack the blue cube on the green cube"
CROP = (0.25, 0.25, 0.75, 0.75)
SEED = 40000


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """One episode of layout SEED recorded through the runtime, read as training reads it."""
    from policy.lerobot_offline import force_offline

    force_offline()
    from policy.lerobot_backend import checked_crop
    from sim.demos import DemoOptions, record_demos
    from tools.demo_training import DemoTensors

    out = tmp_path_factory.mktemp("demos") / "one"
    record_demos(DemoOptions(episodes=1, seed=SEED, out=out, world="vla_sim", image_size=64, total_steps=220,
                             cameras=("wrist", "overview"), gripper_velocity=0.5, motion_noise_rad=0.04, hold_after_plan_s=2.0))
    return DemoTensors(out, 50, 32, ("wrist", "overview"), {"overview": checked_crop("overview", CROP)})


def settings(demos, **changes):
    from tools.plan_frames import PlanFrameSettings

    values = dict(seeds=(SEED,), every=1, hold_after_plan_s=2.0, home=tuple(float(v) for v in demos.state[0]), joint_names=JOINTS,
                  cameras=("wrist", "overview"), image_size=64, crops=(("overview", CROP),), size=32, chunk=50,
                  control_period_s=0.1, gripper_velocity=0.5, motion_noise_rad=0.04)
    values.update(changes)
    return PlanFrameSettings(**values)


@needs_lerobot
def test_plan_frames_are_the_recorded_episode_without_the_runtime(recorded, tmp_path):
    from tools.plan_frames import make_plan_frames

    frames = make_plan_frames(settings(recorded), PROMPT, tmp_path, workers=1)
    assert frames.dropped == [] and set(frames.seeds) == {SEED}
    assert abs(len(frames) - len(recorded)) <= 1
    count = min(len(frames), len(recorded))
    # The label of every instant is the recorder's: the plan's next 50 steps.
    labels = recorded.action[recorded.chunk_rows[:count - 50]]
    np.testing.assert_allclose(frames.action[:count - 50].numpy(), labels.numpy(), atol=1e-3)
    # The arm where the recorded one was (the gripper's release runs a little ahead: the docstring).
    arm_error = (frames.state[:count, :6] - recorded.state[:count, :6]).abs().amax(dim=1)
    assert float(arm_error.median()) < 0.005 and float(arm_error.quantile(0.9)) < 0.03
    for key in ("observation.images.wrist", "observation.images.overview"):
        pixels = (frames.images[key][:count].float() - recorded.images[key][:count].float()).abs().mean(dim=(1, 2, 3))
        assert float(pixels.median()) < 2.0, key


@needs_lerobot
def test_plan_frames_take_every_kth_step_are_cached_and_batch_like_demonstrations(recorded, tmp_path, monkeypatch):
    from tools import plan_frames

    every = plan_frames.make_plan_frames(settings(recorded, every=5), PROMPT, tmp_path, workers=1)
    assert len(every) == pytest.approx(len(recorded) / 5, abs=1)
    assert every.step[:3].tolist() == [0, 5, 10]  # SEED % 5 == 0: this layout's frames start at Home
    assert every.action.shape == (len(every), 50, 7) and every.images["observation.images.overview"].shape[1:] == (3, 32, 32)
    batch = every.batch(np.array([1, 0]))
    assert batch["task"] == [PROMPT, PROMPT] and not batch["action_is_pad"].any()
    assert float(batch["observation.images.wrist"].max()) <= 1.0
    monkeypatch.setattr(plan_frames, "_play_part", lambda *a: pytest.fail("played again"))
    assert len(plan_frames.make_plan_frames(settings(recorded, every=5), PROMPT, tmp_path, workers=1)) == len(every)
    with pytest.raises(pytest.fail.Exception, match="played again"):
        plan_frames.make_plan_frames(settings(recorded, every=5, motion_noise_rad=0.0), PROMPT, tmp_path, workers=1)


@needs_lerobot
def test_a_detour_stops_the_arm_off_its_way_and_the_frames_show_the_way_back_to_the_cube(recorded, tmp_path):
    from sim.cell_model import CellOptions
    from sim.mujoco_cell import MujocoCell
    from sim.oracle import SceneKinematics
    from sim.robot_model import planning_robot_model
    from tools.plan_frames import make_plan_frames

    cell = MujocoCell(CellOptions(image_width=64, image_height=64))
    try:
        cell.reset(SEED, recorded.state[0, :6].numpy())
        cube_m = cell.cube_pose("blue")[0][:2]
    finally:
        cell.close()
    kinematics = SceneKinematics(planning_robot_model())

    def to_cube_m(q) -> float:
        return float(np.linalg.norm(kinematics.tcp_pose(np.asarray(q[:6], dtype=float))[:2, 3] - cube_m))

    direct = make_plan_frames(settings(recorded), PROMPT, tmp_path, workers=1)
    frames = make_plan_frames(settings(recorded, detour_m=0.1), PROMPT, tmp_path, workers=1)
    assert frames.dropped == [] and set(frames.seeds) == {SEED} and frames.step[:2].tolist() == [0, 1]
    state, label = frames.state.numpy(), frames.action.numpy()
    # The first frame is taken where the detour stopped the arm, away from Home and off the direct way.
    assert np.abs(state[0, :6] - recorded.state[0, :6].numpy()).max() > 0.1
    assert min(np.abs(direct.state[:, :6].numpy() - state[0, :6]).max(axis=1)) > 0.02
    # Its label starts where the arm stands and heads for the real cube; the cube ends stacked (kept).
    assert np.abs(label[0, 0, :6] - state[0, :6]).max() < 0.02
    assert to_cube_m(label[0, -1]) < to_cube_m(state[0]) and to_cube_m(label[0, -1]) < 0.01
    assert len(frames) == pytest.approx(len(direct), abs=20)
    # Seeded: the same settings give the same frames.
    again = make_plan_frames(settings(recorded, detour_m=0.1), PROMPT, tmp_path / "again", workers=1)
    np.testing.assert_array_equal(again.state.numpy(), state)


@needs_lerobot
def test_early_layouts_are_played_for_their_first_steps_only_and_join_the_full_ones(recorded, tmp_path):
    from tools.plan_frames import make_plan_frames

    full = make_plan_frames(settings(recorded, every=5), PROMPT, tmp_path, workers=1)
    early = make_plan_frames(settings(recorded, every=5, first_steps=10), PROMPT, tmp_path, workers=1)
    assert settings(recorded, every=5).key() != settings(recorded, every=5, first_steps=10).key()
    # The first 10 steps of the same episode: frames at steps 0 and 5, as the full play has them.
    assert early.step.tolist() == [0, 5] and early.dropped == [] and early.seeds == [SEED, SEED]
    np.testing.assert_allclose(early.state.numpy(), full.state[:2].numpy(), atol=1e-9)
    np.testing.assert_array_equal(early.action.numpy(), full.action[:2].numpy())
    both = full.joined(early)
    assert len(both) == len(full) + 2 and both.step[-2:].tolist() == [0, 5] and both.seeds[-2:] == [SEED, SEED]
    assert all(len(frames) == len(both) for frames in both.images.values()) and len(both.action) == len(both)


def test_every_plan_frame_knows_its_policy_step():
    from dataclasses import replace

    from tools.plan_frames import PlanFrameSettings, frame_steps

    plain = PlanFrameSettings(seeds=(7, 8), every=5, hold_after_plan_s=2.0, home=(0.0,) * 7, joint_names=JOINTS,
                              cameras=("wrist",), image_size=64, crops=(), size=32, chunk=50, control_period_s=0.1,
                              gripper_velocity=0.5, motion_noise_rad=0.04)
    # From Home the layouts take their frames at staggered steps (seed % every); a detour's start at its stop.
    assert frame_steps(plain, [7, 7, 7, 8, 8]).tolist() == [2, 7, 12, 3, 8]
    assert frame_steps(replace(plain, detour_m=0.1), [7, 7, 8]).tolist() == [0, 5, 0]


@needs_lerobot
def test_the_early_approach_lift_and_place_shares_of_a_batch_cover_its_plan_rows_too():
    """Of the plan rows of every batch as of the recorded ones, the early share comes from the
    episodes' first steps, the approach share from the steps before the gripper first holds the
    cube, the lift share from those after and the place share from those before it lets go, so
    the chunks decided from the cameras learn from every played layout."""
    import argparse

    import torch

    from tools.demo_training import HELD_GRIPPER_RAD, grasp_rows, release_rows, train

    class Rows:
        """Episodes of 200 frames whose state is (step, gripper); the gripper holds from step 100 to 149."""

        def __init__(self, episodes: int) -> None:
            self.frame_index = self.step = torch.arange(200).repeat(episodes)
            self.episode = torch.arange(episodes).repeat_interleave(200)
            self.seeds = self.episode.tolist()
            held = (self.step >= 100) & (self.step < 150)
            self.state = torch.stack([self.step.float(), torch.where(held, 0.54, 0.0)], dim=1)

        def __len__(self) -> int:
            return len(self.step)

        def batch(self, rows):
            return {"observation.state": self.state[rows], "task": ["t"] * len(rows)}

    demos = Rows(2)
    assert grasp_rows(demos.state[:, 1], demos.episode, demos.step, 0, 20).tolist() == [*range(100, 120), *range(300, 320)]
    assert grasp_rows(demos.state[:, 1], demos.episode, demos.step, -10, 0).tolist() == [*range(90, 100), *range(290, 300)]
    never = grasp_rows(torch.zeros(200), torch.zeros(200, dtype=torch.long), torch.arange(200), -20, 20)
    assert never.tolist() == [] and HELD_GRIPPER_RAD < 0.54
    assert release_rows(demos.state[:, 1], demos.episode, demos.step, -15, 0).tolist() == [*range(135, 150), *range(335, 350)]
    closed_from_the_start = torch.where(torch.arange(200) < 50, 0.54, 0.0)  # lets go at step 50, never opened before
    assert release_rows(closed_from_the_start, torch.zeros(200, dtype=torch.long), torch.arange(200), -5, 2).tolist() == [*range(45, 52)]
    seen = []

    class Policy(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.weight = torch.nn.Parameter(torch.zeros(1))

        def forward(self, batch):
            seen.append(batch["observation.state"][:, 0].tolist())
            return (self.weight * batch["observation.state"][:, 0]).mean(), None

    policy = Policy()
    args = argparse.Namespace(steps=20, minutes=1.0, seed=0, early_frames=10, early_share=0.25, approach_steps=10,
                              approach_share=0.25, lift_steps=20, lift_share=0.25, place_steps=15, place_share=0.125,
                              plan_share=0.5, batch=16, lr=1e-3)
    train(policy, torch.optim.SGD(policy.parameters(), lr=1e-3), demos, lambda b: b, args, plan_frames=Rows(5))
    assert len(seen) == 20
    for steps in seen:
        for part in (steps[:8], steps[8:]):
            assert sum(s < 10 for s in part) >= 2 and sum(90 <= s < 100 for s in part) >= 2
            assert sum(100 <= s < 120 for s in part) >= 2 and sum(135 <= s < 150 for s in part) >= 1
    args.lift_share = 0.75
    with pytest.raises(SystemExit, match="--early-share 0.25, --approach-share 0.25, --lift-share 0.75, --place-share 0.125 "
                                         "must add up to at most 1"):
        train(policy, torch.optim.SGD(policy.parameters(), lr=1e-3), demos, lambda b: b, args)


def test_the_arm_runs_one_step_behind_the_plan_only_while_the_first_chunk_plays():
    from tools.plan_frames import plan_delay_s

    assert [plan_delay_s(t) for t in (0.0, 1.5, 2.0, 2.5, 9.0)] == pytest.approx([0.1, 0.1, 0.05, 0.0, 0.0])


@needs_lerobot
def test_a_batch_mixes_demonstration_and_plan_rows():
    import torch

    from tools.demo_training import joined

    first = {"observation.state": torch.zeros(2, 7), "task": ["a", "a"]}
    second = {"observation.state": torch.ones(1, 7), "task": ["b"]}
    both = joined(first, second)
    assert both["task"] == ["a", "a", "b"] and both["observation.state"][:, 0].tolist() == [0.0, 0.0, 1.0]

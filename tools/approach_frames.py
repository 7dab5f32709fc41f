"""Training frames of the approach to the first cube, made from the oracle's plan without running an episode.

Until the gripper closes on the first cube, the cell's state is the plan's: the arm where the plan
puts it (plus the recorder's motion noise; the recorder's labels are the plan, sampled every policy
step), the gripper open, the cubes where the layout put them. So for a layout seed, ``plan_stack`` from Home gives both the
frame (the cell reset to the layout with the arm at the plan's position, then rendered) and its
label (the next ``chunk`` steps of the plan), exactly as ``objective record-demos`` labels the same
instant, for a fraction of an episode's cost (a plan and two renders per frame, no runtime).
Recorded demonstrations cover a few hundred layouts; these cover thousands, where the policy has to
find the first cube from the cameras alone.

``make_approach_frames`` renders them in worker processes (each its own cell and kinematics) and
keeps them in a cache file named by a hash of every setting; ``ApproachFrames.batch`` answers what
``DemoTensors.batch`` does, so a training batch mixes both.
"""
from __future__ import annotations

import hashlib
import json
import logging
import multiprocessing
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

LOG = logging.getLogger("approach_frames")


@dataclass(frozen=True)
class ApproachSettings:
    """What the frames are made of (every field goes into the cache file's name)."""

    seeds: tuple[int, ...]
    steps: tuple[int, ...]
    """Policy steps after Home at which frames are taken (kept while the plan is before its grasp)."""
    home: tuple[float, ...]
    """The state at Home, in ``joint_names`` order (arm joints, then the gripper)."""
    joint_names: tuple[str, ...]
    cameras: tuple[str, ...]
    image_size: int
    """Rendered frame size (px), as recorded."""
    crops: tuple[tuple[str, tuple[float, ...]], ...]
    """Camera -> (top, left, bottom, right) fractions, applied before the resize."""
    size: int
    """Training frame size (px)."""
    chunk: int
    control_period_s: float
    gripper_velocity: float | None
    motion_noise_rad: float
    """The recorder's smooth offset of the executed motion (``sim.demos.MotionNoise``): the frame's arm is
    the plan plus it, the label the plan, as in a recorded episode."""

    def key(self) -> str:
        return hashlib.sha256(json.dumps(self.__dict__, sort_keys=True, default=list).encode()).hexdigest()[:16]


@dataclass
class ApproachFrames:
    """Frames with their states, action chunks and layout seeds (row-aligned tensors)."""

    state: Any
    action: Any
    images: dict[str, Any]
    seeds: list[int]
    task: str

    def __len__(self) -> int:
        return len(self.seeds)

    def batch(self, rows: Any) -> dict:
        """As ``DemoTensors.batch``: state, the action chunk (never padded), the task, float CHW images."""
        import torch

        batch = {"observation.state": self.state[rows], "action": self.action[rows],
                 "action_is_pad": torch.zeros(self.action[rows].shape[:2], dtype=torch.bool),
                 "task": [self.task] * len(rows)}
        for key, frames in self.images.items():
            batch[key] = frames[rows].float().div_(255.0)
        return batch


def make_approach_frames(settings: ApproachSettings, task: str, cache: Path, workers: int = 2) -> ApproachFrames:
    """The frames of ``settings``, read from ``cache/<key>.npz`` or made there first."""
    import numpy as np
    import torch

    path = cache / f"{settings.key()}-{hashlib.sha256(task.encode()).hexdigest()[:8]}.npz"
    if not path.is_file():
        started = time.monotonic()
        parts = [settings.seeds[i::workers] for i in range(workers)]
        if workers > 1:
            with multiprocessing.get_context("spawn").Pool(workers) as pool:
                made = pool.starmap(_render_part, [(settings, task, part) for part in parts if part])
        else:
            made = [_render_part(settings, task, settings.seeds)]
        arrays = {key: np.concatenate([part[key] for part in made]) for key in made[0]}
        cache.mkdir(parents=True, exist_ok=True)
        partial = path.with_suffix(".partial.npz")
        np.savez(partial, **arrays)
        partial.replace(path)
        LOG.info("made %d approach frames of %d layouts in %.0f s (%s)", len(arrays["seed"]), len(settings.seeds),
                 time.monotonic() - started, path)
    with np.load(path) as arrays:
        images = {f"observation.images.{c}": torch.from_numpy(arrays[f"image_{c}"]) for c in settings.cameras}
        return ApproachFrames(torch.from_numpy(arrays["state"]), torch.from_numpy(arrays["action"]), images,
                              arrays["seed"].tolist(), task)


def _render_part(settings: ApproachSettings, task: str, seeds: tuple[int, ...]) -> dict:
    """One worker's share: arrays ``state`` (M, A), ``action`` (M, chunk, A), ``seed`` (M,) and
    ``image_<camera>`` (M, 3, size, size) uint8."""
    import numpy as np
    import torch

    from policy.lerobot_backend import checked_crop, crop_slices
    from sim.cell_model import CellOptions
    from sim.demos import MotionNoise
    from sim.mujoco_cell import MujocoCell
    from sim.oracle import OracleConfig, PlanError, SceneKinematics, parse_prompt, plan_stack
    from sim.robot_model import planning_robot_model
    from tools.demo_training import resized

    kinematics = SceneKinematics(planning_robot_model())
    arm = [settings.joint_names.index(name) for name in kinematics.joint_names]
    gripper = [i for i in range(len(settings.joint_names)) if i not in arm]
    if len(gripper) != 1:
        raise ValueError(f"approach frames need the arm joints and one gripper column, got {list(settings.joint_names)}")
    config = OracleConfig() if settings.gripper_velocity is None else OracleConfig(max_gripper_velocity=settings.gripper_velocity)
    home = np.asarray(settings.home, dtype=float)
    top, bottom = parse_prompt(task)
    crops = {camera: checked_crop(camera, box) for camera, box in settings.crops}
    cell = MujocoCell(CellOptions(image_width=settings.image_size, image_height=settings.image_size))
    states, actions, seeds_out, frames = [], [], [], {c: [] for c in settings.cameras}
    offsets = np.arange(settings.chunk) * settings.control_period_s
    try:
        for seed in seeds:
            cell.reset(seed, home[arm])
            try:
                plan = plan_stack(kinematics, home[arm], float(home[gripper[0]]), cell.cube_pose(top), cell.cube_pose(bottom), config)
            except PlanError:
                continue
            grasp_s = plan.boundaries()["descend"][1]
            noise = MotionNoise(settings.motion_noise_rad, seed, len(arm)) if settings.motion_noise_rad > 0 else None
            for step in settings.steps:
                t = step * settings.control_period_s
                if t > grasp_s:
                    break
                arm_chunk, gripper_chunk = plan.sample(t + offsets)
                chunk = np.empty((settings.chunk, len(settings.joint_names)))
                chunk[:, arm], chunk[:, gripper[0]] = arm_chunk, gripper_chunk
                # The arm measured at a frame is one policy step behind the plan (fitted on recordings:
                # 0.003 rad median against 0.007-0.019 with no delay).
                behind = np.array([max(t - settings.control_period_s, 0.0)])
                arm_now, gripper_now = plan.sample(behind)
                state = np.empty(len(settings.joint_names))
                state[arm], state[gripper[0]] = arm_now[0], gripper_now[0]
                if noise is not None:
                    state[arm] += noise.offsets(plan, behind)[0]
                if step:
                    cell.reset(seed, state[arm])
                states.append(state)
                actions.append(chunk)
                seeds_out.append(seed)
                for camera in settings.cameras:
                    frames[camera].append(cell.render(camera))
    finally:
        cell.close()
    out = {"state": np.asarray(states, dtype=np.float32), "action": np.asarray(actions, dtype=np.float32),
           "seed": np.asarray(seeds_out, dtype=np.int64)}
    for camera in settings.cameras:
        stack = np.stack(frames[camera])
        if camera in crops:
            rows, columns = crop_slices(stack.shape[1], stack.shape[2], crops[camera])
            stack = stack[:, rows, columns]
        tensor = torch.from_numpy(np.ascontiguousarray(stack)).permute(0, 3, 1, 2).contiguous()
        out[f"image_{camera}"] = resized(tensor, settings.size).numpy()
    return out

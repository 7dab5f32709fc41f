"""Training frames of the oracle's plan played straight into the cell, without the runtime.

`objective record-demos` runs the oracle through the whole runtime (ExecutePolicy, the controller,
the dataset writer) and takes about 15 s of one core per episode here. The frames a policy learns
from need less: the cell's physics following the oracle's plan, the cameras, and the label. For a
layout seed, ``plan_stack`` from Home gives the plan; the cell (``MujocoCell``) is commanded along it
every ``PHYSICS_DT_S`` (arm position with velocity feed-forward plus the recorder's motion noise,
gripper command), so grasp, carry and release are the cell's own contacts; every ``every``-th
policy step a frame is taken: the measured joints, the rendered cameras, and as label the plan's
next ``chunk`` steps, exactly as the recorder labels the same instant. An episode whose blue cube
does not end on the green one is dropped, as the recorder drops it.

With a detour (``detour_m`` > 0) a layout shows the way back from a wrong approach, the error a
learned policy's first chunk makes: the arm first follows the plan to a pre-grasp moved by a seeded
random offset (2 cm up to ``detour_m`` sideways, a little up or down, turned by up to
``DETOUR_YAW_RAD``) and is stopped part-way there (or, with ``detour_descent``, anywhere from
half-way there to the end of the descent beside the cube); the oracle then plans from where the arm
stands to the real cube, and only that plan gives frames (the first one at the stop) and labels.

The timing follows the recorder's measured one (``tests/test_plan_frames.py`` compares both on the
same seeds): the arm runs one policy step behind the plan while the first chunk plays (the first
request's latency), then on it (later chunks are stitched on time), blended over a second.

With ``first_steps`` a layout is played for only its first steps (the frames the first chunk from
Home learns from), about a tenth of a full episode's cost; its end is not played, so it is kept
without the stack check: its labels are the oracle's plan, whose played episodes stack in all but
3 of 2,000 layouts.

``make_plan_frames`` plays them in worker processes (each its own cell and kinematics) and keeps
them in a cache file named by a hash of the settings (those at their defaults left out);
``PlanFrames.batch`` answers what ``DemoTensors.batch`` does, so a training batch mixes both.
"""
from __future__ import annotations

import hashlib
import json
import logging
import multiprocessing
import time
from dataclasses import MISSING, dataclass, fields, replace
from pathlib import Path
from typing import Any

LOG = logging.getLogger("plan_frames")

PHYSICS_DT_S = 0.01
"""How often the plan is sampled into the cell's commands (the cell steps its physics inside)."""
FIRST_CHUNK_DELAY_S = 0.1
"""How far the arm runs behind the plan during the first chunk (one policy step)."""
CATCH_UP_S = (1.5, 2.5)
"""The delay fades from ``FIRST_CHUNK_DELAY_S`` to 0 over this span of plan time."""
GRIPPER_DELAY_S = 0.1
"""How far the gripper's command runs behind the plan's gripper column (ExecutePolicy sends it as a
gripper goal per policy step). Measured against recordings: the closing matches, the opening runs
0.1-0.2 rad ahead of the recorded one for a few frames (the recorded release lags more)."""
STACK_TOLERANCE_M = 0.015
"""The blue cube's centre within this of the stacked position: the episode is kept (the stack check's)."""
DETOUR_MIN_M = 0.02
"""The smallest sideways offset of a detour's pre-grasp."""
DETOUR_HEIGHT_M = (-0.02, 0.04)
"""The range of a detour's vertical offset."""
DETOUR_YAW_RAD = 0.26
"""A detour's pre-grasp turns by up to this about the vertical."""
DETOUR_FIRST_STOP = 0.5
"""The earliest stop: this fraction of the detour's way to its pre-grasp."""


@dataclass(frozen=True)
class PlanFrameSettings:
    """What the frames are made of (every field goes into the cache file's name)."""

    seeds: tuple[int, ...]
    every: int
    """A frame every this many policy steps."""
    hold_after_plan_s: float
    """Frames continue this long after the plan ends (the recorder's ``--hold-after-plan``)."""
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
    """The recorder's smooth offset of the executed motion (``sim.demos.MotionNoise``): the arm follows
    the plan plus it, the label is the plan."""
    detour_m: float = 0.0
    """The largest sideways offset of a detour's pre-grasp (0: no detours; see the module doc)."""
    detour_descent: bool = False
    """The detour may go on down the moved descent before it stops."""
    first_steps: int = 0
    """Only the first this many policy steps of each layout are played (0: the whole episode)."""
    grasp_height_m: float = 0.0
    """The oracle's grasp height above the table (0: ``OracleConfig``'s)."""

    def key(self) -> str:
        """A hash of the settings; an optional one at its default is left out."""
        named = {f.name: getattr(self, f.name) for f in fields(self)
                 if f.default is MISSING or getattr(self, f.name) != f.default}
        return hashlib.sha256(json.dumps(named, sort_keys=True).encode()).hexdigest()[:16]


@dataclass
class PlanFrames:
    """Frames with their states, action chunks and layout seeds (row-aligned tensors)."""

    state: Any
    action: Any
    images: dict[str, Any]
    seeds: list[int]
    step: Any
    """Each frame's policy step in its episode (from Home, or from a detour's stop)."""
    task: str
    dropped: list[int]
    """Layout seeds without frames: no plan, or (played to the end) not stacked."""

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

    def joined(self, other: "PlanFrames") -> "PlanFrames":
        """These frames, then ``other``'s (same cameras and task)."""
        import torch

        return PlanFrames(torch.cat([self.state, other.state]), torch.cat([self.action, other.action]),
                          {key: torch.cat([frames, other.images[key]]) for key, frames in self.images.items()},
                          self.seeds + other.seeds, torch.cat([self.step, other.step]), self.task,
                          self.dropped + other.dropped)


def make_plan_frames(settings: PlanFrameSettings, task: str, cache: Path, workers: int = 2) -> PlanFrames:
    """The frames of ``settings``, read from ``cache/<key>.npz`` or made there first."""
    import numpy as np
    import torch

    path = cache / f"{settings.key()}-{hashlib.sha256(task.encode()).hexdigest()[:8]}.npz"
    if not path.is_file():
        started = time.monotonic()
        parts = [settings.seeds[i::workers] for i in range(workers)]
        if workers > 1:
            with multiprocessing.get_context("spawn").Pool(workers) as pool:
                made = pool.starmap(_play_part, [(settings, task, part) for part in parts if part])
        else:
            made = [_play_part(settings, task, settings.seeds)]
        arrays = {key: np.concatenate([part[key] for part in made]) for key in made[0]}
        cache.mkdir(parents=True, exist_ok=True)
        partial = path.with_suffix(".partial.npz")
        np.savez(partial, **arrays)  # type: ignore[arg-type]  # numpy 2.4's stub: **arrays might name allow_pickle
        partial.replace(path)
        LOG.info("played %d layouts into %d frames in %.0f s (%d dropped; %s)", len(settings.seeds), len(arrays["seed"]),
                 time.monotonic() - started, len(arrays["dropped"]), path)
    with np.load(path) as arrays:
        images = {f"observation.images.{c}": torch.from_numpy(arrays[f"image_{c}"]) for c in settings.cameras}
        seeds = arrays["seed"].tolist()
        return PlanFrames(torch.from_numpy(arrays["state"]), torch.from_numpy(arrays["action"]), images,
                          seeds, torch.from_numpy(frame_steps(settings, seeds)), task, arrays["dropped"].tolist())


def first_frame_step(settings: PlanFrameSettings, seed: int) -> int:
    """The policy step of a layout's first frame: from Home, the layouts' frames are staggered by
    seed (every step of the episode is some layout's frame); a detour's frames start at its stop."""
    return seed % settings.every if settings.detour_m <= 0 else 0


def frame_steps(settings: PlanFrameSettings, seeds: list[int]) -> Any:
    """The policy step of every frame, given the frames' layout seeds in the order they were made
    (each layout's frames together, a frame every ``settings.every`` steps from its first)."""
    import numpy as np

    steps = np.empty(len(seeds), dtype=np.int64)
    taken = 0
    for row, seed in enumerate(seeds):
        taken = taken + 1 if row and seeds[row - 1] == seed else 0
        steps[row] = first_frame_step(settings, seed) + taken * settings.every
    return steps


def plan_delay_s(t: Any) -> Any:
    """How far behind the plan the arm runs at plan time(s) ``t`` (see the module doc)."""
    import numpy as np

    start, end = CATCH_UP_S
    return FIRST_CHUNK_DELAY_S * np.clip((end - np.asarray(t, dtype=float)) / (end - start), 0.0, 1.0)


def _play_part(settings: PlanFrameSettings, task: str, seeds: tuple[int, ...]) -> dict:
    """One worker's share: arrays ``state`` (M, A), ``action`` (M, chunk, A), ``seed`` (M,),
    ``image_<camera>`` (M, 3, size, size) uint8 and ``dropped`` (the seeds that did not stack)."""
    import mujoco
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
        raise ValueError(f"plan frames need the arm joints and one gripper column, got {list(settings.joint_names)}")
    gripper_column = gripper[0]
    config = OracleConfig() if settings.gripper_velocity is None else OracleConfig(max_gripper_velocity=settings.gripper_velocity)
    if settings.grasp_height_m > 0:
        config = replace(config, grasp_height=settings.grasp_height_m)
    home = np.asarray(settings.home, dtype=float)
    top, bottom = parse_prompt(task)
    crops = {camera: checked_crop(camera, box) for camera, box in settings.crops}
    cell = MujocoCell(CellOptions(image_width=settings.image_size, image_height=settings.image_size))

    def camera_frame(camera: str) -> Any:
        """The camera's frame now, cropped as ``demo_training`` crops recorded ones."""
        frame = cell.render(camera)
        if camera in crops:
            rows, columns = crop_slices(frame.shape[0], frame.shape[1], crops[camera])
            frame = frame[rows, columns]
        return frame

    def training_frames(frames: list) -> Any:
        """An episode's frames of one camera, resized as ``demo_training`` reads recorded ones (uint8 NCHW)."""
        return resized(torch.from_numpy(np.ascontiguousarray(np.stack(frames))).permute(0, 3, 1, 2).contiguous(),
                       settings.size).numpy()

    period = settings.control_period_s
    substeps = int(round(period / PHYSICS_DT_S))
    offsets = np.arange(settings.chunk) * period

    def play(plan: Any, steps: int, delayed: bool, noise: Any, frame_phase: int | None) -> tuple[list, dict]:
        """Command the cell along ``plan`` for ``steps`` policy steps (behind it by ``plan_delay_s``
        when ``delayed``, plus ``noise``); a frame (state, label chunk, camera frames) at every step
        ``s`` with ``s % every == frame_phase`` (none when ``frame_phase`` is None)."""
        # The whole episode's commands at once: arm (with its velocity) and gripper at every tick.
        ticks = np.arange(steps * substeps) * PHYSICS_DT_S
        behind = ticks - plan_delay_s(ticks) if delayed else ticks
        arm_now, _ = plan.sample(behind)
        arm_next, _ = plan.sample(behind + 1e-3)
        if noise is not None:
            arm_now, arm_next = arm_now + noise.offsets(plan, behind), arm_next + noise.offsets(plan, behind + 1e-3)
        arm_velocity = (arm_next - arm_now) / 1e-3
        _, gripper_command = plan.sample(ticks - GRIPPER_DELAY_S)
        taken: list[tuple[Any, Any]] = []
        camera_frames: dict[str, list] = {c: [] for c in settings.cameras}
        for step in range(steps):
            if frame_phase is not None and step % settings.every == frame_phase:
                state = np.empty(len(settings.joint_names))
                state[arm], state[gripper_column] = cell.arm_position(), cell.gripper_position()
                arm_chunk, gripper_chunk = plan.sample(step * period + offsets)
                chunk = np.empty((settings.chunk, len(settings.joint_names)))
                chunk[:, arm], chunk[:, gripper_column] = arm_chunk, gripper_chunk
                taken.append((state, chunk))
                for camera in settings.cameras:
                    camera_frames[camera].append(camera_frame(camera))
            for tick in range(step * substeps, (step + 1) * substeps):
                cell.command_arm(arm_now[tick], arm_velocity[tick])
                cell.command_gripper(float(gripper_command[tick]), 100.0)
                cell.step(PHYSICS_DT_S)
        return taken, camera_frames

    def detour(seed: int, top_pose: tuple) -> None:
        """Play the plan to the seed's moved pre-grasp, stopping part-way (see the module doc)."""
        rng = np.random.default_rng([seed, 0xDE7])
        angle, radius = rng.uniform(0.0, 2.0 * np.pi), rng.uniform(DETOUR_MIN_M, settings.detour_m)
        shift = np.array([radius * np.cos(angle), radius * np.sin(angle), rng.uniform(*DETOUR_HEIGHT_M)])
        turn, turned = np.empty(4), np.empty(4)
        mujoco.mju_axisAngle2Quat(turn, np.array([0.0, 0.0, 1.0]), rng.uniform(-DETOUR_YAW_RAD, DETOUR_YAW_RAD))
        mujoco.mju_mulQuat(turned, turn, np.asarray(top_pose[1], dtype=float))
        wrong = plan_stack(kinematics, home[arm], float(home[gripper_column]), (top_pose[0] + shift, turned),
                           cell.cube_pose(bottom), config)
        arrival_s = wrong.boundaries()["pre_grasp"][1]
        last_s = wrong.boundaries()["descend"][1] if settings.detour_descent else arrival_s
        stop_s = rng.uniform(DETOUR_FIRST_STOP * arrival_s, last_s)
        play(wrong, max(1, int(round(stop_s / period))), True, None, None)

    frames: dict[str, list[Any]]
    states, actions, seeds_out, frames, dropped = [], [], [], {c: [] for c in settings.cameras}, []
    try:
        for seed in seeds:
            cell.reset(seed, home[arm])
            try:
                start = home[arm], float(home[gripper_column])
                if settings.detour_m > 0:
                    detour(seed, cell.cube_pose(top))
                    start = cell.arm_position(), cell.gripper_position()
                plan = plan_stack(kinematics, *start, cell.cube_pose(top), cell.cube_pose(bottom), config)
            except PlanError:
                dropped.append(seed)
                continue
            noise = MotionNoise(settings.motion_noise_rad, seed, len(arm)) if settings.motion_noise_rad > 0 else None
            steps = int(round((plan.duration + settings.hold_after_plan_s) / period))
            if settings.first_steps > 0:
                steps = min(steps, settings.first_steps)
            from_home = settings.detour_m <= 0
            taken, camera_frames = play(plan, steps, from_home, noise, first_frame_step(settings, seed))
            stacked = cell.cube_pose(bottom)[0] + np.array([0.0, 0.0, config.cube_size])
            if settings.first_steps <= 0 and np.linalg.norm(cell.cube_pose(top)[0] - stacked) > STACK_TOLERANCE_M:
                dropped.append(seed)
                continue
            for state, chunk in taken:
                states.append(state)
                actions.append(chunk)
                seeds_out.append(seed)
            for camera in settings.cameras:
                frames[camera].append(training_frames(camera_frames[camera]))
    finally:
        cell.close()
    out = {"state": np.asarray(states, dtype=np.float32).reshape(-1, len(settings.joint_names)),
           "action": np.asarray(actions, dtype=np.float32).reshape(-1, settings.chunk, len(settings.joint_names)),
           "seed": np.asarray(seeds_out, dtype=np.int64), "dropped": np.asarray(dropped, dtype=np.int64)}
    for camera in settings.cameras:
        out[f"image_{camera}"] = np.concatenate(frames[camera]) if frames[camera] else \
            np.zeros((0, 3, settings.size, settings.size), np.uint8)
    return out

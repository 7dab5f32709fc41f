"""``objective record-demos``: oracle demonstrations recorded in the cell as a local LeRobotDataset.

How an episode is recorded (through the normal runtime, so the demonstrations see exactly what a
policy sees in deployment: the same camera topics, joint states and prompt, and the robot moved
by ExecutePolicy through the admittance controller with the shipped Objective's settings):

1. The world (``vla_sim`` when installed, else ``kinematic``; ``--world`` picks) starts with the
   episode's seed, so the cube layout differs per episode, and serves no policy of its own.
2. :data:`RECORD_XML` runs the shipped "Prepare for Policy" SubTree, then ExecutePolicy exactly as
   ``objectives/stack_cubes.xml`` does (dt 0.1 s, 20 committed steps) with the scripted oracle
   behind ``/get_action_chunk``, then the stack check.
3. While ExecutePolicy runs, the world wrapper samples a frame every policy step (0.1 s of sim
   time): the camera topics and ``/joint_states`` as a subscriber reads them, and as ``action``
   the oracle's plan at that instant (the same function its chunks sample: a chunk's row ``k`` is
   the plan ``k`` steps after the request). So the 50-step chunk a policy must learn at frame
   ``t`` is the ``action`` of frames ``t .. t+49``: what LeRobot's ``delta_timestamps`` loads.
   (Requests alone would give an observation only every 20 steps, and a run with one committed
   step per chunk is not what ExecutePolicy is built for: every window would end at rest.)
4. After the run, the frames go into the dataset (``add_frame`` / ``save_episode``), images as
   PNG (``image`` features, no video codec to depend on); episodes whose stack check failed are
   dropped unless ``keep_failed``. ``meta/demos.json`` lists the seeds kept and dropped.
5. With ``workers`` > 1 the episodes run in that many spawned processes and come back in seed
   order; the dataset is written in ``OUT.partial`` and renamed to ``OUT`` once complete.

Demo-only settings (``DemoOptions``; the oracle's defaults, used by ``make demo`` and the
benchmarks, stay as they are):

- ``gripper_velocity``: the oracle's ``max_gripper_velocity`` while recording, so the demonstrated
  gripper column can move well inside the gripper's limits (a learned policy overshoots what it saw).
- ``motion_noise_rad``: DART-style recovery data. The chunks the oracle serves (what is executed)
  get a smooth random offset per arm joint, while every frame's label stays the oracle's plan; so
  the dataset shows states off the plan labelled with the way back. The offset fades in over the
  first ``NOISE_RAMP_S``, fades out over the grasp descent (none while closing and lifting), comes
  back after the lift and fades out over the place descent, so the cube is grasped and released
  exactly where the oracle planned (``MotionNoise.envelope``).
- ``hold_after_plan_s``: frames stop this long after the plan's end (the oracle then only holds its
  final pose, and the training repeats that hold as the label of later steps).
- ``cameras``: the cameras kept in the dataset.

Features: ``observation.state`` and ``action`` (float32, the 6 arm joints then the gripper joint,
the request's ``robot_state`` order), ``observation.images.<camera>`` (H x W x 3 uint8) per camera,
and the prompt as the frame's task. ``meta/info.json`` keeps the joint names.

Episode ``i`` has layout seed ``seed + i``; the same seeds give the same dataset.
"""
from __future__ import annotations

import json
import logging
import math
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from policy.backend import PolicyRequest, PolicyResponse

from runtime.errors import OptionError

LOG = logging.getLogger("objective.demos")

DEFAULT_PROMPT = "stack the blue cube on the green cube"
CAMERAS = ("scene", "wrist", "overview")
FPS = 10
"""The dataset's rate: frames (requests) are 0.1 s apart, the learned policy's step."""
NOISE_RAMP_S = 1.0
"""Seconds over which the motion noise fades in, at the start and after the lift."""
NOISE_PERIODS_S = (2.5, 4.0, 6.5)
"""Periods of the sinusoids summed into each joint's motion noise."""

RECORD_XML = """<?xml version="1.0" encoding="UTF-8"?>
<root BTCPP_format="4" main_tree_to_execute="Record Demonstration">
  <BehaviorTree ID="Record Demonstration">
    <Sequence>
      <SubTree ID="Prepare for Policy"/>
      <ExecutePolicy
          policy_service_name="/get_action_chunk"
          joint_group_name="manipulator"
          prompt="{prompt}"
          total_action_steps="{total_steps}"
          dt="0.1"
          committed_action_steps="20"
          num_interpolation_points="200"
          goal_path_tolerance="0.3"
          policy_tracking_weight="300.0"
          policy_call_timeout="10.0"
          image_topics="/scene_camera/color;/wrist_camera/color;/overview_camera/color"
          image_names="scene;wrist;overview"
          joint_states_topic="/joint_states"
          gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd"
          gripper_joint_name="robotiq_85_left_knuckle_joint"/>
      <SubTree ID="Check if One Cube Is on Another" top_color="{top}" bottom_color="{bottom}"/>
    </Sequence>
  </BehaviorTree>
</root>
"""


@dataclass
class DemoFrame:
    images: dict[str, np.ndarray]
    state: np.ndarray
    action: np.ndarray
    prompt: str
    time: float


class _RecordingWorld:
    """The world, with the oracle served on ``/get_action_chunk`` and a frame sampled every step.

    Delegates everything else to the wrapped world. ``frames`` holds the episode's samples, taken
    from the first real request (ExecutePolicy's second ``new_episode`` request; the first is its
    discarded warmup) for ``duration`` seconds of sim time.
    """

    def __init__(self, inner: Any, prompt: str, duration: float, options: "DemoOptions", seed: int) -> None:
        self.inner = inner
        self.prompt = prompt
        self.duration = duration
        self.options = options
        self.noise = MotionNoise(options.motion_noise_rad, seed) if options.motion_noise_rad > 0 else None
        self.frames: list[DemoFrame] = []
        self.joint_names: list[str] = []
        self.oracle: Any = None
        self.started_at: float | None = None
        self.episode_requests = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def start(self, context: Any) -> None:
        from sensor_msgs.msg import Image, JointState

        from policy.adapter import DEFAULT_SERVICE_NAME, PolicyAdapter
        from sim.oracle import oracle_for_cell

        self.inner.start(context)
        self.oracle = oracle_for_cell(self.inner.cell, config=self.options.oracle_config())
        self.oracle.load()
        PolicyAdapter(_EpisodeStart(self.oracle, self)).serve(context.bus, DEFAULT_SERVICE_NAME)
        self.joint_sub = context.bus.create_subscription("/joint_states", JointState, None)
        self.camera_subs = {c: context.bus.create_subscription(f"/{c}_camera/color", Image, None) for c in self.options.cameras}

    def step_to(self, t: float) -> None:
        self.inner.step_to(t)
        if self.started_at is None or self.oracle.plan is None:
            return
        now = float(self.oracle.peek.time())
        elapsed = now - self.started_at
        if elapsed > self.duration - 1e-9:
            return
        hold = self.options.hold_after_plan_s
        if hold is not None and now - self.oracle.plan.start > self.oracle.plan.duration + hold + 1e-9:
            return
        if elapsed + 1e-9 >= len(self.frames) / FPS:
            self.frames.append(self._sample(now))

    def _sample(self, now: float) -> DemoFrame:
        from policy.images import image_to_rgb

        joints = self.joint_sub.latest
        names = list(joints.name)
        arm_names = list(self.oracle.peek.kinematics.joint_names)
        arm, gripper = self.oracle.plan.sample(np.array([now - self.oracle.plan.start]))
        action = np.empty(len(names), dtype=np.float32)
        for column, name in enumerate(names):
            action[column] = arm[0, arm_names.index(name)] if name in arm_names else float(np.ravel(gripper)[0])
        self.joint_names = names
        return DemoFrame(
            images={c: image_to_rgb(sub.latest, c) for c, sub in self.camera_subs.items()},
            state=np.asarray(joints.position, dtype=np.float32),
            action=action,
            prompt=self.prompt,
            time=now,
        )


class MotionNoise:
    """A smooth random offset per arm joint, a function of plan time (the same at every request,
    so overlapping chunks agree): a sum of sinusoids of ``NOISE_PERIODS_S`` with seeded phases and
    weights, scaled to peak near ``amplitude_rad``, times :meth:`envelope`."""

    def __init__(self, amplitude_rad: float, seed: int, joints: int = 6) -> None:
        rng = np.random.default_rng([seed, 0x5EED])
        self.amplitude_rad = amplitude_rad
        self.phases = rng.uniform(0.0, 2.0 * math.pi, size=(len(NOISE_PERIODS_S), joints))
        weights = rng.uniform(0.5, 1.0, size=(len(NOISE_PERIODS_S), joints))
        self.weights = weights / weights.sum(axis=0, keepdims=True)

    def offsets(self, plan: Any, times: np.ndarray) -> np.ndarray:
        """(len(times), joints) offsets at plan times ``times``."""
        times = np.asarray(times, dtype=float)
        omega = 2.0 * math.pi / np.asarray(NOISE_PERIODS_S)
        waves = np.sin(times[:, None, None] * omega[None, :, None] + self.phases[None]) * self.weights[None]
        return self.amplitude_rad * waves.sum(axis=1) * self.envelope(plan, times)[:, None]

    @staticmethod
    def envelope(plan: Any, times: np.ndarray) -> np.ndarray:
        """How much of the offset applies at plan times ``times``, in [0, 1]: rising from 0 over
        ``NOISE_RAMP_S`` at the plan's start, fading linearly to 0 over the grasp descent (exactly
        on the plan when the fingers close), 0 while closing and lifting, rising again over
        ``NOISE_RAMP_S`` after the lift, fading to 0 over the place descent, 0 from the release on."""
        bounds = plan.boundaries()
        times = np.asarray(times, dtype=float)

        def rise(start: float) -> np.ndarray:
            return np.clip((times - start) / NOISE_RAMP_S, 0.0, 1.0)

        def fade(segment: str) -> np.ndarray:
            start, end = bounds[segment]
            return np.clip((end - times) / max(end - start, 1e-9), 0.0, 1.0)

        grasping = rise(0.0) * fade("descend")
        carrying = rise(bounds["lift"][1]) * fade("place")
        return np.where(times < bounds["close"][0], grasping, carrying)


class _EpisodeStart:
    """The oracle as a backend, telling the world when the real episode starts, and adding the
    world's motion noise (if any) to the arm columns of the chunks it serves (what is executed;
    the recorded labels are sampled from the plan itself)."""

    def __init__(self, inner: Any, world: _RecordingWorld) -> None:
        self.inner, self.world, self.name = inner, world, "oracle"

    def load(self) -> None:
        self.inner.load()

    def warmup(self, example_request: PolicyRequest) -> None:
        self.inner.warmup(example_request)

    def infer(self, request: PolicyRequest) -> PolicyResponse:
        response = self.inner.infer(request)
        if request.new_episode:
            self.world.episode_requests += 1
            if self.world.episode_requests == 2:  # the first one is ExecutePolicy's discarded warmup
                self.world.started_at = float(self.inner.peek.time())
                self.world.frames = []
        noise, plan = self.world.noise, self.inner.plan
        if noise is None or response.actions is None or plan is None:
            return response
        arm_names = list(self.inner.peek.kinematics.joint_names)
        columns = [list(request.joint_names).index(name) for name in arm_names]
        period = response.native_control_period or self.inner.config.control_period
        times = float(self.inner.peek.time()) - plan.start + period * np.arange(len(response.actions))
        actions = np.array(response.actions, dtype=float, copy=True)
        actions[:, columns] += noise.offsets(plan, times)
        return PolicyResponse.chunk(actions, response.native_control_period, response.policy_actions)


@dataclass
class DemoOptions:
    episodes: int
    seed: int
    out: Path
    world: str | None = None
    """None: ``vla_sim`` when installed, else ``kinematic`` (whose cameras are flat gray)."""
    image_size: int = 128
    total_steps: int = 250
    prompt: str = DEFAULT_PROMPT
    keep_failed: bool = False
    """Keep episodes whose final stack check failed (default: drop them, a demonstration must succeed)."""
    overwrite: bool = False
    workers: int = 1
    """Processes recording episodes at once (each runs its own world)."""
    cameras: tuple[str, ...] = CAMERAS
    """Cameras kept in the dataset (a subset of ``CAMERAS``)."""
    gripper_velocity: float | None = None
    """The oracle's ``max_gripper_velocity`` while recording (rad/s); None: the oracle's default."""
    motion_noise_rad: float = 0.0
    """Peak of the smooth offset added to the executed arm motion (rad per joint); 0: none."""
    hold_after_plan_s: float | None = None
    """Stop taking frames this long after the oracle's plan ends; None: take ``total_steps`` frames."""

    def oracle_config(self) -> Any:
        """The oracle's configuration for recording: its defaults, but for ``gripper_velocity``."""
        from sim.oracle import OracleConfig

        if self.gripper_velocity is None:
            return OracleConfig()
        return OracleConfig(max_gripper_velocity=self.gripper_velocity)

    def check(self) -> None:
        """OptionError naming the first setting that cannot be recorded."""
        if self.episodes < 1:
            raise OptionError(f"--episodes must be >= 1, got {self.episodes}")
        if self.workers < 1:
            raise OptionError(f"--workers must be >= 1, got {self.workers}")
        unknown = [c for c in self.cameras if c not in CAMERAS]
        if unknown or not self.cameras or len(set(self.cameras)) != len(self.cameras):
            raise OptionError(f"--cameras must name distinct cameras of {', '.join(CAMERAS)}, got {', '.join(self.cameras) or 'none'}")
        if self.gripper_velocity is not None and not self.gripper_velocity > 0:
            raise OptionError(f"--gripper-velocity must be positive, got {self.gripper_velocity}")
        if not self.motion_noise_rad >= 0:
            raise OptionError(f"--motion-noise must be >= 0, got {self.motion_noise_rad}")
        if self.hold_after_plan_s is not None and not self.hold_after_plan_s >= 0:
            raise OptionError(f"--hold-after-plan must be >= 0, got {self.hold_after_plan_s}")


@dataclass
class DemoSummary:
    out: Path
    world: str
    episodes_kept: int
    episodes_dropped: list[int]
    frames: int
    joint_names: list[str]


def default_world() -> str:
    from importlib.metadata import entry_points

    names = {ep.name for ep in entry_points(group="objective.worlds")}
    return "vla_sim" if "vla_sim" in names else "kinematic"


def dataset_features(joint_names: list[str], image_size: int, cameras: tuple[str, ...] = CAMERAS) -> dict:
    """LeRobotDataset features of the recording."""
    vector = {"dtype": "float32", "shape": (len(joint_names),), "names": list(joint_names)}
    features = {"observation.state": dict(vector), "action": dict(vector)}
    for camera in cameras:
        features[f"observation.images.{camera}"] = {
            "dtype": "image", "shape": (image_size, image_size, 3), "names": ["height", "width", "channels"],
        }
    return features


@dataclass
class EpisodeRecording:
    """One recorded episode: its frames, how its run ended, and the joint order of its vectors."""

    seed: int
    status: str
    reason: str
    frames: list[DemoFrame]
    joint_names: list[str]


def record_episode(seed: int, options: DemoOptions, world_name: str) -> EpisodeRecording:
    """Run the oracle once in a fresh world with layout ``seed``; its frames and status (in this process)."""
    from runtime.tree.loader import load_tree
    from runtime.tree.registry import Registry
    from runtime.app.runner import RunOptions, make_context, run_tree
    from runtime.app.world import create_world
    from sim.oracle import parse_prompt

    top, bottom = parse_prompt(options.prompt)
    run_options = RunOptions(seed=seed, world=world_name, policy_latency="0", sets={
        "prompt": options.prompt, "total_steps": str(options.total_steps), "top": top, "bottom": bottom,
    })
    world_options = {"seed": seed, "realtime": False, "policy": "none", "policy_latency": "0",
                     "image_size": options.image_size}
    world = _RecordingWorld(create_world(world_name, world_options), options.prompt, options.total_steps / FPS, options, seed)
    context = make_context(run_options)
    objectives = Path(__file__).resolve().parent.parent / "objectives"
    loaded = load_tree(RECORD_XML, Registry.from_entry_points(), context, objectives_dir=objectives)
    result = run_tree(loaded, context, run_options, world=world)
    return EpisodeRecording(seed, result.status, result.reason or "", world.frames, world.joint_names)


def record_demos(options: DemoOptions) -> DemoSummary:
    """Record ``options.episodes`` oracle episodes into a LeRobotDataset at ``options.out``.

    Episodes run in ``options.workers`` processes (each its own world); the dataset is written
    here, in seed order, into ``OUT.partial`` and renamed to ``OUT`` only once it is complete.
    """
    from policy.lerobot_offline import force_offline

    force_offline()
    import datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    datasets.disable_progress_bars()
    from sim.oracle import parse_prompt

    options.check()
    parse_prompt(options.prompt)
    out = Path(options.out)
    if out.exists() and not options.overwrite:
        raise OptionError(f"{out} already exists (pass --overwrite to replace it)")
    partial = out.with_name(out.name + ".partial")
    if partial.exists():
        shutil.rmtree(partial)
    world_name = options.world or default_world()
    dataset = None
    dropped: list[int] = []
    kept = frames = 0
    joint_names: list[str] = []
    seeds = [options.seed + episode for episode in range(options.episodes)]
    for episode, recording in enumerate(_record_all(seeds, options, world_name)):
        seed = recording.seed
        if recording.status == "ERROR":  # bad input or a bug: every episode would end the same way
            raise RuntimeError(f"episode {episode} (seed {seed}): {recording.reason}")
        if recording.status != "SUCCESS" and not options.keep_failed:
            LOG.warning("episode %d (seed %d) dropped: %s", episode, seed, recording.reason)
            dropped.append(seed)
            continue
        _check_frames(recording.frames, seed, options.image_size, options.cameras)
        if dataset is None:
            joint_names = recording.joint_names
            dataset = LeRobotDataset.create(
                repo_id="local/stack_cubes_demos", fps=FPS, root=partial, robot_type="ur5e_2f85",
                features=dataset_features(joint_names, options.image_size, options.cameras), use_videos=False,
            )
        for frame in recording.frames:
            dataset.add_frame({
                "observation.state": frame.state,
                "action": frame.action,
                **{f"observation.images.{c}": frame.images[c] for c in options.cameras},
                "task": frame.prompt,
            })
        dataset.save_episode()
        kept += 1
        frames += len(recording.frames)
        LOG.info("episode %d (seed %d): %d frames, %s", episode, seed, len(recording.frames), recording.status)
    if dataset is None:
        raise RuntimeError(f"no successful episode in {options.episodes} (seeds {options.seed}..{options.seed + options.episodes - 1})")
    dataset.finalize()
    (partial / "meta" / "demos.json").write_text(json.dumps({
        "world": world_name, "image_size": options.image_size, "steps": options.total_steps, "prompt": options.prompt,
        "cameras": list(options.cameras), "gripper_velocity": options.gripper_velocity,
        "motion_noise_rad": options.motion_noise_rad, "hold_after_plan_s": options.hold_after_plan_s,
        "seeds": [seed for seed in seeds if seed not in dropped], "dropped_seeds": dropped,
    }, indent=2) + "\n", encoding="utf-8")
    if out.exists():
        shutil.rmtree(out)
    partial.rename(out)
    return DemoSummary(out, world_name, kept, dropped, frames, joint_names)


def _record_all(seeds: list[int], options: DemoOptions, world_name: str):
    """The episodes of ``seeds``, in order: here with one worker, else in a pool of spawned processes."""
    if options.workers == 1 or len(seeds) == 1:
        for seed in seeds:
            yield record_episode(seed, options, world_name)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from functools import partial

    pool = ProcessPoolExecutor(max_workers=min(options.workers, len(seeds)), mp_context=multiprocessing.get_context("spawn"))
    try:
        yield from pool.map(partial(record_episode, options=options, world_name=world_name), seeds)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _check_frames(frames: list[DemoFrame], seed: int, image_size: int, cameras: tuple[str, ...] = CAMERAS) -> None:
    """Frames must be one policy step apart and full size, or the chunk labels would be wrong."""
    if not frames:
        raise RuntimeError(f"episode with seed {seed} recorded no frame")
    for frame in frames:
        missing = [c for c in cameras if c not in frame.images]
        if missing:
            raise RuntimeError(f"episode with seed {seed}: no frame from cameras {missing}")
        shape = frame.images[cameras[0]].shape
        if shape != (image_size, image_size, 3):
            raise RuntimeError(
                f"episode with seed {seed}: camera frames are {shape}, expected {image_size} x {image_size} x 3 "
                f"(does the world take the image_size option?)"
            )
    if not math.isfinite(float(np.sum([f.action.sum() for f in frames]))):
        raise RuntimeError(f"episode with seed {seed}: non-finite actions")

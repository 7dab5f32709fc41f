"""Train the learned stacking policy (`make learned-policy`): located cubes + joints -> a flow-matching chunk.

    .venv/bin/python tools/train_learned.py --out build/policies/learned --seed 0

Steps (each seeded):

1. **Frames.** The oracle's plan played straight into the cell (``tools.plan_frames``: the cell's own
   physics, grasp and release, the recorder's timing and its recovery noise, episodes that do not
   stack dropped) for ``--layouts`` layout seeds from ``--layout-seed``, a frame at every policy step:
   the measured joints (six arm joints, then the gripper) and the plan's next ``--chunk`` steps as label.
   No camera is rendered: the policy reads the cubes through its perception stage
   (``policy.cube_locator``), whose output is the cubes' x, y and face yaw, so training gives it the
   layout's poses plus the perception's measured error (``--position-noise``, ``--yaw-noise``).
2. **Model.** The chunk is learned relative to the observed joints (``relative_actions``: the
   backend adds them back). LeRobot's ``MultiTaskDiTPolicy`` with ``objective="flow_matching"``
   (``policy.learned_stack``): ``observation.state`` = joints and located cubes, the prompt through a
   tiny random CLIP text encoder kept in the checkpoint (``clip/``), no image features.
3. **Training** for ``--steps`` or ``--minutes``, whichever ends first (AdamW, cosine schedule).
4. **Saving** in LeRobot's format in ``--out`` with ``objective_policy.json``: joint names, control
   period, the perception's configuration (``cube_locator``), the training's seed, steps, layout seeds
   and ``data_sha256`` (SHA-256 of the frames' arrays).
5. **Evaluation** (``--eval-episodes``) with ``objective eval objectives/stack_cubes_learned.xml`` on
   held-out seeds into ``<out>.eval/``.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import logging
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

LOG = logging.getLogger("train_learned")
PROMPT = "stack the blue cube on the green cube"
GRIPPER_JOINT = "robotiq_85_left_knuckle_joint"
HELD_OUT = range(100, 150)
CHUNK_STEPS = 50
"""Policy steps per chunk (5 s at the control period of 0.1 s)."""


def policy_start_rad() -> tuple[float, ...]:
    """The arm where the Objective hands it to the policy: the ``Home`` waypoint
    (sim/config/waypoints.yaml) that ``Prepare for Policy`` moves to, in the planning model's joint order."""
    from sim.oracle import SceneKinematics
    from sim.robot_model import load_waypoints, planning_robot_model

    home = load_waypoints()["Home"]
    return tuple(float(home[name]) for name in SceneKinematics(planning_robot_model()).joint_names)


def frame_settings(args: argparse.Namespace, seeds: tuple[int, ...]):
    """The plan frames' settings (``tools.plan_frames``): from the arm where the Objective starts the
    policy (``policy_start_rad``), no camera, a frame every step, the recorder's demonstration settings
    (gripper at 0.5 rad/s, 0.04 rad recovery noise, 2 s held after the plan)."""
    from sim.robot_model import planning_robot_model
    from sim.oracle import SceneKinematics
    from tools.plan_frames import PlanFrameSettings

    reserved = sorted(set(seeds) & set(HELD_OUT))
    if reserved:
        raise SystemExit(f"--layout-seed {args.layout_seed}: the layouts would include held-out seeds {reserved[0]}..{reserved[-1]}")
    arm = tuple(SceneKinematics(planning_robot_model()).joint_names)
    return PlanFrameSettings(
        seeds=seeds, every=args.every, hold_after_plan_s=2.0, home=policy_start_rad() + (0.0,),
        joint_names=arm + (GRIPPER_JOINT,), cameras=(), image_size=64, crops=(), size=64, chunk=CHUNK_STEPS,
        control_period_s=0.1, gripper_velocity=0.5, motion_noise_rad=args.motion_noise,
        grasp_height_m=args.grasp_height)


def load_frames(args: argparse.Namespace, first: int | None = None, count: int | None = None):
    """The plan frames of ``count`` layouts from ``first`` (default: the training's), played ``args.part``
    layouts at a time into the cache."""
    from tools.plan_frames import make_plan_frames

    first = args.layout_seed if first is None else first
    end = first + (args.layouts if count is None else count)
    parts = [make_plan_frames(frame_settings(args, tuple(range(start, min(start + args.part, end)))), PROMPT,
                              args.cache, workers=args.workers) for start in range(first, end, args.part)]
    frames = parts[0]
    for part in parts[1:]:
        frames = frames.joined(part)
    return frames


def keypoint_config(args: argparse.Namespace):
    """The policy's keypoint configuration: the arm's chain from the planning model, the IK's first seed
    where the policy starts (``policy_start_rad``), the geometry of the played plans (``--grasp-height``)."""
    import numpy as np

    from policy.stack_keypoints import KeypointConfig, StackGeometry
    from sim.cell_model import CellOptions
    from sim.oracle import OracleConfig
    from sim.robot_model import arm_chain

    oracle = OracleConfig()
    size = CellOptions().cube_size
    geometry = StackGeometry(args.grasp_height if args.grasp_height > 0 else oracle.grasp_height,
                             oracle.approach_height, oracle.cube_size, oracle.place_clearance)
    return KeypointConfig(arm_chain(), np.asarray(policy_start_rad(), dtype=float), geometry, size / 2)


class LocatedFeatures:
    """What the perception stage gives the chunk model for each frame's layout: the located cubes
    (``cube_features``) and their keypoints (``stack_keypoints``), exact and with ``draws`` draws
    of the perception's error per layout (each with its keypoints solved again)."""

    def __init__(self, rows: "np.ndarray", cubes: "np.ndarray", keypoints: "np.ndarray") -> None:
        self.rows = rows
        """Each frame's layout index."""
        self.cubes = cubes
        """(layouts, 1 + draws, 6): draw 0 exact."""
        self.keypoints = keypoints
        """(layouts, 1 + draws, 4, 6)."""

    @classmethod
    def of_layouts(cls, seeds: list[int], config: Any, args: argparse.Namespace) -> "LocatedFeatures":
        import numpy as np

        from policy.cube_locator import layout_features
        from policy.stack_keypoints import stack_keypoints
        from sim.layouts import layout

        order = sorted(set(seeds))
        index = {seed: i for i, seed in enumerate(order)}
        cubes = np.empty((len(order), 1 + args.perception_draws, 6))
        for i, seed in enumerate(order):
            placed = layout(seed)
            cubes[i, 0] = layout_features([placed["blue"], placed["green"]])
            rng = np.random.default_rng([args.seed, seed])
            for draw in range(1, 1 + args.perception_draws):
                cubes[i, draw] = perceived_numpy(cubes[i, 0], args.position_noise, args.yaw_noise, rng)
        keypoints = np.stack([[stack_keypoints(c, config) for c in layout_cubes] for layout_cubes in cubes])
        return cls(np.array([index[seed] for seed in seeds]), cubes, keypoints)

    def features(self, frames: Any, state: Any, draws: Any) -> Any:
        """(len(frames), 54) float32 for frame numbers ``frames`` observed at ``state`` (their joints, the
        arm's six first), each with perception draw ``draws`` (0: exact): the cubes, then the keypoints'
        features (``policy.stack_keypoints.keypoint_features``)."""
        import numpy as np
        import torch

        from policy.stack_keypoints import keypoint_features

        layouts, draws = self.rows[np.asarray(frames)], np.asarray(draws)
        arm = np.asarray(state)[:, : self.keypoints.shape[-1]].astype(float)
        offsets = keypoint_features(arm, self.keypoints[layouts, draws])
        return torch.from_numpy(np.concatenate([self.cubes[layouts, draws], offsets], axis=1).astype(np.float32))

    def exact(self, state: Any) -> Any:
        """``features`` of every frame (``state``: all frames' joints) with the exact cubes."""
        import numpy as np

        return self.features(np.arange(len(state)), state.numpy(), np.zeros(len(state), dtype=int))


def perceived_numpy(cubes: "np.ndarray", position_noise_m: float, yaw_noise_rad: float, rng: Any) -> "np.ndarray":
    """``cubes`` (x, y, yaw per cube) with the perception's error drawn: Gaussian, yaw wrapped to a quarter turn."""
    import numpy as np

    scale = np.array([position_noise_m, position_noise_m, yaw_noise_rad] * (len(cubes) // 3))
    noisy = cubes + rng.standard_normal(cubes.shape) * scale
    noisy[2::3] = np.remainder(noisy[2::3] + math.pi / 4, math.pi / 2) - math.pi / 4
    return noisy


def locator_config(cell: Any):
    """The perception's configuration, calibrated from the cell: the scene camera for positions (the
    cubes' centre plane), the overview camera for yaws (their top faces), both as the cell places them."""
    from policy.cube_locator import CameraView, CubeLocatorConfig, PinholeCamera, Vector3
    from sim.cell_model import CAMERA_FOVY_DEG

    def view(name: str, plane_z_m: float) -> CameraView:
        index = cell.model.camera(name).id
        rotation = cell.data.cam_xmat[index].reshape(3, 3)
        return CameraView(name, PinholeCamera(cast(Vector3, tuple(float(v) for v in cell.data.cam_xpos[index])),
                                              tuple(cast(Vector3, tuple(float(v) for v in row)) for row in rotation),
                                              CAMERA_FOVY_DEG[name]), plane_z_m)

    size = cell.options.cube_size
    return CubeLocatorConfig(position=view("scene", size / 2), yaw=view("overview", size), cube_size_m=size)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "build/policies/learned")
    parser.add_argument("--cache", type=Path, default=ROOT / "build/plan_frames", help="where played frames are kept")
    parser.add_argument("--layouts", type=int, default=600)
    parser.add_argument("--layout-seed", type=int, default=40000)
    parser.add_argument("--part", type=int, default=50, help="layouts per cache file (a part played is kept)")
    parser.add_argument("--every", type=int, default=1, help="a frame every this many policy steps")
    parser.add_argument("--motion-noise", type=float, default=0.04, help="recovery noise of the played motion (rad)")
    parser.add_argument("--grasp-height", type=float, default=0.025,
                        help="the oracle's grasp height above the table in the played plans (m; 0: the oracle's own, "
                             "0.018, which leaves the pads a hair over the 10 mm collision padding above the table)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--frames-only", action="store_true", help="play the frames into the cache and stop")
    parser.add_argument("--seed", type=int, default=0, help="seeds the model's weights, the batches and the noise")
    parser.add_argument("--steps", type=int, default=6000)
    parser.add_argument("--minutes", type=float, default=30.0, help="training stops after this long, whatever the steps")
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--hidden", type=int, default=64, help="the DiT's width")
    parser.add_argument("--layers", type=int, default=3, help="the DiT's layers")
    parser.add_argument("--position-noise", type=float, default=0.001, help="std of the located positions' error (m)")
    parser.add_argument("--yaw-noise", type=float, default=0.035, help="std of the located yaws' error (rad)")
    parser.add_argument("--perception-draws", type=int, default=8,
                        help="perception errors drawn per layout (each with its keypoints solved); a batch row takes one")
    parser.add_argument("--validation-layouts", type=int, default=20,
                        help="layouts after the training ones whose frames measure the fit on unseen layouts (0: none)")
    parser.add_argument("--noise-scale", type=float, default=1.0,
                        help="objective_policy.json's noise_scale: 1 samples as trained (0, a zero start, lies off the "
                             "training's noise and answers chunks 0.07 rad from the labels)")
    parser.add_argument("--chunk-samples", type=int, default=16,
                        help="objective_policy.json's chunk_samples: the served chunk is the mean of this many flow samples")
    parser.add_argument("--integration-steps", type=int, default=20, help="Euler steps of the served flow")
    parser.add_argument("--eval-episodes", type=int, default=50, help="held-out seeds evaluated after training (0: none)")
    parser.add_argument("--eval-seed-start", type=int, default=100)
    parser.add_argument("--eval-workers", type=int, default=1)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    frames = load_frames(args)
    LOG.info("%d frames of %d layouts (%d dropped)", len(frames), len(set(frames.seeds)), len(frames.dropped))
    if args.frames_only:
        return 0
    import torch

    from policy.learned_stack import CLIP_DIRNAME, LearnedStackSpec, build_learned_stack, write_tiny_clip
    from policy.lerobot_checkpoint import save_checkpoint
    from sim.cell_model import CellOptions
    from sim.mujoco_cell import MujocoCell
    from tools.demo_training import evaluate, evaluation_folder, replace_folder

    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    keypoints = keypoint_config(args)
    located = LocatedFeatures.of_layouts(frames.seeds, keypoints, args)
    state = torch.cat([frames.state, located.exact(frames.state)], dim=1)
    action = frames.action - frames.state[:, None, :]  # relative to the observed joints
    stats = {"observation.state": min_max_stats(state), "action": min_max_stats(action.reshape(-1, action.shape[-1]))}
    staging = args.out.with_name(args.out.name + ".building")
    if staging.exists():
        import shutil

        shutil.rmtree(staging)
    spec = LearnedStackSpec(joint_dim=frames.state.shape[1], cube_dim=state.shape[1] - frames.state.shape[1],
                            chunk_size=CHUNK_STEPS,
                            hidden_dim=args.hidden, layers=args.layers,
                            integration_steps=args.integration_steps)
    config, policy = build_learned_stack(spec, write_tiny_clip(staging / CLIP_DIRNAME, seed=args.seed))
    from lerobot.policies.factory import make_pre_post_processors

    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=stats)
    LOG.info("multi_task_dit (flow matching): %.2f M trainable parameters; %d frames", sum(
        p.numel() for p in policy.parameters() if p.requires_grad) / 1e6, len(state))
    run = train(policy, preprocessor, frames.state, action, located, args)
    run["fit_rad"] = training_fit_rad(policy, preprocessor, postprocessor, state, action, args.seed)
    LOG.info("sampled chunks against their labels on training frames: %.4f rad mean", run["fit_rad"])
    if args.validation_layouts > 0:
        unseen = load_frames(args, args.layout_seed + args.layouts, args.validation_layouts)
        unseen_state = torch.cat([unseen.state, LocatedFeatures.of_layouts(unseen.seeds, keypoints, args).exact(unseen.state)], 1)
        run["unseen_fit_rad"] = training_fit_rad(policy, preprocessor, postprocessor, unseen_state,
                                                 unseen.action - unseen.state[:, None, :], args.seed)
        LOG.info("... on frames of %d unseen layouts: %.4f rad mean", args.validation_layouts, run["unseen_fit_rad"])
    cell = MujocoCell(CellOptions())
    try:
        locator = locator_config(cell)
    finally:
        cell.close()
    metadata = {
        "joint_names": list(frame_settings(args, ()).joint_names), "control_period": 0.1, "prompts": [PROMPT],
        "ignored_images": ["scene", "wrist", "overview"], "default_guidance_horizon": 10,
        "noise_scale": args.noise_scale, "chunk_samples": args.chunk_samples,
        "action_range": action_range(frames.action), "cube_locator": locator.to_json(), "relative_actions": True,
        "stack_keypoints": keypoints.to_json(),
        "training": {
            "policy_type": "multi_task_dit", "objective": "flow_matching", "seed": args.seed, **run,
            "batch": args.batch, "lr": args.lr, "threads": args.threads, "hidden": args.hidden, "layers": args.layers,
            "position_noise_m": args.position_noise, "yaw_noise_rad": args.yaw_noise,
            "perception_draws": args.perception_draws,
            "layout_seeds": [args.layout_seed, args.layout_seed + args.layouts - 1], "layouts_dropped": frames.dropped,
            "frames": len(state), "motion_noise_rad": args.motion_noise, "data_sha256": frames_hash(frames),
        },
    }
    save_checkpoint(staging, config, policy, stats, metadata)
    replace_folder(staging, args.out)
    point_at_clip(args.out, staging / CLIP_DIRNAME)
    LOG.info("saved %s: %d steps in %.0f s, final loss %.4f", args.out, run["steps"], run["seconds"], run["final_loss"])
    result = {"checkpoint": str(args.out), **metadata["training"]}
    if args.eval_episodes > 0:
        result["evaluation"] = evaluate(args.out, args.eval_episodes, args.eval_seed_start, 224, args.eval_workers, None,
                                        objective=ROOT / "objectives" / "stack_cubes_learned.xml")
        LOG.info("evaluation in %s", evaluation_folder(args.out))
    print(json.dumps(result))
    return 0


def point_at_clip(folder: Path, built_at: Path) -> None:
    """Name ``folder``'s own ``clip/`` in its config and preprocessor, where the staging folder's was
    (the backend loads the checkpoint's ``clip/`` wherever the folder is; LeRobot's own loaders read these)."""
    for name in ("config.json", "policy_preprocessor.json"):
        path = folder / name
        path.write_text(path.read_text(encoding="utf-8").replace(str(built_at), str(folder / "clip")), encoding="utf-8")


def action_range(action: Any) -> dict:
    """The labels' range per joint (``objective_policy.json``'s ``action_range``: the served chunk stays inside it)."""
    flat = action.reshape(-1, action.shape[-1])
    return {"min": [round(float(v), 5) for v in flat.min(0).values], "max": [round(float(v), 5) for v in flat.max(0).values]}


def min_max_stats(values: Any) -> dict:
    """LeRobot's normalization statistics of (N, D) ``values``."""
    return {"min": values.min(0).values, "max": values.max(0).values, "mean": values.mean(0), "std": values.std(0)}


def frames_hash(frames: Any) -> str:
    """SHA-256 of the frames' states, actions and layout seeds: the data the checkpoint saw."""
    import numpy as np

    digest = hashlib.sha256()
    for array in (frames.state.numpy(), frames.action.numpy(), np.asarray(frames.seeds, dtype=np.int64)):
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()


def training_fit_rad(policy: Any, preprocessor: Any, postprocessor: Any, state: Any, action: Any, seed: int,
                     rows: int = 256) -> float:
    """Mean absolute error (rad) of sampled chunks against their labels on ``rows`` evenly spaced training
    frames (the cubes exact, the noise seeded): how well the chunk model fits what it was trained on."""
    import torch

    from policy.learned_stack import sample_chunk

    picked = torch.linspace(0, len(state) - 1, min(rows, len(state))).long()
    batch = preprocessor({"observation.state": state[picked], "action": action[picked], "task": [PROMPT] * len(picked)})
    with torch.random.fork_rng(), torch.no_grad():
        torch.manual_seed(seed)
        chunks = postprocessor(sample_chunk(policy, batch))
    return round(float((chunks - action[picked]).abs().mean()), 5)


def train(policy: Any, preprocessor: Any, joints: Any, action: Any, located: LocatedFeatures, args: argparse.Namespace) -> dict:
    """AdamW on random batches for ``args.steps`` or ``args.minutes``; each row's located features with
    one of its layout's perception draws."""
    import torch

    from tools.demo_training import learning_rate_factor

    generator = torch.Generator().manual_seed(args.seed)
    parameters = [p for p in policy.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(parameters, lr=args.lr, weight_decay=1e-4)
    policy.train()
    started, losses, step = time.monotonic(), [], 0
    budget_s = args.minutes * 60.0
    while step < args.steps and time.monotonic() - started < budget_s:
        progress = max(step / args.steps, (time.monotonic() - started) / budget_s)
        for group in optimizer.param_groups:
            group["lr"] = args.lr * learning_rate_factor(step, max(1, args.steps // 20), progress)
        rows = torch.randint(len(joints), (args.batch,), generator=generator)
        draws = torch.randint(1, 1 + args.perception_draws, (args.batch,), generator=generator) \
            if args.perception_draws > 0 else torch.zeros(args.batch, dtype=torch.long)
        observed = torch.cat([joints[rows], located.features(rows.numpy(), joints[rows].numpy(), draws.numpy())], dim=1)
        batch = preprocessor({"observation.state": observed, "action": action[rows], "task": [PROMPT] * args.batch})
        batch["observation.state"] = batch["observation.state"].unsqueeze(1)
        loss, _ = policy.forward(batch)
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(parameters, 1.0)
        optimizer.step()
        losses.append(float(loss.detach()))
        step += 1
        if step % 100 == 0:
            LOG.info("step %d: loss %.4f (%.0f s)", step, sum(losses[-100:]) / 100, time.monotonic() - started)
    policy.eval()
    tail = losses[-50:]
    return {"steps": step, "seconds": round(time.monotonic() - started, 1), "final_loss": round(sum(tail) / max(1, len(tail)), 5)}


if __name__ == "__main__":
    sys.exit(main())

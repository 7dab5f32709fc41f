"""Train a small LeRobot DiffusionPolicy on recorded oracle demonstrations (`make lerobot-diffusion`). Seeded, CPU.

    .venv/bin/python tools/train_diffusion.py --dataset build/demos/stack_cubes \\
        --out build/policies/diffusion --steps 600

The same steps as ``tools/train_tiny_smolvla.py`` (``tools/demo_training.py``: record the dataset
if missing, read it into memory, train under a step and a time budget with an annealed schedule,
save in LeRobot's format with ``objective_policy.json``, evaluate on held-out seeds), for LeRobot's
own ``DiffusionPolicy`` built from config (``policy.tiny_diffusion``: a random-weight ResNet-18
trunk with GroupNorm and a SpatialSoftmax per camera, a narrow 1-D UNet, DDIM sampling).

Batches: ``observation.state`` (B, 1, 7) and each camera (B, 1, 3, H, W) as one observation step,
``action`` (B, horizon, 7) = the oracle's labels of frames t .. t+horizon-1, min-max normalized by
LeRobot's preprocessor with the statistics of the frames read. Adam with LeRobot's diffusion preset
(betas 0.95/0.999, weight decay 1e-6).

Same seed, same data, same step count: the same weights.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tools.demo_training import (  # noqa: E402  (also ensures torchvision before LeRobot)
    add_arguments,
    checkpoint_metadata,
    load_plan_frames,
    load_demos,
    demos_meta,
    evaluate,
    frame_size,
    replace_folder,
    train,
    training_record,
)

LOG = logging.getLogger("train_diffusion")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_arguments(parser, out=ROOT / "build/policies/diffusion", steps=3000, minutes=30.0, batch=16, lr=3e-4)
    parser.add_argument("--horizon", type=int, default=32, help="steps the UNet denoises (a multiple of 2 ** len(down_dims))")
    parser.add_argument("--action-steps", type=int, default=32, help="steps answered per chunk (<= horizon; more than the "
                        "Objective's committed_action_steps)")
    parser.add_argument("--down-dims", default="64,128,256", help="UNet widths, one per level")
    parser.add_argument("--keypoints", type=int, default=32, help="SpatialSoftmax keypoints per camera")
    parser.add_argument("--backbone", default="resnet18", help="torchvision ResNet trunk (random weights)")
    parser.add_argument("--crop-ratio", type=float, default=1.0,
                        help="random crop of this share of each side in training, centre crop when serving (1: none)")
    parser.add_argument("--inference-steps", type=int, default=10, help="DDIM steps per chunk")
    parser.add_argument("--prediction", default="epsilon", choices=("epsilon", "sample"), help="what the UNet predicts")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    import torch

    from policy.lerobot_checkpoint import save_checkpoint
    from policy.tiny_diffusion import TinyDiffusionSpec, build_tiny_diffusion

    demos, crops = load_demos(args, args.horizon)
    meta, cameras = demos.meta, demos.cameras
    image_size = args.train_size or frame_size(demos)
    joint_names = list(meta.features["action"]["names"])
    spec = TinyDiffusionSpec(
        state_dim=len(joint_names), action_dim=len(joint_names), cameras=cameras, image_size=image_size,
        horizon=args.horizon, n_action_steps=args.action_steps, down_dims=tuple(int(d) for d in args.down_dims.split(",")),
        keypoints=args.keypoints, vision_backbone=args.backbone, crop_ratio=args.crop_ratio,
        num_inference_steps=args.inference_steps, prediction_type=args.prediction,
    )
    stats = demos.stats()
    config, policy = build_tiny_diffusion(spec)
    from lerobot.policies.factory import make_pre_post_processors

    preprocessor, _ = make_pre_post_processors(
        config, dataset_stats={k: {s: torch.as_tensor(v) for s, v in d.items()} for k, d in stats.items()}
    )
    pool = policy.diffusion.rgb_encoder.pool
    LOG.info("diffusion policy: %.2f M parameters (vision %.2f M); %d frames, %d episodes, cameras %s at %d px, "
             "%d x %d feature cells under the keypoints", sum(p.numel() for p in policy.parameters()) / 1e6,
             sum(p.numel() for p in policy.diffusion.rgb_encoder.parameters()) / 1e6, len(demos), demos.episodes,
             list(cameras), image_size, pool._in_h, pool._in_w)
    optimizer = torch.optim.Adam(policy.diffusion.parameters(), lr=args.lr, betas=(0.95, 0.999), weight_decay=1e-6)

    def to_batch(batch: dict) -> dict:
        """Normalized by LeRobot's preprocessor, with the one observation step the policy's forward expects."""
        normalized = preprocessor(batch)
        normalized["observation.state"] = normalized["observation.state"].unsqueeze(1)
        return normalized

    run = train(policy, optimizer, demos, to_batch, args, plan_frames=load_plan_frames(args, demos, crops, image_size, args.horizon))
    metadata = {
        **checkpoint_metadata(demos, crops),
        "training": training_record(
            args, demos, run, policy_type="diffusion", image_size=image_size, cameras=list(cameras),
            horizon=spec.horizon, n_action_steps=spec.n_action_steps, down_dims=list(spec.down_dims),
            keypoints=spec.keypoints, backbone=spec.vision_backbone, crop_ratio=spec.crop_ratio,
            inference_steps=spec.num_inference_steps, prediction=spec.prediction_type,
        ),
    }
    staging = args.out.with_name(args.out.name + ".building")
    save_checkpoint(staging, config, policy, stats, metadata)
    replace_folder(staging, args.out)
    LOG.info("saved %s: %d steps in %.0f s, final loss %.4f", args.out, run.steps, run.seconds, metadata["training"]["final_loss"])
    result = {"checkpoint": str(args.out), **metadata["training"]}
    if args.eval_episodes > 0:
        result["evaluation"] = evaluate(args.out, args.eval_episodes, args.eval_seed_start, frame_size(demos), args.workers,
                                        demos_meta(args.dataset).get("world"))
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Train the tiny SmolVLA on recorded oracle demonstrations (`make lerobot-policy`). Seeded, CPU.

    .venv/bin/python tools/train_tiny_smolvla.py --dataset build/demos/stack_cubes \
        --out build/policies/tiny_smolvla --steps 600

1. If ``--dataset`` does not exist, records it first (``objective record-demos`` with
   ``--episodes`` layouts from ``--demo-seed``, and the demonstration settings below).
2. Opens it with LeRobot's ``LeRobotDataset`` and reads it into memory once (``DemoTensors``:
   each frame with the next ``chunk`` actions of its episode, as ``delta_timestamps`` would give),
   normalization stats from the dataset's metadata.
3. Builds the tiny SmolVLA from config (``policy.tiny_smolvla``: no hub, random weights,
   everything trainable), trains it with AdamW and a cosine schedule on LeRobot's preprocessor
   output (normalized state and actions, tokenized prompt), for ``--steps`` steps or
   ``--minutes``, whichever ends first; the schedule follows whichever is further along, so a run
   stopped by the time cap still ends with the learning rate annealed (``learning_rate_factor``).
4. Saves it in LeRobot's format (``save_pretrained`` of the policy and both processors) with the
   backbone folder and ``objective_policy.json``, ready for ``--policy lerobot:OUT`` or
   ``objective serve --backend lerobot --checkpoint OUT``.

Same seed, same dataset, same step count: the same weights (seeded torch and sampling).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from typing import Any
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tools.demo_training import (  # noqa: E402  (also ensures torchvision before LeRobot)
    DemoTensors,
    add_arguments,
    checkpoint_metadata,
    load_plan_frames,
    load_demos,
    dataset_hash,  # noqa: F401  (the tests read it from this script)
    demos_meta,
    evaluate,
    frame_size,
    learning_rate_factor,  # noqa: F401
    metadata_stats,
    replace_folder,
    sample_rows,  # noqa: F401
    train,
    training_record,
)

from tools.layout_target import LayoutProbe, checked_colors, layout_targets  # noqa: E402

LOG = logging.getLogger("train_tiny_smolvla")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_arguments(parser, out=ROOT / "build/policies/tiny_smolvla", steps=1500, minutes=8.0, batch=16, lr=5e-4)
    parser.add_argument("--vision-width", type=int, default=64, help="width of the tiny vision tower")
    parser.add_argument("--vision-layers", type=int, default=2, help="layers of the tiny vision tower")
    parser.add_argument("--patch-size", type=int, default=16, help="vision-tower patch size (px)")
    parser.add_argument("--layout-target", type=float, default=0.0, metavar="WEIGHT",
                        help="add the cube layout as an auxiliary target of the vision tokens of --layout-camera, "
                             "weighted so (tools/layout_target.py; 0: off)")
    parser.add_argument("--layout-camera", default="overview", help="the camera whose vision tokens learn the layout")
    parser.add_argument("--layout-cubes", default="red,green,blue", metavar="A,B",
                        help="the cubes whose positions the layout target holds (default: all)")
    args = parser.parse_args(argv)
    args.layout_cubes = checked_colors(args.layout_cubes.split(","))
    return args


def layout_probe(policy: Any, config: Any, demos: DemoTensors, args: argparse.Namespace, image_size: int,
                 crops: dict, plan_frames: Any = None) -> LayoutProbe:
    """The auxiliary layout target on the vision tokens of ``args.layout_camera`` (SmolVLA embeds one
    camera at a time, in ``config.image_features`` order, then its empty cameras), over the
    demonstrations' rows then ``plan_frames``'."""
    import torch

    camera = args.layout_camera

    keys = list(config.image_features)
    key = f"observation.images.{camera}"
    if key not in keys:
        raise SystemExit(f"--layout-camera {camera}: the policy sees [{', '.join(k.rsplit('.', 1)[1] for k in keys)}]")
    embed = policy.model.vlm_with_expert
    with torch.no_grad():
        features_dim = embed.embed_image(torch.zeros(1, 3, image_size, image_size)).flatten(1).shape[1]
    calls = len(keys) + getattr(config, "empty_cameras", 0)
    colors = args.layout_cubes
    targets = layout_targets(demos.episode_seeds, demos.episode, colors)
    if plan_frames is not None:
        seeds = sorted(set(plan_frames.seeds))
        index = {seed: i for i, seed in enumerate(seeds)}
        targets = torch.cat([targets, layout_targets(seeds, torch.tensor([index[s] for s in plan_frames.seeds]), colors)])
    return LayoutProbe(embed.get_vlm_model().connector, keys.index(key), calls, features_dim, targets, args.layout_target)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    import torch

    from policy.tiny_smolvla import TinySmolVLASpec, build_tiny_smolvla, save_checkpoint

    demos, crops = load_demos(args, TinySmolVLASpec().chunk_size)
    meta, cameras = demos.meta, demos.cameras
    image_size = args.train_size or frame_size(demos)
    joint_names = list(meta.features["action"]["names"])
    spec = TinySmolVLASpec(state_dim=len(joint_names), action_dim=len(joint_names), cameras=cameras, image_size=image_size,
                           vision_width=args.vision_width, vision_layers=args.vision_layers, patch_size=args.patch_size)
    stats = metadata_stats(meta) if not args.extra_dataset else demos.stats()

    staging = args.out.with_name(args.out.name + ".building")
    config, policy = build_tiny_smolvla(staging, spec)
    from lerobot.policies.factory import make_pre_post_processors

    preprocessor, _ = make_pre_post_processors(
        config, dataset_stats={k: {s: torch.as_tensor(v) for s, v in d.items()} for k, d in stats.items()}
    )
    parameters = [p for p in policy.parameters() if p.requires_grad]
    plan_frames = load_plan_frames(args, demos, crops, image_size, spec.chunk_size)
    probe = None
    if args.layout_target > 0:
        probe = layout_probe(policy, config, demos, args, image_size, crops, plan_frames)
        parameters += list(probe.head.parameters())
    LOG.info("tiny SmolVLA: %.2f M parameters (%.2f M trainable); %d frames, %d episodes, cameras %s at %d px",
             sum(p.numel() for p in policy.parameters()) / 1e6, sum(p.numel() for p in parameters) / 1e6,
             len(demos), demos.episodes, list(cameras), image_size)
    optimizer = torch.optim.AdamW(parameters, lr=args.lr, betas=(0.9, 0.95), weight_decay=1e-4)
    run = train(policy, optimizer, demos, preprocessor, args, auxiliary=probe, plan_frames=plan_frames)
    if probe is not None:
        probe.remove()
    metadata = {
        **checkpoint_metadata(demos, crops),
        "default_guidance_horizon": 10,
        "training": training_record(args, demos, run, image_size=image_size, cameras=list(cameras),
                                    patch_size=args.patch_size, vision_width=args.vision_width,
                                    vision_layers=args.vision_layers,
                                    layout_target={"weight": args.layout_target, "camera": args.layout_camera,
                                                   "cubes": list(args.layout_cubes)}
                                    if args.layout_target > 0 else None),
    }
    save_checkpoint(staging, config, policy, stats, metadata)
    replace_folder(staging, args.out)
    _point_at(args.out)
    LOG.info("saved %s: %d steps in %.0f s, final loss %.4f", args.out, run.steps, run.seconds, metadata["training"]["final_loss"])
    result = {"checkpoint": str(args.out), **metadata["training"]}
    if args.eval_episodes > 0:
        result["evaluation"] = evaluate(args.out, args.eval_episodes, args.eval_seed_start, frame_size(demos), args.workers,
                                        demos_meta(args.dataset).get("world"))
    print(json.dumps(result))
    return 0


def _point_at(folder: Path) -> None:
    """Point the saved config's backbone at the checkpoint's own ``vlm/`` (relative to nothing machine-specific
    is possible in LeRobot's config, so the backend re-points it on load; this keeps the file truthful)."""
    config_path = folder / "config.json"
    config = json.loads(config_path.read_text(encoding="utf-8"))
    config["vlm_model_name"] = str(folder.resolve() / "vlm")
    config_path.write_text(json.dumps(config, indent=4) + "\n", encoding="utf-8")


if __name__ == "__main__":
    sys.exit(main())

"""How well a checkpoint's vision features place each cube on layouts it never saw (a ridge probe).

    .venv/bin/python tools/vision_probe.py --checkpoint build/policies/tiny_smolvla \
        --plan-frames build/plan_frames/KEY.npz --dataset build/demos/heldout --camera overview

The features: one camera's vision tokens (the policy's ``embed_image``, flattened) of each
layout's first frame, the arm at or near Home (a plan file's first frame of a layout is among its
first ``every`` steps). A ridge regression from them to the layout
(``tools.layout_target.layout_vector``) is fitted on the first frames of plan layouts
(``tools/plan_frames.py``'s cache file, made with the checkpoint's crop and frame size), 90 % to
fit and 10 % to validate, and tested on the first frames of the recorded episodes of
``--dataset`` (held-out seeds, say). Printed as JSON, per cube: the median distance (cm) between
the position read out and the true one on the validation layouts and on the recordings, and the
same for the layout-blind answer (the mean layout). A policy whose features place a cube badly
cannot aim its first chunk at it.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from policy.lerobot_offline import force_offline  # noqa: E402

force_offline()


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--checkpoint", type=Path, required=True)
    parser.add_argument("--plan-frames", type=Path, required=True, help="a plan-frame cache file (build/plan_frames/*.npz)")
    parser.add_argument("--dataset", type=Path, required=True, help="recorded episodes to test on (their first frames)")
    parser.add_argument("--camera", default="overview")
    parser.add_argument("--ridge", type=float, default=100.0, help="ridge penalty on the standardized features")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    import numpy as np
    import torch

    from policy.lerobot_backend import checked_crop, make_lerobot_backend
    from tools.demo_training import DemoTensors
    from tools.layout_target import cube_errors_cm, layout_vector

    if not args.plan_frames.is_file():
        raise SystemExit(f"--plan-frames {args.plan_frames}: no such file (tools/plan_frames.py writes them in build/plan_frames/)")
    backend = make_lerobot_backend(args.checkpoint, committed_window=None)
    backend.load()
    crops = {camera: checked_crop(camera, box) for camera, box in (backend.metadata.get("camera_crops") or {}).items()
             if camera == args.camera}
    with np.load(args.plan_frames) as plan:
        held = sorted(key[len("image_"):] for key in plan.files if key.startswith("image_"))
        if args.camera not in held:
            raise SystemExit(f"--camera {args.camera}: {args.plan_frames} holds [{', '.join(held)}]")
        seeds = plan["seed"]
        first = np.r_[True, seeds[1:] != seeds[:-1]]
        fit_images, fit_seeds = torch.from_numpy(plan[f"image_{args.camera}"][first]), seeds[first]
    recorded = DemoTensors(args.dataset, 1, fit_images.shape[-1], (args.camera,), crops)
    test_images = recorded.images[f"observation.images.{args.camera}"][torch.nonzero(recorded.frame_index == 0).flatten()]
    embed = backend.policy.model.vlm_with_expert

    def features(images):
        with torch.no_grad():
            return torch.cat([embed.embed_image(block.float() / 255.0 * 2.0 - 1.0).flatten(1)
                              for block in images.split(256)]).numpy()

    fit, test = features(fit_images), features(test_images)
    mean, scale = fit.mean(0), fit.std(0) + 1e-6
    fit, test = (fit - mean) / scale, (test - mean) / scale
    target = np.array([layout_vector(int(seed)) for seed in fit_seeds])
    test_target = np.array([layout_vector(int(seed)) for seed in recorded.episode_seeds])
    split = int(len(fit) * 0.9)
    weights = np.linalg.solve(fit[:split].T @ fit[:split] + args.ridge * np.eye(fit.shape[1]), fit[:split].T @ target[:split])
    blind = np.broadcast_to(target[:split].mean(0), test_target.shape)
    print(json.dumps({
        "checkpoint": str(args.checkpoint), "camera": args.camera, "fit_layouts": split,
        "validation_layouts": len(fit) - split, "recorded_episodes": len(test),
        "validation_cm": cube_errors_cm(fit[split:] @ weights, target[split:]),
        "recorded_cm": cube_errors_cm(test @ weights, test_target),
        "blind_recorded_cm": cube_errors_cm(blind, test_target),
    }))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

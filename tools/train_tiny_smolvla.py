"""Train the tiny SmolVLA on recorded oracle demonstrations (`make lerobot-policy`). Seeded, CPU.

    .venv-lerobot/bin/python tools/train_tiny_smolvla.py --dataset build/demos/stack_cubes \
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
import math
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from policy.lerobot_compat import ensure_torchvision  # noqa: E402

ensure_torchvision()

LOG = logging.getLogger("train_tiny_smolvla")
REPO_ID = "local/stack_cubes_demos"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--dataset", type=Path, default=ROOT / "build/demos/stack_cubes")
    parser.add_argument("--out", type=Path, default=ROOT / "build/policies/tiny_smolvla")
    parser.add_argument("--episodes", type=int, default=12, help="episodes to record when the dataset is missing")
    parser.add_argument("--world", default=None, help="world to record in (default: vla_sim if installed, else kinematic)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the training (initial weights, batches, noise)")
    parser.add_argument("--demo-seed", type=int, default=1000,
                        help="layout seed of the first recorded episode (episode i: seed + i); must not reach the held-out seeds")
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--minutes", type=float, default=8.0, help="stop training after this much wall time")
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--lr", type=float, default=5e-4)
    parser.add_argument("--vision-width", type=int, default=64, help="width of the tiny vision tower")
    parser.add_argument("--vision-layers", type=int, default=2, help="layers of the tiny vision tower")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (one measured fastest on 2 shared cores)")
    parser.add_argument("--workers", type=int, default=2, help="processes recording episodes at once when recording")
    parser.add_argument("--image-size", type=int, default=128, help="camera frames when recording (square, px)")
    parser.add_argument("--train-size", type=int, default=None,
                        help="train on frames resized to this size (px, as the backend resizes requests; default: the dataset's)")
    parser.add_argument("--cameras", default=None, metavar="A,B",
                        help="cameras the policy sees (default: every camera of the dataset); also what is recorded")
    parser.add_argument("--crop", action="append", default=[], metavar="CAMERA=TOP,LEFT,BOTTOM,RIGHT",
                        help="train on (and serve) this part of a camera's frames, fractions of the frame (repeatable; "
                             "needs --train-size)")
    parser.add_argument("--patch-size", type=int, default=16, help="vision-tower patch size (px)")
    parser.add_argument("--early-frames", type=int, default=0,
                        help="with --early-share: an episode's first N frames (the arm at or near Home) are drawn more often")
    parser.add_argument("--early-share", type=float, default=0.0,
                        help="share of every batch drawn from the episodes' first --early-frames frames (0: uniform sampling)")
    parser.add_argument("--gripper-velocity", type=float, default=None,
                        help="the oracle's gripper speed when recording (rad/s; default: the oracle's)")
    parser.add_argument("--motion-noise", type=float, default=0.0,
                        help="recovery demonstrations when recording: peak offset added to the executed motion (rad)")
    parser.add_argument("--hold-after-plan", type=float, default=None,
                        help="when recording, stop taking frames this long after the oracle's plan ends (s)")
    parser.add_argument("--record-steps", type=int, default=250, help="policy steps per episode when recording")
    parser.add_argument("--keep-failed", action="store_true", help="keep recorded episodes whose stack check failed")
    parser.add_argument("--eval-episodes", type=int, default=0,
                        help="after training, evaluate on this many held-out seeds with `objective eval` (0: none)")
    parser.add_argument("--eval-seed-start", type=int, default=100, help="first held-out seed of the evaluation")
    return parser.parse_args(argv)


class DemoTensors:
    """The whole dataset in memory, sampled as LeRobot's loader would with ``delta_timestamps``.

    Opened with ``LeRobotDataset`` (metadata, stats, its Arrow table); every column is read once
    into tensors. Why not LeRobot's per-item ``__getitem__``: with ``delta_timestamps`` on
    ``action`` it decodes the images of all 50 future frames for every sample (2.5 s per sample
    measured here), and 70 ms per sample without. Decoding each PNG once takes 0.7 ms.

    ``batch`` gives what the DataLoader would: ``observation.state``, camera images (``cameras``,
    cropped by ``crops`` and resized to ``size``) as float CHW in [0, 1], ``action`` (B, chunk, A)
    = the actions of frames t..t+chunk-1 of the same episode, continued with the episode's last
    action (the oracle's hold; ``action_is_pad`` stays False, so those steps are learned), and ``task``.
    """

    def __init__(self, root: Path, chunk: int, size: int | None = None, cameras: tuple[str, ...] | None = None,
                 crops: dict | None = None) -> None:
        import io

        import numpy as np
        import torch
        from lerobot.datasets.lerobot_dataset import LeRobotDataset
        from PIL import Image

        from policy.lerobot_backend import crop_slices

        dataset = LeRobotDataset(REPO_ID, root=root)
        self.meta = dataset.meta
        available = tuple(key.split(".", 2)[2] for key in self.meta.camera_keys)
        self.cameras = available if cameras is None else tuple(cameras)
        missing = [c for c in self.cameras if c not in available]
        if missing:
            raise ValueError(f"cameras [{', '.join(missing)}] are not in the dataset {root} (it has [{', '.join(available)}])")
        crops = dict(crops or {})
        table = dataset.hf_dataset.data
        self.state = torch.tensor(np.stack(table.column("observation.state").to_pylist()), dtype=torch.float32)
        self.action = torch.tensor(np.stack(table.column("action").to_pylist()), dtype=torch.float32)
        episodes = np.asarray(table.column("episode_index").to_pylist())
        tasks = dict(zip(self.meta.tasks["task_index"], self.meta.tasks.index)) if self.meta.tasks is not None else {}
        self.tasks = [tasks.get(i, "") for i in table.column("task_index").to_pylist()]
        self.images = {}
        for camera in self.cameras:  # decoded, cropped and resized in blocks: the full frames never all sit in memory
            key = f"observation.images.{camera}"
            column, blocks = table.column(key), []
            for start in range(0, len(column), 1024):
                frames = np.stack([np.asarray(Image.open(io.BytesIO(cell["bytes"])).convert("RGB"))
                                   for cell in column.slice(start, 1024).to_pylist()])
                if camera in crops:
                    rows, columns = crop_slices(frames.shape[1], frames.shape[2], crops[camera])
                    frames = frames[:, rows, columns]
                blocks.append(resized(torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).contiguous(), size))
            self.images[key] = torch.cat(blocks)
        last = np.zeros(len(episodes), dtype=np.int64)
        for episode in np.unique(episodes):
            rows = np.flatnonzero(episodes == episode)
            last[rows] = rows[-1]
        offsets = np.arange(chunk)[None, :]
        wanted = np.arange(len(episodes))[:, None] + offsets
        self.chunk_rows = torch.from_numpy(np.minimum(wanted, last[:, None]))
        # Not padding: after an episode's last frame the oracle holds its final pose, so the last
        # action repeated is the true label of those steps (and a policy must learn to hold).
        self.chunk_pad = torch.zeros(wanted.shape, dtype=torch.bool)
        first = np.array([np.flatnonzero(episodes == e)[0] for e in np.unique(episodes)])
        self.frame_index = torch.from_numpy(np.arange(len(episodes)) - first[np.searchsorted(np.unique(episodes), episodes)])
        """Each row's frame number within its episode (0: the episode's first frame, the arm at Home)."""

    def __len__(self) -> int:
        return len(self.tasks)

    def batch(self, rows) -> dict:
        batch = {
            "observation.state": self.state[rows],
            "action": self.action[self.chunk_rows[rows]],
            "action_is_pad": self.chunk_pad[rows],
            "task": [self.tasks[int(r)] for r in rows],
        }
        for key, frames in self.images.items():
            batch[key] = frames[rows].float().div_(255.0)
        return batch


def resized(frames, size: int | None):
    """uint8 NCHW frames at ``size`` x ``size``, resized as the backend resizes requests
    (``policy.lerobot_backend.resize_frames``), once, in blocks to bound memory."""
    import torch

    from policy.lerobot_backend import resize_frames

    if size is None or tuple(frames.shape[-2:]) == (size, size):
        return frames
    blocks = [resize_frames(block.float().div_(255.0), (size, size)).mul_(255.0).round_().clamp_(0, 255).to(torch.uint8)
              for block in frames.split(1024)]
    return torch.cat(blocks)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    import numpy as np
    import torch

    from policy.tiny_smolvla import TinySmolVLASpec, build_tiny_smolvla, save_checkpoint
    from sim.demos import CAMERAS

    torch.manual_seed(args.seed)
    np.random.seed(args.seed)
    torch.set_num_threads(args.threads)
    cameras, crops = camera_settings(args)
    if not (args.dataset / "meta" / "info.json").is_file():
        from sim.demos import DemoOptions, record_demos

        held_out = range(args.eval_seed_start, args.eval_seed_start + args.eval_episodes)
        overlap = sorted(set(range(args.demo_seed, args.demo_seed + args.episodes)) & set(held_out))
        if overlap:
            raise SystemExit(f"demonstration seeds {args.demo_seed}..{args.demo_seed + args.episodes - 1} include held-out "
                             f"evaluation seeds {overlap[0]}..{overlap[-1]}: choose another --demo-seed")

        LOG.info("recording %d episodes into %s", args.episodes, args.dataset)
        started = time.monotonic()
        summary = record_demos(DemoOptions(episodes=args.episodes, seed=args.demo_seed, out=args.dataset, world=args.world,
                                           image_size=args.image_size, total_steps=args.record_steps, keep_failed=args.keep_failed,
                                           overwrite=True, workers=args.workers, cameras=cameras or CAMERAS,
                                           gripper_velocity=args.gripper_velocity, motion_noise_rad=args.motion_noise,
                                           hold_after_plan_s=args.hold_after_plan))
        LOG.info("recorded %d episodes, %d frames in world '%s' (%.0f s)", summary.episodes_kept, summary.frames,
                 summary.world, time.monotonic() - started)

    loading = time.monotonic()
    demos = DemoTensors(args.dataset, TinySmolVLASpec().chunk_size, args.train_size, cameras, crops)
    meta = demos.meta
    LOG.info("loaded %d frames into memory in %.1f s", len(demos), time.monotonic() - loading)
    cameras = demos.cameras
    frame_size = int(meta.features[meta.camera_keys[0]]["shape"][0])
    image_size = args.train_size or frame_size
    joint_names = list(meta.features["action"]["names"])
    spec = TinySmolVLASpec(state_dim=len(joint_names), action_dim=len(joint_names), cameras=cameras, image_size=image_size,
                           vision_width=args.vision_width, vision_layers=args.vision_layers, patch_size=args.patch_size)
    stats = {key: {k: np.asarray(v, dtype=np.float32) for k, v in meta.stats[key].items() if k in ("mean", "std", "min", "max")}
             for key in ("observation.state", "action")}
    for key in stats:  # a joint that never moved (std 0) must not blow up the normalization
        stats[key]["std"] = np.maximum(stats[key]["std"], 1e-3)

    staging = args.out.with_name(args.out.name + ".building")
    config, policy = build_tiny_smolvla(staging, spec)
    from lerobot.policies.factory import make_pre_post_processors

    preprocessor, _ = make_pre_post_processors(
        config, dataset_stats={k: {s: torch.as_tensor(v) for s, v in d.items()} for k, d in stats.items()}
    )
    parameters = [p for p in policy.parameters() if p.requires_grad]
    LOG.info("tiny SmolVLA: %.2f M parameters (%.2f M trainable); %d frames, %d episodes, cameras %s at %d px",
             sum(p.numel() for p in policy.parameters()) / 1e6, sum(p.numel() for p in parameters) / 1e6,
             meta.total_frames, meta.total_episodes, list(cameras), image_size)
    optimizer = torch.optim.AdamW(parameters, lr=args.lr, betas=(0.9, 0.95), weight_decay=1e-4)
    warmup = max(1, args.steps // 20)
    generator = torch.Generator().manual_seed(args.seed)
    early = torch.nonzero(demos.frame_index < args.early_frames).flatten()
    if args.early_share > 0 and len(early) == 0:
        raise SystemExit("--early-share needs --early-frames >= 1")
    policy.train()
    step, started, losses = 0, time.monotonic(), []
    deadline = started + args.minutes * 60
    while step < args.steps and time.monotonic() < deadline:
        progress = max(step / args.steps, (time.monotonic() - started) / (deadline - started))
        for group in optimizer.param_groups:
            group["lr"] = args.lr * learning_rate_factor(step, warmup, progress)
        rows = sample_rows(demos, args.batch, early, args.early_share, generator)
        loss, _ = policy.forward(preprocessor(demos.batch(rows)))
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(parameters, 10.0)
        optimizer.step()
        losses.append(float(loss.detach()))
        step += 1
        if step % 25 == 0 or step == 1:
            LOG.info("step %d: loss %.4f (%.1f steps/s)", step, np.mean(losses[-25:]), step / (time.monotonic() - started))
    elapsed = time.monotonic() - started
    policy.eval()
    tasks = list(meta.tasks.index) if meta.tasks is not None else []
    metadata = {
        "joint_names": joint_names,
        "control_period": 1.0 / meta.fps,
        "default_guidance_horizon": 10,
        "prompts": tasks,
        "camera_crops": {camera: list(box) for camera, box in crops.items()},
        # The shipped Objectives send the guide's three cameras; a policy trained on fewer drops the rest.
        "ignored_images": [camera for camera in CAMERAS if camera not in cameras],
        "training": {
            "dataset": str(args.dataset), "episodes": meta.total_episodes, "frames": meta.total_frames,
            "data_sha256": dataset_hash(args.dataset), "episode_seeds": demos_meta(args.dataset).get("seeds", []),
            "steps": step, "batch": args.batch, "lr": args.lr, "threads": args.threads,
            "image_size": image_size, "cameras": list(cameras), "patch_size": args.patch_size,
            "vision_width": args.vision_width, "vision_layers": args.vision_layers, "seed": args.seed, "seconds": round(elapsed, 1),
            "early_frames": args.early_frames, "early_share": args.early_share,
            "final_loss": round(float(np.mean(losses[-25:])), 5),
        },
    }
    save_checkpoint(staging, config, policy, stats, metadata)
    if args.out.exists():
        import shutil

        shutil.rmtree(args.out)
    staging.rename(args.out)
    _point_at(args.out)
    LOG.info("saved %s: %d steps in %.0f s, final loss %.4f", args.out, step, elapsed, metadata["training"]["final_loss"])
    result = {"checkpoint": str(args.out), **metadata["training"]}
    if args.eval_episodes > 0:
        result["evaluation"] = evaluate(args.out, args.eval_episodes, args.eval_seed_start, frame_size, args.workers,
                                        demos_meta(args.dataset).get("world"))
    print(json.dumps(result))
    return 0


def sample_rows(demos: "DemoTensors", batch: int, early, early_share: float, generator):
    """``batch`` rows of ``demos``: ``round(early_share * batch)`` of them among ``early`` (the
    episodes' first frames, where only the cameras tell the layouts apart), the rest uniform."""
    import torch

    from_early = round(early_share * batch) if len(early) else 0
    uniform = torch.randint(len(demos), (batch - from_early,), generator=generator)
    if from_early == 0:
        return uniform
    return torch.cat([uniform, early[torch.randint(len(early), (from_early,), generator=generator)]])


def learning_rate_factor(step: int, warmup_steps: int, progress: float) -> float:
    """Linear warm-up over ``warmup_steps``, then cosine from 1 to 0 over ``progress`` in [0, 1]."""
    return min(1.0, (step + 1) / warmup_steps) * 0.5 * (1.0 + math.cos(math.pi * min(max(progress, 0.0), 1.0)))


def camera_settings(args: argparse.Namespace) -> tuple[tuple[str, ...] | None, dict]:
    """``--cameras`` (None: the dataset's) and ``--crop`` (camera -> box), checked against each other."""
    from policy.lerobot_backend import checked_crop

    cameras = tuple(c.strip() for c in args.cameras.split(",") if c.strip()) if args.cameras else None
    crops = {}
    for item in args.crop:
        camera, sep, box = item.partition("=")
        if not sep:
            raise SystemExit(f"--crop {item!r}: expected CAMERA=TOP,LEFT,BOTTOM,RIGHT")
        crops[camera] = checked_crop(camera, [float(v) for v in box.split(",")])
    if crops and args.train_size is None:
        raise SystemExit("--crop needs --train-size (the size the cropped frames are resized to)")
    unknown = sorted(set(crops) - set(cameras or crops))
    if unknown:
        raise SystemExit(f"--crop names cameras [{', '.join(unknown)}] not in --cameras {args.cameras}")
    return cameras, crops


def dataset_hash(root: Path) -> str:
    """SHA-256 over the dataset's files (relative path and bytes, in path order): the data a checkpoint saw."""
    import hashlib

    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        digest.update(str(path.relative_to(root)).encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


def demos_meta(root: Path) -> dict:
    """``meta/demos.json`` of a dataset written by ``record-demos`` (its world and episode seeds); {} without it."""
    path = root / "meta" / "demos.json"
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}


def evaluate(checkpoint: Path, episodes: int, seed_start: int, image_size: int, workers: int, world: str | None) -> dict:
    """``objective eval`` of ``stack_cubes_lerobot.xml`` with the checkpoint on held-out seeds; writes
    ``evaluation.json`` next to the checkpoint and returns it."""
    import subprocess

    out = checkpoint / "eval"
    command = [sys.executable, "-m", "runtime.cli", "eval", str(ROOT / "objectives" / "stack_cubes_lerobot.xml"),
               "--policy", f"lerobot:{checkpoint}", "--episodes", str(episodes), "--seed-start", str(seed_start),
               "--workers", str(min(workers, episodes)), "--out", str(out), "--world-option", f"image_size={image_size}",
               "--record", "none", "--json"] + (["--world", world] if world else [])
    LOG.info("evaluating: %s", " ".join(command))
    started = time.monotonic()
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")  # no ROS graph beyond this machine
    finished = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, env=env)
    if finished.returncode not in (0, 1):
        raise RuntimeError(f"objective eval exited {finished.returncode}: {finished.stderr.strip()[-2000:]}")
    summary = json.loads(finished.stdout.strip().splitlines()[-1])
    evaluation = {"command": " ".join(command[1:]), "seconds": round(time.monotonic() - started), "summary": summary}
    (checkpoint / "evaluation.json").write_text(json.dumps(evaluation, indent=2) + "\n", encoding="utf-8")
    return evaluation


def _point_at(folder: Path) -> None:
    """Point the saved config's backbone at the checkpoint's own ``vlm/`` (relative to nothing machine-specific
    is possible in LeRobot's config, so the backend re-points it on load; this keeps the file truthful)."""
    config_path = folder / "config.json"
    config = json.loads(config_path.read_text(encoding="utf-8"))
    config["vlm_model_name"] = str(folder.resolve() / "vlm")
    config_path.write_text(json.dumps(config, indent=4) + "\n", encoding="utf-8")


if __name__ == "__main__":
    sys.exit(main())

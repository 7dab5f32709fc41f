"""What the training scripts share: demonstrations recorded, read into memory and sampled, the
training loop and its schedule, the record of the data, and the evaluation beside the checkpoint.

Used by ``tools/train_tiny_smolvla.py`` (the tiny SmolVLA) and ``tools/train_diffusion.py``
(LeRobot's DiffusionPolicy). Each script adds its model's options to :func:`add_arguments` and
turns a :class:`DemoTensors` batch into what its policy's ``forward`` takes.

1. ``ensure_dataset``: if ``--dataset`` does not exist, records it (``objective record-demos``
   with ``--episodes`` layouts from ``--demo-seed`` and the demonstration settings); seeds that
   reach the held-out evaluation seeds are refused.
2. :class:`DemoTensors`: the datasets opened with LeRobot's ``LeRobotDataset`` and read into
   memory once (each frame with the next ``chunk`` actions of its episode, as
   ``delta_timestamps`` would give), cameras cropped and resized as the backend does.
3. :func:`train`: AdamW-style optimizer given by the caller, linear warm-up then a cosine to 0
   over the step or the time budget, whichever is further along (a run the time cap stops still
   ends annealed), gradient clipping, seeded batches.
4. :func:`training_record` and :func:`evaluate`: the seeds, settings, episodes and ``data_sha256``
   (SHA-256 over the datasets' files) that go into ``objective_policy.json``, and ``objective
   eval`` on held-out seeds written beside the checkpoint (``<checkpoint>.eval/evaluation.json``).
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from policy.lerobot_offline import force_offline  # noqa: E402

force_offline()

LOG = logging.getLogger("demo_training")
REPO_ID = "local/stack_cubes_demos"


def add_arguments(parser: argparse.ArgumentParser, *, out: Path, steps: int, minutes: float, batch: int, lr: float) -> None:
    """The options every training script has (data, recording, schedule, evaluation), with its defaults."""
    parser.add_argument("--dataset", type=Path, default=ROOT / "build/demos/stack_cubes")
    parser.add_argument("--extra-dataset", type=Path, action="append", default=[],
                        help="another recorded dataset to train on as well (repeatable; must exist, same cameras)")
    parser.add_argument("--out", type=Path, default=out)
    parser.add_argument("--episodes", type=int, default=12, help="episodes to record when the dataset is missing")
    parser.add_argument("--world", default=None, help="world to record in (default: vla_sim if installed, else kinematic)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the training (initial weights, batches, noise)")
    parser.add_argument("--demo-seed", type=int, default=1000,
                        help="layout seed of the first recorded episode (episode i: seed + i); must not reach the held-out seeds")
    parser.add_argument("--steps", type=int, default=steps)
    parser.add_argument("--minutes", type=float, default=minutes, help="stop training after this much wall time")
    parser.add_argument("--batch", type=int, default=batch)
    parser.add_argument("--lr", type=float, default=lr)
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
    parser.add_argument("--early-frames", type=int, default=0,
                        help="with --early-share: an episode's first N frames (the arm at or near Home) are drawn more often")
    parser.add_argument("--early-share", type=float, default=0.0,
                        help="share of every batch drawn from the episodes' first --early-frames steps, in its recorded "
                             "and its played rows alike (0: uniform sampling)")
    for moment, described in (("approach", "the N steps before the first frame of an episode whose gripper holds the cube "
                                        "(the descent and the closing)"),
                          ("lift", "the N steps from the first frame of an episode whose gripper holds the cube (the "
                                   "start of the carry)"),
                          ("place", "the N steps before the frame at which an episode's gripper lets go of the cube (the "
                                    "end of the carry and the setting down)")):
        parser.add_argument(f"--{moment}-steps", type=int, default=0, help=f"with --{moment}-share: {described} are drawn more often")
        parser.add_argument(f"--{moment}-share", type=float, default=0.0,
                            help=f"share of every batch drawn from the --{moment}-steps steps, in its recorded and its played "
                                 "rows alike")
    parser.add_argument("--plan-layouts", type=int, default=0, metavar="N",
                        help="also train on frames of the oracle's plan played into the cell in N more layouts, without "
                             "the runtime (tools/plan_frames.py)")
    parser.add_argument("--plan-early-layouts", type=int, default=0, metavar="N",
                        help="and N more plan layouts (seeds after the --plan-layouts ones) played from Home (no detour) for "
                             "only their first --early-frames steps: what the first chunk from Home learns from, at a "
                             "tenth of the cost")
    parser.add_argument("--plan-seed", type=int, default=30000, help="layout seed of the first plan layout")
    parser.add_argument("--plan-every", type=int, default=5, metavar="K", help="a plan frame every K policy steps")
    parser.add_argument("--plan-share", type=float, default=0.25, help="share of every batch drawn from the plan frames")
    parser.add_argument("--plan-noise", type=float, default=None, metavar="RAD",
                        help="motion noise of the plan frames (default: the recording's --motion-noise); larger shows the "
                             "way back from farther off the plan")
    parser.add_argument("--plan-detour", type=float, default=0.0, metavar="M",
                        help="every plan layout starts with a detour: the arm heads for a pre-grasp moved by up to M "
                             "metres, is stopped part-way, and the frames show the oracle's way back to the cube from "
                             "there (0: from Home, no detour)")
    parser.add_argument("--plan-detour-descent", action="store_true",
                        help="with --plan-detour: the detour may go on down beside the cube before it stops")
    parser.add_argument("--plan-cache", type=Path, default=ROOT / "build/plan_frames",
                        help="folder of the plan frames made so far (one file per setting)")
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


def ensure_dataset(args: argparse.Namespace, cameras: tuple[str, ...] | None) -> None:
    """Record ``args.dataset`` unless it exists (``objective record-demos`` with the script's settings);
    demonstration seeds that reach the held-out evaluation seeds are refused (SystemExit)."""
    missing = [str(p) for p in args.extra_dataset if not (p / "meta" / "info.json").is_file()]
    if missing:
        raise SystemExit(f"--extra-dataset {', '.join(missing)}: no recorded dataset there")
    if (args.dataset / "meta" / "info.json").is_file():
        return
    from sim.demos import CAMERAS, DemoOptions, record_demos

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


def dataset_roots(args: argparse.Namespace) -> list[Path]:
    """The datasets a run trains on: ``--dataset`` then every ``--extra-dataset``."""
    return [args.dataset, *args.extra_dataset]


class DemoTensors:
    """The whole of one or more datasets in memory, sampled as LeRobot's loader would with ``delta_timestamps``.

    Opened with ``LeRobotDataset`` (metadata, stats, its Arrow table); every column is read once
    into tensors. Why not LeRobot's per-item ``__getitem__``: with ``delta_timestamps`` on
    ``action`` it decodes the images of all 50 future frames for every sample (2.5 s per sample
    measured here), and 70 ms per sample without. Decoding each PNG once takes 0.7 ms.

    ``batch`` gives what the DataLoader would: ``observation.state``, camera images (``cameras``,
    cropped by ``crops`` and resized to ``size``) as float CHW in [0, 1], ``action`` (B, chunk, A)
    = the actions of frames t..t+chunk-1 of the same episode, continued with the episode's last
    action (the oracle's hold; ``action_is_pad`` stays False, so those steps are learned), and ``task``.
    Several datasets are concatenated, their episodes kept apart; ``meta`` is the first one's.
    """

    def __init__(self, roots: Path | Sequence[Path], chunk: int, size: int | None = None,
                 cameras: tuple[str, ...] | None = None, crops: dict | None = None) -> None:
        import numpy as np
        import torch
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        roots = [roots] if isinstance(roots, Path) else list(roots)
        datasets = [LeRobotDataset(REPO_ID, root=root) for root in roots]
        self.meta = datasets[0].meta
        self.metas = [d.meta for d in datasets]
        available = tuple(key.split(".", 2)[2] for key in self.meta.camera_keys)
        self.cameras = available if cameras is None else tuple(cameras)
        crops = dict(crops or {})
        images: dict[str, list[Any]]
        states, actions, episodes, images = [], [], [], {f"observation.images.{c}": [] for c in self.cameras}
        self.tasks: list[str] = []
        offset = 0
        for root, dataset in zip(roots, datasets):
            has = tuple(key.split(".", 2)[2] for key in dataset.meta.camera_keys)
            missing = [c for c in self.cameras if c not in has]
            if missing:
                raise ValueError(f"cameras [{', '.join(missing)}] are not in the dataset {root} (it has [{', '.join(has)}])")
            table = dataset.hf_dataset.data
            states.append(np.stack(table.column("observation.state").to_pylist()))
            actions.append(np.stack(table.column("action").to_pylist()))
            local = np.asarray(table.column("episode_index").to_pylist())
            episodes.append(local + offset)
            offset += int(local.max()) + 1
            meta = dataset.meta
            tasks = dict(zip(meta.tasks["task_index"], meta.tasks.index)) if meta.tasks is not None else {}
            self.tasks += [tasks.get(i, "") for i in table.column("task_index").to_pylist()]
            for camera in self.cameras:
                key = f"observation.images.{camera}"
                images[key].append(decoded_frames(table.column(key), crops.get(camera), size))
        self.state = torch.tensor(np.concatenate(states), dtype=torch.float32)
        self.action = torch.tensor(np.concatenate(actions), dtype=torch.float32)
        self.images = {key: torch.cat(blocks) for key, blocks in images.items()}
        episode = np.concatenate(episodes)
        self.episodes = int(len(np.unique(episode)))
        last = np.zeros(len(episode), dtype=np.int64)
        first = np.zeros(len(episode), dtype=np.int64)
        for number in np.unique(episode):
            rows = np.flatnonzero(episode == number)
            last[rows], first[rows] = rows[-1], rows[0]
        wanted = np.arange(len(episode))[:, None] + np.arange(chunk)[None, :]
        self.chunk_rows = torch.from_numpy(np.minimum(wanted, last[:, None]))
        # Not padding: after an episode's last frame the oracle holds its final pose, so the last
        # action repeated is the true label of those steps (and a policy must learn to hold).
        self.chunk_pad = torch.zeros(wanted.shape, dtype=torch.bool)
        self.frame_index = torch.from_numpy(np.arange(len(episode)) - first)
        """Each row's frame number within its episode (0: the episode's first frame, the arm at Home)."""
        self.episode = torch.from_numpy(episode)
        """Each row's episode, numbered across the datasets."""
        self.episode_seeds = [seed for root in roots for seed in demos_meta(root).get("seeds", [])]
        """The layout seed of every episode, in that numbering (empty for a dataset without ``demos.json``)."""

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

    def stats(self) -> dict:
        """Normalization statistics of state and action (mean, std, min, max) over every frame read, as
        float32 arrays; a joint that never moved gets std 1e-3 and a 1e-3 wide range, not a division by 0."""
        import numpy as np

        stats = {}
        for key, values in (("observation.state", self.state), ("action", self.action)):
            array = values.numpy().astype(np.float64)
            low, high = array.min(axis=0), array.max(axis=0)
            flat = high - low < 1e-3
            stats[key] = {"mean": array.mean(axis=0), "std": np.maximum(array.std(axis=0), 1e-3),
                          "min": np.where(flat, low - 5e-4, low), "max": np.where(flat, high + 5e-4, high)}
            stats[key] = {k: v.astype(np.float32) for k, v in stats[key].items()}
        return stats


def metadata_stats(meta) -> dict:
    """State and action statistics from a dataset's LeRobot metadata (mean, std, min, max as float32
    arrays); a joint that never moved (std 0) gets std 1e-3, so the normalization does not blow up."""
    import numpy as np

    stats = {key: {k: np.asarray(v, dtype=np.float32) for k, v in meta.stats[key].items() if k in ("mean", "std", "min", "max")}
             for key in ("observation.state", "action")}
    for key in stats:
        stats[key]["std"] = np.maximum(stats[key]["std"], 1e-3)
    return stats


def decoded_frames(column, crop, size: int | None):
    """A dataset's PNG image column as uint8 NCHW frames, cropped (``crop``: a ``CameraCrop`` or None)
    and resized to ``size``; decoded in blocks so the full frames never all sit in memory."""
    import io

    import numpy as np
    import torch
    from PIL import Image

    from policy.lerobot_backend import crop_slices

    blocks = []
    for start in range(0, len(column), 1024):
        frames = np.stack([np.asarray(Image.open(io.BytesIO(cell["bytes"])).convert("RGB"))
                           for cell in column.slice(start, 1024).to_pylist()])
        if crop is not None:
            rows, columns = crop_slices(frames.shape[1], frames.shape[2], crop)
            frames = frames[:, rows, columns]
        blocks.append(resized(torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).contiguous(), size))
    return torch.cat(blocks)


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


HELD_GRIPPER_RAD = 0.25
"""A gripper at least this closed holds the cube (it closes on a 30 mm cube at 0.54 rad; open is 0)."""


def sample_rows(rows: int, batch: int, focus: Sequence[tuple[Any, float]], generator):
    """``batch`` of ``rows`` row indices: for every ``(pool, share)`` of ``focus``, ``round(share *
    batch)`` of them among ``pool`` (rows of the moments a policy decides from its cameras: an
    episode's first frames, the grasp), the rest uniform."""
    import torch

    counts = [round(share * batch) if len(pool) else 0 for pool, share in focus]
    drawn = [torch.randint(rows, (batch - sum(counts),), generator=generator)]
    drawn += [pool[torch.randint(len(pool), (count,), generator=generator)] for (pool, _), count in zip(focus, counts) if count]
    return torch.cat(drawn)


def grasp_rows(gripper: Any, episode: Any, step: Any, start: int, stop: int) -> Any:
    """The rows whose step lies from ``start`` to before ``stop`` steps after the first frame of
    their episode whose gripper holds the cube (negative: before it). From 0 on: the lift, where
    the chunk starts the carry to the other cube, which only the cameras place (the arm's state
    says where the first cube was); before 0: the descent and the closing, where the wrist camera
    centres the gripper on the cube."""
    held = gripper >= HELD_GRIPPER_RAD
    return _rows_around(episode, step, _first_step(episode, step, held), start, stop)


def release_rows(gripper: Any, episode: Any, step: Any, start: int, stop: int) -> Any:
    """The rows whose step lies from ``start`` to before ``stop`` steps after the frame at which
    their episode's gripper lets go of the cube (its first frame after the grasp that no longer
    holds; negative: before it). Before 0: the end of the carry and the setting down, where the
    chunk decides where the cube goes, which only the cameras say (the wrist camera holding the
    cube sees the other one only as it comes close)."""
    held = gripper >= HELD_GRIPPER_RAD
    grasp = _first_step(episode, step, held)
    return _rows_around(episode, step, _first_step(episode, step, ~held & (step > grasp[episode])), start, stop)


def _first_step(episode: Any, step: Any, where: Any) -> Any:
    """Per episode, the first step at which ``where`` holds (a step no run reaches where it never does)."""
    import torch

    never = torch.iinfo(torch.int64).max // 2
    return torch.full((int(episode.max()) + 1,), never, dtype=torch.int64).scatter_reduce(0, episode[where], step[where], "amin")


def _rows_around(episode: Any, step: Any, moment: Any, start: int, stop: int) -> Any:
    import torch

    since = step - moment[episode]
    return torch.nonzero((since >= start) & (since < stop)).flatten()


def load_demos(args: argparse.Namespace, chunk: int) -> tuple[DemoTensors, dict]:
    """Seed torch and numpy with ``args.seed``, set ``args.threads``, record the dataset if it is
    missing and read it into memory with ``chunk`` actions per frame: the demonstrations and the
    camera crops."""
    import numpy as np
    import torch

    torch.manual_seed(args.seed)
    np.random.seed(args.seed)
    torch.set_num_threads(args.threads)
    cameras, crops = camera_settings(args)
    ensure_dataset(args, cameras)
    loading = time.monotonic()
    demos = DemoTensors(dataset_roots(args), chunk, args.train_size, cameras, crops)
    LOG.info("loaded %d frames of %d episodes into memory in %.1f s", len(demos), demos.episodes, time.monotonic() - loading)
    return demos, crops


def load_plan_frames(args: argparse.Namespace, demos: DemoTensors, crops: dict, size: int, chunk: int) -> Any:
    """``args.plan_layouts`` layouts of plan frames (``tools.plan_frames``), then ``args.plan_early_layouts``
    played from Home (never a detour) for only their first ``args.early_frames`` steps, matching the demonstrations
    (the Home state of the first episode, joints, cameras, crops, frame sizes, prompt and the
    recording's settings), or None; layout seeds that meet the demonstrations' or the held-out seeds
    are refused (SystemExit)."""
    from tools.plan_frames import DETOUR_MIN_M, PlanFrameSettings, make_plan_frames

    if args.plan_layouts <= 0 and args.plan_early_layouts <= 0:
        return None
    if args.plan_early_layouts > 0 and args.early_frames < 1:
        raise SystemExit("--plan-early-layouts needs --early-frames >= 1 (the steps those layouts are played for)")
    if args.plan_every < 1:
        raise SystemExit(f"--plan-every must be >= 1, got {args.plan_every}")
    if args.plan_noise is not None and not args.plan_noise >= 0:
        raise SystemExit(f"--plan-noise must be >= 0, got {args.plan_noise}")
    if args.plan_detour != 0 and not DETOUR_MIN_M < args.plan_detour < 0.5:
        raise SystemExit(f"--plan-detour must be 0 or in ({DETOUR_MIN_M}, 0.5) metres, got {args.plan_detour}")
    if args.plan_detour_descent and not args.plan_detour:
        raise SystemExit("--plan-detour-descent needs --plan-detour")
    seeds = tuple(range(args.plan_seed, args.plan_seed + max(args.plan_layouts, 0)))
    early_seeds = tuple(range(args.plan_seed + len(seeds), args.plan_seed + len(seeds) + max(args.plan_early_layouts, 0)))
    held_out = range(args.eval_seed_start, args.eval_seed_start + max(args.eval_episodes, 50))
    reserved = sorted(set(seeds + early_seeds) & (set(demos.episode_seeds) | set(held_out)))
    if reserved:
        raise SystemExit(f"--plan-seed {args.plan_seed}: the plan layouts would include demonstration or "
                         f"held-out seeds ({reserved[0]}..{reserved[-1]})")
    recorded = demos_meta(args.dataset)
    settings = PlanFrameSettings(
        seeds=seeds, every=args.plan_every, hold_after_plan_s=float(recorded.get("hold_after_plan_s") or 0.0),
        home=tuple(float(v) for v in demos.state[demos.frame_index == 0][0]),
        joint_names=tuple(demos.meta.features["action"]["names"]), cameras=tuple(demos.cameras),
        image_size=int(recorded.get("image_size", args.image_size)),
        crops=tuple((camera, tuple(box)) for camera, box in sorted(crops.items())), size=size, chunk=chunk,
        control_period_s=1.0 / demos.meta.fps, gripper_velocity=recorded.get("gripper_velocity"),
        motion_noise_rad=float(recorded.get("motion_noise_rad", 0.0)) if args.plan_noise is None else args.plan_noise,
        detour_m=args.plan_detour, detour_descent=args.plan_detour_descent)
    started = time.monotonic()
    parts = [make_plan_frames(part, demos.tasks[0], args.plan_cache, workers=args.workers)
             for part in (settings, replace(settings, seeds=early_seeds, first_steps=args.early_frames, detour_m=0.0,
                                            detour_descent=False)) if part.seeds]
    frames = parts[0] if len(parts) == 1 else parts[0].joined(parts[1])
    LOG.info("%d plan frames of %d layouts ready in %.0f s (%d did not stack)", len(frames), len(set(frames.seeds)),
             time.monotonic() - started, len(frames.dropped))
    return frames


def checkpoint_metadata(demos: DemoTensors, crops: dict) -> dict:
    """What every checkpoint's ``objective_policy.json`` says of its interface: joint names, control
    period, prompts, camera crops, and the request images it ignores (the shipped Objectives send
    the guide's three cameras; a policy trained on fewer drops the rest)."""
    from sim.demos import CAMERAS

    meta = demos.meta
    return {
        "joint_names": list(meta.features["action"]["names"]),
        "control_period": 1.0 / meta.fps,
        "prompts": list(meta.tasks.index) if meta.tasks is not None else [],
        "camera_crops": {camera: list(box) for camera, box in crops.items()},
        "ignored_images": [camera for camera in CAMERAS if camera not in demos.cameras],
    }


def learning_rate_factor(step: int, warmup_steps: int, progress: float) -> float:
    """Linear warm-up over ``warmup_steps``, then cosine from 1 to 0 over ``progress`` in [0, 1]."""
    return min(1.0, (step + 1) / warmup_steps) * 0.5 * (1.0 + math.cos(math.pi * min(max(progress, 0.0), 1.0)))


@dataclass
class TrainingRun:
    """What :func:`train` did: steps taken, wall seconds, and the loss of every step."""

    steps: int
    seconds: float
    losses: list[float]

    def final_loss(self, last: int = 25) -> float:
        """Mean loss of the last ``last`` steps (nan before any step)."""
        tail = self.losses[-last:]
        return round(sum(tail) / len(tail), 5) if tail else float("nan")


def train(policy: Any, optimizer: Any, demos: DemoTensors, to_batch: Callable[[dict], dict], args: argparse.Namespace,
          log_every: int = 25, auxiliary: Callable[[Any], Any] | None = None, plan_frames: Any = None) -> TrainingRun:
    """Train ``policy`` (its ``forward(batch)`` returns ``(loss, _)``) for ``args.steps`` steps or
    ``args.minutes``, whichever ends first, on batches of ``args.batch`` rows of ``demos`` drawn with
    ``args.seed`` (``args.early_share`` of them from the episodes' first ``args.early_frames`` steps,
    ``args.approach_share`` and ``args.lift_share`` from the ``args.approach_steps`` steps before and the
    ``args.lift_steps`` steps from the grasp: ``grasp_rows``, ``args.place_share`` from the
    ``args.place_steps`` steps before the release: ``release_rows``), each passed through ``to_batch``
    (normalization, shapes). The learning rate (``args.lr``) warms up over 5 % of the steps, then
    follows a cosine to 0 over the step or time budget, whichever is further along.
    ``plan_frames`` (``tools.plan_frames.PlanFrames``): ``round(args.plan_share * args.batch)`` rows
    of every batch are drawn from it instead, with the same shares among its frames. ``auxiliary(rows)``: a loss added to the policy's
    after its forward (``layout_target``), whose parameters the optimizer holds too, given the
    batch's rows (a plan frame's row counts from ``len(demos)``); the losses recorded are the
    policy's own."""
    import torch

    parameters = [p for group in optimizer.param_groups for p in group["params"]]
    warmup = max(1, args.steps // 20)
    generator = torch.Generator().manual_seed(args.seed)
    moments = (("early", args.early_frames), ("approach", args.approach_steps), ("lift", args.lift_steps),
               ("place", args.place_steps))
    for moment, steps in moments:
        if getattr(args, f"{moment}_share") > 0 and steps < 1:
            raise SystemExit(f"--{moment}-share needs --{moment}-{'frames' if moment == 'early' else 'steps'} >= 1")
    shares = [getattr(args, f"{moment}_share") for moment, _ in moments]
    if not 0 <= sum(shares) <= 1:
        named = ", ".join(f"--{moment}-share {share:g}" for (moment, _), share in zip(moments, shares))
        raise SystemExit(f"{named} must add up to at most 1")

    def focus(gripper: Any, episode: Any, step: Any) -> list:
        return [(torch.nonzero(step < args.early_frames).flatten(), args.early_share),
                (grasp_rows(gripper, episode, step, -args.approach_steps, 0), args.approach_share),
                (grasp_rows(gripper, episode, step, 0, args.lift_steps), args.lift_share),
                (release_rows(gripper, episode, step, -args.place_steps, 0), args.place_share)]

    # The gripper is the state's last column (six arm joints, then the gripper, as the recorder writes them).
    demo_focus = focus(demos.state[:, -1], demos.episode, demos.frame_index)
    if plan_frames is not None:
        _, plan_episode = torch.unique(torch.tensor(plan_frames.seeds), return_inverse=True)
        plan_focus = focus(plan_frames.state[:, -1], plan_episode, plan_frames.step)
    from_plan = round(args.plan_share * args.batch) if plan_frames is not None else 0
    policy.train()
    step, started, losses, extras = 0, time.monotonic(), [], []
    deadline = started + args.minutes * 60
    while step < args.steps and time.monotonic() < deadline:
        progress = max(step / args.steps, (time.monotonic() - started) / (deadline - started))
        for group in optimizer.param_groups:
            group["lr"] = args.lr * learning_rate_factor(step, warmup, progress)
        rows = sample_rows(len(demos), args.batch - from_plan, demo_focus, generator)
        batch = demos.batch(rows)
        if from_plan:
            plan_rows = sample_rows(len(plan_frames), from_plan, plan_focus, generator)
            batch = joined(batch, plan_frames.batch(plan_rows))
            rows = torch.cat([rows, len(demos) + plan_rows])
        loss, _ = policy.forward(to_batch(batch))
        extra = auxiliary(rows) if auxiliary is not None else None
        optimizer.zero_grad()
        (loss if extra is None else loss + extra).backward()
        torch.nn.utils.clip_grad_norm_(parameters, 10.0)
        optimizer.step()
        losses.append(float(loss.detach()))
        extras.append(float(extra.detach()) if extra is not None else 0.0)
        step += 1
        if step % log_every == 0 or step == 1:
            recent = slice(-log_every, None)
            LOG.info("step %d: loss %.4f%s (%.2f steps/s)", step, sum(losses[recent]) / len(losses[recent]),
                     f", auxiliary {sum(extras[recent]) / len(extras[recent]):.4f}" if auxiliary is not None else "",
                     step / (time.monotonic() - started))
    policy.eval()
    return TrainingRun(step, time.monotonic() - started, losses)


def joined(first: dict, second: dict) -> dict:
    """Two batches of the same keys as one (tensors concatenated, lists extended)."""
    import torch

    return {key: first[key] + second[key] if isinstance(first[key], list) else torch.cat([first[key], second[key]])
            for key in first}


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


def dataset_hash(roots: Path | Sequence[Path]) -> str:
    """SHA-256 over the datasets' files (relative path and bytes, in path order, dataset after dataset):
    the data a checkpoint saw. One dataset hashes as it always did."""
    import hashlib

    digest = hashlib.sha256()
    for root in [roots] if isinstance(roots, Path) else roots:
        for path in sorted(p for p in root.rglob("*") if p.is_file()):
            digest.update(str(path.relative_to(root)).encode() + b"\0")
            digest.update(path.read_bytes())
    return digest.hexdigest()


def demos_meta(root: Path) -> dict:
    """``meta/demos.json`` of a dataset written by ``record-demos`` (its world and episode seeds); {} without it."""
    path = root / "meta" / "demos.json"
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}


def training_record(args: argparse.Namespace, demos: DemoTensors, run: TrainingRun, **settings: Any) -> dict:
    """The ``training`` entry of ``objective_policy.json``: data (datasets, episodes, frames, episode
    seeds, ``data_sha256``), seed, steps, schedule, time and final loss, plus the model's ``settings``."""
    roots = dataset_roots(args)
    record = {
        "dataset": str(args.dataset) if not args.extra_dataset else [str(r) for r in roots],
        "episodes": demos.episodes, "frames": len(demos),
        "data_sha256": dataset_hash(roots),
        "episode_seeds": [seed for root in roots for seed in demos_meta(root).get("seeds", [])],
        "steps": run.steps, "batch": args.batch, "lr": args.lr, "threads": args.threads, "seed": args.seed,
        "seconds": round(run.seconds, 1), "early_frames": args.early_frames, "early_share": args.early_share,
        "approach_steps": args.approach_steps, "approach_share": args.approach_share,
        "lift_steps": args.lift_steps, "lift_share": args.lift_share,
        "place_steps": args.place_steps, "place_share": args.place_share,
    }
    if args.plan_layouts > 0 or args.plan_early_layouts > 0:
        record["plan_frames"] = {"layouts": args.plan_layouts, "early_layouts": args.plan_early_layouts,
                                 "seed": args.plan_seed, "every": args.plan_every,
                                 "share": args.plan_share, "noise": args.plan_noise,
                                 "detour_m": args.plan_detour, "detour_descent": args.plan_detour_descent}
    record.update(settings)
    record["final_loss"] = run.final_loss()
    return record


def replace_folder(staging: Path, out: Path) -> None:
    """Move the finished ``staging`` folder to ``out``, replacing what was there."""
    import shutil

    if out.exists():
        shutil.rmtree(out)
    staging.rename(out)


def evaluate(checkpoint: Path, episodes: int, seed_start: int, image_size: int, workers: int, world: str | None,
             objective: Path = ROOT / "objectives" / "stack_cubes_lerobot.xml") -> dict:
    """``objective eval`` of ``objective`` (``stack_cubes_lerobot.xml``) with the checkpoint on held-out seeds into
    :func:`evaluation_folder` (beside the checkpoint, not inside it: ``objective eval`` identifies a
    policy by the hash of its folder's files, so files added there would make a later ``objective
    eval`` of the same folder refuse to resume), with its command and summary in ``evaluation.json``
    there; returns that summary."""
    out = evaluation_folder(checkpoint)
    command = [sys.executable, "-m", "runtime.app.cli", "eval", str(objective),
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
    (out / "evaluation.json").write_text(json.dumps(evaluation, indent=2) + "\n", encoding="utf-8")
    return evaluation


def evaluation_folder(checkpoint: Path) -> Path:
    """Where the training's evaluation of ``checkpoint`` goes: ``<checkpoint>.eval`` beside it."""
    return checkpoint.with_name(checkpoint.name + ".eval")


def frame_size(demos: DemoTensors) -> int:
    """The recorded frames' size (px): what the evaluation's world renders, so the backend's crop
    and resize see what the training saw."""
    meta = demos.meta
    return int(meta.features[meta.camera_keys[0]]["shape"][0])

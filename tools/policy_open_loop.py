"""Open-loop check of a checkpoint on recorded demonstrations: does it localize the cubes?

    .venv/bin/python tools/policy_open_loop.py --checkpoint build/policies/tiny_smolvla \
        --dataset build/demos/heldout --every 20

For every episode of ``--dataset`` (oracle demonstrations, e.g. on held-out seeds), the frames a
request would be made at (0, ``--every``, 2 x ``--every``, ...) go through the checkpoint's backend
exactly as a request does (raw camera frames, cropped and resized by the backend), and the answered
chunk is compared with the oracle's labels for the same steps. Errors are those of the tool centre
point (forward kinematics of the arm columns, centimetres), so "the first chunk from Home goes 12 cm
off" reads as it is. Printed as JSON: per request index, the median over episodes of the mean and
of the final TCP error of the chunk, the same for a layout-blind answer (the labels averaged over
the dataset's episodes: what a policy that ignores the cameras does at best), and the largest
gripper step (rad per policy step; the gripper's velocity limit allows 0.2).
"""
from __future__ import annotations

import argparse
import io
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
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--every", type=int, default=20, help="policy steps between requests (committed steps)")
    parser.add_argument("--requests", type=int, default=4, help="requests per episode checked")
    parser.add_argument("--episodes", type=int, default=None, help="first N episodes only")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    import numpy as np
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from PIL import Image

    from policy.backend import PolicyRequest
    from policy.lerobot_backend import make_lerobot_backend
    from sim.oracle import SceneKinematics
    from sim.robot_model import planning_robot_model

    dataset = LeRobotDataset("local/stack_cubes_demos", root=args.dataset)
    table = dataset.hf_dataset.data
    joint_names = list(dataset.meta.features["action"]["names"])
    state = np.stack(table.column("observation.state").to_pylist())
    action = np.stack(table.column("action").to_pylist())
    episodes = np.asarray(table.column("episode_index").to_pylist())
    task = dataset.meta.tasks.index[0]
    backend = make_lerobot_backend(args.checkpoint, committed_window=None)
    backend.load()
    cameras = [key.split(".", 2)[2] for key in backend.camera_keys]
    kinematics = SceneKinematics(planning_robot_model())
    arm = [joint_names.index(name) for name in kinematics.joint_names]
    gripper = [i for i in range(len(joint_names)) if i not in arm][0]

    def tcp(rows: np.ndarray) -> np.ndarray:
        return np.array([kinematics.tcp_pose(row[arm])[:3, 3] for row in rows])

    per_request: dict[int, dict[str, list]] = {}
    chosen = np.unique(episodes)[: args.episodes]
    for episode in chosen:
        rows = np.flatnonzero(episodes == episode)
        for index in range(args.requests):
            row = rows[0] + index * args.every
            if row > rows[-1]:
                break
            images = {c: np.asarray(Image.open(io.BytesIO(table.column(f"observation.images.{c}")[int(row)].as_py()["bytes"])).convert("RGB"))
                      for c in cameras}
            response = backend.infer(PolicyRequest(task, joint_names, state[row], images, new_episode=index == 0))
            if response.actions is None:
                raise RuntimeError(f"episode {episode} frame {row}: {response.message}")
            labels = action[np.minimum(np.arange(row, row + len(response.actions)), rows[-1])]
            error_cm = 100.0 * np.linalg.norm(tcp(response.actions) - tcp(labels), axis=1)
            steps = np.abs(np.diff(response.actions[:, gripper]))
            entry = per_request.setdefault(index * args.every, {"mean_cm": [], "final_cm": [], "gripper_step": [], "labels": []})
            entry["labels"].append(labels)
            entry["mean_cm"].append(float(error_cm.mean()))
            entry["final_cm"].append(float(error_cm[-1]))
            entry["gripper_step"].append(float(steps.max()))
    for entry in per_request.values():
        blind = np.mean(entry["labels"], axis=0)
        blind_cm = [100.0 * np.linalg.norm(tcp(blind) - tcp(labels), axis=1) for labels in entry["labels"]]
        entry["blind_mean_cm"] = [float(e.mean()) for e in blind_cm]
        entry["blind_final_cm"] = [float(e[-1]) for e in blind_cm]
    summary = {
        "checkpoint": str(args.checkpoint), "dataset": str(args.dataset), "episodes": int(len(chosen)),
        "requests": {
            str(step): {
                "median_mean_tcp_error_cm": round(float(np.median(v["mean_cm"])), 2),
                "median_final_tcp_error_cm": round(float(np.median(v["final_cm"])), 2),
                "p90_mean_tcp_error_cm": round(float(np.percentile(v["mean_cm"], 90)), 2),
                "blind_median_mean_tcp_error_cm": round(float(np.median(v["blind_mean_cm"])), 2),
                "blind_median_final_tcp_error_cm": round(float(np.median(v["blind_final_cm"])), 2),
                "max_gripper_step_rad": round(float(np.max(v["gripper_step"])), 3),
            }
            for step, v in sorted(per_request.items())
        },
    }
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""A checkpoint made by LeRobot's own training command, served and run as a user runs theirs.

    objective record-demos DIR               the project's recorder writes a LeRobot dataset
    lerobot-train --dataset.root=DIR ...     LeRobot 0.6's own training entry point, a few steps
    objective serve --backend lerobot        the saved checkpoint behind the HTTP server
    objective adapter --infer-url URL        GetActionChunk on ROS 2
    objective smoke-test SERVICE             one chunk through the adapter, judged

Five processes, the way the docs tell a user to connect a policy trained with LeRobot (skipped
without the LeRobot extra: `make lerobot`).
"""
from __future__ import annotations

import importlib.util
import json
import os
import random
import secrets
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_ros_e2e import read_line, start, stop, wait_ready

pytestmark = [
    pytest.mark.ros,
    pytest.mark.timeout(300),
    pytest.mark.skipif(importlib.util.find_spec("lerobot") is None, reason="the LeRobot extra is not installed (make lerobot)"),
]

REPO = Path(__file__).resolve().parent.parent
ARM = "shoulder_pan_joint;shoulder_lift_joint;elbow_joint;wrist_1_joint;wrist_2_joint;wrist_3_joint"
GRIPPER = "robotiq_85_left_knuckle_joint"
TRAIN_ARGS = [
    "--dataset.repo_id=local/stack_cubes_demos", "--policy.type=diffusion", "--policy.device=cpu",
    "--policy.push_to_hub=false", "--policy.pretrained_backbone_weights=null", "--policy.use_group_norm=true",
    "--policy.crop_shape=null", "--policy.horizon=16", "--policy.n_action_steps=8", "--policy.down_dims=[16,32]",
    "--policy.num_inference_steps=2", "--steps=2", "--batch_size=2", "--num_workers=0", "--save_freq=2",
    "--wandb.enable=false",
]


@pytest.fixture(scope="module")
def env() -> dict[str, str]:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(random.randint(100, 199)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               POLICY_SERVER_KEY=secrets.token_urlsafe(24), PYTHONUNBUFFERED="1", HF_HUB_OFFLINE="1", MUJOCO_GL="egl")
    return env


def run(command: list[str], env: dict[str, str], timeout: float) -> subprocess.CompletedProcess:
    done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{command[:3]} exited {done.returncode}:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done


@pytest.fixture(scope="module")
def trained(tmp_path_factory, env) -> Path:
    """Two kinematic episodes recorded by the project, then two steps of ``lerobot-train``."""
    root = tmp_path_factory.mktemp("lerobot_train")
    demos, out = root / "demos", root / "train"
    run([sys.executable, "-m", "runtime.app.cli", "record-demos", str(demos), "--episodes", "2", "--seed", "3",
         "--world", "kinematic", "--image-size", "32", "--steps", "20", "--keep-failed", "--cameras", "wrist"],
        env, timeout=120)
    train = Path(sys.executable).with_name("lerobot-train")
    run([str(train), f"--dataset.root={demos}", f"--output_dir={out}", *TRAIN_ARGS], env, timeout=240)
    return out / "checkpoints" / "last"


def test_a_checkpoint_saved_by_lerobot_train_is_served_and_answers_a_chunk_over_ros(trained, env):
    config = json.loads((trained / "pretrained_model" / "config.json").read_text())
    assert config["type"] == "diffusion" and config["n_action_steps"] == 8
    server = start("serve", "--backend", "lerobot", "--checkpoint", str(trained), "--port", "0",
                   "--warmup-images", "wrist=32x32", env=env)
    adapter = None
    try:
        url = read_line(server, r"listening on (http://127\.0\.0\.1:\d+)", timeout=120).group(1)
        health = wait_ready(f"{url}/health", timeout=120)
        assert health["backend"] == "lerobot", health
        service = f"/t{secrets.token_hex(4)}/get_action_chunk"
        adapter = start("adapter", "--infer-url", url, "--service-name", service, "--timeout", "20", env=env)
        read_line(adapter, rf"serving {service} -> ", timeout=60)
        smoke = subprocess.run(
            [sys.executable, "-m", "runtime.app.cli", "smoke-test", service, "--joints", ARM, "--gripper-joint", GRIPPER,
             "--synthetic-joints", "--image-names", "wrist", "--synthetic-images", "--expected-steps", "8",
             "--timeout", "20"],
            cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    finally:
        for proc in (adapter, server):
            if proc is not None:
                stop(proc)
    assert smoke.returncode == 0, smoke.stdout + smoke.stderr
    lines = smoke.stdout.splitlines()
    assert lines[-1] == "VERDICT: PASS"
    assert any(line.split()[:2] == ["step", "count"] and "8 steps (as expected)" in line for line in lines)

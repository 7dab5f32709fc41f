"""LeRobot's DiffusionPolicy as the project builds, trains and serves it: the spec's checks (always
run), then a random-weight checkpoint through the backend and the training script in miniature
(skipped without `make lerobot`)."""
from __future__ import annotations

import importlib.util
import json
import re
import runpy
from pathlib import Path

import numpy as np
import pytest

from policy.backend import PolicyRequest, PolicyStatus
from policy.lerobot_backend import make_lerobot_backend

needs_lerobot = pytest.mark.skipif(
    importlib.util.find_spec("lerobot") is None or importlib.util.find_spec("torch") is None,
    reason="the LeRobot extra is not installed (make lerobot)",
)
JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
          "wrist_3_joint", "robotiq_85_left_knuckle_joint"]
PROMPT = "stack the blue cube on the green cube"
ROOT = Path(__file__).resolve().parent.parent


def frames(size: int, value: int = 90) -> dict[str, np.ndarray]:
    return {name: np.full((size, size, 3), value, dtype=np.uint8) for name in ("scene", "wrist", "overview")}


@needs_lerobot
@pytest.mark.parametrize("changes, message", [
    ({"horizon": 20}, "horizon 20 must be a multiple of 8"),
    ({"n_action_steps": 40}, "n_action_steps 40 exceeds the horizon 32"),
    ({"down_dims": (60, 120)}, "multiples of n_groups 8"),
    ({"cameras": ()}, "at least one camera"),
    ({"crop_ratio": 0.0}, "crop_ratio must be in (0, 1]"),
])
def test_the_spec_refuses_what_lerobot_would_not_build(changes, message):
    from policy.tiny_diffusion import TinyDiffusionSpec

    with pytest.raises(ValueError, match=re.escape(message)):
        TinyDiffusionSpec(**changes)


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """A random-weight small diffusion policy, wrist + overview at 32 px, saved in LeRobot's format
    with known action ranges (min-max normalized: every answer lies inside them)."""
    from policy.lerobot_checkpoint import save_checkpoint
    from policy.tiny_diffusion import TinyDiffusionSpec, build_tiny_diffusion

    folder = tmp_path_factory.mktemp("diffusion")
    spec = TinyDiffusionSpec(image_size=32, horizon=24, n_action_steps=24, down_dims=(16, 32), num_inference_steps=3)
    config, policy = build_tiny_diffusion(spec)
    low, high = np.arange(7.0) - 0.5, np.arange(7.0) + 0.5
    stats = {
        "observation.state": {"mean": np.zeros(7), "std": np.ones(7), "min": -np.ones(7), "max": np.ones(7)},
        "action": {"mean": np.arange(7.0), "std": np.ones(7), "min": low, "max": high},
    }
    save_checkpoint(folder, config, policy, stats, {"joint_names": JOINTS, "control_period": 0.1,
                                                    "ignored_images": ["scene"],
                                                    "camera_crops": {"overview": [0.25, 0.25, 0.75, 0.75]}})
    return folder


@needs_lerobot
def test_a_diffusion_checkpoint_answers_from_the_observation_of_each_request(checkpoint):
    """LeRobot's predict_action_chunk reads the policy's observation queue once it is filled: the
    backend fills it, so the first request after load answers, in range and in the request's joint
    order, and a later request answers for its own frames, not the first request's."""
    backend = make_lerobot_backend(checkpoint, committed_window=None)
    backend.load()
    assert backend.describe()["policy_type"] == "diffusion" and backend.rtc is False
    assert backend.describe()["cameras"] == ["wrist", "overview"]
    order = list(reversed(JOINTS))
    first = backend.infer(PolicyRequest(PROMPT, order, np.zeros(7), frames(64, 90), new_episode=True))
    assert first.status == PolicyStatus.CHUNK, first.message
    assert first.actions.shape == (24, 7) and first.policy_actions is None
    in_checkpoint_order = first.actions[:, [order.index(name) for name in JOINTS]]
    assert np.all(in_checkpoint_order >= np.arange(7.0) - 0.5 - 1e-5)
    assert np.all(in_checkpoint_order <= np.arange(7.0) + 0.5 + 1e-5)

    import torch

    def chunk(image_value: int, state: np.ndarray) -> np.ndarray:
        torch.manual_seed(0)  # the same sampling noise: only the observation differs
        response = backend.infer(PolicyRequest(PROMPT, JOINTS, state, frames(64, image_value)))
        assert response.status == PolicyStatus.CHUNK, response.message
        return response.actions

    dark, bright = chunk(10, np.zeros(7)), chunk(240, np.full(7, 0.5))
    np.testing.assert_array_equal(chunk(10, np.zeros(7)), dark)  # the queue holds the newest observation only
    assert np.abs(bright - dark).max() > 1e-4
    queued = backend.policy._queues["observation.images"]
    assert len(queued) == 1 and tuple(queued[0].shape) == (1, 2, 3, 32, 32)


@needs_lerobot
def test_a_diffusion_checkpoint_at_noise_scale_zero_answers_one_chunk_per_observation(checkpoint):
    """The diffusion policy's starting noise is (1, horizon, action) where SmolVLA's is padded to
    max_action_dim: at noise scale 0 the sampler starts from zeros of the right shape, so one
    observation gets one chunk whatever the random state."""
    backend = make_lerobot_backend(checkpoint, committed_window=None, noise_scale=0.0)
    backend.load()
    request = PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(64, 90), new_episode=True)
    answers = [backend.infer(request) for _ in range(2)]
    assert all(a.status == PolicyStatus.CHUNK for a in answers), answers[0].message
    assert answers[0].actions.shape == (24, 7)
    np.testing.assert_array_equal(answers[0].actions, answers[1].actions)


@needs_lerobot
def test_training_script_trains_saves_and_the_backend_serves_one_chunk(tmp_path):
    """`make lerobot-diffusion` in miniature on a tiny kinematic recording: a few steps, LeRobot's
    format with the data hash and seeds beside it, then one chunk through the backend."""
    from runtime.app.cli import main as objective

    dataset = tmp_path / "demos"
    assert objective(["record-demos", str(dataset), "--episodes", "1", "--seed", "7", "--world", "kinematic",
                      "--image-size", "32", "--steps", "20", "--keep-failed", "--cameras", "wrist,overview"]) == 0
    train = runpy.run_path(str(ROOT / "tools" / "train_diffusion.py"))
    out = tmp_path / "policy"
    code = train["main"]([
        "--dataset", str(dataset), "--extra-dataset", str(dataset), "--out", str(out), "--steps", "3", "--batch", "4",
        "--train-size", "32", "--crop", "overview=0.25,0.25,0.75,0.75", "--cameras", "wrist,overview",
        "--horizon", "24", "--action-steps", "22", "--down-dims", "16,32", "--keypoints", "8", "--inference-steps", "2",
    ])
    assert code == 0
    metadata = json.loads((out / "objective_policy.json").read_text())
    training = metadata["training"]
    assert training["steps"] == 3 and training["policy_type"] == "diffusion" and training["episodes"] == 2
    assert training["frames"] == 40 and training["episode_seeds"] == [7, 7]
    from tools.demo_training import dataset_hash

    assert training["data_sha256"] == dataset_hash([dataset, dataset]) != dataset_hash(dataset)
    assert metadata["ignored_images"] == ["scene"] and metadata["camera_crops"] == {"overview": [0.25, 0.25, 0.75, 0.75]}
    config = json.loads((out / "config.json").read_text())
    assert config["type"] == "diffusion" and config["n_obs_steps"] == 1 and config["noise_scheduler_type"] == "DDIM"
    backend = make_lerobot_backend(out, committed_window=None)
    backend.load()
    response = backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(32), new_episode=True))
    assert response.status == PolicyStatus.CHUNK and response.actions.shape == (22, 7)
    assert np.all(np.isfinite(response.actions))

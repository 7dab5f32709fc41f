"""pi0.5 built from configuration alone (``policy/pi05_offline.py``): LeRobot 0.6's PI05Policy at
the sizes LeRobot fixes (4.14 billion parameters, random weights), saved with its own tokenizer,
loaded by the backend with nothing downloaded, answering a chunk and an RTC-guided chunk.

Slow: building it takes about 5 minutes and 19 GB on a 2-core machine, loading it as long again."""
from __future__ import annotations

import json

import numpy as np
import pytest

from policy.backend import PolicyRequest, PolicyStatus
from policy.lerobot_backend import make_lerobot_backend

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
          "wrist_3_joint", "robotiq_85_left_knuckle_joint"]
PROMPT = "stack the blue cube on the green cube"


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_a_pi05_built_from_configuration_loads_offline_and_answers_a_guided_chunk(tmp_path, monkeypatch):
    from policy.pi05_offline import PALIGEMMA_TOKENIZER, build_pi05_checkpoint

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    folder = build_pi05_checkpoint(tmp_path / "pi05", JOINTS)
    config = json.loads((folder / "config.json").read_text())
    assert config["type"] == "pi05" and config["paligemma_variant"] == "gemma_2b" and config["rtc_config"]["enabled"]
    # The processor keeps LeRobot's hub id; the backend gives the step the checkpoint's tokenizer.
    assert PALIGEMMA_TOKENIZER in (folder / "policy_preprocessor.json").read_text()

    backend = make_lerobot_backend(folder, committed_window=None)
    backend.load()
    assert sum(p.numel() for p in backend.policy.parameters()) > 4e9
    frame = {"scene": np.full((224, 224, 3), 90, dtype=np.uint8)}
    first = backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frame, new_episode=True))
    assert first.status is PolicyStatus.CHUNK, first.message
    assert first.actions.shape == (50, 7) and np.isfinite(first.actions).all()

    tail = first.policy_actions[20:]
    guided = backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frame, previous_action_chunk=tail,
                                         frozen_prefix_steps=4, guidance_horizon=0))
    assert guided.status is PolicyStatus.CHUNK, guided.message
    # Guidance holds the frozen prefix to the carried tail; unguided, it is fresh noise (unit scale).
    assert np.abs(guided.policy_actions[:4] - tail[:4]).mean() < 0.1

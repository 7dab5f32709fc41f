"""Saving a LeRobot policy as the backend loads it: LeRobot's format plus ``objective_policy.json``."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .lerobot_backend import METADATA_FILE, VLM_DIRNAME


def write_metadata(folder: str | Path, metadata: dict[str, Any]) -> Path:
    """Write ``objective_policy.json`` next to a checkpoint: what LeRobot's format does not keep and
    the backend needs (``joint_names``, ``control_period``, ``default_guidance_horizon``, and the
    training ``prompts`` for information)."""
    path = Path(folder) / METADATA_FILE
    path.write_text(json.dumps(metadata, indent=2) + "\n", encoding="utf-8")
    return path


def save_checkpoint(folder: str | Path, config: Any, policy: Any, stats: dict[str, Any], metadata: dict[str, Any]) -> Path:
    """Save a policy in LeRobot's format, with its processors, metadata and (a SmolVLA) backbone folder.

    ``stats`` are the normalization statistics (``{"observation.state": {"mean", "std", "min",
    "max"}, "action": {...}}``, tensors or arrays); they are stored in the processors' state
    files, where ``make_pre_post_processors(config, pretrained_path=folder)`` finds them.
    """
    import shutil

    import torch
    from lerobot.policies.factory import make_pre_post_processors

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    vlm = getattr(config, "vlm_model_name", None)
    if vlm and (folder / VLM_DIRNAME).resolve() != Path(vlm).resolve():  # a SmolVLA's local backbone folder
        shutil.copytree(vlm, folder / VLM_DIRNAME, dirs_exist_ok=True)
    tensors = {key: {k: torch.as_tensor(v, dtype=torch.float32) for k, v in value.items()} for key, value in stats.items()}
    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=tensors)
    policy.save_pretrained(folder)
    preprocessor.save_pretrained(folder)
    postprocessor.save_pretrained(folder)
    write_metadata(folder, metadata)
    return folder

"""Keep LeRobot, transformers and the hub offline: nothing here may download at run time.

Call :func:`force_offline` before ``huggingface_hub``, ``transformers`` or ``lerobot`` is first
imported (they read the switches at import). A checkpoint or config that names a hub model then
fails at once with the hub's offline error instead of waiting on the network. The LeRobot modules
of this project (``lerobot_backend``, ``tiny_smolvla``, ``tiny_diffusion``, the demonstration and
training tools) call it at import or before loading.
"""
from __future__ import annotations

import os

OFFLINE_ENV = {"HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}


def force_offline() -> None:
    """Set the Hugging Face offline switches in this process's environment."""
    for key, value in OFFLINE_ENV.items():
        os.environ[key] = value

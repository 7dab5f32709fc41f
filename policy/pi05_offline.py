"""A pi0.5 built from configuration alone: LeRobot 0.6's ``PI05Policy`` with random weights and a
tokenizer of its own, saved as a checkpoint the backend serves, with nothing downloaded.

LeRobot 0.6.1 fixes pi0.5's sizes in code: PaliGemma on ``gemma_2b`` with its SigLIP tower, the
action expert on ``gemma_300m`` (its vision projector is 2048 wide whatever the variant, so
``gemma_300m`` cannot be the VLM). The smallest pi0.5 it builds therefore has 4.14 billion
parameters: built in float32 and turned to bfloat16 as LeRobot does, it peaks at about 19 GB.
Its prompt tokenizer is PaliGemma's, named by hub id in LeRobot's processor; here the checkpoint
carries a word-level tokenizer in ``tokenizer/`` (the backend gives it to LeRobot's tokenizer
step), so the policy answers prompts of the cell's words.

What it shows is the serving path, not a skill: the weights are random. Checkpoints trained with
LeRobot's own pi0.5 need none of this (their tokenizer is in the Hugging Face cache).
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from numpy.typing import NDArray

from .lerobot_backend import TOKENIZER_DIRNAME, enable_rtc
from .lerobot_checkpoint import save_checkpoint
from .lerobot_offline import force_offline
from .word_tokenizer import word_level_tokenizer

force_offline()

PALIGEMMA_TOKENIZER = "google/paligemma-3b-pt-224"
"""The hub id LeRobot 0.6's pi0.5 processor names for its tokenizer."""
PROMPT_WORDS = "stack put place pick move the a cube cubes block on onto top of and then to red green blue yellow".split()


@dataclass(frozen=True)
class Pi05Spec:
    """The policy's interface: what it observes and outputs (its model sizes are LeRobot's)."""

    state_dim: int = 7
    action_dim: int = 7
    cameras: tuple[str, ...] = ("scene",)
    chunk_size: int = 50
    num_inference_steps: int = 10


def write_tokenizer(folder: str | Path, words: list[str] = PROMPT_WORDS) -> Path:
    """A word-level tokenizer over ``words`` (lower-cased, split on white space), saved in ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    word_level_tokenizer(["[PAD]", "[UNK]", *words], pad_token="[PAD]").save_pretrained(folder)
    return folder


def pi05_config(spec: Pi05Spec = Pi05Spec(), rtc: bool = True) -> Any:
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.pi05.configuration_pi05 import PI05Config

    inputs = {"observation.state": PolicyFeature(type=FeatureType.STATE, shape=(spec.state_dim,)),
              **{f"observation.images.{c}": PolicyFeature(type=FeatureType.VISUAL, shape=(3, 224, 224)) for c in spec.cameras}}
    config = PI05Config(input_features=inputs,
                        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(spec.action_dim,))},
                        dtype="bfloat16", device="cpu", chunk_size=spec.chunk_size, n_action_steps=spec.chunk_size,
                        num_inference_steps=spec.num_inference_steps, push_to_hub=False)
    if rtc:
        enable_rtc(config)
    return config


@contextlib.contextmanager
def _paligemma_tokenizer_from(folder: Path) -> Iterator[None]:
    """While LeRobot builds pi0.5's processors, its tokenizer step's hub id loads ``folder``."""
    from lerobot.processor import tokenizer_processor

    hub_loader = tokenizer_processor.AutoTokenizer

    class Local:
        @staticmethod
        def from_pretrained(name: str, *args: Any, **kwargs: Any) -> Any:
            return hub_loader.from_pretrained(str(folder) if name == PALIGEMMA_TOKENIZER else name, *args, **kwargs)

    tokenizer_processor.AutoTokenizer = Local
    try:
        yield
    finally:
        tokenizer_processor.AutoTokenizer = hub_loader


def build_pi05_checkpoint(folder: str | Path, joint_names: list[str], spec: Pi05Spec = Pi05Spec(),
                          control_period_s: float = 0.1) -> Path:
    """Build a random-weight pi0.5 and save it in ``folder`` as the backend loads it (LeRobot's
    format, ``objective_policy.json`` and ``tokenizer/``), with unit normalisation statistics."""
    from lerobot.policies.pi05.modeling_pi05 import PI05Policy

    folder = Path(folder)
    tokenizer = write_tokenizer(folder / TOKENIZER_DIRNAME)
    config = pi05_config(spec)
    policy = PI05Policy(config)

    def unit(width: int) -> dict[str, NDArray[np.float64]]:
        return {"mean": np.zeros(width), "std": np.ones(width), "min": -np.ones(width), "max": np.ones(width),
                "q01": -np.ones(width), "q99": np.ones(width)}

    stats = {"observation.state": unit(spec.state_dim), "action": unit(spec.action_dim)}
    with _paligemma_tokenizer_from(tokenizer):
        save_checkpoint(folder, config, policy, stats, {"joint_names": list(joint_names), "control_period": control_period_s})
    return folder

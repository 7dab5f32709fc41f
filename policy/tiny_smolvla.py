"""A tiny SmolVLA built from configuration alone: no hub, no pretrained weights, trainable on a CPU.

SmolVLA normally sits on SmolVLM2-500M, downloaded from the hub. LeRobot only needs three things
from that backbone when ``load_vlm_weights=False``: its ``config.json`` (to build the model with
random weights), a tokenizer (for the prompt) and a processor (whose tokenizer must know SmolVLM's
special image tokens). :func:`write_tiny_vlm` writes all three, about 30 KB, with transformers' own
classes, so ``SmolVLAConfig(vlm_model_name=<that folder>)`` builds offline.

The tiny backbone: a 2-layer SigLIP-style vision tower at 128 px (16 px patches by default, 64
patches, pixel-shuffled to 16 tokens per camera; ``patch_size`` 8 at 64 px gives the same tokens
with twice the pixel detail per token), a 4-layer Llama text model of width 128, and a
word-level tokenizer over the words of the cell's prompts. With SmolVLA's action expert (0.75 of
the text width) the policy has about 4 to 5 million parameters and answers a 50-step chunk in
tens of milliseconds on a CPU.

The tokenizer is word-level (``policy/word_tokenizer.py``): the prompts are short and drawn from a
small vocabulary.

Importing this module keeps the hub offline (:mod:`policy.lerobot_offline`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any
from pathlib import Path

from .lerobot_backend import VLM_DIRNAME, enable_rtc
from .lerobot_checkpoint import save_checkpoint as save_checkpoint, write_metadata as write_metadata  # kept importable from here
from .lerobot_offline import force_offline
from .word_tokenizer import word_level_tokenizer

force_offline()

PROMPT_WORDS = (
    "stack put place pick move the a an cube cubes block on onto top of and then to with "
    "red green blue yellow left right first second"
).split()
SPECIAL_TOKENS = ["[PAD]", "[UNK]", "<image>", "<fake_token_around_image>", "<global-img>", "<end_of_utterance>"]
IMAGE_SIZE = 128
PATCH_SIZE = 16
SCALE_FACTOR = 2


@dataclass(frozen=True)
class TinySmolVLASpec:
    """The policy's interface: what it observes and what it outputs."""

    state_dim: int = 7
    action_dim: int = 7
    cameras: tuple[str, ...] = ("scene", "wrist", "overview")
    image_size: int = IMAGE_SIZE
    chunk_size: int = 50
    num_steps: int = 10
    """Flow-matching denoising steps per chunk (SmolVLA's default)."""
    text_width: int = 128
    text_layers: int = 4
    vision_width: int = 64
    vision_layers: int = 2
    patch_size: int = PATCH_SIZE
    """Pixels per side of a vision-tower patch; (image_size / patch_size / 2)^2 tokens per camera."""
    extra_words: tuple[str, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        for name in ("state_dim", "action_dim", "chunk_size", "num_steps", "text_width", "text_layers",
                     "vision_width", "vision_layers", "patch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"TinySmolVLASpec.{name} must be >= 1, got {getattr(self, name)}")
        if not self.cameras:
            raise ValueError("TinySmolVLASpec.cameras must name at least one camera")
        patches = self.image_size // self.patch_size
        if self.image_size % self.patch_size or patches % SCALE_FACTOR:
            raise ValueError(
                f"TinySmolVLASpec.image_size {self.image_size} must be a multiple of {self.patch_size * SCALE_FACTOR} "
                f"(patch {self.patch_size} px, pixel shuffle by {SCALE_FACTOR})"
            )


def write_tiny_vlm(folder: str | Path, spec: TinySmolVLASpec = TinySmolVLASpec()) -> Path:
    """Write the tiny SmolVLM folder (config, word-level tokenizer, processor); returns it."""
    from transformers import (
        SmolVLMConfig,
        SmolVLMImageProcessor,
        SmolVLMProcessor,
        SmolVLMVideoProcessor,
    )

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    words = list(dict.fromkeys(PROMPT_WORDS + list(spec.extra_words)))
    vocab = {token: index for index, token in enumerate(SPECIAL_TOKENS + words)}
    tokenizer = word_level_tokenizer(
        list(vocab),
        pad_token="[PAD]",
        additional_special_tokens=SPECIAL_TOKENS[2:],
        extra_special_tokens={
            "image_token": "<image>",
            "fake_image_token": "<fake_token_around_image>",
            "global_image_token": "<global-img>",
            "end_of_utterance_token": "<end_of_utterance>",
        },
        model_max_length=64,
    )
    heads = max(1, spec.text_width // 32)
    config = SmolVLMConfig(
        image_token_id=vocab["<image>"],
        pad_token_id=vocab["[PAD]"],
        scale_factor=SCALE_FACTOR,
        vision_config={
            "hidden_size": spec.vision_width,
            "intermediate_size": spec.vision_width * 2,
            "num_hidden_layers": spec.vision_layers,
            "num_attention_heads": max(1, spec.vision_width // 32),
            "image_size": spec.image_size,
            "patch_size": spec.patch_size,
        },
        text_config={
            "model_type": "llama",
            "vocab_size": len(vocab),
            "hidden_size": spec.text_width,
            "intermediate_size": spec.text_width * 2,
            "num_hidden_layers": spec.text_layers,
            "num_attention_heads": heads,
            "num_key_value_heads": max(1, heads // 2),
            "head_dim": spec.text_width // heads,
            "max_position_embeddings": 512,
            "pad_token_id": vocab["[PAD]"],
        },
    )
    config.save_pretrained(folder)
    image_processor = SmolVLMImageProcessor(
        do_resize=False, do_image_splitting=False, max_image_size={"longest_edge": spec.image_size},
        size={"longest_edge": spec.image_size},
    )
    video_processor = SmolVLMVideoProcessor(size={"longest_edge": spec.image_size},
                                            max_image_size={"longest_edge": spec.image_size})
    tokens_per_image = (spec.image_size // spec.patch_size // SCALE_FACTOR) ** 2
    processor = SmolVLMProcessor(image_processor, tokenizer, video_processor, image_seq_len=tokens_per_image)
    processor.save_pretrained(folder)
    (folder / "README.txt").write_text(
        "Tiny SmolVLM backbone description for a SmolVLA built from config (random weights, no hub).\n"
        "Written by policy/tiny_smolvla.py:write_tiny_vlm.\n",
        encoding="utf-8",
    )
    return folder


def image_key(camera: str) -> str:
    """LeRobot's observation key for a camera name."""
    return f"observation.images.{camera}"


def tiny_smolvla_config(vlm_folder: str | Path, spec: TinySmolVLASpec = TinySmolVLASpec(), rtc: bool = True) -> Any:
    """A ``SmolVLAConfig`` for the tiny backbone in ``vlm_folder``; RTC enabled when ``rtc``.

    Everything is trainable (the backbone has random weights, so freezing it would freeze noise),
    and the padded state/action widths equal the real ones (no wasted columns).
    """
    from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
    from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig

    inputs = {
        "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(spec.state_dim,)),
        **{
            image_key(camera): PolicyFeature(type=FeatureType.VISUAL, shape=(3, spec.image_size, spec.image_size))
            for camera in spec.cameras
        },
    }
    outputs = {"action": PolicyFeature(type=FeatureType.ACTION, shape=(spec.action_dim,))}
    config = SmolVLAConfig(
        input_features=inputs,
        output_features=outputs,
        device="cpu",
        chunk_size=spec.chunk_size,
        n_action_steps=spec.chunk_size,
        num_steps=spec.num_steps,
        max_state_dim=spec.state_dim,
        max_action_dim=spec.action_dim,
        resize_imgs_with_padding=(spec.image_size, spec.image_size),
        vlm_model_name=str(vlm_folder),
        load_vlm_weights=False,
        num_vlm_layers=spec.text_layers,
        freeze_vision_encoder=False,
        train_expert_only=False,
        tokenizer_max_length=24,
        normalization_mapping={
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.MEAN_STD,
            "ACTION": NormalizationMode.MEAN_STD,
        },
        push_to_hub=False,
    )
    if rtc:
        enable_rtc(config)
    return config


def build_tiny_smolvla(folder: str | Path, spec: TinySmolVLASpec = TinySmolVLASpec(), rtc: bool = True) -> tuple[Any, Any]:
    """Write the tiny backbone under ``folder/vlm`` and build ``(config, policy)`` with random weights."""
    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy

    vlm = write_tiny_vlm(Path(folder) / VLM_DIRNAME, spec)
    config = tiny_smolvla_config(vlm, spec, rtc=rtc)
    return config, SmolVLAPolicy(config)

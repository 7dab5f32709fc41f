"""The learned stacking policy's chunk model: LeRobot's Multi-Task DiT, flow matching, on joints and located cubes.

``build_learned_stack(spec, clip_folder)`` builds LeRobot 0.6's ``MultiTaskDiTPolicy`` with
``objective="flow_matching"`` from configuration alone:

- ``observation.state``: the joints (six arm joints, then the gripper) followed by the cubes as
  the perception stage located them (``policy.cube_locator.cube_features``). The DiT's observation
  encoder conditions on ``observation.state``, the cameras and the prompt only (it reads no
  ``observation.environment_state``), so the located cubes travel in the state vector.
- no image features: the cameras reach the policy through the perception stage.
- the prompt through a tiny CLIP text encoder with random weights (:func:`write_tiny_clip`: a
  ``CLIPTextConfig`` and a word-level tokenizer, made with transformers' own classes, random weights, about 40 KB),
  kept in the checkpoint as ``clip/`` so nothing is downloaded. LeRobot freezes the text encoder and
  trains a projection of its output.

:func:`sample_chunk` integrates the DiT's flow from noise to a chunk (Euler, ``num_integration_steps``)
like ``FlowMatchingObjective.conditional_sample``, as the mean of several samples (one sample's chunk
carries a small step-to-step jitter), with given starting noises and, when a previous
chunk's leftover is given, LeRobot's RTC guidance (``RTCProcessor.denoise_step``) at every step.
LeRobot's DiT runs time from 0 (noise) to 1 (data) with velocity ``data - noise``; LeRobot's RTC code
is written for time from 1 (noise) to 0 with velocity ``noise - data`` (SmolVLA's convention), so the
step hands it ``time = 1 - t`` and the negated velocity, and negates the guided answer back.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .lerobot_offline import force_offline
from .word_tokenizer import word_level_tokenizer

force_offline()

CLIP_DIRNAME = "clip"
"""The checkpoint's text-encoder folder (LeRobot wants 'clip' in the encoder's name)."""
PROMPT_WORDS = "stack put place pick move the a cube cubes block on onto top of and red green blue".split()
SPECIAL_TOKENS = ["[PAD]", "[UNK]", "[EOS]"]


@dataclass(frozen=True)
class LearnedStackSpec:
    """The chunk model's interface and size."""

    joint_dim: int = 7
    cube_dim: int = 6
    """Located-cube features in the state (``cube_features``: x, y, yaw per cube)."""
    chunk_size: int = 50
    hidden_dim: int = 128
    layers: int = 4
    heads: int = 4
    integration_steps: int = 20
    text_width: int = 32

    @property
    def state_dim(self) -> int:
        return self.joint_dim + self.cube_dim


def write_tiny_clip(folder: str | Path, width: int = 32, seed: int = 0) -> Path:
    """A CLIP text encoder (random weights drawn with ``seed``) and a word-level tokenizer in ``folder``."""
    import torch
    from transformers import CLIPTextConfig, CLIPTextModel

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    vocab = {token: index for index, token in enumerate(SPECIAL_TOKENS + PROMPT_WORDS)}
    tokenizer = word_level_tokenizer(list(vocab), pad_token="[PAD]", eos_token="[EOS]", model_max_length=16)
    tokenizer.save_pretrained(folder)
    config = CLIPTextConfig(vocab_size=len(vocab), hidden_size=width, intermediate_size=2 * width, num_hidden_layers=1,
                            num_attention_heads=2, max_position_embeddings=16, projection_dim=width,
                            pad_token_id=0, bos_token_id=1, eos_token_id=2)
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        CLIPTextModel(config).save_pretrained(folder)
    return folder


def learned_stack_config(spec: LearnedStackSpec, clip_folder: str | Path, device: str = "cpu") -> Any:
    """LeRobot's ``MultiTaskDiTConfig`` of the spec: flow matching, state only, the tiny CLIP."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.multi_task_dit.configuration_multi_task_dit import MultiTaskDiTConfig

    return MultiTaskDiTConfig(
        objective="flow_matching", n_obs_steps=1, horizon=spec.chunk_size, n_action_steps=spec.chunk_size,
        hidden_dim=spec.hidden_dim, num_layers=spec.layers, num_heads=spec.heads, dropout=0.0,
        timestep_embed_dim=spec.hidden_dim, num_integration_steps=spec.integration_steps,
        timestep_sampling_strategy="uniform", text_encoder_name=str(clip_folder), tokenizer_max_length=16,
        image_crop_shape=None, device=device, push_to_hub=False, optimizer_lr=3e-4,
        input_features={"observation.state": PolicyFeature(type=FeatureType.STATE, shape=(spec.state_dim,))},
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(spec.joint_dim,))},
    )


def build_learned_stack(spec: LearnedStackSpec, clip_folder: str | Path) -> tuple[Any, Any]:
    """``(config, policy)``: a random-weight ``MultiTaskDiTPolicy`` of the spec."""
    from lerobot.policies.multi_task_dit.modeling_multi_task_dit import MultiTaskDiTPolicy

    config = learned_stack_config(spec, clip_folder)
    return config, MultiTaskDiTPolicy(config)


def sample_chunk(policy: Any, batch: dict[str, Any], noise: Any = None, rtc: Any = None,
                 guidance: dict[str, Any] | None = None, samples: int = 1) -> Any:
    """A normalized chunk (B, horizon, A) from the preprocessed ``batch`` (module doc): the mean of
    ``samples`` flows integrated from independent starting noises.

    ``noise``: the starting noises (B * samples, horizon, A; sample ``k`` of row ``b`` at
    ``b * samples + k``), else standard normal draws. ``rtc``: an ``RTCProcessor``; with
    ``guidance`` (``inference_delay``, ``prev_chunk_left_over``, ``execution_horizon``) every step of
    every sample is guided toward the leftover.
    """
    import torch

    config = policy.config
    batch = dict(batch)
    state = batch["observation.state"]
    if state.ndim == 2:  # the one observation step the encoder expects
        batch["observation.state"] = state.unsqueeze(1)
    conditioning = policy.observation_encoder.encode(batch).repeat_interleave(samples, dim=0)
    rows = conditioning.shape[0] // samples
    shape = (conditioning.shape[0], config.horizon, config.action_feature.shape[0])
    x = torch.randn(shape) if noise is None else noise.reshape(shape).to(conditioning.dtype)
    model = policy.noise_predictor
    steps = config.num_integration_steps
    guidance = guidance or {}
    leftover = guidance.get("prev_chunk_left_over")
    if leftover is not None:
        leftover = (leftover if leftover.ndim == 3 else leftover.unsqueeze(0)).repeat_interleave(samples, dim=0)
    for index in range(steps):
        t = index / steps
        t_batch = torch.full((shape[0],), t, dtype=x.dtype)

        def velocity(x_t: Any, t_batch: Any = t_batch) -> Any:
            """The DiT's velocity in RTC's convention (noise - data)."""
            return -model(x_t, t_batch, conditioning_vec=conditioning)

        if rtc is not None and leftover is not None:
            v = rtc.denoise_step(x, leftover, guidance["inference_delay"], 1.0 - t, velocity,
                                 execution_horizon=guidance.get("execution_horizon"))
        else:
            with torch.no_grad():
                v = velocity(x)
        x = (x - v / steps).detach()
    return x.reshape(rows, samples, *shape[1:]).mean(dim=1)

"""A small LeRobot DiffusionPolicy built from configuration alone: no hub, no pretrained weights.

LeRobot's ``DiffusionRgbEncoder`` is a torchvision ResNet trunk (``children()[:-2]``) ending in a
``SpatialSoftmax``: every keypoint is the softmax-weighted mean image position of one learned
feature map, so the vision path answers "where" by construction (what the tiny SmolVLA's vision
tokens were not seen to learn here). The trunk must be a ResNet (``DiffusionConfig`` refuses any
other ``vision_backbone``); ResNet-18 with random weights is the smallest, 11.2 M parameters, and
with ``use_group_norm`` its BatchNorms become GroupNorms of 16 channels (its widths 64-512 all
divide). Its stride is 32, so at ``image_size`` px the keypoints are soft positions over an
``image_size / 32`` square grid of feature cells.

The denoiser is a 1-D conditional UNet over the action chunk, much narrower than LeRobot's default
(``down_dims`` (512, 1024, 2048)); ``horizon`` must be a multiple of ``2 ** len(down_dims)``.
Sampling is DDIM with ``num_inference_steps`` steps. One observation step (``n_obs_steps`` 1):
ExecutePolicy asks for a chunk every committed window, not every step, so a history of requests
would not be the history of consecutive frames the policy was trained on.

Images are not normalized (``VISUAL`` identity; frames in [0, 1], GroupNorm after every
convolution), state and actions are min-max normalized to [-1, 1] (the sampler clips to that range).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .lerobot_offline import force_offline

force_offline()


@dataclass(frozen=True)
class TinyDiffusionSpec:
    """The policy's interface and size."""

    state_dim: int = 7
    action_dim: int = 7
    cameras: tuple[str, ...] = ("wrist", "overview")
    image_size: int = 96
    """Square frames (px) every camera is resized to (the backend resizes requests the same way)."""
    horizon: int = 32
    """Steps the UNet denoises, from the observation's step on."""
    n_action_steps: int = 32
    """Steps answered per chunk (the first ``n_action_steps`` of the horizon)."""
    down_dims: tuple[int, ...] = (64, 128, 256)
    kernel_size: int = 5
    n_groups: int = 8
    diffusion_step_embed_dim: int = 64
    keypoints: int = 32
    """SpatialSoftmax keypoints per camera (each gives x and y)."""
    vision_backbone: str = "resnet18"
    crop_ratio: float = 1.0
    """Random crop of this share of each side during training (centre crop at inference); 1: none."""
    num_train_timesteps: int = 100
    num_inference_steps: int = 10
    prediction_type: str = "epsilon"

    def __post_init__(self) -> None:
        for name in ("state_dim", "action_dim", "image_size", "horizon", "n_action_steps", "kernel_size", "n_groups",
                     "diffusion_step_embed_dim", "keypoints", "num_train_timesteps", "num_inference_steps"):
            if getattr(self, name) < 1:
                raise ValueError(f"TinyDiffusionSpec.{name} must be >= 1, got {getattr(self, name)}")
        if not self.cameras:
            raise ValueError("TinyDiffusionSpec.cameras must name at least one camera")
        if not self.down_dims or any(d % self.n_groups for d in self.down_dims):
            raise ValueError(f"TinyDiffusionSpec.down_dims {self.down_dims} must be non-empty multiples of n_groups {self.n_groups}")
        factor = 2 ** len(self.down_dims)
        if self.horizon % factor:
            raise ValueError(f"TinyDiffusionSpec.horizon {self.horizon} must be a multiple of {factor} (2 ** len(down_dims))")
        if self.n_action_steps > self.horizon:
            raise ValueError(f"TinyDiffusionSpec.n_action_steps {self.n_action_steps} exceeds the horizon {self.horizon}")
        if self.num_inference_steps > self.num_train_timesteps:
            raise ValueError("TinyDiffusionSpec.num_inference_steps must not exceed num_train_timesteps")
        if not 0.0 < self.crop_ratio <= 1.0:
            raise ValueError(f"TinyDiffusionSpec.crop_ratio must be in (0, 1], got {self.crop_ratio}")


def tiny_diffusion_config(spec: TinyDiffusionSpec = TinyDiffusionSpec()) -> Any:
    """A ``DiffusionConfig`` for ``spec``: random-weight ResNet trunk with GroupNorm, DDIM sampling."""
    from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    inputs = {
        "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(spec.state_dim,)),
        **{
            f"observation.images.{camera}": PolicyFeature(type=FeatureType.VISUAL, shape=(3, spec.image_size, spec.image_size))
            for camera in spec.cameras
        },
    }
    crop = None
    if spec.crop_ratio < 1.0:
        side = int(spec.image_size * spec.crop_ratio)
        crop = (side, side)
    return DiffusionConfig(
        input_features=inputs,
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(spec.action_dim,))},
        device="cpu",
        n_obs_steps=1,
        horizon=spec.horizon,
        n_action_steps=spec.n_action_steps,
        drop_n_last_frames=0,
        normalization_mapping={
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.MIN_MAX,
            "ACTION": NormalizationMode.MIN_MAX,
        },
        vision_backbone=spec.vision_backbone,
        crop_shape=crop,
        crop_is_random=True,
        pretrained_backbone_weights=None,
        use_group_norm=True,
        use_separate_rgb_encoder_per_camera=False,
        spatial_softmax_num_keypoints=spec.keypoints,
        down_dims=spec.down_dims,
        kernel_size=spec.kernel_size,
        n_groups=spec.n_groups,
        diffusion_step_embed_dim=spec.diffusion_step_embed_dim,
        noise_scheduler_type="DDIM",
        num_train_timesteps=spec.num_train_timesteps,
        num_inference_steps=spec.num_inference_steps,
        prediction_type=spec.prediction_type,
        push_to_hub=False,
    )


def build_tiny_diffusion(spec: TinyDiffusionSpec = TinyDiffusionSpec()) -> tuple[Any, Any]:
    """``(config, policy)`` with random weights."""
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

    config = tiny_diffusion_config(spec)
    return config, DiffusionPolicy(config)

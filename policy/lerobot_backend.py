"""LeRobot backend: a local LeRobot checkpoint behind the GetActionChunk contract, with RTC.

Serve your own checkpoint with ``make_lerobot_backend(DIR)`` (the HTTP server's ``--backend lerobot
--checkpoint DIR``, or ``--policy lerobot:DIR`` embedded in a headless world). ``DIR`` is what
LeRobot's ``save_pretrained`` writes (``config.json``, ``model.safetensors``,
``policy_preprocessor.json`` / ``policy_postprocessor.json`` with their normalization stats), or a
training output folder holding it under ``pretrained_model/``. Nothing is downloaded:
``HF_HUB_OFFLINE=1`` is set before LeRobot is imported, so a checkpoint that names a hub backbone
fails at load with the hub's offline error instead of hanging on the network.

Per request (``infer``):

1. **Cameras.** Each request image name is mapped to one of the checkpoint's camera features
   (``observation.images.<name>``); see :func:`map_cameras`. Any mismatch is refused with both
   lists named, because a camera fed into the wrong slot fails silently otherwise. Request images
   the checkpoint's metadata lists as ``ignored_images`` (cameras it was trained without, e.g. the
   shipped Objective's ``scene`` for a two-camera policy) are dropped first, and only those.
2. **Frames** arrive H x W x 3 uint8 RGB (the adapters convert ``bgr8``/``mono8``; a transport
   that hands raw BGR sets ``image_encoding="bgr8"``), are cropped when the checkpoint's metadata
   names a crop for that camera (``camera_crops``: the part of the frame it was trained on, as
   fractions of the frame), become float CHW in [0, 1] and are resized to the feature's size.
3. **State** is reordered from the request's ``joint_names`` into the checkpoint's joint order
   (``objective_policy.json``'s ``joint_names``, else the request order); the preprocessor
   normalizes it and tokenizes the prompt.
4. **RTC.** When the policy has a denoising loop that LeRobot can guide (SmolVLA, pi0, pi0.5) RTC
   is enabled in the config *before* the policy is built (otherwise LeRobot silently ignores the
   arguments), and a request carrying ``previous_action_chunk`` calls
   ``predict_action_chunk(batch, inference_delay=frozen_prefix_steps,
   prev_chunk_left_over=<that tail>, execution_horizon=...)`` with the guide's conversion
   (:func:`execution_horizon`).
5. **Observation queues.** LeRobot's DiffusionPolicy reads its observation from queues that
   only its ``select_action`` fills, not from ``predict_action_chunk``'s batch; the backend fills
   them first (:func:`queue_observation`), one observation per request (train such a policy with
   ``n_obs_steps`` 1: requests are a committed window apart, not one step).
6. **Answer.** The postprocessor denormalizes; the absolute chunk goes back in the request's joint
   order, and the raw normalized chunk as ``policy_actions`` (only for RTC-capable policies: the
   caller echoes its tail back as the next ``previous_action_chunk``).

``warmup`` runs one full-size inference (twice: the first pays for lazy initialisation) so the
server reports ready with steady latency. When the steady latency exceeds half the committed
window (``committed_window`` seconds) a warning is logged: ExecutePolicy would then spend most of
every window waiting for the next chunk.

The pure functions here (:func:`execution_horizon`, :func:`map_cameras`, :func:`frame_to_rgb`,
:func:`joint_order`, :class:`LatencyMonitor`) import neither torch nor LeRobot.
"""
from __future__ import annotations

import json
import logging
import math
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from runtime.errors import ObjectiveError, OptionError

from .backend import PolicyRequest, PolicyResponse

LOG = logging.getLogger("objective.policy.lerobot")

IMAGE_PREFIX = "observation.images."
STATE_KEY = "observation.state"
ACTION_KEY = "action"
VLM_DIRNAME = "vlm"
"""A checkpoint's local SmolVLM description folder (see ``tiny_smolvla``); used instead of the
hub name its config records."""
TOKENIZER_DIRNAME = "tokenizer"
"""A checkpoint's own prompt tokenizer, given to LeRobot's tokenizer step in place of the one its
processor names (``policy/pi05_offline.py`` saves one)."""
METADATA_FILE = "objective_policy.json"
"""Optional file next to a checkpoint with what LeRobot's format does not keep: ``joint_names``
(state/action columns), ``control_period`` (seconds per step at training), ``default_guidance_horizon``,
``camera_crops`` (camera -> ``[top, left, bottom, right]`` fractions of the frame, see :func:`crop_slices`),
``ignored_images`` (request image names the policy does not use), ``noise_scale`` (see
:class:`LeRobotOptions`) and ``cube_locator`` (the perception stage of a policy that observes located
cubes: ``policy.cube_locator.CubeLocatorConfig``) and ``relative_actions`` (true: the policy's chunk is
the joints' offset from the observed state, see :meth:`LeRobotBackend.infer`) and ``chunk_samples``
(a flow the backend samples itself: its chunk is the mean of this many samples, 1 if absent) and
``action_range`` (``{"min": [...], "max": [...]}`` per action column: the answered chunk is clipped
into the range of the labels the policy was trained on) and ``stack_keypoints`` (with ``cube_locator``:
the located cubes also reach the policy as the arm's joints at the stack's four poses, as offsets
from the observed joints and their fine copy: ``policy.stack_keypoints.keypoint_features``)."""
CLIP_DIRNAME = "clip"
"""A checkpoint's local CLIP text-encoder folder (see ``learned_stack``); used instead of the hub name."""
FLOW_SAMPLED_TYPES = frozenset({"multi_task_dit"})
"""LeRobot policies whose flow-matching chunk this backend samples itself (``learned_stack.sample_chunk``),
so that it takes a starting noise and LeRobot's RTC guidance."""
RTC_POLICY_TYPES = frozenset({"smolvla", "pi0", "pi05"})
"""LeRobot policies whose sampling loop takes RTC guidance (LeRobot 0.6 guides pi0-FAST, GR00T and others too; these are the ones served and tested here)."""
QUEUED_OBSERVATION_TYPES = frozenset({"diffusion"})
"""LeRobot policies whose ``predict_action_chunk`` reads the observation from the policy's own
queues (filled only by ``select_action``) instead of its ``batch`` argument: see :func:`queue_observation`."""
DEFAULT_GUIDANCE_HORIZON = 10
"""LeRobot's own RTCConfig default ``execution_horizon``, used as the width when nothing says otherwise."""


# ---------------------------------------------------------------------------------------------
# Pure functions (no torch)
# ---------------------------------------------------------------------------------------------
class CameraMappingError(ObjectiveError, ValueError):
    """Request image names and checkpoint cameras do not correspond; names both sides."""


def checked_noise_scale(value: Any, where: str) -> float:
    """A sampler noise scale: a finite number >= 0 (1 samples as trained, 0 starts at the mean)."""
    try:
        scale = float(value)
    except (TypeError, ValueError):
        scale = float("nan")
    if not math.isfinite(scale) or scale < 0:
        raise OptionError(f"{where}: noise_scale must be a finite number >= 0 (1 samples as trained), got {value!r}")
    return scale


def checked_chunk_samples(value: Any, where: str) -> int:
    """A flow-sampled chunk's sample count: an integer >= 1."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise OptionError(f"{where}: chunk_samples must be an integer >= 1, got {value!r}")
    return value


def checked_action_range(value: Any, action_dim: int, where: str) -> tuple[list[float], list[float]] | None:
    """The metadata's ``action_range`` as (low, high), ``action_dim`` finite numbers each with low <= high (None if absent)."""
    if value is None:
        return None
    try:
        low, high = [float(v) for v in value["min"]], [float(v) for v in value["max"]]
    except (TypeError, KeyError, ValueError):
        low, high = [], []
    valid = len(low) == len(high) == action_dim and all(math.isfinite(a) and math.isfinite(b) and a <= b
                                                          for a, b in zip(low, high))
    if not valid:
        raise OptionError(f"{where}: action_range must be {{\"min\": [...], \"max\": [...]}} with {action_dim} finite "
                          f"numbers each, min <= max, got {value!r}")
    return low, high


def noise_shape(config: Any) -> tuple[int, int, int]:
    """The shape of the starting noise of one sampled chunk: SmolVLA, pi0 and pi0.5 denoise
    ``chunk_size`` steps padded to ``max_action_dim``; the diffusion policy ``horizon`` steps of the
    action."""
    if getattr(config, "type", "") in {"diffusion", *FLOW_SAMPLED_TYPES}:
        return (1, int(config.horizon), int(config.output_features[ACTION_KEY].shape[0]))
    return (1, int(config.chunk_size), int(config.max_action_dim))


def execution_horizon(frozen_prefix_steps: int, guidance_horizon: int, server_default: int) -> int:
    """LeRobot's ``execution_horizon`` for a request (the guide's conversion).

    ``guidance_horizon`` counts steps past the frozen prefix, 0 meaning "the server's configured
    width"; LeRobot's ``execution_horizon`` counts from the start of the chunk. So the width is
    substituted first, then the prefix added: adding a zero width would leave the guided region
    empty, and passing the width without the prefix would let the policy re-decide steps already
    under way.
    """
    if frozen_prefix_steps < 0:
        raise OptionError(f"frozen_prefix_steps must be >= 0, got {frozen_prefix_steps}")
    if guidance_horizon < 0:
        raise OptionError(f"guidance_horizon must be >= 0, got {guidance_horizon}")
    if server_default < 1:
        raise OptionError(f"the server's default guidance horizon must be >= 1, got {server_default}")
    width = guidance_horizon if guidance_horizon > 0 else server_default
    return frozen_prefix_steps + width


def camera_name(feature_key: str) -> str:
    """``observation.images.wrist`` -> ``wrist`` (other keys are returned unchanged)."""
    return feature_key[len(IMAGE_PREFIX):] if feature_key.startswith(IMAGE_PREFIX) else feature_key


def map_cameras(
    request_names: Sequence[str],
    checkpoint_keys: Sequence[str],
    explicit: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """Request image name -> checkpoint image feature key, one to one, or ``CameraMappingError``.

    A request name matches the feature ``observation.images.<name>`` (or the full key itself).
    ``explicit`` maps request names to checkpoint cameras (bare or full keys) for checkpoints
    trained with other camera names, e.g. ``{"scene": "top"}``. Every checkpoint camera must be fed
    and every request image must land somewhere: a missing, extra or doubly-fed camera is refused
    naming both lists, since a frame in the wrong slot fails silently otherwise.
    """
    keys = list(checkpoint_keys)
    by_name = {camera_name(key): key for key in keys}
    wanted = f"[{', '.join(camera_name(k) for k in keys)}]"
    given = f"[{', '.join(request_names)}]"
    explicit = dict(explicit or {})
    unknown_explicit = [name for name in explicit if name not in request_names]
    if unknown_explicit:
        raise CameraMappingError(
            f"camera map names request images [{', '.join(unknown_explicit)}] that the request does not have "
            f"(request images {given})"
        )
    mapping: dict[str, str] = {}
    for name in request_names:
        target = explicit.get(name, name)
        key = target if target in keys else by_name.get(target)
        if key is None:
            raise CameraMappingError(
                f"request image '{name}'" + (f" (mapped to '{target}')" if target != name else "")
                + f" is not a camera of the checkpoint: checkpoint cameras {wanted}, request images {given}"
            )
        mapping[name] = key
    fed = list(mapping.values())
    doubled = sorted({camera_name(k) for k in fed if fed.count(k) > 1})
    if doubled:
        raise CameraMappingError(
            f"checkpoint cameras [{', '.join(doubled)}] are fed by more than one request image: "
            f"checkpoint cameras {wanted}, request images {given}"
        )
    missing = [camera_name(k) for k in keys if k not in fed]
    if missing:
        raise CameraMappingError(
            f"checkpoint cameras [{', '.join(missing)}] get no request image: checkpoint cameras {wanted}, "
            f"request images {given}"
        )
    return mapping


CameraCrop = tuple[float, float, float, float]
"""``(top, left, bottom, right)`` of a frame, as fractions of its height and width."""


def checked_crop(camera: str, box: Sequence[float]) -> CameraCrop:
    """``box`` as a ``CameraCrop``, or OptionError naming the camera when it is not inside the frame."""
    values = tuple(float(v) for v in box)
    if len(values) != 4 or not (0.0 <= values[0] < values[2] <= 1.0 and 0.0 <= values[1] < values[3] <= 1.0):
        raise OptionError(
            f"crop of camera '{camera}' must be [top, left, bottom, right] fractions with 0 <= top < bottom <= 1 "
            f"and 0 <= left < right <= 1, got {list(box)}"
        )
    return values


def crop_slices(height: int, width: int, box: CameraCrop) -> tuple[slice, slice]:
    """Rows and columns of an ``height`` x ``width`` frame inside ``box`` (rounded to whole pixels):
    the same pixels whatever code crops, the training script's or the backend's."""
    top, left, bottom, right = box
    rows = slice(round(top * height), max(round(bottom * height), round(top * height) + 1))
    columns = slice(round(left * width), max(round(right * width), round(left * width) + 1))
    return rows, columns


def parse_camera_map(text: str) -> dict[str, str]:
    """``"scene=top;wrist=hand"`` -> ``{"scene": "top", "wrist": "hand"}`` (``;`` or ``,`` separated)."""
    mapping: dict[str, str] = {}
    for item in text.replace(",", ";").split(";"):
        if not item.strip():
            continue
        name, sep, target = item.partition("=")
        if not sep or not name.strip() or not target.strip():
            raise OptionError(f"camera map item {item!r} is not request_name=checkpoint_camera")
        mapping[name.strip()] = target.strip()
    return mapping


def frame_to_rgb(frame: NDArray[Any], encoding: str = "rgb8", name: str = "") -> NDArray[np.uint8]:
    """An H x W x 3 uint8 RGB view of ``frame`` given as ``rgb8``, ``bgr8`` (H x W x 3) or ``mono8`` (H x W)."""
    label = f"image '{name}'" if name else "image"
    array = np.asarray(frame)
    if array.dtype != np.uint8:
        raise OptionError(f"{label}: expected uint8 pixels, got {array.dtype}")
    encoding = encoding.lower()
    if encoding == "mono8":
        if array.ndim == 3 and array.shape[2] == 1:
            array = array[:, :, 0]
        if array.ndim != 2:
            raise OptionError(f"{label}: mono8 needs H x W pixels, got shape {array.shape}")
        return np.repeat(array[:, :, None], 3, axis=2)
    if encoding not in ("rgb8", "bgr8"):
        raise OptionError(f"{label}: unsupported encoding '{encoding}' (expected rgb8, bgr8 or mono8)")
    if array.ndim != 3 or array.shape[2] != 3:
        raise OptionError(f"{label}: {encoding} needs H x W x 3 pixels, got shape {array.shape}")
    return array[:, :, ::-1] if encoding == "bgr8" else array


def joint_order(request_names: Sequence[str], checkpoint_names: Sequence[str]) -> list[int]:
    """For each checkpoint joint, its column in the request; ValueError naming both lists on a mismatch."""
    if sorted(request_names) != sorted(checkpoint_names) or len(set(request_names)) != len(request_names):
        raise OptionError(
            f"the checkpoint's joints [{', '.join(checkpoint_names)}] do not match the request's robot_state "
            f"joints [{', '.join(request_names)}]"
        )
    return [list(request_names).index(name) for name in checkpoint_names]


class LatencyMonitor:
    """Steady inference latency (median of the last ``window`` calls) against half the committed window.

    ExecutePolicy commits ``committed_action_steps`` steps of each chunk and must have the next
    chunk before they run out; a policy slower than half that window leaves little margin and
    makes the frozen prefix eat most of every chunk. ``record`` returns a warning text the first
    time the steady latency crosses the limit (and again only after it has recovered).
    """

    def __init__(self, committed_window: float | None, window: int = 10) -> None:
        self.limit = None if committed_window is None else committed_window / 2.0
        self.samples: list[float] = []
        self.window = window
        self.warned = False

    def record(self, seconds: float) -> str | None:
        self.samples = (self.samples + [float(seconds)])[-self.window:]
        if self.limit is None:
            return None
        steady = self.steady()
        if steady > self.limit and not self.warned:
            self.warned = True
            return (
                f"steady inference latency {steady * 1000:.0f} ms exceeds half the committed window "
                f"({self.limit * 2 * 1000:.0f} ms): commit more steps per chunk (committed_action_steps) "
                f"or serve a faster policy"
            )
        if steady <= self.limit:
            self.warned = False
        return None

    def steady(self) -> float:
        return statistics.median(self.samples) if self.samples else 0.0


# ---------------------------------------------------------------------------------------------
# The backend
# ---------------------------------------------------------------------------------------------
@dataclass
class LeRobotOptions:
    """How a checkpoint is served. Every field has a command-line spelling in the server."""

    device: str = "cpu"
    rtc: bool = True
    """Enable RTC guidance when the policy type supports it (SmolVLA, pi0, pi0.5)."""
    guidance_horizon: int | None = None
    """The server's default RTC width (steps past the frozen prefix) for requests with
    ``guidance_horizon`` 0. None: the checkpoint metadata's, else LeRobot's default (10)."""
    camera_map: dict[str, str] = field(default_factory=dict)
    """Request image name -> checkpoint camera, when they are named differently."""
    joint_names: list[str] | None = None
    """The checkpoint's state/action column order; None: metadata's, else the request's order."""
    control_period: float | None = None
    """Seconds per step at training (``native_control_period``); None: metadata's, else 0 (unknown)."""
    image_encoding: str = "rgb8"
    """Encoding of ``PolicyRequest.images`` (the adapters deliver rgb8)."""
    committed_window: float | None = 2.0
    """Seconds of motion committed per chunk (committed_action_steps * dt: 20 x 0.1 s in the shipped
    Objectives); the latency warning fires above half of it. None disables the warning."""
    torch_threads: int | None = 1
    """CPU threads for torch (None: torch's default). One thread measured fastest on 2 shared cores."""
    seed: int | None = 0
    """Seeds torch's noise for the flow-matching sampler at load and again at every new episode,
    so that an episode's chunks do not depend on the episodes the process answered before it
    (None: unseeded)."""
    noise_scale: float | None = None
    """Scale of the sampler's starting noise: 1 samples a chunk as trained, 0 starts every chunk at the
    noise's mean, which answers the same chunk for the same observation (the flow's central
    trajectory). None: the checkpoint metadata's ``noise_scale``, else 1."""
    warmup_on_load: bool = False
    """Run the full-size warmup at the end of ``load()`` on a synthetic observation (zero images at
    the checkpoint's sizes, zero state): for hosts that call ``load()`` only, like the embedded world."""


@dataclass
class RtcCall:
    """What the last guided ``predict_action_chunk`` call received (for logs and tests)."""

    inference_delay: int
    execution_horizon: int
    leftover_steps: int


def resolve_checkpoint(path: str | Path) -> Path:
    """The folder holding ``config.json``: ``path`` itself or its ``pretrained_model/``."""
    path = Path(path)
    for candidate in (path, path / "pretrained_model"):
        if (candidate / "config.json").is_file():
            return candidate
    if not path.exists():
        raise FileNotFoundError(f"LeRobot checkpoint '{path}' does not exist")
    raise FileNotFoundError(
        f"'{path}' is not a LeRobot checkpoint: no config.json in it or in its pretrained_model/ "
        f"(expected what policy.save_pretrained writes)"
    )


def enable_rtc(config: Any, execution_horizon: int = DEFAULT_GUIDANCE_HORIZON) -> None:
    """Turn RTC on in a policy config; must happen before the policy is built or loaded.

    Exponential prefix schedule (LeRobot's recommendation); ``execution_horizon`` is only the
    fallback for calls that pass none (this backend always passes one).
    """
    from lerobot.configs.types import RTCAttentionSchedule
    from lerobot.policies.rtc.configuration_rtc import RTCConfig

    config.rtc_config = RTCConfig(
        enabled=True, execution_horizon=execution_horizon, prefix_attention_schedule=RTCAttentionSchedule.EXP
    )


def queue_observation(policy: Any, batch: dict[str, Any]) -> dict[str, Any]:
    """Put a preprocessed observation into the queues of a policy whose ``predict_action_chunk`` reads
    them (LeRobot's DiffusionPolicy), as its ``select_action`` does, and return the batch to
    call ``predict_action_chunk`` with: the cameras stacked into ``observation.images``
    (B, cameras, C, H, W), no ``action`` key (the preprocessor leaves ``action: None``, which would
    land in the policy's action queue), every queued key appended (a fresh queue is filled with
    copies). Called without this, ``predict_action_chunk`` stacks an empty queue after a reset, or
    answers for the previous request's observation."""
    import torch
    from lerobot.policies.utils import populate_queues

    queued = {key: value for key, value in batch.items() if key != ACTION_KEY}
    cameras = list(policy.config.image_features)
    if cameras:
        queued["observation.images"] = torch.stack([batch[key] for key in cameras], dim=-4)
    policy._queues = populate_queues(policy._queues, queued)
    return queued


def resize_frames(frames: Any, size: tuple[int, int]) -> Any:
    """Float NCHW frames at ``size`` (bilinear, antialiased when shrinking): how a request's frames
    reach the checkpoint's feature size, and how the training script resizes its frames to match."""
    import torch.nn.functional as F

    if tuple(frames.shape[-2:]) == tuple(size):
        return frames
    shrinking = frames.shape[-2] > size[0] or frames.shape[-1] > size[1]
    return F.interpolate(frames, size=size, mode="bilinear", align_corners=False, antialias=shrinking)


class LeRobotBackend:
    """A LeRobot checkpoint as a ``PolicyBackend`` (see the module docstring)."""

    name = "lerobot"

    def __init__(self, checkpoint: str | Path, options: LeRobotOptions | None = None) -> None:
        self.checkpoint = Path(checkpoint)
        self.options = options or LeRobotOptions()
        self.policy: Any = None
        self.preprocessor: Any = None
        self.postprocessor: Any = None
        self.config: Any = None
        self.metadata: dict[str, Any] = {}
        self.rtc = False
        self.queued_observation = False
        """The policy reads its observation from its own queues (:func:`queue_observation`)."""
        self.default_guidance = DEFAULT_GUIDANCE_HORIZON
        self.camera_keys: list[str] = []
        self.ignored_images: frozenset[str] = frozenset()
        """Request image names dropped before the cameras are mapped (the metadata's ``ignored_images``)."""
        self.crops: dict[str, CameraCrop] = {}
        """Checkpoint feature key -> the crop applied to its frames (from the metadata's ``camera_crops``)."""
        self.image_sizes: dict[str, tuple[int, int]] = {}
        self.state_dim = 0
        self.action_dim = 0
        self.control_period = 0.0
        self.latency = LatencyMonitor(self.options.committed_window)
        self.last_rtc: RtcCall | None = None
        self.joint_names: list[str] | None = None
        self.calls = 0
        self.noise_scale = 1.0
        self.flow_sampled = False
        """The backend samples the policy's flow itself (``FLOW_SAMPLED_TYPES``), RTC through ``rtc_processor``."""
        self.rtc_processor: Any = None
        self.locator: Any = None
        """The perception stage (``CubeLocatorConfig``) when the metadata names one."""
        self.relative = False
        """The chunk is relative to the observed joints (the metadata's ``relative_actions``)."""
        self.chunk_samples = 1
        """A flow-sampled chunk is the mean of this many samples (the metadata's ``chunk_samples``)."""
        self.action_range: tuple[Any, Any] | None = None
        """(low, high) per action column the chunk is clipped into (the metadata's ``action_range``)."""
        self.located: NDArray[np.float64] | None = None
        """The cube features located in the current episode's first request."""
        self.keypoint_config: Any = None
        """``KeypointConfig`` when the metadata names ``stack_keypoints``."""
        self.keypoints: NDArray[np.float64] | None = None
        """(4, arm joints): the current episode's keypoints (``stack_keypoints``)."""
        self._mappings: dict[tuple[str, ...], dict[str, str]] = {}

    # -- lifecycle ---
    def load(self) -> None:
        from .lerobot_offline import force_offline

        force_offline()
        import torch
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        folder = resolve_checkpoint(self.checkpoint)
        options = self.options
        if options.torch_threads:
            torch.set_num_threads(options.torch_threads)
        if options.seed is not None:
            torch.manual_seed(options.seed)
        metadata_path = folder / METADATA_FILE
        self.metadata = json.loads(metadata_path.read_text(encoding="utf-8")) if metadata_path.is_file() else {}

        config = PreTrainedConfig.from_pretrained(folder)
        config.device = options.device
        overrides: dict[str, Any] = {"device_processor": {"device": options.device}}
        vlm = folder / VLM_DIRNAME
        if getattr(config, "type", "") == "smolvla" and vlm.is_dir():
            config.vlm_model_name = str(vlm)
            overrides["tokenizer_processor"] = {"tokenizer_name": str(vlm)}
        clip = folder / CLIP_DIRNAME
        if getattr(config, "type", "") == "multi_task_dit" and clip.is_dir():
            config.text_encoder_name = str(clip)
            overrides["tokenizer_processor"] = {"tokenizer_name": str(clip)}
        if (folder / TOKENIZER_DIRNAME).is_dir():
            overrides["tokenizer_processor"] = {"tokenizer_name": str(folder / TOKENIZER_DIRNAME)}
        self.flow_sampled = config.type in FLOW_SAMPLED_TYPES and getattr(config, "objective", "") == "flow_matching"
        self.default_guidance = int(
            options.guidance_horizon or self.metadata.get("default_guidance_horizon") or DEFAULT_GUIDANCE_HORIZON
        )
        self.rtc = bool(options.rtc and (self.flow_sampled or (config.type in RTC_POLICY_TYPES and hasattr(config, "rtc_config"))))
        if self.rtc and self.flow_sampled:
            from lerobot.policies.rtc.modeling_rtc import RTCProcessor

            holder = SimpleNamespace()
            enable_rtc(holder, self.default_guidance)
            self.rtc_processor = RTCProcessor(holder.rtc_config)
        elif self.rtc:
            enable_rtc(config, self.default_guidance)
        elif hasattr(config, "rtc_config"):
            config.rtc_config = None
        self.queued_observation = config.type in QUEUED_OBSERVATION_TYPES
        if self.queued_observation and getattr(config, "n_obs_steps", 1) > 1:
            LOG.warning(
                "checkpoint '%s' observes %d steps: its history here is the last %d requests, one committed window "
                "apart, not consecutive steps as in training (train it with n_obs_steps 1)",
                folder, config.n_obs_steps, config.n_obs_steps,
            )
        self.policy = get_policy_class(config.type).from_pretrained(str(folder), config=config)
        self.policy.eval()
        self.preprocessor, self.postprocessor = make_pre_post_processors(
            config, pretrained_path=str(folder), preprocessor_overrides=overrides
        )
        self.config = config
        self.camera_keys = [key for key in config.input_features if key.startswith(IMAGE_PREFIX)]
        self.image_sizes = {key: tuple(config.input_features[key].shape[-2:]) for key in self.camera_keys}
        crops = self.metadata.get("camera_crops") or {}
        unknown = sorted(set(crops) - {camera_name(k) for k in self.camera_keys})
        if unknown:
            raise OptionError(
                f"checkpoint '{folder}': {METADATA_FILE} crops cameras [{', '.join(unknown)}] it does not have "
                f"(cameras [{', '.join(camera_name(k) for k in self.camera_keys)}])"
            )
        self.crops = {IMAGE_PREFIX + name: checked_crop(name, box) for name, box in crops.items()}
        self.ignored_images = frozenset(self.metadata.get("ignored_images") or ())
        self.relative = bool(self.metadata.get("relative_actions", False))
        self.chunk_samples = checked_chunk_samples(self.metadata.get("chunk_samples", 1), str(metadata_path))
        self.locator = None
        if "cube_locator" in self.metadata:
            from .cube_locator import CubeLocatorConfig

            self.locator = CubeLocatorConfig.from_json(self.metadata["cube_locator"], str(metadata_path))
        self.keypoint_config = None
        if "stack_keypoints" in self.metadata:
            from .stack_keypoints import KeypointConfig

            if self.locator is None:
                raise OptionError(f"checkpoint '{folder}': {METADATA_FILE} has stack_keypoints without a cube_locator")
            self.keypoint_config = KeypointConfig.from_json(self.metadata["stack_keypoints"], str(metadata_path))
        fed = sorted(self.ignored_images & {camera_name(k) for k in self.camera_keys})
        if fed:
            raise OptionError(f"checkpoint '{folder}': {METADATA_FILE} ignores images [{', '.join(fed)}] that are cameras it uses")
        self.state_dim = int(config.input_features[STATE_KEY].shape[0]) if STATE_KEY in config.input_features else 0
        if self.locator is not None:
            self.state_dim -= 3 * len(self.locator.colors)  # x, y, yaw per located cube follow the joints
        if self.keypoint_config is not None:
            from .stack_keypoints import keypoint_feature_count

            self.state_dim -= keypoint_feature_count(len(self.keypoint_config.chain.joint_names))  # then the keypoints' features
        self.action_dim = int(config.output_features[ACTION_KEY].shape[0])
        self.action_range = checked_action_range(self.metadata.get("action_range"), self.action_dim, str(metadata_path))
        names = options.joint_names or self.metadata.get("joint_names")
        if names is not None and len(names) != self.action_dim:
            raise OptionError(
                f"checkpoint '{folder}': {len(names)} joint names [{', '.join(names)}] for {self.action_dim} action dimensions"
            )
        self.joint_names = list(names) if names else None
        period = options.control_period if options.control_period is not None else self.metadata.get("control_period", 0.0)
        self.control_period = float(period)
        if options.noise_scale is not None:
            self.noise_scale = checked_noise_scale(options.noise_scale, "the noise_scale option")
        else:
            self.noise_scale = checked_noise_scale(self.metadata.get("noise_scale", 1.0), f"{metadata_path}")
        LOG.info(
            "loaded %s policy from %s: cameras [%s], state %d, action %d, chunk %s, RTC %s (default width %d), noise scale %g",
            config.type, folder, ", ".join(camera_name(k) for k in self.camera_keys), self.state_dim,
            self.action_dim, getattr(config, "chunk_size", "?"), "on" if self.rtc else "off", self.default_guidance,
            self.noise_scale,
        )
        if options.warmup_on_load:
            self.warmup(self.synthetic_request())

    def synthetic_request(self, prompt: str = "warm up") -> PolicyRequest:
        """A full-size request the checkpoint accepts: zero state, black frames at the feature sizes."""
        self._require_loaded()
        names = self.joint_names or [f"joint_{i}" for i in range(self.action_dim)]
        request_name = {target: name for name, target in self.options.camera_map.items()}
        images: dict[str, NDArray[np.uint8]] = {}
        for key in self.camera_keys:
            height, width = self.image_sizes[key]
            name = request_name.get(camera_name(key), request_name.get(key, camera_name(key)))
            images[name] = np.zeros((height, width, 3), dtype=np.uint8)
        if self.locator is not None:
            from .cube_locator import painted_frame

            for name in self.locator.images():  # no cube in a black frame: a flat table with the cubes' colours
                images[name] = painted_frame(self.locator.colors)
        return PolicyRequest(prompt, list(names), np.zeros(len(names)), images, new_episode=True)

    def warmup(self, example_request: PolicyRequest) -> None:
        """Two full-size inferences (the first pays one-off costs); a failed inference raises ValueError.

        The example only sizes the warmup: when its cameras or joints are not the checkpoint's (a
        server started with generic warmup settings), a synthetic observation at the checkpoint's
        own sizes is used instead, since the model runs at those sizes whatever arrives.
        """
        self._require_loaded()
        try:
            self._camera_mapping(self._fed_images(example_request))
            self._columns(example_request)
        except ValueError as exc:
            LOG.info("warmup example does not fit the checkpoint (%s); warming up on a synthetic observation", exc)
            example_request = self.synthetic_request(example_request.prompt)
        for attempt in range(2):
            response = self.infer(example_request)
            if response.actions is None:
                raise OptionError(f"warmup inference failed: {response.message}")
        LOG.info("warmup done: %.0f ms per chunk", self.latency.steady() * 1000)

    def infer(self, request: PolicyRequest) -> PolicyResponse:
        self._require_loaded()
        try:
            columns = self._columns(request)
            if self.locator is not None and (request.new_episode or self.located is None):
                self.located = self._locate(request)
                if self.keypoint_config is not None:
                    from .stack_keypoints import stack_keypoints

                    self.keypoints = stack_keypoints(self.located, self.keypoint_config)
            observation = self._observation(request)
            guidance = self._guidance(request)
        except (ValueError, CameraMappingError) as exc:
            return PolicyResponse.error(str(exc))
        import torch

        if request.new_episode:
            self.policy.reset()
            if self.options.seed is not None:
                torch.manual_seed(self.options.seed)
        joints = observation[STATE_KEY][: self.action_dim].clone()  # a relative chunk's origin
        started = time.perf_counter()
        # no_grad, not inference_mode: RTC's guidance takes a gradient inside the sampling loop
        # (under torch.enable_grad), which inference_mode would forbid.
        with torch.no_grad():
            batch = self.preprocessor(observation)
            if self.queued_observation:
                batch = queue_observation(self.policy, batch)
            if self.flow_sampled:
                from .learned_stack import sample_chunk

                noise = self._starting_noise(self.chunk_samples).get("noise")
                normalized = sample_chunk(self.policy, batch, noise, self.rtc_processor, guidance, self.chunk_samples)
            else:
                normalized = self.policy.predict_action_chunk(batch, **guidance, **self._starting_noise())
            absolute = self.postprocessor(normalized)
            if self.relative:
                absolute = absolute + joints.to(absolute.dtype)
            if self.action_range is not None:
                absolute = torch.clamp(absolute, *(torch.as_tensor(bound, dtype=absolute.dtype) for bound in self.action_range))
        elapsed = time.perf_counter() - started
        self.calls += 1
        warning = self.latency.record(elapsed)
        if warning:
            LOG.warning(warning)
        normalized_np = normalized[0].detach().to("cpu", torch.float64).numpy()
        absolute_np = absolute[0].detach().to("cpu", torch.float64).numpy()
        actions = np.empty_like(absolute_np)
        actions[:, columns] = absolute_np
        return PolicyResponse.chunk(actions, self.control_period, normalized_np if self.rtc else None)

    def describe(self) -> dict[str, Any]:
        """What is served, for a health endpoint or a log line."""
        return {
            "backend": self.name,
            "checkpoint": str(self.checkpoint),
            "policy_type": getattr(self.config, "type", None),
            "cameras": [camera_name(k) for k in self.camera_keys],
            "camera_crops": {camera_name(k): list(box) for k, box in self.crops.items()},
            "ignored_images": sorted(self.ignored_images),
            "joint_names": self.joint_names,
            "state_dim": self.state_dim,
            "action_dim": self.action_dim,
            "chunk_size": getattr(self.config, "chunk_size", getattr(self.config, "horizon", None)),
            "rtc": self.rtc,
            "noise_scale": self.noise_scale,
            "default_guidance_horizon": self.default_guidance,
            "native_control_period": self.control_period,
            "steady_latency_s": round(self.latency.steady(), 4),
            "cube_locator": list(self.locator.images()) if self.locator is not None else None,
        }

    # -- request conversion ---
    def _observation(self, request: PolicyRequest) -> dict[str, Any]:
        import torch

        state = np.asarray(request.joint_positions, dtype=np.float32)
        if self.state_dim and state.shape != (self.state_dim,):
            raise OptionError(
                f"the checkpoint observes {self.state_dim} joint positions, the request has {state.shape[0]} "
                f"([{', '.join(request.joint_names)}])"
            )
        if self.joint_names:
            state = state[joint_order(request.joint_names, self.joint_names)]
        if self.locator is not None:
            state = np.concatenate([state, self.located])
        if self.keypoint_config is not None:
            from .stack_keypoints import keypoint_features

            names = list(self.joint_names or request.joint_names)
            missing = [n for n in self.keypoint_config.chain.joint_names if n not in names]
            if missing:
                raise OptionError(f"the policy's keypoints are of joints [{', '.join(missing)}], which the state "
                                  f"[{', '.join(names)}] does not have")
            arm = [names.index(n) for n in self.keypoint_config.chain.joint_names]
            assert self.keypoints is not None  # located before the first request
            state = np.concatenate([state, keypoint_features(state[arm], self.keypoints)]).astype(np.float32)
        observation: dict[str, Any] = {STATE_KEY: torch.from_numpy(state), "task": request.prompt}
        mapping = self._camera_mapping(self._fed_images(request))
        for name, key in mapping.items():
            rgb = frame_to_rgb(request.images[name], self.options.image_encoding, name)
            if key in self.crops:
                rows, columns = crop_slices(rgb.shape[0], rgb.shape[1], self.crops[key])
                rgb = rgb[rows, columns]
            observation[key] = self._image_tensor(rgb, self.image_sizes[key])
        return observation

    def _locate(self, request: PolicyRequest) -> NDArray[np.float64]:
        """The cube features of the request's frames (``cube_locator``); a missing image or cube raises ValueError."""
        from .cube_locator import cube_features, locate_cubes

        missing = [name for name in self.locator.images() if name not in request.images]
        if missing:
            raise OptionError(
                f"the policy locates the cubes in images [{', '.join(self.locator.images())}]; the request has no "
                f"[{', '.join(missing)}] (request images [{', '.join(request.images)}])"
            )
        images = {name: frame_to_rgb(request.images[name], self.options.image_encoding, name) for name in self.locator.images()}
        return cube_features(locate_cubes(images, self.locator))

    def _fed_images(self, request: PolicyRequest) -> list[str]:
        """The request's image names less the checkpoint's ``ignored_images``."""
        return [name for name in request.images if name not in self.ignored_images]

    def _camera_mapping(self, names: list[str]) -> dict[str, str]:
        cache_key = tuple(names)
        if cache_key not in self._mappings:
            self._mappings[cache_key] = map_cameras(names, self.camera_keys, self.options.camera_map)
        return self._mappings[cache_key]

    @staticmethod
    def _image_tensor(rgb: NDArray[np.uint8], size: tuple[int, int]) -> Any:
        """CHW float32 in [0, 1] at ``size`` (``resize_frames``)."""
        import torch

        tensor = torch.from_numpy(np.array(rgb, copy=True)).permute(2, 0, 1).float().div_(255.0)
        return resize_frames(tensor[None], size)[0]

    def _guidance(self, request: PolicyRequest) -> dict[str, Any]:
        """The RTC keyword arguments of ``predict_action_chunk`` for this request (empty without RTC)."""
        self.last_rtc = None
        tail = request.previous_action_chunk
        if not self.rtc or tail is None or np.asarray(tail).size == 0:
            return {}
        import torch

        tail = np.array(tail, dtype=np.float32, copy=True)
        if tail.ndim != 2 or tail.shape[1] != self.action_dim:
            raise OptionError(
                f"previous_action_chunk has shape {tail.shape}; this policy's normalized actions are "
                f"(steps, {self.action_dim}) (echo policy_action_chunk back untouched)"
            )
        if self.relative:
            tail = self._reanchored(request, tail)
        delay = int(request.frozen_prefix_steps)
        horizon = execution_horizon(delay, int(request.guidance_horizon), self.default_guidance)
        self.last_rtc = RtcCall(delay, horizon, int(tail.shape[0]))
        LOG.debug("RTC: inference_delay=%d execution_horizon=%d leftover=%d steps", delay, horizon, tail.shape[0])
        return {
            "inference_delay": delay,
            "prev_chunk_left_over": torch.from_numpy(tail),
            "execution_horizon": horizon,
        }

    def _reanchored(self, request: PolicyRequest, tail: NDArray[np.float64]) -> NDArray[np.float64]:
        """A relative policy's normalized leftover, made relative to this request's joints: it was relative to
        the joints of the request that produced it (``previous_anchor_positions``)."""
        import torch
        from lerobot.policies.rtc.relative import reanchor_relative_rtc_prefix
        from lerobot.processor import NormalizerProcessorStep, RelativeActionsProcessorStep

        if request.previous_anchor_positions is None:
            raise OptionError("this policy's chunks are relative to the observed joints: previous_action_chunk needs "
                              "previous_anchor_state (the joints of the request that answered it)")
        order = joint_order(request.joint_names, self.joint_names) if self.joint_names else list(range(self.action_dim))
        anchor = torch.from_numpy(np.asarray(request.previous_anchor_positions, dtype=np.float32)[order])
        current = torch.from_numpy(np.asarray(request.joint_positions, dtype=np.float32)[order])
        absolute = self.postprocessor(torch.from_numpy(tail)[None]).to(torch.float32) + anchor
        normalizer = next(step for step in self.preprocessor.steps if isinstance(step, NormalizerProcessorStep))
        relative = RelativeActionsProcessorStep(enabled=True)
        result: NDArray[np.float64] = reanchor_relative_rtc_prefix(absolute, current, relative, normalizer, "cpu")[0].numpy()
        return result

    def _starting_noise(self, samples: int = 1) -> dict[str, Any]:
        """The ``noise`` keyword of ``predict_action_chunk`` (``samples`` draws stacked) at a noise scale
        other than 1 (empty at 1: LeRobot samples its own)."""
        if self.noise_scale == 1.0:
            return {}
        import torch

        rows, *rest = noise_shape(self.config)
        return {"noise": self.noise_scale * torch.randn((rows * samples, *rest), device=self.options.device)}

    def _columns(self, request: PolicyRequest) -> list[int]:
        """Request column of each checkpoint action dimension."""
        if self.joint_names:
            return joint_order(request.joint_names, self.joint_names)
        if len(request.joint_names) != self.action_dim:
            raise OptionError(
                f"the checkpoint outputs {self.action_dim} action dimensions, the request observes "
                f"{len(request.joint_names)} joints ([{', '.join(request.joint_names)}])"
            )
        return list(range(self.action_dim))

    def _require_loaded(self) -> None:
        if self.policy is None:
            raise RuntimeError(f"LeRobot backend for '{self.checkpoint}' is not loaded: call load() first")


def make_lerobot_backend(checkpoint: str | Path, **options: Any) -> LeRobotBackend:
    """A LeRobot backend for ``checkpoint`` with :class:`LeRobotOptions` given by keyword.

    ``camera_map`` may be given as text (``"scene=top;wrist=hand"``). Unknown options raise
    ValueError naming the known ones. The backend is not loaded yet: call ``load()``.
    """
    known = set(LeRobotOptions.__dataclass_fields__)
    unknown = sorted(set(options) - known)
    if unknown:
        raise OptionError(f"unknown LeRobot backend options {', '.join(unknown)} (known: {', '.join(sorted(known))})")
    if isinstance(options.get("camera_map"), str):
        options["camera_map"] = parse_camera_map(options["camera_map"])
    return LeRobotBackend(checkpoint, LeRobotOptions(**options))

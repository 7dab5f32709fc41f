"""What a policy backend is: plain request/response dataclasses and the ``PolicyBackend`` protocol.

A backend turns one observation into one chunk of absolute joint positions. It knows nothing about
ROS or HTTP: the in-process adapter (``policy/adapter.py``), the ROS 2 adapter node and the
HTTP inference server all convert their wire format into a ``PolicyRequest`` and a
``PolicyResponse`` back, so one backend class serves every transport.

The shapes follow the GetActionChunk contract (see ``moveit_pro_ml_msgs/srv/GetActionChunk``):

- ``joint_names`` is the request's ``robot_state.name`` (group joints, then the gripper joint
  when one is configured) and fixes the column order of ``joint_positions`` and of the answer's
  ``actions``.
- ``previous_action_chunk`` is the RTC carryover (steps first) or None when RTC is off.
- ``actions`` is ``(T, len(joint_names))``: one row per policy step, absolute positions.
- ``policy_actions`` is the same chunk in the policy's own action space for RTC, or None for
  policies with no denoising loop (the guide's "single-pass" case).
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray


class PolicyStatus(enum.Enum):
    """What a backend answered; maps 1:1 onto the service's CHUNK_PRODUCED / NO_MORE_ACTIONS / ERROR."""

    CHUNK = "chunk"
    NO_MORE_ACTIONS = "no_more_actions"
    ERROR = "error"


@dataclass
class PolicyRequest:
    """One observation, transport-free."""

    prompt: str
    joint_names: list[str]
    joint_positions: NDArray[np.float64]
    """Shape (len(joint_names),), unnormalized, in ``joint_names`` order."""
    images: dict[str, NDArray[np.uint8]] = field(default_factory=dict)
    """Camera name -> H x W x 3 uint8 RGB (mono cameras replicated to three channels)."""
    new_episode: bool = False
    previous_action_chunk: NDArray[np.float64] | None = None
    """RTC carryover, shape (steps, action_dims); None when empty / RTC off."""
    previous_anchor_positions: NDArray[np.float64] | None = None
    """Positions of ``previous_anchor_state`` (request joint order); None when not sent."""
    frozen_prefix_steps: int = 0
    guidance_horizon: int = 0
    stamp: float = 0.0
    """``robot_state.header.stamp`` in seconds: when the observed joint state was sampled, on the
    robot's clock (sim time in the simulated cell). A backend in another process that needs the
    robot's clock (the remote oracle) reads it here."""


@dataclass
class PolicyResponse:
    """One answer, transport-free. ``actions`` is read only when ``status`` is CHUNK."""

    status: PolicyStatus
    message: str = ""
    actions: NDArray[np.float64] | None = None
    """Shape (T, len(request.joint_names)), absolute joint positions."""
    native_control_period: float = 0.0
    policy_actions: NDArray[np.float64] | None = None
    """Shape (T, A) in the policy's action space, for RTC; None when not applicable."""

    @classmethod
    def chunk(
        cls,
        actions: NDArray[np.float64],
        native_control_period: float,
        policy_actions: NDArray[np.float64] | None = None,
        message: str = "",
    ) -> PolicyResponse:
        values = np.asarray(actions)  # real numbers as floats; anything else kept for the adapter to refuse
        values = values.astype(float) if values.dtype.kind in "iuf" else values
        return cls(PolicyStatus.CHUNK, message, values, native_control_period, policy_actions)

    @classmethod
    def error(cls, message: str) -> PolicyResponse:
        return cls(PolicyStatus.ERROR, message)

    @classmethod
    def no_more_actions(cls, message: str) -> PolicyResponse:
        return cls(PolicyStatus.NO_MORE_ACTIONS, message)


@runtime_checkable
class PolicyBackend(Protocol):
    """A policy behind any transport.

    Lifecycle: ``load()`` once (may be slow: weights, files), then ``warmup(example)`` once with a
    full-size request so the first real call pays no compilation or cache cost, then ``infer``
    per request. ``infer`` should answer ERROR for problems it understands; the adapters turn any
    exception it raises into ERROR too, so a backend never has to guard against every failure.
    """

    name: str

    def load(self) -> None: ...

    def warmup(self, example_request: PolicyRequest) -> None: ...

    def infer(self, request: PolicyRequest) -> PolicyResponse: ...

"""ExecutePolicy's link to the policy: the GetActionChunk client, the request in flight, the
latency estimate and the real-time-chunking carryover.

``send`` refuses a stale observation (``observation.stale_observation``) and asks for the chunk of
a request step; ``answer`` hands over the response once it came (or None while it has not), with
its round trip, which the behavior feeds to ``latency`` (``timing.LatencyEstimate``, what the next
request is timed for); ``carry_over`` keeps what real-time chunking sends back with the next
request. The client is built once (``PolicyLink(client)``); ``reset`` starts a run.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray
from moveit_pro_ml_msgs.srv import GetActionChunk

from .config import PolicyRunConfig
from .observation import StaleObservation, policy_tail, stale_observation
from .states import InFlight
from .timing import LatencyEstimate


@dataclass(frozen=True)
class Carryover:
    """What real-time chunking sends back with the next request: the policy's own chunk of the
    last window sent to the controller, the step its request was for, and the state sent with it."""

    policy_chunk: NDArray[np.float64] | None
    request_step: int
    anchor: Any


@dataclass(frozen=True)
class Answer:
    """A request's outcome: its ``response``, or the ``error`` the call raised in transport."""

    flight: InFlight
    round_trip_s: float
    response: Any = None
    error: Exception | None = None


class PolicyLink:
    """The GetActionChunk client and what one run knows of the policy."""

    def __init__(self, client: Any) -> None:
        self.client = client
        self.reset()

    def reset(self) -> None:
        self.request: InFlight | None = None
        self.latency = LatencyEstimate()
        self.carryover: Carryover | None = None
        self.chunk_steps: int | None = None
        """The policy's chunk size, once an answer showed it (the sizing warning uses it)."""

    def ready(self) -> bool:
        return bool(self.client.service_is_ready())

    def send(self, config: PolicyRunConfig, robot_state: Any, frames: list[Any], received: Sequence[tuple[str, float | None]],
             now_s: float, new_episode: bool, request_step: int, frozen: int) -> None:
        """Ask for the chunk of ``request_step`` with ``robot_state`` and the camera ``frames``;
        ``received``: when each observation arrived, by topic. Raises StaleObservation when one
        is older than ``max_observation_age``."""
        stale = stale_observation(now_s, received, config.observation_age_limit_s)
        if stale is not None:
            raise StaleObservation(stale)
        request = GetActionChunk.Request()
        request.prompt = config.prompt
        request.robot_state = robot_state
        request.image_names = list(config.image_names)
        request.images = frames
        request.new_episode = new_episode
        request.frozen_prefix_steps = frozen
        request.guidance_horizon = config.guidance_horizon
        if config.policy_uses_real_time_chunking and self.carryover is not None and not new_episode:
            request.previous_action_chunk = policy_tail(self.carryover.policy_chunk, request_step - self.carryover.request_step)
            request.previous_anchor_state = self.carryover.anchor
        future = self.client.call_async(request, timeout_s=config.policy_call_timeout)
        self.request = InFlight(future, now_s, request_step, frozen, request.robot_state)

    def timed_out(self, now_s: float, limit_s: float) -> bool:
        """Whether the request in flight has waited more than ``limit_s`` (it is cancelled then)."""
        flight = self.request
        assert flight is not None
        if flight.future.done() or now_s - flight.sent_at_s <= limit_s:
            return False
        self.cancel()
        return True

    def answer(self, now_s: float) -> Answer | None:
        """The answer to the request in flight once it came (None while it has not); the chunk
        size of a response that carries a chunk is noted."""
        flight = self.request
        assert flight is not None
        if not flight.future.done():
            return None
        self.request = None
        round_trip_s = now_s - flight.sent_at_s
        try:
            response = flight.future.result()
        except Exception as exc:  # a transport failure of the call
            return Answer(flight, round_trip_s, error=exc)
        if response.status == GetActionChunk.Response.CHUNK_PRODUCED and response.chunk.points:
            self.chunk_steps = len(response.chunk.points)
        return Answer(flight, round_trip_s, response)

    def carry_over(self, policy_chunk: NDArray[np.float64] | None, request_step: int, anchor: Any) -> None:
        """Keep the policy chunk of the window just sent, for the next request's real-time chunking."""
        self.carryover = Carryover(policy_chunk, request_step, anchor)

    def cancel(self) -> None:
        if self.request is not None:
            self.request.future.cancel()
            self.request = None

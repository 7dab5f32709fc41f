"""ExecutePolicy's states: the run's phases, and in the STREAM phase the policy side, the
controller side and the sent motion (what the controller has been sent). Immutable values; each transition returns a new one.

- ``Phase``: STARTUP -> WARMUP -> STREAM -> DONE (any phase may end in DONE).
- ``StreamState`` (policy side, what a STREAM tick does): SCHEDULING (send the next request when
  its step comes) -> AWAITING_CHUNK (a request is in flight) -> SCHEDULING once its chunk is
  sent to the controller, or HOLDING (the chunk cannot be planned yet) -> SCHEDULING.
- ``action_goal.GoalState`` (controller side): NONE -> SENT -> PLAYING -> ENDED, and SENT again
  with each chunk (the arm rests where the run found it before the first, and at the end of the
  sent motion once the last ENDED); a goal refused for arriving late rolls back to the
  ``Rollback`` taken when it was sent.
- The run succeeds when every step is sent, no request is in flight and the last goal ENDED.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..action_goal import Goal, GoalState
from .chunk import Chunk
from .seam import ChunkMotion
from runtime.motion.samples import Samples
from .stream import StepGrid


class Phase(enum.Enum):
    STARTUP = "startup"  # wait for the service, the actions, the cameras and the joint states
    WARMUP = "warmup"  # one discarded request seeds the latency estimate
    STREAM = "stream"  # request, plan, check, send, watch
    DONE = "done"


class StreamState(enum.Enum):
    SCHEDULING = "scheduling"  # nothing in flight or held: request when the next request step comes
    AWAITING_CHUNK = "awaiting_chunk"  # a request is in flight
    HOLDING = "holding"
    """A received chunk waits to be planned: the previous goal is unanswered, or the motion still
    playing ends before the chunk could join it."""


@dataclass(frozen=True)
class InFlight:
    """A request the policy has not answered yet."""

    future: Any
    sent_at_s: float
    request_step: int
    frozen: int
    anchor: Any  # the JointState sent with the request


@dataclass(frozen=True)
class HeldChunk:
    """A chunk received and read, with the request it answers."""

    chunk: Chunk
    flight: InFlight
    index: int
    """The chunk's number in the run, from 1."""
    policy_chunk: NDArray[np.float64] | None = None
    """The policy's own chunk (``policy_action_chunk``), when it was read and sent."""


@dataclass(frozen=True)
class SentMotion:
    """What the controller has been sent: the step grid with the windows sent, and the motion
    and its densified samples (None before the first chunk)."""

    grid: StepGrid
    motion: ChunkMotion | None = None
    samples: Samples | None = None


@dataclass(frozen=True)
class Rollback:
    """A chunk sent to the controller, and the sent motion from before it: what a goal refused
    for arriving late goes back to."""

    held: HeldChunk
    sent: SentMotion
    goal: Goal
    stall_s: float  # the stall its plan counted: a rollback takes it back
    chunk_index: int = 0
    takes_over_s: float = 0.0  # when the chunk's goal was meant to take over (its stamp)


def stream_state(held: HeldChunk | None, request: InFlight | None) -> StreamState:
    """What the next STREAM tick does. A held chunk comes first: a late goal's rollback may hold
    its chunk again while the next request is already in flight."""
    if held is not None:
        return StreamState.HOLDING
    if request is not None:
        return StreamState.AWAITING_CHUNK
    return StreamState.SCHEDULING


def stream_finished(sent: SentMotion, request: InFlight | None, goal: Goal) -> bool:
    """Every step sent, no request in flight, and the last goal's result came."""
    return sent.grid.remaining == 0 and request is None and goal.state is GoalState.ENDED

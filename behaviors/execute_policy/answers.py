"""The answers to a policy run's requests, with the GetActionChunk contract: what each status
means, how a call that fails or does not answer ends the run, and a chunk read from an answer
(``read_answer``: the step period, then ``chunk.read_chunk``'s joint names, shape and finite
values, and the policy chunk when the run reads it; ``first_chunk_problem``: a first chunk longer
than the window). Each rejection is a ``failure.Failure``.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from . import config as cfg
from .chunk import Chunk, ChunkError, period_problem, read_chunk, read_policy_chunk
from .failure import Failure, FailureKind
from .run_warnings import RunWarnings

STATUS_NAMES = {0: "UNKNOWN", 1: "CHUNK_PRODUCED", 2: "NO_MORE_ACTIONS", 3: "ERROR"}
"""GetActionChunk's response statuses, by value."""


def status_reason(response: Any, what: str) -> str:
    """Why an answer that is not a chunk ends the run: its status and the policy's message."""
    status = STATUS_NAMES.get(response.status, f"status {response.status}")
    detail = response.message or ("the policy left the status unset" if response.status == 0 else "no message")
    return f"the policy answered {status} for the {what}: {detail}"


def timed_out(config: cfg.PolicyRunConfig) -> Failure:
    return Failure(
        FailureKind.POLICY_TIMEOUT,
        f"the policy service '{config.policy_service_name}' did not answer within policy_call_timeout = {config.policy_call_timeout:g} s")


def call_failed(config: cfg.PolicyRunConfig, error: Exception) -> Failure:
    """A transport failure of the call."""
    return Failure(FailureKind.POLICY_ERROR, f"calling the policy service '{config.policy_service_name}' failed: {error}")


def no_more_actions(response: Any) -> str:
    """The message of the SUCCESS a ``NO_MORE_ACTIONS`` answer ends the run with."""
    return f"the policy has no more actions: {response.message}".rstrip(": ")


def not_a_chunk(response: Any, chunk_number: int) -> Failure:
    """An answer that is neither a chunk nor ``NO_MORE_ACTIONS`` (``ERROR``, ``UNKNOWN``)."""
    return Failure(FailureKind.POLICY_ERROR, status_reason(response, f"chunk {chunk_number}"))


def read_answer(response: Any, chunk_number: int, config: cfg.PolicyRunConfig, joints: Sequence[str], reads_policy_chunk: bool,
                warnings: RunWarnings) -> tuple[Chunk, NDArray[np.float64] | None] | Failure:
    """The chunk of a ``CHUNK_PRODUCED`` answer and its policy chunk (None unless
    ``reads_policy_chunk``), or the Failure that rejects it; ``warnings`` hears about the step
    period and about a real-time-chunking run's missing policy chunk."""
    period = period_problem(response.native_control_period)
    if period is not None:
        return Failure(FailureKind.MALFORMED_CHUNK, f"chunk {chunk_number} rejected: {period}")
    warnings.period(response.native_control_period, chunk_number, config.dt)
    try:
        chunk = read_chunk(response.chunk, joints, config.gripper_joint_name or None)
        policy_chunk = read_policy_chunk(response.policy_action_chunk) if reads_policy_chunk else None
    except ChunkError as err:
        return Failure(FailureKind.MALFORMED_CHUNK, f"chunk {chunk_number} rejected: {err}")
    if config.policy_uses_real_time_chunking and policy_chunk is None:
        warnings.no_policy_chunk(chunk_number)
    return chunk, policy_chunk


def first_chunk_problem(chunk: Chunk, config: cfg.PolicyRunConfig) -> Failure | None:
    """The guide's rule for the first chunk (``config.committed_window_problem``): it must be
    longer than the window."""
    problem = cfg.committed_window_problem(config.committed_action_steps, chunk.steps)
    return None if problem is None else Failure(FailureKind.SHORT_CHUNK, f"chunk 1 rejected: {problem}")

"""Replay backend: serves recorded chunks in order, then ends the stream with NO_MORE_ACTIONS.

File format (JSON lines, UTF-8, one chunk per line, no pickle anywhere)::

    {"joint_names": ["shoulder_pan_joint", ...], "native_control_period": 0.1,
     "actions": [[...], [...]], "policy_actions": null}

- ``joint_names``: the columns of ``actions`` (the request's ``robot_state.name`` when recorded).
- ``actions``: one row per step, absolute joint positions, one column per joint name.
- ``native_control_period`` (optional, default 0.0): the guide reserves 0 for sources with no
  training rate, such as a replay; a recording of a 10 Hz policy may keep its 0.1.
- ``policy_actions`` (optional): the RTC chunk in the policy's action space, or null.

Blank lines and lines starting with ``#`` are skipped.

Behaviour: each call answers the next chunk; a request with ``new_episode`` rewinds to the first
chunk (ExecutePolicy sends its discarded warmup and its first real request both with
``new_episode``, so the run starts at chunk 0). After the last chunk the next call answers
NO_MORE_ACTIONS, as the contract asks of a source that ends its stream. A request observing
different joints than the recording answers ERROR naming both lists; the same joints in another
order are served reordered by name.

``RecordingBackend`` wraps any backend and writes the chunks it serves to such a file, so a run
of the oracle (or a real policy) can be replayed later.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from runtime.errors import ObjectiveError

from .backend import PolicyBackend, PolicyRequest, PolicyResponse, PolicyStatus


class ReplayFileError(ObjectiveError, ValueError):
    """A replay file cannot be read; names the file, line and problem."""


@dataclass
class RecordedChunk:
    joint_names: list[str]
    actions: NDArray[np.float64]
    native_control_period: float = 0.0
    policy_actions: NDArray[np.float64] | None = None

    def to_json(self) -> str:
        return json.dumps(
            {
                "joint_names": list(self.joint_names),
                "native_control_period": float(self.native_control_period),
                "actions": np.asarray(self.actions, dtype=float).tolist(),
                "policy_actions": None if self.policy_actions is None else np.asarray(self.policy_actions, dtype=float).tolist(),
            }
        )


def write_replay(path: str | Path, chunks: Iterable[RecordedChunk]) -> int:
    """Write ``chunks`` as a replay file; returns how many were written."""
    count = 0
    with open(path, "w", encoding="utf-8") as out:
        for chunk in chunks:
            out.write(chunk.to_json() + "\n")
            count += 1
    return count


def read_replay(path: str | Path) -> list[RecordedChunk]:
    """Parse and validate a replay file (see the module docstring for the format)."""
    path = Path(path)
    if not path.is_file():
        raise ReplayFileError(f"replay file not found: {path}")
    chunks = []
    with open(path, encoding="utf-8") as stream:
        for number, line in enumerate(stream, start=1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            chunks.append(_parse_line(text, f"{path}:{number}"))
    if not chunks:
        raise ReplayFileError(f"{path}: no chunks in the file")
    return chunks


def _parse_line(text: str, where: str) -> RecordedChunk:
    try:
        record = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ReplayFileError(f"{where}: not valid JSON ({exc.msg})") from None
    if not isinstance(record, dict):
        raise ReplayFileError(f"{where}: expected a JSON object per line")
    names = record.get("joint_names")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise ReplayFileError(f"{where}: 'joint_names' must be a non-empty list of strings")
    try:
        actions = np.asarray(record.get("actions"), dtype=float)
    except (TypeError, ValueError):
        raise ReplayFileError(f"{where}: 'actions' must be a list of rows of numbers") from None
    if actions.ndim != 2 or actions.shape[0] == 0 or actions.shape[1] != len(names):
        raise ReplayFileError(
            f"{where}: 'actions' must be a non-empty list of rows with {len(names)} values each, got shape {actions.shape}"
        )
    if not np.all(np.isfinite(actions)):
        raise ReplayFileError(f"{where}: 'actions' has non-finite values")
    period = record.get("native_control_period", 0.0)
    if not isinstance(period, (int, float)) or period < 0:
        raise ReplayFileError(f"{where}: 'native_control_period' must be a number >= 0, got {period!r}")
    policy = record.get("policy_actions")
    if policy is not None:
        try:
            policy = np.asarray(policy, dtype=float)
        except (TypeError, ValueError):
            raise ReplayFileError(f"{where}: 'policy_actions' must be null or a list of rows of numbers") from None
        if policy.ndim != 2 or policy.shape[0] != actions.shape[0]:
            raise ReplayFileError(f"{where}: 'policy_actions' must have one row per step ({actions.shape[0]}), got shape {policy.shape}")
    return RecordedChunk(list(names), actions, float(period), policy)


class ReplayBackend:
    """Serves the chunks of a replay file in order (see the module docstring)."""

    name = "replay"

    def __init__(self, path: str | Path, native_control_period: float | None = None) -> None:
        """``native_control_period`` overrides the recorded one when given (0.0 = no training rate)."""
        self.path = Path(path)
        self.native_control_period = native_control_period
        self.chunks: list[RecordedChunk] = []
        self.cursor = 0
        """Index of the chunk the next call serves."""

    def load(self) -> None:
        self.chunks = read_replay(self.path)
        self.cursor = 0

    def warmup(self, example_request: PolicyRequest) -> None:
        """Check the recording matches the example's joints; consumes nothing."""
        self._require_loaded()
        problem = _names_problem(self.chunks[0].joint_names, example_request.joint_names)
        if problem:
            raise ValueError(problem)

    def infer(self, request: PolicyRequest) -> PolicyResponse:
        self._require_loaded()
        if request.new_episode:
            self.cursor = 0
        if self.cursor >= len(self.chunks):
            return PolicyResponse.no_more_actions(
                f"replay of '{self.path.name}' finished after {len(self.chunks)} chunks"
            )
        chunk = self.chunks[self.cursor]
        problem = _names_problem(chunk.joint_names, request.joint_names)
        if problem:
            return PolicyResponse.error(f"replay chunk {self.cursor}: {problem}")
        order = [chunk.joint_names.index(n) for n in request.joint_names]
        self.cursor += 1
        period = chunk.native_control_period if self.native_control_period is None else self.native_control_period
        return PolicyResponse.chunk(chunk.actions[:, order], period, chunk.policy_actions)

    def _require_loaded(self) -> None:
        if not self.chunks:
            raise RuntimeError(f"replay backend for '{self.path}' is not loaded: call load() first")


def _names_problem(recorded: Sequence[str], observed: Sequence[str]) -> str | None:
    if sorted(recorded) == sorted(observed):
        return None
    return (
        f"recorded joints [{', '.join(recorded)}] do not match the request's robot_state joints "
        f"[{', '.join(observed)}]"
    )


class RecordingBackend:
    """Wraps a backend and appends every chunk it serves to a replay file.

    A request with ``new_episode`` starts the file afresh, mirroring ``ReplayBackend`` rewinding,
    so the warmup chunk ExecutePolicy discards is not kept. Each chunk is appended (and flushed)
    as it is served, so the file is complete even if the run stops abruptly.
    """

    def __init__(self, inner: PolicyBackend, path: str | Path) -> None:
        self.inner = inner
        self.path = Path(path)
        self.name = f"recording({inner.name})"
        self.recorded: list[RecordedChunk] = []

    def load(self) -> None:
        self.inner.load()

    def warmup(self, example_request: PolicyRequest) -> None:
        self.inner.warmup(example_request)

    def infer(self, request: PolicyRequest) -> PolicyResponse:
        if request.new_episode or not self.path.exists():
            self.recorded = []
            self.path.write_text("", encoding="utf-8")
        response = self.inner.infer(request)
        if response.status is PolicyStatus.CHUNK and response.actions is not None:
            chunk = RecordedChunk(
                list(request.joint_names),
                np.asarray(response.actions, dtype=float),
                float(response.native_control_period),
                response.policy_actions,
            )
            self.recorded.append(chunk)
            with open(self.path, "a", encoding="utf-8") as out:
                out.write(chunk.to_json() + "\n")
        return response

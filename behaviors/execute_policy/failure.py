"""What ends a policy run in FAILURE: a ``Failure``, its kind and what happened, in words.

A rejected chunk's kind is the check it failed (``checks.CheckKind``); every other kind is a
``FailureKind``. The kind's value is what the run's summary reports as ``failure_kind`` and what an
evaluation groups failed episodes by. Pure.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass

from .checks import CheckKind


class FailureKind(enum.Enum):
    """What kind of FAILURE ended the run, besides a rejected chunk's ``checks.CheckKind``."""

    SHORT_CHUNK = "chunk too short"
    """A chunk with nothing left to execute after its seam, or a first chunk not longer than the window."""
    MALFORMED_CHUNK = "malformed chunk"
    POLICY_ERROR = "policy error"
    POLICY_TIMEOUT = "policy timeout"
    CONTROLLER = "controller"
    GRIPPER = "gripper"
    SCENE_CHANGED = "scene changed"
    STALE_OBSERVATION = "stale observation"


REJECTED_CHUNK_KINDS = (FailureKind.SHORT_CHUNK, FailureKind.MALFORMED_CHUNK)
"""The ``FailureKind``s of a rejected chunk (a failed check's ``CheckKind`` is one as well)."""


@dataclass(frozen=True)
class Failure:
    """Why a run ends in FAILURE: its ``kind`` and the ``detail`` that names what happened (the
    run's message)."""

    kind: FailureKind | CheckKind
    detail: str

    @property
    def rejects_chunk(self) -> bool:
        """Whether a chunk the policy sent is what fails: a failed check, too short or malformed."""
        return isinstance(self.kind, CheckKind) or self.kind in REJECTED_CHUNK_KINDS

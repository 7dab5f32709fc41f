"""What ends a policy run in FAILURE: a ``Failure``, its kind and what happened, in words.

Every kind is a ``FailureKind``: a rejected chunk's is the check it failed (``CHECK_KINDS``, what
``checks.PointChecks`` reports) or what else was wrong with it, and every other ending has its own.
The kind's value is what the run's summary reports as ``failure_kind`` and what an evaluation
groups failed episodes by. Pure.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass


class FailureKind(enum.Enum):
    """What kind of FAILURE ended the run."""

    POSITION_LIMIT = "position limit"
    VELOCITY_LIMIT = "velocity limit"
    ACCELERATION_LIMIT = "acceleration limit"
    WORKSPACE_LIMIT = "workspace limit"
    TOOL_AXIS_LIMIT = "tool axis limit"
    LINEAR_SPEED_LIMIT = "linear speed limit"
    ANGULAR_SPEED_LIMIT = "angular speed limit"
    SELF_COLLISION = "self collision"
    WORLD_COLLISION = "world collision"
    SHORT_CHUNK = "chunk too short"
    """A chunk with nothing left to execute after its seam, or a first chunk not longer than the window."""
    MALFORMED_CHUNK = "malformed chunk"
    POLICY_ERROR = "policy error"
    POLICY_TIMEOUT = "policy timeout"
    CONTROLLER = "controller"
    GRIPPER = "gripper"
    SCENE_CHANGED = "scene changed"
    STALE_OBSERVATION = "stale observation"
    FORCE_TORQUE = "force-torque threshold"
    """A reading on ``wrench_topic`` over ``absolute_force_torque_threshold`` (the controller's own
    force-torque abort is a ``CONTROLLER`` failure)."""

    @classmethod
    def of_limit(cls, quantity: str) -> FailureKind:
        """The kind of a ``LimitViolation`` of ``quantity`` (position, velocity, acceleration) or
        an ``EnvelopeViolation`` (workspace, tool axis, linear speed, angular speed)."""
        return cls(f"{quantity} limit")

    @classmethod
    def of_collision(cls, kind: str) -> FailureKind:
        """The kind of a ``CollisionResult`` of ``kind`` (self, world)."""
        return cls(f"{kind} collision")


CHECK_KINDS = frozenset({
    FailureKind.POSITION_LIMIT, FailureKind.VELOCITY_LIMIT, FailureKind.ACCELERATION_LIMIT, FailureKind.WORKSPACE_LIMIT,
    FailureKind.TOOL_AXIS_LIMIT, FailureKind.LINEAR_SPEED_LIMIT, FailureKind.ANGULAR_SPEED_LIMIT,
    FailureKind.SELF_COLLISION, FailureKind.WORLD_COLLISION,
})
"""The kinds of a failed check (``checks.CheckFailure``): which check a point failed."""

REJECTED_CHUNK_KINDS = CHECK_KINDS | {FailureKind.SHORT_CHUNK, FailureKind.MALFORMED_CHUNK}
"""The kinds of a rejected chunk: a failed check, too short or malformed."""


@dataclass(frozen=True)
class Failure:
    """Why a run ends in FAILURE: its ``kind`` and the ``detail`` that names what happened (the
    run's message)."""

    kind: FailureKind
    detail: str

    @property
    def rejects_chunk(self) -> bool:
        """Whether a chunk the policy sent is what fails: a failed check, too short or malformed."""
        return self.kind in REJECTED_CHUNK_KINDS

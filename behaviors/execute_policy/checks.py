"""Where a point is checked: the chunk's values against the joints' position limits, and every
densified point against the position, velocity and acceleration limits, the Cartesian envelope
and the planning scene (self-collision, and world collision with ``link_padding``). Each check
returns why the points fail, a ``CheckFailure`` (its kind, one of ``failure.CHECK_KINDS``, and a
sentence naming the run's policy step), or None.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..safety import MotionSafety
from .chunk import Chunk
from .failure import FailureKind
from runtime.motion.samples import Samples
from .stream import StepGrid, Window


@dataclass(frozen=True)
class CheckFailure:
    """Why points fail a check: its kind and the sentence that says where (``str()`` gives it)."""

    kind: FailureKind
    """One of ``failure.CHECK_KINDS``."""
    message: str

    def __str__(self) -> str:
        return self.message


@dataclass(frozen=True)
class PointChecks:
    safety: MotionSafety
    rules: Any  # the scene's collision rules when the run started (``MotionSafety.snapshot``)
    link_padding_m: float
    gripper_position: float | None  # of the gripper joint now: the collision geometry's fingers
    grid: StepGrid

    def values(self, chunk: Chunk, window: Window) -> CheckFailure | None:
        """The values the window is built from, as the policy sent them (the gripper column
        too), against the position limits; then the gripper column from the seam on, every step
        of which may be streamed, against the gripper's position, velocity and acceleration
        limits (its join to the target before the seam is ``gripper.join_targets``')."""
        last = window.end_step - window.request_step + 1
        outside = self.safety.first_value_out_of_limits(chunk.arm[:last], None if chunk.gripper is None else chunk.gripper[:last])
        if outside is None and chunk.gripper is not None:
            seam = window.seam_step - window.request_step
            rates = self.safety.first_gripper_target_out_of_limits(chunk.gripper[seam:], self.grid.dt)
            outside = None if rates is None else replace(rates, step=rates.step + seam)
        if outside is None:
            return None
        return CheckFailure(FailureKind.of_limit(outside.quantity), f"{outside} (policy step {window.request_step + outside.step} of the run)")

    def limits(self, samples: Samples, window: Window) -> CheckFailure | None:
        violation = self.safety.first_limit_violation(samples)
        if violation is None:
            return None
        step = window.request_step + int(np.floor((violation.time - self.grid.time(window.request_step)) / self.grid.dt + 1e-9))
        return CheckFailure(FailureKind.of_limit(violation.quantity), f"densified {violation} (policy step {step} of the run)")

    def path(self, samples: Samples, window: Window) -> CheckFailure | None:
        """Limits first, then collisions."""
        violation = self.limits(samples, window)
        if violation is not None:
            return violation
        return self.collision(samples)

    def collision(self, samples: Samples) -> CheckFailure | None:
        hit = self.safety.first_collision(self.rules, samples, self.link_padding_m, self.gripper_position)
        return None if hit is None else CheckFailure(FailureKind.of_collision(hit.kind), f"densified {hit}")

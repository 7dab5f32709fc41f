"""Which points are checked, and how: the chunk's values against the joints' position limits; the
densified points of a motion (``densify``: what the checks see and the controller receives);
every densified point against the position, velocity and acceleration limits, the Cartesian envelope
and the planning scene (self-collision, and world collision with ``link_padding``). Each check
returns why the points fail, a ``CheckFailure`` (its kind, one of ``failure.CHECK_KINDS``, and a
sentence naming the run's policy step), or None. ``first_passing`` checks a planned window: the
chunk's own motion, then each of the window's endings in turn, and returns the first that passes.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ..safety import MotionSafety
from .chunk import Chunk
from .failure import FailureKind
from runtime.motion.samples import Samples
from .stream import StepGrid, Window

if TYPE_CHECKING:
    from .seam import ChunkMotion
    from .tail import Ending


@dataclass(frozen=True)
class CheckFailure:
    """Why points fail a check: its kind and the sentence that says where (``str()`` gives it)."""

    kind: FailureKind
    """One of ``failure.CHECK_KINDS``."""
    message: str

    def __str__(self) -> str:
        return self.message


class Checks(Protocol):
    """The point checks a plan must pass (``PointChecks``); each returns why it fails, or None."""

    def values(self, chunk: Chunk, window: Window) -> CheckFailure | None: ...
    def limits(self, samples: Samples, window: Window) -> CheckFailure | None: ...
    def path(self, samples: Samples, window: Window) -> CheckFailure | None: ...


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
        assert violation.time is not None  # samples are timed
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


MAX_SAMPLE_SPACING = 0.01
"""Seconds. Samples are never sparser than this, whatever ``num_interpolation_points`` says: the
checks see only the samples, and the controller interpolates between them, so a sparse window
could hide an over-speed between two points that are each within the limits."""


def densify(motion: ChunkMotion, num_points: int) -> Samples:
    """At least ``num_points`` evenly spaced samples from the seam to the end of the window
    (inclusive), and no more than ``MAX_SAMPLE_SPACING`` apart; then the extension and the
    runout, if any, at that spacing (the window's end stays a sample: the next seam)."""
    needed = int(np.ceil((motion.end - motion.seam) / MAX_SAMPLE_SPACING - 1e-9)) + 1
    times = np.linspace(motion.seam, motion.end, max(2, num_points, needed))
    tail_s = motion.rest_time - motion.end
    if tail_s > 0:
        count = int(np.ceil(tail_s / MAX_SAMPLE_SPACING - 1e-9))
        times = np.concatenate([times, motion.end + tail_s * np.arange(1, count + 1) / count])
    p, v, a = motion.evaluate(times)
    return Samples(np.asarray(times, dtype=np.float64), p, v, a)  # float64 already: typed so for numpy 2.2's stubs


@dataclass(frozen=True)
class Passed:
    """The ending of a window's motion that passed the checks, and its samples."""

    ending: Ending
    samples: Samples


def first_passing(checks: Checks, window: Window, joined: ChunkMotion, endings: list[Ending], num_points: int) -> Passed | CheckFailure:
    """The chunk's own motion over the window (``joined`` without the blend into the sent
    motion) against the limits: a chunk over the limits on its own is the policy's, and the
    join is planned within them. Then the joined motion with each of ``endings`` in turn
    (``tail.tails_to_try``) against the limits and the planning scene: the first that passes,
    or, when none does, why the first fails."""
    reason = checks.limits(densify(joined.chunk_alone(), num_points), window)
    if reason is not None:
        return reason
    first: CheckFailure | None = None
    for ending in endings:
        samples = densify(ending.motion, num_points)
        reason = checks.path(samples, window)
        if reason is None:
            return Passed(ending, samples)
        first = reason if first is None else first
    assert first is not None, "a window has at least one ending"
    return first

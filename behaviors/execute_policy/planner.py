"""Where a chunk's seam is planned: a pure function from the sent motion, the chunk and the
time to Planned / Wait / Failure (a rejected chunk). Nothing here talks to the bus or reads the clock.

``plan_chunk`` owns no formula: it asks each idea, in order, and has every densified point
checked (``PlanInput.checks``, see ``checks.PointChecks``):

1. ``at_rest``: where the window may start (a chunk that finds the arm at rest, or the earliest seam);
2. ``stream``: the window on the step grid;
3. ``checks``: the values the window is built from;
4. ``seam``: whether the chunk can still join the motion playing, or waits;
5. ``at_rest``: when its goal takes over;
6. ``shaping`` and ``seam``: the chunk's fit, joined to the sent motion at the seam;
7. ``tail``: what follows the window (its tail, cut short as far as the checks need, or a stop);
8. ``checks``: the chunk's own motion, then the joined one with each ending in turn;
9. ``stream``: the stall before the seam, and the grid after the commit.

A Planned result carries the grid after the commit; the caller keeps the grid from before it
for a rollback.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from . import at_rest, seam, tail
from .at_rest import Arrival
from .checks import CheckFailure
from .chunk import Chunk
from .failure import Failure, FailureKind
from .shaping import ShapingConfig, densify, fit_chunk
from runtime.motion.samples import Samples
from .states import GoalState, SentMotion
from .stream import Window, WindowError, drained_seconds


class Checks(Protocol):
    """The point checks a plan must pass; each returns why it fails, or None."""

    def values(self, chunk: Chunk, window: Window) -> CheckFailure | None: ...
    def limits(self, samples: Samples, window: Window) -> CheckFailure | None: ...
    def path(self, samples: Samples, window: Window) -> CheckFailure | None: ...


@dataclass(frozen=True)
class PlanInput:
    sent: SentMotion  # what the controller has been sent so far
    goal: GoalState  # of the newest goal
    chunk: Chunk
    index: int  # chunk number, 1-based
    request_step: int
    frozen: int
    earliest_seam_step: int  # the first step a goal sent now reaches the controller before
    rest_position: np.ndarray | None  # the arm's position now; needed only before the first chunk
    config: ShapingConfig
    checks: Checks
    arrival: Arrival | None = None  # when the chunk came; None: it is placed by earliest_seam_step alone


class WaitReason(enum.Enum):
    GOAL_UNANSWERED = "the controller has not answered the previous goal"
    MOTION_ENDS_FIRST = "the motion still playing ends before the chunk could join it"


@dataclass(frozen=True)
class Wait:
    reason: WaitReason


@dataclass(frozen=True)
class Planned:
    window: Window
    seam_time_s: float  # of the window's seam step
    sent: SentMotion  # once sent: the new grid, motion and samples
    stall_s: float  # the arm had left full speed (runout, then rest) this long before the seam
    takes_over_s: float  # the goal's stamp: the seam, or within its step for a first chunk (at_rest.take_over_time)


def rejected(index: int, why: CheckFailure) -> Failure:
    """Chunk ``index`` rejected for failing a check."""
    return Failure(why.kind, f"chunk {index} rejected: {why}")


def plan_chunk(inp: PlanInput) -> Planned | Wait | Failure:
    if inp.goal is GoalState.SENT:
        # Whether the controller plays the previous goal decides how this chunk joins (a refused
        # goal rolls the stream back).
        return Wait(WaitReason.GOAL_UNANSWERED)
    first: Failure | None = None
    for start in at_rest.starts(inp.sent.motion, inp.arrival, inp.sent.grid, inp.earliest_seam_step):
        plan = _plan(inp, start)
        if not isinstance(plan, Failure):
            return plan
        first = plan if first is None else first
    assert first is not None
    return first


def _plan(inp: PlanInput, start: at_rest.Start) -> Planned | Wait | Failure:
    """``plan_chunk`` with the window started at ``start``."""
    shaping, grid, chunk, index, previous = inp.config, inp.sent.grid, inp.chunk, inp.index, inp.sent.motion
    try:
        window = grid.plan_window(index, inp.request_step, inp.frozen, chunk.steps, inp.earliest_seam_step,
                                  runout_reserve=tail.runout_reserve_steps(shaping.committed_action_steps, shaping.dt),
                                  start_step=start.step)
    except WindowError as err:
        return Failure(FailureKind.SHORT_CHUNK, f"chunk {index} rejected: {err}")
    outside = inp.checks.values(chunk, window)
    if outside is not None:
        return rejected(index, outside)
    seam_time = grid.time(window.seam_step)
    if seam.motion_ends_first(previous, seam_time, inp.goal):
        return Wait(WaitReason.MOTION_ENDS_FIRST)
    takes_over = at_rest.take_over_time(seam_time, start.from_rest)
    joined = seam.join(previous, fit_chunk(chunk.arm, shaping.policy_tracking_weight), window, grid, takes_over,
                       inp.rest_position, shaping)
    endings = tail.tails_to_try(joined, chunk, window, grid.remaining - window.tail_played - window.steps, shaping)
    # A chunk over the limits on its own is the policy's; the join is planned within them.
    reason = inp.checks.limits(densify(joined.chunk_alone(), shaping.num_interpolation_points), window)
    if reason is not None:
        return rejected(index, reason)
    first: CheckFailure | None = None
    for ending_tail, motion in endings:
        samples = densify(motion, shaping.num_interpolation_points)
        reason = inp.checks.path(samples, window)
        if reason is None:
            stall = drained_seconds(None if previous is None else previous.full_speed_end, seam_time)
            new_grid = grid.with_window(window, ending_tail, chunk.steps)
            return Planned(window, seam_time, SentMotion(new_grid, motion, samples), stall, takes_over)
        first = reason if first is None else first
    assert first is not None
    return rejected(index, first)

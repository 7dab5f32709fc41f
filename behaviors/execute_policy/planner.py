"""Where a chunk's seam is planned: a pure function from the sent motion, the chunk and the
time to Planned / Wait / Failure (a rejected chunk). Nothing here talks to the bus or reads the clock.

``plan_chunk`` owns no formula: it asks each idea in turn, for each start ``at_rest.starts``
lists (a chunk that finds the arm at rest is tried at its arrival step first), until one is
not refused:

1. ``stream``: the window on the step grid (``StepGrid.plan_window``) and the grid once it is
   sent (``StepGrid.with_window``);
2. ``checks``: the values the window is built from, as the policy sent them;
3. ``seam``: when the goal takes over (``take_over_time``), whether the chunk can still join
   the motion playing (else it waits), and the chunk's fit (``step_spline.fit_chunk``) joined
   to it at the seam;
4. ``tail``: how the window ends: its tail, the tail cut short, or at rest (``tails_to_try``);
5. ``checks``: every densified point, of the chunk's own motion and of the first ending that
   passes (``first_passing``);
6. ``stream``: the stall before the seam.

A Planned result carries the grid after the commit, with the tail that passed the checks; the
caller keeps the grid from before it for a rollback.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from . import at_rest, checks, seam, tail
from .at_rest import Arrival
from .checks import CheckFailure, Checks
from .chunk import Chunk
from .config import ShapingConfig
from .failure import Failure, FailureKind
from ..action_goal import GoalState
from .states import SentMotion
from .step_spline import fit_chunk
from .stream import Window, WindowError, drained_seconds


@dataclass(frozen=True)
class PlanInput:
    sent: SentMotion  # what the controller has been sent so far
    goal: GoalState  # of the newest goal
    chunk: Chunk
    index: int  # chunk number, 1-based
    request_step: int
    frozen: int
    earliest_seam_step: int  # the first step a goal sent now reaches the controller before
    rest_position: NDArray[np.float64] | None  # the arm's position now; needed only before the first chunk
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
    takes_over_s: float  # the goal's stamp: the seam, or within its step for a first chunk (seam.take_over_time)


def plan_chunk(inp: PlanInput) -> Planned | Wait | Failure:
    if inp.goal is GoalState.SENT:
        # Whether the controller plays the previous goal decides how this chunk joins (a refused
        # goal rolls the stream back).
        return Wait(WaitReason.GOAL_UNANSWERED)
    config, grid, chunk, previous = inp.config, inp.sent.grid, inp.chunk, inp.sent.motion
    refusals: list[WindowError | CheckFailure] = []
    for start in at_rest.starts(previous, inp.arrival, grid, inp.earliest_seam_step):
        try:
            window = grid.plan_window(inp.index, inp.request_step, inp.frozen, chunk.steps, inp.earliest_seam_step,
                                      runout_reserve=tail.runout_reserve_steps(config.committed_action_steps, config.dt),
                                      start_step=start.step)
        except WindowError as err:
            refusals.append(err)
            continue
        after = grid.with_window(window, chunk_steps=chunk.steps)  # its tail comes with the checks
        outside = inp.checks.values(chunk, window)
        if outside is not None:
            refusals.append(outside)
            continue
        seam_time = grid.time(window.seam_step)
        takes_over = seam.take_over_time(seam_time, start.from_rest)
        if seam.motion_ends_first(previous, seam_time, inp.goal):
            return Wait(WaitReason.MOTION_ENDS_FIRST)
        joined = seam.join(previous, fit_chunk(chunk.arm, config.policy_tracking_weight), window, grid, takes_over,
                           inp.rest_position, config)
        endings = tail.tails_to_try(joined, chunk, window, grid.remaining - window.tail_played - window.steps, config)
        passed = checks.first_passing(inp.checks, window, joined, endings, config.num_interpolation_points)
        if isinstance(passed, CheckFailure):
            refusals.append(passed)
            continue
        stall = drained_seconds(None if previous is None else previous.full_speed_end, seam_time)
        sent = SentMotion(replace(after, tail=passed.ending.tail), passed.ending.motion, passed.samples)
        return Planned(window, seam_time, sent, stall, takes_over)
    # Every start refused: the first start's reason is the chunk's.
    why = refusals[0]
    return Failure(FailureKind.SHORT_CHUNK if isinstance(why, WindowError) else why.kind, f"chunk {inp.index} rejected: {why}")

"""Bookkeeping of one run's step grid: requests, seams and windows sent. Pure state.

Step ``n`` of the run happens at ``origin_s + n * dt`` (origin_s = the first real request). A chunk
requested at step ``r`` covers steps ``r, r+1, ...``; it takes over at its seam step and
contributes a window of at most ``committed_action_steps`` steps; the next chunk
takes over where that window ends. Nothing here talks to the bus or the clock.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from runtime.errors import ObjectiveError

from .tail import NO_TAIL, Tail, tail_progress

if TYPE_CHECKING:
    from .states import SentMotion


@dataclass(frozen=True)
class Window:
    """The part of one chunk that is executed: chunk steps ``[seam - request, ... + steps]``."""

    index: int  # chunk number, 1-based (the warmup is not counted)
    request_step: int  # the run step where the chunk's step 0 is played (its request, or shifted)
    seam_step: int
    steps: int
    tail_played: int = 0
    """Steps of the previous chunk beyond its window (its tail) the arm played before this seam:
    executed steps of the run, like the window's."""

    @property
    def end_step(self) -> int:
        return self.seam_step + self.steps

    @property
    def first_chunk_step(self) -> int:
        """Index, inside the chunk, of the step at the seam."""
        return self.seam_step - self.request_step


def drained_seconds(motion_end: float | None, until: float) -> float:
    """Seconds by ``until`` that the sent motion (ending at ``motion_end``; None before the
    first chunk) has been drained: the arm in the runout, then at rest, waiting for a chunk."""
    return 0.0 if motion_end is None else max(0.0, until - motion_end)


def stall_at_stop_s(sent: SentMotion | None, now_s: float) -> float:
    """The wait so far when the run ends while the arm waits for a chunk (a stall too)."""
    if sent is None or sent.grid.remaining == 0 or sent.motion is None:
        return 0.0
    return drained_seconds(sent.motion.full_speed_end, now_s)


class WindowError(ObjectiveError, ValueError):
    pass


@dataclass(frozen=True)
class StepGrid:
    """The run's step grid and the windows sent on it. Immutable: ``with_window`` returns the
    grid after a window, so the grid from before it is what a rollback goes back to."""

    origin_s: float
    dt: float
    window_steps: int  # the most steps a window takes from its chunk (``committed_action_steps``)
    total_steps: int
    sent_end: int = 0  # step where the sent motion ends (the next seam)
    executed_until: int = 0  # steps sent so far (the windows, and the tail steps played before late seams)
    seam_step: int = 0  # where the last window sent took over
    tail: Tail = NO_TAIL  # what the arm plays after sent_end when no chunk takes over there
    chunk_steps: int = 0  # steps of the last chunk sent

    def time(self, step: int) -> float:
        return self.origin_s + step * self.dt

    def step_at_or_after(self, t: float) -> int:
        return max(0, math.ceil((t - self.origin_s) / self.dt - 1e-9))

    def step_at_or_before(self, t: float) -> int:
        return max(0, math.floor((t - self.origin_s) / self.dt + 1e-9))

    @property
    def remaining(self) -> int:
        return self.total_steps - self.executed_until

    def ideal_request_step(self, frozen: int) -> int:
        """Request this step so that the chunk lands ``frozen`` steps later, at the next seam.

        When that step was already behind the window's seam (the latency is longer than the
        window), the chunk will be late whenever it is asked for, and joins the tail. It is then
        asked for ``frozen`` steps before the tail's extension ends, so that it lands as the arm
        starts slowing down. When the latency is longer than half a chunk and the runout (more
        than ``half_chunk + runout`` steps), such a request would observe the arm early on the
        chunk being played, and its chunk would add little beyond it: the request is then due
        once half a chunk is left, as LeRobot's async client asks (the arm pauses, but each chunk
        takes it about half a chunk further)."""
        on_time = self.sent_end - frozen
        if on_time >= self.seam_step or self.tail.steps == 0:
            return on_time
        full_speed_end = self.sent_end + self.tail.extension_steps
        half_chunk = self.chunk_steps // 2
        if frozen <= half_chunk + self.tail.runout_steps:
            return max(on_time, full_speed_end - frozen)
        return max(on_time, full_speed_end + self.tail.runout_steps - half_chunk)

    def plan_window(self, index: int, request_step: int, frozen: int, chunk_steps: int, earliest_seam: int,
                    runout_reserve: int = 0, start_step: int | None = None) -> Window:
        """The window a chunk of ``chunk_steps`` steps requested at ``request_step`` executes,
        given the first step it can still join at (``earliest_seam``, from its arrival). A late
        chunk's window leaves ``runout_reserve`` steps of the chunk for its own runout.
        ``start_step`` (None: ``earliest_seam``) is where a chunk that does not take over at the
        end of the sent motion starts: for one that finds the arm at rest, ``at_rest.from_rest_seam``.

        Raises WindowError when the chunk ends before the seam.
        """
        # The chunk takes over where the sent motion ends (normally request + frozen prefix);
        # the frozen prefix is only the estimate sent to the policy, so a chunk that arrives early
        # after a late request still joins there. A chunk that arrives later starts at the first
        # step it can: the first chunk from rest, a later one during the previous window's runout
        # or after it, at rest. It is played from the chunk step that matches how far the arm got
        # along the previous chunk rather than from the step the clock says, so the arm does not
        # have to catch up on steps it never moved through.
        on_time = index > 1 and earliest_seam <= self.sent_end
        if on_time:
            seam = self.sent_end
        else:
            seam = max(self.sent_end, earliest_seam if start_step is None else start_step)
        played = 0
        if not on_time:
            reached = 0
            if index > 1:
                played = tail_progress(seam - self.sent_end, self.tail.extension_steps, self.tail.runout_steps)
                reached = self.sent_end + played - request_step
            request_step = seam - max(0, reached)  # the chunk's time line, shifted to start at the arm's state
        # A chunk with N steps has positions up to chunk step N-1: the window needs its end point.
        available = request_step + chunk_steps - 1 - seam
        if not on_time and available - runout_reserve >= 1:
            available -= runout_reserve
        steps = min(self.window_steps, self.remaining - played, available)
        if steps < 1:
            raise WindowError(
                f"chunk {index} has {chunk_steps} steps but takes over at its step {seam - request_step} "
                f"(frozen prefix {frozen} steps plus arrival delay): nothing is left to execute"
            )
        return Window(index, request_step, seam, steps, played)

    def steps_executed_by(self, t: float) -> int:
        """Steps the arm has played by ``t``: of the windows sent (the steps after ``t`` of
        the last window are not), then of the last window's tail."""
        now = self.step_at_or_before(t)
        if now <= self.sent_end:
            return self.executed_until - (self.sent_end - now)
        return self.executed_until + tail_progress(now - self.sent_end, self.tail.extension_steps, self.tail.runout_steps)

    def with_window(self, window: Window, tail: Tail = NO_TAIL, chunk_steps: int = 0) -> StepGrid:
        """The grid once ``window`` (of a chunk of ``chunk_steps`` steps) is sent, followed by
        ``tail``. The planner makes it with the window and sets the ``tail`` its checks pass."""
        return replace(self, sent_end=window.end_step, executed_until=self.executed_until + window.tail_played + window.steps,
                       seam_step=window.seam_step, tail=tail, chunk_steps=chunk_steps)

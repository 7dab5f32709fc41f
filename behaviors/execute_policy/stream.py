"""Bookkeeping of one run's step grid: requests, seams and committed windows. Pure state.

Step ``n`` of the run happens at ``origin + n * dt`` (origin = the first real request). A chunk
requested at step ``r`` covers steps ``r, r+1, ...``; it takes over at its seam step and
contributes a committed window of at most ``committed_action_steps`` steps; the next chunk
takes over where that window ends. Nothing here talks to the bus or the clock.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Window:
    """The part of one chunk that is executed: chunk steps ``[seam - request, ... + steps]``."""

    index: int  # chunk number, 1-based (the warmup is not counted)
    request_step: int
    seam_step: int
    steps: int

    @property
    def end_step(self) -> int:
        return self.seam_step + self.steps

    @property
    def first_chunk_step(self) -> int:
        """Index, inside the chunk, of the step at the seam."""
        return self.seam_step - self.request_step


class WindowError(ValueError):
    pass


@dataclass
class StepGrid:
    origin: float
    dt: float
    committed_steps: int
    total_steps: int
    committed_end: int = 0  # step where the committed motion ends (the next seam)
    executed_until: int = 0  # steps committed so far (sum of windows)

    def time(self, step: int) -> float:
        return self.origin + step * self.dt

    def step_at_or_after(self, t: float) -> int:
        return max(0, math.ceil((t - self.origin) / self.dt - 1e-9))

    def step_at_or_before(self, t: float) -> int:
        return max(0, math.floor((t - self.origin) / self.dt + 1e-9))

    @property
    def remaining(self) -> int:
        return self.total_steps - self.executed_until

    def ideal_request_step(self, frozen: int) -> int:
        """Request this step so that the chunk lands ``frozen`` steps later, at the next seam."""
        return self.committed_end - frozen

    def plan_window(self, index: int, request_step: int, frozen: int, chunk_steps: int, earliest_seam: int) -> Window:
        """The window a chunk of ``chunk_steps`` steps requested at ``request_step`` executes,
        given the first step it can still join at (``earliest_seam``, from its arrival).

        Raises WindowError when the chunk ends before the seam.
        """
        # The chunk takes over where the committed motion ends (normally request + frozen prefix);
        # a chunk that arrives after that starts at the first step it can (the robot paused).
        # The frozen prefix is only the estimate sent to the policy: a chunk that arrives early
        # after a late request still joins at the end of the committed motion.
        seam = max(earliest_seam, self.committed_end if index > 1 else request_step)
        # A chunk with N steps has positions up to chunk step N-1: the window needs its end point.
        available = request_step + chunk_steps - 1 - seam
        steps = min(self.committed_steps, self.remaining, available)
        if steps < 1:
            raise WindowError(
                f"chunk {index} has {chunk_steps} steps but takes over at its step {seam - request_step} "
                f"(frozen prefix {frozen} steps plus arrival delay): nothing is left to execute"
            )
        return Window(index, request_step, seam, steps)

    def commit(self, window: Window) -> None:
        self.committed_end = window.end_step
        self.executed_until += window.steps

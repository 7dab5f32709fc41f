"""Timing: the latency estimate, when to ask for the next chunk, how many of its steps are
frozen, and when a goal sent now takes effect. Pure arithmetic.

All instants are on the run's step grid: step ``n`` happens at ``start + n * dt``. A request made
at step ``r`` gets a chunk whose step 0 is step ``r``; the steps that elapse while the call is
in flight are its frozen prefix, and the chunk takes over at the seam ``r + frozen``.
"""
from __future__ import annotations

import enum
import math
from collections import deque
from typing import TYPE_CHECKING, Sequence

if TYPE_CHECKING:
    from .stream import StepGrid

LATENCY_WINDOW_CALLS = 20
"""Round trips the latency estimate looks back over (the warmup's included while it is among them)."""
LATENCY_QUANTILE = 0.9
"""The estimate is this quantile (nearest rank) of the recent round trips."""


def nearest_rank_quantile(values: Sequence[float], quantile: float) -> float:
    """The smallest of ``values`` that at least ``quantile`` of them do not exceed (0.0 for none).

    With fewer than ``1 / (1 - quantile)`` values that is the largest one: too few calls have been
    seen to call any of them an outlier.
    """
    if not values:
        return 0.0
    ordered = sorted(values)
    rank = max(1, math.ceil(round(quantile * len(ordered), 9)))
    return ordered[min(rank, len(ordered)) - 1]


class LatencyEstimate:
    """A high quantile of the recent policy round trips: what the next request is timed for.

    The estimate is the 90th percentile (nearest rank) of the last 20 round trips. While fewer
    than 10 have been seen it is the slowest of them, so an early slow call (a warmup that paid
    for compilation, a spike) is covered at once; it stops counting once it is less than one in
    ten, and for good when it leaves the window, so the estimate comes back down after an outlier.
    Latencies that recur (more than one in ten of the recent round trips) keep it up.
    """

    def __init__(self, window_calls: int = LATENCY_WINDOW_CALLS, quantile: float = LATENCY_QUANTILE) -> None:
        self.quantile = quantile
        self.recent: deque[float] = deque(maxlen=window_calls)
        self.seconds = 0.0

    def update(self, seconds: float) -> None:
        self.recent.append(seconds)
        self.seconds = nearest_rank_quantile(self.recent, self.quantile)


def frozen_prefix_steps(latency_s: float, dt: float, margin_s: float) -> int:
    """Steps that elapse between the request instant and the chunk's arrival, rounded up."""
    return max(1, math.ceil((latency_s + margin_s) / dt - 1e-9))


def prefetch_margin(latency_s: float, tick_period_s: float, goal_latency_s: float) -> float:
    """Slack added to the latency estimate: two ticks plus a tenth of the estimate, plus twice
    the goal delivery time (the chunk's goal must reach the controller by the seam)."""
    return 2.0 * tick_period_s + 0.1 * latency_s + 2 * goal_latency_s


def next_request_step(grid: StepGrid, frozen: int, now_s: float) -> int | None:
    """The step to request the next chunk for, once it is due (so it lands ``frozen`` steps
    later, at the next seam; ``StepGrid.ideal_request_step``); None before then. A late request
    asks for the step of now."""
    ideal = grid.ideal_request_step(frozen)
    if now_s + 1e-9 < grid.time(ideal):
        return None
    return max(ideal, grid.step_at_or_before(now_s))


def goal_takes_effect_s(now_s: float, tick_period_s: float, goal_latency_s: float) -> float:
    """The earliest instant a goal sent now surely takes effect: it must reach the controller
    first, so one tick plus twice the goal delivery time seen so far (zero in process; over ROS,
    transport and the next spin)."""
    return now_s + tick_period_s + 2 * goal_latency_s


def earliest_seam_step(grid: StepGrid, now_s: float, tick_period_s: float, goal_latency_s: float) -> int:
    """The first step a goal sent now can take over at (``goal_takes_effect_s``)."""
    return grid.step_at_or_after(goal_takes_effect_s(now_s, tick_period_s, goal_latency_s))


def window_covers_latency(window_steps: int, dt: float, latency_s: float) -> bool:
    """The guide's sizing rule: ``(committed_action_steps - 1) * dt >= 2 * latency``."""
    return (window_steps - 1) * dt >= 2.0 * latency_s


class SizingRisk(enum.IntEnum):
    """What a latency means for a run, worst last: the guide's sizing rule holds; it fails, but
    the chunk's steps beyond the window (the tail) keep the arm moving until the next chunk
    lands; or pauses at chunk boundaries are to be expected."""

    COVERED = 0
    TAIL_COVERS = 1
    PAUSES = 2


def sizing_risk(window_steps: int, dt: float, latency_s: float, chunk_steps: int | None) -> SizingRisk:
    """The risk of ``latency_s`` with chunks of ``chunk_steps`` (None: not known yet). With one
    request in flight the tail keeps the arm moving while the latency is at most about half the
    chunk's duration (docs/execute-policy.md, Latency beyond the window)."""
    if window_covers_latency(window_steps, dt, latency_s):
        return SizingRisk.COVERED
    if chunk_steps is not None and chunk_steps > window_steps and latency_s <= chunk_steps * dt / 2.0:
        return SizingRisk.TAIL_COVERS
    return SizingRisk.PAUSES


def sizing_warning(window_steps: int, dt: float, latency_s: float, what: str, detail: str = "",
                   chunk_steps: int | None = None) -> str | None:
    """The sizing warning, with the figures, when ``latency_s`` (``what``: where the figure comes
    from, ``detail``: how it was made) is more than the window (``committed_action_steps``) covers; else None.
    ``chunk_steps`` (the policy's chunk size, None: not known) says whether the tail covers it."""
    risk = sizing_risk(window_steps, dt, latency_s, chunk_steps)
    if risk is SizingRisk.COVERED:
        return None
    needed = math.ceil(2.0 * latency_s / dt - 1e-9) + 1
    head = (f"(committed_action_steps - 1) * dt = {(window_steps - 1) * dt:.3f} s is below twice the {what} "
            f"{latency_s:.3f} s{detail}")
    if chunk_steps is not None and needed >= chunk_steps:
        fix = f"covering it would take committed_action_steps = {needed}, not below the chunk's {chunk_steps} steps: a faster policy or longer chunks"
    else:
        fix = f"committed_action_steps = {needed} would cover it"
    if risk is SizingRisk.TAIL_COVERS:
        assert chunk_steps is not None
        return (f"{head}: chunks land after their committed window ends; the arm goes on along the chunk's steps "
                f"beyond the window meanwhile, and pauses only once the latency passes about {chunk_steps * dt / 2.0:.3f} s, "
                f"half the {chunk_steps}-step chunk ({fix})")
    if chunk_steps is not None and chunk_steps > window_steps:
        head += f" and longer than half the {chunk_steps}-step chunk ({chunk_steps * dt / 2.0:.3f} s)"
    return f"{head}: expect pauses at chunk boundaries ({fix})"

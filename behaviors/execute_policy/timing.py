"""When to ask for the next chunk, and how many of its steps are frozen. Pure arithmetic.

All instants are on the run's step grid: step ``n`` happens at ``start + n * dt``. A request made
at step ``r`` gets a chunk whose step 0 is step ``r``; the steps that elapse while the call is
in flight are its frozen prefix, and the chunk takes over at the seam ``r + frozen``.
"""
from __future__ import annotations

import math


class LatencyEstimate:
    """The largest round trip seen so far: it only ever grows (one slow call is remembered)."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self.samples: list[float] = []

    def update(self, seconds: float) -> None:
        self.samples.append(seconds)
        self.seconds = max(self.seconds, seconds)


def frozen_prefix_steps(latency_s: float, dt: float, margin_s: float) -> int:
    """Steps that elapse between the request instant and the chunk's arrival, rounded up."""
    return max(1, math.ceil((latency_s + margin_s) / dt - 1e-9))


def prefetch_margin(latency_s: float, tick_period: float) -> float:
    """Slack added to the latency estimate: two ticks plus a tenth of the estimate."""
    return 2.0 * tick_period + 0.1 * latency_s


def window_covers_latency(committed_steps: int, dt: float, latency_s: float) -> bool:
    """The guide's sizing rule: ``(committed_action_steps - 1) * dt >= 2 * latency``."""
    return (committed_steps - 1) * dt >= 2.0 * latency_s

"""Time for behaviors: every behavior reads the runtime clock, never ``time.time()``.

Two clocks share one tiny interface. ``SimClock`` is advanced explicitly by the runner, so a
headless run goes as fast as the CPU allows and is deterministic. ``WallClock`` follows real time
(for a policy on real ROS 2 or a real robot); the runner sleeps to keep the tick rate.
"""
from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """Seconds since the run started."""

    def now(self) -> float: ...

    def advance(self, dt: float) -> None:
        """Move time forward by ``dt`` (a SimClock jumps, a WallClock sleeps until then)."""
        ...


class SimClock:
    """Simulated time: only moves when the runner advances it."""

    def __init__(self, start: float = 0.0) -> None:
        self._now = float(start)

    def now(self) -> float:
        return self._now

    def advance(self, dt: float) -> None:
        if dt < 0:
            raise ValueError(f"SimClock cannot go backwards (dt={dt})")
        self._now += dt

    def __repr__(self) -> str:
        return f"SimClock(now={self._now:.6f})"


class WallClock:
    """Real time since construction; ``advance`` sleeps until the target instant."""

    def __init__(self) -> None:
        self._start = time.monotonic()
        self._target = 0.0

    def now(self) -> float:
        return time.monotonic() - self._start

    def sync(self, now: float) -> None:
        """Read ``now`` at this instant and go on from there (a run that follows another
        process's clock, such as a simulated robot's ``/clock``)."""
        self._start = time.monotonic() - now
        self._target = now

    def catch_up(self, now: float) -> None:
        """Jump forward to ``now`` if it is ahead of this clock, never back (a later reading of
        the clock this run follows: one read while its publisher was starved is late, the
        freshest is nearest)."""
        ahead = now - self.now()
        if ahead > 0.0:
            self._start -= ahead
            self._target += ahead

    def advance(self, dt: float) -> None:
        self._target = max(self._target + dt, self.now() - dt)  # never accumulate a backlog
        delay = self._target - self.now()
        if delay > 0:
            time.sleep(delay)

    def __repr__(self) -> str:
        return f"WallClock(now={self.now():.6f})"


def next_due(due: float, period: float, now: float) -> float:
    """When the next message of a topic published every ``period`` is due, one having been
    published at ``now`` for ``due``: a period on, or a period from now when that is already past
    (never a burst to catch up)."""
    following = due + period
    return following if following > now else now + period

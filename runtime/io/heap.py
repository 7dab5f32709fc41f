"""The Python heap during a paced loop: garbage is collected between ticks, never inside one.

CPython's cyclic collector runs whenever enough objects were allocated, wherever that happens:
inside a tick, on any thread. A full collection walks every tracked object, and a run starts with
hundreds of thousands of them (the robot model, the planning scene, rclpy, numpy, message
classes): 50-130 ms measured on this project's machines, one late tick each time. A young
collection after a tick that built a trajectory goal takes 5-8 ms.

``PacedHeap`` therefore, for the duration of a paced loop:
- collects once and freezes what is left (``gc.freeze``: moved to a permanent generation that no
  collection walks), so collections only walk what the loop itself made;
- turns automatic collection off, and collects in ``between_ticks()``, which the loop calls after
  a tick's work, before it sleeps until the next one: the youngest generation after every tick,
  the middle one every ``MIDDLE_EVERY`` ticks, the oldest (what the loop made and kept) every
  ``OLDEST_EVERY`` ticks;
- on leaving, turns collection back on and gives the frozen objects back to the oldest
  generation (``gc.unfreeze``), so a process that runs many loops (``objective server``, an
  evaluation worker) still collects what a finished run left behind.

A caller that turned the collector off (``gc.disable()``) keeps it off: nothing is done then.
"""
from __future__ import annotations

import gc
from types import TracebackType

MIDDLE_EVERY = 10
"""Ticks between collections of the middle generation (CPython's own ratio between generations)."""
OLDEST_EVERY = 1000
"""Ticks between collections of the oldest generation (ten seconds at 100 Hz): it walks everything
the loop made and kept, 10-30 ms in a ``stack_cubes.xml`` run on ROS 2, time the next tick's start
may have to wait for."""


class PacedHeap:
    """``with PacedHeap(): while ...: tick(); heap.between_ticks(); sleep()``."""

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled
        self.ticks = 0
        self._active = False

    def __enter__(self) -> PacedHeap:
        self._active = self.enabled and gc.isenabled()
        if self._active:
            gc.collect()
            gc.freeze()
            gc.disable()
        return self

    def between_ticks(self) -> None:
        """Collect what the tick left, by the cadence above (nothing when not active)."""
        if not self._active:
            return
        self.ticks += 1
        if self.ticks % OLDEST_EVERY == 0:
            gc.collect(2)
        elif self.ticks % MIDDLE_EVERY == 0:
            gc.collect(1)
        else:
            gc.collect(0)

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None) -> None:
        if self._active:
            self._active = False
            gc.enable()
            gc.unfreeze()

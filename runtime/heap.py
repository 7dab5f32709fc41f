"""The Python heap during a paced loop: what is alive when the loop starts is kept out of the
cyclic garbage collector's way.

CPython's collector walks every tracked object of a generation when it collects it. A run
starts with hundreds of thousands of them (the robot model, the planning scene, rclpy, numpy,
message classes), so a full collection in the middle of a run stops every thread for 50-130 ms
on this project's machines: one collection, one late tick. ``frozen_heap()`` collects once before
the loop and then freezes what is left (``gc.freeze``: moved to a permanent generation that no
collection walks), so the collections during the loop only walk what the loop itself made.
On leaving, the frozen objects go back to the oldest generation (``gc.unfreeze``), so a process
that runs many loops (``objective server``, an evaluation worker) still collects what a finished
run left behind.
"""
from __future__ import annotations

import contextlib
import gc
from typing import Iterator


@contextlib.contextmanager
def frozen_heap(enabled: bool = True) -> Iterator[None]:
    """Collect, then freeze the heap for the ``with`` body; nothing when ``enabled`` is False or
    the caller turned the collector off (``gc.disable()``: their choice is kept)."""
    if not enabled or not gc.isenabled():
        yield
        return
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()

"""``ServiceWorker``: the thread of one service whose handler must not run on the tick's thread.

A paced run (``--realtime``, ``--ros``) ticks its tree every 10 ms on one thread, and the buses
that run server callbacks on that thread (``InProcessBus``, a ``RosBus`` with
``serve_in_spin_once``) would make the tick wait for every handler. Most handlers take
microseconds; a policy's inference takes tens of milliseconds to seconds (the scripted oracle
plans for about a second on its first request). Such a service is created with
``own_thread=True``, and the bus hands its requests to a ``ServiceWorker``: the calls run on the
worker's thread in the order they came, one at a time (as a server with one model answers), and
the bus delivers each answer to its caller when the call is done, as an answer from a server in
another process arrives late.

On a simulated clock the in-process bus runs such a service on a worker too, and the call waits
for it (the clock standing still), at most for the caller's timeout (``runtime.io.bus``).

The bus that made a worker owns it and closes it when the service or the bus goes away:
``close`` drops the calls not started and waits at most ``STOP_WAIT_S`` for the one in
progress. A handler cannot be interrupted, so one that runs longer is left to finish on its own
(the thread is a daemon: it never keeps the process alive) and its answer is dropped.
"""
from __future__ import annotations

import collections
import logging
import threading
from typing import Callable

STOP_WAIT_S = 2.0
"""How long ``close`` waits for the call in progress."""

log = logging.getLogger("objective")


class ServiceWorker:
    """Runs the calls handed to it (``submit``) on a thread of its own, one at a time, in order."""

    def __init__(self, service_name: str) -> None:
        self.service_name = service_name
        self._calls: collections.deque[Callable[[], None]] = collections.deque()
        self._wake = threading.Condition()
        self._closing = False
        self._thread = threading.Thread(target=self._run, name=f"service {service_name}", daemon=True)
        self._thread.start()

    def submit(self, call: Callable[[], None]) -> None:
        """Run ``call()`` after the calls submitted before it; dropped once the worker is closing.
        ``call`` hands its outcome over itself (the bus's delivery queue, an event)."""
        with self._wake:
            if self._closing:
                return
            self._calls.append(call)
            self._wake.notify()

    def close(self, timeout_s: float = STOP_WAIT_S) -> bool:
        """Drop the calls not started and stop the thread; False when the call in progress still
        ran after ``timeout_s`` (it finishes on its own, unheard). Idempotent."""
        with self._wake:
            self._closing = True
            self._calls.clear()
            self._wake.notify()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            log.warning("service '%s': its handler still runs after %g s; its answer is dropped", self.service_name, timeout_s)
            return False
        return True

    def _run(self) -> None:
        while True:
            with self._wake:
                while not self._calls and not self._closing:
                    self._wake.wait()
                if self._closing:
                    return
                call = self._calls.popleft()
            try:
                call()
            except Exception:  # a call hands its own errors over; this is a bug, and the service goes on
                log.exception("service '%s': a call failed on its worker", self.service_name)

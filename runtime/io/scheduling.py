"""Real-time scheduling of the thread that ticks a paced loop (``--realtime-priority N``).

On a machine that runs more than the runtime (a simulated robot, a policy server, a recorder,
anything else), the kernel's fair scheduler shares a core between them, and a tick that needs
15 ms of CPU can take 40 ms of wall time. As ros2_control's controller manager does for its
update loop, the tick thread can ask for ``SCHED_FIFO`` at a priority (1-99): it then runs
whenever it is ready, ahead of every ordinary process. It sleeps between ticks, so the others
keep the rest of the CPU (and Linux keeps 5 % of every second for them in any case).

Asking needs the right to: root, ``CAP_SYS_NICE``, or an ``rtprio`` limit for the user (for
example ``@realtime - rtprio 99`` in ``/etc/security/limits.conf``, the set-up ros2_control's
documentation gives). Without it the run goes on at the default priority with one warning that
says so: a robot computer that was not set up for real time still runs, only less punctually.

Only the calling thread changes (Linux schedules threads, not processes): the ROS executors, the
camera thread and a hosted policy's worker keep the default priority, except threads the tick
thread itself starts while it holds the priority, which inherit it.
"""
from __future__ import annotations

import contextlib
import logging
import os
from typing import Iterator

LOG = logging.getLogger("objective.scheduling")
PRIORITY_RANGE = (1, 99)
"""SCHED_FIFO priorities Linux accepts."""
SETUP_HINT = ("run as root, or give the user an rtprio limit (e.g. '@realtime - rtprio 99' in "
              "/etc/security/limits.conf, as ros2_control's controller manager needs)")


def check_priority(priority: int) -> str | None:
    """What is wrong with ``priority`` as a SCHED_FIFO priority (None: nothing)."""
    low, high = PRIORITY_RANGE
    if isinstance(priority, bool) or not isinstance(priority, int) or not low <= priority <= high:
        return f"a real-time priority must be an integer from {low} to {high}, got {priority!r}"
    return None


@contextlib.contextmanager
def realtime_priority(priority: int | None) -> Iterator[str]:
    """Run the ``with`` body on this thread at SCHED_FIFO ``priority`` (None: unchanged) and
    restore the thread's scheduling after. Yields what the thread runs at, for the run's
    summary: ``"SCHED_FIFO 50"``, or ``"default"`` (with the reason when it was refused)."""
    if priority is None:
        yield "default"
        return
    problem = check_priority(priority)
    if problem is not None:
        raise ValueError(problem)
    if not hasattr(os, "sched_setscheduler"):
        LOG.warning("real-time priority %d not available on this platform: ticking at the default priority", priority)
        yield "default (SCHED_FIFO not available on this platform)"
        return
    before_policy, before_param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as err:
        LOG.warning("could not tick at real-time priority %d (SCHED_FIFO): %s; ticking at the default priority (%s)",
                    priority, err.strerror, SETUP_HINT)
        yield f"default (SCHED_FIFO {priority} refused: {err.strerror})"
        return
    try:
        yield f"SCHED_FIFO {priority}"
    finally:
        os.sched_setscheduler(0, before_policy, before_param)

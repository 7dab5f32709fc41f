"""SIGINT and SIGTERM during a run: stop at the next tick, as a preemption.

``stop_on_signals`` installs handlers for both signals while a run lasts. The first signal only
sets ``StopRequest.signum``; the runner looks at it before every tick, halts the tree (RUNNING
nodes get ``terminate(INVALID)``: goals cancelled, the robot stopped), finishes the recording
and reports ``INTERRUPTED``. A signal that arrives when waiting would be pointless raises
``Interrupted`` at once instead: a second signal (the first one is not being honoured fast
enough), or any signal once ``StopRequest.urgent`` is set (the tick loop is over). Inside
``StopRequest.held_back`` (a recording's end) a signal waits until the step is done.

The exit code of an interrupted run is the shell's: 128 + the signal number (130 for SIGINT,
143 for SIGTERM).
"""
from __future__ import annotations

import contextlib
import signal
import threading
from dataclasses import dataclass
from typing import Any, Iterator

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """Raised by the handler when a signal must stop whatever runs now."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal_name(signum))
        self.signum = signum


def raised_by_code(error: BaseException) -> bool:
    """Whether ``error`` is a fault of the code that raised it, to be reported as that code's
    error: any Exception, and a SystemExit or KeyboardInterrupt that a policy or a plug-in raised
    itself (``sys.exit(7)``, ``raise KeyboardInterrupt``). A signal's ``Interrupted`` is not: it
    stops the run."""
    return isinstance(error, (Exception, SystemExit, KeyboardInterrupt)) and not isinstance(error, Interrupted)


def describe_error(error: BaseException) -> str:
    """``Type: message`` (``SystemExit: 7``), or the type alone when it has no message."""
    text = str(error)
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def exit_code_for(signum: int) -> int:
    """The exit status a shell reports for a process the signal ended: 128 + its number."""
    return 128 + int(signum)


@dataclass
class StopRequest:
    """What the signal handlers tell the runner (see the module doc)."""

    signum: int | None = None
    urgent: bool = False
    held: int | None = None
    """A signal that arrived inside ``held_back`` (handled on the way out)."""
    holding: bool = False
    cause: str | None = None
    """Who asked the run to stop when it was not a signal (``cancel``); the run's reason says it."""

    @property
    def requested(self) -> bool:
        return self.signum is not None

    def cancel(self, cause: str) -> None:
        """Stop the run at the next tick as SIGINT does (halted, INTERRUPTED), for ``cause``
        (e.g. "cancelled by an action client") rather than a signal; callable from any thread."""
        self.cause = cause
        self.signum = signal.SIGINT

    def on_signal(self, signum: int, frame: Any = None) -> None:
        if self.holding:
            self.held = signum
            return
        if self.urgent or self.signum is not None:
            self.signum = self.signum or signum
            raise Interrupted(signum)
        self.signum = signum

    @contextlib.contextmanager
    def held_back(self) -> Iterator[None]:
        """Inside, a signal is only noted; on the way out it is handled as if it arrived then
        (``Interrupted`` when it must stop what runs). For steps that must not be cut in half:
        the end of a recording, a summary being written."""
        self.holding = True
        try:
            yield
        finally:
            self.holding = False
        signum, self.held = self.held, None
        if signum is not None:
            self.on_signal(signum)


def held_back(stop: StopRequest | None) -> contextlib.AbstractContextManager[None]:
    """``stop.held_back()``, or nothing without a ``StopRequest``."""
    return stop.held_back() if stop is not None else contextlib.nullcontext()


@contextlib.contextmanager
def stop_on_signals(stop: StopRequest) -> Iterator[StopRequest]:
    """While inside, SIGINT and SIGTERM go to ``stop.on_signal``; the previous handlers come back after.

    Outside the main thread Python cannot install signal handlers; then nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {signum: signal.signal(signum, stop.on_signal) for signum in STOP_SIGNALS}
    try:
        yield stop
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)

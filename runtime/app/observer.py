"""What watches a run from outside the engine: the recording (``--record DIR``, ``--live``).

A package attaches a run observer by naming a factory in the ``objective.run_observers``
entry-point group, as worlds attach through ``objective.worlds``; the engine imports none of
them. ``runtime.app.runner.run_file`` asks the group only when ``RunOptions.observed`` (a run to
record or to serve live), so a plain run loads nothing of it.

    factory(loaded, context, options) -> RunObserver | None   (None: nothing to do for these options)

The factory is called once the tree is loaded and before the world starts, so it may wrap
``context.bus`` to see every message. The observer is then told how the run ended
(``finished``) or that it never got to a result (``aborted``: the world could not start, a
signal while loading); either call ends its work.
"""
from __future__ import annotations

from importlib.metadata import entry_points
from typing import TYPE_CHECKING, Any, Protocol

from runtime.errors import ObjectiveError
from runtime.extras import load_entry_point

if TYPE_CHECKING:
    from runtime.io.interrupt import StopRequest

OBSERVER_GROUP = "objective.run_observers"


class RunObserver(Protocol):
    def finished(self, result: Any, stop: "StopRequest | None") -> None:
        """The run ended with ``result`` (a ``RunResult``); ``stop`` still reaches signals meanwhile."""

    def aborted(self, error: BaseException, stop: "StopRequest | None") -> None:
        """The run raised ``error`` before it had a result; the runner raises it on afterwards."""


def attach_observers(loaded: Any, context: Any, options: Any) -> list[RunObserver]:
    """The observers the installed packages attach to this run; ObjectiveError when none does
    what the options ask for (the recording package or its dependencies are not installed)."""
    observers = []
    for ep in sorted(entry_points(group=OBSERVER_GROUP), key=lambda e: e.name):
        factory = load_entry_point(ep, f"run observer '{ep.name}'")
        observer = factory(loaded, context, options)
        if observer is not None:
            observers.append(observer)
    if not observers:
        raise ObjectiveError("--record and --live need the recording package, which is not installed: "
                             "pip install 'objective-runtime[record]'")
    return observers

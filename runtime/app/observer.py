"""What watches a run: the progress line, the Groot2 monitor, the Objective server's feedback, the
recording (``--record DIR``, ``--live``). Each is a ``RunObserver``, and the runner
(``runtime.app.runner.RunLoop``) tells every observer of a run what happens to it.

A package attaches a run observer by naming a factory in the ``objective.run_observers``
entry-point group, as worlds attach through ``objective.worlds``; the engine imports none of
them. ``runtime.app.runner.run_loaded`` asks the group only when ``RunOptions.observed`` (a run to
record or to serve live), so a plain run loads nothing of it.

    factory(loaded, context, options) -> RunObserver | None   (None: nothing to do for these options)

The factory is called once the tree is loaded and before the world starts, so it may wrap
``context.bus`` to see every message.
"""
from __future__ import annotations

from importlib.metadata import entry_points
from typing import TYPE_CHECKING

from runtime.errors import ObjectiveError
from runtime.extras import load_entry_point

if TYPE_CHECKING:
    from runtime.io.interrupt import StopRequest
    from runtime.tree.behavior import RunContext
    from runtime.tree.controls import Visit
    from runtime.tree.loader import LoadedTree

    from .runner import RunOptions, RunResult

OBSERVER_GROUP = "objective.run_observers"


class RunObserver:
    """Told what happens to one run; each hook does nothing unless a subclass says otherwise.

    A run calls ``started`` once and ``ticked`` after every tick, then ends with exactly one of
    ``finished`` (it has a result) or ``aborted`` (it raised). A run that cannot start at all
    (bad options, no such world) calls ``aborted`` alone.
    """

    def started(self, loaded: LoadedTree) -> None:
        """The world started and every node is set up: before the first tick."""

    def ticked(self, now_s: float, visited: list[Visit]) -> None:
        """After every tick: the clock, and every node the tick visited with the status it reported."""

    def finished(self, result: RunResult, stop: StopRequest | None) -> None:
        """The run ended with ``result``: the tree is halted, the world and the bus are closed.
        ``stop`` still hears signals meanwhile."""

    def aborted(self, error: BaseException, stop: StopRequest | None) -> None:
        """The run raised ``error`` before it had a result; the runner raises it on afterwards."""


def attach_observers(loaded: LoadedTree, context: RunContext, options: RunOptions) -> list[RunObserver]:
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

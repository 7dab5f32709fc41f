"""What a simulated (or real) world provides to a run.

The runner owns the loop: ``clock.advance(period)``, ``world.step_to(clock.now())``,
``bus.spin_once()``, then one tick of the tree. A world therefore keeps its own time equal to
the clock after each ``step_to``; its controllers run at their own rate in between. Worlds are
found through the ``objective.worlds`` entry-point group: each names ``create(options) -> World``.
"""
from __future__ import annotations

from typing import Any, Protocol

from runtime.tree.behavior import RunContext


class World(Protocol):
    name: str

    def start(self, context: RunContext) -> None:
        """Serve topics, services and actions on ``context.bus``; fill ``context.scene``."""
        ...

    def step_to(self, t: float) -> None:
        """Advance physics and controllers until clock time ``t``."""
        ...

    def reset(self, seed: int) -> None:
        """Restore the initial state with a layout drawn from ``seed``."""
        ...

    def summary(self) -> dict[str, Any]:
        """JSON-serialisable facts for the run summary (may be empty)."""
        ...

    def close(self) -> None: ...

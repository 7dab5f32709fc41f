"""Small shared pieces for behaviors that call services and actions without blocking."""
from __future__ import annotations

from typing import Callable

from runtime.tree.behavior import Behavior
from runtime.errors import SetupError


class Deadline:
    """``expired`` once ``seconds`` of runtime-clock time have passed since construction."""

    def __init__(self, node: Behavior, seconds: float) -> None:
        self._clock = node.context.clock
        self.seconds = seconds
        self.until = self._clock.now() + seconds

    @property
    def expired(self) -> bool:
        return self._clock.now() >= self.until - 1e-9


def when_ready(is_ready: Callable[[], bool], deadline: Deadline, what: str) -> bool:
    """True when ready, False while waiting; a ``SetupError`` once the deadline passed: a service or
    action that is not there is a mistake of the setup, which ends the run as ERROR (never retried)."""
    if is_ready():
        return True
    if deadline.expired:
        raise SetupError(f"{what} is not available after {deadline.seconds:g} s")
    return False


def release_subscription(node: Behavior, attribute: str = "subscription") -> None:
    """Destroy the subscription a node keeps in ``attribute`` (None: none), once."""
    sub = getattr(node, attribute, None)
    if sub is not None:
        node.context.bus.destroy_subscription(sub)
        setattr(node, attribute, None)

"""The run's event log: what happened, on the clock, for summaries and recordings."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable


@dataclass(frozen=True)
class Event:
    time: float
    kind: str
    source: str
    data: dict[str, Any] = field(default_factory=dict)


class EventLog:
    """Append-only list of events; listeners (recorders, progress displays) see each one."""

    def __init__(self, clock: Any) -> None:
        self._clock = clock
        self.events: list[Event] = []
        self._listeners: list[Callable[[Event], None]] = []

    def emit(self, kind: str, source: str, **data: Any) -> Event:
        event = Event(self._clock.now(), kind, source, data)
        self.events.append(event)
        for listener in self._listeners:
            listener(event)
        return event

    def subscribe(self, listener: Callable[[Event], None]) -> None:
        self._listeners.append(listener)

    def of_kind(self, kind: str) -> list[Event]:
        return [e for e in self.events if e.kind == kind]

"""Small leaves every Objective uses: constant results, waiting, and log messages.

Waiting leaves (Sleep, Wait) read the run's clock, never wall time, so a headless run under a
``SimClock`` waits exactly the simulated time and takes no real time at all.
"""
from __future__ import annotations

import logging
from typing import ClassVar

from .behavior import Behavior, Status
from .decorators import elapsed
from runtime.errors import PortError
from .ports import UINT32_MAX, InputPort, PortType, Range


class AlwaysSuccess(Behavior):
    description: ClassVar[str] = "Returns SUCCESS, always."

    def update(self) -> Status:
        return Status.SUCCESS


class AlwaysFailure(Behavior):
    description: ClassVar[str] = "Returns FAILURE, always."

    def update(self) -> Status:
        return Status.FAILURE


class _TimedWait(Behavior):
    """RUNNING until the run's clock has advanced by the wait, counted from the first tick."""

    started_at: float = 0.0

    def wait_ms(self) -> float:
        raise NotImplementedError

    def initialise(self) -> None:
        self.started_at = self.context.clock.now()
        self.duration_ms = self.wait_ms()

    def update(self) -> Status:
        if self.duration_ms <= 0 or elapsed(self.started_at, self.context.clock.now(), self.duration_ms):
            return Status.SUCCESS
        return Status.RUNNING


class Sleep(_TimedWait):
    """BT.CPP ``SleepNode`` (src/actions/sleep_node.cpp), on the run's clock."""

    description: ClassVar[str] = "Returns RUNNING for msec milliseconds of run-clock time, then SUCCESS."
    ports = (InputPort("msec", PortType.UINT, description="How long to sleep, in milliseconds.", valid=Range(0, UINT32_MAX, "ms")),)

    def wait_ms(self) -> float:
        return float(self.get_input("msec"))


class Wait(_TimedWait):
    description: ClassVar[str] = (
        "Returns RUNNING until the run's clock has advanced by 'seconds' since it started, then SUCCESS."
    )
    ports = (InputPort("seconds", PortType.FLOAT, description="How long to wait, in seconds.", valid=Range(0.0, UINT32_MAX / 1000, "s")),)

    def wait_ms(self) -> float:
        seconds: float = self.get_input("seconds")
        return seconds * 1000.0


LOG_LEVELS = {
    "debug": logging.DEBUG,
    "info": logging.INFO,
    "warn": logging.WARNING,
    "error": logging.ERROR,
}


class LogMessage(Behavior):
    description: ClassVar[str] = (
        "Writes 'message' to the run's log and event record at log_level (debug, info, warn or "
        "error), then returns SUCCESS."
    )
    ports = (
        InputPort("message", PortType.STRING, description="The text to log."),
        InputPort("log_level", PortType.STRING, "info", "debug, info, warn or error."),
    )

    def check_literals(self) -> None:
        level = self.bindings["log_level"]
        if level.key is None:
            self._level(level.literal)  # a bad literal is a load-time error

    def _level(self, name: str) -> int:
        try:
            return LOG_LEVELS[str(name).strip().lower()]
        except KeyError:
            raise PortError(
                f"port 'log_level' must be one of debug, info, warn, error; got {name!r}",
                self.location,
                self.xml_id,
            ) from None

    def update(self) -> Status:
        message = self.get_input("message")
        level_name = str(self.get_input("log_level")).strip().lower()
        level = self._level(level_name)
        self.context.logger.log(level, "%s", message)
        self.context.events.emit("log", self.name, level=logging.getLevelName(level).lower(), message=message)
        return Status.SUCCESS


NODES = (AlwaysSuccess, AlwaysFailure, Sleep, Wait, LogMessage)

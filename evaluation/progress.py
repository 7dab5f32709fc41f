"""The progress bar of ``objective eval`` on a terminal: done/total, successes so far, ETA.

Only created when stderr is a TTY; otherwise the evaluation prints nothing until its summary.
"""
from __future__ import annotations

import time
from typing import Callable, TextIO

from .episode import EpisodeRecord, EpisodeStatus

BAR_WIDTH = 24


def eta_seconds(done: int, total: int, elapsed_s: float) -> float | None:
    """Seconds left at the rate so far (None before the first episode of this run)."""
    if done <= 0:
        return None
    return max(0.0, (total - done) * elapsed_s / done)


def format_duration(seconds: float | None) -> str:
    if seconds is None:
        return "--:--"
    seconds = int(round(seconds))
    hours, rest = divmod(seconds, 3600)
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}" if hours else f"{rest // 60:02d}:{rest % 60:02d}"


def progress_text(done: int, total: int, successes: int, errors: int, eta: float | None) -> str:
    filled = int(BAR_WIDTH * done / total) if total else BAR_WIDTH
    bar = "#" * filled + "." * (BAR_WIDTH - filled)
    rate = f" ({100 * successes / done:.0f}%)" if done else ""
    errs = f", {errors} errors" if errors else ""
    return f"[{bar}] {done}/{total} episodes, {successes} successes{rate}{errs}, ETA {format_duration(eta)}"


class ProgressBar:
    """One self-overwriting line; counts the episodes resumed from the file as done."""

    def __init__(self, stream: TextIO, total: int, resumed: list[EpisodeRecord],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.stream, self.total, self.clock = stream, total, clock
        self.resumed = len(resumed)
        self.successes = sum(r.status is EpisodeStatus.SUCCESS for r in resumed)
        self.errors = sum(r.status is EpisodeStatus.ERROR for r in resumed)
        self.new = 0
        self.started = clock()
        self._width = 0
        self.draw()

    def __call__(self, record: EpisodeRecord) -> None:
        self.new += 1
        self.successes += record.status is EpisodeStatus.SUCCESS
        self.errors += record.status is EpisodeStatus.ERROR
        self.draw()

    def draw(self) -> None:
        done = self.resumed + self.new
        eta = eta_seconds(self.new, self.total - self.resumed, self.clock() - self.started)
        text = progress_text(done, self.total, self.successes, self.errors, eta)
        self.stream.write("\r" + text.ljust(self._width))
        self.stream.flush()
        self._width = len(text)

    def clear(self) -> None:
        self.stream.write("\r" + " " * self._width + "\r")
        self.stream.flush()

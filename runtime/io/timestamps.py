"""Seconds on the runtime clock <-> builtin_interfaces Time/Duration messages."""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from builtin_interfaces.msg import Duration, Time


def split_seconds(seconds: float) -> tuple[int, int]:
    """Whole seconds and nanoseconds (rounded to the nearest nanosecond), as the messages hold them."""
    nanoseconds = int(round(seconds * 1e9))
    return nanoseconds // 1_000_000_000, nanoseconds % 1_000_000_000


def split_seconds_array(seconds: NDArray[np.float64]) -> tuple[list[int], list[int]]:
    """``split_seconds`` of every value, in one vectorised pass (the same integers: numpy's
    rounding, like Python's, takes a tie to the even neighbour, and both divisions floor)."""
    nanoseconds = np.round(np.asarray(seconds, dtype=float) * 1e9).astype(np.int64)
    return (nanoseconds // 1_000_000_000).tolist(), (nanoseconds % 1_000_000_000).tolist()


def time_msg(seconds: float) -> Time:
    sec, nanosec = split_seconds(seconds)
    return Time(sec=sec, nanosec=nanosec)


def duration_msg(seconds: float) -> Duration:
    sec, nanosec = split_seconds(seconds)
    return Duration(sec=sec, nanosec=nanosec)


def to_seconds(msg: Any) -> float:
    """Seconds of a Time or Duration message."""
    seconds: float = msg.sec + msg.nanosec * 1e-9
    return seconds

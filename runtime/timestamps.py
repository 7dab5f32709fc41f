"""Seconds on the runtime clock <-> builtin_interfaces Time/Duration messages."""
from __future__ import annotations

from typing import Any

from builtin_interfaces.msg import Duration, Time


def split_seconds(seconds: float) -> tuple[int, int]:
    """Whole seconds and nanoseconds (rounded to the nearest nanosecond), as the messages hold them."""
    nanoseconds = int(round(seconds * 1e9))
    return nanoseconds // 1_000_000_000, nanoseconds % 1_000_000_000


def time_msg(seconds: float) -> Time:
    sec, nanosec = split_seconds(seconds)
    return Time(sec=sec, nanosec=nanosec)


def duration_msg(seconds: float) -> Duration:
    sec, nanosec = split_seconds(seconds)
    return Duration(sec=sec, nanosec=nanosec)


def to_seconds(msg: Any) -> float:
    """Seconds of a Time or Duration message."""
    return msg.sec + msg.nanosec * 1e-9

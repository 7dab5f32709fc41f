"""Watching a force-torque sensor's wrench topic for a threshold crossing.

A stock ``joint_trajectory_controller`` has no force-torque abort: the wrist wrench comes from a
``force_torque_sensor_broadcaster`` as ``geometry_msgs/WrenchStamped``. ``WrenchWatch`` subscribes
best-effort (a reliable and a best-effort publisher both match) and remembers the first reading
whose absolute value exceeds its axis's threshold; the behavior that owns it then cancels the goal.
"""
from __future__ import annotations

from typing import Any

from geometry_msgs.msg import WrenchStamped

WRENCH_AXES = (("Fx", "N"), ("Fy", "N"), ("Fz", "N"), ("Tx", "N m"), ("Ty", "N m"), ("Tz", "N m"))


def wrench_values(msg: WrenchStamped) -> tuple[float, ...]:
    force, torque = msg.wrench.force, msg.wrench.torque
    return (force.x, force.y, force.z, torque.x, torque.y, torque.z)


def threshold_crossing(values: tuple[float, ...], thresholds: tuple[float, ...]) -> str | None:
    """The first axis (Fx, Fy, Fz, Tx, Ty, Tz order) whose |value| exceeds its threshold, as
    "Fz = -52.30 N exceeds the absolute threshold 45.00 N"; a NaN reading counts as exceeding."""
    for (axis, unit), value, limit in zip(WRENCH_AXES, values, thresholds):
        if not abs(value) <= limit:
            return f"{axis} = {value:.2f} {unit} exceeds the absolute threshold {limit:.2f} {unit}"
    return None


class WrenchWatch:
    """The first threshold crossing seen on ``topic``: every reading delivered between ticks, and
    the latest one when ``crossing()`` is asked (an in-process sensor topic is read on demand)."""

    def __init__(self, bus: Any, topic: str, thresholds: tuple[float, ...]) -> None:
        self.topic, self.thresholds = topic, tuple(thresholds)
        self.first_crossing: str | None = None
        self.subscription = bus.create_subscription(topic, WrenchStamped, self._on_reading, reliable=False)

    def reset(self) -> None:
        """Forget the crossings seen so far (a new run of the behavior that watches)."""
        self.first_crossing = None

    @property
    def has_reading(self) -> bool:
        return self.subscription.latest is not None

    def _on_reading(self, msg: WrenchStamped) -> None:
        if self.first_crossing is None:
            self.first_crossing = threshold_crossing(wrench_values(msg), self.thresholds)

    def crossing(self) -> str | None:
        """The first crossing so far (None: none)."""
        latest = self.subscription.latest
        if self.first_crossing is None and latest is not None:
            self.first_crossing = threshold_crossing(wrench_values(latest), self.thresholds)
        return self.first_crossing

"""Joint-limit checks of a densified motion: position, velocity, acceleration. Pure, vectorised."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .shaping import Samples


@dataclass(frozen=True)
class JointLimitTable:
    """Limits of the commanded joints, in the order of the motion's columns."""

    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    max_velocity: np.ndarray
    max_acceleration: np.ndarray


@dataclass(frozen=True)
class LimitViolation:
    quantity: str  # "position" | "velocity" | "acceleration"
    index: int  # densified sample index
    time: float
    joint: str
    value: float
    limit: float

    def describe(self) -> str:
        unit = {"position": "rad", "velocity": "rad/s", "acceleration": "rad/s^2"}[self.quantity]
        return (
            f"{self.quantity} limit violated at sample {self.index} (t={self.time:.3f} s): "
            f"joint '{self.joint}' {self.quantity} {self.value:.4f} {unit} exceeds the limit {self.limit:.4f} {unit}"
        )


def first_limit_violation(samples: Samples, limits: JointLimitTable, tolerance: float = 1e-9) -> LimitViolation | None:
    """The earliest sample that leaves the limits, or None when all samples are inside."""
    p, v, a = samples.positions, samples.velocities, samples.accelerations
    checks = (
        ("position", np.maximum(limits.lower - p, p - limits.upper), None),
        ("velocity", np.abs(v) - limits.max_velocity, limits.max_velocity),
        ("acceleration", np.abs(a) - limits.max_acceleration, limits.max_acceleration),
    )
    best: LimitViolation | None = None
    for quantity, excess, _ in checks:
        bad = excess > tolerance
        if not bad.any():
            continue
        index = int(np.argmax(bad.any(axis=1)))
        joint = int(np.argmax(excess[index]))
        if best is not None and index >= best.index:
            continue
        if quantity == "position":
            value = float(p[index, joint])
            limit = float(limits.upper[joint] if value > limits.upper[joint] else limits.lower[joint])
        elif quantity == "velocity":
            value, limit = float(v[index, joint]), float(limits.max_velocity[joint])
        else:
            value, limit = float(a[index, joint]), float(limits.max_acceleration[joint])
        best = LimitViolation(quantity, index, float(samples.times[index]), limits.names[joint], value, limit)
    return best

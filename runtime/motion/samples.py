"""``Samples``: a densified motion, what every motion behavior checks against the planning scene
and sends to a controller as trajectory points."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Samples:
    """A densified motion: ``times`` (M,), and (M, J) positions, velocities, accelerations."""

    times: NDArray[np.float64]
    positions: NDArray[np.float64]
    velocities: NDArray[np.float64]
    accelerations: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.times)

    @property
    def duration_s(self) -> float:
        return float(self.times[-1] - self.times[0])

    @classmethod
    def at_rest(cls, position: NDArray[np.float64]) -> Samples:
        """A motion of no length: ``position`` alone, at time 0."""
        q = np.asarray(position, dtype=float).reshape(1, -1)
        return cls(np.zeros(1), q, np.zeros_like(q), np.zeros_like(q))

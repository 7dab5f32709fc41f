"""Seeded cube layouts on the table, in front of the robot and inside its comfortable reach.

``layout(seed)`` is a pure function: the same seed gives the same layout on every machine
(numpy's PCG64 stream), so a headless run is reproducible from its seed alone.

The workspace is a band in front of the robot (which faces +y, see ``sim.cell_model``): far
enough from the base that a top-down grasp does not fold the arm onto itself, close enough that
the wrist stays well inside the UR5e's 850 mm reach.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.cell_model import CUBE_COLORS
from runtime.errors import OptionError


@dataclass(frozen=True)
class Workspace:
    """Where cube centres may land (metres, world frame; yaw in radians)."""

    x_range: tuple[float, float] = (-0.25, 0.25)
    y_range: tuple[float, float] = (0.32, 0.60)
    min_radius: float = 0.34
    """Closest a cube may be to the robot base axis."""
    max_radius: float = 0.62
    """Farthest a cube may be from the robot base axis."""
    min_separation: float = 0.08
    """Smallest distance between two cube centres (room for the open fingers between them)."""


DEFAULT_WORKSPACE = Workspace()
_MAX_ATTEMPTS = 10_000


def layout(seed: int, workspace: Workspace = DEFAULT_WORKSPACE) -> dict[str, tuple[float, float, float]]:
    """Cube colour -> (x, y, yaw) for ``seed``: inside ``workspace``, pairwise separated.

    Yaw is uniform in [-pi/4, pi/4): a cube looks the same every quarter turn.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise OptionError(f"layout seed must be a non-negative integer, got {seed!r}")
    rng = np.random.default_rng(int(seed))
    placed: dict[str, tuple[float, float, float]] = {}
    for color in CUBE_COLORS:
        for _ in range(_MAX_ATTEMPTS):
            x = float(rng.uniform(*workspace.x_range))
            y = float(rng.uniform(*workspace.y_range))
            yaw = float(rng.uniform(-math.pi / 4, math.pi / 4))
            if is_valid_position(x, y, placed.values(), workspace):
                placed[color] = (x, y, yaw)
                break
        else:
            raise ValueError(f"no room for cube '{color}' in {workspace} after {_MAX_ATTEMPTS} draws")
    return placed


def is_valid_position(x: float, y: float, others, workspace: Workspace = DEFAULT_WORKSPACE) -> bool:
    """Inside the workspace band and at least ``min_separation`` from every other (x, y, ...)."""
    radius = math.hypot(x, y)
    if not workspace.min_radius <= radius <= workspace.max_radius:
        return False
    if not (workspace.x_range[0] <= x <= workspace.x_range[1] and workspace.y_range[0] <= y <= workspace.y_range[1]):
        return False
    return all(math.hypot(x - o[0], y - o[1]) >= workspace.min_separation for o in others)

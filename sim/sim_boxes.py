"""Boxes a run places in the simulated cell: an object that appears mid-run.

``PlacedBoxes`` belongs to a ``CellWorld``. It checks a request (``check_box``), asks the cell
to make the box appear (the MuJoCo cell: a fixed box that collides and shows in the cameras; the
kinematic cell: a record, it has no physics), and mirrors it into the planning scene as a world
object of the same name, the way the cubes are mirrored, unless the caller asks it not to (a box
the planning scene does not know about is one the robot can run into).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from runtime.motion.scene import Box, PlanningScene


class BoxCell(Protocol):
    def place_box(self, name: str, size_m: np.ndarray, position_m: np.ndarray, quat_wxyz: np.ndarray) -> None: ...

    def remove_box(self, name: str) -> None: ...


@dataclass(frozen=True)
class PlacedBox:
    name: str
    size_m: tuple[float, float, float]
    """Full edge lengths along the box's own x, y, z."""
    pose: np.ndarray
    """4x4 world pose of the box's centre."""
    mirrored: bool
    """Whether the planning scene holds it as a world object."""

    def as_summary(self) -> dict[str, Any]:
        return {
            "size_m": [round(v, 4) for v in self.size_m],
            "position_m": [round(float(v), 4) for v in self.pose[:3, 3]],
            "in_planning_scene": self.mirrored,
        }


def check_box(name: str, size_m: Any, pose: Any) -> tuple[tuple[float, float, float], np.ndarray]:
    """The size and pose of a box request, or ValueError naming what is wrong."""
    if not name or name == "*":
        raise ValueError(f"a box needs a name (got {name!r})")
    size = np.asarray(size_m, dtype=float).reshape(-1)
    if size.size != 3:
        raise ValueError(f"dimensions need 3 values (x;y;z in metres), got {size.size}")
    for axis, value in zip("xyz", size.tolist()):
        if not math.isfinite(value) or value <= 0:
            raise ValueError(f"dimension {axis} must be a positive number of metres, got {value}")
    matrix = np.asarray(pose, dtype=float)
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise ValueError("the box pose is not a finite 4x4 transform")
    return (float(size[0]), float(size[1]), float(size[2])), matrix


class PlacedBoxes:
    """The boxes placed in one cell, kept in step with the cell and the planning scene."""

    def __init__(self) -> None:
        self.boxes: dict[str, PlacedBox] = {}

    def place(self, cell: BoxCell, scene: PlanningScene, name: str, size_m: Any, pose: Any, mirror: bool = True) -> PlacedBox:
        """Place (or move) box ``name``; ValueError, with nothing changed, when it cannot be."""
        size, matrix = check_box(name, size_m, pose)
        mirrored_before = name in self.boxes and self.boxes[name].mirrored
        if name in {a.name for a in scene.attachments}:
            raise ValueError(f"'{name}' is attached to the robot in the planning scene: pick another name")
        if name in scene.objects and not mirrored_before:
            raise ValueError(f"'{name}' is already an object of the planning scene: pick another name")
        from scipy.spatial.transform import Rotation  # scipy.spatial: ~0.3 s, imported on first use

        quat_xyzw = Rotation.from_matrix(matrix[:3, :3]).as_quat()
        cell.place_box(name, np.array(size), matrix[:3, 3].copy(), np.roll(quat_xyzw, 1))
        if mirror:
            scene.add_object(name, Box(size), matrix, fixed=True)
        elif mirrored_before:
            scene.remove_object(name)
        box = self.boxes[name] = PlacedBox(name, size, matrix, mirror)
        return box

    def remove(self, cell: BoxCell, scene: PlanningScene, name: str) -> None:
        box = self.boxes.get(name)
        if box is None:
            raise ValueError(f"no box '{name}' was placed in the cell (placed: {', '.join(sorted(self.boxes)) or 'none'})")
        cell.remove_box(name)
        if box.mirrored and name in scene.objects:
            scene.remove_object(name)
        del self.boxes[name]

    def forget(self, scene: PlanningScene) -> None:
        """After the cell was reset (which removed its boxes): drop their mirrors too."""
        for box in self.boxes.values():
            if box.mirrored and box.name in scene.objects:
                scene.remove_object(box.name)
        self.boxes.clear()

    def summary(self) -> dict[str, Any]:
        return {name: box.as_summary() for name, box in sorted(self.boxes.items())}

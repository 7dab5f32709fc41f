"""Sim control: reset the simulated world, place a box in it or take one away.

World-level nodes: they call the world directly (``context.world.reset(seed)``,
``place_box``, ``remove_box``), because these are not things a real robot offers on the bus.
Against a run without a simulated world they fail with a reason instead of pretending.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from runtime.app.world import PlacesBoxes
from runtime.tree.behavior import Behavior, Status
from runtime.tree.ports import UINT32_MAX, InputPort, NameKind, Names, PortType, Range

from .poses import FrameError, ReadsRobotState, frame_in_world, offset_matrix
from .scene_objects import ChecksPorts, box_dimensions, object_id


class ResetSim(Behavior):
    """Reset the simulated world to a seeded layout, then give it one tick to publish it.

    The reset happens in the first tick; the node answers SUCCESS in the next one, after the
    runner has stepped the world and delivered its messages, so the nodes that follow read the
    new joint states and cube poses, never the ones from before the reset.
    """

    needs_world = True
    description = "Reset the simulated world (robot at its start, cubes in the layout drawn from seed)."
    ports = (InputPort("seed", PortType.UINT, 0, "Seed of the new cube layout.", valid=Range(0, UINT32_MAX)),)

    def initialise(self) -> None:
        self.reset_done = False

    def update(self) -> Status:
        if self.reset_done:
            self.feedback_message = f"world reset with seed {self.get_input('seed')}"
            return Status.SUCCESS
        world = self.context.world
        if world is None:
            return self.fail("this run hosts no simulated world to reset (ResetSim works only against a simulated cell)")
        seed = self.get_input("seed")
        try:
            world.reset(seed)
        except ValueError as err:
            return self.fail(f"the world refused the reset with seed {seed}: {err}")
        self.reset_done = True
        return Status.RUNNING


def finite_values(count: int, unit: str) -> Any:
    """A check: ``count`` finite numbers."""

    def check(values: Any) -> list[float]:
        numbers = [float(v) for v in values]
        if len(numbers) != count:
            raise ValueError(f"needs {count} values, got {len(numbers)}")
        bad = [v for v in numbers if not math.isfinite(v)]
        if bad:
            raise ValueError(f"values must be finite {unit}, got {';'.join(f'{v:g}' for v in numbers)}")
        return numbers

    return check


def unit_quaternion(values: Any) -> list[float]:
    quat: list[float] = finite_values(4, "numbers")(values)
    if math.sqrt(sum(v * v for v in quat)) < 1e-9:
        raise ValueError(f"{';'.join(f'{v:g}' for v in quat)} is not a rotation (zero length)")
    return quat


NO_SIM_WORLD = "this run hosts no simulated cell that can place boxes ({node} works only against vla_sim or kinematic)"


class PlaceSimBox(ChecksPorts, ReadsRobotState, Behavior):
    """Make a box appear in the simulated cell (or move one placed before), as an object that
    appears mid-run: in MuJoCo it is fixed in place, collides and shows in the cameras."""

    needs_world = True
    description = (
        "Place a fixed box (object_id, full dimensions x;y;z in m) in the simulated cell at position_xyz / "
        "orientation_xyzw in reference_frame; mirrored into the planning scene unless add_to_planning_scene is false."
    )
    ports = (
        InputPort("object_id", PortType.STRING, description="Name of the box (also its planning-scene id), e.g. tray.",
                  names=Names(NameKind.OBJECT, creates=True)),
        InputPort("dimensions", PortType.FLOAT_LIST, description="Full edge lengths x;y;z in metres.",
                  valid=Range(0.0, 100.0, "m", min_open=True), length=3),
        InputPort("position_xyz", PortType.FLOAT_LIST, description="Centre x;y;z in metres, in reference_frame.",
                  valid=Range(-100.0, 100.0, "m"), length=3),
        InputPort("orientation_xyzw", PortType.FLOAT_LIST, "0;0;0;1", "Orientation quaternion x;y;z;w in reference_frame.",
                  valid=Range(-1.0, 1.0), length=4),
        InputPort("reference_frame", PortType.STRING, "world", "world, a robot frame (e.g. tcp) or a planning-scene object.", names=Names(NameKind.FRAME)),
        InputPort("add_to_planning_scene", PortType.BOOL, True, "true: the planning scene gets it too (as the cubes); false: only the physics knows it."),
    )
    checked = {
        "object_id": object_id,
        "dimensions": box_dimensions,
        "position_xyz": finite_values(3, "metres"),
        "orientation_xyzw": unit_quaternion,
    }

    def update(self) -> Status:
        world, scene = self.context.world, self.context.scene
        if not isinstance(world, PlacesBoxes) or scene is None:
            return self.fail(NO_SIM_WORLD.format(node="PlaceSimBox"))
        try:
            name, size = self.checked_input("object_id"), self.checked_input("dimensions")
            local = offset_matrix(self.checked_input("position_xyz"), self.checked_input("orientation_xyzw"))
            pose = frame_in_world(scene, self.get_input("reference_frame"), self.state()) @ local
            world.place_box(name, size, pose, mirror=self.get_input("add_to_planning_scene"))
        except (ValueError, FrameError) as err:
            return self.fail(str(err))
        x, y, z = np.round(pose[:3, 3], 3)
        self.feedback_message = f"placed box '{name}' at ({x:g}, {y:g}, {z:g}) in world"
        return Status.SUCCESS


class RemoveSimBox(ChecksPorts, Behavior):
    """Take a box placed by PlaceSimBox out of the simulated cell (and out of the planning scene)."""

    needs_world = True
    description = "Remove a box that PlaceSimBox placed in the simulated cell (and its planning-scene mirror)."
    ports = (InputPort("object_id", PortType.STRING, description="Name the box was placed under."),)
    checked = {"object_id": object_id}

    def update(self) -> Status:
        world = self.context.world
        if not isinstance(world, PlacesBoxes):
            return self.fail(NO_SIM_WORLD.format(node="RemoveSimBox"))
        try:
            name = self.checked_input("object_id")
            world.remove_box(name)
        except ValueError as err:
            return self.fail(str(err))
        self.feedback_message = f"removed box '{name}' from the cell"
        return Status.SUCCESS


NODES = (ResetSim, PlaceSimBox, RemoveSimBox)

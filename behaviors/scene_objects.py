"""Collision objects in the planning scene: add a box, move or remove an object.

Named and ported as MoveIt Pro's collision-object Behaviors (9.4 and later: ``AddCollisionBox``,
``MoveCollisionObject``, ``RemoveCollisionObject``): an object is referred to by a plain-text
``object_id``, a box has full edge lengths ``dimensions`` (x;y;z, metres) and a ``pose``
(a ``geometry_msgs/PoseStamped`` whose frame is ``world``, a robot frame or another scene
object). They edit the live planning scene in the tick they run; MoveIt Pro's optional
``planning_scene`` port (edit a scene held on the blackboard instead) is not offered.

A change is seen at once by every later check, and by a running ExecutePolicy, which re-checks
the rest of its sent motion whenever the scene changes ("the planning scene changed: ...").
These are virtual objects: the simulated cell's physics does not know them (``PlaceSimBox``
places a box the physics does know).

Values written literally in the XML are checked when the Objective loads (an empty id, two
dimensions, a negative size); values read from the blackboard are checked when the node runs.
"""
from __future__ import annotations

import math
from typing import Any, Callable

from runtime.tree.behavior import PortBinding, Status
from runtime.errors import PortError
from runtime.tree.ports import InputPort, NameKind, Names, PortType, Range
from runtime.motion.scene import Box

from .poses import NO_SCENE, FrameError, SceneBehavior, as_pose_stamped, pose_in_world
from .scene import describe_objects


# -- pure checks (ValueError names what is wrong) -------------------------------------------------
def object_id(value: Any) -> str:
    name = str(value).strip()
    if not name or name == "*":
        raise ValueError(f"object_id must name one object, got {str(value)!r}")
    return name


def box_dimensions(values: Any) -> tuple[float, float, float]:
    """Full edge lengths x;y;z in metres: three positive finite numbers."""
    sizes = [float(v) for v in values]
    if len(sizes) != 3:
        raise ValueError(f"dimensions needs 3 values (x;y;z in metres), got {len(sizes)}")
    for axis, size in zip("xyz", sizes):
        if not math.isfinite(size) or size <= 0:
            raise ValueError(f"dimensions {axis} must be a positive number of metres, got {size}")
    return sizes[0], sizes[1], sizes[2]


class ChecksPorts:
    """Checks the ports listed in ``checked`` (port -> pure check) on literals at load time and
    on every value when the node runs; ports in ``from_blackboard`` (messages) must not be literal."""

    checked: dict[str, Callable[[Any], Any]] = {}
    from_blackboard: tuple[str, ...] = ()
    bindings: dict[str, PortBinding]
    location: Any
    xml_id: str

    def check_literals(self) -> None:
        for port in self.from_blackboard:
            binding = self.bindings[port]
            if binding.key is None and isinstance(binding.literal, str):
                raise PortError(
                    f"port '{port}' needs a geometry_msgs/PoseStamped from the blackboard, e.g. {{{port}}} written by "
                    f"GetLatestTransform or TransformPose; got the text {binding.literal!r}",
                    self.location,
                    self.xml_id,
                )
        for port, check in self.checked.items():
            binding = self.bindings[port]
            if binding.key is None and binding.literal is not None:
                try:
                    check(binding.literal)
                except ValueError as err:
                    raise PortError(f"port '{port}': {err}", self.location, self.xml_id) from None

    def checked_input(self, port: str) -> Any:
        """The port's value through its check (ValueError names the port)."""
        try:
            return self.checked[port](self.get_input(port))  # type: ignore[attr-defined]
        except ValueError as err:
            raise ValueError(f"port '{port}': {err}") from None


OBJECT_ID = InputPort("object_id", PortType.STRING, description="Id of the collision object in the planning scene, e.g. box.",
                      names=Names(NameKind.OBJECT))
NEW_OBJECT_ID = InputPort("object_id", PortType.STRING, description="Id of the collision object in the planning scene, e.g. box.",
                          names=Names(NameKind.OBJECT, creates=True))
POSE = InputPort(
    "pose",
    PortType.ANY,
    description="Pose of the object's centre (geometry_msgs/PoseStamped; frame world, a robot frame or a scene object).",
)


class AddCollisionBox(ChecksPorts, SceneBehavior):
    """Add a box to the planning scene as a world object (replace one with overwrite=true)."""

    description = "Add a box collision object (object_id, full dimensions x;y;z in m, pose) to the planning scene."
    ports = (
        NEW_OBJECT_ID,
        InputPort("dimensions", PortType.FLOAT_LIST, description="Full edge lengths x;y;z in metres, along the pose's axes.",
                  valid=Range(0.0, 100.0, "m", min_open=True), length=3),
        POSE,
        InputPort("overwrite", PortType.BOOL, False, "true: replace an object with the same id; false: fail if one exists."),
    )
    checked = {"object_id": object_id, "dimensions": box_dimensions}
    from_blackboard = ("pose",)

    def update(self) -> Status:
        scene = self.context.scene
        if scene is None:
            return self.fail(NO_SCENE)
        try:
            name, size = self.checked_input("object_id"), self.checked_input("dimensions")
            matrix = pose_in_world(scene, as_pose_stamped(self.get_input("pose"), "pose"), self.state())
        except (ValueError, FrameError) as err:
            return self.fail(str(err))
        if name in {a.name for a in scene.attachments}:
            return self.fail(f"'{name}' is attached to the robot: detach it (DetachObject) before replacing it")
        if name in scene.objects and not self.get_input("overwrite"):
            return self.fail(f"object '{name}' is already in the planning scene (set overwrite=true to replace it)")
        scene.add_object(name, Box(size), matrix)
        x, y, z = matrix[:3, 3]
        self.feedback_message = f"added box '{name}' {size[0]:g} x {size[1]:g} x {size[2]:g} m at ({x:.3f}, {y:.3f}, {z:.3f}) in world"
        return Status.SUCCESS


def world_object(scene: Any, name: str) -> str | None:
    """Why ``name`` cannot be moved or removed as a world object, or None when it can."""
    if name in {a.name for a in scene.attachments}:
        return f"'{name}' is attached to the robot: detach it (DetachObject) first"
    if name not in scene.objects:
        return f"no collision object '{name}' in the planning scene (objects: {describe_objects(scene)})"
    return None


class EditsWorldObject(ChecksPorts, SceneBehavior):
    """An edit of one existing world object, named by ``object_id``: ``edit`` does it and says what it did."""

    checked = {"object_id": object_id}

    def update(self) -> Status:
        scene = self.context.scene
        if scene is None:
            return self.fail(NO_SCENE)
        try:
            name = self.checked_input("object_id")
            problem = world_object(scene, name)
            if problem is not None:
                return self.fail(problem)
            self.feedback_message = self.edit(scene, name)
        except (ValueError, FrameError) as err:
            return self.fail(str(err))
        return Status.SUCCESS

    def edit(self, scene: Any, name: str) -> str:
        raise NotImplementedError


class MoveCollisionObject(EditsWorldObject):
    """Give a world object of the planning scene a new pose (its shape stays)."""

    description = "Move a collision object of the planning scene to a new pose."
    ports = (OBJECT_ID, POSE)
    from_blackboard = ("pose",)

    def edit(self, scene: Any, name: str) -> str:
        matrix = pose_in_world(scene, as_pose_stamped(self.get_input("pose"), "pose"), self.state())
        scene.move_object(name, matrix)
        x, y, z = matrix[:3, 3]
        return f"moved '{name}' to ({x:.3f}, {y:.3f}, {z:.3f}) in world"


class RemoveCollisionObject(EditsWorldObject):
    """Take a world object out of the planning scene."""

    description = "Remove a collision object from the planning scene."
    ports = (OBJECT_ID,)

    def edit(self, scene: Any, name: str) -> str:
        scene.remove_object(name)
        return f"removed '{name}' from the planning scene"


NODES = (AddCollisionBox, MoveCollisionObject, RemoveCollisionObject)

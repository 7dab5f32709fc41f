"""Planning-scene edits: collision rules and attached objects.

These act on ``context.scene`` in the tick they run and succeed in that tick. They change what
later motions and ExecutePolicy runs allow: an Objective that grasps a cube first allows contact
between the gripper and that cube (``SetCollisionRule``), and may attach the cube to the gripper
while carrying it (``AttachObject``) so the checks see it moving with the hand. A run that is
already streaming keeps the rules it started with (ExecutePolicy snapshots them at its start).
"""
from __future__ import annotations

from typing import Any

from runtime.tree.behavior import Status
from runtime.tree.ports import InputPort, NameKind, Names, PortType

from .poses import NO_SCENE, FrameError, SceneBehavior

ANY_OBJECT = "*"


def describe_links(scene: Any) -> str:
    links = ", ".join(scene.robot.link_names) 
    groups = ", ".join(scene.robot.group_names) or "none"
    return f"links: {links}; groups: {groups}"


def describe_objects(scene: Any) -> str:
    names = sorted(scene.objects) + sorted(a.name for a in scene.attachments)
    return ", ".join(names) or "none"


def unknown_links(scene: Any, names: list[str]) -> list[str]:
    """Names that are neither a robot link, an SRDF group, an attached object nor ``*``.

    An attached object counts as a link: it moves with the robot, so a rule can let another
    object touch it (placing a carried cube on another one).
    """
    robot = scene.robot
    carried = {a.name for a in scene.attachments}
    return [n for n in names if n != ANY_OBJECT and n not in robot.link_names and n not in robot.group_names and n not in carried]


class SetCollisionRule(SceneBehavior):
    """Allow (or forbid again) contact between a scene object and robot links.

    ``*`` stands for the objects the task may handle that are in the scene when the rule is set
    (``PlanningScene.handled_objects``): never the fixed ones such as the table, which a rule
    must name, and never an object that appears later, which stays an obstacle to every link.
    """

    description = ("Allow or forbid contact between a planning-scene object and robot links or a group; * stands for "
                   "every object in the scene now except the fixed ones (the table), which must be named.")
    ports = (
        InputPort("object_name", PortType.STRING, description="Planning-scene object, e.g. cube_blue, or * for every object in the scene now but the fixed ones (the table)."),
        InputPort("link_names", PortType.STRING_LIST, description="Robot links (';'-separated), a group name such as gripper, or an attached object."),
        InputPort("allow", PortType.BOOL, True, "true: contact is allowed; false: contact counts as a collision again."),
    )

    def update(self) -> Status:
        scene = self.context.scene
        if scene is None:
            return self.fail(NO_SCENE)
        obj = self.get_input("object_name").strip()
        links = [n for n in self.get_input("link_names") if n]
        if not obj:
            return self.fail("object_name is empty: name a planning-scene object or *")
        if obj != ANY_OBJECT and obj not in scene.objects and obj not in {a.name for a in scene.attachments}:
            return self.fail(f"no object '{obj}' in the planning scene (objects: {describe_objects(scene)}, or * for all)")
        if not links:
            return self.fail("link_names is empty: name robot links or a group such as gripper")
        unknown = unknown_links(scene, links)
        if unknown:
            return self.fail(f"unknown robot link or group {', '.join(repr(n) for n in unknown)} ({describe_links(scene)})")
        allow = self.get_input("allow")
        objects = scene.handled_objects if obj == ANY_OBJECT else [obj]
        for name in objects:
            (scene.allow if allow else scene.disallow)(name, links)
        self.feedback_message = f"{'allowed' if allow else 'forbade'} contact between {', '.join(objects) or 'no object'} and {', '.join(links)}"
        return Status.SUCCESS


class AttachObject(SceneBehavior):
    """Carry a scene object with a robot link, keeping where it is now relative to that link."""

    description = "Attach a planning-scene object to a robot link (it then moves with the link in every check)."
    ports = (
        InputPort("object_name", PortType.STRING, description="World object to attach, e.g. cube_blue.", names=Names(NameKind.OBJECT)),
        InputPort("link_name", PortType.STRING, "gripper_base", "Robot link that carries it.", names=Names(NameKind.FRAME)),
        InputPort("touch_links", PortType.STRING_LIST, "", "Links or groups it may touch while carried, e.g. gripper (the fingers)."),
    )

    def update(self) -> Status:
        scene = self.context.scene
        if scene is None:
            return self.fail(NO_SCENE)
        obj, link = self.get_input("object_name"), self.get_input("link_name")
        touch = [n for n in self.get_input("touch_links") if n]
        attached = {a.name: a.link for a in scene.attachments}
        if obj in attached:
            return self.fail(f"'{obj}' is already attached to '{attached[obj]}'")
        if obj not in scene.objects:
            return self.fail(f"no world object '{obj}' in the planning scene (objects: {describe_objects(scene)})")
        if link not in scene.robot.link_names:
            return self.fail(f"'{link}' is not a robot link ({describe_links(scene)})")
        unknown = unknown_links(scene, touch)
        if unknown:
            return self.fail(f"touch_links: unknown robot link or group {', '.join(repr(n) for n in unknown)} ({describe_links(scene)})")
        try:
            row = self.state().row(scene)
        except FrameError as err:
            return self.fail(f"cannot attach '{obj}': {err}")
        scene.attach(obj, link, q=row, touch_links=touch)
        self.feedback_message = f"'{obj}' attached to '{link}'"
        return Status.SUCCESS


class DetachObject(SceneBehavior):
    """Stop carrying an object: it stays in the world where the link holds it now."""

    description = "Detach an attached object; it stays in the planning scene where it is now."
    ports = (InputPort("object_name", PortType.STRING, description="Attached object, e.g. cube_blue."),)

    def update(self) -> Status:
        scene = self.context.scene
        if scene is None:
            return self.fail(NO_SCENE)
        obj = self.get_input("object_name")
        attached = [a.name for a in scene.attachments]
        if obj not in attached:
            return self.fail(f"'{obj}' is not attached (attached objects: {', '.join(attached) or 'none'})")
        try:
            row = self.state().row(scene)
        except FrameError as err:
            return self.fail(f"cannot detach '{obj}': {err}")
        scene.detach(obj, q=row)
        self.feedback_message = f"'{obj}' detached"
        return Status.SUCCESS


NODES = (SetCollisionRule, AttachObject, DetachObject)

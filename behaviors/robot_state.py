"""MoveIt Pro's state and scene nodes: GetCurrentPlanningScene, GetJointState, ClearSnapshot and
UpdatePlanningSceneService.

MoveIt Pro passes a ``moveit_msgs/PlanningScene`` between these; this runtime has no
moveit_msgs, so ``GetCurrentPlanningScene`` writes a ``SceneState``: the robot's joint state
and the world objects' poses at that instant, which ``GetJointState`` reads the joints from.
The planning scene here has no point-cloud (octomap) layer: ``ClearSnapshot`` finds nothing to
clear, and ``UpdatePlanningSceneService`` fails saying so.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState

from runtime.tree.behavior import Behavior, Status
from runtime.tree.ports import InputPort, NameKind, Names, OutputPort, PortType
from runtime.io.timestamps import time_msg

from .poses import NO_SCENE, WORLD_FRAME, FrameError, SceneBehavior, frame_in_world, matrix_to_pose
from .safety import SafetyError, make_safety


@dataclass(frozen=True)
class SceneState:
    """What ``GetCurrentPlanningScene`` captures: the stand-in for a moveit_msgs/PlanningScene."""

    stamp_s: float
    joint_state: JointState
    """Every joint the robot publishes, as read from ``/joint_states``."""
    objects: dict[str, PoseStamped] = field(default_factory=dict)
    """World-frame poses of the planning-scene objects, attached ones included."""
    attached: dict[str, str] = field(default_factory=dict)
    """Attached object -> the link carrying it."""


def group_joint_state(source: JointState, joints: tuple[str, ...], stamp_s: float) -> JointState:
    """The positions (and velocities, when present) of ``joints`` from ``source``; KeyError naming the missing ones."""
    index = {name: i for i, name in enumerate(source.name)}
    missing = [j for j in joints if j not in index]
    if missing:
        raise KeyError(f"the joint state lacks {', '.join(missing)}")
    msg = JointState(name=list(joints), position=[float(source.position[index[j]]) for j in joints])
    if len(source.velocity) == len(source.name):
        msg.velocity = [float(source.velocity[index[j]]) for j in joints]
    msg.header.stamp = time_msg(stamp_s)
    return msg


class GetCurrentPlanningScene(SceneBehavior):
    """MoveIt Pro's GetCurrentPlanningScene."""

    description: ClassVar[str] = (
        "Capture the planning scene now (joint state and object poses) for GetJointState and ValidateTrajectory."
    )
    ports = (
        OutputPort("planning_scene_msg", PortType.ANY, "The captured scene (a SceneState).", default="{planning_scene}"),
    )

    def update(self) -> Status:
        scene = self.context.scene
        if scene is None:
            return self.fail(NO_SCENE)
        latest = self.state().subscription.latest
        if latest is None:
            return self.fail(f"no joint states on '{self.state().topic}' yet")
        now = self.now()
        names = list(scene.objects) + [a.name for a in scene.attachments]
        try:
            objects = {n: matrix_to_pose(WORLD_FRAME, frame_in_world(scene, n, self.state()), now) for n in names}
        except FrameError as err:
            return self.fail(str(err))
        attached = {a.name: a.link for a in scene.attachments}
        self.set_output("planning_scene_msg", SceneState(now, latest, objects, attached))
        return Status.SUCCESS


class GetJointState(Behavior):
    """MoveIt Pro's GetJointState: a group's joints from a captured planning scene."""

    needs_world = True
    description: ClassVar[str] = "Write the joint state of a planning group's joints from a scene captured by GetCurrentPlanningScene."
    ports = (
        InputPort("planning_scene", PortType.ANY, "{planning_scene}", "A scene from GetCurrentPlanningScene."),
        InputPort("planning_group_name", PortType.STRING, "manipulator", "SRDF joint group whose joints are written.", names=Names(NameKind.JOINT_GROUP)),
        OutputPort("joint_state", PortType.JOINT_STATE, "The group's joint positions.", default="{joint_state}"),
        OutputPort("joint_positions", PortType.FLOAT_LIST, "The same positions as a vector of numbers, for GetElementOfVector and Scripts (not in MoveIt Pro)."),
    )

    def update(self) -> Status:
        captured = self.get_input("planning_scene")
        if not isinstance(captured, SceneState):
            return self.fail(f"planning_scene must come from GetCurrentPlanningScene, got a {type(captured).__name__}")
        try:
            joints = make_safety(self.context.scene, self.get_input("planning_group_name"), None).group_joints
            msg = group_joint_state(captured.joint_state, joints, captured.stamp_s)
        except (SafetyError, KeyError) as err:
            return self.fail(str(err).strip('"'))
        self.set_output("joint_state", msg)
        self.set_output("joint_positions", list(msg.position))
        return Status.SUCCESS


class ClearSnapshot(Behavior):
    """MoveIt Pro's ClearSnapshot."""

    description: ClassVar[str] = (
        "Clear the point-cloud snapshot from the planning scene. This runtime's planning scene has no point-cloud layer, "
        "so there is never one to clear: it succeeds and says so."
    )

    def update(self) -> Status:
        self.feedback_message = "no point-cloud snapshot in this planning scene: nothing to clear"
        return Status.SUCCESS


class UpdatePlanningSceneService(Behavior):
    """MoveIt Pro's UpdatePlanningSceneService: not possible here, and it says why."""

    description: ClassVar[str] = (
        "Add a point cloud to the planning scene. Not available: this runtime's planning scene has no point-cloud "
        "(octomap) layer, so it always fails with that reason."
    )
    ports = (
        InputPort("point_cloud", PortType.ANY, description="The point cloud (sensor_msgs/PointCloud2)."),
        InputPort("point_cloud_service", PortType.STRING, "/point_cloud_service", "The service MoveIt Pro would call."),
    )

    def update(self) -> Status:
        return self.fail("the planning scene here has no point-cloud (octomap) layer: point clouds cannot be added")


NODES = (GetCurrentPlanningScene, GetJointState, ClearSnapshot, UpdatePlanningSceneService)

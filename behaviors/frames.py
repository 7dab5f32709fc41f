"""MoveIt Pro's pose re-expression nodes: TransformPoseFrame and TransformPoseWithPose.

Frames are those ``behaviors.poses`` knows: ``world``, every robot frame (placed at the current
joint state) and every planning-scene object. MoveIt Pro asks tf2; here the planning scene is
the transform tree.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np
from geometry_msgs.msg import PoseStamped

from runtime.tree.behavior import Behavior, Status
from runtime.tree.ports import InputPort, NameKind, Names, OutputPort, PortType

from .poses import NO_SCENE, FrameError, SceneBehavior, frame_in_world, matrix_to_pose, pose_in_world, pose_to_matrix


def compose(transform: PoseStamped, pose: PoseStamped, stamp_s: float) -> PoseStamped:
    """``transform * pose``: ``pose`` read as expressed in the frame ``transform`` places,
    the result in ``transform``'s own frame (``header.frame_id``)."""
    matrix = pose_to_matrix(transform.pose) @ pose_to_matrix(pose.pose)
    return matrix_to_pose(transform.header.frame_id, matrix, stamp_s)


class TransformPoseFrame(SceneBehavior):
    """MoveIt Pro's TransformPoseFrame: the same pose, expressed in another frame."""

    description: ClassVar[str] = (
        "Express input_pose in target_frame_id (world, a robot frame at the current joint state, or a planning-scene object)."
    )
    ports = (
        InputPort("input_pose", PortType.POSE_STAMPED, description="The pose to re-express."),
        InputPort("target_frame_id", PortType.STRING, "world", "Frame to express it in.", names=Names(NameKind.FRAME)),
        OutputPort("output_pose", PortType.POSE_STAMPED, "The same pose in target_frame_id."),
    )

    def update(self) -> Status:
        scene = self.context.scene
        if scene is None:
            return self.fail(NO_SCENE)
        target = self.get_input("target_frame_id")
        try:
            in_world = pose_in_world(scene, self.get_input("input_pose"), self.state())
            result = np.linalg.inv(frame_in_world(scene, target, self.state())) @ in_world
        except (ValueError, FrameError) as err:
            return self.fail(str(err))
        self.set_output("output_pose", matrix_to_pose(target, result, self.now()))
        return Status.SUCCESS


class TransformPoseWithPose(Behavior):
    """MoveIt Pro's TransformPoseWithPose: apply one pose (as a transform) to another."""

    description: ClassVar[str] = (
        "Compose transform_pose * input_pose: input_pose is read in the frame transform_pose places; "
        "the result is in transform_pose's frame_id."
    )
    ports = (
        InputPort("input_pose", PortType.POSE_STAMPED, description="The pose to move."),
        InputPort("transform_pose", PortType.POSE_STAMPED, description="The transform to apply, as a pose."),
        OutputPort("output_pose", PortType.POSE_STAMPED, "transform_pose * input_pose."),
    )

    def update(self) -> Status:
        try:
            result = compose(self.get_input("transform_pose"), self.get_input("input_pose"), self.context.clock.now())
        except ValueError as err:
            return self.fail(str(err))
        self.set_output("output_pose", result)
        return Status.SUCCESS


NODES = (TransformPoseFrame, TransformPoseWithPose)

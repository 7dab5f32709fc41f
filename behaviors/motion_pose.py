"""MoveToPose: put a robot frame (the TCP by default) at a pose, through the scene's IK.

The target pose (a ``geometry_msgs/PoseStamped`` in any frame the pose behaviors know) is turned
into joint positions with ``runtime.motion.scene.solve_ik``, seeded with the current joint state so
the answer is the nearby solution, not a flipped elbow or wrist; the motion itself is
MoveToJointState's: ruckig, within the limits, collision-checked before it starts. The path is
straight in joint space, not in Cartesian space: keep approach moves short (a few cm).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from runtime.tree.ports import InputPort, NameKind, Names, PortType, Range
from runtime.tree.world import Scene
from runtime.motion.scene.kinematics import solve_ik

from .motion import _MoveToJoints
from .trajectory_goal import PlanningError
from .poses import FrameError, RobotState, as_pose_stamped, pose_in_world


class MoveToPose(_MoveToJoints):
    """Move the joint group so ``tip_frame`` reaches ``target_pose`` (position and orientation)."""

    description = "Move a joint group so a robot frame (default: the TCP) reaches a pose (IK from the current state, then a checked joint motion)."
    ports = (
        InputPort("target_pose", PortType.ANY, description="Where tip_frame should go (geometry_msgs/PoseStamped), e.g. {grasp_pose}."),
        InputPort("tip_frame", PortType.STRING, "tcp", "Robot frame placed at the target (a link or a site such as tcp).", names=Names(NameKind.FRAME)),
        InputPort("position_tolerance", PortType.FLOAT, 0.0005, "Largest IK position error accepted (m).", valid=Range(0.0, 1.0, "m", min_open=True)),
        InputPort("orientation_tolerance", PortType.FLOAT, 0.005, "Largest IK orientation error accepted (rad).", valid=Range(0.0, math.pi, "rad", min_open=True)),
    ) + _MoveToJoints.common_ports

    def target(self, joints: tuple[str, ...]) -> NDArray[np.float64]:
        scene = self.context.scene
        assert scene is not None  # a node that needs the world runs with its scene
        tip = self.get_input("tip_frame")
        if not scene.robot.has_frame(tip):
            raise PlanningError(f"tip_frame '{tip}' is not a frame of the robot model")
        state = RobotState(self.joint_states, self.topic)  # the subscription the base class made
        try:
            pose = as_pose_stamped(self.get_input("target_pose"), "target_pose")
            goal = pose_in_world(scene, pose, state)
            start = state.positions(joints)
        except (ValueError, FrameError) as err:
            raise PlanningError(str(err)) from None
        result = solve_ik(
            scene.robot,
            self.get_input("joint_group_name"),
            goal,
            seeds=[start],
            frame=tip,
            position_tolerance=self.get_input("position_tolerance"),
            orientation_tolerance=self.get_input("orientation_tolerance"),
        )
        if not result.success:
            p = goal[:3, 3]
            raise PlanningError(
                f"no IK solution puts '{tip}' at ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) in 'world': best is "
                f"{result.position_error * 1000:.1f} mm and {result.orientation_error:.3f} rad away"
            )
        return _nearest_turn(result.positions, start, scene, joints)


def _nearest_turn(solution: NDArray[np.float64], start: NDArray[np.float64], scene: Scene, joints: tuple[str, ...]) -> NDArray[np.float64]:
    """Shift each joint by whole turns toward ``start`` when its limits allow (same pose, shorter motion)."""
    lower, upper = scene.robot.position_limits(joints)
    out = solution.copy()
    for i in range(len(out)):
        turns = np.round((start[i] - out[i]) / (2 * np.pi))
        candidate = out[i] + turns * 2 * np.pi
        if lower[i] <= candidate <= upper[i]:
            out[i] = candidate
    return out


NODES = (MoveToPose,)

"""The cell's hardware interface, as the simulated controllers see it (ros2_control style).

The MuJoCo cell implements it (state interfaces: positions, velocities, wrench; command
interfaces: arm position/velocity targets and the gripper). Controllers never touch MuJoCo
directly, so they can be tested against a kinematic fake and could drive other hardware.
"""
from __future__ import annotations

from typing import Protocol

import numpy as np


class Hardware(Protocol):
    arm_joint_names: tuple[str, ...]
    """The six UR5e joints, in the order they are published on /joint_states."""

    gripper_joint_name: str
    """The single gripper joint, ``robotiq_85_left_knuckle_joint`` (0 = open, 0.8 = closed)."""

    def time(self) -> float:
        """Simulation time in seconds (equal to the runtime clock after each world step)."""
        ...

    def arm_position(self) -> np.ndarray: ...

    def arm_velocity(self) -> np.ndarray: ...

    def command_arm(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        """Servo targets for the arm joints (held until the next command)."""
        ...

    def gripper_position(self) -> float: ...

    def gripper_velocity(self) -> float: ...

    def command_gripper(self, position: float, max_effort: float) -> None:
        """Drive the gripper toward ``position`` (driver joint, rad) with at most ``max_effort`` N."""
        ...

    def wrench(self) -> np.ndarray:
        """Fx Fy Fz Tx Ty Tz at the wrist F/T sensor, tared (the gripper's own weight removed).

        Sign and frame, as the admittance controller needs them: the wrench the environment
        applies to the tool (pushing the gripper down gives Fz < 0), expressed in the same frame
        as ``wrist_jacobian`` (the world/base frame). MuJoCo's force/torque sensors report the
        opposite sign in the site frame: negate and rotate by the site's orientation.
        """
        ...

    def tare_wrench(self) -> None:
        """Zero the F/T sensor at its current reading, as a driver's zero service does."""
        ...

    def wrist_jacobian(self) -> np.ndarray:
        """6 x 6 Jacobian of the F/T frame (linear; angular) with respect to the arm joints,
        in the world/base frame (``mujoco.mj_jacSite``), the frame ``wrench`` is expressed in."""
        ...

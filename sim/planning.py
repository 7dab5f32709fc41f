"""The cell's planning scene: the robot model the simulator uses, its limits, the table and the
cubes as world objects. Shared by every world that hosts the cell (MuJoCo or kinematic).

The cubes are there to be grasped, so by default the gripper (the SRDF group ``gripper``: palm
and fingers; a held cube sits within a centimetre of the palm) may touch them
(``CubeContact.GRIPPER``): a policy's grasp is not a collision, while the arm's links keep
``link_padding`` from the cubes, every link keeps it from the table, and an object that appears
in the scene is an obstacle to every link. MoveIt Pro's own vla_sim goes
further and leaves the cubes out of its planning scene; ``CubeContact.NONE`` goes the other way:
the cubes are obstacles to every link until an Objective allows contact (``SetCollisionRule``).
"""
from __future__ import annotations

import enum
from typing import Mapping

import numpy as np
import pinocchio as pin

from runtime.motion.scene import Box, PlanningScene, load_envelope, load_joint_limits, pose_matrix
from runtime.errors import OptionError

from .cell_model import CUBE_COLORS, TABLE_CENTER_XY, TABLE_HALF_SIZE, TABLE_TOP_Z
from .robot_model import ARM_JOINTS, CARTESIAN_LIMITS_PATH, GRIPPER_DRIVER_JOINT, JOINT_LIMITS_PATH, TCP_SITE, planning_robot_model

CUBE_SIZE = 0.03
GRIPPER_GROUP = "gripper"


class CubeContact(enum.Enum):
    """Which robot links may touch the cubes before any Objective says so (``--world-option cube_contact=``)."""

    GRIPPER = "gripper"
    NONE = "none"

    @classmethod
    def parse(cls, value: object) -> CubeContact:
        if isinstance(value, cls):
            return value
        try:
            return cls(str(value).strip().lower())
        except ValueError:
            raise OptionError(f"cube_contact must be {' or '.join(m.value for m in cls)}, got '{value}'") from None


def cube_object(color: str) -> str:
    return f"cube_{color}"


def quat_to_matrix(quat_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(quat_wxyz, dtype=float) / np.linalg.norm(quat_wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def make_cell_scene(
    cube_poses: Mapping[str, tuple[np.ndarray, np.ndarray]],
    cube_size: float = CUBE_SIZE,
    cube_contact: CubeContact = CubeContact.GRIPPER,
) -> PlanningScene:
    """Robot (group ``manipulator`` + the gripper joint), joint limits, the Cartesian envelope,
    table and cubes.

    The robot stands on the table, so the table is allowed against its base and shoulder; the
    gripper is allowed against the cubes unless ``cube_contact`` is ``NONE``.
    """
    robot = planning_robot_model()
    joints = list(ARM_JOINTS) + [GRIPPER_DRIVER_JOINT]
    lower, upper = robot.position_limits(joints)
    limits = load_joint_limits(JOINT_LIMITS_PATH, {j: (lo, hi) for j, lo, hi in zip(joints, lower, upper)})
    envelope = load_envelope(CARTESIAN_LIMITS_PATH, robot, TCP_SITE)
    scene = PlanningScene(robot, "manipulator", GRIPPER_DRIVER_JOINT, limits=limits, envelope=envelope)
    hx, hy, hz = TABLE_HALF_SIZE
    scene.add_object("table", Box((2 * hx, 2 * hy, 2 * hz)), pose_matrix((TABLE_CENTER_XY[0], TABLE_CENTER_XY[1], TABLE_TOP_Z - hz)), fixed=True)
    scene.allow("table", ["base", "shoulder_link"])
    for color in CUBE_COLORS:
        pos, quat = cube_poses[color]
        scene.add_object(cube_object(color), Box((cube_size,) * 3), pose_matrix(pos, quat_to_matrix(quat)))
        if cube_contact is CubeContact.GRIPPER:
            scene.allow(cube_object(color), GRIPPER_GROUP)
    return scene


SYNC_TOLERANCE = 1e-6
"""Metres (and quaternion components): a cube that moved less than this since the last sync is
left alone, so a scene whose cubes rest keeps its collision placements (and its version)."""

CubePoses = Mapping[str, tuple[np.ndarray, np.ndarray]]
SyncedCubes = Mapping[str, list[float]]
"""What ``sync_cubes`` placed in the scene: per cube, its position then its quaternion (7 floats)."""


def sync_cubes(scene: PlanningScene, cube_poses: CubePoses, synced: SyncedCubes | None = None) -> dict[str, list[float]]:
    """Move the scene's cubes to where the world has them (attached cubes move with the robot).

    ``synced`` is what the previous call returned: cubes still within ``SYNC_TOLERANCE`` of it
    are skipped. Returns the poses the scene now holds, to pass back next time.
    """
    carried = {a.name for a in scene.attachments}
    now = dict(synced or {})
    for color, (pos, quat) in cube_poses.items():
        name = cube_object(color)
        if name in carried:
            now.pop(color, None)  # placed afresh once it is released
            continue
        # Plain floats: comparing them costs less than numpy reductions, per cube per tick.
        values = pos.tolist() + quat.tolist()
        last = now.get(color)
        if last is not None and _within(last, values):
            continue
        position, rotation = np.array(pos, dtype=float), quat_to_matrix(quat)
        if not (np.isfinite(position).all() and np.isfinite(rotation).all()):
            raise ValueError(f"the world reports a pose of cube '{color}' that is not finite: position {pos}, quaternion {quat}")
        # A unit quaternion's matrix is a rotation: handed over as a pin.SE3, the scene takes it as
        # it is (checking a 4x4 matrix for a rotation block costs ~40 us, per cube per tick).
        scene.move_object(name, pin.SE3(rotation, position))
        now[color] = values
    return now


def _within(a: list[float], b: list[float]) -> bool:
    # A sleeping cube reports the very same numbers; NaN never equals itself, so it goes on to fail.
    return a == b or all(abs(x - y) < SYNC_TOLERANCE for x, y in zip(a, b))

"""A kinematic cell: the same robot, controllers, topics and policy service as the MuJoCo cell
(``sim.world.CellWorld`` hosts either), without physics. The arm is exactly where its controller
commands it; a cube between closing fingers is carried rigidly and dropped onto whatever is
below when the fingers open; cameras show a flat gray frame.

Use it where physics is beside the point: ExecutePolicy's streaming tests, latency sweeps and
benchmarks (hundreds of simulated seconds per wall second). World name ``kinematic``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from .layouts import layout
from .planning import CUBE_SIZE
from .robot_model import ARM_JOINTS, GRIPPER_DRIVER_JOINT, TCP_SITE, planning_robot_model
from .world import CellWorld, image_size_option

GRIPPER_SPEED = 1.6  # rad/s of the driver joint: fully closed in 0.5 s
GRIPPER_CLOSED_ON_CUBE = 0.52  # driver angle where the 2F-85's pads meet a 30 mm cube
GRASP_RADIUS = 0.025  # a cube centre this close to the TCP is between the fingers


def _yaw_quat(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


@dataclass
class KinematicCell:
    """Implements ``sim.hardware.Hardware`` with perfect tracking and rigid grasps."""

    arm: np.ndarray
    t: float = 0.0
    arm_joint_names: tuple[str, ...] = ARM_JOINTS
    gripper_joint_name: str = GRIPPER_DRIVER_JOINT
    external_wrench: np.ndarray = field(default_factory=lambda: np.zeros(6))
    cubes: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    image_size: int = 32

    def __post_init__(self) -> None:
        self.arm = np.asarray(self.arm, dtype=float).copy()
        self.arm_velocity_now: np.ndarray = np.zeros(6)
        self.gripper = 0.0
        self.gripper_target = 0.0
        self.gripper_rate = 0.0
        self.carried: str | None = None
        self.grasp_offset = np.eye(4)
        self.boxes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._robot = planning_robot_model()
        self._full = self._robot.neutral().copy()
        self._fk_data = self._robot.model.createData()
        self._tcp_frame = self._robot.frame_id(TCP_SITE)
        self._neutral = self._full.tolist()
        self._slots = [(source, *slot) for source, joint in enumerate((*ARM_JOINTS, GRIPPER_DRIVER_JOINT))
                       for slot in _q_slots(self._robot, joint)]
        self.frame = np.full((self.image_size, self.image_size, 3), 128, dtype=np.uint8)
        self.wrench_tare = np.zeros(6)

    # -- Hardware ---
    def time(self) -> float:
        return self.t

    def arm_position(self) -> np.ndarray:
        return self.arm.copy()

    def arm_velocity(self) -> np.ndarray:
        return self.arm_velocity_now.copy()

    def command_arm(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        self.arm_velocity_now = np.zeros(6) if velocity is None else np.array(velocity, dtype=float)
        self.arm = np.array(position, dtype=float)

    def gripper_position(self) -> float:
        return self.gripper

    def gripper_velocity(self) -> float:
        return self.gripper_rate

    def command_gripper(self, position: float, max_effort: float) -> None:
        self.gripper_target = float(min(max(position, 0.0), 0.8))

    def wrench(self) -> np.ndarray:
        return self.external_wrench - self.wrench_tare

    def tare_wrench(self) -> None:
        self.wrench_tare = self.external_wrench.copy()

    def wrist_jacobian(self) -> np.ndarray:
        robot = self._robot
        q = self._configuration()
        frame = robot.frame_id(TCP_SITE)
        J = pin.computeFrameJacobian(robot.model, robot.model.createData(), q, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        return np.asarray(J[:, [robot.joint_q_index(j) for j in ARM_JOINTS]])

    # -- the world's view ---
    @classmethod
    def at_layout(cls, arm: np.ndarray, seed: int, image_size: int = 32) -> KinematicCell:
        cell = cls(arm, image_size=image_size)
        cell.reset(seed, arm)
        return cell

    def cube_poses(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        return {c: self.cube_pose(c) for c in self.cubes}

    def reset(self, seed: int, arm: np.ndarray) -> None:
        self.cubes = {c: (np.array([x, y, CUBE_SIZE / 2]), _yaw_quat(yaw)) for c, (x, y, yaw) in layout(seed).items()}
        self.arm = np.asarray(arm, dtype=float).copy()
        self.wrench_tare = np.zeros(6)
        self.arm_velocity_now = np.zeros(6)
        self.gripper = self.gripper_target = self.gripper_rate = 0.0
        self.carried = None
        self.boxes = {}

    def place_box(self, name: str, size_m: np.ndarray, position_m: np.ndarray, quat_wxyz: np.ndarray) -> None:
        """A placed box is only recorded: without physics nothing can run into it."""
        self.boxes[name] = (np.asarray(size_m, dtype=float).copy(), np.asarray(position_m, dtype=float).copy())

    def remove_box(self, name: str) -> None:
        del self.boxes[name]

    def render(self, camera: str) -> np.ndarray:
        return self.frame

    def snapshot(self) -> None:
        """Nothing to copy: every frame is the same flat gray."""

    def render_snapshot(self, snapshot: None, camera: str) -> np.ndarray:
        return self.frame

    def close_snapshot_renderer(self) -> None:
        pass

    def close(self) -> None:
        pass

    # -- kinematics of the cell ---
    def _configuration(self) -> np.ndarray:
        """Same ``q`` as ``RobotModel.configuration`` for the arm and gripper driver, from slots found once.

        Not ``RobotModel.configuration_map``: its vectorised map takes twice as long for one row
        (4.5 vs 2.1 us), and this runs up to twice a control step (measured: the kinematic world
        9 % slower end to end with it). Filled as a list of floats, made an array once."""
        values = self.arm.tolist()
        values.append(float(self.gripper))
        q = self._neutral.copy()
        for source, idx, mult, offset, unbounded in self._slots:
            v = mult * values[source] + offset
            if unbounded:
                q[idx], q[idx + 1] = np.cos(v), np.sin(v)
            else:
                q[idx] = v
        return np.array(q)

    def tcp_pose(self) -> np.ndarray:
        """Same pose as ``runtime.motion.scene.frame_pose`` (same pinocchio calls), on one reused ``Data``."""
        model, data = self._robot.model, self._fk_data
        pin.forwardKinematics(model, data, self._configuration())
        return pin.updateFramePlacement(model, data, self._tcp_frame).homogeneous.copy()

    def cube_pose(self, color: str) -> tuple[np.ndarray, np.ndarray]:
        pos, quat = self.cubes[color]
        return pos.copy(), quat.copy()

    def step(self, dt: float) -> None:
        self.t += dt
        target = self.gripper_target
        # The 0.52 limit only bites when the target is past it, so the FK behind it runs only then.
        if target > GRIPPER_CLOSED_ON_CUBE and (self.carried or self._cube_between_fingers()):
            target = GRIPPER_CLOSED_ON_CUBE
        move = min(max(target - self.gripper, -GRIPPER_SPEED * dt), GRIPPER_SPEED * dt)
        self.gripper += move
        self.gripper_rate = move / dt
        if self.carried is None and self.gripper >= GRIPPER_CLOSED_ON_CUBE - 1e-6:
            self._grasp()
        elif self.carried is not None and self.gripper_target < GRIPPER_CLOSED_ON_CUBE - 0.1:
            self._release()
        if self.carried is not None:
            pose = self.tcp_pose() @ self.grasp_offset
            self.cubes[self.carried] = (pose[:3, 3].copy(), _matrix_quat(pose[:3, :3]))

    def _cube_between_fingers(self) -> str | None:
        tcp = self.tcp_pose()[:3, 3]
        for color, (pos, _) in self.cubes.items():
            if np.linalg.norm(pos - tcp) < GRASP_RADIUS:
                return color
        return None

    def _grasp(self) -> None:
        color = self._cube_between_fingers()
        if color is None:
            return
        self.carried = color
        pos, quat = self.cubes[color]
        cube = np.eye(4)
        cube[:3, :3], cube[:3, 3] = _quat_matrix(quat), pos
        self.grasp_offset = np.linalg.inv(self.tcp_pose()) @ cube

    def _release(self) -> None:
        color, self.carried = self.carried, None
        assert color is not None  # released only while carrying
        pos, quat = self.cubes[color]
        support = 0.0
        for other, (opos, _) in self.cubes.items():
            if other != color and np.all(np.abs(opos[:2] - pos[:2]) < CUBE_SIZE) and opos[2] < pos[2]:
                support = max(support, opos[2] + CUBE_SIZE / 2)
        pos = pos.copy()
        pos[2] = support + CUBE_SIZE / 2
        self.cubes[color] = (pos, quat)


_QSlot = tuple[int, float, float, bool]  # q index, multiplier, offset, stored as (cos, sin)


def _q_slots(robot: Any, joint: str) -> list[_QSlot]:
    """Where one value of ``joint`` lands in a full ``q`` (itself and its coupled followers)."""
    model = robot.model
    return [(robot.joint_q_index(target), mult, offset, model.joints[model.getJointId(target)].nq == 2)
            for target, mult, offset in robot.driven_by(joint)]


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    return pin.Quaternion(q[0], q[1], q[2], q[3]).toRotationMatrix()


def _matrix_quat(R: np.ndarray) -> np.ndarray:
    q = pin.Quaternion(R)
    return np.array([q.w, q.x, q.y, q.z])


class KinematicWorld(CellWorld):
    """World ``kinematic`` (a ``CellWorld`` around a ``KinematicCell``)."""

    def __init__(self, options: dict[str, Any]) -> None:
        size = image_size_option(options, 32)
        super().__init__("kinematic", options, lambda arm, seed: KinematicCell.at_layout(arm, seed, size))


def create_kinematic(options: dict[str, Any]) -> KinematicWorld:
    """World ``kinematic``: perfect tracking and rigid grasps, no physics."""
    return KinematicWorld(options)

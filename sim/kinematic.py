"""A kinematic cell: the same robot, controllers, topics and policy service as the MuJoCo cell,
without physics. The arm is exactly where its controller commands it; a cube between closing
fingers is carried rigidly and dropped onto whatever is below when the fingers open.

Use it where physics is beside the point: ExecutePolicy's streaming tests, latency sweeps and
benchmarks (hundreds of simulated seconds per wall second). World name ``kinematic``.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin
from geometry_msgs.msg import TransformStamped
from sensor_msgs.msg import Image, JointState

from runtime.behavior import RunContext
from runtime.scene import frame_pose
from runtime.timestamps import time_msg

from .cell_model import CUBE_COLORS
from .controllers import make_controllers
from .layouts import layout
from .policy.embedded import serve_embedded_policy
from .policy.oracle_remote import CUBE_POSE_TOPIC, cube_pose_msg
from .planning import CUBE_SIZE, cell_robot, make_cell_scene, sync_cubes
from .robot_model import ARM_JOINTS, GRIPPER_DRIVER_JOINT, TCP_SITE, load_waypoints

CONTROL_PERIOD = 0.002
GRIPPER_SPEED = 1.6  # rad/s of the driver joint: fully closed in 0.5 s
GRIPPER_CLOSED_ON_CUBE = 0.52  # driver angle where the 2F-85's pads meet a 30 mm cube
GRASP_RADIUS = 0.025  # a cube centre this close to the TCP is between the fingers
CAMERA_TOPICS = {"scene": "/scene_camera/color", "wrist": "/wrist_camera/color", "overview": "/overview_camera/color"}


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

    def __post_init__(self) -> None:
        self.arm = np.asarray(self.arm, dtype=float).copy()
        self.arm_velocity_now = np.zeros(6)
        self.gripper = 0.0
        self.gripper_target = 0.0
        self.gripper_rate = 0.0
        self.carried: str | None = None
        self.grasp_offset = np.eye(4)
        self._robot = cell_robot()
        self._full = self._robot.neutral().copy()

    # -- Hardware ---
    def time(self) -> float:
        return self.t

    def arm_position(self) -> np.ndarray:
        return self.arm.copy()

    def arm_velocity(self) -> np.ndarray:
        return self.arm_velocity_now.copy()

    def command_arm(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        self.arm_velocity_now = np.zeros(6) if velocity is None else np.asarray(velocity, dtype=float).copy()
        self.arm = np.asarray(position, dtype=float).copy()

    def gripper_position(self) -> float:
        return self.gripper

    def gripper_velocity(self) -> float:
        return self.gripper_rate

    def command_gripper(self, position: float, max_effort: float) -> None:
        self.gripper_target = float(np.clip(position, 0.0, 0.8))

    def wrench(self) -> np.ndarray:
        return self.external_wrench.copy()

    def wrist_jacobian(self) -> np.ndarray:
        robot = self._robot
        q = self._configuration()
        frame = robot.frame_id(TCP_SITE)
        J = pin.computeFrameJacobian(robot.model, robot.model.createData(), q, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        return np.asarray(J[:, [robot.joint_q_index(j) for j in ARM_JOINTS]])

    # -- kinematics of the cell ---
    def _configuration(self) -> np.ndarray:
        return self._robot.configuration({**dict(zip(ARM_JOINTS, self.arm)), GRIPPER_DRIVER_JOINT: self.gripper}, self._full)

    def tcp_pose(self) -> np.ndarray:
        return frame_pose(self._robot, self._configuration(), TCP_SITE)

    def cube_pose(self, color: str) -> tuple[np.ndarray, np.ndarray]:
        pos, quat = self.cubes[color]
        return pos.copy(), quat.copy()

    def step(self, dt: float) -> None:
        self.t += dt
        limit = GRIPPER_CLOSED_ON_CUBE if self.carried or self._cube_between_fingers() else 0.8
        target = min(self.gripper_target, limit)
        move = float(np.clip(target - self.gripper, -GRIPPER_SPEED * dt, GRIPPER_SPEED * dt))
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
        pos, quat = self.cubes[color]  # type: ignore[index]
        support = 0.0
        for other, (opos, _) in self.cubes.items():
            if other != color and np.all(np.abs(opos[:2] - pos[:2]) < CUBE_SIZE) and opos[2] < pos[2]:
                support = max(support, opos[2] + CUBE_SIZE / 2)
        pos = pos.copy()
        pos[2] = support + CUBE_SIZE / 2
        self.cubes[color] = (pos, quat)


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    return pin.Quaternion(q[0], q[1], q[2], q[3]).toRotationMatrix()


def _matrix_quat(R: np.ndarray) -> np.ndarray:
    q = pin.Quaternion(R)
    return np.array([q.w, q.x, q.y, q.z])


class KinematicWorld:
    """World ``kinematic``: the cell's services on the bus, stepped at 500 Hz without physics."""

    name = "kinematic"
    OPTIONS = ("seed", "realtime", "policy_latency", "record_dir", "image_size", "policy", "start", "joint_states_reliable")

    def __init__(self, options: dict[str, Any]) -> None:
        unknown = sorted(set(options) - set(self.OPTIONS))
        if unknown:
            raise ValueError(f"world 'kinematic': unknown options {', '.join(unknown)} (known: {', '.join(self.OPTIONS)})")
        self.options = options
        self.seed = int(options.get("seed") or 0)
        self.image_size = int(options.get("image_size") or 32)
        self.waypoints = load_waypoints()
        start = options.get("start") or "Ready"
        self.start_arm = np.array([self.waypoints[start][j] for j in ARM_JOINTS])
        self.cell = self._new_cell(self.seed)

    def _new_cell(self, seed: int) -> KinematicCell:
        cubes = {c: (np.array([x, y, CUBE_SIZE / 2]), _yaw_quat(yaw)) for c, (x, y, yaw) in layout(seed).items()}
        return KinematicCell(self.start_arm, cubes=cubes)

    # -- World ---
    def start(self, context: RunContext) -> None:
        self.context = context
        bus = context.bus
        self.controllers = make_controllers(bus, self.cell, context.clock)
        reliable = bool(self.options.get("joint_states_reliable", True))
        self.joint_states = bus.create_publisher("/joint_states", JointState, reliable=reliable)
        self.frame = np.full((self.image_size, self.image_size, 3), 128, dtype=np.uint8)
        for topic in CAMERA_TOPICS.values():
            bus.create_lazy_publisher(topic, Image, self._camera_frame)
        for color in self.cell.cubes:  # the remote oracle's privileged view; produced only when read
            bus.create_lazy_publisher(CUBE_POSE_TOPIC.format(color=color), TransformStamped,
                                      functools.partial(self._cube_pose, color), rate_hz=50.0)
        context.scene = make_cell_scene(self.cell.cubes)
        context.resources["waypoints"] = self.waypoints
        context.world = self
        self.adapter = serve_embedded_policy(bus, self.options.get("policy"), self.cell, self.options.get("policy_latency"), self.seed)
        self._publish()

    def step_to(self, t: float) -> None:
        while self.cell.t + CONTROL_PERIOD <= t + 1e-9:
            self.controllers.update(self.cell.t, CONTROL_PERIOD)
            self.cell.step(CONTROL_PERIOD)
        self._publish()
        sync_cubes(self.context.scene, self.cell.cubes)

    def reset(self, seed: int) -> None:
        self.seed = seed
        self.cell.cubes = self._new_cell(seed).cubes
        self.cell.arm = self.start_arm.copy()
        self.cell.carried = None
        self.controllers.reset()
        sync_cubes(self.context.scene, self.cell.cubes)
        self._publish()

    def summary(self) -> dict[str, Any]:
        return {
            "cubes": {c: [round(float(v), 4) for v in self.cell.cubes[c][0]] for c in CUBE_COLORS},
            "gripper": round(self.cell.gripper, 4),
            "carried": self.cell.carried,
        }

    def close(self) -> None:
        pass

    # -- publishing ---
    def _publish(self) -> None:
        msg = JointState()
        t = self.cell.t
        msg.header.stamp = time_msg(t)
        msg.name = list(ARM_JOINTS) + [GRIPPER_DRIVER_JOINT]
        msg.position = self.cell.arm.tolist() + [self.cell.gripper]
        msg.velocity = self.cell.arm_velocity_now.tolist() + [self.cell.gripper_rate]
        self.joint_states.publish(msg)

    def _cube_pose(self, color: str) -> TransformStamped:
        position, quat = self.cell.cubes[color]
        return cube_pose_msg(color, position, quat, self.cell.t)

    def _camera_frame(self) -> Image:
        from .policy.images import rgb_to_image

        return rgb_to_image(self.frame)


def create(options: dict[str, Any]) -> KinematicWorld:
    return KinematicWorld(options)

"""The stack's keypoints: the arm's joints at the four poses of a stack, from the located cubes.

A stack of the blue cube on the green one passes four tool poses, each pointing straight down:
above the blue cube (``pre_grasp``), at its grasp height (``grasp``), above the green cube
(``pre_place``) and where the held cube is released on it (``place``). :func:`stack_poses` gives them
from the cubes' positions and face yaws (the grasp squares the cube: its yaw is the face yaw
closest to the tool's heading, the place's the green cube's face yaw closest to the grasp's).

The learned stacking policy reads the located cubes through these poses: :class:`ArmChain` (the
arm's kinematic chain, numpy only, carried in the checkpoint's ``objective_policy.json`` as the
camera poses are) solves each for the arm's joints, chained from Home, and the chunk model is
conditioned on the keypoints' offsets from the observed joints (:func:`keypoint_features`). The
oracle (``sim.oracle``) plans its stacks through the same :func:`stack_poses`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from runtime.errors import ObjectiveError

KEYPOINTS = ("pre_grasp", "grasp", "pre_place", "place")
MAX_IK_STEP_RAD = 0.3
"""The largest change of a joint in one step of the IK solver (keeps an unreachable target's answer near)."""


class KeypointError(ObjectiveError, ValueError):
    """A keypoint has no joint solution, or the keypoint configuration is malformed."""


# ---------------------------------------------------------------------------------------------
# Poses (pure)
# ---------------------------------------------------------------------------------------------
def wrap_quarter(angle: float) -> float:
    """``angle`` modulo pi/2, in [-pi/4, pi/4)."""
    return (angle + math.pi / 4) % (math.pi / 2) - math.pi / 4


def tcp_yaw(pose: NDArray[np.float64]) -> float:
    """Heading of the TCP's x axis projected on the table."""
    return math.atan2(pose[1, 0], pose[0, 0])


def aligned_yaw(face_yaw: float, reference: float) -> float:
    """The yaw equal to ``face_yaw`` modulo pi/2 that is closest to ``reference``."""
    return reference + wrap_quarter(face_yaw - reference)


def top_down_pose(position: Sequence[float] | NDArray[np.float64], yaw: float) -> NDArray[np.float64]:
    """TCP pose at ``position`` pointing straight down, its x axis at heading ``yaw``.

    With z = -world z and x = (cos yaw, sin yaw, 0), the fingers (closing along y) close along
    (sin yaw, -cos yaw, 0).
    """
    c, s = math.cos(yaw), math.sin(yaw)
    pose = np.eye(4)
    pose[:3, 0] = (c, s, 0.0)
    pose[:3, 1] = (s, -c, 0.0)
    pose[:3, 2] = (0.0, 0.0, -1.0)
    pose[:3, 3] = position
    return pose


@dataclass(frozen=True)
class StackGeometry:
    """Where the tool goes relative to the cubes."""

    grasp_height_m: float = 0.018
    """TCP above the top cube's centre when grasping."""
    approach_height_m: float = 0.10
    """How far above the grasp and the place the tool approaches and retreats."""
    cube_size_m: float = 0.03
    place_clearance_m: float = 0.002
    """Gap left under the top cube when it is released."""


@dataclass(frozen=True)
class StackPoses:
    """The four tool poses of a stack (4x4 each) and the grasp's and the place's yaws (rad)."""

    pre_grasp: NDArray[np.float64]
    grasp: NDArray[np.float64]
    pre_place: NDArray[np.float64]
    place: NDArray[np.float64]
    grasp_yaw_rad: float
    place_yaw_rad: float


def stack_poses(top_position_m: Sequence[float] | NDArray[np.float64], top_face_yaw_rad: float,
                bottom_position_m: Sequence[float] | NDArray[np.float64],
                bottom_face_yaw_rad: float, tool_yaw_rad: float, geometry: StackGeometry) -> StackPoses:
    """The stack's tool poses for cubes at these centres and face yaws, the tool now heading ``tool_yaw_rad``."""
    top, bottom = np.asarray(top_position_m, dtype=float), np.asarray(bottom_position_m, dtype=float)
    grasp_yaw = aligned_yaw(top_face_yaw_rad, tool_yaw_rad)
    # The held cube keeps its offset to the TCP; rotate to the bottom cube's faces for a neat stack.
    place_yaw = aligned_yaw(bottom_face_yaw_rad, grasp_yaw)
    grasp = top + np.array([0.0, 0.0, geometry.grasp_height_m])
    place = bottom + np.array([0.0, 0.0, geometry.cube_size_m + geometry.place_clearance_m + geometry.grasp_height_m])
    up = np.array([0.0, 0.0, geometry.approach_height_m])
    return StackPoses(top_down_pose(grasp + up, grasp_yaw), top_down_pose(grasp, grasp_yaw),
                      top_down_pose(place + up, place_yaw), top_down_pose(place, place_yaw), grasp_yaw, place_yaw)


# ---------------------------------------------------------------------------------------------
# The arm's kinematic chain (numpy)
# ---------------------------------------------------------------------------------------------
def _matrix(values: Any, shape: tuple[int, ...], what: str) -> NDArray[np.float64]:
    array = np.asarray(values, dtype=float)
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise KeypointError(f"{what} must be {shape} finite numbers, got {values!r}")
    return array


def _rotation_about(axis: NDArray[np.float64], angle: float) -> NDArray[np.float64]:
    """Rodrigues' rotation of ``angle`` about the unit ``axis``."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    result: NDArray[np.float64] = np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)
    return result


def _rotation_error(target: NDArray[np.float64], current: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rotation vector (world axes) that turns ``current`` into ``target``."""
    r = target @ current.T
    angle = math.acos(max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0)))
    vee = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if angle < 1e-9:
        return vee / 2.0
    if math.pi - angle < 1e-6:  # half a turn: the axis from the symmetric part
        axis = np.sqrt(np.maximum((np.diag(r) + 1.0) / 2.0, 0.0))
        result: NDArray[np.float64] = axis * angle
        return result
    return vee * angle / (2.0 * math.sin(angle))


@dataclass(frozen=True)
class ArmChain:
    """A serial arm of revolute joints up to its tool frame.

    Joint ``i`` sits at ``placements[i]`` (4x4, in joint ``i - 1``'s frame; the first in the world)
    and turns about ``axes[i]`` (its own frame); the tool is at ``tool`` in the last joint's frame.
    """

    joint_names: tuple[str, ...]
    placements: tuple[NDArray[np.float64], ...]
    axes: tuple[NDArray[np.float64], ...]
    tool: NDArray[np.float64]
    lower_rad: NDArray[np.float64]
    upper_rad: NDArray[np.float64]

    def frames(self, q: NDArray[np.float64]) -> tuple[list[NDArray[np.float64]], NDArray[np.float64]]:
        """Each joint's world frame (4x4, turned by its angle) and the tool's pose."""
        pose, frames = np.eye(4), []
        for placement, axis, angle in zip(self.placements, self.axes, np.asarray(q, dtype=float)):
            pose = pose @ placement
            turned = np.eye(4)
            turned[:3, :3] = _rotation_about(axis, float(angle))
            pose = pose @ turned
            frames.append(pose)
        return frames, pose @ self.tool

    def tool_pose(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.frames(q)[1]

    def solve_ik(self, target: NDArray[np.float64], seed: NDArray[np.float64], max_iterations: int = 300, tolerance_m: float = 1e-6,
                 tolerance_rad: float = 1e-5, damping: float = 1e-6) -> NDArray[np.float64]:
        """Joints that put the tool at ``target`` (4x4), by damped least squares from ``seed`` alone
        (no restarts: the keypoints chain from Home and must stay on its branch)."""
        q = np.asarray(seed, dtype=float).copy()
        error = np.zeros(6)
        for _ in range(max_iterations):
            frames, pose = self.frames(q)
            error[:3] = target[:3, 3] - pose[:3, 3]
            error[3:] = _rotation_error(target[:3, :3], pose[:3, :3])
            if np.linalg.norm(error[:3]) < tolerance_m and np.linalg.norm(error[3:]) < tolerance_rad:
                return q
            jacobian = np.empty((6, len(q)))
            for column, (frame, axis) in enumerate(zip(frames, self.axes)):
                world_axis = frame[:3, :3] @ axis
                jacobian[:3, column] = np.cross(world_axis, pose[:3, 3] - frame[:3, 3])
                jacobian[3:, column] = world_axis
            step = jacobian.T @ np.linalg.solve(jacobian @ jacobian.T + damping * np.eye(6), error)
            step *= min(1.0, MAX_IK_STEP_RAD / max(float(np.abs(step).max()), 1e-12))
            q = np.clip(q + step, self.lower_rad, self.upper_rad)
        raise KeypointError(f"no joint solution for the tool at {np.round(target[:3, 3], 3).tolist()} from "
                            f"{np.round(seed, 3).tolist()} (left {np.linalg.norm(error[:3]) * 1000:.1f} mm, "
                            f"{np.linalg.norm(error[3:]):.3f} rad off)")

    def to_json(self) -> dict[str, Any]:
        return {"joint_names": list(self.joint_names), "placements": [p.tolist() for p in self.placements],
                "axes": [a.tolist() for a in self.axes], "tool": self.tool.tolist(),
                "lower_rad": self.lower_rad.tolist(), "upper_rad": self.upper_rad.tolist()}

    @classmethod
    def from_json(cls, data: Any, where: str) -> ArmChain:
        try:
            names = tuple(str(n) for n in data["joint_names"])
            count = len(names)
            chain = cls(names, tuple(_matrix(p, (4, 4), "a placement") for p in data["placements"]),
                        tuple(_matrix(a, (3,), "an axis") for a in data["axes"]), _matrix(data["tool"], (4, 4), "tool"),
                        _matrix(data["lower_rad"], (count,), "lower_rad"), _matrix(data["upper_rad"], (count,), "upper_rad"))
        except (KeyError, TypeError) as exc:
            raise KeypointError(f"{where}: arm_chain needs joint_names, placements, axes, tool, lower_rad and "
                                f"upper_rad ({exc!r})") from None
        except KeypointError as exc:
            raise KeypointError(f"{where}: arm_chain: {exc}") from None
        if not (len(chain.placements) == len(chain.axes) == count):
            raise KeypointError(f"{where}: arm_chain has {count} joint names, {len(chain.placements)} placements and "
                                f"{len(chain.axes)} axes")
        return chain


# ---------------------------------------------------------------------------------------------
# The keypoints of located cubes
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class KeypointConfig:
    """What the policy needs to turn located cubes into keypoints (``objective_policy.json``'s ``stack_keypoints``)."""

    chain: ArmChain
    home_rad: NDArray[np.float64]
    """The arm at Home, where the keypoints chain from."""
    geometry: StackGeometry
    cube_center_z_m: float
    """Height of a cube's centre on the table (the located cubes are on the table)."""

    def to_json(self) -> dict[str, Any]:
        g = self.geometry
        return {"arm_chain": self.chain.to_json(), "home_rad": self.home_rad.tolist(),
                "grasp_height_m": g.grasp_height_m, "approach_height_m": g.approach_height_m,
                "cube_size_m": g.cube_size_m, "place_clearance_m": g.place_clearance_m,
                "cube_center_z_m": self.cube_center_z_m}

    @classmethod
    def from_json(cls, data: Any, where: str) -> KeypointConfig:
        if not isinstance(data, dict):
            raise KeypointError(f"{where}: stack_keypoints must be an object, got {type(data).__name__}")
        chain = ArmChain.from_json(data.get("arm_chain"), where)
        try:
            numbers = {key: float(data[key]) for key in ("grasp_height_m", "approach_height_m", "cube_size_m",
                                                         "place_clearance_m", "cube_center_z_m")}
        except (KeyError, TypeError, ValueError) as exc:
            raise KeypointError(f"{where}: stack_keypoints needs numbers grasp_height_m, approach_height_m, cube_size_m, "
                                f"place_clearance_m and cube_center_z_m ({exc!r})") from None
        home = _matrix(data.get("home_rad"), (len(chain.joint_names),), f"{where}: stack_keypoints.home_rad")
        center_z = numbers.pop("cube_center_z_m")
        return cls(chain, home, StackGeometry(**numbers), center_z)


def stack_keypoints(cubes: NDArray[np.float64], config: KeypointConfig) -> NDArray[np.float64]:
    """(4, joints): the arm at ``KEYPOINTS`` for located cubes ``cubes`` (x, y, face yaw of the top cube,
    then of the bottom one: ``cube_locator.cube_features``), each solved from the one the arm comes from
    (the pre-grasp from Home, the pre-place from the pre-grasp, where the lift ends)."""
    cubes = np.asarray(cubes, dtype=float)
    if cubes.shape != (6,) or not np.all(np.isfinite(cubes)):
        raise KeypointError(f"the located cubes must be 6 finite numbers (x, y, yaw of each), got {cubes.tolist()}")
    z = config.cube_center_z_m
    poses = stack_poses((cubes[0], cubes[1], z), float(cubes[2]), (cubes[3], cubes[4], z), float(cubes[5]),
                        tcp_yaw(config.chain.tool_pose(config.home_rad)), config.geometry)
    chain = config.chain
    pre_grasp = chain.solve_ik(poses.pre_grasp, config.home_rad)
    grasp = chain.solve_ik(poses.grasp, pre_grasp)
    pre_place = chain.solve_ik(poses.pre_place, pre_grasp)  # the lift returns to the pre-grasp
    return np.stack([pre_grasp, grasp, pre_place, chain.solve_ik(poses.place, pre_place)])


FINE_SCALE_RAD = 0.05
"""The scale of the keypoint offsets' fine copy: ``tanh(offset / FINE_SCALE_RAD)`` resolves the last
centimetres of an approach, which the offsets themselves (normalised over their range of radians) blur."""


def keypoint_feature_count(arm_joints: int) -> int:
    """How many values ``keypoint_features`` gives for an arm of ``arm_joints`` joints."""
    return 2 * len(KEYPOINTS) * arm_joints


def keypoint_features(arm_rad: NDArray[np.floating[Any]], keypoints: NDArray[np.float64]) -> NDArray[np.float64]:
    """The keypoints' offsets from the observed arm joints, flattened keypoint by keypoint, then their fine
    copy (``FINE_SCALE_RAD``). Batched: ``arm_rad`` (..., J) and ``keypoints`` (..., 4, J) give (..., 8 J)."""
    arm = np.asarray(arm_rad, dtype=float)
    offsets = (np.asarray(keypoints, dtype=float) - arm[..., None, :]).reshape(*arm.shape[:-1], -1)
    return np.concatenate([offsets, np.tanh(offsets / FINE_SCALE_RAD)], axis=-1)

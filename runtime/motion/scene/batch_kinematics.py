"""Forward kinematics of a few frames over many configurations at once, in numpy.

The Cartesian envelope reads the tool's pose and velocity at every densified point of a motion
(hundreds per chunk). pinocchio answers one configuration per call; this module composes the
joint transforms of the frames' kinematic chains for all configurations together, so a chunk
costs a few array operations per joint instead of several pinocchio calls per point.

It covers the joints of serial arms: revolute about a frame axis or any axis (bounded or
continuous) and prismatic along one. ``BatchKinematics.supports`` says whether a chain has only
those; callers use pinocchio point by point otherwise. Results equal pinocchio's (``oMf`` and
``getFrameVelocity`` in ``LOCAL_WORLD_ALIGNED``) to rounding: tests/test_envelope.py compares them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import NDArray
import pinocchio as pin

_AXES = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}


@dataclass(frozen=True)
class _Joint:
    parent: int
    """Position of the parent joint in the chain; -1 for the world."""
    rotation: NDArray[np.float64]
    """(3, 3) placement in the parent joint's frame at zero."""
    translation: NDArray[np.float64]
    revolute: bool
    """True: rotation about ``axis``; False: translation along it."""
    axis: NDArray[np.float64]
    """Unit axis in the joint's own frame."""
    q_index: int
    continuous: bool
    """The configuration holds (cos, sin) of the angle (pinocchio's RUB joints)."""
    v_index: int


@dataclass(frozen=True)
class FrameStates:
    positions: NDArray[np.float64]
    """(N, F, 3): each frame's origin in the world."""
    point_last_rotations: tuple[NDArray[np.float64], ...]
    """Each frame's orientation in the world, (3, 3, N) per frame."""
    twist: NDArray[np.float64] | None = None
    """(N, 6): one frame's linear then angular velocity, world axes at its origin, when asked."""

    def rotations(self, frame: int) -> NDArray[np.float64]:
        """(N, 3, 3): frame number ``frame``'s orientation at each point."""
        return self.point_last_rotations[frame].transpose(2, 0, 1)

    def axis(self, frame: int, axis: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 3): ``axis`` (in frame number ``frame``) in the world at each point."""
        world: NDArray[np.float64] = np.matmul(np.asarray(axis, dtype=float), self.point_last_rotations[frame]).T
        return world


def _joint_kind(joint: pin.JointModel) -> tuple[bool, NDArray[np.float64], bool] | None:
    """(revolute, unit axis, continuous) of a joint this module handles, else None."""
    name = joint.shortname()
    if name in ("JointModelRX", "JointModelRY", "JointModelRZ"):
        return True, np.array(_AXES[name[-1]]), False
    if name in ("JointModelRUBX", "JointModelRUBY", "JointModelRUBZ"):
        return True, np.array(_AXES[name[-1]]), True
    if name in ("JointModelPX", "JointModelPY", "JointModelPZ"):
        return False, np.array(_AXES[name[-1]]), False
    if name in ("JointModelRevoluteUnaligned", "JointModelPrismaticUnaligned"):
        axis = np.asarray(joint.extract().axis, dtype=float)
        return name == "JointModelRevoluteUnaligned", axis / np.linalg.norm(axis), False
    return None


def _ancestors(model: pin.Model, joint_id: int) -> list[int]:
    chain = []
    while joint_id > 0:
        chain.append(joint_id)
        joint_id = int(model.parents[joint_id])
    return chain[::-1]


class BatchKinematics:
    """World poses and velocities of ``frame_ids`` of ``model`` for ``(N, nq)`` configurations."""

    def __init__(self, model: pin.Model, frame_ids: Sequence[int]) -> None:
        joint_ids = sorted({j for fid in frame_ids for j in _ancestors(model, int(model.frames[fid].parentJoint))})
        order = {j: k for k, j in enumerate(joint_ids)}
        self.supported = True
        self._joints: list[_Joint] = []
        for j in joint_ids:
            kind = _joint_kind(model.joints[j])
            if kind is None:
                self.supported = False
                break
            placement = model.jointPlacements[j]
            parent = int(model.parents[j])
            self._joints.append(_Joint(order[parent] if parent > 0 else -1, np.array(placement.rotation),
                                       np.array(placement.translation), kind[0], kind[1],
                                       int(model.idx_qs[j]), kind[2], int(model.idx_vs[j])))
        self._frames = [(order.get(int(model.frames[fid].parentJoint), -1), np.array(model.frames[fid].placement.rotation),
                         np.array(model.frames[fid].placement.translation)) for fid in frame_ids]
        self._chains = [[order[j] for j in _ancestors(model, int(model.frames[fid].parentJoint))] for fid in frame_ids]
        self._q_columns = [joint.q_index for joint in self._joints]
        self._v_columns = [joint.v_index for joint in self._joints]
        self._continuous = [k for k, joint in enumerate(self._joints) if joint.continuous]

    def states(self, q: NDArray[np.float64], v: NDArray[np.float64] | None = None, twist_frame: int | None = None) -> FrameStates:
        """The frames' world poses at each row of ``q`` (N, nq); with ``v`` (N, nv) and
        ``twist_frame`` (a position in ``frame_ids``), that frame's velocity too."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        rotations, positions = self._joint_poses(q)
        count = len(q)
        frame_r, frame_p = [], []
        for parent, rotation, translation in self._frames:
            if parent < 0:
                frame_r.append(np.broadcast_to(rotation[:, :, None], (3, 3, count)))
                frame_p.append(np.broadcast_to(translation[:, None], (3, count)))
            else:
                frame_r.append(np.matmul(rotation.T, rotations[parent]))
                frame_p.append(positions[parent] + np.matmul(translation, rotations[parent]))
        twist = None
        if v is not None and twist_frame is not None:
            v = np.atleast_2d(np.asarray(v, dtype=float))
            twist = self._twist(rotations, positions, frame_p[twist_frame], v, twist_frame)
        return FrameStates(np.stack(frame_p).transpose(2, 0, 1), tuple(frame_r), twist)

    def _joint_poses(self, q: NDArray[np.float64]) -> tuple[list[NDArray[np.float64]], list[NDArray[np.float64]]]:
        """Each chain joint's world rotation and origin, in chain order. Arrays are laid out
        point-last, (3, 3, N) and (3, N), so that each matrix element is one contiguous row."""
        count = len(q)
        identity = np.broadcast_to(np.eye(3)[:, :, None], (3, 3, count))
        origin = np.zeros((3, count))
        values = q.T[self._q_columns]  # (J, N): each joint's angle or displacement
        for k in self._continuous:
            index = self._joints[k].q_index
            values[k] = np.arctan2(q[:, index + 1], q[:, index])
        cosines, sines = np.cos(values), np.sin(values)
        rotations: list[NDArray[np.float64]] = []
        positions: list[NDArray[np.float64]] = []
        for k, joint in enumerate(self._joints):
            parent_r, parent_p = (identity, origin) if joint.parent < 0 else (rotations[joint.parent], positions[joint.parent])
            r0 = np.matmul(joint.rotation.T, parent_r)  # parent_r @ placement, element by element
            p0 = parent_p + np.matmul(joint.translation, parent_r)
            if joint.revolute:
                rotations.append(_rotated(r0, joint.axis, cosines[k], sines[k]))
                positions.append(p0)
            else:
                rotations.append(r0)
                positions.append(p0 + np.matmul(joint.axis, r0) * values[k])
        return rotations, positions

    def _twist(self, rotations: list[NDArray[np.float64]], positions: list[NDArray[np.float64]], origin: NDArray[np.float64], v: NDArray[np.float64],
               frame: int) -> NDArray[np.float64]:
        """(N, 6): linear then angular velocity of frame ``frame`` at ``origin`` (3, N), world
        axes (pinocchio's LOCAL_WORLD_ALIGNED): the sum over the chain's joints of each joint's
        world axis times its rate, for the angular part, and for the linear part of
        ``axis x (origin - joint origin)`` (revolute) or ``axis`` (prismatic) times its rate."""
        chain = self._chains[frame]
        if not chain:
            return np.zeros((origin.shape[1], 6))
        rates = v.T[[self._v_columns[k] for k in chain]]  # (C, N)
        axes = np.stack([np.matmul(self._joints[k].axis, rotations[k]) for k in chain]) * rates[:, None, :]  # (C, 3, N)
        revolute = [i for i, k in enumerate(chain) if self._joints[k].revolute]
        sliding = [i for i, k in enumerate(chain) if not self._joints[k].revolute]
        turning = axes[revolute]
        angular = turning.sum(axis=0)
        # sum of w_i x (origin - p_i) = (sum of w_i) x origin - sum of w_i x p_i
        linear = _cross(angular, origin) - _cross(turning, np.stack([positions[chain[i]] for i in revolute])).sum(axis=0)
        if sliding:
            linear += axes[sliding].sum(axis=0)
        return np.vstack((linear, angular)).T


def _rotated(r0: NDArray[np.float64], axis: NDArray[np.float64], c: NDArray[np.float64], s: NDArray[np.float64]) -> NDArray[np.float64]:
    """``r0 @ R(axis, angle)`` for rotations ``r0`` (3, 3, N), which it may overwrite, a unit
    ``axis`` and the angles' cosines ``c`` and sines ``s`` (N,). About a coordinate axis only the
    other two columns turn; about any other axis, Rodrigues' formula
    ``c r0 + s r0 [axis]x + (1 - c) (r0 axis) axis^T``."""
    coordinate = np.flatnonzero(axis == 1.0)
    if len(coordinate) == 1:
        i = int(coordinate[0])
        j, k = (i + 1) % 3, (i + 2) % 3
        column_j, column_k = r0[:, j], r0[:, k]
        turned_j = c * column_j
        turned_j += s * column_k
        column_k *= c
        column_k -= s * column_j
        column_j[...] = turned_j
        return r0
    x, y, z = axis
    cross = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    turned: NDArray[np.float64] = c * r0 + s * np.matmul(cross.T, r0) + (1.0 - c) * (np.matmul(axis, r0)[:, None, :] * axis[None, :, None])
    return turned


def _cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cross product of vectors laid out along the second-to-last axis: (3, N) or (C, 3, N)."""
    ax, ay, az = a[..., 0, :], a[..., 1, :], a[..., 2, :]
    bx, by, bz = b[..., 0, :], b[..., 1, :], b[..., 2, :]
    return np.stack((ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx), axis=-2)

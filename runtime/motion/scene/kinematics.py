"""Forward kinematics and a damped-least-squares IK for a group's tip.

The functions take a ``RobotModel`` and create their own pinocchio ``Data``, so they can be
called from any thread and never disturb a planning scene's caches; an ``IkSolver`` keeps its
set-up and ``Data`` for many solves by one caller. Poses are 4x4 homogeneous matrices.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
import pinocchio as pin

from .model import RobotModel


def frame_pose(robot: RobotModel, q_full: NDArray[np.float64], frame: str) -> NDArray[np.float64]:
    """World pose (4x4) of a link, joint or site frame at full configuration ``q_full``."""
    return frame_poses(robot, q_full, [frame])[frame]


def frame_poses(robot: RobotModel, q_full: NDArray[np.float64], frames: Sequence[str]) -> dict[str, NDArray[np.float64]]:
    """World poses of several frames from one FK pass."""
    q = np.asarray(q_full, dtype=float)
    if q.shape != (robot.model.nq,):
        raise ValueError(f"full configuration needs {robot.model.nq} values, got shape {q.shape}")
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, q)
    out = {}
    for name in frames:
        fid = robot.frame_id(name)
        out[name] = pin.updateFramePlacement(robot.model, data, fid).homogeneous.copy()
    return out


def frame_jacobian(robot: RobotModel, q_full: NDArray[np.float64], frame: str, joints: Sequence[str]) -> NDArray[np.float64]:
    """6 x len(joints) Jacobian of ``frame`` at ``q_full``: linear then angular velocity, in
    world axes at the frame's origin (pinocchio's LOCAL_WORLD_ALIGNED), columns in ``joints`` order."""
    model = robot.model
    data = model.createData()
    q = np.asarray(q_full, dtype=float)
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    jacobian = pin.getFrameJacobian(model, data, robot.frame_id(frame), pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    return np.asarray(jacobian[:, [int(model.idx_vs[model.getJointId(j)]) for j in joints]])


@dataclass(frozen=True)
class IkResult:
    success: bool
    positions: NDArray[np.float64]
    """Group joint values (the best found, even when not successful)."""
    position_error: float
    """Metres between the reached and the target position."""
    orientation_error: float
    """Radians between the reached and the target orientation."""
    iterations: int


class IkSolver:
    """Damped-least-squares IK for one group's frame, set up once and solved many times.

    Damped least squares on the SE(3) log error in the frame, with joint limits enforced by
    clipping after each step. It keeps its own pinocchio ``Data``: one solver, one caller at a
    time (``solve_ik`` makes a fresh one per call).
    """

    def __init__(self, robot: RobotModel, group: str, frame: str | None = None, reference: NDArray[np.float64] | None = None):
        self.robot, self.group = robot, group
        self.layout = robot.configuration_map(group, None, reference)
        self.joints = tuple(self.layout.group.joints)
        self.frame_id = robot.frame_id(frame or self.layout.group.tip_link)
        self.lower, self.upper = robot.position_limits(self.joints)
        self._v_idx = [int(robot.model.idx_vs[robot.model.getJointId(j)]) for j in self.joints]
        self._data = robot.model.createData()

    def solve(
        self,
        target: NDArray[np.float64],
        seeds: ArrayLike | None = None,
        position_tolerance: float = 1e-4,
        orientation_tolerance: float = 1e-3,
        position_only: bool = False,
        max_iterations: int = 100,
        damping: float = 1e-4,
        random_restarts: int = 8,
        rng_seed: int = 0,
    ) -> IkResult:
        """Joint values of the group that put the frame at ``target`` (see ``solve_ik``)."""
        goal = pin.SE3(np.asarray(target, dtype=float))
        lower, upper, v_idx, fid = self.lower, self.upper, self._v_idx, self.frame_id
        model, data, layout = self.robot.model, self._data, self.layout
        starts = [] if seeds is None else [np.asarray(s, dtype=float) for s in np.atleast_2d(seeds)]
        for s in starts:
            if s.shape != (len(self.joints),):
                raise ValueError(f"IK seed has {s.shape[0]} values; group {self.group!r} has {len(self.joints)} joints")
        if random_restarts > 0:
            rng = np.random.default_rng(rng_seed)
            lo, hi = np.maximum(lower, -np.pi), np.minimum(upper, np.pi)
            starts += [rng.uniform(lo, hi) for _ in range(random_restarts)]
        if not starts:
            starts = [np.clip(np.zeros(len(self.joints)), lower, upper)]

        best: IkResult | None = None
        rows = slice(0, 3) if position_only else slice(0, 6)
        for start in starts:
            x = np.clip(start, lower, upper)
            for iteration in range(1, max_iterations + 1):
                q = layout(x)
                pin.forwardKinematics(model, data, q)
                current = pin.updateFramePlacement(model, data, fid)
                error_frame = current.actInv(goal)
                err = pin.log6(error_frame).vector
                pos_err = float(np.linalg.norm(goal.translation - current.translation))
                rot_err = float(np.linalg.norm(err[3:]))
                done = pos_err <= position_tolerance and (position_only or rot_err <= orientation_tolerance)
                if best is None or _score(pos_err, rot_err, position_only) < _score(best.position_error, best.orientation_error, position_only):
                    best = IkResult(done, x.copy(), pos_err, rot_err, iteration)
                if done:
                    return best
                J = pin.computeFrameJacobian(model, data, q, fid, pin.ReferenceFrame.LOCAL)[:, v_idx]
                J = pin.Jlog6(error_frame.inverse()) @ J
                J, e = J[rows], err[rows]
                dx = J.T @ np.linalg.solve(J @ J.T + damping * np.eye(J.shape[0]), e)
                x = np.clip(x + dx, lower, upper)
        assert best is not None
        return best


def solve_ik(
    robot: RobotModel,
    group: str,
    target: NDArray[np.float64],
    seeds: ArrayLike | None = None,
    frame: str | None = None,
    reference: NDArray[np.float64] | None = None,
    **options: Any,
) -> IkResult:
    """Joint values of ``group`` that put ``frame`` (default: the group's tip) at ``target``.

    Seeds are tried in order, then ``random_restarts`` seeds drawn uniformly within the limits
    (capped to +-pi) from ``rng_seed``: the answer is deterministic. Joints outside the group
    keep their value from ``reference`` (default: neutral). ``options`` are ``IkSolver.solve``'s
    (tolerances, ``position_only``, ``max_iterations``, ``damping``, ``random_restarts``,
    ``rng_seed``); a caller solving many times keeps one ``IkSolver``.
    """
    return IkSolver(robot, group, frame, reference).solve(target, seeds, **options)


def _score(pos_err: float, rot_err: float, position_only: bool) -> float:
    return pos_err + (0.0 if position_only else 0.1 * rot_err)

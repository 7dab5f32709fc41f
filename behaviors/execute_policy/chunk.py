"""Reading a GetActionChunk response into arrays, with the contract's rules. Pure.

Without a gripper, each point's positions go to the joint group's joints in list order, so the
chunk's ``joint_names`` must be exactly the group's joints in that order. With a gripper, values
are matched by name: the names must be the group's joints plus exactly the configured gripper
joint, in any order. Every value must be finite and every point must have one value per name.
A chunk has at most ``MAX_CHUNK_STEPS`` points.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from runtime.errors import ObjectiveError

MAX_CHUNK_STEPS = 10_000
"""The most points one chunk may carry: 1,000 s at 10 Hz, 200 times the 50 steps of SmolVLA or
pi0. Planning costs time and memory linear in a chunk's steps (``step_spline``); the cap keeps
one answer from holding a tick for long (a 10,000-step chunk is read and planned in well under a
second) and names the policy's mistake."""


class ChunkError(ObjectiveError, ValueError):
    """The chunk breaks the contract; the message says how."""


@dataclass(frozen=True)
class Chunk:
    """A chunk's arm positions (N, J) in joint-group order and the gripper column (N,) if any."""

    arm: NDArray[np.float64]
    gripper: NDArray[np.float64] | None

    @property
    def steps(self) -> int:
        return len(self.arm)


def read_chunk(
    trajectory: Any,
    group_joints: Sequence[str],
    gripper_joint: str | None,
) -> Chunk:
    """Validate a ``trajectory_msgs/JointTrajectory`` chunk and return it as arrays."""
    names = list(trajectory.joint_names)
    points = list(trajectory.points)
    if not points:
        raise ChunkError("chunk has no points")
    if len(points) > MAX_CHUNK_STEPS:
        raise ChunkError(f"chunk has {len(points)} points, more than the {MAX_CHUNK_STEPS} one chunk may carry")
    group = list(group_joints)
    if gripper_joint is None:
        if names != group:
            raise ChunkError(
                f"joint names do not match the joint group: got [{', '.join(names)}], "
                f"expected [{', '.join(group)}] in this order (without a gripper, positions go to the group's joints in list order)"
            )
        order = list(range(len(group)))
        gripper_index = None
    else:
        missing = [j for j in group if j not in names]
        if missing:
            raise ChunkError(f"joint names do not match the joint group: missing [{', '.join(missing)}] in [{', '.join(names)}]")
        extra = [n for n in names if n not in group]
        if len(names) != len(set(names)):
            raise ChunkError(f"chunk names a joint twice: [{', '.join(names)}]")
        if extra != [gripper_joint]:
            if len(extra) == 1:
                raise ChunkError(
                    f"chunk names two gripper joints: the configured gripper joint is '{gripper_joint}', "
                    f"the chunk's extra joint is '{extra[0]}'"
                )
            raise ChunkError(
                f"chunk must carry the group's joints plus exactly the gripper joint '{gripper_joint}', "
                f"got extra joints [{', '.join(extra)}]"
            )
        order = [names.index(j) for j in group]
        gripper_index = names.index(gripper_joint)
    width = len(names)
    rows = []
    for step, point in enumerate(points):
        values = list(point.positions)
        if len(values) != width:
            raise ChunkError(f"step {step} has {len(values)} positions for {width} joint names")
        rows.append(values)
    data = np.asarray(rows, dtype=float)
    bad = ~np.isfinite(data)
    if bad.any():
        step, column = (int(i) for i in np.argwhere(bad)[0])
        raise ChunkError(f"step {step} joint '{names[column]}' is not finite ({data[step, column]})")
    arm = data[:, order]
    gripper = data[:, gripper_index] if gripper_index is not None else None
    return Chunk(arm, gripper)


def read_policy_chunk(array: Any) -> NDArray[np.float64] | None:
    """A ``std_msgs/Float64MultiArray`` as (steps, dims), or None when it is empty (no data).

    The layout must put the step dimension first with ``data_offset`` 0, and its sizes must
    account for every value; every value must be finite. Anything else is a ``ChunkError``: the
    policy means real-time chunking to work, and an echo read as empty would turn it off in
    silence."""
    data = np.asarray(array.data, dtype=float)
    if data.size == 0:
        return None
    layout = array.layout
    fix = "lay it out as (steps, action dims), steps first, with data_offset 0"
    if layout.data_offset != 0:
        raise ChunkError(f"policy_action_chunk has data_offset {layout.data_offset}: {fix}")
    dims = [int(d.size) for d in layout.dim]
    if len(dims) == 1:
        dims.append(data.size // max(1, dims[0]))
    if len(dims) != 2 or dims[0] * dims[1] != data.size or dims[0] == 0:
        raise ChunkError(f"policy_action_chunk has {data.size} values but its layout gives sizes {dims}: {fix}")
    bad = ~np.isfinite(data)
    if bad.any():
        step, column = divmod(int(np.argmax(bad)), dims[1])
        raise ChunkError(f"policy_action_chunk step {step} dim {column} is not finite ({data[step * dims[1] + column]})")
    return data.reshape(dims[0], dims[1])


def period_problem(period_s: float) -> str | None:
    """Why a ``native_control_period`` is not one, or None (0 means no training rate to report)."""
    if math.isfinite(period_s) and period_s >= 0:
        return None
    return (f"native_control_period is {period_s:g} s: answer the seconds per step the policy was trained at, "
            "or 0 when it has no training rate")

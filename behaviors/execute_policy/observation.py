"""Building GetActionChunk requests from what the robot reports. Pure message assembly."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from runtime.errors import ObjectiveError


class ObservationError(ObjectiveError, ValueError):
    pass


class StaleObservation(Exception):
    """An observation too old to feed the policy (``stale_observation``): the world stopped
    publishing, so the run fails (the robot stops); not a mistake of the setup."""


def robot_state(joint_state: Any, joints: Sequence[str], gripper_joint: str | None, topic: str) -> JointState:
    """Positions of the group's joints, then the gripper joint, taken from a JointState by name."""
    index = {name: i for i, name in enumerate(joint_state.name)}
    wanted = list(joints) + ([gripper_joint] if gripper_joint else [])
    missing = [name for name in wanted if name not in index]
    if missing:
        if gripper_joint in missing:
            raise ObservationError(
                f"the joint states on '{topic}' do not include the gripper joint '{gripper_joint}': "
                "it must be published alongside the arm joints"
            )
        raise ObservationError(f"the joint states on '{topic}' do not include [{', '.join(missing)}]")
    if len(joint_state.position) != len(joint_state.name):
        raise ObservationError(
            f"the joint states on '{topic}' have {len(joint_state.name)} names but {len(joint_state.position)} positions"
        )
    state = JointState()
    state.header = joint_state.header
    state.name = wanted
    state.position = [float(joint_state.position[index[name]]) for name in wanted]
    return state


def stale_observation(now_s: float, received_at: Sequence[tuple[str, float | None]], limit_s: float) -> str | None:
    """Why the observations ``(topic, runtime clock seconds it arrived)`` cannot be fed to the
    policy: the first one older than ``limit_s``, named by its topic; None when all are fresh."""
    for topic, at_s in received_at:
        if at_s is not None and now_s - at_s > limit_s + 1e-9:
            return (f"the newest message on '{topic}' is {now_s - at_s:.2f} s old, more than max_observation_age = "
                    f"{limit_s:.2f} s: its publisher stopped or fell behind; the policy is not fed an old world, "
                    "robot stopped")
    return None


def policy_tail(policy_chunk: NDArray[np.float64] | None, offset: int) -> Float64MultiArray:
    """The unexecuted tail of a policy chunk from step ``offset``, step dimension first."""
    msg = Float64MultiArray()
    if policy_chunk is None or offset >= len(policy_chunk):
        return msg
    tail = np.ascontiguousarray(policy_chunk[max(0, offset):], dtype=float)
    steps, width = tail.shape
    msg.layout.dim = [
        MultiArrayDimension(label="step", size=steps, stride=steps * width),
        MultiArrayDimension(label="action", size=width, stride=width),
    ]
    msg.layout.data_offset = 0
    msg.data = tail.ravel().tolist()
    return msg

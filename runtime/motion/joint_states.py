"""``sensor_msgs/JointState`` messages built fast, for a world that publishes one every tick.

rosidl's constructor sends each field through its property setter and builds a ``Header`` and
a ``Time`` the same way: about 40 us a message under a profiler, 3,100 messages a run.
``joint_state`` fills the same slots directly; the message is equal (``==``) to the
constructor's and serializes the same (``tests/test_joint_states.py``). With
``ROS_PYTHON_CHECK_FIELDS=1`` (rosidl's switch for checked fields) it uses the constructors.
"""
from __future__ import annotations

import array
from typing import Sequence

from builtin_interfaces.msg import Time
from sensor_msgs.msg import JointState, _joint_state
from std_msgs.msg import Header

from runtime.io.timestamps import split_seconds, time_msg


def joint_state(stamp_s: float, names: Sequence[str], positions: Sequence[float],
                velocities: Sequence[float]) -> JointState:
    """``JointState(header=Header(stamp=time_msg(stamp_s)), name=list(names), position=positions,
    velocity=velocities)``, efforts empty."""
    if _joint_state.ros_python_check_fields == "1":  # rosidl was asked to check every field: let it
        return JointState(header=Header(stamp=time_msg(stamp_s)), name=list(names), position=positions,
                          velocity=velocities)
    stamp = Time.__new__(Time)
    stamp._check_fields = False
    stamp._sec, stamp._nanosec = split_seconds(stamp_s)
    header = Header.__new__(Header)
    header._check_fields = False
    header._stamp, header._frame_id = stamp, ""
    msg = JointState.__new__(JointState)
    msg._check_fields = False
    msg._header = header
    msg._name = list(names)
    msg._position = array.array("d", positions)
    msg._velocity = array.array("d", velocities)
    msg._effort = array.array("d")
    return msg

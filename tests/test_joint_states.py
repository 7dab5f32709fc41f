"""runtime.motion.joint_states builds the JointState rosidl's constructors build, only faster."""
from __future__ import annotations

from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState, _joint_state
from std_msgs.msg import Header

from runtime.motion.joint_states import joint_state
from runtime.io.timestamps import time_msg

NAMES = ("shoulder_pan_joint", "elbow_joint", "robotiq_85_left_knuckle_joint")


def constructed(stamp_s: float, positions: list[float], velocities: list[float]) -> JointState:
    return JointState(header=Header(stamp=time_msg(stamp_s)), name=list(NAMES), position=positions, velocity=velocities)


def test_message_equals_the_constructors_and_serializes_the_same():
    for stamp_s in (0.0, 1.9999999999, 12.345678901, 3.0):
        positions, velocities = [0.1, -2.5, 0.7999], [1e-9, -0.0, 3.25]
        fast, slow = joint_state(stamp_s, NAMES, positions, velocities), constructed(stamp_s, positions, velocities)
        assert fast == slow
        assert (fast.header.stamp.sec, fast.header.stamp.nanosec) == (slow.header.stamp.sec, slow.header.stamp.nanosec)
        # Not byte for byte: rmw leaves CDR alignment padding uninitialized (after the empty frame_id).
        wire, slow_wire = serialize_message(fast), serialize_message(slow)
        assert len(wire) == len(slow_wire)
        assert deserialize_message(wire, JointState) == slow and deserialize_message(slow_wire, JointState) == fast
    assert joint_state(2.0, NAMES, [0.0] * 3, [0.0] * 3).header.stamp.sec == 2
    assert len(joint_state(0.0, NAMES, [0.0] * 3, [0.0] * 3).effort) == 0


def test_names_are_a_list_of_their_own():
    msg = joint_state(0.5, NAMES, [0.0] * 3, [0.0] * 3)
    msg.name.append("extra")  # a subscriber changing its copy changes no other message
    assert joint_state(0.5, NAMES, [0.0] * 3, [0.0] * 3).name == list(NAMES)


def test_checked_fields_use_the_constructors(monkeypatch):
    monkeypatch.setattr(_joint_state, "ros_python_check_fields", "1")
    msg = joint_state(0.25, NAMES, [0.0] * 3, [1.0] * 3)
    assert msg._check_fields is True
    assert msg == constructed(0.25, [0.0] * 3, [1.0] * 3)

"""``recording.cdr.message_encoder``: the CDR a recording writes for every message type
the runtime records, read back by rclpy's deserializer (what the report uses) and by
mcap-ros2-support's decoder built from the recorded schema (what Foxglove does), and equal to
rclpy's own bytes except in padding (rclpy leaves padding uninitialized)."""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from recording.cdr import message_encoder
from recording.schema import message_definition, type_name


def _messages() -> list[object]:
    from builtin_interfaces.msg import Duration, Time
    from control_msgs.action import GripperCommand
    from controller_manager_msgs.srv import ListControllers, SwitchController
    from geometry_msgs.msg import Point, PoseWithCovariance, WrenchStamped
    from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance as Follow
    from rcl_interfaces.msg import Log
    from sensor_msgs.msg import Image
    from std_msgs.msg import ColorRGBA, String
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    from visualization_msgs.msg import Marker, MarkerArray

    rng = np.random.default_rng(7)
    feedback = Follow.Feedback(joint_names=["shoulder_pan_joint", "élbow"])
    feedback.header.stamp, feedback.header.frame_id = Time(sec=17, nanosec=5), "base"
    feedback.desired.positions, feedback.actual.velocities = rng.normal(size=2).tolist(), rng.normal(size=2).tolist()
    feedback.error.time_from_start = Duration(sec=-3, nanosec=999)
    feedback.wrench.force.x, feedback.wrench.torque.z = 1.5, -2.25
    trajectory = JointTrajectory(joint_names=["a", "bb", "ccc"], points=[
        JointTrajectoryPoint(positions=rng.normal(size=3).tolist(), velocities=rng.normal(size=3).tolist(),
                             effort=[], time_from_start=Duration(sec=k, nanosec=k * 1000)) for k in range(4)])
    goal = Follow.Goal(joint_trajectory=trajectory, path_tolerance=0.1, admittance_stiffness=[1.0] * 6)
    marker = Marker(ns="robot", id=3, type=Marker.TRIANGLE_LIST, frame_locked=True, text="x",
                    points=[Point(x=float(v), y=-1.0, z=2.0) for v in range(5)], colors=[ColorRGBA(r=0.5, a=1.0)])
    image = Image(height=2, width=3, encoding="rgb8", is_bigendian=0, step=9, data=bytes(range(18)))
    return [
        feedback, goal, trajectory, Follow.Result(error_code=-6, error_string="F/T"),
        WrenchStamped(), MarkerArray(markers=[marker, Marker(action=Marker.DELETE)]), MarkerArray(), image,
        String(data="{\"a\": 1}"), Log(level=Log.WARN, name="objective", msg="ünïcode"),
        GripperCommand.Goal(), GripperCommand.Feedback(position=0.4, stalled=True), GripperCommand.Result(reached_goal=True),
        SwitchController.Request(activate_controllers=["jtac"], strictness=2, timeout=Duration(sec=1)),
        ListControllers.Request(), ListControllers.Response(), PoseWithCovariance(covariance=np.arange(36, dtype=float)),
    ]


@pytest.mark.parametrize("msg", _messages(), ids=lambda m: type(m).__name__)
def test_hand_encoded_messages_decode_as_what_was_sent(msg):
    from mcap_ros2._dynamic import generate_dynamic

    encode = message_encoder(type(msg))
    assert encode is not None
    data = encode(msg)
    assert deserialize_message(data, type(msg)) == msg
    reference = serialize_message(msg)  # its padding bytes (ours are zeros) are whatever was in memory
    assert len(data) <= len(reference) and all(ours == 0 for ours, theirs in zip(data, reference) if ours != theirs)
    name = type_name(type(msg))
    decode = generate_dynamic(name, message_definition(type(msg)))[name]
    assert repr(decode(data)) == repr(decode(reference))  # (its classes compare by identity)


def test_a_type_with_a_field_it_does_not_know_is_left_to_rclpy():
    from rosidl_parser import definition as idl

    from recording import cdr

    assert cdr._field_writer(idl.BasicType("long double")) is None and cdr._field_writer(idl.UnboundedWString()) is None


def test_a_trajectory_is_read_back_from_the_cdr_of_both_encoders():
    from builtin_interfaces.msg import Duration, Time
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from recording.cdr import joint_trajectory_arrays

    points = [JointTrajectoryPoint(positions=[0.5, -1.0], velocities=[], accelerations=[1.0, 2.0],
                                   time_from_start=Duration(sec=1, nanosec=250_000_000)),
              JointTrajectoryPoint(positions=[0.25, 3.0], velocities=[0.125, 0.0], effort=[7.0],
                                   time_from_start=Duration(sec=2, nanosec=0))]
    msg = JointTrajectory(joint_names=["a", "bb"], points=points)
    msg.header.stamp, msg.header.frame_id = Time(sec=12, nanosec=500_000_000), "base_link"
    for data in (message_encoder(JointTrajectory)(msg), serialize_message(msg)):
        got = joint_trajectory_arrays(data)
        assert got == (12.5, ("a", "bb"), (1.25, 2.0), ((0.5, -1.0), (0.25, 3.0)), ((), (0.125, 0.0)))
    with pytest.raises(ValueError, match="truncated"):
        joint_trajectory_arrays(serialize_message(msg)[:60])


def test_a_goal_reuses_the_bytes_of_the_trajectory_encoded_before_it():
    from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance as Follow
    from trajectory_msgs.msg import JointTrajectory

    goal = next(m for m in _messages() if isinstance(m, Follow.Goal))
    alone = message_encoder(Follow.Goal)(goal)
    known: dict[int, bytes] = {}
    trajectory = message_encoder(JointTrajectory)(goal.joint_trajectory, known)
    assert known == {id(goal.joint_trajectory): trajectory}
    assert message_encoder(Follow.Goal)(goal, known) == alone and alone.startswith(trajectory)
    known[id(goal.joint_trajectory)] = trajectory[:4] + b"\xff" + trajectory[5:]  # what it reuses, marked
    assert message_encoder(Follow.Goal)(goal, known)[4] == 0xFF

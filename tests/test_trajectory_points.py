"""runtime.motion.trajectory_points builds the messages rosidl's constructor builds, only faster."""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from trajectory_msgs.msg import _joint_trajectory_point

from runtime.io.timestamps import duration_msg, split_seconds, split_seconds_array
from runtime.motion.trajectory_points import trajectory_points


def _constructed(times, positions, velocities=None, accelerations=None) -> list[JointTrajectoryPoint]:
    points = []
    for k, t in enumerate(times):
        fields = {"positions": positions[k].tolist(), "time_from_start": duration_msg(t)}
        if velocities is not None:
            fields["velocities"] = velocities[k].tolist()
        if accelerations is not None:
            fields["accelerations"] = accelerations[k].tolist()
        points.append(JointTrajectoryPoint(**fields))
    return points


def _path(n: int = 40) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(3)
    # times that round to the nanosecond both ways, past whole seconds, and one exactly on a second
    times = np.concatenate([[0.0], np.cumsum(rng.uniform(0.001, 0.1, n - 2)), [3.0]]) + 1e-10
    return times, rng.normal(size=(n, 6)), rng.normal(size=(n, 6)), rng.normal(size=(n, 6))


def test_points_equal_the_constructors_and_serialize_the_same():
    times, p, v, a = _path()
    fast, slow = trajectory_points(times, p, v, a), _constructed(times, p, v, a)
    assert fast == slow
    assert [(q.time_from_start.sec, q.time_from_start.nanosec) for q in fast[-2:]] == \
           [(q.time_from_start.sec, q.time_from_start.nanosec) for q in slow[-2:]]
    assert fast[-1].time_from_start.sec == 3
    fast_msg, slow_msg = JointTrajectory(joint_names=list("abcdef"), points=fast), JointTrajectory(joint_names=list("abcdef"), points=slow)
    # Not byte for byte: rmw's CDR serializer leaves alignment padding uninitialized (seen differing
    # at byte 17, after the empty frame_id), so equal messages can differ there.
    wire, slow_wire = serialize_message(fast_msg), serialize_message(slow_msg)
    assert len(wire) == len(slow_wire)
    assert deserialize_message(wire, JointTrajectory) == slow_msg
    assert deserialize_message(slow_wire, JointTrajectory) == fast_msg


def test_fields_left_out_are_empty_as_in_the_constructor():
    times, p, _, _ = _path(5)
    fast = trajectory_points(times, p)
    assert fast == _constructed(times, p)
    assert len(fast[0].velocities) == 0 and len(fast[0].accelerations) == 0 and len(fast[0].effort) == 0
    assert trajectory_points(np.zeros(0), np.zeros((0, 6))) == []


def test_points_can_be_changed_like_constructed_ones():
    times, p, v, a = _path(3)
    point = trajectory_points(times, p, v, a)[1]
    point.positions = [1.0] * 6
    point.time_from_start.sec = 7
    assert list(point.positions) == [1.0] * 6 and point.time_from_start.sec == 7


def test_checked_fields_go_through_the_constructor(monkeypatch):
    """With rosidl's ROS_PYTHON_CHECK_FIELDS=1 a NaN-free but wrongly typed value is refused as rosidl refuses it."""
    monkeypatch.setattr(_joint_trajectory_point, "ros_python_check_fields", "1")
    times, p, v, a = _path(4)
    points = trajectory_points(times, p, v, a)
    assert points == _constructed(times, p, v, a)
    assert all(q._check_fields for q in points)
    with pytest.raises(AssertionError, match="positions"):
        points[0].positions = ["not a number"]


def test_stamps_split_in_one_pass_as_one_by_one():
    rng = np.random.default_rng(11)
    ties = (np.arange(-2000, 2000) + 0.5) * 1e-9  # half a nanosecond: ties, or the nearest double to one
    seconds = np.concatenate([rng.uniform(-5.0, 40.0, 5000), ties, ties + 1.0, [0.0, -0.0, 1.0, -1.0, 2.9999999995, 1e-10]])
    secs, nanosecs = split_seconds_array(seconds)
    assert list(zip(secs, nanosecs)) == [split_seconds(float(s)) for s in seconds]
    assert all(type(v) is int for v in secs[:3] + nanosecs[:3])

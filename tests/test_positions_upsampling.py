"""``benchmarks/executors/positions_upsampling.py``, the model of ros2_controllers'
``positions_upsampling`` (#2491, cross-chunk continuity #2573), against the test cases of #2491
(``joint_trajectory_controller/test/test_trajectory.cpp`` and
``test_trajectory_controller_upsampling.cpp``): their inputs and expected values, in Python, and
the cross-chunk start velocity of #2573 as its pull request describes it (its own test cases are
not in the stored snapshot of ros2_controllers)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from benchmarks.executors.positions_upsampling import (
    UpsamplingParams, fill_cubic_spline_velocities, is_positions_only, preprocess_incoming_trajectory, synthesize_timing,
)
from runtime.io.timestamps import duration_msg, to_seconds
from sim.controllers.jtc import validate_trajectory
from sim.controllers.jtc_trajectory import JtcPoints, JtcTrajectory
from sim.controllers.trajectory import TrajectoryState

ON_30_HZ = UpsamplingParams(enable=True, policy_frequency_hz=30.0)


def chunk(rows: list[list[float]], dt_s: float, joints: tuple[str, ...] | None = None) -> JointTrajectory:
    """Positions-only points ``dt_s`` apart from 0 (all at 0 when ``dt_s`` is 0), as the tests' ``make_positions_chunk``."""
    names = list(joints or [f"joint{j + 1}" for j in range(len(rows[0]))])
    return JointTrajectory(joint_names=names, points=[JointTrajectoryPoint(positions=[float(v) for v in row], time_from_start=duration_msg(i * dt_s))
                                                       for i, row in enumerate(rows)])


def arrays(msg: JointTrajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    times = np.array([to_seconds(p.time_from_start) for p in msg.points])
    return times, np.array([list(p.positions) for p in msg.points]), np.array([list(p.velocities) for p in msg.points])


def accelerations_at_knots(times, positions, velocities) -> tuple[np.ndarray, np.ndarray]:
    """The cubic Hermite's acceleration arriving at and leaving each interior knot."""
    h = np.diff(times)[:, None]
    p0, p1, v0, v1 = positions[:-1], positions[1:], velocities[:-1], velocities[1:]
    arrive = (6 * p0 - 6 * p1) / h**2 + (2 * v0 + 4 * v1) / h
    leave = (-6 * p0 + 6 * p1) / h**2 - (4 * v0 + 2 * v1) / h
    return arrive[:-1], leave[1:]


def test_the_filled_spline_has_continuous_acceleration_and_rests_at_both_ends():
    dt = 0.1
    rows = [[0.1 + 0.4 * math.sin(math.pi * i * dt), 0.5 - 0.1 * i] for i in range(7)]  # two joints, distinct paths
    times, positions, _ = arrays(chunk(rows, dt))
    velocities = fill_cubic_spline_velocities(times, positions)
    assert velocities.shape == (7, 2)
    arrive, leave = accelerations_at_knots(times, positions, velocities)
    assert arrive == pytest.approx(leave, abs=1e-6)
    assert velocities[0] == pytest.approx([0, 0], abs=1e-9) and velocities[-1] == pytest.approx([0, 0], abs=1e-9)


def peak_sampled_acceleration(trajectory: JtcTrajectory, span_s: float, sample_dt_s: float = 0.002) -> float:
    """The peak |second difference| of JTC's sampled positions over the chunk."""
    positions = trajectory.sample_many(np.arange(0.0, span_s + 1e-12, sample_dt_s)).position[:, 0]
    return float(np.max(np.abs(np.diff(positions, 2)) / sample_dt_s**2))


def test_sampled_after_the_fill_the_chunk_is_smooth_where_positions_alone_are_a_staircase():
    """50 knots at 25 Hz on a sin^2 path, through JTC's sampler: filled, the sampled acceleration
    tracks the spline's; unfilled (linear, C0), its spikes are over three times larger."""
    dt, n = 1.0 / 25.0, 50
    s = np.arange(n) / (n - 1)
    times, positions = np.arange(n) * dt, (0.1 + 0.5 * np.sin(math.pi * s) ** 2)[:, None]
    velocities = fill_cubic_spline_velocities(times, positions)
    start = TrajectoryState(positions[0], np.zeros(1), np.zeros(1))
    filled = JtcTrajectory(JtcPoints.build(times, positions, velocities), 0.0, start)
    unfilled = JtcTrajectory(JtcPoints.build(times, positions), 0.0, start)
    peak_filled, peak_unfilled = peak_sampled_acceleration(filled, (n - 1) * dt), peak_sampled_acceleration(unfilled, (n - 1) * dt)
    _, leave = accelerations_at_knots(times, positions, velocities)
    analytic_peak = float(np.max(np.abs(np.append(leave, (-6 * positions[0] + 6 * positions[1]) / dt**2 - (4 * velocities[0] + 2 * velocities[1]) / dt))))
    assert peak_filled < 2.0 * analytic_peak + 1.0
    assert peak_unfilled > 3.0 * peak_filled


def test_edge_cases_two_points_rest_to_rest_fewer_a_no_op_and_chunks_of_any_size():
    times, positions, _ = arrays(chunk([[0.0], [0.5]], 0.1))
    assert fill_cubic_spline_velocities(times, positions) == pytest.approx(np.zeros((2, 1)))
    times, positions, _ = arrays(chunk([[0.3]], 0.1))
    assert fill_cubic_spline_velocities(times, positions) is None
    assert fill_cubic_spline_velocities(np.empty(0), np.empty((0, 1))) is None
    one = preprocess_incoming_trajectory(chunk([[0.3]], 0.1), ON_30_HZ, None)
    assert list(one.points[0].velocities) == []  # untouched
    small = preprocess_incoming_trajectory(chunk([[0.0], [0.1], [0.2]], 0.1), ON_30_HZ, None)
    large = preprocess_incoming_trajectory(chunk([[v] for v in (0.0, 0.1, 0.2, 0.3, 0.2, 0.1, 0.0, 0.1, 0.2)], 0.1), ON_30_HZ, None)
    assert (len(small.points), len(large.points)) == (3, 9)
    assert all(len(p.velocities) == 1 for p in [*small.points, *large.points])
    assert small.points[0].velocities[0] == pytest.approx(0.0) and large.points[-1].velocities[0] == pytest.approx(0.0)


def test_three_uniform_points_get_the_hand_solved_interior_velocity():
    """Rest at both ends: v1 = 3/4 (p2 - p0) / h = 2.25."""
    times, positions, _ = arrays(chunk([[0.0], [0.1], [0.3]], 0.1))
    assert fill_cubic_spline_velocities(times, positions)[:, 0] == pytest.approx([0.0, 0.75 * 0.3 / 0.1, 0.0], abs=1e-9)


def test_times_not_strictly_increasing_leave_the_trajectory_untouched():
    msg = chunk([[0.0], [0.1], [0.2]], 0.0)  # every time_from_start 0
    times, positions, _ = arrays(msg)
    assert fill_cubic_spline_velocities(times, positions) is None
    untimed = preprocess_incoming_trajectory(msg, UpsamplingParams(enable=True, policy_frequency_hz=0.0), None)
    assert all(list(p.velocities) == [] for p in untimed.points)


def test_an_untimed_chunk_is_timed_one_policy_step_apart_from_one_step_ahead():
    timed = synthesize_timing(chunk([[0.1 * i] for i in range(5)], 0.0), 30.0)
    assert [to_seconds(p.time_from_start) for p in timed.points] == pytest.approx([(i + 1) / 30.0 for i in range(5)], abs=1e-9)


def test_timing_the_policy_set_is_kept():
    timed = synthesize_timing(chunk([[0.0], [0.1], [0.2]], 0.123), 30.0)
    assert [to_seconds(p.time_from_start) for p in timed.points][1:] == pytest.approx([0.123, 0.246], abs=1e-9)


def test_only_positions_only_chunks_are_upsampled():
    msg = chunk([[0.0], [0.1], [0.2]], 0.05)
    assert is_positions_only(msg)
    msg.points[1].velocities = [0.5]
    assert not is_positions_only(msg)
    msg = chunk([[0.0], [0.1], [0.2]], 0.05)
    msg.points[1].accelerations = [0.5]  # accelerations without velocities: not positions-only either
    assert not is_positions_only(msg)


def test_off_the_preprocessing_changes_nothing():
    msg = preprocess_incoming_trajectory(chunk([[0.0], [0.1], [0.2], [0.1], [0.0]], 0.0), UpsamplingParams(False, 30.0), None)
    assert all(list(p.velocities) == [] and to_seconds(p.time_from_start) == 0.0 for p in msg.points)


def test_on_an_untimed_chunk_is_timed_and_filled_resting_at_both_ends():
    msg = preprocess_incoming_trajectory(chunk([[0.0], [0.1], [0.2], [0.1], [0.0]], 0.0), ON_30_HZ, None)
    assert [to_seconds(p.time_from_start) for p in msg.points] == pytest.approx([(i + 1) / 30.0 for i in range(5)], abs=1e-9)
    assert all(len(p.velocities) == 1 for p in msg.points)
    assert msg.points[0].velocities[0] == pytest.approx(0.0, abs=1e-9) and msg.points[-1].velocities[0] == pytest.approx(0.0, abs=1e-9)


def test_on_a_chunk_with_velocities_passes_unchanged_and_the_stamp_is_kept():
    msg = chunk([[0.0], [0.1], [0.2]], 0.05)
    for point, v in zip(msg.points, (0.0, 0.5, 0.0)):
        point.velocities = [v]
    assert preprocess_incoming_trajectory(msg, ON_30_HZ, None).points[1].velocities[0] == pytest.approx(0.5)
    stamped = chunk([[0.0], [0.1], [0.2], [0.1], [0.0]], 0.0)
    stamped.header.stamp = Time(sec=123, nanosec=456)
    out = preprocess_incoming_trajectory(stamped, ON_30_HZ, None)
    assert (out.header.stamp.sec, out.header.stamp.nanosec) == (123, 456)


def test_off_the_controller_refuses_an_untimed_chunk_on_the_upsampling_accepts_it():
    joints = ("joint1", "joint2", "joint3")
    rows = [[0.0] * 3, [0.1] * 3, [0.2] * 3, [0.1] * 3, [0.0] * 3]
    untimed = chunk(rows, 0.0, joints)
    assert validate_trajectory(untimed, joints, 0.0) is not None  # all-zero, non-increasing times
    upsampled = preprocess_incoming_trajectory(untimed, ON_30_HZ, None)
    assert validate_trajectory(upsampled, joints, 0.0) is None
    assert all(len(p.velocities) == 3 for p in upsampled.points)


def test_across_chunks_the_first_knot_starts_at_the_last_commanded_velocity_and_the_last_rests():
    """#2573: the start clamped to the velocity last commanded, the end at rest, C2 in between."""
    rows = [[0.02 * i, -0.01 * i] for i in range(10)]
    msg = preprocess_incoming_trajectory(chunk(rows, 0.0), UpsamplingParams(True, 10.0), np.array([0.2, -0.1]))
    times, positions, velocities = arrays(msg)
    assert velocities[0] == pytest.approx([0.2, -0.1]) and velocities[-1] == pytest.approx([0.0, 0.0])
    arrive, leave = accelerations_at_knots(times, positions, velocities)
    assert arrive == pytest.approx(leave, abs=1e-6)
    # A steady stream: interior knots keep the stream's velocity (0.2 rad/s), with no dip at the seam.
    assert velocities[1:4, 0] == pytest.approx([0.2, 0.2, 0.2], abs=0.01)

"""The streaming benchmark's metrics, on hand-made streams whose answers are known."""
import importlib.util

import numpy as np
import pytest

from benchmarks.baselines import Stream, TaskPath, stream_metrics

PATH = TaskPath(start=np.zeros(1), amplitudes=np.array([[0.5]]), duration=2.0)  # 0 -> 1 rad in 2 s


def test_a_stream_that_waits_then_follows_the_path_has_task_and_motion_time():
    dt = 0.1
    wait = np.zeros((5, 1))  # 0.5 s at the start, waiting for the first chunk
    follow = PATH.at(np.arange(0.0, 2.0 + 1e-9, dt))[1:]
    hold = np.ones((5, 1))
    metrics = stream_metrics(Stream(dt, np.vstack([wait, follow, hold]), seams=[5], calls=1), PATH)
    assert metrics.done
    assert metrics.stall_fraction == 0.0
    assert metrics.motion_time_s == pytest.approx(metrics.task_time_s - 0.4)
    assert metrics.max_path_dev < 1e-9


def test_a_pause_mid_path_counts_as_stall_and_a_dead_stop_as_a_velocity_jump():
    dt = 0.1
    q = PATH.at(np.arange(0.0, 2.0 + 1e-9, dt))
    paused = np.vstack([q[:10], np.repeat(q[9:10], 5, axis=0), q[10:], np.ones((3, 1))])
    metrics = stream_metrics(Stream(dt, paused, seams=[10, 15], calls=2), PATH)
    assert metrics.stall_fraction == pytest.approx(5 * dt / metrics.task_time_s)
    peak_speed = float(np.max(np.diff(q[:, 0]))) / dt
    assert metrics.max_vel_jump == pytest.approx(peak_speed, rel=0.05)


def test_the_lerobot_baseline_runs_lerobot_s_own_queue_code_where_lerobot_is_installed(monkeypatch):
    """With lerobot installed (``make lerobot``) the baseline merges every chunk with LeRobot's
    own ``RobotClient._aggregate_action_queues`` and says so; it plays exactly what the
    reimplementation (used without lerobot) plays."""
    from benchmarks.baselines import LeRobotQueue, ReimplementedQueue, TaskPolicy, benchmark_task, latency_trace, run_lerobot_aggregate

    if importlib.util.find_spec("lerobot") is None:
        pytest.skip("the LeRobot extra is not installed (make lerobot)")
    queue = LeRobotQueue()  # installed: an import error in it fails the test
    from lerobot.async_inference.robot_client import RobotClient

    merges: list[int] = []
    aggregate = RobotClient._aggregate_action_queues

    def counted(self, incoming, aggregate_fn=None):
        merges.append(len(incoming))
        return aggregate(self, incoming, aggregate_fn)

    monkeypatch.setattr(RobotClient, "_aggregate_action_queues", counted)
    path = benchmark_task(np.zeros(6))
    trace = latency_trace("lognormal", 1.5, 50, seed=1)
    theirs = run_lerobot_aggregate(TaskPolicy(path, 0.1, 50, seed=1), trace, np.zeros(6), 0.1, 60, queue=queue)
    ours = run_lerobot_aggregate(TaskPolicy(path, 0.1, 50, seed=1), trace, np.zeros(6), 0.1, 60, queue=ReimplementedQueue())
    assert theirs.implementation.startswith("lerobot (RobotClient") and ours.implementation.startswith("reimplementation")
    assert len(merges) >= 2 and set(merges) == {50}  # every chunk went through LeRobot's code
    assert theirs.seams == ours.seams and theirs.calls == ours.calls
    assert np.allclose(theirs.positions, ours.positions, atol=1e-12)


def test_the_cubic_spline_starts_at_the_given_velocity_ends_at_rest_and_is_c2():
    from benchmarks.baselines import cubic_spline_velocities
    from sim.controllers.jtc_trajectory import JtcPoints, JtcTrajectory

    times = 0.1 * np.arange(1, 11)
    positions = (0.3 * times + 0.2 * np.sin(3 * times))[:, None]
    velocities = cubic_spline_velocities(times, positions, np.array([0.25]))
    assert velocities[0, 0] == pytest.approx(0.25) and velocities[-1, 0] == pytest.approx(0.0, abs=1e-12)
    points = JtcPoints.build(times, positions, velocities)
    spline = JtcTrajectory(points, times[0], points.state(0))
    for t in times[1:-1]:  # continuous acceleration through every interior knot
        assert spline.sample(t - 1e-7).acceleration[0] == pytest.approx(spline.sample(t + 1e-7).acceleration[0], abs=1e-4)


def test_the_newest_wins_baseline_streams_the_task_without_checks_or_seam_jumps_at_low_latency():
    from benchmarks.baselines import TaskPolicy, benchmark_task, run_jtc_newest_wins

    path = benchmark_task(np.zeros(6))
    stream = run_jtc_newest_wins(TaskPolicy(path, 0.1, 50, seed=0), [0.05] * 200, np.zeros(6), 0.1, 110, 20)
    metrics = stream_metrics(stream, path)
    assert stream.calls >= 5 and len(stream.seams) == stream.calls  # every answer won at its arrival
    assert metrics.done  # the last chunk played to its end: the task's goal
    assert metrics.max_path_dev < 0.1
    assert metrics.max_vel_jump < 0.3


def test_a_glitching_chunk_reaches_the_arm_over_the_limits_through_the_unchecked_baselines():
    import math

    from benchmarks.baselines import GlitchingPolicy, TaskPolicy, benchmark_task, run_jtc_newest_wins, run_sync, setpoints_over_limits

    path = benchmark_task(np.zeros(6))
    trace = [0.5] * 200
    clean = run_sync(TaskPolicy(path, 0.1, 50, seed=0), trace, np.zeros(6), 0.1, 20, 110)
    glitched = run_sync(GlitchingPolicy(TaskPolicy(path, 0.1, 50, seed=0)), trace, np.zeros(6), 0.1, 20, 110)
    assert setpoints_over_limits(clean, math.pi, 5.0) == 0 and setpoints_over_limits(glitched, math.pi, 5.0) > 0
    jtc = run_jtc_newest_wins(GlitchingPolicy(TaskPolicy(path, 0.1, 50, seed=0)), trace, np.zeros(6), 0.1, 110, 20)
    assert np.abs(np.diff(jtc.positions[:, 0])).max() / 0.1 > math.pi  # the jump reaches the arm through the spline

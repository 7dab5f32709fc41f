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
        pytest.skip("lerobot is not in this venv (make lerobot builds .venv-lerobot on Python 3.11; make test runs this file there)")
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
    assert theirs.implementation.startswith("lerobot 0.4.4") and ours.implementation.startswith("reimplementation")
    assert len(merges) >= 2 and set(merges) == {50}  # every chunk went through LeRobot's code
    assert theirs.seams == ours.seams and theirs.calls == ours.calls
    assert np.allclose(theirs.positions, ours.positions, atol=1e-12)

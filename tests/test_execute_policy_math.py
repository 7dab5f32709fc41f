"""The pure pieces of ExecutePolicy: shaping, seam blending, limit checks, chunk reading."""
import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from behaviors.execute_policy.chunk import ChunkError, read_chunk, read_policy_chunk
from behaviors.execute_policy.shaping import densify, fit_chunk, join_at_seam, runout_duration
from behaviors.execute_policy.stream import runout_progress
from behaviors.execute_policy.timing import LatencyEstimate, frozen_prefix_steps, window_covers_latency

GROUP = ["j1", "j2"]


def _chunk(names, rows):
    return JointTrajectory(joint_names=names, points=[JointTrajectoryPoint(positions=list(r)) for r in rows])


def test_smoothing_spline_tracks_a_smooth_chunk_closely():
    k = np.arange(50)
    chunk = np.stack([0.5 * np.sin(k * 0.1), 0.2 * np.cos(k * 0.07)], axis=1)
    spline = fit_chunk(chunk, tracking_weight=300.0)
    assert np.max(np.abs(spline(k) - chunk)) < 2e-3


def test_lower_tracking_weight_smooths_more():
    rng = np.random.default_rng(0)
    chunk = np.cumsum(rng.normal(0, 0.02, size=(50, 2)), axis=0)
    k = np.arange(50)
    rough = np.abs(np.diff(fit_chunk(chunk, 3000.0)(k), 2, axis=0)).mean()
    smooth = np.abs(np.diff(fit_chunk(chunk, 3.0)(k), 2, axis=0)).mean()
    assert smooth < rough / 2


def test_seam_is_continuous_in_position_and_velocity():
    dt = 0.1
    first = fit_chunk(np.linspace([0.0, 0.0], [1.0, -1.0], 30), 300.0)
    m1 = join_at_seam(first, dt, 0.0, 0.0, 2.0, np.zeros(2), np.zeros(2), 0.5)
    second = fit_chunk(np.linspace([0.9, -0.7], [2.0, -2.0], 30), 300.0)
    seam = 1.5
    p_old, v_old, _ = m1.evaluate(np.array([seam]))
    m2 = join_at_seam(second, dt, 1.2, seam, 3.0, p_old[0], v_old[0], 0.5)
    p_new, v_new, _ = m2.evaluate(np.array([seam]))
    assert np.allclose(p_new, p_old, atol=1e-12)
    assert np.allclose(v_new, v_old, atol=1e-9)
    # After the blend the motion is the chunk's own spline.
    t = np.array([2.5])
    assert np.allclose(m2.evaluate(t)[0], second((t - 1.2) / dt), atol=1e-12)


def test_densify_spans_the_window_and_velocity_matches_finite_differences():
    spline = fit_chunk(np.linspace([0.0, 0.0], [1.0, 0.5], 20), 300.0)
    motion = join_at_seam(spline, 0.1, 0.0, 0.3, 1.5, spline(3.0), spline(3.0, nu=1) / 0.1, 0.4)
    s = densify(motion, 200)
    assert len(s) == 200 and s.times[0] == pytest.approx(0.3) and s.times[-1] == pytest.approx(1.5)
    fd = np.gradient(s.positions, s.times, axis=0)
    assert np.max(np.abs(fd[1:-1] - s.velocities[1:-1])) < 1e-3


def _moving_window(runout: float):
    """A window of a chunk moving at 0.2 and -0.1 rad/s (30 steps of 0.1 s), seam 0.3 s, end 1.5 s."""
    spline = fit_chunk(np.linspace([0.0, 0.0], [0.58, -0.29], 30), 300.0)
    motion = join_at_seam(spline, 0.1, 0.0, 0.3, 1.5, spline(3.0), spline(3.0, nu=1) / 0.1, 0.4)
    return spline, motion.with_runout(runout)


def test_runout_continues_the_window_smoothly_along_the_chunk_and_ends_at_rest():
    spline, motion = _moving_window(0.6)
    bare = motion.with_runout(0.0)
    at_end = [x[0] for x in motion.evaluate(np.array([1.5]))]
    just_after = [x[0] for x in motion.evaluate(np.array([1.5 + 1e-7]))]
    for mine, unbounded, after in zip(at_end, (x[0] for x in bare.evaluate(np.array([1.5]))), just_after):
        assert np.allclose(mine, unbounded, atol=1e-12)  # the window itself is unchanged
        assert np.allclose(after, mine, atol=1e-4)  # position, velocity and acceleration continuous
    p, v, a = (x[0] for x in motion.evaluate(np.array([motion.rest_time])))
    assert motion.rest_time == pytest.approx(2.1)
    assert np.allclose(v, 0.0, atol=1e-12) and np.allclose(a, 0.0, atol=1e-12)
    assert np.allclose(p, spline(15.0 + 3.0), atol=1e-12)  # 0.6 s of runout cover 3 chunk steps
    s = densify(motion, 200)
    assert s.times[199] == pytest.approx(1.5) and s.times[-1] == pytest.approx(2.1)
    assert np.max(np.diff(s.times)) <= 0.01 + 1e-12
    speed = np.abs(s.velocities[199:, 0])
    assert np.all(np.diff(speed) <= 1e-12)  # only slows down


def test_runout_length_brakes_within_half_the_acceleration_limit_and_needs_spare_steps():
    v, a_max = np.array([0.2, -0.1]), np.array([5.0, 5.0])
    assert runout_duration(v, a_max, 0.1, 1.0, spare_steps=10) == pytest.approx(1.0)  # nominal: 5 steps
    assert runout_duration(np.array([2.0, 0.0]), np.array([3.0, 3.0]), 0.1, 1.0, 20) == pytest.approx(2.0)  # 3 v / a
    assert runout_duration(v, a_max, 0.1, 1.0, spare_steps=4) == 0.0  # the chunk ends too soon
    assert runout_duration(np.zeros(2), np.full(2, np.inf), 0.1, 0.3, 5) == pytest.approx(0.4)


def test_runout_progress_counts_chunk_steps_covered():
    assert [runout_progress(i, 5) for i in (0, 1, 5, 10, 12)] == [0, 1, 4, 5, 5]
    assert runout_progress(3, 0) == 0


def test_read_chunk_without_gripper_requires_group_order():
    c = read_chunk(_chunk(GROUP, [[0.1, 0.2], [0.3, 0.4]]), GROUP, None)
    assert c.arm.tolist() == [[0.1, 0.2], [0.3, 0.4]] and c.gripper is None
    with pytest.raises(ChunkError, match="joint names do not match the joint group"):
        read_chunk(_chunk(["j2", "j1"], [[0.1, 0.2]]), GROUP, None)


def test_read_chunk_with_gripper_matches_by_name():
    c = read_chunk(_chunk(["g", "j2", "j1"], [[0.5, 0.2, 0.1]]), GROUP, "g")
    assert c.arm.tolist() == [[0.1, 0.2]] and c.gripper.tolist() == [0.5]
    with pytest.raises(ChunkError, match="two gripper joints.*'g'.*'finger'"):
        read_chunk(_chunk(["j1", "j2", "finger"], [[0.1, 0.2, 0.3]]), GROUP, "g")


@pytest.mark.parametrize(
    "rows, message",
    [
        ([[0.1, float("nan")]], "step 0 joint 'j2' is not finite"),
        ([[0.1, 0.2], [0.1]], "step 1 has 1 positions for 2 joint names"),
        ([], "chunk has no points"),
    ],
)
def test_read_chunk_rejects_malformed_chunks(rows, message):
    with pytest.raises(ChunkError, match=message):
        read_chunk(_chunk(GROUP, rows), GROUP, None)


def test_policy_chunk_layout_step_first_offset_zero():
    arr = Float64MultiArray(data=[float(i) for i in range(6)])
    arr.layout.dim = [MultiArrayDimension(label="step", size=3, stride=6), MultiArrayDimension(label="action", size=2, stride=2)]
    assert read_policy_chunk(arr).tolist() == [[0, 1], [2, 3], [4, 5]]
    arr.layout.data_offset = 1
    assert read_policy_chunk(arr) is None
    assert read_policy_chunk(Float64MultiArray()) is None


def test_timing_rules():
    est = LatencyEstimate()
    est.update(0.3)
    est.update(0.1)
    assert est.seconds == 0.3
    assert frozen_prefix_steps(0.3, 0.1, 0.02) == 4
    assert frozen_prefix_steps(0.0, 0.1, 0.0) == 1
    assert window_covers_latency(20, 0.1, 0.95) and not window_covers_latency(20, 0.1, 0.96)


def test_a_chunk_that_finds_the_arm_at_rest_plays_from_the_arms_step():
    from behaviors.execute_policy.stream import StepGrid

    grid = StepGrid(origin=0.0, dt=0.1, committed_steps=20, total_steps=100)
    first = grid.plan_window(1, request_step=0, frozen=3, chunk_steps=50, earliest_seam=5)
    assert (first.seam_step, first.request_step, first.first_chunk_step) == (5, 5, 0)
    grid.commit(first)  # committed motion ends at step 25
    on_time = grid.plan_window(2, request_step=22, frozen=3, chunk_steps=50, earliest_seam=24)
    assert (on_time.seam_step, on_time.first_chunk_step) == (25, 3)
    late = grid.plan_window(2, request_step=22, frozen=3, chunk_steps=50, earliest_seam=31)
    # Drained at step 25 (chunk step 3 of the new chunk); joins at 31, played from chunk step 3.
    assert (late.seam_step, late.first_chunk_step, late.request_step) == (31, 3, 28)

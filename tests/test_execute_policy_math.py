"""The pure pieces of ExecutePolicy: shaping, seam blending, limit checks, chunk reading."""
import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from behaviors.execute_policy.chunk import ChunkError, read_chunk, read_policy_chunk
from behaviors.execute_policy.config import committed_window_problem
from behaviors.execute_policy.gripper import result_problem
from behaviors.execute_policy.checks import densify
from behaviors.execute_policy.seam import join_at_seam
from behaviors.execute_policy.step_spline import fit_chunk
from behaviors.execute_policy.stream import drained_seconds
from behaviors.execute_policy.tail import NO_TAIL, Tail, plan_tail, runout_duration, runout_progress, tail_progress
from behaviors.execute_policy.timing import (
    LatencyEstimate,
    frozen_prefix_steps,
    nearest_rank_quantile,
    SizingRisk,
    sizing_risk,
    sizing_warning,
    window_covers_latency,
)
from runtime.io.bus import STATUS_ABORTED, STATUS_CANCELED, STATUS_SUCCEEDED

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


def _moving_window(tail: Tail):
    """A window of a chunk moving at 0.2 and -0.1 rad/s (30 steps of 0.1 s), seam 0.3 s, end 1.5 s."""
    spline = fit_chunk(np.linspace([0.0, 0.0], [0.58, -0.29], 30), 300.0)
    motion = join_at_seam(spline, 0.1, 0.0, 0.3, 1.5, spline(3.0), spline(3.0, nu=1) / 0.1, 0.4)
    return spline, motion.with_tail(tail)


def test_runout_continues_the_window_smoothly_along_the_chunk_and_ends_at_rest():
    spline, motion = _moving_window(Tail(0, 3, 0.1))
    bare = motion.bare()
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


def test_tail_progress_is_one_step_a_step_through_the_extension_then_the_runout_s():
    assert [tail_progress(i, 8, 5) for i in (0, 3, 8, 9, 13, 18, 30)] == [0, 3, 8, 9, 12, 13, 13]
    assert tail_progress(4, 0, 0) == 0


def test_the_tail_plays_the_chunk_beyond_the_window_at_full_speed_then_rests_at_its_last_step():
    # 14 chunk steps beyond the window (15 .. 29): the runout (nominal 0.6 s) takes the last 3,
    # the 11 before it are played as the policy planned them, one per dt.
    spline, window = _moving_window(NO_TAIL)
    tail = plan_tail(np.array([0.2, 0.1]), np.array([5.0, 5.0]), 0.1, 0.6, spare_steps=14)
    assert tail == Tail(11, 3, 0.1)
    motion = window.with_tail(tail)
    assert (motion.full_speed_end, motion.rest_time) == (pytest.approx(2.6), pytest.approx(3.2))
    k = np.arange(0, 12)
    p, v, _ = motion.evaluate(1.5 + 0.1 * k)
    assert np.allclose(p, spline(15.0 + k), atol=1e-12) and np.allclose(v, spline(15.0 + k, nu=1) / 0.1, atol=1e-12)
    p, v, a = (x[0] for x in motion.evaluate(np.array([motion.rest_time])))
    assert np.allclose(p, spline(29.0), atol=1e-12)  # the chunk's last step
    assert np.allclose(v, 0.0, atol=1e-12) and np.allclose(a, 0.0, atol=1e-12)
    s = densify(motion, 200)
    assert s.times[-1] == pytest.approx(3.2) and np.max(np.diff(s.times)) <= 0.01 + 1e-12
    assert np.max(np.abs(np.diff(s.velocities, axis=0))) < 0.01  # C1: no velocity step anywhere
    assert np.max(np.abs(s.accelerations)) <= 0.5 * 5.0  # brakes within half the limit
    assert plan_tail(np.array([0.2, 0.1]), np.array([5.0, 5.0]), 0.1, 0.6, spare_steps=2) == NO_TAIL  # no room to stop


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
    assert read_policy_chunk(Float64MultiArray()) is None
    arr.layout.data_offset = 1  # the guide reads it as empty, RTC off in silence: here it is refused
    with pytest.raises(ChunkError, match="policy_action_chunk has data_offset 1: lay it out as"):
        read_policy_chunk(arr)


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

    grid = StepGrid(origin_s=0.0, dt=0.1, window_steps=20, total_steps=100)
    first = grid.plan_window(1, request_step=0, frozen=3, chunk_steps=50, earliest_seam=5)
    assert (first.seam_step, first.request_step, first.first_chunk_step) == (5, 5, 0)
    grid = grid.with_window(first)  # sent motion ends at step 25
    on_time = grid.plan_window(2, request_step=22, frozen=3, chunk_steps=50, earliest_seam=24)
    assert (on_time.seam_step, on_time.first_chunk_step) == (25, 3)
    late = grid.plan_window(2, request_step=22, frozen=3, chunk_steps=50, earliest_seam=31)
    # Drained at step 25 (chunk step 3 of the new chunk); joins at 31, played from chunk step 3.
    assert (late.seam_step, late.first_chunk_step, late.request_step) == (31, 3, 28)


# -- the latency estimate ---------------------------------------------------------------------
def test_nearest_rank_quantile_is_the_largest_until_one_in_ten_can_be_left_out():
    assert nearest_rank_quantile([], 0.9) == 0.0
    assert nearest_rank_quantile([0.1] * 8 + [3.0], 0.9) == 3.0  # 9 values: too few to leave one out
    assert nearest_rank_quantile([0.1] * 9 + [3.0], 0.9) == 0.1  # 10: the slowest is the top tenth
    assert nearest_rank_quantile([0.1] * 18 + [2.0, 3.0], 0.9) == 0.1
    assert nearest_rank_quantile([0.1] * 17 + [1.0, 2.0, 3.0], 0.9) == 1.0


def test_latency_estimate_covers_a_spike_at_once_and_recovers_after_it():
    """A 3 s call as the second streamed request (the warmup and one call before it) is covered
    at once, and once ten round trips have been seen the spike is the slowest tenth and the
    estimate is back at the usual 0.05 s (a maximum would keep it at 3 s for the rest of the
    run: a 34-step frozen prefix)."""
    est = LatencyEstimate()
    history = []
    for seconds in [0.05, 0.05, 3.0] + [0.05] * 25:
        est.update(seconds)
        history.append(est.seconds)
    assert history[:2] == [0.05, 0.05]
    assert history[2:9] == [3.0] * 7  # 3 to 9 round trips seen
    assert history[9:] == [0.05] * 19  # from the 10th on
    assert frozen_prefix_steps(est.seconds, 0.1, 0.02 + 0.1 * est.seconds) == 1


def test_latency_estimate_keeps_up_with_latency_that_recurs_and_forgets_what_left_the_window():
    """Heavy-tailed latency: slow calls that are more than one in ten of the last 20 keep the
    estimate at the slow level; once 20 fast calls followed, nothing slow is left to count."""
    est = LatencyEstimate()
    for seconds in [0.2, 0.2, 1.5, 0.2, 0.2, 1.3, 0.2, 1.4, 0.2, 0.2] + [0.2] * 10:
        est.update(seconds)
    assert est.seconds == 1.3  # 3 of 20: the 18th smallest is the least slow of them
    for _ in range(20):
        est.update(0.2)
    assert est.seconds == 0.2


def test_sizing_warning_names_the_figures():
    assert sizing_warning(20, 0.1, 0.95, "measured latency") is None
    assert sizing_warning(20, 0.1, 1.2, "latency estimate", " (the 90th percentile of the last 4 round trips)") == (
        "(committed_action_steps - 1) * dt = 1.900 s is below twice the latency estimate 1.200 s (the 90th percentile "
        "of the last 4 round trips): expect pauses at chunk boundaries (committed_action_steps = 25 would cover it)"
    )


def test_sizing_warning_says_whether_the_chunk_s_tail_covers_the_latency():
    # 50-step chunks at dt 0.1: the arm plays the steps beyond the 2 s window while it waits, so
    # up to about half the chunk (2.5 s) no pause is expected; beyond it, pauses are.
    assert [sizing_risk(20, 0.1, latency, 50) for latency in (0.95, 1.2, 2.5, 2.6)] == [
        SizingRisk.COVERED, SizingRisk.TAIL_COVERS, SizingRisk.TAIL_COVERS, SizingRisk.PAUSES]
    assert sizing_risk(20, 0.1, 1.2, None) is SizingRisk.PAUSES  # chunk size not known yet
    assert sizing_warning(20, 0.1, 1.2, "measured latency", chunk_steps=50) == (
        "(committed_action_steps - 1) * dt = 1.900 s is below twice the measured latency 1.200 s: chunks land after "
        "their committed window ends; the arm goes on along the chunk's steps beyond the window meanwhile, and pauses "
        "only once the latency passes about 2.500 s, half the 50-step chunk (committed_action_steps = 25 would cover it)"
    )
    assert sizing_warning(20, 0.1, 3.0, "measured latency", chunk_steps=50) == (
        "(committed_action_steps - 1) * dt = 1.900 s is below twice the measured latency 3.000 s and longer than half "
        "the 50-step chunk (2.500 s): expect pauses at chunk boundaries (covering it would take committed_action_steps "
        "= 61, not below the chunk's 50 steps: a faster policy or longer chunks)"
    )


# -- joining a chunk that starts away from the arm ---------------------------------------------
def _offset_join(max_acceleration):
    """A re-planned chunk after a slow inference: it is 0.55 rad away from where the
    sent motion is at the seam (and 0.23 rad/s slower); the window is 15 steps of 0.1 s."""
    chunk = np.linspace([0.0, 0.0], [0.3, -0.1], 50)
    spline = fit_chunk(chunk, 300.0)
    k = 34.0
    start_p = spline(k) + np.array([0.55, 0.0])
    start_v = spline(k, nu=1) / 0.1 + np.array([0.23, 0.0])
    return join_at_seam(spline, 0.1, 0.0, 3.4, 4.9, start_p, start_v, 0.75, max_acceleration=max_acceleration)


def test_a_chunk_that_starts_away_from_the_arm_is_joined_within_the_acceleration_limit():
    """A seam blend of a fixed half window (0.75 s here) would join a 0.55 rad offset at
    5.6 rad/s^2, and the chunk would be rejected ('acceleration ... exceeds the limit'). The blend
    is as long as the acceleration the chunk leaves free requires, and the join stays continuous
    at the seam."""
    limit = np.array([5.0, 5.0])
    fixed = _offset_join(None)
    _, _, a_fixed = fixed.evaluate(np.linspace(3.4, 4.9, 301))
    assert np.abs(a_fixed).max() > limit[0]  # what main planned
    joined = _offset_join(limit)
    assert joined.blend_duration > 0.75
    t = np.linspace(3.4, 3.4 + joined.blend_duration, 601)
    p, v, a = joined.evaluate(t)
    assert np.abs(a).max() <= 0.5 * limit[0] + 1e-9  # the chunk alone does not accelerate: the blend gets half
    assert np.allclose(p[0], joined.offset_position + joined.spline(34.0), atol=1e-12)


# -- window sizing, the gripper's answers, and chunk reading ----------------------------------
def test_committed_window_must_be_smaller_than_the_chunk():
    assert committed_window_problem(19, 20) is None
    assert committed_window_problem(20, 20) == (
        "committed_action_steps (20) must be smaller than the policy's chunk size (20 steps): "
        "set committed_action_steps to at most 19"
    )


def test_drained_time_counts_from_the_end_of_the_committed_motion():
    assert drained_seconds(None, 5.0) == 0.0  # no chunk yet: nothing was drained
    assert drained_seconds(4.0, 3.5) == 0.0
    assert drained_seconds(4.0, 7.25) == 3.25


class _Result:
    def __init__(self, position, stalled=False, reached=False):
        self.position, self.stalled, self.reached_goal = position, stalled, reached


def test_gripper_results_a_stalled_grasp_is_normal_an_abort_short_of_the_target_is_not():
    action = "/robotiq_gripper_controller/gripper_cmd"
    assert result_problem(action, 0.8, STATUS_SUCCEEDED, _Result(0.8, reached=True)) is None
    assert result_problem(action, 0.8, STATUS_SUCCEEDED, _Result(0.45, stalled=True)) is None
    assert result_problem(action, 0.8, STATUS_ABORTED, _Result(0.45, stalled=True)) is None  # allow_stalling off
    assert result_problem(action, 0.8, STATUS_CANCELED, _Result(0.3)) is None  # preempted by the next goal
    assert result_problem(action, 0.8, STATUS_ABORTED, _Result(0.0)) == (
        "the gripper controller '/robotiq_gripper_controller/gripper_cmd' aborted the goal to 0.8000 rad "
        "with the fingers at 0.0000 rad, not stalled on an object"
    )

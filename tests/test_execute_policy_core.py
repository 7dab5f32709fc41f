"""ExecutePolicy's pure core without a world: the immutable step grid, the planner's
Planned / Wait / Failure decisions, and the stream's named states and their transitions."""
from dataclasses import dataclass, replace

import numpy as np
import pytest

from behaviors.execute_policy.checks import CheckFailure
from behaviors.execute_policy.chunk import Chunk
from behaviors.execute_policy.failure import Failure, FailureKind
from behaviors.execute_policy.at_rest import Arrival
from behaviors.execute_policy.planner import PlanInput, Planned, Wait, WaitReason, plan_chunk
from behaviors.execute_policy.config import ShapingConfig
from behaviors.execute_policy.tail import NO_TAIL, RUNOUT_SLOWDOWN, Tail, runout_chunk_steps, runout_duration, shorter_tails
from behaviors.execute_policy.states import (
    SentMotion,
    Goal,
    GoalState,
    HeldChunk,
    InFlight,
    StreamState,
    stream_finished,
    stream_state,
)
from behaviors.execute_policy.stream import StepGrid, stall_at_stop_s
from behaviors.execute_policy.timing import earliest_seam_step, next_request_step

DT = 0.1
SHAPING = ShapingConfig(dt=DT, committed_action_steps=20, policy_tracking_weight=300.0, num_interpolation_points=100,
                        max_acceleration=np.full(2, 5.0))
START = np.array([0.1, -0.2])


@dataclass
class FakeChecks:
    """Checks that pass unless told otherwise; ``path_horizon_s`` fails paths that go past it."""

    values_reason: CheckFailure | None = None
    limits_reason: CheckFailure | None = None
    path_horizon_s: float = float("inf")

    def values(self, chunk, window):
        return self.values_reason

    def limits(self, samples, window):
        return self.limits_reason

    def path(self, samples, window):
        beyond = samples.times[-1] > self.path_horizon_s + 1e-9
        return CheckFailure(FailureKind.WORLD_COLLISION, "beyond the horizon") if beyond else None


def ramp(steps: int = 50, speed: float = 0.05) -> Chunk:
    """A chunk from START moving joint 0 at ``speed`` rad per step."""
    rows = START + np.outer(np.arange(steps) * speed, [1.0, 0.0])
    return Chunk(rows, None)


def plan(sent: SentMotion, chunk: Chunk, *, index=1, request_step=0, frozen=2, earliest=2,
         goal=GoalState.NONE, checks=None) -> Planned | Wait | Failure:
    return plan_chunk(PlanInput(sent, goal, chunk, index, request_step, frozen, earliest,
                                START if sent.motion is None else None, SHAPING, checks or FakeChecks()))


def first_plan(total_steps: int = 100) -> tuple[SentMotion, Planned]:
    start = SentMotion(StepGrid(0.0, DT, 20, total_steps))
    planned = plan(start, ramp())
    assert isinstance(planned, Planned)
    return start, planned


# -- the step grid -------------------------------------------------------------------------
def test_committing_a_window_returns_a_new_grid_and_leaves_the_old_one_for_a_rollback():
    grid = StepGrid(0.0, DT, 20, 100)
    window = grid.plan_window(1, request_step=0, frozen=3, chunk_steps=50, earliest_seam=3)
    after = grid.with_window(window, Tail(20, 5, DT), chunk_steps=50)
    assert (after.sent_end, after.executed_until, after.tail, after.chunk_steps) == (23, 20, Tail(20, 5, DT), 50)
    assert (grid.sent_end, grid.executed_until, grid.tail, grid.chunk_steps) == (0, 0, NO_TAIL, 0)
    with pytest.raises(AttributeError):
        grid.sent_end = 7  # type: ignore[misc]


def test_steps_executed_count_what_the_arm_has_played_of_the_windows_sent():
    grid = StepGrid(0.0, DT, 20, 100).with_window(StepGrid(0.0, DT, 20, 100).plan_window(1, 0, 3, 50, 3))
    assert [grid.steps_executed_by(t) for t in (0.3, 1.0, 2.3, 5.0)] == [0, 7, 20, 20]


def test_the_next_request_is_due_frozen_steps_before_the_seam_and_late_asks_for_now():
    grid = StepGrid(0.0, DT, 20, 100).with_window(StepGrid(0.0, DT, 20, 100).plan_window(1, 0, 3, 50, 3))  # seam at 23
    assert next_request_step(grid, frozen=4, now_s=1.85) is None
    assert next_request_step(grid, frozen=4, now_s=1.9) == 19
    assert next_request_step(grid, frozen=4, now_s=2.04) == 20


def test_a_goal_sent_now_can_take_over_one_tick_plus_twice_its_delivery_time_later():
    grid = StepGrid(0.0, DT, 20, 100)
    assert earliest_seam_step(grid, now_s=1.0, tick_period_s=0.01, goal_latency_s=0.0) == 11
    assert earliest_seam_step(grid, now_s=1.0, tick_period_s=0.01, goal_latency_s=0.1) == 13
    assert earliest_seam_step(grid, now_s=1.0, tick_period_s=0.05, goal_latency_s=0.0) == 11
    assert earliest_seam_step(grid, now_s=1.0, tick_period_s=0.1, goal_latency_s=0.0) == 11
    assert earliest_seam_step(grid, now_s=1.0, tick_period_s=0.11, goal_latency_s=0.0) == 12


def test_a_runout_covers_half_as_many_chunk_steps_as_run_steps():
    assert RUNOUT_SLOWDOWN == 2
    seconds = runout_duration(np.array([0.5, 0.0]), np.array([5.0, 5.0]), DT, nominal=1.0, spare_steps=30)
    assert seconds == pytest.approx(1.0) and runout_chunk_steps(seconds, DT) == 5


# -- the planner ---------------------------------------------------------------------------
def test_the_first_chunk_starts_from_the_arm_at_rest_at_the_earliest_step():
    start, planned = first_plan()
    assert (planned.window.seam_step, planned.window.steps, planned.seam_time_s, planned.stall_s) == (2, 20, pytest.approx(0.2), 0.0)
    motion = planned.sent.motion
    p, v, _ = motion.evaluate(np.array([0.2]))
    assert np.allclose(p[0], START, atol=1e-9) and np.allclose(v[0], 0.0, atol=1e-9)
    assert planned.sent.grid.sent_end == 22 and planned.sent.grid.tail.runout_steps == runout_chunk_steps(motion.runout, DT) > 0
    assert start.grid.sent_end == 0 and start.motion is None  # the state before is untouched


def test_a_first_chunk_starts_at_the_step_it_arrived_and_its_goal_takes_effect_within_that_step():
    start = SentMotion(StepGrid(0.0, DT, 20, 100))

    def first(arrival: Arrival, earliest: int) -> Planned:
        planned = plan_chunk(PlanInput(start, GoalState.NONE, ramp(), 1, 0, 6, earliest, START, SHAPING, FakeChecks(), arrival))
        assert isinstance(planned, Planned)
        return planned

    # Arrived on step 5; a goal sent now takes effect at 0.51 s (one tick), so the earliest whole
    # step is 6. The window starts at step 5 with the chunk's step 0 (the arm has rested there),
    # and the goal takes over at 0.51 s from rest.
    on_step = first(Arrival(step=5, goal_takes_effect_s=0.51), earliest=6)
    assert (on_step.window.seam_step, on_step.window.first_chunk_step, on_step.seam_time_s) == (5, 0, pytest.approx(0.5))
    assert on_step.takes_over_s == pytest.approx(0.51) and on_step.sent.motion.seam == pytest.approx(0.51)
    assert on_step.sent.samples.times[0] == pytest.approx(0.51)  # nothing before the goal takes effect
    p, v, _ = on_step.sent.motion.evaluate(np.array([0.51]))
    assert np.allclose(p[0], START, atol=1e-12) and np.allclose(v[0], 0.0, atol=1e-12)
    assert on_step.sent.grid.sent_end == 25
    # Arrived between steps (0.45 s): the window and the goal both start at step 5, as before.
    between = first(Arrival(step=5, goal_takes_effect_s=0.46), earliest=5)
    assert (between.window.seam_step, between.takes_over_s) == (5, pytest.approx(0.5))
    # A goal that takes longer to reach the controller (over ROS): the window starts at the step
    # before the earliest whole step, so the arm never catches up more than a step from rest.
    slow = first(Arrival(step=3, goal_takes_effect_s=0.57), earliest=6)
    assert (slow.window.seam_step, slow.window.first_chunk_step, slow.takes_over_s) == (5, 0, pytest.approx(0.57))
    # A goal that takes effect exactly as a step begins (a tick as long as a step) takes over there.
    on_boundary = first(Arrival(step=5, goal_takes_effect_s=0.6), earliest=6)
    assert (on_boundary.window.seam_step, on_boundary.takes_over_s) == (6, pytest.approx(0.6))


def test_a_chunk_waits_while_the_previous_goal_is_unanswered():
    _, planned = first_plan()
    assert plan(planned.sent, ramp(), index=2, request_step=19, goal=GoalState.SENT) == Wait(WaitReason.GOAL_UNANSWERED)


def test_an_on_time_chunk_joins_at_the_end_of_the_sent_motion_without_a_stall():
    _, first = first_plan()
    second = plan(first.sent, ramp(), index=2, request_step=19, frozen=3, earliest=21, goal=GoalState.PLAYING)
    assert isinstance(second, Planned)
    assert (second.window.seam_step, second.window.first_chunk_step, second.stall_s) == (22, 3, 0.0)
    assert second.sent.grid.executed_until == 40
    p_join, v_join, _ = second.sent.motion.evaluate(np.array([2.2]))
    p_prev, v_prev, _ = first.sent.motion.evaluate(np.array([2.2]))
    assert np.allclose(p_join, p_prev, atol=1e-9) and np.allclose(v_join, v_prev, atol=1e-9)


def test_a_chunk_too_late_to_join_the_playing_motion_waits_then_starts_from_rest_with_a_stall():
    _, first = first_plan()
    motion = first.sent.motion
    late_step = int(np.ceil(motion.rest_time / DT)) + 1
    waits = plan(first.sent, ramp(), index=2, request_step=19, frozen=3, earliest=late_step, goal=GoalState.PLAYING)
    assert waits == Wait(WaitReason.MOTION_ENDS_FIRST)
    planned = plan(first.sent, ramp(), index=2, request_step=19, frozen=3, earliest=late_step, goal=GoalState.ENDED)
    assert isinstance(planned, Planned)
    assert planned.window.seam_step == late_step
    assert planned.stall_s == pytest.approx(late_step * DT - motion.full_speed_end)


def test_a_late_chunk_joins_the_tail_where_the_arm_is_and_the_steps_played_there_count():
    _, first = first_plan()
    # Chunk 1's window ends at step 22; its 29 steps beyond: 26 at full speed, then a 3-step runout.
    assert first.sent.grid.tail == Tail(26, 3, DT)
    late = plan(first.sent, ramp(), index=2, request_step=19, frozen=3, earliest=30, goal=GoalState.PLAYING)
    assert isinstance(late, Planned)
    # 8 steps into the tail, the arm is where chunk 2's step 11 puts it: played from there, no stall.
    assert (late.window.seam_step, late.window.first_chunk_step, late.window.tail_played, late.stall_s) == (30, 11, 8, 0.0)
    assert late.sent.grid.executed_until == 20 + 8 + 20
    p_join, v_join, _ = late.sent.motion.evaluate(np.array([3.0]))
    p_tail, v_tail, _ = first.sent.motion.evaluate(np.array([3.0]))
    assert np.allclose(p_join, p_tail, atol=1e-9) and np.allclose(v_join, v_tail, atol=1e-9)
    assert np.allclose(v_tail[0], [0.5, 0.0], atol=1e-6)  # still the chunk's own 0.05 rad per step


def test_the_next_request_is_timed_on_the_tail_when_the_latency_outgrows_the_window():
    _, first = first_plan()
    grid = first.sent.grid  # window from step 2 to 22, full speed to step 48, last chunk step at 51
    assert next_request_step(grid, frozen=4, now_s=1.75) is None and next_request_step(grid, frozen=4, now_s=1.8) == 18
    # 24 steps of latency: no request lands by step 22; it is timed to land as the tail slows down.
    assert next_request_step(grid, frozen=24, now_s=2.35) is None and next_request_step(grid, frozen=24, now_s=2.4) == 24
    # 40 steps: longer than half a chunk and the runout: asked for once half a chunk is left.
    assert next_request_step(grid, frozen=40, now_s=2.55) is None and next_request_step(grid, frozen=40, now_s=2.6) == 26


def test_a_tail_unsafe_from_some_point_on_is_cut_short_before_it():
    assert shorter_tails(Tail(26, 3, DT)) == [Tail(13, 3, DT), Tail(6, 3, DT), Tail(3, 3, DT), Tail(1, 3, DT), Tail(0, 3, DT), NO_TAIL]
    start = SentMotion(StepGrid(0.0, DT, 20, 100))
    # The whole tail would end at 2.2 + 2.6 + 0.6 = 5.4 s; with 13 steps at full speed at 4.1 s,
    # with 6 at 3.4 s: the longest that stays before 4.0 s.
    planned = plan(start, ramp(), checks=FakeChecks(path_horizon_s=4.0))
    assert isinstance(planned, Planned)
    assert planned.sent.grid.tail == Tail(6, 3, DT) and planned.sent.motion.rest_time == pytest.approx(3.4)


def test_rejections_name_the_chunk_and_the_reason():
    start = SentMotion(StepGrid(0.0, DT, 20, 100))
    outside = CheckFailure(FailureKind.POSITION_LIMIT, "j1 at 9 rad")
    too_fast = CheckFailure(FailureKind.VELOCITY_LIMIT, "velocity of j1")
    assert plan(start, ramp(), checks=FakeChecks(values_reason=outside)) == Failure(FailureKind.POSITION_LIMIT, "chunk 1 rejected: j1 at 9 rad")
    assert plan(start, ramp(), checks=FakeChecks(limits_reason=too_fast)) == Failure(FailureKind.VELOCITY_LIMIT, "chunk 1 rejected: velocity of j1")
    _, first = first_plan()
    short = plan(first.sent, ramp(steps=3), index=2, request_step=19, frozen=3, earliest=21, goal=GoalState.PLAYING)
    assert isinstance(short, Failure) and short.detail.startswith("chunk 2 rejected: chunk 2 has 3 steps but takes over at its step 3")
    assert short.kind is FailureKind.SHORT_CHUNK and short.rejects_chunk


def test_a_path_unsafe_all_along_its_tail_is_sent_without_one():
    start = SentMotion(StepGrid(0.0, DT, 20, 100))
    planned = plan(start, ramp(), checks=FakeChecks(path_horizon_s=2.2))  # the window ends at 2.2 s
    assert isinstance(planned, Planned)
    assert planned.sent.motion.rest_time == planned.sent.motion.end and planned.sent.grid.tail == NO_TAIL
    assert np.allclose(planned.sent.samples.velocities[-1], 0.0, atol=1e-9)  # at rest where the window ends
    unsafe = plan(start, ramp(), checks=FakeChecks(path_horizon_s=1.0))
    assert unsafe == Failure(FailureKind.WORLD_COLLISION, "chunk 1 rejected: beyond the horizon")


def test_a_window_with_too_few_run_steps_after_it_for_a_runout_ends_at_rest():
    # Three run steps remain after the window: too few for a runout from the ramp's 0.5 rad/s
    # (with four, one fits). The window is not the run's last, yet nothing follows it at speed:
    # it comes to rest at its end (a stock JTC refuses a goal whose last point moves).
    _, planned = first_plan(total_steps=23)
    motion = planned.sent.motion
    assert planned.sent.grid.tail == NO_TAIL and planned.sent.grid.remaining > 0
    _, v, _ = motion.evaluate(np.array([motion.end]))
    assert motion.rest_time == motion.end and np.allclose(v, 0.0, atol=1e-9)
    assert np.allclose(planned.sent.samples.velocities[-1], 0.0, atol=1e-9)


def test_a_seam_blend_that_outlasts_the_tail_brings_the_window_to_rest_at_its_end():
    # Under a gentle acceleration limit the ramp's 0.5 rad/s, started from rest, is joined over a
    # blend of 7.9 s: longer than the window and a tail (4.9 s), whose runout slows the chunk but
    # not the blend. With that tail the goal would end at 0.036 rad/s (a stock JTC refuses it).
    gentle = replace(SHAPING, max_acceleration=np.full(2, 0.5))
    start = SentMotion(StepGrid(0.0, DT, 20, 100))
    planned = plan_chunk(PlanInput(start, GoalState.NONE, ramp(), 1, 0, 2, 2, START, gentle, FakeChecks()))
    assert isinstance(planned, Planned)
    motion = planned.sent.motion
    assert motion.blend_duration == pytest.approx(7.88, abs=0.01) and planned.sent.grid.tail == NO_TAIL
    assert motion.rest_time == motion.end and planned.sent.grid.remaining > 0
    assert np.allclose(planned.sent.samples.velocities[-1], 0.0, atol=1e-9)
    assert np.allclose(planned.sent.samples.positions[-1], motion.evaluate(np.array([motion.end]))[0][0])


def test_a_shorter_tail_that_the_seam_blend_outlasts_is_passed_over():
    # A 6.57 s blend: the full tail (rest 6.8 s after the seam) outlasts it, but goes past the
    # path's horizon; the next shorter tail (half the extension, rest after 6.3 s) would pass
    # the checks and end moving, so the window comes to rest at its end instead.
    gentle = replace(SHAPING, max_acceleration=np.full(2, 0.6))
    start = SentMotion(StepGrid(0.0, DT, 20, 100))
    planned = plan_chunk(PlanInput(start, GoalState.NONE, ramp(), 1, 0, 2, 2, START, gentle, FakeChecks(path_horizon_s=6.6)))
    assert isinstance(planned, Planned)
    assert planned.sent.motion.blend_duration == pytest.approx(6.57, abs=0.01)
    assert planned.sent.grid.tail == NO_TAIL
    assert np.allclose(planned.sent.samples.velocities[-1], 0.0, atol=1e-9)


def test_the_runs_last_window_ends_at_rest_without_a_runout():
    _, planned = first_plan(total_steps=20)
    motion = planned.sent.motion
    _, v, _ = motion.evaluate(np.array([motion.end]))
    assert motion.runout == 0.0 and np.allclose(v, 0.0, atol=1e-9)
    assert planned.sent.grid.remaining == 0


def test_a_run_that_stops_while_the_arm_waits_counts_the_wait_as_a_stall():
    start, planned = first_plan()
    end = planned.sent.motion.full_speed_end  # the arm leaves full speed when the chunk's tail runs out
    assert stall_at_stop_s(None, 9.0) == 0.0 and stall_at_stop_s(start, 9.0) == 0.0
    assert stall_at_stop_s(planned.sent, end + 0.7) == pytest.approx(0.7)
    _, last = first_plan(total_steps=20)
    assert stall_at_stop_s(last.sent, 9.0) == 0.0  # every step sent: nothing waits


# -- the stream's states -------------------------------------------------------------------
def test_stream_state_holding_comes_before_awaiting_and_scheduling():
    flight = InFlight(None, 0.0, 0, 2, None)
    held = HeldChunk(ramp(), None, flight)
    assert stream_state(None, None) is StreamState.SCHEDULING
    assert stream_state(None, flight) is StreamState.AWAITING_CHUNK
    assert stream_state(held, None) is StreamState.HOLDING
    assert stream_state(held, flight) is StreamState.HOLDING


def test_the_stream_is_finished_when_all_steps_are_sent_nothing_is_asked_and_the_goal_ended():
    _, last = first_plan(total_steps=20)
    ended = Goal(GoalState.ENDED, outcome="ok")
    flight = InFlight(None, 0.0, 0, 2, None)
    assert stream_finished(last.sent, None, ended)
    assert not stream_finished(last.sent, flight, ended)
    assert not stream_finished(last.sent, None, Goal(GoalState.PLAYING, handle=object(), result_future=object()))
    _, partial = first_plan(total_steps=100)
    assert not stream_finished(partial.sent, None, ended)

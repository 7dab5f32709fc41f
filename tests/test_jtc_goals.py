"""ExecutePolicy's goals for a stock JTC, against a model of what JTC plays.

``controller_link.jtc_stream_points`` builds a streamed chunk's goal; the model is the simulated
JTC's sampling (``sim.controllers.jtc_trajectory``: linear, cubic or quintic from the fields
present, merge at arrival or hard replace). Two consecutive windows are planned with the
executor's own shaping (smoothing spline, seam blend, densified samples): the first is what the
controller plays, the second arrives at a random instant before its seam.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from behaviors.controller_link import JtcStreamGoal, jtc_stream_points
from behaviors.execute_policy.checks import densify
from behaviors.execute_policy.seam import join_at_seam
from behaviors.execute_policy.step_spline import fit_chunk
from runtime.motion.samples import Samples
from sim.controllers.jtc_trajectory import JtcPoints, JtcTrajectory, merge_at_arrival, replace_at_arrival
from sim.controllers.trajectory import TIME_EPS

DT = 0.1
STEPS = 30
JOINTS = 6


def chunk(seed: int, start: np.ndarray) -> np.ndarray:
    """A policy-like chunk: a random smooth drift from ``start`` with step noise."""
    rng = np.random.default_rng(seed)
    drift = np.cumsum(rng.normal(0.0, 0.02, (STEPS, JOINTS)), axis=0)
    return start + drift + rng.normal(0.0, 0.003, (STEPS, JOINTS))


def plans(seed: int, request_step: int, seam_step: int) -> tuple[Samples, Samples]:
    """The first window (steps 0..seam_step, from rest) and the next one, joined at ``seam_step``."""
    first = chunk(seed, np.zeros(JOINTS))
    spline_a = fit_chunk(first, 300.0)
    motion_a = join_at_seam(spline_a, DT, 0.0, 0.0, (seam_step + 10) * DT, spline_a(0.0), np.zeros(JOINTS), nominal_s=DT)
    seam = seam_step * DT
    p, v, _ = motion_a.evaluate(np.array([seam]))
    second = chunk(seed + 1, first[request_step])
    motion_b = join_at_seam(fit_chunk(second, 300.0), DT, request_step * DT, seam, seam + 12 * DT, p[0], v[0], nominal_s=6 * DT)
    return densify(motion_a, 100), densify(motion_b, 100)


def goal_points(goal: JtcStreamGoal) -> JtcPoints:
    """The goal as JTC reads it: times from the stamp, the seam's point without accelerations."""
    points = goal.samples
    has_acceleration = np.full(len(points), True)
    has_acceleration[goal.seam_index] = False
    return JtcPoints(points.times - goal.stamp_s, points.positions, points.velocities, points.accelerations,
                     np.full(len(points), True), has_acceleration)


def playing(previous: Samples) -> JtcTrajectory:
    """The previous goal as JTC plays it (stamped at its first sample)."""
    points = JtcPoints.build(previous.times, previous.positions, previous.velocities, previous.accelerations)
    return JtcTrajectory(points, float(previous.times[0]), points.state(0))


def planned_state(previous: Samples, new: Samples, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The planned motion at sample times ``t`` (each a sample of one of the two plans)."""
    before = t < new.times[0] - 1e-9
    positions = np.where(before[:, None], _at(previous, t, "positions"), _at(new, t, "positions"))
    velocities = np.where(before[:, None], _at(previous, t, "velocities"), _at(new, t, "velocities"))
    return positions, velocities


def _at(samples: Samples, t: np.ndarray, name: str) -> np.ndarray:
    k = np.clip(np.searchsorted(samples.times, t - 1e-9), 0, len(samples.times) - 1)
    return getattr(samples, name)[k]


arrivals = st.tuples(st.integers(0, 10_000), st.integers(8, 14), st.floats(0.05, 0.6))


@settings(max_examples=25, deadline=None)
@given(arrivals)
def test_merge_at_arrival_plays_exactly_the_planned_samples_with_the_seam_at_the_planned_step(case):
    seed, seam_step, lead_s = case
    previous, new = plans(seed, seam_step - 5, seam_step)
    seam = new.times[0]
    arrival = seam - lead_s
    goal = jtc_stream_points(previous, new, lands_s=arrival + 0.01)
    played = merge_at_arrival(playing(previous), goal_points(goal), goal.stamp_s, arrival, before=playing(previous).sample(arrival))
    ahead = np.concatenate([previous.times[previous.times > arrival], new.times])
    ahead = ahead[ahead < new.times[-1]]
    positions, velocities = planned_state(previous, new, ahead)
    got = played.sample_many(ahead)
    np.testing.assert_allclose(got.position, positions, atol=1e-9)  # every checked sample, on time
    np.testing.assert_allclose(got.velocity, velocities, atol=1e-7)
    # between the samples: what the controller played before the goal, up to the sample before
    # the seam; from there on the planned motion (the cubics through the seam: within 10 um rad)
    before = previous.times[previous.times < seam - 1e-6][-1]
    dense = np.arange(arrival + 0.012, before, 0.001)
    np.testing.assert_allclose(played.sample_many(dense).position, playing(previous).sample_many(dense).position, atol=1e-9)
    dense = np.arange(before, new.times[-1], 0.0005)
    np.testing.assert_allclose(played.sample_many(dense).position, _planned_dense(previous, new, dense), atol=1e-5)
    across = played.sample_many(np.array([seam - 1e-6, seam + 1e-6]))
    assert np.abs(np.diff(across.velocity, axis=0)).max() < 1e-4  # velocity continuous at the seam


@settings(max_examples=25, deadline=None)
@given(arrivals, st.floats(-0.2, 0.2))
def test_a_hard_replacing_jtc_gets_a_continuous_motion_wherever_the_goal_lands(case, landing_error_s):
    seed, seam_step, lead_s = case
    previous, new = plans(seed, seam_step - 5, seam_step)
    seam = new.times[0]
    expected = seam - lead_s
    arrival = min(expected + landing_error_s, seam - 0.005)  # late or early against the estimate, always before the seam
    goal = jtc_stream_points(previous, new, lands_s=expected)
    stamp = goal.stamp_s
    old = playing(previous)
    played = replace_at_arrival(goal_points(goal), stamp, arrival, before=old.sample(arrival))
    dense = np.arange(arrival, new.times[-1], 0.001)
    states = played.sample_many(dense)
    step_velocity = np.abs(np.diff(states.position, axis=0)).max() / 0.001
    peak_velocity = max(np.abs(previous.velocities).max(), np.abs(new.velocities).max())
    assert step_velocity <= peak_velocity * 1.05 + 1e-3  # no jump: never much faster than the plan
    # Picks up where the arm is (a goal landing within TIME_EPS of its stamp starts at its first
    # point: at most TIME_EPS of the plan's motion away).
    assert np.abs(states.position[0] - old.sample(arrival).position).max() < peak_velocity * TIME_EPS + 1e-9
    after = dense[dense >= max(stamp, arrival) + 0.02]
    np.testing.assert_allclose(played.sample_many(after).position, _planned_dense(previous, new, after), atol=2e-4)


def _planned_dense(previous: Samples, new: Samples, t: np.ndarray) -> np.ndarray:
    before = t < new.times[0]
    return np.where(before[:, None], playing(previous).sample_many(t).position, playing(new).sample_many(t).position)


@settings(max_examples=25, deadline=None)
@given(arrivals)
def test_no_point_jtc_plays_exceeds_what_the_checked_samples_reach(case):
    seed, seam_step, lead_s = case
    previous, new = plans(seed, seam_step - 5, seam_step)
    arrival = new.times[0] - lead_s
    goal = jtc_stream_points(previous, new, lands_s=arrival + 0.01)
    played = merge_at_arrival(playing(previous), goal_points(goal), goal.stamp_s, arrival, before=playing(previous).sample(arrival))
    dense = played.sample_many(np.arange(arrival + 0.012, new.times[-1], 0.0005))
    checked = Samples(*(np.concatenate([getattr(previous, f)[previous.times > arrival], getattr(new, f)]) for f in
                        ("times", "positions", "velocities", "accelerations")))
    for got, limit in ((dense.velocity, checked.velocities), (dense.acceleration, checked.accelerations)):
        peak = np.abs(limit).max(axis=0)
        assert np.all(np.abs(got).max(axis=0) <= peak * 1.01 + 1e-6)  # within 1 % of the checked peak, per joint


def test_the_goal_starts_at_the_first_sample_at_or_after_the_landing_and_ends_at_rest():
    previous, new = plans(3, 5, 10)
    lands = new.times[0] - 0.25
    goal = jtc_stream_points(previous, new, lands)
    points = goal.samples
    first = previous.times[previous.times >= lands - 1e-6][0]
    assert goal.stamp_s == first and points.times[0] == first
    assert points.times[goal.seam_index] == pytest.approx(new.times[0])
    assert points.times[-1] == new.times[-1] and np.all(np.diff(points.times) > 0)


def test_a_goal_that_ends_at_rest_ends_with_exactly_zero_velocity():
    _, new = plans(5, 5, 10)
    velocities = new.velocities.copy()
    velocities[-1] = 3e-9  # at rest, up to rounding: JTC refuses anything above float epsilon
    goal = jtc_stream_points(None, Samples(new.times, new.positions, velocities, new.accelerations), lands_s=0.0)
    assert np.all(goal.samples.velocities[-1] == 0.0)


def test_without_a_playing_motion_the_goal_is_the_new_samples_at_the_seam():
    _, new = plans(4, 5, 10)
    goal = jtc_stream_points(None, new, lands_s=0.0)
    assert goal.stamp_s == new.times[0] and len(goal.samples) == len(new) and goal.seam_index == 0

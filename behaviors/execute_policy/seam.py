"""The seam: how a chunk joins the motion the controller plays. Pure functions, no state.

At the seam the chunk's smoothed motion differs from the sent one (``state_at``: where the arm
is and how fast it moves when the goal takes over) by an offset in position and velocity. The
offset is blended out with the quintic of ``runtime.motion.seam_blend`` (shared with the
simulated controllers) over half the window (``nominal_blend_s``), longer where that would take
more than ``BLEND_SHARE`` of the acceleration the chunk's own motion leaves free
(``join_at_seam``). A chunk whose seam comes after the motion still playing has ended cannot
join it (``motion_ends_first``).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from runtime.motion import seam_blend

from ..action_goal import GoalState
from .shaping import ChunkMotion
from .step_spline import StepSpline

if TYPE_CHECKING:
    from .shaping import ShapingConfig
    from .stream import StepGrid, Window


NOMINAL_BLEND_WINDOWS = 0.5
"""The blend lasts this share of the window (at least one step) unless the offset needs longer."""


def nominal_blend_s(window_steps: int, dt: float) -> float:
    """How long the blend lasts unless the offset needs longer: half the window, at least a step."""
    return max(dt, NOMINAL_BLEND_WINDOWS * window_steps * dt)


def motion_ends_first(previous: ChunkMotion | None, seam_time_s: float, goal: GoalState) -> bool:
    """Whether the seam comes too late to join the motion the controller still plays (its
    runout included): a seam after its end would be refused. The chunk then waits for it to
    finish and starts from rest (a pause, counted as a stall)."""
    return previous is not None and seam_time_s > previous.rest_time + 1e-9 and goal is not GoalState.ENDED


def state_at(motion: ChunkMotion | None, t: float, rest_position: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity of the sent motion at ``t`` (at rest after it ends; at
    ``rest_position`` before the first chunk)."""
    if motion is None:
        assert rest_position is not None, "the arm's position is needed before the first chunk"
        return rest_position, np.zeros(len(rest_position))
    if t > motion.rest_time + 1e-9:  # drained: the arm rests where the motion ended
        p, _, _ = motion.evaluate(np.array([motion.rest_time]))
        return p[0], np.zeros(p.shape[1])
    p, v, _ = motion.evaluate(np.array([t]))
    return p[0], v[0]


def join(previous: ChunkMotion | None, spline: StepSpline, window: Window, grid: StepGrid, takes_over_s: float,
         rest_position: np.ndarray | None, shaping: ShapingConfig) -> ChunkMotion:
    """The chunk's motion (its fit ``spline``) over ``window``, taking over from the sent motion
    ``previous`` at ``takes_over_s`` (``at_rest.take_over_time``) where the arm is then."""
    position, velocity = state_at(previous, takes_over_s, rest_position)
    return join_at_seam(spline, shaping.dt, grid.time(window.request_step), takes_over_s, grid.time(window.end_step),
                        position, velocity, blend_duration=nominal_blend_s(window.steps, shaping.dt),
                        max_acceleration=shaping.max_acceleration)


BLEND_SHARE = 0.5
"""The blend may use this share of the acceleration the chunk's own motion leaves free (half,
as the runout brakes with half the limit): a long way to join is covered gently."""


def chunk_acceleration_peak(spline: StepSpline, dt: float, from_step: float) -> np.ndarray:
    """Per joint, the largest acceleration (rad/s^2) of the smoothed chunk from ``from_step`` to
    its last step. Its second derivative is piecewise linear between the integer steps (the
    knots), so the steps and ``from_step`` are where it peaks."""
    last = spline.last_step
    steps = np.unique(np.concatenate([[min(from_step, last)], np.arange(math.ceil(from_step), math.floor(last) + 1)]))
    return np.abs(np.atleast_2d(spline(steps, nu=2))).max(axis=0) / (dt * dt)


def join_at_seam(
    spline: StepSpline,
    dt: float,
    chunk_start: float,
    seam: float,
    end: float,
    sent_position: np.ndarray,
    sent_velocity: np.ndarray,
    blend_duration: float,
    max_acceleration: np.ndarray | None = None,
) -> ChunkMotion:
    """The chunk's motion from ``seam`` to ``end``, continuous in position and velocity with
    the sent motion's state (``sent_position``, ``sent_velocity``) at the seam.

    The offset between the two is blended out (``runtime.motion.seam_blend``) over ``blend_duration``
    seconds; with ``max_acceleration`` (per joint) over longer where that would take more than
    ``BLEND_SHARE`` of the acceleration the chunk leaves free: a chunk that starts away from where the
    arm is (a policy that re-planned, or ran ahead of an arm that paused) joins more slowly
    instead of being planned over the limits."""
    if not end > seam:
        raise ValueError(f"empty window: seam t={seam:.3f} s, end t={end:.3f} s")
    k = (seam - chunk_start) / dt
    offset_p = np.asarray(sent_position, dtype=float) - spline(k)
    offset_v = np.asarray(sent_velocity, dtype=float) - spline(k, nu=1) / dt
    if max_acceleration is not None:
        headroom = np.asarray(max_acceleration, dtype=float) - chunk_acceleration_peak(spline, dt, k)
        blend_duration = seam_blend.blend_duration(offset_p, offset_v, BLEND_SHARE * headroom, blend_duration)
    return ChunkMotion(spline, dt, chunk_start, seam, end, offset_p, offset_v, max(blend_duration, 1e-6))

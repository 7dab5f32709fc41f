"""Where a chunk's seam is planned: a pure function from the sent motion, the chunk and the
time to Planned / Wait / Failure (a rejected chunk). Nothing here talks to the bus or reads the clock.

``plan_chunk`` picks the chunk's window on the step grid (``StepGrid.plan_window``), decides
whether it can join the motion the controller plays or must wait, blends it into that motion
(``shaping``), gives it a tail (the chunk's steps beyond the window at full speed, then a runout
to rest at its last step) or brings the run's last window to rest, and has every
densified point checked (``PlanInput.checks``, see ``checks.PointChecks``). A Planned result
carries the grid after the commit; the caller keeps the grid from before it for a rollback.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .checks import CheckFailure
from .chunk import Chunk
from .failure import Failure, FailureKind
from .shaping import NO_TAIL, ChunkMotion, Tail, densify, fit_chunk, join_at_seam, plan_tail, runout_chunk_steps
from runtime.motion.samples import Samples
from .states import GoalState, SentMotion
from .at_rest import Arrival, arrives_at_rest, take_over_time, window_arrival_step
from .stream import StepGrid, Window, WindowError, drained_seconds

class Checks(Protocol):
    """The point checks a plan must pass; each returns why it fails, or None."""

    def values(self, chunk: Chunk, window: Window) -> CheckFailure | None: ...
    def limits(self, samples: Samples, window: Window) -> CheckFailure | None: ...
    def path(self, samples: Samples, window: Window) -> CheckFailure | None: ...


@dataclass(frozen=True)
class ShapingConfig:
    """The run's settings the planner uses (from ``config.PolicyRunConfig``)."""

    dt: float
    committed_action_steps: int
    policy_tracking_weight: float
    num_interpolation_points: int
    max_acceleration: np.ndarray


@dataclass(frozen=True)
class PlanInput:
    sent: SentMotion  # what the controller has been sent so far
    goal: GoalState  # of the newest goal
    chunk: Chunk
    index: int  # chunk number, 1-based
    request_step: int
    frozen: int
    earliest_seam_step: int  # the first step a goal sent now reaches the controller before
    rest_position: np.ndarray | None  # the arm's position now; needed only before the first chunk
    config: ShapingConfig
    checks: Checks
    arrival: Arrival | None = None  # when the chunk came; None: it is placed by earliest_seam_step alone


class WaitReason(enum.Enum):
    GOAL_UNANSWERED = "the controller has not answered the previous goal"
    MOTION_ENDS_FIRST = "the motion still playing ends before the chunk could join it"


@dataclass(frozen=True)
class Wait:
    reason: WaitReason


@dataclass(frozen=True)
class Planned:
    window: Window
    seam_time_s: float  # of the window's seam step
    sent: SentMotion  # once sent: the new grid, motion and samples
    stall_s: float  # the arm had left full speed (runout, then rest) this long before the seam
    takes_over_s: float  # the goal's stamp: the seam, or within its step for a first chunk (take_over_time)


def rejected(index: int, why: CheckFailure) -> Failure:
    """Chunk ``index`` rejected for failing a check."""
    return Failure(why.kind, f"chunk {index} rejected: {why}")


def plan_chunk(inp: PlanInput) -> Planned | Wait | Failure:
    if inp.goal is GoalState.SENT:
        # Whether the controller plays the previous goal decides how this chunk joins (a refused
        # goal rolls the stream back).
        return Wait(WaitReason.GOAL_UNANSWERED)
    from_rest = inp.arrival if arrives_at_rest(inp.sent.motion, inp.arrival, inp.sent.grid) else None  # see ``at_rest``
    plan = _plan(inp, from_rest)
    if isinstance(plan, Failure) and from_rest is not None:
        # A window started at the arrival step gives the start from rest a fraction of a step
        # less (the goal takes over within the step): a short window may need the whole step.
        later = _plan(inp, None)
        if not isinstance(later, Failure):
            return later
    return plan


def _plan(inp: PlanInput, from_rest: Arrival | None) -> Planned | Wait | Failure:
    """``plan_chunk`` with the window started at the arrival step (``from_rest``) or at the
    earliest seam (None)."""
    shaping, grid, chunk, index = inp.config, inp.sent.grid, inp.chunk, inp.index
    previous = inp.sent.motion
    try:
        window = grid.plan_window(index, inp.request_step, inp.frozen, chunk.steps, inp.earliest_seam_step,
                                  runout_reserve=runout_chunk_steps(nominal_runout_s(shaping), shaping.dt),
                                  arrival_step=window_arrival_step(from_rest, grid, inp.earliest_seam_step))
    except WindowError as err:
        return Failure(FailureKind.SHORT_CHUNK, f"chunk {index} rejected: {err}")
    outside = inp.checks.values(chunk, window)
    if outside is not None:
        return rejected(index, outside)
    seam_time = grid.time(window.seam_step)
    if previous is not None and seam_time > previous.rest_time + 1e-9 and inp.goal is not GoalState.ENDED:
        # Too late to join the motion the controller is still playing (its runout included): a
        # seam after its end would be refused. Wait for it to finish; the chunk then starts from
        # rest (a pause, counted as a stall).
        return Wait(WaitReason.MOTION_ENDS_FIRST)
    takes_over = take_over_time(seam_time, from_rest)
    start_p, start_v = state_at(previous, takes_over, inp.rest_position)
    motion = join_at_seam(
        fit_chunk(chunk.arm, shaping.policy_tracking_weight),
        shaping.dt,
        grid.time(window.request_step),
        takes_over,
        grid.time(window.end_step),
        start_p,
        start_v,
        blend_duration=max(shaping.dt, 0.5 * window.steps * shaping.dt),
        max_acceleration=shaping.max_acceleration,
    )
    last_window = window.tail_played + window.steps >= grid.remaining
    tail = NO_TAIL if last_window else chunk_tail(motion, chunk, window, grid.remaining - window.tail_played - window.steps, shaping)
    motion = ending(motion, tail)
    # A chunk over the limits on its own is the policy's; the join is planned within them.
    reason = inp.checks.limits(densify(motion.chunk_alone(), shaping.num_interpolation_points), window)
    if reason is not None:
        return rejected(index, reason)
    samples = densify(motion, shaping.num_interpolation_points)
    reason = inp.checks.path(samples, window)
    for shorter in shorter_tails(tail) if reason is not None else ():
        # The tail only keeps the arm going while the next chunk is late: where the chunk's path
        # beyond its window is unsafe but the window is not, the tail stops short of the unsafe
        # point (a shorter extension, then the runout), or the window ends without one. A shorter
        # tail that the seam's blend outlasts would not end at rest: passed over.
        if not comes_to_rest(motion, shorter):
            continue
        candidate = ending(motion, shorter)
        candidate_samples = densify(candidate, shaping.num_interpolation_points)
        if inp.checks.path(candidate_samples, window) is None:
            motion, samples, reason, tail = candidate, candidate_samples, None, shorter
            break
    if reason is not None:
        return rejected(index, reason)
    stall = drained_seconds(None if previous is None else previous.full_speed_end, seam_time)
    new_grid = grid.with_window(window, tail, chunk.steps)
    return Planned(window, seam_time, SentMotion(new_grid, motion, samples), stall, takes_over)


def ending(motion: ChunkMotion, tail: Tail) -> ChunkMotion:
    """The window's motion followed by ``tail``, or, with no tail (the run's last window, a chunk
    with too few steps beyond the window for a runout, a seam blend that outlasts the tail, a
    tail the path checks refuse), brought to rest at the window's end: a motion is never sent
    ending at speed (a stock JTC refuses such a goal, and nothing would carry the arm on if the
    next chunk were late)."""
    return motion.with_tail(tail) if tail.steps > 0 else motion.at_rest_at_end()


def comes_to_rest(motion: ChunkMotion, tail: Tail) -> bool:
    """Whether ``ending(motion, tail)`` is at rest when it ends: always without a tail; with one,
    only when the seam's blend is over before the runout ends (the runout slows the chunk's
    playback, not the blend: a chunk that starts far from the arm, or at another speed, is
    joined gently over a blend that can outlast a window and its tail)."""
    return tail.steps == 0 or motion.seam + motion.blend_duration <= motion.end + tail.extension_s + tail.runout_s + 1e-9


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


def nominal_runout_s(shaping: ShapingConfig) -> float:
    """How long a runout takes unless braking from the chunk's speed needs longer: a quarter of a
    window (it plays the chunk's last steps at half speed on average: time lost to a late chunk)."""
    return 0.25 * shaping.committed_action_steps * shaping.dt


def chunk_tail(motion: ChunkMotion, chunk: Chunk, window: Window, remaining_steps: int, shaping: ShapingConfig) -> Tail:
    """The window's tail if no chunk takes over at its end: the chunk's steps beyond the window
    at full speed, then a runout to rest at its last step (``shaping.plan_tail``). It stops a
    step short of the run's ``remaining_steps`` after the window, so a late chunk always has a
    step left to take over. None (``NO_TAIL``) when the seam's blend outlasts it
    (``comes_to_rest``)."""
    spare = min(chunk.steps - 1 - (window.end_step - window.request_step), remaining_steps - 1)
    if spare < 1:
        return NO_TAIL
    beyond = motion.end + shaping.dt * np.arange(spare + 1)
    _, velocity, _ = motion.evaluate(beyond)  # the window's motion carried on along the chunk
    tail = plan_tail(np.abs(velocity).max(axis=0), shaping.max_acceleration, shaping.dt, nominal_runout_s(shaping), spare)
    return tail if comes_to_rest(motion, tail) else NO_TAIL


def shorter_tails(tail: Tail) -> list[Tail]:
    """Tails to try, longest first, when ``tail`` fails the checks: the same runout after half
    the extension, a quarter, ..., none; then no tail at all."""
    extensions = []
    steps = tail.extension_steps // 2
    while steps > 0:
        extensions.append(steps)
        steps //= 2
    shorter = [Tail(e, tail.runout_steps, tail.dt) for e in extensions]
    if tail.extension_steps > 0:
        shorter.append(Tail(0, tail.runout_steps, tail.dt))
    return shorter + [NO_TAIL] if tail.steps > 0 else []


def next_request_step(grid: StepGrid, frozen: int, now_s: float) -> int | None:
    """The step to request the next chunk for, once it is due (so it lands ``frozen`` steps
    later, at the next seam); None before then. A late request asks for the step of now."""
    ideal = grid.ideal_request_step(frozen)
    if now_s + 1e-9 < grid.time(ideal):
        return None
    return max(ideal, grid.step_at_or_before(now_s))


def goal_takes_effect_s(now_s: float, tick_period_s: float, goal_latency_s: float) -> float:
    """The earliest instant a goal sent now surely takes effect: it must reach the controller
    first, so one tick plus twice the goal delivery time seen so far (zero in process; over ROS,
    transport and the next spin)."""
    return now_s + tick_period_s + 2 * goal_latency_s


def earliest_seam_step(grid: StepGrid, now_s: float, tick_period_s: float, goal_latency_s: float) -> int:
    """The first step a goal sent now can take over at (``goal_takes_effect_s``)."""
    return grid.step_at_or_after(goal_takes_effect_s(now_s, tick_period_s, goal_latency_s))


def stall_at_stop_s(sent: SentMotion | None, now_s: float) -> float:
    """The wait so far when the run ends while the arm waits for a chunk (a stall too)."""
    if sent is None or sent.grid.remaining == 0 or sent.motion is None:
        return 0.0
    return drained_seconds(sent.motion.full_speed_end, now_s)

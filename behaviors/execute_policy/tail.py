"""The tail: what follows a window when the next chunk is late. Pure functions, no state.

The chunk's steps beyond its window are the policy's own plan, so the arm goes on playing them
at full speed (the **extension**, one step per ``dt``) and slows to rest only as they run out
(the **runout**: it plays the chunk's last steps with playback speed ``1 - (3 s^2 - 2 s^3)``,
``runout_warp``, over a quarter of a window, longer if braking needs it, ``runout_duration``).
The tail stops a step short of the run's end, so a late chunk always has a step left to take
over. A tail the checks refuse is cut short (``tails_to_try``: half the extension, a quarter,
..., none, then no tail). A window without a tail comes to rest at its end (``ending``). How far
the arm got along a tail a given time after the window's end is ``tail_progress``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from .chunk import Chunk
    from .config import ShapingConfig
    from .seam import ChunkMotion
    from .stream import Window

RUNOUT_SLOWDOWN = 2
"""A runout plays the chunk at half speed on average: ``runout / (RUNOUT_SLOWDOWN * dt)`` chunk
steps in ``runout / dt`` run steps."""
NOMINAL_RUNOUT_WINDOWS = 0.25
"""A runout takes this share of a window unless braking from the chunk's speed needs longer (it
plays the chunk's last steps at half speed on average: time lost to a late chunk)."""


@dataclass(frozen=True)
class Tail:
    """What follows a window when the next chunk is late: ``extension_steps`` of the chunk's
    steps beyond the window at full speed, then a runout of ``runout_s`` seconds over its last
    ``runout_steps`` steps, ending at rest."""

    extension_steps: int
    runout_steps: int
    dt: float

    @property
    def extension_s(self) -> float:
        return self.extension_steps * self.dt

    @property
    def runout_s(self) -> float:
        return RUNOUT_SLOWDOWN * self.dt * self.runout_steps

    @property
    def steps(self) -> int:
        """Chunk steps the tail covers in all."""
        return self.extension_steps + self.runout_steps


NO_TAIL = Tail(0, 0, 1.0)


def runout_warp(s: NDArray[np.float64], runout: float, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Chunk steps advanced since the window's end, their rate and its rate, at runout fraction ``s``.

    The playback speed falls from one step per ``dt`` to zero as ``1 - (3 s^2 - 2 s^3)``: no
    acceleration step where the runout begins (the speed's slope is zero there) nor where it
    ends, and ``runout / (2 dt)`` steps are covered in all.
    """
    s = np.clip(s, 0.0, 1.0)
    steps = runout / dt * (s - s**3 + 0.5 * s**4)
    rate = (1.0 - 3.0 * s**2 + 2.0 * s**3) / dt
    rate_of_rate = (-6.0 * s + 6.0 * s**2) / (runout * dt)
    return steps, rate, rate_of_rate


def nominal_runout_s(committed_action_steps: int, dt: float) -> float:
    """How long a runout takes unless braking from the chunk's speed needs longer."""
    return NOMINAL_RUNOUT_WINDOWS * committed_action_steps * dt


def runout_duration(end_velocity: NDArray[np.float64], max_acceleration: NDArray[np.float64], dt: float, nominal: float, spare_steps: int) -> float:
    """Length of the runout after a window that ends at ``end_velocity``: ``nominal`` seconds,
    longer if that would brake harder than half of ``max_acceleration`` (the warp peaks at
    1.5 v / runout), in whole pairs of ``dt`` so the runout covers whole chunk steps. Zero when
    the chunk has fewer than the needed ``spare_steps`` beyond the window: it says nothing about
    where to go."""
    speed = np.abs(np.asarray(end_velocity, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        needed = float(np.max(np.where(speed > 0, 3.0 * speed / np.asarray(max_acceleration, dtype=float), 0.0), initial=0.0))
    steps = math.ceil(max(nominal, needed) / (RUNOUT_SLOWDOWN * dt) - 1e-9)
    if steps < 1 or steps > spare_steps:
        return 0.0
    return RUNOUT_SLOWDOWN * dt * steps


def runout_chunk_steps(runout_s: float, dt: float) -> int:
    """Chunk steps a runout of ``runout_s`` seconds covers (it takes ``RUNOUT_SLOWDOWN`` run steps each)."""
    return round(runout_s / (RUNOUT_SLOWDOWN * dt))


def runout_reserve_steps(committed_action_steps: int, dt: float) -> int:
    """Chunk steps a late chunk's window leaves for its own runout: those of a nominal runout."""
    return runout_chunk_steps(nominal_runout_s(committed_action_steps, dt), dt)


def plan_tail(peak_velocity: NDArray[np.float64], max_acceleration: NDArray[np.float64], dt: float, nominal_runout_s: float, spare_steps: int) -> Tail:
    """The tail over the ``spare_steps`` chunk steps beyond a window, the fastest of which move
    at ``peak_velocity``: the runout (``runout_duration``, braking from that speed) takes the
    last steps, so the motion comes to rest at the chunk's last step, and the steps before it
    are played at full speed. No tail when the spare steps cannot hold a runout."""
    runout = runout_duration(peak_velocity, max_acceleration, dt, nominal_runout_s, spare_steps)
    if runout <= 0:
        return NO_TAIL
    runout_steps = runout_chunk_steps(runout, dt)
    return Tail(spare_steps - runout_steps, runout_steps, dt)


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


def chunk_tail(motion: ChunkMotion, chunk: Chunk, window: Window, remaining_steps: int, shaping: ShapingConfig) -> Tail:
    """The window's tail if no chunk takes over at its end: the chunk's steps beyond the window
    at full speed, then a runout to rest at its last step (``plan_tail``). It stops a step
    short of the run's ``remaining_steps`` after the window, so a late chunk always has a step
    left to take over. None (``NO_TAIL``) when the seam's blend outlasts it (``comes_to_rest``)."""
    spare = min(chunk.steps - 1 - (window.end_step - window.request_step), remaining_steps - 1)
    if spare < 1:
        return NO_TAIL
    beyond = motion.end + shaping.dt * np.arange(spare + 1)
    _, velocity, _ = motion.evaluate(beyond)  # the window's motion carried on along the chunk
    tail = plan_tail(np.abs(velocity).max(axis=0), shaping.max_acceleration, shaping.dt,
                     nominal_runout_s(shaping.committed_action_steps, shaping.dt), spare)
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


@dataclass(frozen=True)
class Ending:
    """How a window's motion ends: followed by ``tail``, or at rest (``NO_TAIL``), and the motion
    that ends so (``ending``)."""

    tail: Tail
    motion: ChunkMotion


def tails_to_try(motion: ChunkMotion, chunk: Chunk, window: Window, remaining_steps: int, shaping: ShapingConfig) -> list[Ending]:
    """The window's endings, in the order the checks try them: its tail (``chunk_tail``; none
    for the run's last window, ``remaining_steps`` 0), then, should the checks refuse it, the
    tail cut short before the failing point (``shorter_tails``), each with the motion that ends
    with it (``ending``). The tail only keeps the arm going while the next chunk is late: where
    the chunk's path beyond its window is unsafe but the window is not, the tail stops short of
    the unsafe point, or the window ends without one. A shorter tail that the seam's blend
    outlasts would not end at rest: left out."""
    tail = NO_TAIL if remaining_steps <= 0 else chunk_tail(motion, chunk, window, remaining_steps, shaping)
    return [Ending(tail, ending(motion, tail))] + [Ending(shorter, ending(motion, shorter)) for shorter in shorter_tails(tail)
                                                  if comes_to_rest(motion, shorter)]


def runout_progress(steps_since_end: int, runout_steps: int) -> int:
    """Chunk steps (rounded) the arm has covered ``steps_since_end`` run steps into a runout
    that covers ``runout_steps`` chunk steps in ``RUNOUT_SLOWDOWN * runout_steps`` run steps."""
    if runout_steps <= 0 or steps_since_end <= 0:
        return 0
    run_steps = RUNOUT_SLOWDOWN * runout_steps
    if steps_since_end >= run_steps:
        return runout_steps
    covered, _, _ = runout_warp(np.array([steps_since_end / run_steps]), float(run_steps), 1.0)
    return int(round(float(covered[0])))


def tail_progress(steps_since_end: int, tail_extension_steps: int, tail_runout_steps: int) -> int:
    """Chunk steps the arm has covered ``steps_since_end`` run steps after a window's end when no
    chunk took over: one a step through the tail's extension, then through its runout."""
    if steps_since_end <= tail_extension_steps:
        return max(0, steps_since_end)
    return tail_extension_steps + runout_progress(steps_since_end - tail_extension_steps, tail_runout_steps)

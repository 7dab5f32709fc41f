"""Where a chunk starts when it finds the arm at rest: the one place of that rule.

The arm rests before the first chunk, and once the sent motion (its runout included) has ended
by the step a chunk arrived (``arrives_at_rest``). Such a chunk's window starts at the first step
at or after its arrival, as both baselines play a chunk into an empty queue (``from_rest_seam``),
provided its goal takes effect strictly before the earliest seam step begins
(``window_arrival_step``); otherwise at the step before the earliest seam. Its goal takes over
within that first step, when it takes effect (``seam.take_over_time``): the arm rests until then, and
the blend from rest catches up the fraction of a step. Where that fraction leaves a short window
too little to pass the checks, the chunk is planned again from the earliest seam (``starts``
lists both, in the order they are tried). A chunk that finds the arm moving joins at the
earliest seam. Pure functions.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .seam import ChunkMotion
    from .stream import StepGrid


@dataclass(frozen=True)
class Arrival:
    """When a chunk came, on the step grid, and the earliest instant a goal sent now takes effect."""

    step: int  # the first step at or after the chunk arrived
    goal_takes_effect_s: float  # now plus one tick and twice the goal delivery time (``timing.goal_takes_effect_s``)


@dataclass(frozen=True)
class Start:
    """Where a chunk's window may start: ``step`` (``StepGrid.plan_window``'s ``start_step``),
    and the arrival of a chunk that finds the arm at rest (None: the arm moves, or the window
    starts at the earliest seam), for ``seam.take_over_time``."""

    step: int
    from_rest: Arrival | None


def starts(previous: ChunkMotion | None, arrival: Arrival | None, grid: StepGrid, earliest_seam_step: int) -> list[Start]:
    """The starts to plan a chunk from, in order, until one is not refused: a chunk that finds
    the arm at rest (``arrives_at_rest``) first at its arrival step (``from_rest_seam``), then,
    should that fraction of a step leave its window too little to pass the checks, at the
    earliest seam; any other chunk at the earliest seam."""
    at_earliest = Start(earliest_seam_step, None)
    if not arrives_at_rest(previous, arrival, grid):
        return [at_earliest]
    assert arrival is not None
    step = from_rest_seam(earliest_seam_step, window_arrival_step(arrival, grid, earliest_seam_step))
    return [Start(step, arrival), at_earliest]


def arrives_at_rest(previous: ChunkMotion | None, arrival: Arrival | None, grid: StepGrid) -> bool:
    """Whether the arm rests when the chunk arrives: before the first chunk, or once the
    sent motion (its runout included) has ended by the arrival step."""
    if arrival is None:
        return False
    return previous is None or previous.rest_time <= grid.time(arrival.step) + 1e-9


def window_arrival_step(arrival: Arrival | None, grid: StepGrid, earliest_seam_step: int) -> int | None:
    """The arrival step the window of a chunk that finds the arm at rest may start at
    (``from_rest_seam``; ``arrival`` None: the arm moves): only while its goal takes
    effect strictly before the earliest seam step begins, so that the goal takes over within the
    window's first step. None: the window starts at the earliest seam."""
    if arrival is None or grid.time(earliest_seam_step) - arrival.goal_takes_effect_s <= 1e-9:
        return None
    return arrival.step


def from_rest_seam(earliest_seam: int, arrival_step: int | None) -> int:
    """The step where a chunk that finds the arm at rest (the first chunk, or one after the
    previous motion ran out) starts its window: the first step at or after the chunk arrived,
    as both baselines play a chunk into an empty queue, unless its goal cannot take effect
    within that step (``earliest_seam`` is later still); then the step before the earliest seam.
    A goal that takes effect within the window's first step (one tick after the arrival, in
    process) starts the motion from rest there (``seam.take_over_time``). ``arrival_step``
    None (the arm is moving): the earliest seam."""
    if arrival_step is None:
        return earliest_seam
    return max(0, arrival_step, earliest_seam - 1)

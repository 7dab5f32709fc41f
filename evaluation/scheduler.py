"""The evaluation loop: seeds to idle workers, records into ``episodes.jsonl`` as they finish.

Each seed is in at most one worker at a time and is written once (``EvalStore.add`` refuses a
seed already there), so an episode retried after a lost worker is never counted twice. A seed
whose worker died is run again on a fresh worker up to ``retries`` times, then recorded as an
ERROR; a hung episode is recorded as an ERROR at once (running it again would hang again). An
episode that ends with a mistake of the setup before its first tick (``static_setup_error``: an
unknown waypoint, a missing topic) stops the loop: every other seed would end the same, so none
is started; the episodes already running finish. A protective stop (``protective_stop``) stops
it too: no seed is started after it, and the running episodes end on it (the executor forwards it).
"""
from __future__ import annotations

import shutil
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable

from runtime.errors import ObjectiveError

from .config import EvalConfig
from .episode import EPISODE_TIMEOUT, WORKER_LOST, EpisodeRecord, EpisodeStatus
from .executors import Event, EventKind, Executor
from .store import EvalStore

Progress = Callable[[EpisodeRecord], None]


@dataclass
class LoopResult:
    finished: int
    """Episodes recorded by this run (not those resumed from the file)."""
    interrupted: bool = False
    stopped_by: EpisodeRecord | None = None
    """The episode whose static setup error stopped the loop (``static_setup_error``)."""
    protective_stop: str | None = None
    """Why the protective stop stopped the loop."""


def static_setup_error(record: EpisodeRecord) -> bool:
    """An ERROR of the setup found before the first tick: it does not depend on the seed."""
    return record.status is EpisodeStatus.ERROR and record.failure_kind == "SetupError" and record.ticks == 0


StopCheck = Callable[[bool], "str | None"]
"""Asked between waits whether the protective stop is engaged (its reason), told whether episodes run."""
STOP_POLL_S = 0.1
"""Wall time between two looks at the protective stop."""


def run_episodes(config: EvalConfig, executor: Executor, store: EvalStore, progress: Progress | None = None,
                 protective_stop: StopCheck | None = None) -> LoopResult:
    """Run every seed of ``config`` not yet in ``store``; ObjectiveError when workers cannot load."""
    pending = deque(seed for seed in config.seeds if seed not in store.records)
    attempts: dict[int, int] = {}
    finished = 0
    stopped_by: EpisodeRecord | None = None
    stopped_why: str | None = None

    def record(item: EpisodeRecord) -> None:
        nonlocal finished, stopped_by
        item.attempts = attempts.get(item.seed, 1)
        if store.add(item):
            finished += 1
            if progress is not None:
                progress(item)
        if stopped_by is None and static_setup_error(item):
            stopped_by = item
            pending.clear()

    try:
        while pending or executor.running():
            if protective_stop is not None and stopped_why is None:
                stopped_why = protective_stop(executor.running() > 0)
                if stopped_why is not None:
                    pending.clear()
            while pending and executor.idle_slots():
                seed = pending.popleft()
                attempts[seed] = attempts.get(seed, 0) + 1
                executor.submit(seed)
            for event in executor.wait(timeout_s=1.0 if protective_stop is None else STOP_POLL_S):
                _handle(event, config, pending, attempts, record)
                if stopped_why is not None:
                    pending.clear()  # a lost worker's seed is not run again
    except KeyboardInterrupt:
        return LoopResult(finished, interrupted=True, stopped_by=stopped_by, protective_stop=stopped_why)
    return LoopResult(finished, stopped_by=stopped_by, protective_stop=stopped_why)


def _handle(event: Event, config: EvalConfig, pending: deque[int], attempts: dict[int, int],
            record: Callable[[EpisodeRecord], None]) -> None:
    if event.kind is EventKind.LOAD_FAILED:
        raise ObjectiveError(f"a worker could not start: {event.reason}")
    if event.seed is None:
        return  # a worker died between episodes: it was replaced, nothing was lost
    if event.kind is EventKind.DONE and event.record is not None:
        record(event.record)
    elif event.kind is EventKind.TIMED_OUT:
        error = EpisodeRecord.error(event.seed, event.reason, event.wall_seconds, worker=event.worker, kind=EPISODE_TIMEOUT)
        record(keep_stranded_recording(config, error))
    elif event.kind is EventKind.LOST:
        if attempts[event.seed] <= config.retries:
            pending.appendleft(event.seed)  # the next attempt starts its recording afresh
        else:
            tries = attempts[event.seed]
            reason = f"{event.reason}; {tries} attempt{'s' if tries > 1 else ''}, each lost its worker"
            error = EpisodeRecord.error(event.seed, reason, event.wall_seconds, worker=event.worker, kind=WORKER_LOST)
            record(keep_stranded_recording(config, error))


STOPPED_MID_EPISODE = ("its worker was stopped mid-episode: the recording ends at its last flush, with no report "
                       "(objective report DIR renders it, marked partial)")


def keep_stranded_recording(config: EvalConfig, error: EpisodeRecord) -> EpisodeRecord:
    """``error`` (of an episode whose worker was stopped or died) with the recording that worker
    left in ``recordings/.partial-seed-N``, kept as ``recordings/seed-N`` and marked partial
    (``recording_incomplete``): every ``--record`` that records keeps ERROR episodes."""
    from .worker import RECORDINGS_DIR, recording_name

    recordings = config.out / RECORDINGS_DIR
    scratch = recordings / f".partial-{recording_name(error.seed)}"
    if not scratch.is_dir():
        return error
    final = recordings / recording_name(error.seed)
    shutil.rmtree(final, ignore_errors=True)
    scratch.rename(final)
    error.recording = f"{RECORDINGS_DIR}/{final.name}"
    error.run["recording_incomplete"] = STOPPED_MID_EPISODE
    return error


def wait_for_workers(executor: Executor, timeout_s: float, clock: Callable[[], float] = time.monotonic) -> None:
    """Block until every worker has loaded (or raise as ``run_episodes`` would): for benchmarks
    that time episodes without the load."""
    deadline = clock() + timeout_s
    while executor.idle_slots() < executor.workers:
        if clock() > deadline:
            raise ObjectiveError(f"workers did not load within {timeout_s:g} s")
        for event in executor.wait(timeout_s=0.5):
            if event.kind is EventKind.LOAD_FAILED:
                raise ObjectiveError(f"a worker could not start: {event.reason}")


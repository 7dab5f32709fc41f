"""Where episodes run: the events an executor reports and the local one (worker processes).

An executor has ``workers`` slots. The scheduler (``evaluation.run``) hands a seed to an idle
slot and waits for events:

- ``DONE``: the episode's record;
- ``TIMED_OUT``: no record within ``episode_timeout_s`` of wall time (a hung episode): the worker
  was stopped and a fresh one takes the slot;
- ``LOST``: the worker died mid-episode (a crash, a lost node): a fresh one takes the slot and the
  scheduler runs the seed again, a bounded number of times;
- ``LOAD_FAILED``: a worker could not load the Objective, world or policy (bad input): the
  evaluation stops with the reason.

The local executor runs each slot as a process (``spawn``: nothing of the parent's state is
shared) that builds an ``EpisodeWorker`` and answers seeds over a pipe. Its stdout, stderr and
logs go to ``DIR/logs/worker-N.log``.
"""
from __future__ import annotations

import enum
import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from runtime.app.protective_stop import SharedStop

from .config import WorkerSpec
from .episode import EpisodeRecord

CONTEXT = multiprocessing.get_context("spawn")
"""How local workers start: nothing of the parent's state is shared but what they are given."""
LOAD_TIMEOUT_S = 900.0
"""Wall-clock bound on a worker's warm-up (imports, world, checkpoint)."""


class EventKind(enum.Enum):
    DONE = "done"
    TIMED_OUT = "timed_out"
    LOST = "lost"
    LOAD_FAILED = "load_failed"


@dataclass
class Event:
    kind: EventKind
    seed: int | None = None
    record: EpisodeRecord | None = None
    reason: str = ""
    wall_seconds: float = 0.0
    worker: str = ""


class Executor(Protocol):
    workers: int

    def idle_slots(self) -> int: ...

    def submit(self, seed: int) -> None: ...

    def running(self) -> int: ...

    def wait(self, timeout_s: float) -> list[Event]: ...

    def close(self) -> None: ...


def hung_event(seed: int | None, timeout_s: float, worker: str) -> Event:
    """The event of an episode that gave no result in time (its worker has been replaced)."""
    return Event(EventKind.TIMED_OUT, seed, reason=(
        f"no result within {timeout_s:g} s of wall time (--episode-timeout): the episode hung; "
        "its worker was stopped and replaced"), wall_seconds=timeout_s, worker=worker)


def load_timeout_event(worker: str) -> Event:
    return Event(EventKind.LOAD_FAILED, reason=f"{worker} did not finish loading within {LOAD_TIMEOUT_S:g} s", worker=worker)


def describe_exit(code: int | None) -> str:
    """``exit code 3`` or ``signal SIGABRT`` for a process's exit status."""
    if code is None:
        return "no exit status"
    if code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"


class SlotState(enum.Enum):
    LOADING = "loading"
    IDLE = "idle"
    RUNNING = "running"


@dataclass
class _Slot:
    index: int
    process: Any
    conn: Any
    state: SlotState = SlotState.LOADING
    since: float = field(default_factory=time.monotonic)
    seed: int | None = None

    @property
    def name(self) -> str:
        return f"worker-{self.index}"


def worker_main(conn: Any, spec: WorkerSpec, name: str, recordings: str | None, log_file: str | None,
                stop: SharedStop | None = None) -> None:
    """A local worker process: warm up, then run each seed sent until told to stop (``stop``: the
    protective stop the evaluation forwards to its episodes)."""
    from runtime.errors import ObjectiveError

    from .worker import EpisodeWorker

    if log_file:
        _log_to(log_file)
    worker = EpisodeWorker(spec, name, Path(recordings) if recordings else None, stop)
    try:
        info = worker.warm_up()
    except ObjectiveError as err:
        conn.send(("load_error", str(err)))
        return
    except Exception as err:  # anything else that stops a load is reported, not printed
        conn.send(("load_error", f"{type(err).__name__}: {err}"))
        return
    conn.send(("ready", info))
    try:
        while True:
            try:
                message = conn.recv()
            except EOFError:
                break
            if message[0] != "run":
                break
            conn.send(("record", worker.run(int(message[1])).to_json()))
    finally:
        worker.close()


def _log_to(path: str) -> None:
    """Send this process's stdout, stderr and the runtime's log records to ``path``."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(asctime)s [%(levelname)s] %(name)s: %(message)s"))
    for name in ("objective", "sim"):
        logger = logging.getLogger(name)
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        logger.propagate = False


class SlotPool:
    """What both executors share: slots in named states, and what a slot past its deadline means.

    Subclasses keep ``slots`` (objects with ``index``, ``name``, ``state``, ``since``, ``seed``) and
    ``episode_timeout_s``, and implement ``_replace(slot)`` (stop its worker, start a fresh one)."""

    slots: list[Any]
    episode_timeout_s: float

    def idle_slots(self) -> int:
        return sum(1 for s in self.slots if s.state is SlotState.IDLE)

    def running(self) -> int:
        return sum(1 for s in self.slots if s.state is SlotState.RUNNING)

    def _take_idle(self, seed: int) -> Any:
        slot = next(s for s in self.slots if s.state is SlotState.IDLE)
        slot.state, slot.seed, slot.since = SlotState.RUNNING, seed, time.monotonic()
        return slot

    def _deadline(self, slot: Any) -> float:
        if slot.state is SlotState.RUNNING:
            running_until: float = slot.since + self.episode_timeout_s
            return running_until
        if slot.state is SlotState.LOADING:
            loading_until: float = slot.since + LOAD_TIMEOUT_S
            return loading_until
        return float("inf")

    def _replace(self, slot: Any) -> None:
        raise NotImplementedError

    def _timed_out(self, slot: Any) -> Event:
        state, seed = slot.state, slot.seed
        self._replace(slot)
        if state is SlotState.LOADING:
            return load_timeout_event(slot.name)
        return hung_event(seed, self.episode_timeout_s, slot.name)


class LocalExecutor(SlotPool):
    """``workers`` local processes, each keeping its loaded world; see the module doc. ``stop``:
    a protective stop (made with ``CONTEXT``) every worker's episodes end on."""

    def __init__(self, spec: WorkerSpec, workers: int, out: Path, episode_timeout_s: float,
                 stop: SharedStop | None = None) -> None:
        self.spec, self.workers, self.out, self.episode_timeout_s = spec, workers, out, episode_timeout_s
        self.stop = stop
        self._context = CONTEXT
        self._started = 0
        (out / "logs").mkdir(parents=True, exist_ok=True)
        self.slots = [self._spawn(i) for i in range(workers)]

    def _spawn(self, index: int) -> _Slot:
        parent, child = self._context.Pipe()
        self._started += 1
        recordings = str(self.out / "recordings") if self.spec.record.value != "none" else None
        process = self._context.Process(
            target=worker_main, name=f"objective-eval-worker-{index}", daemon=True,
            args=(child, self.spec, f"worker-{index}", recordings, str(self.out / "logs" / f"worker-{index}.log"), self.stop),
        )
        process.start()
        child.close()
        return _Slot(index, process, parent)

    def _replace(self, slot: _Slot) -> None:
        self._stop(slot)
        self.slots[slot.index] = self._spawn(slot.index)

    @staticmethod
    def _stop(slot: _Slot) -> None:
        if slot.process.is_alive():
            slot.process.kill()
        slot.process.join(timeout=10)
        slot.conn.close()

    # -- Executor ---
    def submit(self, seed: int) -> None:
        self._take_idle(seed).conn.send(("run", seed))

    def wait(self, timeout_s: float) -> list[Event]:
        """Events of the slots that answered, died or ran out of time, within ``timeout_s``."""
        now = time.monotonic()
        deadline = min([now + timeout_s] + [self._deadline(s) for s in self.slots])
        waitables = [s.conn for s in self.slots] + [s.process.sentinel for s in self.slots]
        ready = multiprocessing.connection.wait(waitables, timeout=max(0.0, deadline - now))
        events: list[Event] = []
        for slot in list(self.slots):
            if slot.conn in ready:
                events.extend(self._receive(slot))
            elif slot.process.sentinel in ready or not slot.process.is_alive():
                events.append(self._died(slot))
            elif time.monotonic() >= self._deadline(slot):
                events.append(self._timed_out(slot))
        return events

    def _receive(self, slot: _Slot) -> list[Event]:
        try:
            kind, payload = slot.conn.recv()
        except (EOFError, OSError):
            return [self._died(slot)]
        if kind == "ready":
            slot.state, slot.since = SlotState.IDLE, time.monotonic()
            return []
        if kind == "load_error":
            self._stop(slot)
            return [Event(EventKind.LOAD_FAILED, reason=str(payload), worker=slot.name)]
        record = EpisodeRecord.from_json(payload)
        slot.state, slot.seed = SlotState.IDLE, None
        return [Event(EventKind.DONE, record.seed, record, worker=slot.name)]

    def _died(self, slot: _Slot) -> Event:
        slot.process.join(timeout=10)
        how = describe_exit(slot.process.exitcode)
        seed, state, elapsed = slot.seed, slot.state, time.monotonic() - slot.since
        self._replace(slot)
        log = f"logs/{slot.name}.log"
        if state is SlotState.LOADING:
            return Event(EventKind.LOAD_FAILED, reason=f"{slot.name} died while loading ({how}; see {log})", worker=slot.name)
        return Event(EventKind.LOST, seed, reason=f"its worker died ({how}; see {log})", wall_seconds=elapsed, worker=slot.name)

    def close(self) -> None:
        for slot in self.slots:
            if slot.process.is_alive() and slot.state is not SlotState.RUNNING:
                try:
                    slot.conn.send(("stop", None))
                except (BrokenPipeError, OSError):
                    pass
        for slot in self.slots:
            if slot.state is not SlotState.RUNNING:  # a running episode is stopped at once (interrupted)
                slot.process.join(timeout=5)
            self._stop(slot)

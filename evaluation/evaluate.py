"""``evaluate``: an evaluation from its config to ``episodes.jsonl``, ``summary.json`` and ``report.html``."""
from __future__ import annotations

import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from runtime.io.interrupt import StopRequest, exit_code_for, held_back, signal_name
from runtime.tree.loader import validate
from runtime.app.protective_stop import SharedStop
from runtime.tree.registry import Registry

from .config import EvalConfig, ExecutorKind, identity
from .executors import Executor, LocalExecutor
from .report import write_report
from .episode import EpisodeRecord
from .scheduler import Progress, run_episodes
from .stats import summarise
from .store import EvalStore


@dataclass
class EvalOutcome:
    directory: Path
    summary: dict[str, Any]
    signum: int | None = None
    """The signal that interrupted the evaluation (None: it ran to its end)."""

    @property
    def interrupted(self) -> bool:
        return self.signum is not None

    @property
    def exit_code(self) -> int:
        """0: every requested episode finished (successes and failures alike); 1: some ended ERROR,
        or the protective stop stopped the evaluation; 130 / 143: interrupted by SIGINT / SIGTERM
        (run the command again to resume)."""
        if self.signum is not None:
            return exit_code_for(self.signum)
        return 1 if self.summary["errors"] or self.summary.get("protective_stop") else 0


def make_executor(config: EvalConfig, protective_stop: SharedStop | None = None) -> Executor:
    """The executor ``config`` names; ``protective_stop`` reaches the episodes of local workers only."""
    if config.executor is ExecutorKind.RAY:
        from .ray_executor import RayExecutor

        return RayExecutor(config.spec, config.workers, config.out, config.episode_timeout_s, config.ray_address)
    return LocalExecutor(config.spec, config.workers, config.out, config.episode_timeout_s, protective_stop)


class StopSource(Protocol):
    """Where the protective stop is heard (``runtime.app.stop_listener.StopListener``)."""

    shared: SharedStop

    def poll(self, running: bool) -> str | None: ...


def evaluate(config: EvalConfig, registry: Registry, progress: Any = None, stop: StopRequest | None = None,
             protective_stop: StopSource | None = None) -> EvalOutcome:
    """Run the episodes of ``config`` not yet in its DIR and summarise all of them.

    ``progress(store_records)`` builds a callable told about every finished episode (the CLI's
    bar). ``stop``: where SIGINT/SIGTERM handlers note the signal that interrupts it (it is
    raised as ``KeyboardInterrupt``); the summary of the episodes so far is written either way
    and names it. Raises ObjectiveError for bad input: options, the Objective (``file:line:
    Node: what``), a DIR made by another Objective or policy or in use by another evaluation, a
    world or policy the workers cannot load. ``protective_stop``: once it is engaged no episode
    starts, the running ones end FAILURE "protective stop" (local workers) and the summary says so.
    """
    config.check()
    spec = config.spec
    trees = validate(spec.objective, registry, spec.tree, spec.search_paths, spec.objectives_dir).trees_or_raise()
    ident = identity(spec, (file for tree in trees for file in tree.files))
    store = EvalStore(config.out, ident)
    resumed = sum(1 for seed in config.seeds if seed in store.records)
    started = time.monotonic()
    signum: int | None = None
    stopped_by: EpisodeRecord | None = None
    stopped_why: str | None = None
    try:
        try:
            if resumed < config.episodes:
                tell: Progress | None = progress([store.records[s] for s in config.seeds if s in store.records]) if progress else None
                executor = make_executor(config, protective_stop.shared if protective_stop is not None else None)
                try:
                    loop = run_episodes(config, executor, store, tell,
                                        protective_stop.poll if protective_stop is not None else None)
                    stopped_by, stopped_why = loop.stopped_by, loop.protective_stop
                    if loop.interrupted:
                        signum = _signal(stop)
                finally:
                    executor.close()
        except KeyboardInterrupt:
            signum = _signal(stop)
        with held_back(stop):  # the summary is written whole, whatever signal arrives meanwhile
            summary = _summarise(config, store, ident, resumed, started, signum)
            if stopped_by is not None:
                summary["stopped"] = {"seed": stopped_by.seed, "reason": stopped_by.reason}
            if stopped_why is not None:
                summary["protective_stop"] = stopped_why
            if stopped_by is not None or stopped_why is not None:
                store.write_summary(summary)
    finally:
        store.close()
    return EvalOutcome(config.out, summary, signum)


def _signal(stop: StopRequest | None) -> int:
    """The signal that interrupted the evaluation (SIGINT when nobody noted one)."""
    return (stop.signum if stop is not None else None) or signal.SIGINT


def _summarise(config: EvalConfig, store: EvalStore, ident: dict[str, Any], resumed: int, started: float,
               signum: int | None) -> dict[str, Any]:
    """Write ``summary.json`` and ``report.html`` of the episodes in ``store``; the summary."""
    spec = config.spec
    records = [store.records[s] for s in config.seeds if s in store.records]
    summary = summarise(records, config.episodes)
    summary.update({
        "interrupted": signal_name(signum) if signum is not None else None,
        "seeds": [config.seed_start, config.seed_start + config.episodes - 1],
        "resumed": resumed,
        "executor": config.executor.value,
        "workers": config.workers,
        "wall_seconds": round(time.monotonic() - started, 3),
        "policy": spec.policy.text,
        "policy_latency": spec.policy_latency,
        "deterministic": spec.policy.deterministic and spec.policy_latency.strip().lower() != "measured",
        "identity": ident,
    })
    store.write_summary(summary)
    write_report(config.out, summary, records, ident)
    return summary

"""``evaluate``: an evaluation from its config to ``episodes.jsonl``, ``summary.json`` and ``report.html``."""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from runtime.loader import validate
from runtime.registry import Registry

from .config import EvalConfig, ExecutorKind, identity
from .executors import Executor, LocalExecutor
from .report import write_report
from .scheduler import Progress, run_episodes
from .stats import summarise
from .store import EvalStore


@dataclass
class EvalOutcome:
    directory: Path
    summary: dict[str, Any]
    interrupted: bool = False

    @property
    def exit_code(self) -> int:
        """0: every requested episode finished (successes and failures alike); 1: some ended ERROR;
        130: interrupted (run the command again to resume)."""
        if self.interrupted:
            return 130
        return 1 if self.summary["errors"] else 0


def make_executor(config: EvalConfig) -> Executor:
    if config.executor is ExecutorKind.RAY:
        from .ray_executor import RayExecutor

        return RayExecutor(config.spec, config.workers, config.out, config.episode_timeout_s, config.ray_address)
    return LocalExecutor(config.spec, config.workers, config.out, config.episode_timeout_s)


def evaluate(config: EvalConfig, registry: Registry, progress: Any = None) -> EvalOutcome:
    """Run the episodes of ``config`` not yet in its DIR and summarise all of them.

    ``progress(store_records)`` builds a callable told about every finished episode (the CLI's
    bar). Raises ObjectiveError for bad input: options, the Objective (``file:line: Node: what``),
    a DIR made by another Objective or policy, a world or policy the workers cannot load.
    """
    config.check()
    spec = config.spec
    validate(spec.objective, registry, spec.tree, spec.search_paths, spec.objectives_dir).trees_or_raise()
    ident = identity(spec)
    store = EvalStore(config.out, ident)
    resumed = sum(1 for seed in config.seeds if seed in store.records)
    started = time.monotonic()
    interrupted = False
    try:
        if resumed < config.episodes:
            tell: Progress | None = progress([store.records[s] for s in config.seeds if s in store.records]) if progress else None
            executor = make_executor(config)
            try:
                interrupted = run_episodes(config, executor, store, tell).interrupted
            finally:
                executor.close()
    except KeyboardInterrupt:
        interrupted = True
    finally:
        store.close()
    records = [store.records[s] for s in config.seeds if s in store.records]
    summary = summarise(records, config.episodes)
    summary.update({
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
    return EvalOutcome(config.out, summary, interrupted)

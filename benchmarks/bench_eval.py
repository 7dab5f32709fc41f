"""Evaluation throughput: episodes per hour of ``objectives/stack_cubes.xml``.

Side by side, in rounds (each round runs every configuration once, so the machine's load
falls on all of them alike; figures are medians over rounds):

- ``shell loop``: one ``objective run --seed i`` process per episode, one after another;
- ``local x1`` / ``local x2``: ``objective eval`` with the local executor and 1 / 2 workers;
- ``ray x2``: ``objective eval --executor ray --workers 2`` on a local Ray instance (skipped
  without ``make ray``).

For the evaluations, ``startup_s`` is the time until every worker has loaded (Ray's own start
included for Ray) and ``episodes_per_hour`` counts the episodes over the whole run, start-up
included; ``steady_per_hour`` leaves the start-up out. ``speedup`` is against ``local x1``
(steady rates), ``efficiency`` is speed-up / workers, and ``ray_overhead_s_per_episode`` is
Ray's steady seconds per episode minus the local executor's with the same workers.

    .venv/bin/python benchmarks/bench_eval.py [--world kinematic|vla_sim] [--episodes N] [--rounds R]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import common  # noqa: F401  (environment and sys.path first)
from common import ROOT, median, report

from evaluation.config import EvalConfig, ExecutorKind, RecordMode, WorkerSpec
from evaluation.evaluate import make_executor
from evaluation.policies import parse_policy
from evaluation.scheduler import run_episodes, wait_for_workers
from evaluation.store import EvalStore
from evaluation.config import identity

OBJECTIVE = ROOT / "objectives" / "stack_cubes.xml"
OBJECTIVE_CLI = ROOT / ".venv" / "bin" / "objective"
LATENCY = "0.1"


def shell_loop(world: str, seeds: range) -> dict[str, Any]:
    start = time.perf_counter()
    statuses = []
    for seed in seeds:
        done = subprocess.run([str(OBJECTIVE_CLI), "run", str(OBJECTIVE), "--seed", str(seed), "--world", world,
                               "--policy-latency", LATENCY], capture_output=True, text=True)
        statuses.append(done.returncode)
    total = time.perf_counter() - start
    return {"total_s": total, "startup_s": 0.0, "run_s": total, "successes": statuses.count(0)}


def evaluation(world: str, seeds: range, workers: int, executor: ExecutorKind) -> dict[str, Any]:
    spec = WorkerSpec(objective=OBJECTIVE, world=world, policy=parse_policy("oracle"), policy_latency=LATENCY,
                      record=RecordMode.NONE)
    with tempfile.TemporaryDirectory(prefix="bench-eval-") as folder:
        config = EvalConfig(spec=spec, out=Path(folder), episodes=len(seeds), seed_start=seeds.start, workers=workers,
                            executor=executor)
        store = EvalStore(config.out, identity(spec, [OBJECTIVE]))  # a fresh DIR: the identity is only stored
        start = time.perf_counter()
        runner = make_executor(config)
        try:
            wait_for_workers(runner, 900.0)
            loaded = time.perf_counter()
            run_episodes(config, runner, store)
            finished = time.perf_counter()
        finally:
            runner.close()
            store.close()
        successes = sum(r.status.value == "SUCCESS" for r in store.records.values())
    return {"total_s": finished - start, "startup_s": loaded - start, "run_s": finished - loaded, "successes": successes}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", default="kinematic")
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    try:
        import ray  # noqa: F401

        have_ray = True
    except ImportError:
        have_ray = False
    configurations: list[tuple[str, int, Any]] = [
        ("shell loop", 1, lambda seeds: shell_loop(args.world, seeds)),
        ("local x1", 1, lambda seeds: evaluation(args.world, seeds, 1, ExecutorKind.LOCAL)),
        ("local x2", 2, lambda seeds: evaluation(args.world, seeds, 2, ExecutorKind.LOCAL)),
    ]
    if have_ray:
        configurations.append(("ray x2", 2, lambda seeds: evaluation(args.world, seeds, 2, ExecutorKind.RAY)))
    samples: dict[str, list[dict[str, Any]]] = {name: [] for name, _, _ in configurations}
    seeds = range(100, 100 + args.episodes)
    for round_index in range(args.rounds):
        for name, _, run in configurations:
            sample = run(seeds)
            samples[name].append(sample)
            print(f"round {round_index + 1} {name}: {sample}", file=sys.stderr, flush=True)
    rows = []
    per_episode = {name: median([s["run_s"] for s in runs]) / args.episodes for name, runs in samples.items()}
    for name, workers, _ in configurations:
        runs = samples[name]
        row = {
            "bench": "eval", "config": name, "world": args.world, "workers": workers, "episodes": args.episodes,
            "rounds": args.rounds, "successes": median([s["successes"] for s in runs]),
            "startup_s": round(median([s["startup_s"] for s in runs]), 2),
            "episodes_per_hour": round(3600 * args.episodes / median([s["total_s"] for s in runs])),
            "steady_per_hour": round(3600 / per_episode[name]),
            "speedup": round(per_episode["local x1"] / per_episode[name], 2),
        }
        row["efficiency"] = round(row["speedup"] / workers, 2)
        if name == "ray x2":
            row["ray_overhead_s_per_episode"] = round(per_episode[name] - per_episode["local x2"], 2)
        rows.append(row)
    report(f"objective eval throughput, {OBJECTIVE.name} on {args.world}", rows,
           ["config", "workers", "startup_s", "episodes_per_hour", "steady_per_hour", "speedup", "efficiency", "successes"],
           notes=[f"{args.episodes} episodes per configuration, medians of {args.rounds} interleaved rounds; "
                  f"{os.cpu_count()} CPUs shared with other work, so absolute figures are noisy"])


if __name__ == "__main__":
    main()

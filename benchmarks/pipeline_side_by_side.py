"""The chunk pipeline of two checkouts in one process, alternating repeat by repeat.

Loads ``BASELINE/benchmarks/bench_pipeline.py`` with the baseline's own modules, then this
checkout's with its own, and runs their ``pipeline`` (one chunk, validate to collision check)
in turn, ``--repeats`` times at ``--points``. Alternating every repeat in one process keeps the
ratio steady where ``side_by_side.py`` (whole runs in turn) drifts with the machine's load. It
prints the median of each stage both checkouts have, this checkout's total without the Cartesian
envelope's stage (the checks a cell without an envelope runs), and the ratios this / baseline.
Both checkouts must import with this Python (this venv).

    git worktree add /tmp/base <commit>
    .venv/bin/python benchmarks/pipeline_side_by_side.py --baseline /tmp/base --points 200 --repeats 300
"""
from __future__ import annotations

import argparse
import importlib
import os
import statistics
import sys
import time
from pathlib import Path
from types import ModuleType
from typing import Any

HERE = Path(__file__).resolve().parents[1]
OWN_MODULES = {"runtime", "behaviors", "sim", "policy", "recording", "evaluation", "tools", "benchmarks",
               "bench_pipeline", "common"}
"""Top-level names a checkout provides: dropped from ``sys.modules`` before the next one loads."""


def load(checkout: Path) -> tuple[ModuleType, tuple[Any, ...]]:
    """``checkout``'s bench_pipeline module and its pipeline's inputs (safety, snapshot, chunk)."""
    for name in list(sys.modules):
        if name.split(".")[0] in OWN_MODULES:
            del sys.modules[name]
    sys.path[:0] = [str(checkout / "benchmarks"), str(checkout)]
    os.chdir(checkout)
    try:
        bench = importlib.import_module("bench_pipeline")
        _, safety, msg = bench.make_inputs()
    finally:
        del sys.path[:2]
    return bench, (safety, safety.snapshot(), msg)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="the other checkout (a git worktree)")
    parser.add_argument("--points", type=int, default=200, help="num_interpolation_points")
    parser.add_argument("--repeats", type=int, default=300)
    options = parser.parse_args()
    if not (options.baseline / "benchmarks" / "bench_pipeline.py").is_file():
        raise SystemExit(f"pipeline_side_by_side: {options.baseline / 'benchmarks' / 'bench_pipeline.py'} does not exist")
    checkouts = {"baseline": load(options.baseline.resolve()), "this": load(HERE)}
    times: dict[str, dict[str, list[float]]] = {name: {} for name in checkouts}
    for bench, (safety, snapshot, msg) in checkouts.values():
        for _ in range(20):
            bench.pipeline(safety, snapshot, msg, options.points)  # warm caches
    for _ in range(options.repeats):
        for name, (bench, (safety, snapshot, msg)) in checkouts.items():
            start = time.perf_counter()
            stages = bench.pipeline(safety, snapshot, msg, options.points, time.perf_counter)
            total_s = time.perf_counter() - start
            stages.update(total=total_s, total_without_envelope=total_s - stages.get("envelope", 0.0))
            for stage, seconds in stages.items():
                times[name].setdefault(stage, []).append(seconds * 1000.0)
    print(f"# pipeline_side_by_side: {options.points} points, {options.repeats} repeats alternating in one process; "
          f"medians in ms\n# baseline: {options.baseline.resolve()}  this: {HERE}")
    base = {stage: statistics.median(values) for stage, values in times["baseline"].items()}
    for stage, values in times["this"].items():
        this = statistics.median(values)
        if stage in base:
            print(f"{stage:24s} baseline {base[stage]:7.3f}  this {this:7.3f}  this/baseline {this / base[stage]:6.3f}")
        else:
            print(f"{stage:24s} baseline       -  this {this:7.3f}")


if __name__ == "__main__":
    main()

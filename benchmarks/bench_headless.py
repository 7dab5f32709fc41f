"""Headless speed: the cube-stacking Objective end to end, as sim seconds per wall second.

``objectives/stack_cubes.xml`` (prepare the cell, ExecutePolicy with the embedded oracle policy
and three 224x224 cameras, then the cube-on-cube check), run in this process exactly as
``objective run`` runs it, on the MuJoCo world ``vla_sim`` (physics, three rendered 224x224 cameras) when it is installed,
and on the ``kinematic`` world (no physics; camera frames are flat images) for comparison: one
row per world, saying which (``"world"``). The runner's wall time covers world
start-up, ticks, physics, rendering, policy and checks; it excludes loading the XML.

The target is stated for one core, so by default the process pins itself to one CPU and asks
Mesa's software rasteriser for one thread (``LP_NUM_THREADS=1``) before anything renders;
``--all-cores`` measures without either.

    .venv/bin/python benchmarks/bench_headless.py [--runs N] [--world NAME] [--all-cores]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from importlib.metadata import entry_points
from typing import Any

ALL_CORES = "--all-cores" in sys.argv
if not ALL_CORES:  # before mujoco or Mesa start any thread
    os.environ.setdefault("LP_NUM_THREADS", "1")
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

import common  # noqa: E402,F401  (environment and sys.path first)
from common import ROOT, report, rounded  # noqa: E402

from runtime.registry import WORLD_GROUP, Registry  # noqa: E402
from runtime.runner import RunOptions, run_file  # noqa: E402

OBJECTIVE = ROOT / "objectives" / "stack_cubes.xml"
IMAGE_SIZE = 224


def run_once(registry: Registry, world: str, seed: int) -> dict[str, Any]:
    options = RunOptions(seed=seed, world=world, max_seconds=120.0, world_options={"image_size": IMAGE_SIZE})
    start = time.perf_counter()
    result = run_file(OBJECTIVE, registry, options)
    total = time.perf_counter() - start
    stack = result.extra.get("stack_check") or {}
    return {
        "status": result.status,
        "reason": result.reason,
        "sim_seconds": result.sim_seconds,
        "wall_seconds": result.wall_seconds,
        "total_wall_seconds": total,
        "stacked": bool(stack.get("stacked")),
    }


def measure(registry: Registry, world: str, runs: int) -> dict[str, Any]:
    """One row: ``runs`` seeded runs of the Objective on ``world``, medians."""
    results = [run_once(registry, world, seed) for seed in range(runs)]
    ratios = [r["sim_seconds"] / r["wall_seconds"] for r in results]
    row: dict[str, Any] = {
        "bench": "headless",
        "world": world,
        "objective": OBJECTIVE.name,
        "image_size": IMAGE_SIZE,
        "cores": len(os.sched_getaffinity(0)),
        "runs": runs,
        "successes": sum(r["status"] == "SUCCESS" for r in results),
        "sim_per_wall": rounded(statistics.median(ratios), 3),
        "sim_seconds": rounded(statistics.median(r["sim_seconds"] for r in results), 3),
        "wall_seconds": rounded(statistics.median(r["wall_seconds"] for r in results), 3),
    }
    failures = sorted({r["reason"] for r in results if r["status"] != "SUCCESS"})
    if failures:
        row["failures"] = failures
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="seeded runs (seeds 0..N-1) per world; rows quote medians")
    parser.add_argument("--world", action="append", help="measure this world (repeatable; default: vla_sim if installed, and kinematic)")
    parser.add_argument("--all-cores", action="store_true", help="do not pin the process to one core")
    args = parser.parse_args()
    registry = Registry.from_entry_points()
    installed = {ep.name for ep in entry_points(group=WORLD_GROUP)}
    worlds = args.world or [w for w in ("vla_sim", "kinematic") if w in installed]
    cores = len(os.sched_getaffinity(0))
    rows, notes = [], ["target: sim_per_wall >= 10 (ten times real time) on one core",
                       f"seeds 0..{args.runs - 1} per world; medians; {cores} core(s) for this process"]
    if "vla_sim" not in installed:
        notes.append("vla_sim is not installed (no 'vla_sim' entry point in objective.worlds): kinematic only")
    for world in worlds:
        try:
            rows.append(measure(registry, world, args.runs))
        except Exception as err:  # a world that cannot run the Objective is reported, not hidden
            rows.append({"bench": "headless", "world": world, "objective": OBJECTIVE.name, "sim_per_wall": None,
                         "error": f"{type(err).__name__}: {err}"})
    report("bench_headless: stack_cubes.xml end to end", rows, ["world", "cores", "runs", "successes", "sim_seconds", "wall_seconds", "sim_per_wall"], notes)


if __name__ == "__main__":
    main()

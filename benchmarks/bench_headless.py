"""Headless speed: the cube-stacking Objective end to end, as sim seconds per wall second.

``objectives/stack_cubes.xml`` (prepare the cell, ExecutePolicy with the embedded oracle policy
and three 224x224 cameras, then the cube-on-cube check), run in this process exactly as
``objective run`` runs it, on the MuJoCo world ``vla_sim`` when it is installed and starts, else
on the ``kinematic`` world (no physics; camera frames are flat images). The row says which world
ran (``"world"``) and, if ``vla_sim`` was skipped, why. The runner's wall time covers world
start-up, ticks, physics, rendering, policy and checks; it excludes loading the XML.

    .venv/bin/python benchmarks/bench_headless.py [--runs N] [--world NAME]
"""
from __future__ import annotations

import argparse
import statistics
import time
from importlib.metadata import entry_points
from typing import Any

import common  # noqa: F401  (environment and sys.path first)
from common import ROOT, report, rounded

from runtime.errors import ObjectiveError
from runtime.registry import WORLD_GROUP, Registry
from runtime.runner import RunOptions, run_file

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


def pick_world(registry: Registry, wanted: str | None) -> tuple[str, str]:
    """The world to measure and, when ``vla_sim`` is not it, why."""
    if wanted:
        return wanted, ""
    names = {ep.name for ep in entry_points(group=WORLD_GROUP)}
    if "vla_sim" not in names:
        return "kinematic", "vla_sim is not installed (no 'vla_sim' entry point in objective.worlds)"
    try:
        probe = run_once(registry, "vla_sim", 0)
    except (ObjectiveError, Exception) as err:  # a world still being written may fail anywhere
        return "kinematic", f"vla_sim did not run: {type(err).__name__}: {err}"
    if probe["status"] != "SUCCESS":
        return "vla_sim", ""  # it runs: measure it, the rows say whether the stack succeeded
    return "vla_sim", ""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="seeded runs (seeds 0..N-1); the row quotes medians")
    parser.add_argument("--world", help="measure this world instead of vla_sim-if-available")
    args = parser.parse_args()
    registry = Registry.from_entry_points()
    world, why = pick_world(registry, args.world)
    runs = []
    for seed in range(args.runs):
        try:
            runs.append(run_once(registry, world, seed))
        except ObjectiveError as err:
            raise SystemExit(f"bench_headless: world '{world}' cannot run {OBJECTIVE.name}: {err}") from None
    ratios = [r["sim_seconds"] / r["wall_seconds"] for r in runs]
    row: dict[str, Any] = {
        "bench": "headless",
        "world": world,
        "objective": OBJECTIVE.name,
        "image_size": IMAGE_SIZE,
        "runs": len(runs),
        "successes": sum(r["status"] == "SUCCESS" for r in runs),
        "sim_per_wall": rounded(statistics.median(ratios), 3),
        "sim_seconds": rounded(statistics.median(r["sim_seconds"] for r in runs), 3),
        "wall_seconds": rounded(statistics.median(r["wall_seconds"] for r in runs), 3),
    }
    if why:
        row["vla_sim"] = why
    failures = sorted({r["reason"] for r in runs if r["status"] != "SUCCESS"})
    if failures:
        row["failures"] = failures
    notes = ["target: sim_per_wall >= 10 (ten times real time) on one core", f"seeds 0..{args.runs - 1}; medians"]
    if why:
        notes.append(f"measured on 'kinematic' because {why}")
    report("bench_headless: stack_cubes.xml end to end", [row], ["world", "runs", "successes", "sim_seconds", "wall_seconds", "sim_per_wall"], notes)


if __name__ == "__main__":
    main()

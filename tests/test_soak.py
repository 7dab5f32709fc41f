"""Soak: 50 consecutive seeded headless episodes of the cube-stacking Objective in one process,
without growth in memory or file descriptors. Slow (a few minutes).

Runs on ``kinematic`` (``SOAK_WORLD=vla_sim`` soaks the MuJoCo world instead, when installed:
about 3 s per episode); prints which, and the success count. Memory is watched three ways after a garbage collection at the end of every
episode: resident set size, live Python objects (``gc.get_objects``), and open file descriptors.
The first five episodes warm caches (scene checkers, renderers, imports) and are not judged.
"""
from __future__ import annotations

import gc
import json
import os
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from runtime.tree.registry import WORLD_GROUP, Registry
from runtime.app.runner import RunOptions, run_file

ROOT = Path(__file__).resolve().parent.parent
OBJECTIVE = ROOT / "objectives" / "stack_cubes.xml"
EPISODES, WARMUP = 50, 5


def rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def soak_world() -> str:
    wanted = os.environ.get("SOAK_WORLD", "kinematic")
    if wanted not in {ep.name for ep in entry_points(group=WORLD_GROUP)}:
        pytest.skip(f"SOAK_WORLD={wanted} is not an installed world")
    return wanted


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_fifty_seeded_episodes_without_growth(record_property):
    registry = Registry.from_entry_points()
    world = soak_world()
    samples, statuses, reasons = [], [], []
    for seed in range(EPISODES):
        result = run_file(OBJECTIVE, registry, RunOptions(seed=seed, world=world, max_seconds=120.0))
        statuses.append(result.status)
        if result.status != "SUCCESS":
            reasons.append(f"seed {seed}: {result.failing_node}: {result.reason}")
        del result
        gc.collect()
        samples.append((rss_bytes(), len(gc.get_objects()), open_fds()))
    successes = statuses.count("SUCCESS")
    (rss0, objects0, fds0), (rss1, objects1, fds1) = samples[WARMUP - 1], samples[-1]
    report = {
        "world": world, "episodes": EPISODES, "successes": successes,
        "rss_growth_mb": round((rss1 - rss0) / 1e6, 2), "object_growth": objects1 - objects0,
        "fds": [fds0, fds1], "failures": reasons,
    }
    print("soak:", json.dumps(report))
    record_property("soak", json.dumps(report))
    assert fds1 <= fds0, f"file descriptors grew from {fds0} to {fds1} over {EPISODES - WARMUP} episodes"
    # A leak of one scene, world or tree per episode would be thousands of objects and megabytes each.
    assert objects1 - objects0 < 2000, f"live Python objects grew by {objects1 - objects0}"
    assert rss1 - rss0 < 40e6, f"resident memory grew by {(rss1 - rss0) / 1e6:.1f} MB"
    assert successes == EPISODES, f"{successes}/{EPISODES} episodes succeeded: {reasons}"

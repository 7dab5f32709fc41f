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

Each row gives wall and CPU seconds (``time.process_time``: on a loaded machine the CPU time
is the steadier figure). ``--profile`` then runs seed 0 of each world once more under cProfile
and prints where its time went (physics, controllers, rendering, the tree, the world's per-tick
upkeep, the rest). cProfile slows the Python parts far more than physics and rendering: read the
parts against each other, not as the unprofiled seconds.

    .venv/bin/python benchmarks/bench_headless.py [--runs N] [--world NAME] [--all-cores] [--profile]
"""
from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import statistics
import sys
import time
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any

ALL_CORES = "--all-cores" in sys.argv
if not ALL_CORES:  # before mujoco or Mesa start any thread
    os.environ.setdefault("LP_NUM_THREADS", "1")
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

import common  # noqa: E402,F401  (environment and sys.path first)
from common import ROOT, report, rounded  # noqa: E402

import numpy as np  # noqa: E402

from runtime.tree.registry import WORLD_GROUP, Registry  # noqa: E402
from runtime.app.runner import RunOptions, run_file  # noqa: E402

OBJECTIVE = ROOT / "objectives" / "stack_cubes.xml"
IMAGE_SIZE = 224


def run_once(registry: Registry, world: str, seed: int) -> dict[str, Any]:
    options = RunOptions(seed=seed, world=world, max_seconds=120.0, world_options={"image_size": IMAGE_SIZE})
    start, start_cpu = time.perf_counter(), time.process_time()
    result = run_file(OBJECTIVE, registry, options)
    total, cpu = time.perf_counter() - start, time.process_time() - start_cpu
    stack = result.extra.get("stack_check") or {}
    return {
        "status": result.status,
        "reason": result.reason,
        "sim_seconds": result.sim_seconds,
        "wall_seconds": result.wall_seconds,
        "total_wall_seconds": total,
        "cpu_seconds": cpu,
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
        "cpu_seconds": rounded(statistics.median(r["cpu_seconds"] for r in results), 3),
        "sim_per_cpu": rounded(statistics.median(r["sim_seconds"] / r["cpu_seconds"] for r in results), 3),
    }
    failures = sorted({r["reason"] for r in results if r["status"] != "SUCCESS"})
    if failures:
        row["failures"] = failures
    return row


PROFILE_PARTS = {
    # part: (file suffix, function name) whose cumulative time it is
    "physics": ("<built-in method mujoco._functions.mj_step>", ""),
    "cell_step": ("sim/mujoco_cell.py", "step"),
    "control_loop": ("sim/controllers/manager.py", "advance"),
    "render": ("sim/mujoco_cell.py", "render"),
    "tree": ("runtime/tree/controls.py", "tick_tree"),
    "world_step": ("sim/world.py", "step_to"),
    "run": ("runtime/app/runner.py", "run_file"),
}


def cumulative_seconds(stats: dict, file_suffix: str, function: str) -> float:
    """Cumulative seconds of the profiled functions matching ``file_suffix`` and ``function``
    (a built-in's whole name as ``file_suffix``, ``function`` empty)."""
    total = 0.0
    for (file, _line, name), (_cc, _nc, _tt, ct, _callers) in stats.items():
        if (not function and name == file_suffix) or (function and name == function and file.endswith(file_suffix)):
            total += ct
    return total


def breakdown(stats: dict) -> dict[str, float]:
    """Profiled seconds of one run by part. Camera frames render inside the tree's tick (read
    lazily), so they are taken out of the tree's share; the controllers are the control loop
    (``ControllerManager.advance``) without the physics steps it calls; the world's upkeep is its
    per-tick work besides the control loop (joint states, planning-scene cubes)."""
    part = {name: cumulative_seconds(stats, *where) for name, where in PROFILE_PARTS.items()}
    return {
        "physics": part["physics"],
        "controllers": part["control_loop"] - part["cell_step"],
        "render": part["render"],
        "tree": part["tree"] - part["render"],
        "world_upkeep": part["world_step"] - part["control_loop"],
        "other": part["run"] - part["world_step"] - part["tree"],
        "total": part["run"],
    }


def profile(registry: Registry, world: str) -> dict[str, Any]:
    profiler = cProfile.Profile()
    profiler.enable()
    result = run_once(registry, world, 0)
    profiler.disable()
    parts = breakdown(pstats.Stats(profiler).stats)  # type: ignore[attr-defined]
    row: dict[str, Any] = {"bench": "headless_profile", "world": world, "status": result["status"]}
    row.update({f"{name}_s": rounded(seconds, 3) for name, seconds in parts.items()})
    return row


@dataclass
class RecordedPhysics:
    """What a run asked of MuJoCo: the model, the state before its first step, the controls of
    every step, and the camera frames rendered before each step (by step index)."""

    model: Any = None
    data: Any = None
    state: np.ndarray | None = None
    controls: list[np.ndarray] = field(default_factory=list)
    frames: dict[int, list[str]] = field(default_factory=dict)


def record_physics(registry: Registry, seed: int) -> RecordedPhysics:
    """Seed ``seed`` of the Objective on vla_sim, with MuJoCo's step and the renderer's scene
    update wrapped to record what the cell asked of them."""
    import mujoco

    recorded, state_spec = RecordedPhysics(), mujoco.mjtState.mjSTATE_INTEGRATION
    step, update_scene = mujoco.mj_step, mujoco.Renderer.update_scene

    def recording_step(model: Any, data: Any) -> None:
        if recorded.data is None:
            recorded.model, recorded.data = model, data
            recorded.state = np.empty(mujoco.mj_stateSize(model, state_spec))
            mujoco.mj_getState(model, data, recorded.state, state_spec)
        if data is recorded.data:
            recorded.controls.append(data.ctrl.copy())
        step(model, data)

    def recording_update_scene(renderer: Any, data: Any, camera: Any = -1, *args: Any, **kwargs: Any) -> None:
        recorded.frames.setdefault(len(recorded.controls), []).append(camera)
        update_scene(renderer, data, camera, *args, **kwargs)

    mujoco.mj_step, mujoco.Renderer.update_scene = recording_step, recording_update_scene
    try:
        result = run_once(registry, "vla_sim", seed)
    finally:
        mujoco.mj_step, mujoco.Renderer.update_scene = step, update_scene
    if result["status"] != "SUCCESS":
        raise RuntimeError(f"the recorded run ended {result['status']}: {result['reason']}")
    return recorded


def replay_seconds(recorded: RecordedPhysics, render: bool) -> float:
    """Wall seconds to replay the recorded steps back to back (and, with ``render``, the frames)."""
    import mujoco

    model, data = recorded.model, mujoco.MjData(recorded.model)
    mujoco.mj_setState(model, data, recorded.state, mujoco.mjtState.mjSTATE_INTEGRATION)
    mujoco.mj_forward(model, data)
    renderer = mujoco.Renderer(model, IMAGE_SIZE, IMAGE_SIZE) if render else None
    start = time.perf_counter()
    for k, ctrl in enumerate(recorded.controls):
        if renderer is not None:
            for camera in recorded.frames.get(k, ()):
                renderer.update_scene(data, camera=camera)
                renderer.render()
        data.ctrl[:] = ctrl
        mujoco.mj_step(model, data)
    seconds = time.perf_counter() - start
    if renderer is not None:
        renderer.close()
    return seconds


def floor(registry: Registry, repeats: int) -> dict[str, Any]:
    """What no control loop can beat: seed 0's MuJoCo steps (same controls) replayed in a tight
    loop, alone and with the run's camera frames, against the time 40x real time allows."""
    recorded = record_physics(registry, 0)
    sim_seconds = len(recorded.controls) * recorded.model.opt.timestep
    physics, with_frames = [], []
    for _ in range(repeats):  # alternating, so that both see the same machine
        physics.append(replay_seconds(recorded, render=False))
        with_frames.append(replay_seconds(recorded, render=True))
    physics_s, with_frames_s = statistics.median(physics), statistics.median(with_frames)
    return {
        "bench": "headless_floor",
        "world": "vla_sim",
        "steps": len(recorded.controls),
        "frames": sum(len(cameras) for cameras in recorded.frames.values()),
        "sim_seconds": rounded(sim_seconds, 3),
        "physics_s": rounded(physics_s, 3),
        "physics_per_wall": rounded(sim_seconds / physics_s, 3),
        "physics_frames_s": rounded(with_frames_s, 3),
        "physics_frames_per_wall": rounded(sim_seconds / with_frames_s, 3),
        "left_at_40x_s": rounded(sim_seconds / 40.0 - with_frames_s, 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="seeded runs (seeds 0..N-1) per world; rows quote medians")
    parser.add_argument("--world", action="append", help="measure this world (repeatable; default: vla_sim if installed, and kinematic)")
    parser.add_argument("--all-cores", action="store_true", help="do not pin the process to one core")
    parser.add_argument("--profile", action="store_true", help="then profile seed 0 of each world: seconds by part")
    parser.add_argument("--floor", action="store_true",
                        help="then replay seed 0's MuJoCo steps and frames (vla_sim) back to back: physics and rendering alone")
    args = parser.parse_args()
    registry = Registry.from_entry_points()
    installed = {ep.name for ep in entry_points(group=WORLD_GROUP)}
    worlds = args.world or [w for w in ("vla_sim", "kinematic") if w in installed]
    cores = len(os.sched_getaffinity(0))
    rows, notes = [], ["target: sim_per_wall >= 40 on one core",
                       f"seeds 0..{args.runs - 1} per world; medians; {cores} core(s) for this process"]
    if "vla_sim" not in installed:
        notes.append("vla_sim is not installed (no 'vla_sim' entry point in objective.worlds): kinematic only")
    for world in worlds:
        try:
            rows.append(measure(registry, world, args.runs))
        except Exception as err:  # a world that cannot run the Objective is reported, not hidden
            rows.append({"bench": "headless", "world": world, "objective": OBJECTIVE.name, "sim_per_wall": None,
                         "error": f"{type(err).__name__}: {err}"})
    report("bench_headless: stack_cubes.xml end to end", rows,
           ["world", "cores", "runs", "successes", "sim_seconds", "wall_seconds", "sim_per_wall", "cpu_seconds", "sim_per_cpu"], notes)
    if args.profile:
        profiles = [profile(registry, world) for world in worlds if not any(r["world"] == world and "error" in r for r in rows)]
        report("bench_headless --profile: seed 0 under cProfile, seconds by part", profiles,
               ["world", "physics_s", "controllers_s", "render_s", "tree_s", "world_upkeep_s", "other_s", "total_s"])
    if args.floor and "vla_sim" in installed:
        report("bench_headless --floor: seed 0's physics steps and frames replayed back to back (median of 5)", [floor(registry, 5)],
               ["world", "steps", "frames", "sim_seconds", "physics_s", "physics_per_wall", "physics_frames_s", "physics_frames_per_wall", "left_at_40x_s"],
               ["left_at_40x_s: what 40x real time leaves for everything else (the tree, controllers, policy, checks)"])


if __name__ == "__main__":
    main()

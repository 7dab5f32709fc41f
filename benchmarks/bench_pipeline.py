"""Chunk pipeline cost: everything ExecutePolicy does to one chunk before the controller sees it.

validate (``read_chunk`` of a 50-step GetActionChunk chunk with the gripper column) + smooth
(``fit_chunk``) + blend (``join_at_seam``, and the window's tail: the chunk's steps beyond the
window, then a runout) + densify (the tail adds one sample per 10 ms after the window) + limit checks (position, velocity,
acceleration of every densified point) + the Cartesian envelope (keep-in boxes, tool cone and TCP speeds of
every densified point) + self and world collision checks (``make_safety`` over
the real cell planning scene, ``sim.planning.make_cell_scene``: UR5e + 2F-85, table, three cubes,
padding 0.01 m), at ``num_interpolation_points`` 100, 200 and 400, as a fraction of the committed
window ``committed_action_steps * dt`` = 20 * 0.1 s = 2 s. The chunk is collision-free, so every
point is checked (the worst case; a colliding chunk stops at its first hit).

Two rows per point count, alternating repeat by repeat so both see the same machine load:
``early_out`` (what ExecutePolicy runs: ``check_path`` settles proven-free runs of points with one
check, ``runtime/motion/scene/swept.py``) and ``per_point`` (every point checked on its own, the same
answers); ``speedup`` is per_point's median over early_out's, for the whole pipeline and for the
collision stage. ``p50_without_envelope_ms`` is the median of each repeat's total less its
envelope stage: the pipeline of a cell without a Cartesian envelope.

    .venv/bin/python benchmarks/bench_pipeline.py [--repeats N]
"""
from __future__ import annotations

import argparse
import time
from typing import Any, Callable

import common  # noqa: F401  (environment and sys.path first)
from common import percentile, report, rounded

import numpy as np
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from behaviors.execute_policy.chunk import read_chunk
from behaviors.execute_policy.checks import densify
from behaviors.execute_policy.seam import join_at_seam
from behaviors.execute_policy.step_spline import fit_chunk
from behaviors.execute_policy.tail import plan_tail
from behaviors.safety import make_safety
from benchmarks.baselines import TaskPolicy, benchmark_task
from sim.layouts import layout
from sim.planning import CUBE_SIZE, make_cell_scene
from sim.robot_model import ARM_JOINTS, GRIPPER_DRIVER_JOINT, load_waypoints

DT, COMMITTED, CHUNK_STEPS, WEIGHT, PADDING = 0.1, 20, 50, 300.0, 0.01
WINDOW_MS = COMMITTED * DT * 1000.0
STAGES = ("validate", "smooth", "blend", "densify", "limits", "envelope", "collision")


def make_inputs() -> tuple[Any, Any, Any]:
    """The cell scene, its safety adapter for ``manipulator`` + gripper, and a chunk message."""
    cubes = {c: (np.array([x, y, CUBE_SIZE / 2]), np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])) for c, (x, y, yaw) in layout(0).items()}
    scene = make_cell_scene(cubes)
    safety = make_safety(scene, "manipulator", GRIPPER_DRIVER_JOINT)
    waypoints = load_waypoints()
    start = np.array([waypoints["Ready"][j] for j in ARM_JOINTS])
    rows = TaskPolicy(benchmark_task(start), DT, CHUNK_STEPS, seed=1).chunk(0, start)
    names = list(ARM_JOINTS) + [GRIPPER_DRIVER_JOINT]
    msg = JointTrajectory(
        joint_names=names,
        points=[JointTrajectoryPoint(positions=[float(v) for v in r] + [0.0]) for r in rows],
    )
    return scene, safety, msg


def per_point_collision(safety: Any, snapshot: Any, samples: Any) -> str | None:
    """``safety.first_collision`` with every point checked on its own (no early-out)."""
    rows = np.hstack([samples.positions, np.zeros((len(samples), 1))])
    hit = safety.scene.check_path(rows, samples.times, PADDING, snapshot=snapshot, layout=safety.layout, early_out=False)
    return None if hit is None else str(hit)


def pipeline(safety: Any, snapshot: Any, msg: Any, points: int, clock: Callable[[], float] | None = None,
             early_out: bool = True) -> dict[str, float]:
    """One chunk through every stage; with ``clock``, the seconds each stage took."""
    marks = [clock()] if clock else []

    def mark() -> None:
        if clock:
            marks.append(clock())

    chunk = read_chunk(msg, safety.group_joints, GRIPPER_DRIVER_JOINT)
    mark()
    spline = fit_chunk(chunk.arm, WEIGHT)
    mark()
    seam, end = 0.3, 0.3 + COMMITTED * DT  # a frozen prefix of 3 steps, then the committed window
    p0 = spline(3.0) + 0.002  # the committed motion's state at the seam, slightly off the chunk
    v0 = spline(3.0, nu=1) / DT
    motion = join_at_seam(spline, DT, 0.0, seam, end, p0, v0, nominal_s=0.5 * COMMITTED * DT)
    spare = CHUNK_STEPS - 1 - (3 + COMMITTED)  # the window's tail, as the planner makes it
    _, beyond_v, _ = motion.evaluate(end + DT * np.arange(spare + 1))
    motion = motion.with_tail(plan_tail(np.abs(beyond_v).max(axis=0), safety.limits.max_acceleration, DT, 0.25 * COMMITTED * DT, spare))
    mark()
    samples = densify(motion, points)
    mark()
    violation = safety.limits.check(samples.positions, samples.velocities, samples.accelerations, samples.times)
    mark()
    violation = violation or safety.first_envelope_violation(samples)  # together: safety.first_limit_violation
    mark()
    if early_out:
        collision = safety.first_collision(snapshot, samples, PADDING, 0.0)
    else:
        collision = per_point_collision(safety, snapshot, samples)
    mark()
    if violation is not None or collision is not None:
        raise SystemExit(f"the benchmark chunk must pass every check, got: {violation or collision}")
    return {name: marks[i + 1] - marks[i] for i, name in enumerate(STAGES)} if clock else {}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=300)
    args = parser.parse_args()
    scene, safety, msg = make_inputs()
    snapshot = safety.snapshot()
    rows = []
    methods = {"early_out": True, "per_point": False}
    for points in (100, 200, 400):
        totals: dict[str, list[float]] = {m: [] for m in methods}
        without_envelope: dict[str, list[float]] = {m: [] for m in methods}
        stages: dict[str, dict[str, list[float]]] = {m: {s: [] for s in STAGES} for m in methods}
        for method, early_out in methods.items():
            for _ in range(5):
                pipeline(safety, snapshot, msg, points, early_out=early_out)  # warm caches (collision checkers, the smoothing map)
        for _ in range(args.repeats):
            for method, early_out in methods.items():
                start = time.perf_counter()
                split = pipeline(safety, snapshot, msg, points, time.perf_counter, early_out)
                totals[method].append((time.perf_counter() - start) * 1000.0)
                without_envelope[method].append(totals[method][-1] - split["envelope"] * 1000.0)
                for name, seconds in split.items():
                    stages[method][name].append(seconds * 1000.0)
        for method in methods:
            p50 = percentile(totals[method], 50)
            row = {
                "bench": "pipeline",
                "points": points,
                "collision_method": method,
                "p50_ms": rounded(p50, 3),
                "p95_ms": rounded(percentile(totals[method], 95), 3),
                "p50_without_envelope_ms": rounded(percentile(without_envelope[method], 50), 3),
                "window_fraction": rounded(p50 / WINDOW_MS, 5),
                "repeats": args.repeats,
            }
            row.update({f"{name}_ms": rounded(percentile(values, 50), 3) for name, values in stages[method].items()})
            rows.append(row)
        fast, slow = rows[-2], rows[-1]
        for row in (fast, slow):
            row["speedup"] = rounded(slow["p50_ms"] / row["p50_ms"], 2)
            row["collision_speedup"] = rounded(slow["collision_ms"] / row["collision_ms"], 2)
    columns = ["points", "collision_method", "p50_ms", "p95_ms", "p50_without_envelope_ms", "window_fraction", *(f"{s}_ms" for s in STAGES),
               "speedup", "collision_speedup"]
    notes = [
        f"one 50-step chunk (6 arm joints + gripper), committed window {COMMITTED} x {DT} s = {WINDOW_MS:g} ms; "
        f"{args.repeats} repeats per method, alternating; medians (stage columns are each stage's own median)",
        "early_out: check_path's proven early-out (ExecutePolicy's); per_point: every point checked on its own",
        "target: window_fraction < 0.01 at 200 points (< 20 ms), and <= 1.5 ms p50 at 200 points",
    ]
    report("bench_pipeline: one chunk, validate to collision check", rows, columns, notes)


if __name__ == "__main__":
    main()

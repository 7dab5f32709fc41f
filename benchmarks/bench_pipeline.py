"""Chunk pipeline cost: everything ExecutePolicy does to one chunk before the controller sees it.

validate (``read_chunk`` of a 50-step GetActionChunk chunk with the gripper column) + smooth
(``fit_chunk``) + blend (``join_at_seam``, and the window's runout) + densify (the runout adds one
sample per 10 ms after the window) + limit checks (position, velocity,
acceleration of every densified point) + self and world collision checks (``make_safety`` over
the real cell planning scene, ``sim.planning.make_cell_scene``: UR5e + 2F-85, table, three cubes,
padding 0.01 m), at ``num_interpolation_points`` 100, 200 and 400, as a fraction of the committed
window ``committed_action_steps * dt`` = 20 * 0.1 s = 2 s. The chunk is collision-free, so every
point is checked (the worst case; a colliding chunk stops at its first hit).

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
from behaviors.execute_policy.shaping import densify, fit_chunk, join_at_seam, runout_duration
from behaviors.safety import make_safety
from benchmarks.baselines import TaskPolicy, benchmark_task
from sim.layouts import layout
from sim.planning import CUBE_SIZE, make_cell_scene
from sim.robot_model import ARM_JOINTS, GRIPPER_DRIVER_JOINT, load_waypoints

DT, COMMITTED, CHUNK_STEPS, WEIGHT, PADDING = 0.1, 20, 50, 300.0, 0.01
WINDOW_MS = COMMITTED * DT * 1000.0
STAGES = ("validate", "smooth", "blend", "densify", "limits", "collision")


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


def pipeline(safety: Any, snapshot: Any, msg: Any, points: int, clock: Callable[[], float] | None = None) -> dict[str, float]:
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
    motion = join_at_seam(spline, DT, 0.0, seam, end, p0, v0, blend_duration=0.5 * COMMITTED * DT)
    _, v_end, _ = motion.evaluate(np.array([end]))
    spare = CHUNK_STEPS - 1 - (3 + COMMITTED)
    motion = motion.with_runout(runout_duration(v_end[0], safety.limits.max_acceleration, DT, 0.5 * COMMITTED * DT, spare))
    mark()
    samples = densify(motion, points)
    mark()
    violation = safety.limits.check(samples.positions, samples.velocities, samples.accelerations, samples.times)
    mark()
    collision = safety.first_collision(snapshot, samples, PADDING, 0.0)
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
    for points in (100, 200, 400):
        for _ in range(5):
            pipeline(safety, snapshot, msg, points)  # warm caches (collision checker, scipy)
        totals, stages = [], {s: [] for s in STAGES}
        for _ in range(args.repeats):
            start = time.perf_counter()
            split = pipeline(safety, snapshot, msg, points, time.perf_counter)
            totals.append((time.perf_counter() - start) * 1000.0)
            for name, seconds in split.items():
                stages[name].append(seconds * 1000.0)
        p50 = percentile(totals, 50)
        row = {
            "bench": "pipeline",
            "points": points,
            "p50_ms": rounded(p50, 3),
            "p95_ms": rounded(percentile(totals, 95), 3),
            "window_fraction": rounded(p50 / WINDOW_MS, 5),
            "repeats": args.repeats,
        }
        row.update({f"{name}_ms": rounded(percentile(values, 50), 3) for name, values in stages.items()})
        rows.append(row)
    columns = ["points", "p50_ms", "p95_ms", "window_fraction", *(f"{s}_ms" for s in STAGES)]
    notes = [
        f"one 50-step chunk (6 arm joints + gripper), committed window {COMMITTED} x {DT} s = {WINDOW_MS:g} ms; "
        f"{args.repeats} repeats, medians (stage columns are each stage's own median)",
        "target: window_fraction < 0.01 at 200 points (< 20 ms), aim < 5 ms",
    ]
    report("bench_pipeline: one chunk, validate to collision check", rows, columns, notes)


if __name__ == "__main__":
    main()

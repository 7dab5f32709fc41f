"""Collision-free planning on the cell: plan time, success and path length, beside the straight move.

Seeded queries: a start and a goal configuration, each the IK solution (seeded from Home, in
Home's branch: every joint within half a turn of it) of a TCP pose looking down, the start left
of the cubes' workspace centre (x < -0.08 m) and the goal right of it (x > 0.08 m), between 8
and 30 cm above the table; both collision-free in both scenes. Two scenes: the cell as it is
(table and three cubes), and the same with a wall across the workspace (``obstacle``: 4 x 30 x
20 cm, centred at x = 0, y = 0.45 m), which most straight moves from left to right go through.
Per scene: how many straight joint moves are free, how many queries the planner solves within
its 1 s timeout, its plan time (median and p95; the straight check included), and the
joint-space length (rad) of the planned path beside that of the straight move between the same
configurations.

The planner is the runtime's (``runtime.motion.scene.planner``: OMPL's RRT-Connect and shortcutting,
one thread) with the state check the planning behaviors give it (``behaviors.planning.state_validity``:
the planning scene's collision check and the cell's Cartesian envelope).

    .venv/bin/python benchmarks/bench_planning.py [--queries 200] [--seed 0]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import common  # noqa: F401  (environment and sys.path first)
from common import median, percentile, report

OBSTACLE_SIZE_M = (0.04, 0.30, 0.20)
OBSTACLE_CENTER_M = (0.0, 0.45, 0.10)
TIMEOUT_S = 1.0
PADDING_M = 0.01


def cell_scene(with_obstacle: bool):
    from runtime.motion.scene import Box, pose_matrix
    from sim.layouts import layout
    from sim.planning import make_cell_scene

    cubes = {c: (np.array([x, y, 0.015]), np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])) for c, (x, y, yaw) in layout(0).items()}
    scene = make_cell_scene(cubes)
    if with_obstacle:
        scene.add_object("obstacle", Box(OBSTACLE_SIZE_M), pose_matrix(OBSTACLE_CENTER_M), fixed=True)
    return scene


def make_queries(count: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` (start, goal) pairs, free in both scenes, from TCP poses looking down."""
    from behaviors.planning import state_validity
    from behaviors.safety import make_safety
    from runtime.motion.scene import solve_ik

    home = np.array([-1.8732, -1.7159, 1.7867, -1.6416, -1.5708, -0.3024])
    rng = np.random.default_rng(seed)
    scenes = [cell_scene(False), cell_scene(True)]
    safeties = [make_safety(s, "manipulator", s.gripper_joint) for s in scenes]
    checks = [state_validity(m, PADDING_M, s.snapshot(), 0.0) for s, m in zip(scenes, safeties)]
    down = np.diag([1.0, -1.0, -1.0])  # TCP z down
    states: list[np.ndarray] = []
    while len(states) < 2 * count:
        side = -1.0 if len(states) % 2 == 0 else 1.0
        target = np.eye(4)
        target[:3, :3] = down
        target[:3, 3] = (side * rng.uniform(0.08, 0.3), rng.uniform(0.3, 0.55), rng.uniform(0.08, 0.30))
        result = solve_ik(scenes[0].robot, "manipulator", target, seeds=[home], frame="tcp", random_restarts=0)
        same_branch = result.success and bool(np.all(np.abs(result.positions - home) < np.pi))
        if same_branch and all(check(result.positions) for check in checks):
            states.append(result.positions)
    return [(states[2 * i], states[2 * i + 1]) for i in range(count)]


def measure_ompl(scene, queries, seed: int) -> list[tuple[float, bool, float | None, bool]]:
    """Per query: milliseconds, solved, path length (rad), straight move free."""
    from behaviors.planning import state_validity
    from behaviors.safety import make_safety
    from runtime.motion.scene.planner import PathPlanningError, PlannerSettings, motion_is_free, plan_path

    safety = make_safety(scene, "manipulator", scene.gripper_joint)
    is_free = state_validity(safety, PADDING_M, scene.snapshot(), 0.0)
    lower, upper = safety.limits.lower, safety.limits.upper
    out = []
    for i, (start, goal) in enumerate(queries):
        settings = PlannerSettings(timeout_s=TIMEOUT_S, seed=seed + i)
        began = time.perf_counter()
        try:
            path = plan_path(is_free, start, goal, lower, upper, settings)
            solved, length = True, path.length_rad
        except PathPlanningError:
            solved, length = False, None
        ms = (time.perf_counter() - began) * 1000.0
        out.append((ms, solved, length, motion_is_free(is_free, start, goal, settings.check_step_rad)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    queries = make_queries(args.queries, args.seed)
    rows = []
    for with_obstacle in (False, True):
        scene = cell_scene(with_obstacle)
        results = measure_ompl(scene, queries, args.seed)
        times = [r[0] for r in results]
        solved = [r for r in results if r[1]]
        straight_lengths = [float(np.linalg.norm(g - s)) for (s, g), r in zip(queries, results) if r[1]]
        detours = [r[2] / float(np.linalg.norm(g - s)) for (s, g), r in zip(queries, results) if r[1] and not r[3] and r[2] is not None]
        within_1s = sum(1 for r in solved if r[0] <= 1000.0)
        rows.append({
            "bench": "planning",
            "scene": "cell + obstacle" if with_obstacle else "cell",
            "queries": len(results),
            "straight_free": sum(1 for r in results if r[3]),
            "solved": len(solved),
            "solved_within_1s_pct": round(100.0 * within_1s / len(results), 1),
            "median_ms": round(median(times), 2),
            "p95_ms": round(percentile(times, 95), 2),
            "median_ms_searched": round(median([r[0] for r in solved if not r[3]]), 2) if any(not r[3] for r in solved) else None,
            "median_length_rad": round(median([r[2] for r in solved if r[2] is not None]), 3) if solved else None,
            "median_straight_length_rad": round(median(straight_lengths), 3) if solved else None,
            "median_detour": round(median(detours), 2) if detours else None,
        })
    report("bench_planning: OMPL RRT-Connect + shortcutting on the cell's planning scene", rows,
           ["scene", "queries", "straight_free", "solved", "solved_within_1s_pct", "median_ms", "p95_ms",
            "median_ms_searched", "median_length_rad", "median_straight_length_rad", "median_detour"],
           notes=[f"timeout {TIMEOUT_S:g} s, padding {PADDING_M} m, one thread; times include the straight-move check",
                  "median_ms_searched: the queries whose straight move is blocked (RRT-Connect ran)",
                  "lengths: joint-space (rad) of the planned path and of the straight move between the same start and goal",
                  "median_detour: planned length / straight length, over the queries whose straight move is blocked"])


if __name__ == "__main__":
    main()

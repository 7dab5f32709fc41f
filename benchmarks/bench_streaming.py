"""Streaming quality under latency: ExecutePolicy against three baselines, on the sim clock.

Same policy (``benchmarks.baselines.TaskPolicy``: a 10 s smooth task path with per-chunk phase and
position disagreement and per-step jitter, seeded by call index), same latency traces (call
``i`` takes ``trace[i]``; fixed, and heavy-tailed lognormal with sd = mean), four executors:

- ``ours``: ExecutePolicy on the ``kinematic`` world (real behavior, controllers, planning-scene
  checks); its commanded stream is recorded at the 500 Hz control loop and read at the policy
  ticks. The warmup call takes the trace's mean latency.
- ``sync`` and ``lerobot_aggregate``: ``benchmarks.baselines`` (pure simulations of the commanded
  stream at the policy ticks). ``lerobot_aggregate`` runs LeRobot's own queue code where lerobot
  is installed (``make lerobot``) and a reimplementation otherwise: the ``implementation`` column
  says which.
- ``jtc_newest_wins``: ros2_controllers' approach (``benchmarks.baselines.run_jtc_newest_wins``):
  positions-only chunks, newest wins, a C2 spline through each chunk started at the last
  command's velocity, merged at arrival by the cell's JTC model; no checks.

Every executor plays ``total_action_steps`` = 110 policy steps (dt 0.1 s, committed window 20
steps = 2 s; chunks of 50 steps). Metrics (``benchmarks.baselines.stream_metrics``) are computed on the
setpoints at the policy ticks, t = 0 at the first real request. Rows are medians over the
seeds whose run succeeded (``ok_runs`` of ``runs``; ``failures`` lists why the others failed);
``reached_goal`` counts the successful runs that ended within 0.02 rad of the task's goal.

    .venv/bin/python benchmarks/bench_streaming.py [--quick]
"""
from __future__ import annotations

import argparse
import math
import statistics
from dataclasses import asdict
from typing import Any

import common  # noqa: F401  (environment and sys.path first)
from common import report, rounded

import numpy as np
from moveit_pro_ml_msgs.srv import GetActionChunk
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from runtime.io.bus import SimulatedLatency, TraceLatency
from runtime.tree.loader import load_tree
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, make_context, run_tree
from benchmarks.baselines import (
    GlitchingPolicy,
    Stream,
    TaskPolicy,
    benchmark_task,
    latency_trace,
    run_jtc_newest_wins,
    run_lerobot_aggregate,
    run_sync,
    sample_stream,
    setpoints_over_limits,
    stream_metrics,
)
from sim.kinematic import KinematicWorld
from sim.robot_model import ARM_JOINTS

DT, COMMITTED, CHUNK, TOTAL = 0.1, 20, 50, 110
SERVICE = "/get_action_chunk"
WINDOW = COMMITTED * DT
XML = f"""<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>
<SwitchController activate_controllers="joint_trajectory_admittance_controller" deactivate_controllers="velocity_force_controller"/>
<ExecutePolicy policy_service_name="{SERVICE}" joint_group_name="manipulator" total_action_steps="{TOTAL}" dt="{DT}"
  committed_action_steps="{COMMITTED}" num_interpolation_points="200" goal_path_tolerance="0.3" policy_call_timeout="30.0"/>
</Sequence></BehaviorTree></root>"""


def run_ours(registry: Registry, policy: TaskPolicy | GlitchingPolicy, trace: list[float]) -> tuple[Stream | None, dict[str, Any]]:
    """ExecutePolicy on the kinematic world; the commanded stream on the policy tick grid."""
    options = RunOptions(seed=0, max_seconds=120.0, world="kinematic")
    context = make_context(options)
    world = KinematicWorld({"seed": 0, "policy": "none"})
    loaded = load_tree(XML, registry, context)
    calls = {"n": 0}

    def serve(request: Any) -> Any:
        observed = np.array(request.robot_state.position)
        if calls["n"] == 0:  # the warmup: answered, then forgotten (its chunk is discarded)
            rows = policy.chunk(10**6, observed)
            policy.reset()
        else:
            rows = policy.chunk(calls["n"] - 1, observed)
        calls["n"] += 1
        response = GetActionChunk.Response(status=GetActionChunk.Response.CHUNK_PRODUCED, native_control_period=DT)
        response.chunk = JointTrajectory(
            joint_names=list(request.robot_state.name),
            points=[JointTrajectoryPoint(positions=[float(v) for v in r]) for r in rows],
        )
        return response

    context.bus.create_service(SERVICE, GetActionChunk, serve)
    assert isinstance(context.bus, SimulatedLatency)  # the in-process bus
    context.bus.set_latency(SERVICE, TraceLatency([float(np.mean(trace))] + trace))  # the warmup takes the mean
    log_t: list[float] = []
    log_q: list[np.ndarray] = []
    command = world.cell.command_arm

    def record(position: Any, velocity: Any = None) -> None:
        log_t.append(world.cell.t)
        log_q.append(np.array(position, dtype=float))
        command(position, velocity)

    world.cell.command_arm = record  # type: ignore[method-assign]
    policy.reset()
    result = run_tree(loaded, context, options, world=world)
    summary = result.extra.get("execute_policy", {})
    info = {"status": result.status, "reason": result.reason, "stall_seconds": summary.get("stall_seconds")}
    requests = context.events.of_kind("chunk_requested")
    if len(requests) < 2:
        return None, info
    origin = requests[1].time  # the first real request (the warmup's is requests[0])
    times, positions = np.array(log_t), np.array(log_q)
    # Before the first command the arm rests where it started.
    start = np.array([world.waypoints["Ready"][j] for j in ARM_JOINTS])
    times = np.concatenate([[0.0], times])
    positions = np.vstack([start, positions])
    keep = np.concatenate([times[1:] != times[:-1], [True]])  # last command of each control step
    times, positions = times[keep], positions[keep]
    seams = [int(round((e.data["seam_time"] - origin) / DT)) + 1 for e in context.events.of_kind("chunk_executed")]
    ticks = sample_stream(times, positions, origin, DT, times[-1])
    return Stream(DT, ticks, seams, calls["n"] - 1), info


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one seed and fewer latencies (a smoke run)")
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    seeds = [0] if args.quick else list(range(args.seeds))
    factors = [0.0, 0.475, 2.0] if args.quick else [0.0, 0.25, 0.475, 1.0, 2.0]
    registry = Registry.from_entry_points()
    start = np.array([KinematicWorld({"policy": "none"}).waypoints["Ready"][j] for j in ARM_JOINTS])
    path = benchmark_task(start)
    rows: list[dict[str, Any]] = []
    for kind in ("fixed", "lognormal"):
        for factor in factors:
            if kind == "lognormal" and factor == 0.0:
                continue
            latency = factor * WINDOW
            per_method: dict[str, list[dict[str, Any]]] = {"ours": [], "sync": [], "lerobot_aggregate": [], "jtc_newest_wins": []}
            for seed in seeds:
                trace = latency_trace(kind, latency, 200, seed)
                make = lambda: TaskPolicy(path, DT, CHUNK, seed=seed)  # noqa: E731
                streams: dict[str, tuple[Stream | None, dict[str, Any]]] = {
                    "ours": run_ours(registry, make(), trace),
                    "sync": (run_sync(make(), trace, start, DT, COMMITTED, TOTAL), {"status": "SUCCESS"}),
                    "lerobot_aggregate": (run_lerobot_aggregate(make(), trace, start, DT, TOTAL), {"status": "SUCCESS"}),
                    "jtc_newest_wins": (run_jtc_newest_wins(make(), trace, start, DT, TOTAL, COMMITTED), {"status": "SUCCESS"}),
                }
                for method, (stream, info) in streams.items():
                    entry = {"ok": info["status"] == "SUCCESS", "reason": info.get("reason", "")}
                    if stream is not None:
                        entry.update(asdict(stream_metrics(stream, path)), implementation=stream.implementation)
                    per_method[method].append(entry)
            for method, entries in per_method.items():
                rows.append(_row(method, kind, latency, entries))
    notes = [
        f"dt {DT} s, committed {COMMITTED} steps (window {WINDOW:g} s), chunk {CHUNK} steps, {TOTAL} steps per run, "
        f"seeds {seeds}; no-stall bound (committed-1)*dt/2 = {(COMMITTED - 1) * DT / 2:g} s",
        "medians over seeds; jumps and jerk from the setpoints at the policy ticks (finite differences over dt)",
    ]
    columns = ["method", "latency", "latency_s", "ok_runs", "reached_goal", "stall_fraction", "task_time_s", "motion_time_s", "max_vel_jump", "max_acc_jump", "rms_jerk", "max_path_dev", "implementation"]
    report("bench_streaming: executors under policy latency (sim clock)", rows, columns, notes)
    report("bench_streaming: an unsafe chunk (call 3 jumps joint 0 by 0.6 rad)", unsafe_rows(registry, start, path, seeds),
           ["method", "latency_s", "runs", "ended", "setpoints_over_limits"],
           [f"setpoints at the policy ticks over the UR5e's limits ({MAX_VELOCITY:.3g} rad/s, {MAX_ACCELERATION:g} rad/s^2), "
            "summed over the seeds; 'ended': runs that stopped on the chunk"])


MAX_VELOCITY, MAX_ACCELERATION = math.pi, 5.0  # sim/config/joint_limits.yaml, every arm joint


def unsafe_rows(registry: Registry, start: np.ndarray, path: Any, seeds: list[int]) -> list[dict[str, Any]]:
    """Each executor fed the same glitching policy at 0.95 s fixed latency: how many setpoints over
    the limits reach the arm."""
    latency = 0.475 * WINDOW
    rows = []
    for method in ("ours", "sync", "lerobot_aggregate", "jtc_newest_wins"):
        over = ended = 0
        for seed in seeds:
            trace = latency_trace("fixed", latency, 200, seed)
            policy = GlitchingPolicy(TaskPolicy(path, DT, CHUNK, seed=seed))
            if method == "ours":
                stream, info = run_ours(registry, policy, trace)
                ended += info["status"] == "FAILURE"
            elif method == "sync":
                stream = run_sync(policy, trace, start, DT, COMMITTED, TOTAL)
            elif method == "lerobot_aggregate":
                stream = run_lerobot_aggregate(policy, trace, start, DT, TOTAL)
            else:
                stream = run_jtc_newest_wins(policy, trace, start, DT, TOTAL, COMMITTED)
            over += 0 if stream is None else setpoints_over_limits(stream, MAX_VELOCITY, MAX_ACCELERATION)
        rows.append({"bench": "streaming_unsafe", "method": method, "latency_s": round(latency, 4), "runs": len(seeds),
                     "ended": ended, "setpoints_over_limits": over})
    return rows


def _row(method: str, kind: str, latency: float, entries: list[dict[str, Any]]) -> dict[str, Any]:
    measured = [e for e in entries if e["ok"] and "task_time_s" in e]  # a failed run's metrics are not comparable

    def med(key: str) -> float | None:
        values = [e[key] for e in measured]
        return rounded(statistics.median(values)) if values else None

    failures = sorted({e["reason"] for e in entries if not e["ok"]})
    row: dict[str, Any] = {
        "bench": "streaming",
        "method": method,
        "latency": kind,
        "latency_s": round(latency, 4),
        "runs": len(entries),
        "ok_runs": sum(e["ok"] for e in entries),
        "stall_fraction": med("stall_fraction"),
        "task_time_s": med("task_time_s"),
        "motion_time_s": med("motion_time_s"),
        "max_vel_jump": med("max_vel_jump"),
        "max_acc_jump": med("max_acc_jump"),
        "rms_jerk": med("rms_jerk"),
        "max_path_dev": med("max_path_dev"),
        "reached_goal": sum(bool(e.get("done")) for e in measured),
        "implementation": "; ".join(sorted({e["implementation"] for e in entries if "implementation" in e})),
    }
    if failures:
        row["failures"] = failures
    return row


if __name__ == "__main__":
    main()

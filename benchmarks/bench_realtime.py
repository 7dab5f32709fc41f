"""Real time: how well ``objective run objectives/stack_cubes.xml`` keeps its 100 Hz tick on the
wall clock, and what that costs the robot, in three set-ups, quiet and under a bounded CPU load.

- ``realtime``: ``--realtime``, the cell and the oracle in the runtime's process, no ROS;
- ``realtime, recorded``: the same with ``--record`` (the run's bag and report written by the
  recording worker into a temporary directory): what recording costs the ticks;
- ``ros, one process``: ``--ros --policy oracle``, the cell and the oracle hosted by the runtime's
  node on ROS 2;
- ``ros, robot apart``: four processes, as on a real arm: ``objective sim-robot`` (the cell
  alone, with ``/clock``), ``objective serve --backend oracle``, ``objective adapter``, and the
  runtime with ``--ros --use-sim-time --world robot`` (it only ticks its tree). The stack check
  and the cube collision rules are left out of the Objective there (the robot world's scene holds no cubes); the robot's own
  summary says where the cubes ended.

Under load, two busy processes spin a core each for the run's duration (bounded in time, killed
after it). Per row, medians over the seeds: late-tick fraction (ticks whose work took longer
than the 10 ms period), worst tick, tick-interval p50/p99 (wall time between tick starts),
GetActionChunk round trip p50, goal send-to-accepted (worst), the F/T peak (N), and how many
seeds stacked. The CPU seconds of the runtime's process per wall second of its run are beside
them: they depend much less than the wall-clock figures on what else the machine runs.

    .venv/bin/python benchmarks/bench_realtime.py [--seeds 0,1] [--world vla_sim|kinematic]
                                                  [--setups realtime,recorded,ros,robot] [--no-load | --only-load] [--priority N]

The runtime ticks at SCHED_FIFO priority 50 (``--realtime-priority 50``, as ros2_control's update
loop asks for) unless ``--priority 0``; each row says what its ticks ran at.
"""
from __future__ import annotations

import argparse
import json
import os
import random
import re
import resource
import secrets
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import common  # noqa: F401  (environment and sys.path first)
from common import ROOT, median, report

OBJECTIVE = ROOT / "objectives" / "stack_cubes.xml"
OBJECTIVE_CLI = [sys.executable, "-m", "runtime.app.cli"]
BUSY_LOOP = "import time, sys\nend = time.monotonic() + float(sys.argv[1])\nwhile time.monotonic() < end:\n    pass\n"
RUN_TIMEOUT_S = 240.0
SETUPS = {"realtime": "realtime", "recorded": "realtime, recorded", "ros": "ros, one process", "robot": "ros, robot apart"}


def busy(count: int, seconds: float) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", BUSY_LOOP, str(seconds)]) for _ in range(count)]


def end(processes: list[subprocess.Popen], sig: int = signal.SIGKILL) -> list[str]:
    """Stop ``processes`` (``sig``), wait for them; their stdout (empty where not piped)."""
    outs = []
    for process in processes:
        if process.poll() is None:
            process.send_signal(sig)
    for process in processes:
        try:
            out, _ = process.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            process.kill()
            out, _ = process.communicate()
        outs.append(out or "")
    return outs


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def start(args: list[str], env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen([*OBJECTIVE_CLI, *args], cwd=ROOT, env=env, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL)


def wait_line(process: subprocess.Popen, pattern: str, timeout_s: float) -> re.Match:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert process.stdout is not None  # start() pipes it
        line = process.stdout.readline()
        if not line:
            break
        match = re.search(pattern, line)
        if match:
            return match
    raise SystemExit(f"bench_realtime: no line matching {pattern!r} from {process.args!s}")


def last_json(text: str) -> dict[str, Any]:
    return json.loads([line for line in text.splitlines() if line.startswith("{")][-1])


@dataclass
class Policy:
    """The oracle behind the HTTP server and the adapter (for the robot-apart set-up)."""

    server: subprocess.Popen
    adapter: subprocess.Popen

    @classmethod
    def start(cls, env: dict[str, str]) -> "Policy":
        server = start(["serve", "--backend", "oracle", "--port", "0"], env)
        url = wait_line(server, r"listening on (http://127\.0\.0\.1:\d+)", 90).group(1)
        adapter = start(["adapter", "--infer-url", url, "--timeout", "8"], env)
        wait_line(adapter, r"serving /get_action_chunk", 60)
        return cls(server, adapter)

    def stop(self) -> None:
        end([self.adapter, self.server], signal.SIGTERM)


def run(setup: str, world: str, seed: int, loaded: bool, env: dict[str, str], description: list[str],
        priority: int = 0) -> dict[str, Any]:
    """One run of ``setup`` (the runtime's ticks at SCHED_FIFO ``priority``, 0: the default): the
    runtime's summary, the robot's where it runs apart, CPU seconds."""
    args = ["run", str(OBJECTIVE), "--seed", str(seed), "--json"]
    robot, record = None, None
    if setup in ("realtime", "recorded"):
        args += ["--realtime", "--world", world]
        if setup == "recorded":
            record = tempfile.TemporaryDirectory(prefix="bench-realtime-")
            args += ["--record", record.name]
    elif setup == "ros":
        args += ["--ros", "--policy", "oracle", "--world", world]
    else:
        robot = start(["sim-robot", "--world", world, "--seed", str(seed)], env)
        wait_line(robot, r"serving on ROS 2", 90)
        stack = Path(tempfile.mkdtemp()) / "stack.xml"
        # The robot world's scene holds the robot alone: no cube to check or to name in a rule.
        stack.write_text("\n".join(line for line in OBJECTIVE.read_text().splitlines()
                                   if 'SubTree ID="Check if One Cube Is on Another"' not in line
                                   and "<SetCollisionRule " not in line))
        args = ["run", str(stack), "--json", "--ros", "--use-sim-time", "--world", "robot",
                *[a for option in description for a in ("--world-option", option)]]
    if priority:
        args += ["--realtime-priority", str(priority)]
    load = busy(2, RUN_TIMEOUT_S) if loaded else []
    try:
        cpu = children_cpu()
        runner = subprocess.run([*OBJECTIVE_CLI, *args], cwd=ROOT, env=env, text=True, capture_output=True,
                                timeout=RUN_TIMEOUT_S)
        cpu = children_cpu() - cpu  # before the busy processes are reaped, which would count them
    finally:
        end(load)
        if record is not None:
            record.cleanup()
    summary = last_json(runner.stdout)
    robot_summary = last_json(end([robot], signal.SIGTERM)[0]) if robot is not None else None
    return {"summary": summary, "robot": robot_summary, "runtime_cpu_s": cpu}


def stacked(result: dict[str, Any]) -> bool:
    summary = result["summary"]
    if result["robot"] is None:
        return summary["status"] == "SUCCESS"
    cubes = result["robot"]["world"]["cubes"]
    blue, green = cubes["blue"], cubes["green"]
    on_top = abs(blue[0] - green[0]) < 0.015 and abs(blue[1] - green[1]) < 0.015 and abs(blue[2] - green[2] - 0.03) < 0.01
    return summary["status"] == "SUCCESS" and on_top


def row(setup: str, world: str, loaded: bool, results: list[dict[str, Any]]) -> dict[str, Any]:
    pacing = [r["summary"].get("pacing", {}) for r in results]
    policy = [r["summary"].get("execute_policy", {}) for r in results]
    worlds = [r["robot"]["world"] if r["robot"] is not None else r["summary"].get("world", {}) for r in results]
    return {
        "bench": "realtime",
        "setup": SETUPS[setup],
        "world": world,
        "load": "2 busy" if loaded else "quiet",
        "scheduling": pacing[0].get("scheduling", "default") if pacing else "default",
        "seeds": len(results),
        "stacked": sum(stacked(r) for r in results),
        "late_fraction": round(median([p.get("late_ticks", 0) / max(r["summary"]["ticks"], 1) for p, r in zip(pacing, results)]), 4),
        "worst_tick_s": median([p.get("worst_tick_s", float("nan")) for p in pacing]),
        "interval_p50_s": median([p.get("interval_p50_s", float("nan")) for p in pacing]),
        "interval_p99_s": median([p.get("interval_p99_s", float("nan")) for p in pacing]),
        "chunk_rtt_p50_s": median([e.get("latency_p50_s", float("nan")) for e in policy]),
        "goal_accept_max_s": median([e.get("goal_latency_max_s", float("nan")) for e in policy]),
        "peak_force_n": median([w.get("peak_force_n", float("nan")) for w in worlds]),
        "cpu_per_run_s": round(median([r["runtime_cpu_s"] / max(r["summary"]["wall_seconds"], 1e-9) for r in results]), 3),
        "statuses": [r["summary"]["status"] for r in results],
        "failures": [r["summary"]["reason"] for r in results if r["summary"]["status"] != "SUCCESS"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="0", help="comma-separated seeds (default 0)")
    parser.add_argument("--world", default="vla_sim", choices=("vla_sim", "kinematic"))
    parser.add_argument("--setups", default="realtime,ros,robot", help="comma-separated: realtime, recorded, ros, robot")
    parser.add_argument("--no-load", action="store_true", help="only the quiet rows")
    parser.add_argument("--only-load", action="store_true", help="only the rows under two busy processes")
    parser.add_argument("--priority", type=int, default=50,
                        help="the runtime's --realtime-priority (SCHED_FIFO, default 50; 0: the default scheduling)")
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    setups = [s for s in args.setups.split(",") if s]
    unknown = sorted(set(setups) - set(SETUPS))
    if unknown:
        raise SystemExit(f"bench_realtime: unknown set-ups {unknown} (known: {', '.join(SETUPS)})")
    env = dict(os.environ, ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID", str(random.randint(100, 199))),
               POLICY_SERVER_KEY=secrets.token_urlsafe(24), PYTHONUNBUFFERED="1")
    from sim.robot_node import describe

    description = describe(Path(tempfile.mkdtemp()) / "cell")
    policy = Policy.start(env) if "robot" in setups else None
    rows = []
    try:
        for loaded in [load for load in (False, True) if not (args.no_load and load) and not (args.only_load and not load)]:
            for setup in setups:
                results = [run(setup, args.world, seed, loaded, env, description, args.priority) for seed in seeds]
                rows.append(row(setup, args.world, loaded, results))
    finally:
        if policy is not None:
            policy.stop()
    report(
        "real time: objectives/stack_cubes.xml on the wall clock",
        rows,
        ["setup", "world", "load", "scheduling", "seeds", "stacked", "late_fraction", "worst_tick_s", "interval_p50_s", "interval_p99_s",
         "chunk_rtt_p50_s", "goal_accept_max_s", "peak_force_n", "cpu_per_run_s"],
        notes=["wall-clock figures depend on what else the machine runs; cpu_per_run_s: CPU seconds of the runtime's "
               "process (start-up included; the runtime alone where the robot runs apart) per wall second of its run"],
    )


if __name__ == "__main__":
    main()

"""Recording overhead: ``objective run objectives/stack_cubes.xml --world WORLD`` with and
without ``--record DIR`` (``--world``: kinematic, the default, or vla_sim: MuJoCo and three cameras).

What a user waits for is the wall time of the run: with ``--record`` the run serializes what it
records and pipes it to the recording worker (``recording/report/worker.py``), which writes
run.mcap and events.jsonl, builds the report's data and encodes the camera video as messages
arrive; after the run the worker closes the files and writes the SVG plots and the page (that
wait alone: ``bench_report_wait.py``). Two rows, each over alternating plain/recorded pairs so
both see the same machine load:

- in-process (``run_file``, as ``objective run`` runs it): wall seconds of the whole call, CPU
  seconds of this process (the recording itself) and of the worker (its imports and the report);
- whole ``objective run`` processes: wall seconds, and CPU seconds of the process tree
  (interpreter start-up, the worker and the ffmpeg child included).

``overhead`` is the wall time added, over the plain run's; the target is at most 0.15. CPU
overheads are reported beside it: they are larger, since the worker runs on another core.

    .venv/bin/python benchmarks/bench_recording.py [--pairs N] [--world kinematic|vla_sim]
"""
from __future__ import annotations

import argparse
import resource
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import common  # noqa: F401  (environment and sys.path first)
from common import ROOT, median, report, rounded

from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, run_file

OBJECTIVE = ROOT / "objectives" / "stack_cubes.xml"


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def timed_run(registry: Registry, world: str, record_dir: Path | None) -> dict[str, float]:
    """Wall seconds of one run (report included), CPU of this process and of its children."""
    wall, cpu, children = time.perf_counter(), time.process_time(), children_cpu()
    result = run_file(OBJECTIVE, registry, RunOptions(world=world, record_dir=record_dir))
    out = {"wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu, "children_cpu": children_cpu() - children,
           "sim_seconds": result.sim_seconds}
    if result.status != "SUCCESS":
        raise SystemExit(f"bench_recording: the run failed: {result.reason}")
    if record_dir is not None and not (record_dir / "report.html").is_file():
        raise SystemExit(f"bench_recording: no report in {record_dir}")
    return out


def process_run(world: str, record_dir: Path | None) -> dict[str, float]:
    """CPU (process tree) and wall seconds of one ``objective run`` process."""
    command = [str(ROOT / ".venv" / "bin" / "objective"), "run", str(OBJECTIVE), "--world", world]
    if record_dir is not None:
        command += ["--record", str(record_dir)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = time.perf_counter()
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - wall
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"bench_recording: {' '.join(command)} exited {done.returncode}: {done.stderr[-500:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"cpu": cpu, "wall": wall}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=3, help="plain/recorded pairs (medians are quoted)")
    parser.add_argument("--world", default="kinematic", choices=("kinematic", "vla_sim"), help="the world to run on")
    args = parser.parse_args()
    registry = Registry.from_entry_points()
    scratch = Path(tempfile.mkdtemp(prefix="bench_recording_"))
    try:
        timed_run(registry, args.world, scratch / "warmup")  # first-run imports (including the renderer's) off the books
        plain, recorded = [], []
        for k in range(args.pairs):
            plain.append(timed_run(registry, args.world, None))
            recorded.append(timed_run(registry, args.world, scratch / f"run{k}"))
        mcap_bytes = (scratch / "run0" / "run.mcap").stat().st_size
        processes_plain, processes_recorded = [], []
        for k in range(args.pairs):
            processes_plain.append(process_run(args.world, None))
            processes_recorded.append(process_run(args.world, scratch / f"process{k}"))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    base_wall, recorded_wall = median([p["wall"] for p in plain]), median([r["wall"] for r in recorded])
    base_cpu = median([p["cpu"] for p in plain])
    row = {
        "bench": "recording",
        "objective": OBJECTIVE.name,
        "world": args.world,
        "pairs": args.pairs,
        "sim_seconds": rounded(plain[0]["sim_seconds"], 2),
        "plain_wall_s": rounded(base_wall, 3),
        "recorded_wall_s": rounded(recorded_wall, 3),
        "overhead": rounded(recorded_wall / base_wall - 1.0, 3),
        "plain_cpu_s": rounded(base_cpu, 3),
        "record_cpu_s": rounded(median([r["cpu"] for r in recorded]) - base_cpu, 3),
        "worker_cpu_s": rounded(median([r["children_cpu"] for r in recorded]), 3),
        "mcap_bytes": mcap_bytes,
    }
    plain_cpu, recorded_cpu = median([p["cpu"] for p in processes_plain]), median([p["cpu"] for p in processes_recorded])
    plain_wall, process_wall = median([p["wall"] for p in processes_plain]), median([p["wall"] for p in processes_recorded])
    process_row = {
        "bench": "recording_process",
        "objective": OBJECTIVE.name,
        "world": args.world,
        "pairs": args.pairs,
        "plain_wall_s": rounded(plain_wall, 3),
        "recorded_wall_s": rounded(process_wall, 3),
        "overhead": rounded(process_wall / plain_wall - 1.0, 3),
        "plain_cpu_s": rounded(plain_cpu, 3),
        "recorded_cpu_s": rounded(recorded_cpu, 3),
        "cpu_overhead": rounded(recorded_cpu / plain_cpu - 1.0, 3),
    }
    notes = ["target: overhead (wall time added by --record, report included) <= 0.15 (whole processes)",
             "in-process row: run_file calls; record_cpu_s = extra CPU of this process, worker_cpu_s = the report worker's",
             "process row: whole `objective run` processes; CPU of the process tree"]
    columns = ["bench", "plain_wall_s", "recorded_wall_s", "overhead", "plain_cpu_s", "record_cpu_s", "worker_cpu_s",
               "recorded_cpu_s", "cpu_overhead"]
    report(f"bench_recording: stack_cubes.xml on '{args.world}', --record versus none", [row, process_row], columns, notes)


if __name__ == "__main__":
    main()

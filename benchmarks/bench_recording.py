"""Recording overhead: ``objective run objectives/stack_cubes.xml --world kinematic`` with and
without ``--record DIR``.

Runs alternate (plain, recorded, plain, recorded...) in this process, as ``objective run`` runs
them (``run_file``), so both see the same machine load. Times are CPU seconds of this process
(``time.process_time``), which a busy shared machine disturbs far less than wall time; the
renderer's ffmpeg child process is not in them, so its wall time is reported apart. Three costs
of a recorded run:

- ``record``: the extra CPU of the run itself (the RecordingBus serializing into run.mcap, the
  events.jsonl lines);
- ``render``: reading the recording back and writing joints.png, latency.png, tree.svg,
  cameras.mp4 and report.html;
- ``imports``: importing matplotlib and imageio, paid once per ``objective run --record`` process
  (measured in a fresh interpreter).

``overhead`` is their sum over the plain run's CPU time (loading the XML included, interpreter
start-up excluded: a conservative denominator). The target is at most 0.20.

A second row measures what a user pays: whole ``objective run`` processes with and without
``--record`` (interpreter start-up and the ffmpeg child included), as CPU seconds of the process
tree (``RUSAGE_CHILDREN``) and as wall seconds (noisy on a shared machine).

    .venv/bin/python benchmarks/bench_recording.py [--pairs N]
"""
from __future__ import annotations

import argparse
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import common  # noqa: F401  (environment and sys.path first)
from common import ROOT, median, report, rounded

from runtime.registry import Registry
from runtime.runner import RunOptions, run_file

OBJECTIVE = ROOT / "objectives" / "stack_cubes.xml"
IMPORTS = "import time; t = time.process_time(); import matplotlib.figure, matplotlib.backends.backend_agg, imageio.v2; print(time.process_time() - t)"


def timed_run(registry: Registry, record_dir: Path | None) -> dict[str, float]:
    """CPU seconds of one run; with ``record_dir``, split into the run and the report rendering."""
    import runtime.report as report_module

    rendering = {"cpu": 0.0, "wall": 0.0}
    original = report_module.render_report

    def measured_render(directory: Any, logger: Any = None) -> Any:
        cpu, wall = time.process_time(), time.perf_counter()
        try:
            return original(directory, logger)
        finally:
            rendering["cpu"] += time.process_time() - cpu
            rendering["wall"] += time.perf_counter() - wall

    report_module.render_report = measured_render
    try:
        cpu = time.process_time()
        result = run_file(OBJECTIVE, registry, RunOptions(world="kinematic", record_dir=record_dir))
        total = time.process_time() - cpu
    finally:
        report_module.render_report = original
    if result.status != "SUCCESS":
        raise SystemExit(f"bench_recording: the run failed: {result.reason}")
    return {"run": total - rendering["cpu"], "render": rendering["cpu"], "render_wall": rendering["wall"],
            "sim_seconds": result.sim_seconds}


def process_run(record_dir: Path | None) -> dict[str, float]:
    """CPU (process tree) and wall seconds of one ``objective run`` process."""
    command = [str(ROOT / ".venv" / "bin" / "objective"), "run", str(OBJECTIVE), "--world", "kinematic"]
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


def import_cost() -> float:
    out = subprocess.run([sys.executable, "-c", IMPORTS], check=True, capture_output=True, text=True, cwd=ROOT)
    return float(out.stdout.strip())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=3, help="plain/recorded pairs (medians are quoted)")
    args = parser.parse_args()
    registry = Registry.from_entry_points()
    scratch = Path(tempfile.mkdtemp(prefix="bench_recording_"))
    try:
        timed_run(registry, scratch / "warmup")  # first-run imports (including the renderer's) off the books
        plain, recorded = [], []
        for k in range(args.pairs):
            plain.append(timed_run(registry, None))
            recorded.append(timed_run(registry, scratch / f"run{k}"))
        mcap_bytes = (scratch / "run0" / "run.mcap").stat().st_size
        processes_plain, processes_recorded = [], []
        for k in range(args.pairs):
            processes_plain.append(process_run(None))
            processes_recorded.append(process_run(scratch / f"process{k}"))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    imports = median([import_cost() for _ in range(3)])
    base = median([p["run"] for p in plain])
    record = median([r["run"] for r in recorded]) - base
    render = median([r["render"] for r in recorded])
    row = {
        "bench": "recording",
        "objective": OBJECTIVE.name,
        "world": "kinematic",
        "pairs": args.pairs,
        "sim_seconds": rounded(plain[0]["sim_seconds"], 2),
        "plain_cpu_s": rounded(base, 3),
        "record_cpu_s": rounded(record, 3),
        "render_cpu_s": rounded(render, 3),
        "render_wall_s": rounded(median([r["render_wall"] for r in recorded]), 3),
        "imports_cpu_s": rounded(imports, 3),
        "overhead": rounded((record + render + imports) / base, 3),
        "run_overhead": rounded(record / base, 3),
        "mcap_bytes": mcap_bytes,
    }
    plain_cpu = median([p["cpu"] for p in processes_plain])
    plain_wall = median([p["wall"] for p in processes_plain])
    process_row = {
        "bench": "recording_process",
        "objective": OBJECTIVE.name,
        "world": "kinematic",
        "pairs": args.pairs,
        "plain_cpu_s": rounded(plain_cpu, 3),
        "recorded_cpu_s": rounded(median([p["cpu"] for p in processes_recorded]), 3),
        "overhead": rounded(median([p["cpu"] for p in processes_recorded]) / plain_cpu - 1.0, 3),
        "plain_wall_s": rounded(plain_wall, 3),
        "recorded_wall_s": rounded(median([p["wall"] for p in processes_recorded]), 3),
        "wall_overhead": rounded(median([p["wall"] for p in processes_recorded]) / plain_wall - 1.0, 3),
    }
    notes = ["target: overhead <= 0.20",
             "in-process row: CPU seconds of this process, medians; render_wall_s includes the ffmpeg child",
             "process row: whole `objective run` processes, CPU of the process tree; wall is noisy on a shared machine"]
    columns = ["bench", "plain_cpu_s", "record_cpu_s", "render_cpu_s", "imports_cpu_s", "recorded_cpu_s", "overhead", "wall_overhead"]
    report("bench_recording: stack_cubes.xml on 'kinematic', --record versus none", [row, process_row], columns, notes)


if __name__ == "__main__":
    main()

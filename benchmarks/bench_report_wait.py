"""The report's wait: wall seconds a recorded run spends after its last tick until its report is
written (``Recorder.finish`` plus ``ReportWorker.render``, timed around the calls), on
``objectives/stack_cubes.xml`` and the kinematic world, in-process runs (``run_file``).

The target: at most about 0.1 s. The two methods are wrapped for the timing only;
the run is otherwise the one ``objective run --record`` does.

    .venv/bin/python benchmarks/bench_report_wait.py [--runs N]
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import common  # noqa: F401  (environment and sys.path first)
from common import ROOT, median, report, rounded

from recording.recorder import Recorder
from runtime.tree.registry import Registry
from recording.report.worker import ReportWorker
from runtime.app.runner import RunOptions, run_file

OBJECTIVE = ROOT / "objectives" / "stack_cubes.xml"


def timed(method: Callable[..., Any], seconds: list[float]) -> Callable[..., Any]:
    def call(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return method(*args, **kwargs)
        finally:
            seconds.append(time.perf_counter() - start)

    return call


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=4, help="recorded runs (the median is quoted)")
    args = parser.parse_args()
    registry = Registry.from_entry_points()
    finish_s: list[float] = []
    render_s: list[float] = []
    Recorder.finish = timed(Recorder.finish, finish_s)  # type: ignore[method-assign]
    ReportWorker.render = timed(ReportWorker.render, render_s)  # type: ignore[method-assign]
    scratch = Path(tempfile.mkdtemp(prefix="bench_report_wait_"))
    try:
        run_file(OBJECTIVE, registry, RunOptions(world="kinematic", record_dir=scratch / "warmup"))
        finish_s.clear()
        render_s.clear()
        for k in range(args.runs):
            result = run_file(OBJECTIVE, registry, RunOptions(world="kinematic", record_dir=scratch / f"run{k}"))
            if result.status != "SUCCESS" or not (scratch / f"run{k}" / "report.html").is_file():
                raise SystemExit(f"bench_report_wait: run {k} ended {result.status} or wrote no report")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    waits = [a + b for a, b in zip(finish_s, render_s)]
    row = {"bench": "report_wait", "objective": OBJECTIVE.name, "runs": args.runs,
           "wait_s": rounded(median(waits), 3), "wait_max_s": rounded(max(waits), 3),
           "finish_s": rounded(median(finish_s), 3), "render_s": rounded(median(render_s), 3)}
    report("bench_report_wait: a recorded run's wait for its report after the last tick", [row],
           ["bench", "wait_s", "wait_max_s", "finish_s", "render_s"], ["target: wait_s <= about 0.1"])


if __name__ == "__main__":
    main()

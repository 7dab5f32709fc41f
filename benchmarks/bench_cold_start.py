"""Cold start: whole ``objective run objectives/stack_cubes.xml`` processes, with and without the
on-disk cache (``runtime/app/disk_cache.py``: the composed robot MJCF, the simplified visual meshes,
the compiled cell and the planning model's MuJoCo facts).

A cold start is everything before the tree does its work: interpreter start-up, imports, the
vla_sim world (MJCF composed, meshes simplified, cell compiled, renderer made), the planning
scene (robot model loaded), the tree loaded. Each process runs the objective with
``--max-seconds 0.01`` (it stops after its first ticks and exits 1, as documented), so its wall
time is the cold start plus a few milliseconds of ticking. Three ways, interleaved run by run so
all see the same machine load:

- ``off``: ``OBJECTIVE_CACHE=off``, nothing read or written (no cache at all);
- ``cold``: an empty cache directory each run (computes everything and writes the entries);
- ``warm``: a cache directory filled by a run before the first measured one.

``--full`` adds the same three ways for whole runs of the objective (31 s of sim time), where the
cold start is a small part. A row's ``speedup`` is ``off``'s median wall time over its own.
``--importtime`` prints the slowest imports of ``objective`` itself (``python -X importtime``).
``--against DIR`` times another checkout's ``DIR/.venv/bin/objective`` (e.g. ``../main``) the
same three ways, interleaved run by run with this one, for a side-by-side on a loaded machine.

    .venv/bin/python benchmarks/bench_cold_start.py [--runs N] [--full] [--importtime] [--against DIR]
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import common  # noqa: F401  (environment and sys.path first)
from common import ROOT, median, report, rounded

from runtime.app.disk_cache import ENV_DIR, ENV_SWITCH

OBJECTIVE = Path("objectives") / "stack_cubes.xml"
OBJECTIVE_BIN = Path(".venv") / "bin" / "objective"
WAYS = ("off", "cold", "warm")


def process_run(checkout: Path, way: str, cache: Path, full: bool) -> dict[str, float]:
    """Wall and CPU (process tree) seconds of one ``objective run`` process of ``checkout``."""
    env = dict(os.environ, **{ENV_DIR: str(cache)})
    env.pop(ENV_SWITCH, None)
    if way == "off":
        env[ENV_SWITCH] = "off"
    elif way == "cold":
        shutil.rmtree(cache, ignore_errors=True)
    command = [str(checkout / OBJECTIVE_BIN), "run", str(OBJECTIVE)] + ([] if full else ["--max-seconds", "0.01"])
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = time.perf_counter()
    done = subprocess.run(command, cwd=checkout, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - wall
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    expected = "SUCCESS" if full else "stopped after --max-seconds"
    if expected not in done.stdout + done.stderr:
        raise SystemExit(f"bench_cold_start: {' '.join(command)} ({way}) exited {done.returncode}: "
                         f"{(done.stdout + done.stderr)[-600:]}")
    return {"wall": wall, "cpu": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)}


def measure(runs: int, full: bool, scratch: Path, checkouts: list[Path]) -> list[dict]:
    cases = [(checkout, way) for checkout in checkouts for way in WAYS]
    caches = {case: scratch / f"{index}-{case[1]}" for index, case in enumerate(cases)}
    for checkout in checkouts:  # fills the warm caches (and the OS file cache)
        process_run(checkout, "warm", caches[(checkout, "warm")], full)
    samples: dict[tuple[Path, str], list[dict[str, float]]] = {case: [] for case in cases}
    for _ in range(runs):
        for case in cases:
            samples[case].append(process_run(*case, caches[case], full))
    rows = []
    for checkout, way in cases:
        base = median([s["wall"] for s in samples[(checkout, "off")]])
        wall = median([s["wall"] for s in samples[(checkout, way)]])
        rows.append({
            "bench": "cold_start_full_run" if full else "cold_start",
            "checkout": "this" if checkout == ROOT else str(checkout),
            "objective": OBJECTIVE.name,
            "cache": way,
            "runs": runs,
            "wall_s": rounded(wall, 3),
            "min_wall_s": rounded(min(s["wall"] for s in samples[(checkout, way)]), 3),
            "cpu_s": rounded(median([s["cpu"] for s in samples[(checkout, way)]]), 3),
            "speedup": rounded(base / wall, 2),
        })
    return rows


def slowest_imports(count: int = 15) -> None:
    done = subprocess.run([sys.executable, "-X", "importtime", "-c", "import runtime.app.cli, runtime.tree.registry as r; r.Registry.from_entry_points()"],
                          cwd=ROOT, capture_output=True, text=True)
    rows = []
    for line in done.stderr.splitlines():
        parts = line.split("|")
        if len(parts) == 3 and parts[1].strip().isdigit():
            rows.append((int(parts[1]), parts[2].rstrip()))
    print("# slowest imports (cumulative us) of runtime.app.cli + every registered behavior:")
    for us, name in sorted(rows, reverse=True)[:count]:
        print(f"#   {us:>9}  {name.strip()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="measured runs per way (medians are quoted)")
    parser.add_argument("--full", action="store_true", help="also time whole runs of the objective")
    parser.add_argument("--importtime", action="store_true", help="print the slowest imports")
    parser.add_argument("--against", type=Path, metavar="DIR",
                        help="another checkout (with its .venv) to time interleaved with this one, e.g. ../main")
    args = parser.parse_args()
    checkouts = [ROOT]
    if args.against is not None:
        other = args.against.resolve()
        if not (other / OBJECTIVE_BIN).is_file():
            raise SystemExit(f"bench_cold_start: --against {args.against}: no {OBJECTIVE_BIN} there (run make setup in it)")
        checkouts.append(other)
    scratch = Path(tempfile.mkdtemp(prefix="bench_cold_start_"))
    try:
        rows = measure(args.runs, False, scratch, checkouts)
        if args.full:
            rows += measure(args.runs, True, scratch, checkouts)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    if args.importtime:
        slowest_imports()
    notes = [
        f"whole `objective run {OBJECTIVE}` processes (--max-seconds 0.01: start-up and the first ticks); "
        f"{args.runs} runs per way, interleaved; medians",
        "off: OBJECTIVE_CACHE=off; cold: empty cache each run (computes and writes); warm: cache filled beforehand",
        "target: <= 1 s per cold start",
    ]
    report("bench_cold_start: objective run, disk cache off / cold / warm", rows,
           ["bench", "checkout", "cache", "wall_s", "min_wall_s", "cpu_s", "speedup"], notes)


if __name__ == "__main__":
    main()

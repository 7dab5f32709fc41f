"""One benchmark run on two checkouts in turn, on one machine: the ratio of each figure.

Runs ``BASELINE/benchmarks/SCRIPT`` and this checkout's ``benchmarks/SCRIPT`` alternately (baseline,
this, baseline, this ...) ``--rounds`` times with the same arguments; each run imports its own
checkout's code (a benchmark puts its checkout first on ``sys.path``) with the checkout's own
``.venv`` when it has one (``make setup`` there: the installed entry points name one layout of
modules), else this Python. Rows are matched by their
non-numeric fields and numeric keys named by ``--key`` (e.g. ``points``); for every numeric field
asked for with ``--field`` it prints the median over the rounds for each checkout and the ratio
this / baseline; ``--field THIS=BASELINE`` compares this checkout's field ``THIS`` with the
baseline's ``BASELINE`` (a figure the two name differently). Alternating keeps the ratio meaningful when the machine's load drifts. A baseline
is a second worktree of this repository, e.g. ``git worktree add /tmp/base <commit>``
(then ``make setup`` in it when the two checkouts' modules differ in layout).

    .venv/bin/python benchmarks/side_by_side.py --baseline /tmp/base --rounds 5 \\
        --key points --field p50_ms --field limits_ms -- bench_pipeline.py --repeats 50
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parents[1]


def python_of(checkout: Path) -> str:
    """The checkout's own venv's Python when it has one (its entry points name its own modules),
    else this one."""
    own = checkout / ".venv" / "bin" / "python"
    return str(own) if own.is_file() else sys.executable


def run_rows(checkout: Path, script: str, args: list[str]) -> list[dict[str, Any]]:
    """The JSON rows one run of ``script`` in ``checkout`` prints."""
    done = subprocess.run([python_of(checkout), str(checkout / "benchmarks" / script), *args], cwd=checkout,
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"side_by_side: {checkout / 'benchmarks' / script} exited {done.returncode}:\n{done.stderr[-2000:]}")
    return [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]


def row_key(row: dict[str, Any], keys: list[str]) -> tuple[Any, ...]:
    return tuple((k, row[k]) for k in sorted(row) if k in keys or isinstance(row[k], str))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="the other checkout (a git worktree)")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--key", action="append", default=[], help="a numeric field that tells rows apart")
    parser.add_argument("--field", action="append", required=True,
                        help="a numeric field to compare; THIS=BASELINE for one named differently in the baseline")
    parser.add_argument("script", help="the benchmark's file name in benchmarks/")
    parser.add_argument("args", nargs=argparse.REMAINDER)
    options = parser.parse_args()
    if not (options.baseline / "benchmarks" / options.script).is_file():
        raise SystemExit(f"side_by_side: {options.baseline / 'benchmarks' / options.script} does not exist")
    args = [a for a in options.args if a != "--"]
    pairs = [tuple(f.split("=", 1)) if "=" in f else (f, f) for f in options.field]  # (this, baseline)
    figures: dict[str, dict[tuple[Any, ...], dict[str, list[float]]]] = {"baseline": {}, "this": {}}
    for _ in range(options.rounds):
        for name, checkout in (("baseline", options.baseline.resolve()), ("this", HERE)):
            for row in run_rows(checkout, options.script, args):
                slot = figures[name].setdefault(row_key(row, options.key), {})
                for this_field, baseline_field in pairs:
                    field = baseline_field if name == "baseline" else this_field
                    if isinstance(row.get(field), (int, float)):
                        slot.setdefault(f"{this_field}={baseline_field}", []).append(float(row[field]))
    print(f"# side_by_side: {options.script} {' '.join(args)}; {options.rounds} rounds, alternating; medians over rounds")
    print(f"# baseline: {options.baseline.resolve()}  this: {HERE}")
    for key, this in figures["this"].items():
        base = figures["baseline"].get(key, {})
        label = " ".join(f"{k}={v}" for k, v in key if k != "bench")
        for pair, values in this.items():
            if pair not in base:
                continue
            a, b = statistics.median(values), statistics.median(base[pair])
            ratio = a / b if b else float("nan")
            this_field, baseline_field = pair.split("=")
            field = this_field if this_field == baseline_field else f"{this_field} / {baseline_field}"
            print(f"{label:50s} {field:16s} baseline {b:10.4g}  this {a:10.4g}  this/baseline {ratio:6.3f}")


if __name__ == "__main__":
    main()

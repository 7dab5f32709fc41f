"""benchmarks/bench_planning.py prints its figures: a table and one JSON line per scene."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_the_planning_benchmark_prints_both_scenes():
    proc = subprocess.run([sys.executable, "benchmarks/bench_planning.py", "--queries", "4"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    rows = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    assert [r["scene"] for r in rows] == ["cell", "cell + obstacle"]
    for row in rows:
        assert row["queries"] == 4 and row["solved"] == 4
        assert set(row) >= {"median_ms", "p95_ms", "solved_within_1s_pct", "median_length_rad", "median_straight_length_rad"}
    assert rows[0]["straight_free"] == 4  # no obstacle: every straight move is free

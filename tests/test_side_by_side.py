"""benchmarks/side_by_side.py: one benchmark on two checkouts in turn, the ratio of each figure."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

FAKE = '''import json, sys
print("a table a person reads")
for points in (100, 200):
    print(json.dumps({{"bench": "fake", "points": points, "method": "m", "p50_ms": {value} * points, "other_ms": 4 * {value} * points}}))
'''


def checkout(tmp_path: Path, name: str, value: float) -> Path:
    root = tmp_path / name
    (root / "benchmarks").mkdir(parents=True)
    (root / "benchmarks" / "bench_fake.py").write_text(FAKE.format(value=value))
    return root


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(ROOT / "benchmarks" / "side_by_side.py"), *args],
                          capture_output=True, text=True, check=False)


def compare_fakes(tmp_path: Path, *args: str) -> list[str]:
    """side_by_side's figure lines for bench_fake.py, the baseline's figures half of this one's.
    This checkout has no bench_fake.py, so the 'this' side is pointed at a copy through the
    script's own path."""
    base = checkout(tmp_path, "base", 0.5)
    this = checkout(tmp_path, "this", 1.0)
    (this / "benchmarks" / "side_by_side.py").write_text((ROOT / "benchmarks" / "side_by_side.py").read_text())
    done = subprocess.run([sys.executable, str(this / "benchmarks" / "side_by_side.py"), "--baseline", str(base), *args,
                           "bench_fake.py"], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    return [line for line in done.stdout.splitlines() if not line.startswith("#")]


def test_rows_are_matched_by_their_keys_and_each_field_gets_its_ratio(tmp_path):
    lines = compare_fakes(tmp_path, "--rounds", "2", "--key", "points", "--field", "p50_ms")
    assert len(lines) == 2
    assert "method=m points=100" in lines[0] and "baseline         50  this        100  this/baseline  2.000" in lines[0]
    assert "method=m points=200" in lines[1] and "this/baseline  2.000" in lines[1]


def test_a_field_named_differently_in_the_baseline_is_compared_with_this_checkouts(tmp_path):
    """``--field THIS=BASELINE``: this checkout's ``other_ms`` (400 at 100 points) against the
    baseline's ``p50_ms`` (50)."""
    lines = compare_fakes(tmp_path, "--rounds", "1", "--key", "points", "--field", "other_ms=p50_ms")
    assert "method=m points=100" in lines[0] and "other_ms / p50_ms" in lines[0]
    assert "baseline         50  this        400  this/baseline  8.000" in lines[0]


def test_a_missing_baseline_script_is_named():
    done = run("--baseline", "/nonexistent", "--field", "p50_ms", "bench_pipeline.py")
    assert done.returncode == 1
    assert done.stderr.strip() == "side_by_side: /nonexistent/benchmarks/bench_pipeline.py does not exist"


def test_the_pipeline_of_two_checkouts_alternates_in_one_process():
    """``pipeline_side_by_side.py`` with this checkout as its own baseline: every stage of both,
    the envelope's, and the total without it."""
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "pipeline_side_by_side.py"), "--baseline", str(ROOT),
                           "--points", "100", "--repeats", "2"], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    stages = [line.split()[0] for line in done.stdout.splitlines() if not line.startswith("#")]
    assert stages == ["validate", "smooth", "blend", "densify", "limits", "envelope", "collision", "total",
                      "total_without_envelope"]
    assert "this/baseline" in done.stdout.splitlines()[-1]


def test_a_missing_baseline_pipeline_is_named():
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "pipeline_side_by_side.py"), "--baseline", "/nonexistent"],
                          capture_output=True, text=True, check=False)
    assert done.returncode == 1
    assert done.stderr.strip() == "pipeline_side_by_side: /nonexistent/benchmarks/bench_pipeline.py does not exist"

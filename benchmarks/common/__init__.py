"""What every benchmark script shares: the environment, medians, and the output format.

Each script prints its figures as a table, then one JSON object per measured row on its own
line (``{"bench": ..., ...}``), so a person reads the table and a tool greps the JSON. Figures
are medians over repeated runs; nothing here asserts a timing.
"""
from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

ROOT = Path(__file__).resolve().parents[2]

# Before anything imports rclpy or mujoco: discovery stays on loopback, rendering is headless.
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("ROS_LOG_DIR", str(ROOT / "build" / "ros_log"))
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def time_calls(fn: Callable[[], Any], repeats: int, warmup: int = 3) -> list[float]:
    """Wall milliseconds of ``repeats`` calls of ``fn`` (after ``warmup`` untimed calls)."""
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        out.append((time.perf_counter() - start) * 1000.0)
    return out


def percentile(values: Sequence[float], q: float) -> float:
    ordered = sorted(values)
    if not ordered:
        return float("nan")
    k = (len(ordered) - 1) * q / 100.0
    lo, hi = int(k), min(int(k) + 1, len(ordered) - 1)
    return ordered[lo] + (ordered[hi] - ordered[lo]) * (k - lo)


def median(values: Sequence[float]) -> float:
    return statistics.median(values) if values else float("nan")


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cpus, Python {platform.python_version()}"


def report(title: str, rows: list[dict[str, Any]], columns: Sequence[str], notes: Sequence[str] = ()) -> None:
    """Print ``rows`` as a table (the ``columns`` given), then each row as one JSON line."""
    print(f"# {title}  ({machine()})")
    for note in notes:
        print(f"# {note}")
    cells = [[_cell(row.get(c)) for c in columns] for row in rows]
    widths = [max(len(c), *(len(r[i]) for r in cells)) if cells else len(c) for i, c in enumerate(columns)]
    print("  ".join(c.rjust(w) for c, w in zip(columns, widths)))
    for r in cells:
        print("  ".join(v.rjust(w) for v, w in zip(r, widths)))
    for row in rows:
        print(json.dumps(row, allow_nan=False, default=_jsonable))
    sys.stdout.flush()


def _cell(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _jsonable(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)


def rounded(value: float, digits: int = 4) -> float | None:
    """JSON-safe rounding (NaN and inf become null)."""
    if value is None or value != value or value in (float("inf"), float("-inf")):
        return None
    return round(float(value), digits)

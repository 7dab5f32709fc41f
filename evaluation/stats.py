"""The numbers of an evaluation, from its episode records: pure functions, no I/O.

- :func:`wilson_interval`: the 95 % Wilson score interval of a success rate (sound at 0 and n).
- :func:`failure_groups`: the episodes that did not succeed, grouped by their failure's kind
  (``EpisodeRecord.failure_kind``: "velocity limit", "policy timeout", "SetupError", ...).
- :func:`summarise`: the ``summary.json`` object (counts, rate, groups, percentiles).
"""
from __future__ import annotations

import math
import re
from collections import Counter
from typing import Any, Iterable, Mapping

from .episode import EpisodeRecord, EpisodeStatus

Z_95 = 1.959963984540054
"""The standard normal quantile of 0.975."""

PERCENTILES = (50, 90, 95, 99)
HEADLINE_METRICS = {
    "stall_seconds": "execute_policy.stall_seconds",
    "policy_latency_p95_s": "execute_policy.latency_p95_s",
    "episode_sim_seconds": "sim_seconds",
    "episode_wall_seconds": "wall_seconds",
}
"""The percentiles every summary names, and where each comes from in an episode's metrics."""
PEAK_FORCE_PATTERN = re.compile(r"(^|\.)(peak|max)_force")
"""Peak force is read wherever a run's summary reports one (its key names a peak or max force)."""

def wilson_interval(successes: int, trials: int, z: float = Z_95) -> tuple[float, float]:
    """The Wilson score interval of ``successes / trials``; (0, 1) when there are no trials."""
    if trials <= 0:
        return 0.0, 1.0
    if not 0 <= successes <= trials:
        raise ValueError(f"successes must be within 0..{trials}, got {successes}")
    p = successes / trials
    z2 = z * z
    centre = (p + z2 / (2 * trials)) / (1 + z2 / trials)
    half = z * math.sqrt(p * (1 - p) / trials + z2 / (4 * trials * trials)) / (1 + z2 / trials)
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == trials else min(1.0, centre + half)
    return low, high


def percentiles(values: Iterable[float]) -> dict[str, float] | None:
    """p50/p90/p95/p99 (linear interpolation), min and max of ``values``; None when there are none."""
    data = sorted(float(v) for v in values)
    if not data:
        return None
    out = {f"p{q}": round(_quantile(data, q / 100), 6) for q in PERCENTILES}
    out["min"], out["max"], out["n"] = round(data[0], 6), round(data[-1], 6), len(data)
    return out


def _quantile(data: list[float], q: float) -> float:
    position = q * (len(data) - 1)
    low = math.floor(position)
    high = min(low + 1, len(data) - 1)
    return data[low] + (data[high] - data[low]) * (position - low)


def failure_groups(records: Iterable[EpisodeRecord]) -> list[dict[str, Any]]:
    """Episodes that did not succeed, grouped by status, failing node and failure kind (by the
    reason itself where the failing node gave no kind); largest first. ``reason`` names the group."""
    groups: dict[tuple[str, str, str], list[EpisodeRecord]] = {}
    for record in records:
        if record.status is EpisodeStatus.SUCCESS:
            continue
        key = (record.status.value, record.failing_node or "", record.failure_kind or record.reason.strip())
        groups.setdefault(key, []).append(record)
    out = []
    for (status, node, reason), members in groups.items():
        seeds = sorted(r.seed for r in members)
        out.append({
            "status": status, "failing_node": node or None, "reason": reason, "failure_kind": members[0].failure_kind,
            "count": len(members), "seeds": seeds, "example": next(r.reason for r in members if r.seed == seeds[0]),
        })
    return sorted(out, key=lambda g: (-g["count"], g["status"], g["reason"]))


def metric_percentiles(records: list[EpisodeRecord]) -> dict[str, dict[str, float]]:
    """Percentiles of every number the episodes reported, by dotted path (finished episodes only)."""
    values: dict[str, list[float]] = {}
    for record in records:
        if record.status is EpisodeStatus.ERROR:
            continue
        for path, value in record.numbers().items():
            if not path.endswith(".seed"):  # the world echoes the seed: not a measurement
                values.setdefault(path, []).append(value)
    return {path: stats for path, stats in ((p, percentiles(v)) for p, v in sorted(values.items())) if stats}


def headline(metrics: Mapping[str, dict[str, float]]) -> dict[str, dict[str, float] | None]:
    """The named percentiles: stall, policy latency, peak force (when reported), episode time."""
    out: dict[str, dict[str, float] | None] = {name: metrics.get(path) for name, path in HEADLINE_METRICS.items()}
    force = sorted(path for path in metrics if PEAK_FORCE_PATTERN.search(path))
    out["peak_force"] = {**metrics[force[0]], "from": force[0]} if force else None  # type: ignore[dict-item]
    return out


def summarise(records: list[EpisodeRecord], requested: int) -> dict[str, Any]:
    """The ``summary.json`` object for ``records`` (one per seed) out of ``requested`` episodes.

    The success rate counts every finished episode: an ERROR (crash, hang, lost worker) is not a
    success. ``errors`` says how many there were, so a reader can tell the two apart.
    """
    counts = Counter(r.status for r in records)
    episodes = len(records)
    successes = counts[EpisodeStatus.SUCCESS]
    low, high = wilson_interval(successes, episodes)
    metrics = metric_percentiles(records)
    return {
        "episodes": episodes,
        "requested": requested,
        "complete": episodes >= requested,
        "successes": successes,
        "failures": counts[EpisodeStatus.FAILURE],
        "errors": counts[EpisodeStatus.ERROR],
        "success_rate": round(successes / episodes, 6) if episodes else None,
        "success_rate_ci95": [round(low, 6), round(high, 6)],
        "failure_groups": failure_groups(records),
        "percentiles": headline(metrics),
        "metrics": metrics,
    }

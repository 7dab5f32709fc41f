"""What ExecutePolicy runs did: one ``RunMetrics`` per run, and the summary of every run of an
Objective (``summarise_runs``), kept under ``POLICY_RUNS`` in the run's resources."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from runtime.tree.resources import Resource

POLICY_RUNS: Resource[list[RunMetrics]] = Resource("execute_policy.runs")
"""The ``RunContext.resources`` key of the metrics of every ExecutePolicy run of the Objective:
each node's, each time a RetryUntilSuccessful or a loop started it again."""


@dataclass
class RunMetrics:
    """What one run of an ExecutePolicy node did."""

    node: str = ""
    chunks: int = 0
    steps_executed: int = 0
    stall_seconds: float = 0.0
    rejections: int = 0
    gripper_clamped: int = 0
    """Gripper targets a little outside the gripper's range, clamped into it."""
    latencies: list[float] = field(default_factory=list)
    latency_estimate_s: float = 0.0
    """What the last request was timed for (``timing.LatencyEstimate``)."""
    goal_latency_max_s: float = 0.0
    """The longest a controller goal took from sending to its acceptance."""
    oldest_observation_s: float = 0.0
    """The age of the oldest camera frame or joint state fed to the policy (see ``max_observation_age``)."""
    warnings: list[str] = field(default_factory=list)
    message: str = ""
    rejection_reason: str = ""

    def as_dict(self) -> dict[str, Any]:
        lat = np.asarray(self.latencies) if self.latencies else np.zeros(1)
        return {
            "chunks": self.chunks,
            "steps_executed": self.steps_executed,
            "stall_seconds": round(self.stall_seconds, 4),
            "rejections": self.rejections,
            "gripper_clamped": self.gripper_clamped,
            "latency_p50_s": round(float(np.percentile(lat, 50)), 4),
            "latency_p95_s": round(float(np.percentile(lat, 95)), 4),
            "latency_max_s": round(float(lat.max()), 4),
            "latency_estimate_s": round(self.latency_estimate_s, 4),
            "goal_latency_max_s": round(self.goal_latency_max_s, 4),
            "oldest_observation_s": round(self.oldest_observation_s, 4),
            "warnings": list(self.warnings),
            "message": self.message,
            "rejection_reason": self.rejection_reason,
        }


def summarise_runs(runs: list[RunMetrics]) -> dict[str, Any]:
    """The ``execute_policy`` summary of every run: totals (counts and stall summed, latency
    percentiles over every round trip, the last run's estimate, message and rejection), then
    ``run_count`` and ``runs``, each run's own figures in the order they started."""
    last = runs[-1] if runs else RunMetrics()
    total = RunMetrics(
        chunks=sum(r.chunks for r in runs),
        steps_executed=sum(r.steps_executed for r in runs),
        stall_seconds=sum(r.stall_seconds for r in runs),
        rejections=sum(r.rejections for r in runs),
        gripper_clamped=sum(r.gripper_clamped for r in runs),
        latencies=[s for r in runs for s in r.latencies],
        latency_estimate_s=last.latency_estimate_s,
        goal_latency_max_s=max((r.goal_latency_max_s for r in runs), default=0.0),
        oldest_observation_s=max((r.oldest_observation_s for r in runs), default=0.0),
        warnings=[w for r in runs for w in r.warnings],
        message=last.message,
        rejection_reason=last.rejection_reason,
    )
    return {**total.as_dict(), "run_count": len(runs), "runs": [{"node": r.node, **r.as_dict()} for r in runs]}

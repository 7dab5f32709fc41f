"""One evaluated episode: what ``episodes.jsonl`` holds per line.

An episode is ``objective run`` of the Objective with one seed. Its record keeps what a user
compares across seeds: the status and reason (with the failing node and its ``file:line``), the
simulated and wall seconds, everything the run's summary adds (``execute_policy`` metrics, the
world's final state, whatever a newer behavior reports: read generically) and the root blackboard
(the entries the Objective's checks wrote).
"""
from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from runtime.app.runner import RunResult

BASE_SUMMARY_KEYS = frozenset({"status", "failing_node", "reason", "failure_kind", "sim_seconds", "wall_seconds", "ticks",
                               "blackboard"})
"""The fields of ``RunResult.to_json`` every run has; the rest are what behaviors and the world add."""
WALL_CLOCK_FIELDS = frozenset({"wall_seconds", "worker", "attempts", "recording"})
"""Fields that depend on where and when an episode ran, not on its seed."""
EPISODE_TIMEOUT = "episode timeout"
WORKER_LOST = "worker lost"
"""The failure kinds of an episode that did not finish because of its worker."""


class EpisodeStatus(enum.Enum):
    SUCCESS = "SUCCESS"
    FAILURE = "FAILURE"
    """The Objective ran and its root failed (a check, a rejected chunk, ``--max-seconds``)."""
    ERROR = "ERROR"
    """The episode did not finish: bad input found while running, an exception, a crashed or hung
    worker (killed after ``--episode-timeout``), a worker lost too often."""


@dataclass
class EpisodeRecord:
    seed: int
    status: EpisodeStatus
    reason: str = ""
    failing_node: str | None = None
    failing_location: str | None = None
    failure_kind: str | None = None
    """What kind of ending a FAILURE or ERROR was (``RunResult.failure_kind``, ``EPISODE_TIMEOUT``,
    ``WORKER_LOST``): what ``stats.failure_groups`` groups by."""
    sim_seconds: float = 0.0
    wall_seconds: float = 0.0
    ticks: int = 0
    run: dict[str, Any] = field(default_factory=dict)
    """What the run's summary adds to the base fields: ``execute_policy``, ``world``, ..."""
    blackboard: dict[str, Any] = field(default_factory=dict)
    worker: str = ""
    attempts: int = 1
    recording: str | None = None
    """The episode's recording directory, relative to the evaluation's DIR, when it was kept."""

    @classmethod
    def from_result(cls, seed: int, result: RunResult) -> EpisodeRecord:
        summary = result.to_json()
        return cls(
            seed=seed,
            status=EpisodeStatus(result.status),
            reason=result.reason,
            failing_node=result.failing_node,
            failing_location=result.failing_location,
            failure_kind=result.failure_kind,
            sim_seconds=round(result.sim_seconds, 6),
            wall_seconds=round(result.wall_seconds, 3),
            ticks=result.ticks,
            run={k: v for k, v in summary.items() if k not in BASE_SUMMARY_KEYS},
            blackboard=dict(result.blackboard),
        )

    @classmethod
    def error(cls, seed: int, reason: str, wall_seconds: float = 0.0, attempts: int = 1, worker: str = "",
              kind: str | None = None) -> EpisodeRecord:
        return cls(seed=seed, status=EpisodeStatus.ERROR, reason=reason, wall_seconds=round(wall_seconds, 3),
                   attempts=attempts, worker=worker, failure_kind=kind)

    def numbers(self) -> dict[str, float]:
        """Every number of the run's summary by dotted path, plus ``sim_seconds`` and ``wall_seconds``."""
        out = flatten_numbers(self.run)
        out["sim_seconds"], out["wall_seconds"] = self.sim_seconds, self.wall_seconds
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "seed": self.seed, "status": self.status.value, "reason": self.reason,
            "failing_node": self.failing_node, "failing_location": self.failing_location,
            "failure_kind": self.failure_kind, "sim_seconds": self.sim_seconds, "wall_seconds": self.wall_seconds, "ticks": self.ticks,
            "run": self.run, "blackboard": self.blackboard,
            "worker": self.worker, "attempts": self.attempts, "recording": self.recording,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> EpisodeRecord:
        """The record of one ``episodes.jsonl`` line; KeyError/ValueError for a line that is not one."""
        return cls(
            seed=int(data["seed"]), status=EpisodeStatus(data["status"]), reason=str(data.get("reason") or ""),
            failing_node=data.get("failing_node"), failing_location=data.get("failing_location"),
            failure_kind=data.get("failure_kind"),
            sim_seconds=float(data.get("sim_seconds") or 0.0), wall_seconds=float(data.get("wall_seconds") or 0.0),
            ticks=int(data.get("ticks") or 0), run=dict(data.get("run") or {}),
            blackboard=dict(data.get("blackboard") or {}), worker=str(data.get("worker") or ""),
            attempts=int(data.get("attempts") or 1), recording=data.get("recording"),
        )

    def seeded_view(self) -> dict[str, Any]:
        """The record without the fields that depend on the worker and the wall clock: equal for
        equal seeds whenever the policy and its latency model are deterministic."""
        data = self.to_json()
        for key in WALL_CLOCK_FIELDS:
            data.pop(key)
        return data


def flatten_numbers(tree: Mapping[str, Any], prefix: str = "") -> dict[str, float]:
    """Every number in a nested summary dict, keyed by its dotted path (booleans and lists left out)."""
    out: dict[str, float] = {}
    for key, value in tree.items():
        path = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten_numbers(value, path + "."))
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
            out[path] = float(value)
    return out

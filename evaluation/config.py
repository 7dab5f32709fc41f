"""What an evaluation runs (``EvalConfig``), what every worker needs of it (``WorkerSpec``), and
the identity that makes a DIR resumable only by the same Objective and policy."""
from __future__ import annotations

import enum
import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from runtime.io.bus import DEFAULT_POLICY_LATENCY  # the same default as objective run
from runtime.errors import ObjectiveError

from .policies import PolicySpec, check_latency, parse_policy, policy_digest

DEFAULT_EPISODE_TIMEOUT_S = 600.0
DEFAULT_RETRIES = 1
MAX_WORKERS = 64
"""The most episodes run at once: each worker is a process holding a world of its own."""
MAX_SEED = 2**32 - 1
"""Seeds are 0 .. 2**32 - 1 (what numpy's random generators take)."""


class RecordMode(enum.Enum):
    FAILURES = "failures"
    ALL = "all"
    NONE = "none"

    def keeps(self, status: str) -> bool:
        return self is RecordMode.ALL or (self is RecordMode.FAILURES and status != "SUCCESS")


class ExecutorKind(enum.Enum):
    LOCAL = "local"
    RAY = "ray"


@dataclass(frozen=True)
class WorkerSpec:
    """Everything a worker needs to run episodes (picklable: it travels to processes and Ray actors)."""

    objective: Path
    tree: str | None = None
    search_paths: tuple[Path, ...] = ()
    objectives_dir: Path | None = None
    world: str | None = None
    policy: PolicySpec = field(default_factory=lambda: parse_policy(None))
    policy_latency: str = DEFAULT_POLICY_LATENCY
    sets: tuple[tuple[str, str], ...] = ()
    world_options: tuple[tuple[str, str], ...] = ()
    """``--world-option KEY=VALUE`` (e.g. ``image_size=128``), as ``objective run`` takes them."""
    max_seconds: float | None = None
    record: RecordMode = RecordMode.FAILURES


@dataclass(frozen=True)
class EvalConfig:
    spec: WorkerSpec
    out: Path
    episodes: int
    seed_start: int = 0
    workers: int = 1
    executor: ExecutorKind = ExecutorKind.LOCAL
    ray_address: str | None = None
    episode_timeout_s: float = DEFAULT_EPISODE_TIMEOUT_S
    retries: int = DEFAULT_RETRIES

    @property
    def seeds(self) -> range:
        return range(self.seed_start, self.seed_start + self.episodes)

    def check(self) -> None:
        """ObjectiveError for options that cannot work, before any worker starts."""
        if self.episodes < 1:
            raise ObjectiveError(f"--episodes must be at least 1, got {self.episodes}")
        if not 1 <= self.workers <= MAX_WORKERS:
            raise ObjectiveError(f"--workers must be 1 to {MAX_WORKERS} (each worker is a process with a world of its own), "
                                 f"got {self.workers}")
        if not 0 <= self.seed_start <= MAX_SEED - self.episodes + 1:
            raise ObjectiveError(f"--seed-start must be 0 to {MAX_SEED - self.episodes + 1} (seeds are 0 to {MAX_SEED}), "
                                 f"got {self.seed_start}")
        if self.retries < 0:
            raise ObjectiveError(f"--retries must not be negative, got {self.retries}")
        if not self.episode_timeout_s > 0:
            raise ObjectiveError(f"--episode-timeout must be positive, got {self.episode_timeout_s}")
        if self.ray_address and self.executor is not ExecutorKind.RAY:
            raise ObjectiveError("--ray-address needs --executor ray")
        if not self.spec.objective.is_file():
            raise ObjectiveError(f"{self.spec.objective}: no such file")
        check_latency(self.spec.policy_latency)
        if self.out.exists() and not self.out.is_dir():
            raise ObjectiveError(f"--out {self.out}: exists and is not a directory")


def identity(spec: WorkerSpec, files: Iterable[Path]) -> dict[str, Any]:
    """What a DIR's episodes depend on besides the seed; a resume must match it exactly.
    ``files``: every file the Objective is built from (``LoadedTree.files``: its SubTrees' too)."""
    objective = spec.objective.resolve()
    return {
        "objective": str(objective),
        "objective_sha256": _sha256(objective),
        "objective_files": {str(file): _sha256(file) for file in sorted({Path(f).resolve() for f in files})},
        "tree": spec.tree,
        "policy": spec.policy.text,
        "policy_sha256": policy_digest(spec.policy),
        "policy_latency": spec.policy_latency,
        "world": spec.world,
        "sets": dict(spec.sets),
        "world_options": dict(spec.world_options),
        "max_seconds": spec.max_seconds,
    }


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def files_mismatch(stored: dict[str, str] | None, current: dict[str, str]) -> str | None:
    """Which of the Objective's files differ between a DIR (``stored``) and now, or None."""
    if stored is None:
        return "an Objective whose SubTree files were not recorded (by an earlier version)"
    changed = [f for f in sorted(set(stored) | set(current)) if stored.get(f) != current.get(f)]
    if not changed:
        return None
    how = {f: "now used" if f not in stored else "no longer used" if f not in current else "edited" for f in changed}
    shown = ", ".join(f"{f} ({how[f]})" for f in changed[:3]) + (f" and {len(changed) - 3} more" if len(changed) > 3 else "")
    return f"a different Objective: {shown}"


def identity_mismatch(stored: dict[str, Any], current: dict[str, Any]) -> str | None:
    """Why a DIR made with ``stored`` cannot be resumed with ``current`` (None when it can)."""
    labels = {
        "objective_sha256": "a different Objective (its file's content differs)",
        "policy": "a different policy",
        "policy_sha256": "a different policy (the checkpoint or replay file's content differs)",
    }
    for key in ("objective_sha256", "tree", "policy", "policy_sha256", "policy_latency", "world", "world_options", "sets", "max_seconds"):
        if stored.get(key) != current.get(key):
            what = labels.get(key, f"a different {key.replace('_', ' ')}")
            if key == "objective_sha256":
                return f"was made by {what}: {stored.get('objective')}, now {current.get('objective')}"
            return f"was made by {what}: {stored.get(key)!r}, now {current.get(key)!r}"
    files = files_mismatch(stored.get("objective_files"), current["objective_files"])
    return None if files is None else f"was made by {files}"

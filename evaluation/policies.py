"""The policies an evaluation can run, and the one place it imports the policy side (``policy``).

A spec names the policy the world serves on ``/get_action_chunk``, as ``objective run --policy``:

| spec | what | deterministic per seed |
|---|---|---|
| ``oracle`` (default) | the scripted oracle, peeking at the cell | yes |
| ``replay:FILE`` | the chunks recorded in FILE | yes |
| ``lerobot:DIR`` | a LeRobot checkpoint, loaded once per worker; torch is seeded with the episode's seed | yes on one machine type (CPU float maths may differ across CPUs) |
| ``http://127.0.0.1:PORT``, ``https://HOST`` | a running inference server; its bearer key from ``POLICY_SERVER_KEY`` | no: the server's model, state and load are outside the evaluation |
| ``none`` | nothing is served (the Objective needs no policy) | yes |

"Deterministic" also needs a latency model that does not read the wall clock: a fixed number
of seconds or ``lognormal:MEAN,SD`` (seeded by the episode's seed), not ``measured``.
"""
from __future__ import annotations

import enum
import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from runtime.bus import parse_latency
from runtime.errors import ObjectiveError, OptionError

HTTP_TIMEOUT_S = 10.0
"""Wall-clock deadline of one call to an inference server (the shipped Objectives' policy_call_timeout)."""


class PolicyKind(enum.Enum):
    ORACLE = "oracle"
    REPLAY = "replay"
    LEROBOT = "lerobot"
    HTTP = "http"
    NONE = "none"


@dataclass(frozen=True)
class PolicySpec:
    kind: PolicyKind
    text: str
    path: Path | None = None
    key: str | None = field(default=None, repr=False, compare=False)
    """An inference server's bearer key, read from ``POLICY_SERVER_KEY`` where the evaluation
    starts and carried to every worker with the spec (a Ray node has no such variable)."""

    @property
    def deterministic(self) -> bool:
        return self.kind is not PolicyKind.HTTP


def parse_policy(text: str | None) -> PolicySpec:
    """The spec of ``--policy`` (None: the oracle); ObjectiveError naming what is wrong."""
    text = (text or "oracle").strip()
    lowered = text.lower()
    if lowered in ("oracle", "none"):
        return PolicySpec(PolicyKind(lowered), lowered)
    if lowered.startswith(("http://", "https://")):
        from policy.http_client import InferUrlError, check_infer_url
        from policy.server import key_from_env

        try:
            check_infer_url(text)
        except InferUrlError as err:
            raise ObjectiveError(f"--policy: {err}") from None
        return PolicySpec(PolicyKind.HTTP, text, key=key_from_env(dict(os.environ)))
    kind, sep, rest = text.partition(":")
    if sep and kind in ("replay", "lerobot") and rest:
        path = Path(rest).expanduser()
        if kind == "replay" and not path.is_file():
            raise ObjectiveError(f"--policy replay:{rest}: no such file")
        if kind == "lerobot" and not path.is_dir():
            raise ObjectiveError(f"--policy lerobot:{rest}: no such checkpoint directory")
        return PolicySpec(PolicyKind(kind), f"{kind}:{path.resolve()}", path.resolve())
    raise ObjectiveError(f"--policy: unknown policy '{text}' (expected oracle, replay:FILE, lerobot:DIR, http(s)://HOST:PORT or none)")


def check_latency(spec: str) -> None:
    try:
        parse_latency(spec)
    except OptionError as err:
        raise ObjectiveError(f"--policy-latency: {err}") from None


def policy_digest(spec: PolicySpec) -> str:
    """What identifies the policy's content: a SHA-256 over a replay file or a checkpoint's files."""
    if spec.path is None:
        return ""
    digest = hashlib.sha256()
    files = [spec.path] if spec.path.is_file() else sorted(p for p in spec.path.rglob("*") if p.is_file())
    for file in files:
        digest.update(str(file.relative_to(spec.path) if file != spec.path else file.name).encode())
        with open(file, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


class PolicyHost:
    """The policy a worker serves on each episode's bus, built once per world (per worker).

    ``serve`` puts the backend on a new episode's bus under ``/get_action_chunk`` with the
    episode's latency model; every backend starts afresh on the first request of an episode
    (``new_episode``), and a LeRobot backend's sampling noise is seeded with the episode's seed.
    """

    def __init__(self, spec: PolicySpec, cell: Any) -> None:
        self.spec = spec
        self.backend = _make_backend(spec, cell)
        if self.backend is not None:
            self.backend.load()

    def serve(self, bus: Any, seed: int, latency: str) -> None:
        if self.backend is None:
            return
        from policy.adapter import DEFAULT_SERVICE_NAME, PolicyAdapter

        if self.spec.kind is PolicyKind.LEROBOT:
            import torch

            torch.manual_seed(seed)
        PolicyAdapter(self.backend).serve(bus, DEFAULT_SERVICE_NAME)
        if hasattr(bus, "set_latency"):
            bus.set_latency(DEFAULT_SERVICE_NAME, parse_latency(latency, seed))


def _make_backend(spec: PolicySpec, cell: Any) -> Any:
    if spec.kind is PolicyKind.NONE:
        return None
    if spec.kind is PolicyKind.HTTP:
        from policy.http_client import ClientConfig, HttpBackend

        return HttpBackend(ClientConfig(spec.text, timeout=HTTP_TIMEOUT_S, key=spec.key))
    from sim.embedded_policy import make_backend

    try:
        return make_backend(spec.text, cell)
    except ObjectiveError as err:
        raise ObjectiveError(f"--policy {spec.text}: {err}") from None

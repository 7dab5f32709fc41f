"""The policies an evaluation can run, and the one place it imports the policy side (``policy``).

A spec names the policy the world serves on ``/get_action_chunk``, as ``objective run --policy``
(parsed by ``policy.specs``, the table of specs is there). Deterministic per seed: ``oracle``,
``replay:FILE``, ``none``, and ``lerobot:DIR`` on one machine type (torch is seeded with the
episode's seed; CPU float maths may differ across CPUs); not an inference server (its model,
state and load are outside the evaluation) nor your own factory (the evaluation cannot tell).

"Deterministic" also needs a latency model that does not read the wall clock: a fixed number
of seconds or ``lognormal:MEAN,SD`` (seeded by the episode's seed), not ``measured``.
"""
from __future__ import annotations

import hashlib
from typing import Any

from policy.specs import PolicyKind, PolicySpec, PolicySpecError
from policy.specs import parse_policy as parse_policy_spec
from runtime.io.bus import Bus, SimulatedLatency, capability, parse_latency
from runtime.app.world import KeepsEpisodes
from runtime.errors import ObjectiveError, OptionError

__all__ = ["PolicyHost", "PolicyKind", "PolicySpec", "check_latency", "parse_policy", "policy_digest"]


def parse_policy(text: str | None) -> PolicySpec:
    """The spec of ``--policy`` (None: the oracle); ObjectiveError naming what is wrong."""
    try:
        return parse_policy_spec(text)
    except PolicySpecError as err:
        raise ObjectiveError(f"--{err}") from None  # "--policy 'X': what is wrong"


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

    def __init__(self, spec: PolicySpec, world: KeepsEpisodes) -> None:
        self.spec = spec
        self.backend = _make_backend(spec, world)
        if self.backend is not None:
            self.backend.load()

    def serve(self, bus: Bus, seed: int, latency: str) -> None:
        if self.backend is None:
            return
        from policy.adapter import DEFAULT_SERVICE_NAME, PolicyAdapter

        if self.spec.kind is PolicyKind.LEROBOT:
            import torch

            torch.manual_seed(seed)
        PolicyAdapter(self.backend).serve(bus, DEFAULT_SERVICE_NAME)
        modelled = capability(bus, SimulatedLatency)
        if modelled is not None:
            modelled.set_latency(DEFAULT_SERVICE_NAME, parse_latency(latency, seed))


def _make_backend(spec: PolicySpec, world: KeepsEpisodes) -> Any:
    try:
        return world.policy_backend(spec)
    except ObjectiveError as err:
        raise ObjectiveError(f"--policy {spec.text}: {err}") from None

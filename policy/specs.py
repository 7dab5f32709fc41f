"""What ``--policy SPEC`` names, parsed in one place for ``objective run`` and ``objective eval``.

| spec | the policy served on ``/get_action_chunk`` |
|---|---|
| ``oracle`` (default) | the scripted oracle, peeking at the simulated cell (built by ``sim``) |
| ``replay:FILE`` | the chunks recorded in FILE (JSON lines) |
| ``lerobot:DIR`` | a LeRobot checkpoint (``make lerobot``) |
| ``FILE.py:NAME``, ``MODULE:NAME`` | your own backend factory (``policy.factory``) |
| ``http://127.0.0.1:PORT``, ``https://HOST`` | a running inference server; its bearer key from ``POLICY_SERVER_KEY`` |
| ``none`` | nothing is served (the Objective needs no policy, or one comes from elsewhere) |

``replay`` and ``lerobot`` are read as kinds, so a module of those names is not a factory module.
"""
from __future__ import annotations

import enum
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from runtime.app.command import POLICY_SPECS
from runtime.errors import OptionError

from .factory import FactoryError, build_backend, factory_file, is_factory_spec

HTTP_TIMEOUT_S = 10.0
"""Wall-clock deadline of one call to an inference server (the shipped Objectives' policy_call_timeout)."""


class PolicySpecError(OptionError):
    """A ``--policy`` that names no policy; the message starts ``policy '...'`` and says what is wrong."""


class PolicyKind(enum.Enum):
    ORACLE = "oracle"
    REPLAY = "replay"
    LEROBOT = "lerobot"
    FACTORY = "factory"
    HTTP = "http"
    NONE = "none"


@dataclass(frozen=True)
class PolicySpec:
    kind: PolicyKind
    text: str
    path: Path | None = None
    """The replay file, the checkpoint directory or the factory's file."""
    key: str | None = field(default=None, repr=False, compare=False)
    """An inference server's bearer key, read from ``POLICY_SERVER_KEY`` where the spec is parsed
    and carried with it (a Ray node has no such variable)."""

    @property
    def deterministic(self) -> bool:
        return self.kind not in (PolicyKind.HTTP, PolicyKind.FACTORY)


def parse_policy(text: str | None) -> PolicySpec:
    """The spec ``text`` names (None: the oracle); PolicySpecError naming what is wrong."""
    text = (text or "oracle").strip()
    lowered = text.lower()
    if lowered in ("oracle", "none"):
        return PolicySpec(PolicyKind(lowered), lowered)
    if lowered.startswith(("http://", "https://")):
        from .http_client import InferUrlError, check_infer_url
        from .server import key_from_env

        try:
            check_infer_url(text)
        except InferUrlError as err:
            raise PolicySpecError(f"policy '{text}': {err}") from None
        return PolicySpec(PolicyKind.HTTP, text, key=key_from_env(dict(os.environ)))
    kind, sep, rest = text.partition(":")
    if sep and kind in ("replay", "lerobot") and rest:
        path = Path(rest).expanduser()
        if kind == "replay" and not path.is_file():
            raise PolicySpecError(f"policy 'replay:{rest}': no such file")
        if kind == "lerobot" and not path.is_dir():
            raise PolicySpecError(f"policy 'lerobot:{rest}': no such checkpoint directory")
        return PolicySpec(PolicyKind(kind), f"{kind}:{path.resolve()}", path.resolve())
    if is_factory_spec(text):
        file = factory_file(text)
        if file is None:
            return PolicySpec(PolicyKind.FACTORY, text)
        if not file.is_file():
            raise PolicySpecError(f"policy '{text}': no such file {file}")
        return PolicySpec(PolicyKind.FACTORY, f"{file.resolve()}:{text.rpartition(':')[2]}", file.resolve())
    raise PolicySpecError(f"policy '{text}' is unknown (expected {POLICY_SPECS})")


def make_backend(spec: PolicySpec, oracle: Any = None) -> Any:
    """The backend ``spec`` names (None for ``none``), not yet loaded; ``oracle`` builds the oracle's
    (the simulated cell supplies it). PolicySpecError when it cannot be built."""
    if spec.kind is PolicyKind.NONE:
        return None
    if spec.kind is PolicyKind.ORACLE:
        if oracle is None:
            raise PolicySpecError("policy 'oracle' peeks at the simulated cell: this world has none "
                                  f"(name another: {POLICY_SPECS})")
        return oracle()
    if spec.kind is PolicyKind.REPLAY:
        from .replay import ReplayBackend

        assert spec.path is not None  # a replay spec names its file
        return ReplayBackend(spec.path)
    if spec.kind is PolicyKind.LEROBOT:
        from .lerobot_backend import make_lerobot_backend

        assert spec.path is not None  # a lerobot spec names its checkpoint
        return make_lerobot_backend(spec.path, warmup_on_load=True)
    if spec.kind is PolicyKind.HTTP:
        from .http_client import ClientConfig, HttpBackend

        return HttpBackend(ClientConfig(spec.text, timeout=HTTP_TIMEOUT_S, key=spec.key))
    from .server import BackendOptions

    try:
        return build_backend(spec.text, BackendOptions())
    except FactoryError as err:
        raise PolicySpecError(str(err)) from None  # "policy factory FILE.py:NAME ..."

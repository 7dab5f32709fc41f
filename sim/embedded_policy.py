"""The policy a headless world serves on ``/get_action_chunk``, chosen by a spec string.

``oracle`` (default): the scripted cube-stacking oracle, peeking at the cell.
``replay:FILE``: the chunks recorded in FILE (JSON lines), then NO_MORE_ACTIONS.
``lerobot:DIR``: the LeRobot checkpoint in DIR (``policy.lerobot_backend``; needs ``make lerobot``),
warmed up with a synthetic full-size observation when loaded.
``none``: serve nothing (a policy comes from elsewhere, or a test serves its own).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from policy.adapter import DEFAULT_SERVICE_NAME, PolicyAdapter
from runtime.bus import parse_latency
from runtime.errors import OptionError

POLICY_SPECS = "oracle, replay:FILE or none"


def make_backend(spec: str | None, cell: Any) -> Any:
    """The backend named by ``spec`` (None for ``none``); ValueError for an unknown spec."""
    spec = (spec or "oracle").strip()
    if spec == "none":
        return None
    if spec == "oracle":
        from .oracle import oracle_for_cell

        return oracle_for_cell(cell)
    if spec.startswith("replay:"):
        from policy.replay import ReplayBackend

        path = Path(spec.split(":", 1)[1])
        if not path.is_file():
            raise OptionError(f"policy 'replay:{path}': no such file")
        return ReplayBackend(path)
    if spec.startswith("lerobot:"):
        from policy.lerobot_backend import make_lerobot_backend

        path = Path(spec.split(":", 1)[1])
        if not path.is_dir():
            raise OptionError(f"policy 'lerobot:{path}': no such checkpoint directory")
        return make_lerobot_backend(path, warmup_on_load=True)
    raise OptionError(f"unknown policy '{spec}' (expected {POLICY_SPECS})")


def serve_embedded_policy(bus: Any, spec: str | None, cell: Any, latency: str | None, seed: int) -> PolicyAdapter | None:
    """Serve the backend on the bus under ``/get_action_chunk`` with the latency model."""
    backend = make_backend(spec, cell)
    if backend is None:
        return None
    backend.load()
    adapter = PolicyAdapter(backend).serve(bus, DEFAULT_SERVICE_NAME)
    if latency and hasattr(bus, "set_latency"):
        bus.set_latency(DEFAULT_SERVICE_NAME, parse_latency(latency, seed))
    return adapter

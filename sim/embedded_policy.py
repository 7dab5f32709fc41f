"""The policy a headless world serves on ``/get_action_chunk``, chosen by a ``--policy`` spec.

The spec is parsed by ``policy.specs`` (oracle, replay:FILE, lerobot:DIR, FILE.py:FACTORY,
MODULE:FACTORY, http(s)://HOST:PORT, none); the cell supplies only the oracle, which peeks at it.
A LeRobot checkpoint is warmed up with a synthetic full-size observation when loaded.
"""
from __future__ import annotations

from typing import Any

from policy.adapter import DEFAULT_SERVICE_NAME, PolicyAdapter
from policy.specs import PolicySpec, PolicySpecError, parse_policy
from policy.specs import make_backend as make_spec_backend
from runtime.io.bus import Bus, SimulatedLatency, capability, parse_latency
from runtime.errors import ObjectiveError
from runtime.io.interrupt import describe_error, raised_by_code

def make_backend(spec: PolicySpec | str | None, cell: Any) -> Any:
    """The backend named by ``spec`` (None for ``none``); PolicySpecError (an OptionError) for a spec that names none."""
    if not isinstance(spec, PolicySpec):
        spec = parse_policy(spec)

    def oracle() -> Any:
        from .oracle import oracle_for_cell

        return oracle_for_cell(cell)

    return make_spec_backend(spec, oracle)


def serve_embedded_policy(bus: Bus, spec: str | None, cell: Any, latency: str | None, seed: int) -> PolicyAdapter | None:
    """Serve the backend on the bus under ``/get_action_chunk`` with the latency model."""
    backend = make_backend(spec, cell)
    if backend is None:
        return None
    try:
        backend.load()
    except ObjectiveError:
        raise
    except BaseException as err:  # the policy's own code: its error, sys.exit() and KeyboardInterrupt included
        if not raised_by_code(err):
            raise
        name = getattr(backend, "name", type(backend).__name__)
        raise PolicySpecError(f"policy backend '{name}' failed to load: {describe_error(err)}") from None
    adapter = PolicyAdapter(backend).serve(bus, DEFAULT_SERVICE_NAME)
    modelled = capability(bus, SimulatedLatency)  # None: a real graph, whose latency is its own
    if latency and modelled is not None:
        modelled.set_latency(DEFAULT_SERVICE_NAME, parse_latency(latency, seed))
    return adapter

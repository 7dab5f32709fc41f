"""The GetActionChunk adapter node: ``/get_action_chunk`` on real ROS 2, forwarding to the HTTP server.

Run it as ``objective adapter --infer-url http://127.0.0.1:PORT``. It is the guide's thin ROS 2
bridge: the process next to the robot stack that has rclpy and the ``moveit_pro_ml_msgs``
interfaces but no ML stack. One ``PolicyAdapter`` (the same code the headless runtime serves on
its in-process bus) with an ``HttpBackend`` behind it, on a ``RosBus`` node called
``get_action_chunk_adapter``:

- the request's frames are converted to RGB and sent raw (lossless); the RTC carryover
  (``previous_action_chunk``, ``previous_anchor_state``, ``frozen_prefix_steps``,
  ``guidance_horizon``) and ``robot_state.header.stamp`` are forwarded as they are: the
  ``guidance_horizon`` -> ``execution_horizon`` conversion belongs to the server's backend;
- the answer is validated (non-empty chunk, one column per observed joint, finite) and its joint
  names echo ``robot_state.name``;
- any failure answers ERROR with a reason within the HTTP timeout (2.5 s by default, below
  ExecutePolicy's ``policy_call_timeout`` of 3 s);
- every served chunk is counted and logged (``--log-every``), the counter the guide's bring-up
  says to watch climbing.

Start-up refuses an ``infer_url`` that is neither loopback nor verified HTTPS, with the reason.
SIGINT and SIGTERM stop it cleanly (exit 0).
"""
from __future__ import annotations

import logging
import os
import threading
from dataclasses import dataclass
from pathlib import Path

from .adapter import DEFAULT_SERVICE_NAME, PolicyAdapter
from .http_client import DEFAULT_TIMEOUT_S, ClientConfig, HttpBackend
from .server import stop_on_signals

NODE_NAME = "get_action_chunk_adapter"
log = logging.getLogger("policy.node")


@dataclass(frozen=True)
class AdapterConfig:
    infer_url: str
    service_name: str = DEFAULT_SERVICE_NAME
    timeout: float = DEFAULT_TIMEOUT_S
    key: str | None = None
    ca_file: Path | None = None
    client_cert: Path | None = None
    client_key: Path | None = None
    log_every: int = 1
    """Log the served-chunk count every this many chunks."""


def http_adapter(config: AdapterConfig) -> PolicyAdapter:
    """The adapter logic with its HTTP backend; ``InferUrlError``/``ValueError`` for a bad config.

    Transport-free: serve it on any bus (``adapter.serve(bus, name)``), in-process or ROS 2.
    """
    backend = HttpBackend(ClientConfig(
        infer_url=config.infer_url,
        timeout=config.timeout,
        key=config.key,
        ca_file=config.ca_file,
        client_cert=config.client_cert,
        client_key=config.client_key,
    ))
    return PolicyAdapter(backend, log_every=config.log_every, logger=logging.getLogger("policy.adapter"))


def run_adapter_node(config: AdapterConfig, stop: threading.Event | None = None) -> int:
    """Serve ``config.service_name`` on ROS 2 until SIGINT/SIGTERM (or ``stop``); returns 0.

    Configuration errors raise before anything joins the ROS graph.
    """
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    adapter = http_adapter(config)
    backend: HttpBackend = adapter.backend  # type: ignore[assignment]
    if not config.key:
        log.warning("POLICY_SERVER_KEY is not set: requests carry no bearer key (the server must run --insecure-no-key)")
    health = backend.health()
    log.info("inference server at %s reports %s%s", backend.endpoint.health_url, health.get("status"),
             f": {health['message']}" if health.get("message") else "")

    import rclpy
    from rclpy.executors import ExternalShutdownException

    from runtime.io.clock import WallClock
    from runtime.io.ros import RosBus

    stop = stop or threading.Event()
    restore = stop_on_signals(stop)
    bus = RosBus(WallClock(), node_name=NODE_NAME)
    try:
        adapter.serve(bus, config.service_name)
        print(f"serving {config.service_name} -> {backend.url}", flush=True)
        while bus.context.ok() and not stop.wait(0.1):
            pass
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        bus.close()
        rclpy.try_shutdown(context=bus.context)
        restore()
        log.info("stopped: served %d chunks, answered %d errors in %d calls",
                 adapter.served_chunks, adapter.errors, adapter.calls)
    return 0

